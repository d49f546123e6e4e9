"""Simulated SAM monitored live: plant_sim with its operator, fdi_node and the operator HMI
(for machines that have ros2 launch). The HMI's operator token comes from HYDRO_ROS_HMI_TOKEN in
the environment of `ros2 launch`; without it the page is read-only."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    use_sim_time = LaunchConfiguration("use_sim_time")
    namespace = LaunchConfiguration("namespace")
    return LaunchDescription([
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the simulated machine's nodes and topics"),
        DeclareLaunchArgument("use_sim_time", default_value="false"),
        DeclareLaunchArgument("real_time_factor", default_value="1.0"),
        DeclareLaunchArgument("hmi_port", default_value="8080", description="the HMI page on http://127.0.0.1:<port>/"),
        Node(
            package="hydro_ros",
            executable="plant_sim",
            namespace=namespace,
            parameters=[{"use_sim_time": use_sim_time, "real_time_factor": LaunchConfiguration("real_time_factor")}],
        ),
        Node(package="hydro_ros", executable="fdi_node", namespace=namespace, parameters=[{"use_sim_time": use_sim_time}]),
        Node(package="hydro_ros", executable="hmi", namespace=namespace, parameters=[{"port": LaunchConfiguration("hmi_port")}]),
    ])
