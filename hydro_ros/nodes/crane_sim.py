"""crane_sim: a planned machine (a config with a ``planner:`` section) as a simulated machine, the closed-loop crane of
``hydro_ros.workflows.execution`` (plant + P-VI Appendix A controller) in scaled real time.

The crane starts at rest with its tip at the start of ``initial_path`` (extension
``initial_extension``, or the smallest feasible one when negative). A JointTrajectory on
``trajectory_topic`` (what trajectory_server sends to its ``output_topic``) is executed when it
starts within ``start_tolerance`` of the current joints; otherwise it is refused, since a jump
would be a crash on a real machine. Publishes the contract topics (every joint in one
JointState, pressures per cylinder, supply pressure, valve commands) at ``publish_rate`` and, when
a trajectory is done (after the controller's settle time), its measures as JSON on the latched
``~/execution``: pump energy, ISO 9283 path accuracy, tracking errors. Topic names are relative,
so ``-r __ns:=/crane`` puts a crane beside another machine on one graph (the contract's names
without a namespace).

With ``external_commands`` the crane is a plant only, as a real one is to ``trajectory_executor``: it
applies the valve commands it receives on /hydraulics/valve_commands (neutral when none is younger
than ``command_timeout``) and publishes its sensors; it takes no trajectory and reports no execution.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from builtin_interfaces.msg import Time
from rclpy.node import Node
from sensor_msgs.msg import FluidPressure, JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import load_crane
from hydro_ros.nodes.common import LATCHED_QOS, SENSOR_QOS, VALVE_COMMAND_TIMEOUT, checked_valve_commands, relative, run_node
from hydro_ros.nodes.parameters import declare, declared, parameter, specs_of
from hydro_ros.planning.controller import CylinderReference
from hydro_ros.planning.serving import path_start_state
from hydro_ros.planning.trajectory import JointTrajectoryData
from hydro_ros.safety.motion import ValveDeadman
from hydro_ros.workflows.execution import ClosedLoop, execution_from_rows, log_row, measures

MAX_CATCH_UP_S = 0.25


@dataclass
class CraneSimParameters:
    """crane_sim's parameters, each declared once with its unit, range and description."""

    config: str = parameter(str(default_config_path("k70m")), "machine config with a planner: section (YAML)", existing_file=True)
    real_time_factor: float = parameter(1.0, "[-] simulated seconds per wall second", 0.01, 100.0)
    tick_period: float = parameter(0.01, "[s] wall time between simulation steps", 0.001, 1.0)
    seed: int = parameter(0, "seed of the sensor noise", 0)
    supply: str = parameter("cp", "pump: constant pressure or load sensing", choices=("cp", "ls"))
    initial_path: str = parameter("", "path id whose start the crane begins at; empty: the config's first path")
    initial_extension: float = parameter(-1.0, "[m] telescope extension at the start; negative: the smallest feasible one", None, 10.0)
    trajectory_topic: str = parameter("joint_trajectory", "JointTrajectory input (trajectory_server's output_topic)")
    start_tolerance: float = parameter(0.02, "[rad or m] a trajectory is refused unless it starts this close to the joints", 0.0, 1.0,
                                       read_only=False)
    publish_rate: float = parameter(50.0, "[Hz] rate of the sensor topics", 1.0, 1000.0)
    external_commands: bool = parameter(False, "take the valve commands from /hydraulics/valve_commands (an outside controller, e.g. "
                                               "trajectory_executor) instead of following trajectories itself")
    command_timeout: float = declared(VALVE_COMMAND_TIMEOUT)


PARAMETERS = specs_of(CraneSimParameters)


