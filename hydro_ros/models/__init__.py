"""Physical models (no ROS): the SAM's valve-controlled cylinder and the crane's kinematics and hydraulics."""
