"""trajectory_executor: the P-VI Appendix A motion controller of a real crane, as a node.

It takes a JointTrajectory on ``~/joint_trajectory`` (the form a ros2_control
JointTrajectoryController takes; trajectory_server's ``output_topic``) and the crane's
``/joint_states``, and sends ``/hydraulics/valve_commands`` (JointState: one name per cylinder,
position = valve command in [-1, 1]) at ``rate`` (``hydro_ros.planning.controller``). After the last
point it regulates to it for the controller's settle time, then idles. While it idles, and whenever
it stops, every valve is commanded neutral: a hydraulic crane holds its load on closed valves.

A lifecycle node (ros2_control's habit): configure reads the crane config; activate starts the
control loop; deactivate, shutdown and destruction send neutral commands first, and so does the
process on SIGINT or SIGTERM (it handles them itself, so its publisher still works). ``autostart``
(default true) configures and activates at start for machines without a lifecycle manager.

It stops (neutral at once, the trajectory dropped, the reason on ``~/status``) on:
- ``/fdi/halt`` true from any publisher: no motion until the configured ``monitor`` node itself confirms (a
  ``false`` from anyone else is refused and its sender named);
- with ``require_monitor`` (the default; opting out is logged at every configure), no fresh confirmation: motion needs a
  ``false`` from the monitor whose source stamp is at most HEARTBEAT_TIMEOUT_S (0.5 s) old, new (not a replay) and not
  followed by a ``true`` (:class:`hydro_ros.safety.motion.MotionAuthority`). The monitor says ``true`` whenever it
  cannot vouch for every actuator, and a latched or late-delivered ``false`` is old: a late joiner never moves on a stale
  "all clear". The valves go neutral within HEARTBEAT_TIMEOUT_S plus one control period of the last confirmation;
- a joint state from ``joint_state_source`` older than ``joint_state_timeout`` (a controller that cannot
  see the machine must not move it); joint states from other publishers are refused;
- an empty trajectory (ros2_control's "stop the current one").
A trajectory is taken only from ``trajectory_source``. It is refused when it has more than ``max_points``
points (counted in the serialized message before anything is decoded; decoding and checking run on a
thread of their own, so the control loop never waits for a trajectory), lacks a joint or names one twice, has non-finite values or non-increasing times,
leaves a joint's position range or a cylinder's velocity limit, or starts farther than
``start_tolerance`` from the measured joints. A trajectory that replaces a running one takes over
through a ramp of at most ``command_slew_rate`` per second in every valve command (the old motion is
decelerated, never reversed in one step).

``~/status`` (latched String, JSON): ``state`` (inactive, idle, executing, holding, stopped, refused),
``reason``, for a trajectory its ``points`` and ``duration_s``, and ``foreign_publishers`` once any
node other than the configured sources has sent to it; ``/diagnostics`` (``hydro_ros/trajectory_executor``)
says the same every second, WARN while a foreign publisher is on one of its inputs.
"""

from __future__ import annotations

import json
import math
import queue
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.duration import Duration
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from rclpy.task import Future
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from trajectory_msgs.msg import JointTrajectory

from hydro_ros.bags.cdr import decode_joint_trajectory, joint_trajectory_size
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import Crane, load_crane
from hydro_ros.nodes.authority import PinnedSource
from hydro_ros.nodes.common import HALT_QOS, LATCHED_QOS, MACHINE_ID, SENSOR_QOS, destroy_entities, machine_instance, namespaced_statuses, relative, run_node
from hydro_ros.nodes.parameters import declare, declared, parameter, specs_of
from hydro_ros.planning.controller import CylinderReference, MotionController
from hydro_ros.planning.trajectory import LIMIT_TOLERANCE, JointTrajectoryData
from hydro_ros.safety.motion import Heartbeat, MotionAuthority

