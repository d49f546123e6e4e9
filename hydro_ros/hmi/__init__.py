"""The operator HMI: its state model and web server (no rclpy; the node is hydro_ros.nodes.hmi)."""
