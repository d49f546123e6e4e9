"""What ships around the monitor and the planner (no ROS): commissioning a machine from its own recordings, the
fleet view over many machines' recordings, the discrepancy workflow that names the effect a model is missing, the
closed-loop execution of a stored trajectory, and their plots. Each module is imported on its own
(``hydro_ros.workflows.commissioning``): they pull in heavy optional libraries (matplotlib)."""
