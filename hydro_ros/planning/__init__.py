"""Energy-optimal redundancy resolution (no ROS): paths, costs, the fast DP and its baselines, the
trajectory database with its catalog build, and serving a stored plan from the actual joints."""
