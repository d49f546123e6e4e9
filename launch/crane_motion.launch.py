"""The crane's motion side: trajectory_server (serves the trajectory database) and trajectory_executor (the P-VI
controller that turns a served trajectory into valve commands), with the monitor's halt guarding it.

    ros2 launch hydro_ros crane_motion.launch.py database:=/var/lib/hydro_ros/k70m.db namespace:=crane

The server sends each served trajectory to the executor's input (``trajectory_executor/joint_trajectory``); the
executor takes trajectories only from this server, joint states only from ``joint_state_source`` (can_bridge) and
moves only while fdi_node's /fdi/halt says false (``require_monitor``). It is a lifecycle node driven by launch
(``auto_configure``, ``auto_activate``): until it is active it sends nothing, and deactivation leaves every valve
neutral. Start machine.launch.py beside it for the sensors and the monitor.
"""

from launch import LaunchDescription
from launch.actions import DeclareLaunchArgument, EmitEvent, RegisterEventHandler
from launch.conditions import IfCondition
from launch.events import matches_action
from launch.substitutions import LaunchConfiguration, PathJoinSubstitution
from launch_ros.actions import LifecycleNode, Node
from launch_ros.event_handlers import OnStateTransition
from launch_ros.events.lifecycle import ChangeState
from launch_ros.substitutions import FindPackageShare
from lifecycle_msgs.msg import Transition


def generate_launch_description() -> LaunchDescription:
    share = FindPackageShare("hydro_ros")
    namespace = LaunchConfiguration("namespace")
    config = LaunchConfiguration("config")
    def ros_arguments(name: str) -> list:
        # each node in its own SROS2 enclave under the root (docs/deploy.md); without ROS_SECURITY_ENABLE it is not read
        return ["--log-level", LaunchConfiguration("log_level"), "--enclave", PathJoinSubstitution([LaunchConfiguration("enclave"), name])]

    arguments = [
        DeclareLaunchArgument("namespace", default_value="", description="namespace of the crane's nodes and topics"),
        DeclareLaunchArgument("config", default_value=PathJoinSubstitution([share, "config", "k70m.yaml"]),
                              description="machine config with a planner: section"),
        DeclareLaunchArgument("database", description="trajectory database (hydro-ros db build)"),
        DeclareLaunchArgument("joint_state_source", default_value="can_bridge", description="the only node whose /joint_states move it"),
        DeclareLaunchArgument("auto_configure", default_value="true", description="configure trajectory_executor at launch"),
        DeclareLaunchArgument("auto_activate", default_value="true", description="activate trajectory_executor once configured"),
        DeclareLaunchArgument("enclave", default_value="/hydro_ros", description="SROS2 enclave root: each node runs in <enclave>/<node>"),
        DeclareLaunchArgument("log_level", default_value="info", description="log level of both nodes"),
    ]
    server = Node(package="hydro_ros", executable="trajectory_server", name="trajectory_server", namespace=namespace, output="screen",
                  parameters=[{"database": LaunchConfiguration("database"), "config": config,
                               "output_topic": "trajectory_executor/joint_trajectory"}], ros_arguments=ros_arguments("trajectory_server"))
    executor = LifecycleNode(package="hydro_ros", executable="trajectory_executor", name="trajectory_executor", namespace=namespace,
                             output="screen", ros_arguments=ros_arguments("trajectory_executor"),
                             parameters=[{"config": config, "autostart": False, "trajectory_source": "trajectory_server",
                                          "joint_state_source": LaunchConfiguration("joint_state_source"), "require_monitor": True}])
    configure = EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(executor), transition_id=Transition.TRANSITION_CONFIGURE),
                          condition=IfCondition(LaunchConfiguration("auto_configure")))
    # activate after launch's own configure only (configuring -> inactive, once): a deactivate, or an operator's
    # cleanup -> configure, also ends in inactive and must leave the node stopped (ros2_socketcan's launch habit)
    activate = RegisterEventHandler(OnStateTransition(
        target_lifecycle_node=executor, start_state="configuring", goal_state="inactive", handle_once=True,
        entities=[EmitEvent(event=ChangeState(lifecycle_node_matcher=matches_action(executor), transition_id=Transition.TRANSITION_ACTIVATE))]),
        condition=IfCondition(LaunchConfiguration("auto_activate")))
    return LaunchDescription([*arguments, server, executor, activate, configure])