class CraneSim(Node):
    """The simulated crane: the closed loop, its sensor publishers and its trajectory input."""

    def __init__(self) -> None:
        super().__init__("crane_sim")
        self.params = declare(self, CraneSimParameters, self._on_parameter)
        real_time_factor = self.params.real_time_factor
        seed = self.params.seed
        self.crane, config = load_crane(self.params.config)
        self.config = config
        supply = self.params.supply
        initial_path = self.params.initial_path or next(iter(config.paths))
        trajectory_topic = self.params.trajectory_topic
        self.start_tolerance = self.params.start_tolerance
        publish_rate = self.params.publish_rate
        if initial_path not in config.paths:
            raise InputError(f"parameter initial_path={initial_path!r}: not a path of {config.name} ({', '.join(config.paths)})")
        self.seed = seed
        start = path_start_state(config, initial_path, self.params.initial_extension)
        self.loop = ClosedLoop(config, supply, start, seed=seed)
        self.rtf = real_time_factor
        self.names = list(self.crane.names)
        # relative names: /joint_states etc. by default, /<ns>/joint_states for a machine in a namespace
        self.pub_joints = self.create_publisher(JointState, relative(topics.JOINT_STATES), SENSOR_QOS)
        self.external = self.params.external_commands
        self.deadman = ValveDeadman(self.names, self.params.command_timeout)
        if self.external:  # the valve commands are the outside controller's topic, not this node's
            self.pub_commands = None
            self.create_subscription(JointState, relative(topics.VALVE_COMMANDS), self._on_valve_commands, SENSOR_QOS)
        else:
            self.pub_commands = self.create_publisher(JointState, relative(topics.VALVE_COMMANDS), SENSOR_QOS)
        self.pub_supply = self.create_publisher(FluidPressure, relative(topics.SUPPLY_PRESSURE), SENSOR_QOS)
        self.pub_pressures = [
            (self.create_publisher(FluidPressure, relative(topics.pressure_a(name)), SENSOR_QOS),
             self.create_publisher(FluidPressure, relative(topics.pressure_b(name)), SENSOR_QOS))
            for name in self.names
        ]
        self.pub_execution = self.create_publisher(String, "~/execution", LATCHED_QOS)
        if not self.external:
            self.create_subscription(JointTrajectory, trajectory_topic, self._on_trajectory, 10)
        self.publish_every = max(int(round(1.0 / (publish_rate * self.loop.plant.dt))), 1)
        self.trajectory: JointTrajectoryData | None = None
        self.rows: list[tuple] = []
        self.end_time = math.inf
        self.start_wall = time.monotonic()
        self.stamp_origin_ns = self.get_clock().now().nanoseconds
        self.create_timer(self.params.tick_period, self._tick)
        self.get_logger().info(
            f"crane {config.name} ({supply.upper()} pump) at the start of {initial_path!r}, "
            f"extension {float(self.crane.extension.stroke(start[self.crane.redundant])):.3f} m; "
            + (f"valve commands on {topics.VALVE_COMMANDS}" if self.external else f"trajectories on {trajectory_topic}")
        )

    def _on_parameter(self, name: str, value: Any) -> None:
        if name == "start_tolerance":
            self.start_tolerance = value

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        if not msg.points:  # ros2_control's habit: an empty trajectory stops the one being executed
            self._hold()
            return
        try:
            trajectory = self._trajectory_data(msg)
        except InputError as exc:
            self._report({"ok": False, "error": str(exc)})
            return
        self.loop.follow(trajectory)
        self.trajectory = trajectory
        self.rows = [log_row(self.loop)]
        self.end_time = self.loop.time + float(trajectory.time[-1]) + self.loop.settings["settle_time"]
        self.get_logger().info(f"executing a {trajectory.time[-1]:.1f} s trajectory of {len(trajectory.time)} points")

    def _on_valve_commands(self, msg: JointState) -> None:
        """An outside controller's commands, by cylinder name; a missing or refused one is neutral."""
        accepted, refused = checked_valve_commands(list(msg.name), list(msg.position), self.names)
        if refused:
            self.get_logger().error(f"{topics.VALVE_COMMANDS} refused: {refused}: neutral", throttle_duration_sec=2.0)
        # a message sets every cylinder: one it does not name (or refuses) is neutral
        self.deadman.command({name: accepted.get(name, 0.0) for name in self.names}, time.monotonic())

    def _hold(self) -> None:
        """Stop where the crane is: track its current joints, at rest."""
        self.loop.reference = CylinderReference.hold(self.crane, np.array(self.loop.plant.joint_motion().q))
        if self.trajectory is not None:
            self.trajectory = None
            self._report({"ok": False, "cancelled": True, "error": "trajectory cancelled: holding the joints where they are"})
        self.get_logger().info("empty trajectory: holding the current joints")

    def _trajectory_data(self, msg: JointTrajectory) -> JointTrajectoryData:
        missing = [name for name in self.names if name not in msg.joint_names]
        if missing or not msg.points:
            raise InputError(f"trajectory: joint(s) {', '.join(missing) or '-'} missing or no points")
        order = [list(msg.joint_names).index(name) for name in self.names]
        time_s = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
        positions = np.array([[p.positions[i] for i in order] for p in msg.points], dtype=float)
        velocities = np.array([[p.velocities[i] if p.velocities else 0.0 for i in order] for p in msg.points], dtype=float)
        if not (np.isfinite(positions).all() and np.isfinite(velocities).all()) or np.any(np.diff(time_s) <= 0):
            raise InputError("trajectory: non-finite values or times not increasing")
        current = np.array(self.loop.plant.joint_motion().q)
        gap = float(np.abs(positions[0] - current).max())
        if gap > self.start_tolerance:
            raise InputError(f"trajectory: starts {gap:.3f} rad/m from the current joints (tolerance {self.start_tolerance}); refused")
        return JointTrajectoryData(self.names, time_s, positions, velocities, np.zeros_like(positions), np.zeros(len(time_s)))

    def _report(self, result: dict[str, Any]) -> None:
        if not result.get("ok", True):
            self.get_logger().warning(result["error"])
        self.pub_execution.publish(String(data=json.dumps(result)))

    def _tick(self) -> None:
        loop = self.loop
        target = (time.monotonic() - self.start_wall) * self.rtf
        steps = min(int((target - loop.time) / loop.plant.dt), int(MAX_CATCH_UP_S / loop.plant.dt))
        command = None
        if self.external:
            outputs = self.deadman.outputs(time.monotonic())
            command = np.array([outputs[name] for name in self.names])
        for _ in range(max(steps, 0)):
            loop.advance(command)
            if loop.steps % self.publish_every == 0:
                self._publish()
                if self.trajectory is not None:
                    self.rows.append(log_row(loop))
        if self.trajectory is not None and loop.time >= self.end_time:
            execution = execution_from_rows(loop.plant.supply, self.names, self.rows, self.crane)
            self._report({"ok": True, **measures(self.crane, self.trajectory, execution, seed=self.seed)})
            self.trajectory = None

    def _publish(self) -> None:
        loop = self.loop
        motion = loop.plant.joint_motion()
        s = loop.plant.state
        stamp_ns = self.stamp_origin_ns + int(round(loop.time * 1e9))
        seconds, nanoseconds = divmod(stamp_ns, 1_000_000_000)
        stamp = Time(sec=seconds, nanosec=nanoseconds)
        joints = JointState(name=self.names, position=[float(q) for q in motion.q], velocity=[float(v) for v in motion.qd])
        joints.header.stamp = stamp
        self.pub_joints.publish(joints)
        if self.pub_commands is not None:
            commands = JointState(name=self.names, position=loop.command.tolist())
            commands.header.stamp = stamp
            self.pub_commands.publish(commands)
        self.pub_supply.publish(_pressure(stamp, "supply", s.supply_pressure))
        for (pub_a, pub_b), name, p_a, p_b in zip(self.pub_pressures, self.names, s.pressure_a, s.pressure_b):
            pub_a.publish(_pressure(stamp, name, p_a))
            pub_b.publish(_pressure(stamp, name, p_b))


def _pressure(stamp: Any, frame: str, value: float) -> FluidPressure:
    msg = FluidPressure(fluid_pressure=float(value))
    msg.header.stamp = stamp
    msg.header.frame_id = frame
    return msg


def main(args: list[str] | None = None) -> None:
    run_node(CraneSim, args)


if __name__ == "__main__":
    main()
