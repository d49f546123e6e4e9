"""Nothing moves unasked: trajectory_executor on a live graph against a blind monitor, a spoofing node and bad trajectories.

crane_sim is the plant (its valves take the executor's commands); the probe node ``client`` is both the configured
trajectory source and the configured monitor; a second node ``spoof`` in the same process is anyone else on the graph.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest
from builtin_interfaces.msg import Duration
from rclpy.serialization import serialize_message
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from hydro_ros.contract import topics
from hydro_ros.nodes.common import HALT_QOS, LATCHED_QOS, SENSOR_QOS
from hydro_ros.safety.motion import HEARTBEAT_PERIOD_S, HEARTBEAT_TIMEOUT_S
from test.conftest import K70M
from test.ros_graph import node_process, probe_node, spin_until

EXECUTOR = "/crane/trajectory_executor"
SLEW_STEP = 5.0 / 100.0  # command_slew_rate over the controller's 100 Hz


def _move(joints: np.ndarray, names: list[str], extension_step: float, duration: float, points: int = 21) -> JointTrajectory:
    msg = JointTrajectory(joint_names=names)
    for k, t in enumerate(np.linspace(0.0, duration, points)):
        point = JointTrajectoryPoint(positions=(joints + np.array([0.0, 0.0, 0.0, extension_step * k / (points - 1)])).tolist(),
                                     velocities=[0.0, 0.0, 0.0, extension_step / duration])
        point.time_from_start = Duration(sec=int(t), nanosec=int(round((t % 1.0) * 1e9)))
        msg.points.append(point)
    return msg


def test_the_executor_takes_orders_only_from_its_sources_and_never_steps_a_valve(ros_domain, k70m):
    names = k70m.joint_names
    with node_process("hydro_ros.nodes.crane_sim", "-r", "__ns:=/crane", "-p", f"config:={K70M}", "-p", "external_commands:=true",
                      "-p", "publish_rate:=100.0", "-p", "initial_path:=horizontal", "-p", "initial_extension:=0.3"), \
            node_process("hydro_ros.nodes.trajectory_executor", "-r", "__ns:=/crane", "-p", f"config:={K70M}",
                         "-p", "joint_state_source:=crane_sim", "-p", "trajectory_source:=/client", "-p", "monitor:=/client",
                         "-p", "joint_state_timeout:=1.0"), \
            probe_node("client") as node:
        import rclpy

        spoof = rclpy.create_node("spoof")
        seen: dict[str, list] = {"joints": [], "commands": [], "status": []}
        node.create_subscription(JointState, "/crane" + topics.JOINT_STATES,
                                 lambda m: seen["joints"].append(np.array(m.position)), 10)
        # (the executor's stamp of the command, the command): its own clock tells whether its loop stalled
        node.create_subscription(JointState, "/crane" + topics.VALVE_COMMANDS, lambda m: seen["commands"].append(
            (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, np.array(m.position))), 2000)
        node.create_subscription(String, f"{EXECUTOR}/status", lambda m: seen["status"].append(json.loads(m.data)), LATCHED_QOS)
        trajectories = node.create_publisher(JointTrajectory, f"{EXECUTOR}/joint_trajectory", 10)
        halt = node.create_publisher(Bool, "/crane" + topics.FDI_HALT, HALT_QOS)
        spoof_trajectories = spoof.create_publisher(JointTrajectory, f"{EXECUTOR}/joint_trajectory", 10)
        spoof_halt = spoof.create_publisher(Bool, "/crane" + topics.FDI_HALT, HALT_QOS)
        spoof_joints = spoof.create_publisher(JointState, "/crane" + topics.JOINT_STATES, SENSOR_QOS)
        heartbeat = {"on": False}
        node.create_timer(HEARTBEAT_PERIOD_S, lambda: heartbeat["on"] and halt.publish(Bool(data=False)))

        def spin(seconds: float) -> None:
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                rclpy.spin_once(node, timeout_sec=0.01)
                rclpy.spin_once(spoof, timeout_sec=0.0)

        def send(msg: JointTrajectory, publisher=trajectories) -> dict:
            # asked again when no answer comes: the executor's reader may not have matched the writer yet, or the graph not
            # yet say whose the writer is (both only after start-up)
            for _ in range(5):
                count = len(seen["status"])
                publisher.publish(msg)
                end = time.monotonic() + 2.0
                while time.monotonic() < end:
                    answers = [s for s in seen["status"][count:] if s["state"] in ("refused", "executing")]
                    if answers:
                        return answers[0]
                    spin(0.05)
            raise AssertionError(f"no answer on ~/status: {seen['status'][-3:]}")

        try:
            assert spin_until(node, lambda: seen["joints"] and trajectories.get_subscription_count() > 0
                              and spoof_trajectories.get_subscription_count() > 0
                              and seen["status"] and seen["status"][-1]["state"] == "idle", 30)
            # require_monitor is the default: with no monitor vouching, nothing runs
            for _ in range(10):  # once the executor has matched crane_sim's joint states
                refused = send(_move(seen["joints"][-1], names, 0.3, 6.0))
                if "joint state" not in refused["reason"] and "not yet identified" not in refused["reason"]:
                    break
                spin(0.5)
            assert refused["state"] == "refused" and "no heartbeat from the condition monitor" in refused["reason"], seen["status"]
            heartbeat["on"] = True
            # the executor has the crane's joint states once a trajectory 0.1 m off them is refused for its start (the
            # heartbeat's reason hides theirs until then; a loaded machine delivers them late), and nothing moves
            for _ in range(20):
                off = send(_move(seen["joints"][-1] + np.array([0.0, 0.0, 0.0, 0.1]), names, 0.3, 6.0))
                if off["state"] == "refused" and "from the measured joints" in off["reason"]:
                    break
                spin(0.5)
            assert "from the measured joints" in off["reason"], off

            # anyone else's trajectory is refused and named; a joint named twice and an oversize trajectory are refused
            count = len(seen["status"])
            for _ in range(10):
                spoof_trajectories.publish(_move(seen["joints"][-1], names, 0.3, 6.0))
                spin(0.5)
                if "foreign_publishers" in seen["status"][-1]:
                    break
            assert all(s["state"] != "executing" for s in seen["status"][count:])
            assert seen["status"][-1]["foreign_publishers"]["trajectory"] == ["/spoof"]
            twice = _move(seen["joints"][-1], names, 0.3, 6.0)
            twice.joint_names = [names[0], *names[:-1]]
            assert "named twice" in send(twice)["reason"]

            # a replacing trajectory ramps the commands over: no step above the slew limit
            assert send(_move(seen["joints"][-1], names, 0.3, 6.0))["state"] == "executing"
            spin_until(node, lambda: np.abs(seen["commands"][-1][1]).max() > 0.5, 5)
            assert np.abs(seen["commands"][-1][1]).max() > 0.5
            switched = len(seen["commands"])
            assert send(_move(seen["joints"][-1], names, -0.3, 6.0))["state"] == "executing"
            spin(1.0)
            commands = np.array([c for _, c in seen["commands"][switched - 1:]])
            steps = np.abs(np.diff(commands, axis=0))
            assert commands[0, 3] > 0.5 and steps.max() == pytest.approx(SLEW_STEP)  # the ramp took over ...
            assert steps.max() <= SLEW_STEP + 1e-9  # ... and no step was larger

            # an oversize trajectory is refused before decoding, and the control loop never waits for it
            huge = serialize_message(_move(seen["joints"][-1], names, -0.01, 100.0, points=40_001))
            assert len(huge) > 4e6  # 4 MB that the executor never decodes
            before = len(seen["commands"])
            status = send(huge)
            assert status["state"] == "refused" and "40001 points, max_points 10000" in status["reason"]
            spin(0.3)
            stamps = [t for t, _ in seen["commands"][before - 1:]]
            # decoding 40 001 points takes 0.6 s of an idle core here; receiving 4 MB on 2 loaded cores stalls the loop 0.1-0.3 s
            assert np.diff(stamps).max() < 0.5, "the control loop stalled on an oversize trajectory"

            # fake joint states from anyone else are not taken: a trajectory from where they say the crane is, is refused
            fake = seen["joints"][-1] + np.array([0.0, 0.2, 0.0, 0.0])
            for _ in range(60):  # until the graph names the spoof's publisher
                spoof_joints.publish(JointState(name=names, position=fake.tolist()))
                spin(0.05)
                if "joint_states" in seen["status"][-1].get("foreign_publishers", {}):
                    break
            from_fake = send(_move(fake, names, 0.1, 6.0))
            assert from_fake["state"] == "refused" and "from the measured joints" in from_fake["reason"]
            assert from_fake["foreign_publishers"]["joint_states"] == ["/spoof"]

            # anyone may halt; only the monitor clears it (its next heartbeat: here held back to see the latch)
            assert send(_move(seen["joints"][-1], names, 0.3, 6.0))["state"] == "executing"
            heartbeat["on"] = False
            spin(0.3)  # the monitor's last "no halt" delivered first
            spoof_halt.publish(Bool(data=True))
            spin(0.5)
            assert seen["status"][-1]["state"] == "stopped" and not seen["commands"][-1][1].any()
            spoof_halt.publish(Bool(data=False))
            spin(0.5)
            assert "halt" in send(_move(seen["joints"][-1], names, 0.3, 6.0))["reason"]
            heartbeat["on"] = True
            spin(1.0)
            assert send(_move(seen["joints"][-1], names, 0.3, 6.0))["state"] == "executing"

            # the monitor going silent (dead) stops the crane within the heartbeat timeout (and a control period)
            spin_until(node, lambda: np.abs(seen["commands"][-1][1]).max() > 0.5, 5)
            heartbeat["on"] = False
            silent = time.time()  # the executor stamps its commands with the system clock
            spin(2.5)
            assert any(s["state"] == "stopped" and "silent" in s["reason"] for s in seen["status"])
            after = [(t, c) for t, c in seen["commands"] if t > silent]
            first_neutral = next(t for t, c in after if not c.any())
            assert first_neutral - silent < HEARTBEAT_TIMEOUT_S + 0.3
            assert all(not c.any() for t, c in after if t >= first_neutral)
        finally:
            spoof.destroy_node()


def test_joint_states_going_stale_mid_move_stop_the_crane_neutral_until_they_return(ros_domain):
    """The probe is the crane's sensor bridge (its joint states), the monitor and the trajectory source. Mid-move its
    joint states stop: the executor stops for "joint state stale" on ~/status, every command it stamps after the probe
    heard that is neutral (by event order, not a latency: that is measured in bench/halt_latency.py), and when the joint
    states return nothing moves until a new trajectory is sent."""

    from hydro_ros.models.crane import load_crane

    timeout = 0.2
    crane, _ = load_crane(K70M)
    names = list(crane.names)
    pose = np.array([0.5 * (c.q_min + c.q_max) for c in crane.cylinders])
    with node_process("hydro_ros.nodes.trajectory_executor", "-r", "__ns:=/crane", "-p", f"config:={K70M}",
                      "-p", "joint_state_source:=/client", "-p", "trajectory_source:=/client", "-p", "monitor:=/client",
                      "-p", f"joint_state_timeout:={timeout}"), probe_node("client") as node:
        commands: list[tuple[float, np.ndarray]] = []
        status: list[dict] = []
        sent: list[float] = []  # system-clock times of the joint states published
        node.create_subscription(JointState, "/crane" + topics.VALVE_COMMANDS, lambda m: commands.append(
            (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, np.array(m.position))), 2000)
        heard: list[float] = []  # system-clock times the probe received each status
        node.create_subscription(String, f"{EXECUTOR}/status", lambda m: (status.append(json.loads(m.data)), heard.append(time.time())),
                                 LATCHED_QOS)
        trajectories = node.create_publisher(JointTrajectory, f"{EXECUTOR}/joint_trajectory", 10)
        halt = node.create_publisher(Bool, "/crane" + topics.FDI_HALT, HALT_QOS)
        joints = node.create_publisher(JointState, "/crane" + topics.JOINT_STATES, SENSOR_QOS)
        feeding = {"on": True}

        def publish_joints() -> None:
            if feeding["on"]:
                joints.publish(JointState(name=names, position=pose.tolist()))
                sent.append(time.time())

        node.create_timer(0.01, publish_joints)
        node.create_timer(HEARTBEAT_PERIOD_S, lambda: halt.publish(Bool(data=False)))

        def executing() -> bool:
            trajectories.publish(_move(pose, names, 0.3, 6.0))
            spin_until(node, lambda: False, 0.3)
            return any(s["state"] == "executing" for s in status)

        assert spin_until(node, lambda: trajectories.get_subscription_count() > 0 and status, 30), status
        assert any(executing() for _ in range(20)), status[-3:]
        assert spin_until(node, lambda: commands and np.abs(commands[-1][1]).max() > 0.1, 5)
        before = len(status)  # a stop before this (a stalled probe's heartbeat) is not the one under test
        feeding["on"] = False
        assert spin_until(node, lambda: any(s["state"] == "stopped" for s in status[before:]), 10), status[-3:]
        spin_until(node, lambda: False, 1.0)
        index = next(i for i, s in enumerate(status) if i >= before and s["state"] == "stopped")
        assert "joint state stale" in status[index]["reason"], status[index]
        after = [c for t, c in commands if t > heard[index]]
        assert after and not any(c.any() for c in after), [c for c in after if c.any()][:3]
        moving = [t for t, c in commands if c.any()]
        assert moving and sent[-1] < moving[-1] + 1.0  # it was moving when its joint states stopped
        # the joint states return: the dropped trajectory stays dropped
        feeding["on"] = True
        back = len(commands)
        spin_until(node, lambda: False, 1.0)
        assert len(commands) > back and not any(c.any() for _, c in commands[back:])
        assert status[-1]["state"] != "executing"


def test_the_follow_joint_trajectory_action_is_offered_only_where_control_msgs_is_and_says_why_not():
    """control_msgs has no wheel here: the guard names it and the topic path; where it is installed the type is the
    action's (a ROS machine; the action itself is not exercised here)."""
    from hydro_ros.nodes.trajectory_executor import PARAMETERS, follow_joint_trajectory_action

    action, why_not = follow_joint_trajectory_action()
    try:
        import control_msgs  # noqa: F401
    except ImportError:
        assert action is None and "control_msgs" in why_not and "~/joint_trajectory" in why_not
    else:
        assert action.__name__ == "FollowJointTrajectory" and not why_not
    assert PARAMETERS["follow_joint_trajectory"].default is False  # goals from any client: off unless asked for