LAST_WORDS_S = 0.5  # [s] the longest the executor waits, on its way out, for its neutral commands to be delivered
@dataclass
class TrajectoryExecutorParameters:
    """trajectory_executor's parameters, each declared once with its unit, range and description."""

    machine_id: str = declared(MACHINE_ID)
    config: str = parameter(str(default_config_path("k70m")), "machine config with a planner: section (YAML): joints, limits, valve table, controller",
                            existing_file=True)
    autostart: bool = parameter(True, "configure and activate at start; false: wait for a lifecycle manager")
    rate: float = parameter(0.0, "[Hz] control rate; 0: the config's controller.rate (100 Hz)", 0.0, 1000.0)
    joint_state_timeout: float = parameter(0.1, "[s] a joint state older than this stops the crane", 0.005, 5.0, read_only=False)
    start_tolerance: float = parameter(0.02, "[rad or m] a trajectory is refused unless it starts this close to the joints", 0.0, 1.0,
                                       read_only=False)
    require_monitor: bool = parameter(True, "execute only while the condition monitor vouches for the machine (its /fdi/halt false "
                                            "heartbeat); false is logged at every configure")
    monitor: str = parameter("fdi_node", "the condition monitor's node name (relative to this node's namespace, or absolute): only its "
                                         "/fdi/halt false clears a halt and counts as its heartbeat")
    trajectory_source: str = parameter("trajectory_server", "the only node whose trajectories on ~/joint_trajectory are taken")
    joint_state_source: str = parameter("can_bridge", "the only node whose /joint_states are taken (the machine's sensor bridge; "
                                                      "crane_sim or plant_sim in simulation)")
    max_points: int = parameter(10000, "a trajectory with more points is refused before it is decoded", 2, 1000000)
    command_slew_rate: float = parameter(5.0, "[1/s] largest change of a valve command per second while one trajectory takes over from "
                                              "another", 0.1, 1000.0)
    follow_joint_trajectory: bool = parameter(False, "also offer the FollowJointTrajectory action ~/follow_joint_trajectory (MoveIt, "
                                                     "ros2_control clients) where control_msgs is installed; its goals are taken from any "
                                                     "client SROS2 lets call it, so it is off unless asked for")


PARAMETERS = specs_of(TrajectoryExecutorParameters)


def follow_joint_trajectory_action() -> tuple[Any, str]:
    """control_msgs' FollowJointTrajectory action type, or None and why it is not there."""
    try:
        from control_msgs.action import FollowJointTrajectory
    except ImportError:
        return None, ("control_msgs is not installed (ros-kilted-control-msgs on a ROS machine): no FollowJointTrajectory "
                      "action; trajectories go to ~/joint_trajectory, the JointTrajectoryController topic")
    return FollowJointTrajectory, ""


