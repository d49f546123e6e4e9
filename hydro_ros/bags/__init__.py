"""Contract bags (contract section 2): ROS 2 bag directories with MCAP storage, no ROS needed."""
