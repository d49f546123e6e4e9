"""Physical models of valve-controlled hydraulic cylinders (no ROS imports)."""
