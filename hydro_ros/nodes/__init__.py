"""Thin ROS 2 nodes wiring the libraries to the contract topics."""
