"""Bring-up of a machine (a SAM type or the K70M crane): can_bridge (sensors from the CAN bus), fdi_node (the monitor), the
operator HMI and, where installed, diagnostic_aggregator.

    ros2 launch hydro_ros machine.launch.py params_file:=/path/to/my_machine.yaml namespace:=machine2

Arguments: ``namespace`` (every node and topic under it, so machines share a graph), ``params_file``
(one per machine: config/params/<machine>.yaml, written by ``hydro-ros params``), ``use_sim_time``,
and ``start_<node>`` for each node. The HMI's operator token comes from HYDRO_ROS_HMI_TOKEN in the
environment of ``ros2 launch``; without it the page is read-only. can_bridge configures and activates
itself (``autostart``); set it false in the params file to leave its life cycle to a manager.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument
from launch.conditions import IfCondition
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import Node
from launch_ros.parameter_descriptions import ParameterFile
from launch_ros.substitutions import FindPackageShare

NODES = ("can_bridge", "fdi_node", "hmi")


def _installed(package: str) -> bool:
    from ament_index_python.packages import PackageNotFoundError, get_package_share_directory

    try:
        get_package_share_directory(package)
    except (PackageNotFoundError, OSError):  # OSError: no AMENT_PREFIX_PATH at all
        return False
    return True


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("hydro_ros")
    namespace = LaunchConfiguration("namespace")
    use_sim_time = LaunchConfiguration("use_sim_time")
    params = ParameterFile(LaunchConfiguration("params_file"), allow_substs=True)
    arguments = [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of every node and topic of this machine"),
        DeclareLaunchArgument("params_file", default_value=PathJoinSubstitution([share, "config", "params", "sam.yaml"]),
                              description="ros__parameters of the nodes (hydro-ros params --config ...)"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="take the time from /clock"),
        *(DeclareLaunchArgument(f"start_{name}", default_value="true", description=f"start {name}") for name in NODES),
        DeclareLaunchArgument("start_diagnostic_aggregator", default_value=str(_installed("diagnostic_aggregator")).lower(),
                              description="start diagnostic_aggregator with config/diagnostic_aggregator.yaml (if installed)"),
    ]
    nodes = [
        Node(package="hydro_ros", executable=name, name=name, namespace=namespace, output="screen",
             parameters=[params, {"use_sim_time": use_sim_time}], condition=IfCondition(LaunchConfiguration(f"start_{name}")))
        for name in NODES
    ]
    aggregator = Node(package="diagnostic_aggregator", executable="aggregator_node", name="analyzers", namespace=namespace,
                      parameters=[PathJoinSubstitution([share, "config", "diagnostic_aggregator.yaml"]), {"use_sim_time": use_sim_time}],
                      condition=IfCondition(LaunchConfiguration("start_diagnostic_aggregator")))
    return LaunchDescription([*arguments, *nodes, aggregator])