class TrajectoryExecutor(LifecycleNode):
    def __init__(self) -> None:
        super().__init__("trajectory_executor")
        self.params = declare(self, TrajectoryExecutorParameters, self._on_parameter)
        self.joint_state_timeout = self.params.joint_state_timeout
        self.start_tolerance = self.params.start_tolerance
        self.require_monitor = self.params.require_monitor
        self.lock = threading.Lock()  # the trajectory checker's thread against the control loop
        self.incoming: queue.Queue[bytes | None] = queue.Queue(maxsize=4)
        self.checker: threading.Thread | None = None
        self.last_command: np.ndarray | None = None
        self.slewing = False
        self.crane: Crane | None = None
        self.active = False
        self._entities: list[Any] = []
        self.joints: np.ndarray | None = None
        self.joints_time: Time | None = None
        self.authority = MotionAuthority(self.require_monitor)  # the safety core's heartbeat rule (hydro_ros.safety.motion)
        self.reference: CylinderReference | None = None
        self.started: Time | None = None
        self.holding_until = math.inf
        self.state = "inactive"
        self.reason = ""
        self.status_pub = self.create_publisher(String, "~/status", LATCHED_QOS)
        self._say("inactive", "not configured")
        if self.params.autostart:
            self.trigger_configure()
            self.trigger_activate()

    def _on_parameter(self, name: str, value: Any) -> None:
        if name == "joint_state_timeout":
            self.joint_state_timeout = value
        elif name == "start_tolerance":
            self.start_tolerance = value

    # life cycle ----------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        try:
            self.crane, config = load_crane(self.params.config)
        except InputError as exc:
            self.get_logger().error(str(exc))
            return TransitionCallbackReturn.FAILURE
        self.controller = MotionController.for_crane(self.crane, config)
        self.settle_time = config.controller["settle_time"]
        rate = self.params.rate or config.controller["rate"]
        self.names = list(self.crane.names)
        self.slew_step = self.params.command_slew_rate / rate
        self.sources = {
            "halt": PinnedSource(self, relative(topics.FDI_HALT), self.params.monitor),
            "joint_states": PinnedSource(self, relative(topics.JOINT_STATES), self.params.joint_state_source),
            "trajectory": PinnedSource(self, "~/joint_trajectory", self.params.trajectory_source),
        }
        self.command_pub = self.create_lifecycle_publisher(JointState, relative(topics.VALVE_COMMANDS), SENSOR_QOS)
        self.diag_pub = self.create_lifecycle_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)
        self._entities = [
            self.command_pub,
            self.diag_pub,
            self.create_subscription(JointState, relative(topics.JOINT_STATES), self._on_joint_state, SENSOR_QOS),
            self.create_subscription(Bool, relative(topics.FDI_HALT), self._on_halt, HALT_QOS),
            self.create_subscription(JointTrajectory, "~/joint_trajectory", self._on_trajectory, 10, raw=True),
            self.create_timer(1.0 / rate, self._control),
            self.create_timer(1.0, self._diagnose),
        ]
        self.get_logger().info(f"crane {config.name}: cylinders {', '.join(self.names)}, control at {rate:g} Hz; "
                               + ", ".join(f"{kind} from {source.source}" for kind, source in self.sources.items()))
        self.checker = threading.Thread(target=self._check_trajectories, daemon=True, name="trajectory-checker")
        self.checker.start()
        if not self.require_monitor:
            self.get_logger().warning("require_monitor is false: trajectories run without a condition monitor vouching for "
                                      "the machine (only a halt request stops them)")
        if self.params.follow_joint_trajectory:
            self._offer_action()
        return TransitionCallbackReturn.SUCCESS

    def _offer_action(self) -> None:
        """FollowJointTrajectory where control_msgs is installed: a goal's trajectory goes through the same checks and the
        same control loop as one on ~/joint_trajectory; the goal ends when the executor is idle (succeeded) or has
        stopped or refused it (aborted). Without control_msgs the reason is said once and the topic path stays."""
        action, why_not = follow_joint_trajectory_action()
        if action is None:
            self.get_logger().warning(f"follow_joint_trajectory: {why_not}")
            return
        from rclpy.action import ActionServer
        from rclpy.serialization import serialize_message

        async def execute(goal_handle: Any) -> Any:
            result = action.Result()
            self._goal_done = Future()
            try:
                self.incoming.put_nowait(serialize_message(goal_handle.request.trajectory))
            except queue.Full:
                self._goal_done.set_result(("refused", "trajectories arrive faster than they are checked"))
            state, reason = await self._goal_done
            if state == "idle":
                goal_handle.succeed()
            else:
                goal_handle.abort()
                result.error_code, result.error_string = action.Result.INVALID_GOAL, f"{state}: {reason}"
            return result

        self._entities.append(ActionServer(self, action, "~/follow_joint_trajectory", execute))
        self.get_logger().warning("follow_joint_trajectory: offered; its goals are taken from any client the SROS2 policy "
                                  "lets call it (the topic takes only trajectory_source's)")

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        self._say("idle", "active: waiting for a trajectory")
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        with self.lock:
            self._stop("inactive", "deactivated")
            self.active = False
        self.authority.clear_halt()  # an operator's lifecycle action clears a halt no monitor is there to clear
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        if self.active:
            self._last_words("shut down")
        self._release()
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self) -> None:
        if self.active:
            self._last_words("node destroyed")
        self._release()
        super().destroy_node()

    def _last_words(self, reason: str) -> None:
        """Neutral commands before the process goes: sent, then waited for until every valve driver has them (reliable
        delivery, at most LAST_WORDS_S): a loaded machine's exit would otherwise drop the message still in flight."""
        self._stop("inactive", reason)
        self.active = False
        self.command_pub.wait_for_all_acked(Duration(seconds=LAST_WORDS_S))

    def _release(self) -> None:
        destroy_entities(self, self._entities)
        if self.checker is not None:
            self.incoming.put(None)
            self.checker.join(timeout=2.0)
            self.checker = None

    # inputs --------------------------------------------------------------------------------------
    def _on_joint_state(self, msg: JointState, info: dict[str, Any]) -> None:
        if not self.sources["joint_states"].accepts(info):
            self._foreign("joint_states")
            return
        by_name = dict(zip(msg.name, msg.position))
        if all(name in by_name for name in self.names):
            positions = np.array([by_name[name] for name in self.names], dtype=float)
            if np.isfinite(positions).all():
                self.joints = positions
                self.joints_time = self.get_clock().now()

    def _on_halt(self, msg: Bool, info: dict[str, Any]) -> None:
        from_monitor = self.sources["halt"].accepts(info)
        was_halted = self.authority.halted
        beat = Heartbeat(bool(msg.data), from_monitor, bytes(info["publisher_gid"]["data"]), info.get("publication_sequence_number") or 0,
                         int(info["source_timestamp"]))
        refused = self.authority.receive(beat, time.time_ns())
        if msg.data:
            if not was_halted:
                source = "the monitor" if from_monitor else self.sources["halt"].last_sender or "an unidentified publisher"
                self.get_logger().warning(f"halt requested on /fdi/halt by {source}: no motion until the monitor confirms")
            with self.lock:
                if self.reference is not None:
                    self._stop("stopped", "halt requested on /fdi/halt")
        elif not from_monitor:
            self._foreign("halt")  # only the monitor can say "no halt"
        elif refused:
            self.get_logger().warning(f"/fdi/halt: heartbeat not taken: {refused}", throttle_duration_sec=5.0)

    def _foreign(self, kind: str) -> None:
        source = self.sources[kind]
        sender = source.last_sender
        if sender is None:
            return  # a publisher the graph does not list yet (discovery): counted as unidentified
        self.get_logger().warning(f"{source.topic}: message from {sender} refused (only {source.source} is taken)",
                                  throttle_duration_sec=5.0)
        if source.foreign[sender] == 1:
            self._say(self.state, self.reason, force=True)

    def _on_trajectory(self, data: bytes, info: dict[str, Any]) -> None:
        source = self.sources["trajectory"]
        if not source.accepts(info):
            if source.last_sender is not None:
                self._foreign("trajectory")
            else:  # the sender should know: it may be the source, not yet listed on the graph (send again)
                self._refuse(f"trajectory: refused, its publisher is not yet identified on the graph (only {source.source} is taken)")
            return
        try:
            _, points = joint_trajectory_size(data)
        except InputError as exc:  # CdrError is one
            self._refuse(str(exc))
            return
        if points > self.params.max_points:
            self._refuse(f"trajectory: {points} points, max_points {self.params.max_points}")
        elif points == 0:
            with self.lock:
                if self.reference is not None:
                    self._stop("stopped", "empty trajectory: stop")
        else:
            try:
                self.incoming.put_nowait(data)
            except queue.Full:
                self._refuse("trajectory: refused, trajectories arrive faster than they are checked")

    def _check_trajectories(self) -> None:
        """The checker's thread: decode and check each trajectory, then hand it to the control loop."""
        while (data := self.incoming.get()) is not None:
            try:
                trajectory = self._checked(*decode_joint_trajectory(data))
            except InputError as exc:  # CdrError is one
                self._refuse(str(exc))
                continue
            assert self.crane is not None
            reference = CylinderReference(self.crane, trajectory)
            with self.lock:
                why_not = self._why_not_move() if self.active else "the executor is not active"  # changed while it was checked
                if why_not:
                    self._refuse(f"trajectory: refused, {why_not}")
                    continue
                self.slewing = self.reference is not None  # a running motion is ramped over, not cut
                self.reference = reference
                self.started = self.get_clock().now()
                self.holding_until = self.reference.duration + self.settle_time
                self._say("executing", "replaces the running trajectory" if self.slewing else "", points=len(trajectory.time),
                          duration_s=self.reference.duration)

    def _refuse(self, reason: str) -> None:
        self._say("refused", reason)
        self.get_logger().warning(reason)

    def _checked(self, joint_names: list[str], times: np.ndarray, points: np.ndarray, point_velocities: np.ndarray) -> JointTrajectoryData:
        assert self.crane is not None
        # the message's own defects first: they are the sender's to mend whatever the machine is doing
        twice = sorted({name for name in joint_names if joint_names.count(name) > 1})
        if twice:
            raise InputError(f"trajectory: joint(s) {', '.join(twice)} named twice")
        missing = [name for name in self.names if name not in joint_names]
        if missing:
            raise InputError(f"trajectory: joint(s) {', '.join(missing)} missing (has {', '.join(joint_names) or 'none'})")
        order = [joint_names.index(name) for name in self.names]
        positions, velocities = points[:, order], point_velocities[:, order]
        if not (np.isfinite(positions).all() and np.isfinite(velocities).all() and np.isfinite(times).all()):
            raise InputError("trajectory: non-finite position, velocity or time")
        if len(times) > 1 and np.any(np.diff(times) <= 0.0):
            raise InputError("trajectory: time_from_start not increasing")
        if not self.active:
            raise InputError("trajectory: refused, the executor is not active")
        why_not = self._why_not_move()
        if why_not:
            raise InputError(f"trajectory: refused, {why_not}")
        data = JointTrajectoryData(self.names, times, positions, velocities, np.zeros_like(positions), np.zeros(len(times)))
        for i, cylinder in enumerate(self.crane.cylinders):
            span = (cylinder.q_max - cylinder.q_min) * LIMIT_TOLERANCE
            low, high = positions[:, i].min(), positions[:, i].max()
            if low < cylinder.q_min - span or high > cylinder.q_max + span:
                raise InputError(f"trajectory: joint {cylinder.name} leaves [{cylinder.q_min:.3f}, {cylinder.q_max:.3f}] "
                                 f"(reaches {low:.3f} .. {high:.3f})")
        speeds = np.abs(CylinderReference(self.crane, data).velocities).max(axis=0)
        for cylinder, speed in zip(self.crane.cylinders, speeds):
            if speed > cylinder.velocity_max * (1.0 + LIMIT_TOLERANCE):
                raise InputError(f"trajectory: cylinder {cylinder.name} at {speed:.3f} m/s, limit {cylinder.velocity_max:.3f} m/s")
        gap = float(np.abs(positions[0] - self.joints).max())
        if gap > self.start_tolerance:
            raise InputError(f"trajectory: starts {gap:.3f} rad/m from the measured joints (start_tolerance {self.start_tolerance})")
        return data

    # control -------------------------------------------------------------------------------------
    def _why_not_move(self) -> str:
        now = self.get_clock().now()
        why_not = self.authority.why_not(time.time_ns())
        if why_not:
            return why_not
        if self.joints is None or self.joints_time is None:
            return f"no joint state on {topics.JOINT_STATES}"
        age = (now - self.joints_time).nanoseconds * 1e-9
        if age > self.joint_state_timeout:
            return f"joint state stale ({age:.2f} s old, joint_state_timeout {self.joint_state_timeout} s)"
        return ""

    def _control(self) -> None:
        with self.lock:
            self._control_step()

    def _control_step(self) -> None:
        if not self.active:
            return
        if self.reference is None:
            self._send(np.zeros(len(self.names)))
            return
        why_not = self._why_not_move()
        if why_not:
            self._stop("stopped", why_not)
            return
        assert self.started is not None and self.crane is not None and self.joints is not None
        t = (self.get_clock().now() - self.started).nanoseconds * 1e-9
        if t > self.holding_until:
            self.reference = None
            self._send(np.zeros(len(self.names)))
            self._say("idle", "trajectory done")
            return
        if t > self.reference.duration and self.state == "executing":
            self._say("holding", "at the last point for the settle time")
        stroke_ref, velocity_ref = self.reference.at(t)
        strokes = np.array([cylinder.stroke(q) for cylinder, q in zip(self.crane.cylinders, self.joints)])
        command = np.clip(self.controller.command(stroke_ref, velocity_ref, strokes), -1.0, 1.0)
        if self.slewing and self.last_command is not None:
            step = command - self.last_command
            self.slewing = bool(np.any(np.abs(step) > self.slew_step))
            command = self.last_command + np.clip(step, -self.slew_step, self.slew_step)
        self._send(command)

    def _stop(self, state: str, reason: str) -> None:
        """Drop the trajectory and command every valve neutral now."""
        self.reference = None
        self.slewing = False
        if self.active:
            self._send(np.zeros(len(self.names)))
        self._say(state, reason)
        if state == "stopped":
            self.get_logger().warning(f"stopped: {reason}")
        else:  # rclpy's logger refuses two severities from one call site
            self.get_logger().info(f"{state}: {reason}")

    def _send(self, commands: np.ndarray) -> None:
        self.last_command = np.asarray(commands, dtype=float)
        msg = JointState(name=self.names, position=[float(c) for c in commands])
        msg.header.stamp = self.get_clock().now().to_msg()
        self.command_pub.publish(msg)

    def _foreign_publishers(self) -> dict[str, list[str]]:
        return {kind: sorted(source.foreign) for kind, source in getattr(self, "sources", {}).items() if source.foreign}

    def _say(self, state: str, reason: str, *, force: bool = False, **extra: Any) -> None:
        if state == self.state and not extra and state != "refused" and not force:
            return
        self.state, self.reason = state, reason
        goal = getattr(self, "_goal_done", None)
        if goal is not None and not goal.done() and state in ("idle", "stopped", "refused", "inactive"):
            goal.set_result((state, reason))
        foreign = self._foreign_publishers()
        status = {"state": state, "reason": reason, **extra, **({"foreign_publishers": foreign} if foreign else {})}
        self.status_pub.publish(String(data=json.dumps(status)))

    def _diagnose(self) -> None:
        if not self.active:
            return
        foreign = self._foreign_publishers()
        present = {kind: source.others() for kind, source in self.sources.items()}
        present = {kind: names for kind, names in present.items() if names}
        level = 1 if foreign or present else 0
        message = "; ".join(f"{kind} refused from {', '.join(names)}" for kind, names in foreign.items()) or (
            "; ".join(f"other publishers on {kind}: {', '.join(names)}" for kind, names in present.items()) or "ok")
        values = {"state": self.state, "reason": self.reason, "halted": str(self.authority.halted).lower(),
                  **{f"heartbeats_refused: {why}": str(n) for why, n in self.authority.refused.items()},
                  "require_monitor": str(self.require_monitor).lower(),
                  **{f"{kind}_source": source.source for kind, source in self.sources.items()},
                  **{f"{kind}_refused": str(source.refused) for kind, source in self.sources.items()},
                  **{f"{kind}_unidentified": str(source.unidentified) for kind, source in self.sources.items()}}
        array = DiagnosticArray(status=namespaced_statuses(self, [
            DiagnosticStatus(level=bytes([level]), name="hydro_ros/trajectory_executor", message=message,
                             hardware_id=machine_instance(self, self.crane.name if self.crane else ""),
                             values=[KeyValue(key=k, value=v) for k, v in values.items()])]))
        array.header.stamp = self.get_clock().now().to_msg()
        self.diag_pub.publish(array)


def main(args: list[str] | None = None) -> None:
    run_node(TrajectoryExecutor, args)


if __name__ == "__main__":
    main()
