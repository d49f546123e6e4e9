"""Studies over the science layers (no ROS): FDI evaluation and parity fit, the discrepancy workflow,
the GSA, the DP comparison, closed-loop execution, and their plots. Each module is imported on its
own (``hydro_ros.studies.gsa``): they pull in heavy optional libraries (matplotlib, SALib)."""
