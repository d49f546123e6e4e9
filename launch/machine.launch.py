"""Bring-up of a machine (a SAM type, the K70M crane or your own): can_bridge (sensors from the CAN bus), fdi_node (the
monitor), the operator HMI and, where installed, diagnostic_aggregator.

    ros2 launch hydro_ros machine.launch.py params_file:=/path/to/my_machine.yaml namespace:=machine2 channel:=can1

Arguments: ``namespace`` (every node and topic under it, so machines share a graph; /diagnostics stays absolute and
names the namespace in each status), ``params_file`` (one per machine: config/params/<machine>.yaml, written by
``hydro-ros params``), ``interface`` and ``channel`` of the bus, ``log_level``, ``use_sim_time``, ``enclave`` (the SROS2
enclave root: each node runs in <enclave>/<node>, read only when security is enabled), and ``start_<node>`` for each
node. can_bridge is a lifecycle node driven by launch, as ros2_socketcan's: ``auto_configure`` emits its configure
transition, and ``auto_activate`` its activate once it reaches inactive; a configure that fails (no such
bus) leaves it unconfigured and says why. The HMI's operator token comes from HYDRO_ROS_HMI_TOKEN in the environment of
``ros2 launch``; without it the page is read-only.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.parameter_descriptions import ParameterFile
from launch_ros.substitutions import FindPackageShare
from lifecycle_msgs.msg import Transition

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
    def ros_arguments(name: str) -> list:
        # each node in its own SROS2 enclave under the root (docs/deploy.md); without ROS_SECURITY_ENABLE it is not read
        return ["--log-level", LaunchConfiguration("log_level"), "--enclave", PathJoinSubstitution([LaunchConfiguration("enclave"), name])]

    arguments = [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of every node and topic of this machine"),
        DeclareLaunchArgument("params_file", default_value=PathJoinSubstitution([share, "config", "params", "sam.yaml"]),
                              description="ros__parameters of the nodes (hydro-ros params --config ...)"),
        DeclareLaunchArgument("interface", default_value="socketcan", description="python-can interface of the machine's bus"),
        DeclareLaunchArgument("channel", default_value="can0", description="channel of the machine's bus"),
        DeclareLaunchArgument("auto_configure", default_value="true", description="configure can_bridge (open the bus) at launch"),
        DeclareLaunchArgument("auto_activate", default_value="true", description="activate can_bridge once configured"),
        DeclareLaunchArgument("enclave", default_value="/hydro_ros", description="SROS2 enclave root: each node runs in <enclave>/<node>"),
        DeclareLaunchArgument("log_level", default_value="info", description="log level of every node"),
        DeclareLaunchArgument("use_sim_time", default_value="false", description="take the time from /clock"),
        *(DeclareLaunchArgument(f"start_{name}", default_value="true", description=f"start {name}") for name in NODES),
        DeclareLaunchArgument("start_diagnostic_aggregator", default_value=str(_installed("diagnostic_aggregator")).lower(),
                              description="start diagnostic_aggregator with config/diagnostic_aggregator.yaml (if installed)"),
    ]
    bridge = LifecycleNode(package="hydro_ros", executable="can_bridge", name="can_bridge", namespace=namespace, output="screen",
                           parameters=[params, {"use_sim_time": use_sim_time, "autostart": False, "interface": LaunchConfiguration("interface"),
                                                "channel": LaunchConfiguration("channel")}],
                           ros_arguments=ros_arguments("can_bridge"), condition=IfCondition(LaunchConfiguration("start_can_bridge")))
    configure = EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(bridge), transition_id=Transition.TRANSITION_CONFIGURE),
                          condition=IfCondition(LaunchConfiguration("auto_configure")))
    # activate after launch's own configure only (configuring -> inactive, once): a deactivate, or an operator's
    # cleanup -> configure, also ends in inactive and must leave the node stopped (ros2_socketcan's launch habit)
    activate = RegisterEventHandler(OnStateTransition(
        target_lifecycle_node=bridge, start_state="configuring", goal_state="inactive", handle_once=True,
        entities=[EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(bridge), transition_id=Transition.TRANSITION_ACTIVATE))]),
        condition=IfCondition(LaunchConfiguration("auto_activate")))
    nodes = [
        Node(package="hydro_ros", executable=name, name=name, namespace=namespace, output="screen",
             parameters=[params, {"use_sim_time": use_sim_time}], ros_arguments=ros_arguments(name),
             condition=IfCondition(LaunchConfiguration(f"start_{name}")))
        for name in NODES if name != "can_bridge"
    ]
    # /diagnostics is absolute: one aggregator per graph reads every machine's statuses (their names carry the namespace)
    aggregator = Node(package="diagnostic_aggregator", executable="aggregator_node", name="analyzers",
                      parameters=[PathJoinSubstitution([share, "config", "diagnostic_aggregator.yaml"]), {"use_sim_time": use_sim_time}],
                      condition=IfCondition(LaunchConfiguration("start_diagnostic_aggregator")))
    return LaunchDescription([*arguments, bridge, activate, configure, *nodes, aggregator])
