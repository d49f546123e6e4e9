"""Simulated SAM: plant_sim with its operator (for machines that have ros2 launch)."""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.substitutions import LaunchConfiguration
from launch_ros.actions import Node


def generate_launch_description() -> LaunchDescription:
    return LaunchDescription([
        DeclareLaunchArgument("use_sim_time", default_value="false"),
        DeclareLaunchArgument("real_time_factor", default_value="1.0"),
        Node(
            package="hydro_ros",
            executable="plant_sim",
            parameters=[{
                "use_sim_time": LaunchConfiguration("use_sim_time"),
                "real_time_factor": LaunchConfiguration("real_time_factor"),
            }],
        ),
    ])
