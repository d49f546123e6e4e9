"""plant_sim: the machine of a config in (scaled) real time on the contract topics.

Publishes the measured topics of docs/interface.md section 1 (raw CDR, the same bytes a bag holds),
optionally /clock. Valve commands come from the simulated operator (`excitation: operator`,
then they are published on /hydraulics/valve_commands as the machine would) or from that topic
(`excitation: topic`). Every actuator of a config in the SAM's layout is simulated, each a boom of its
own (``sim.scenario.MachineRun``). Faults and effects are injected at run time by setting the parameters
`fault.<name>`, or `fault.<actuator>.<name>` on a machine of several actuators (units: `hydro-ros sim
--help`). Health on /diagnostics as `hydro_ros/plant_sim`.

Crane mode (a config with a ``planner:`` section and an actuator per planar joint, e.g. config/k70m.yaml):
the crane's cylinders with their valves (``hydro_ros.sim.arm_cylinders``), every joint in one
/joint_states (the base held where it started), the pressures of every cylinder. Faults name
their cylinder: ``fault.<actuator>.<name>``. With ``excitation: trajectory`` the crane starts at
the start of ``initial_path`` and works each JointTrajectory it receives on ``trajectory_topic``
(trajectory_server's ``output_topic``) as a cycle, forwards, a hold, back, a hold; a trajectory
that does not start within ``start_tolerance`` of the joints is refused (logged, and on
/diagnostics), an empty one holds the joints where they are. ``crane_sim`` is the other crane
simulator: the closed loop of P-VI's controller for energy and tracking, without valves to monitor.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import SetParametersResult
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import FluidPressure, JointState, PointCloud2
from trajectory_msgs.msg import JointTrajectory

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.cdr import encode_sample_block
from hydro_ros.bags.writer import block_machine_payloads
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine, load_machine_config
from hydro_ros.contract.names import INJECTION_UNITS, Injection
from hydro_ros.contract.samples import Samples
from hydro_ros.nodes.common import (
    CLOCK_QOS,
    MACHINE_ID,
    SAMPLE_BLOCKS,
    SENSOR_QOS,
    SENSOR_TOPICS,
    VALVE_COMMAND_TIMEOUT,
    checked_valve_commands,
    machine_instance,
    namespaced_statuses,
    publishes_sensor_topic,
    relative,
    run_node,
)
from hydro_ros.nodes.parameters import Parameters, Spec, declare, declared, parameter, specs_of
from hydro_ros.safety.motion import ValveDeadman
from hydro_ros.sim.scenario import MachineRun

MAX_CATCH_UP_S = 0.25  # simulate at most this much per tick; beyond it the node reports lag
TIP_PAYLOAD = "fault.payload_mass"  # on an arm (or crane) the payload hangs at the tip, not on a cylinder: one parameter


@dataclass
class PlantSimParameters:
    """plant_sim's parameters, each declared once with its unit, range and description."""

    machine_id: str = declared(MACHINE_ID)
    config: str = parameter(str(default_config_path("sam")), "machine config (YAML) of the simulated machine: a SAM-style one, or a crane "
                                                             "with an actuator per planar joint (crane mode)", existing_file=True)
    seed: int = parameter(0, "seed of the operator's moves and the sensor noise", 0)
    excitation: str = parameter("operator", "where valve commands come from: the simulated operator, /hydraulics/valve_commands, or "
                                            "(crane mode) the trajectories on trajectory_topic", choices=("operator", "topic", "trajectory"))
    real_time_factor: float = parameter(1.0, "[-] simulated seconds per wall second", 0.01, 100.0)
    publish_clock: bool = parameter(False, "publish /clock from the simulation time (stamps then start at 0)")
    command_timeout: float = declared(VALVE_COMMAND_TIMEOUT)
    tick_period: float = parameter(0.01, "[s] wall time between simulation steps (each publishes the samples due)", 0.001, 1.0)
    can_interface: str = parameter("", "python-can interface that also carries the sensors as CAN frames (socketcan, udp_multicast); "
                                       "empty: none")
    can_channel: str = parameter("", "channel of can_interface (can0, a multicast address)")
    sensor_topics: str = declared(SENSOR_TOPICS)
    sample_blocks: bool = declared(SAMPLE_BLOCKS)
    initial_path: str = parameter("", "crane mode, excitation trajectory: the path id whose start the crane begins at; empty: the config's first")
    initial_extension: float = parameter(-1.0, "[m] crane mode, excitation trajectory: extension cylinder stroke at the start; negative: the "
                                               "smallest feasible one", None, 10.0)
    trajectory_topic: str = parameter("joint_trajectory", "crane mode: JointTrajectory input (trajectory_server's output_topic)")
    start_tolerance: float = parameter(0.05, "[rad or m] crane mode: a trajectory is refused unless it starts this close to the joints", 0.0, 1.0,
                                       read_only=False)


# faults and effects by name: dotted, so a table of their own beside the dataclass
FAULT_PARAMETERS = {
    f"fault.{name}": Spec(0.0, f"[{unit}] size of the fault or effect {name} from the moment it is set; 0: none (several "
                               f"actuators: fault.<actuator>.{name}" + ("; an arm's or a crane's payload at its tip" if name == "payload_mass"
                                                                        else "") + ")", read_only=False)
    for name, unit in sorted(INJECTION_UNITS.items())
}
PARAMETERS = {**specs_of(PlantSimParameters), **FAULT_PARAMETERS}


class SamSource:
    """The actuators of a config in the SAM's layout (``sim.scenario.MachineRun``: each a boom of its own, or the links of
    its ``arm:`` together): the operators' or the topic's commands through their plants; faults per actuator."""

    def __init__(self, machine: Machine, seed: int) -> None:
        from hydro_ros.sim.arm_cylinders import NOT_PER_CYLINDER

        self.plant = MachineRun(machine, {}, seed=seed)
        self.not_per_cylinder = NOT_PER_CYLINDER if machine.arm is not None else {}
        self.tip_payload = machine.arm is not None
        self.actuators = machine.actuator_names
        self.joints = {a.name: a.joint for a in machine.actuators}
        self.mobile = machine.mobile
        self.topics = tuple(topics.sensor_topics(self.actuators, mobile=self.mobile))

    @property
    def time(self) -> float:
        return self.plant.time

    @property
    def sample_index(self) -> int:
        return self.plant.sample_index

    def step(self, n: int, commands: np.ndarray | None) -> Samples:
        return self.plant.step(n, commands)

    def payloads(self, block: Samples, k: int, stamp: int, variance: float) -> list[tuple[str, bytes]]:
        return block_machine_payloads(block, k, stamp, self.joints, variance, self.mobile)

    def set_fault(self, actuator: str, name: str, value: float, now: float) -> None:
        self.plant.set_fault(actuator, name, value, now)

    def payload_problem(self, value: float) -> str:
        """Why a tip payload_mass of ``value`` cannot be set (an arm's; ``tip_payload`` says whether there is one)."""
        return self.plant.arm.payload_problem(value) if self.plant.arm is not None else ""

    def active_faults(self) -> list[str]:
        faults = self.plant.active_faults()
        return faults if len(self.actuators) > 1 else [fault.split(":", 1)[-1] for fault in faults]

    def fault_parameter(self, name: str) -> tuple[str, str]:
        if len(self.actuators) == 1 or name == TIP_PAYLOAD:
            return self.actuators[0], name.removeprefix("fault.")
        actuator, _, fault = name.removeprefix("fault.").partition(".")
        return actuator, fault


class CraneSource:
    """The cylinders of a crane config (``hydro_ros.sim.arm_cylinders``); faults per cylinder."""

    def __init__(self, machine: Machine, crane: Any, config: CraneConfig, seed: int, start_joints: dict[str, float] | None) -> None:
        from hydro_ros.models.serial_arm import SerialArm
        from hydro_ros.sim.arm_cylinders import NOT_PER_CYLINDER, ArmCylinders, ArmRun

        self.actuators = machine.actuator_names
        self.joints = {a.name: a.joint for a in machine.actuators}
        planar = [self.joints[a] for a in self.actuators]
        start_joints = start_joints or {}
        self.held = {name: float(start_joints.get(name, 0.0)) for name in crane.names if name not in planar}
        self.plant = ArmCylinders(machine, SerialArm.of(machine), ArmRun(math.inf, seed),
                                  None if not start_joints else [start_joints[name] for name in planar])
        self.mobile = machine.mobile
        self.topics = tuple(topics.sensor_topics(self.actuators, mobile=self.mobile))
        self.not_per_cylinder = NOT_PER_CYLINDER
        self.tip_payload = True

    @property
    def time(self) -> float:
        return self.plant.sample_index * self.plant.dt

    @property
    def sample_index(self) -> int:
        return self.plant.sample_index

    def step(self, n: int, commands: np.ndarray | None) -> Samples:
        return self.plant.step(n, commands)[1]

    def payloads(self, block: Samples, k: int, stamp: int, variance: float) -> list[tuple[str, bytes]]:
        return block_machine_payloads(block, k, stamp, self.joints, variance, self.mobile, self.held)

    def set_fault(self, actuator: str, name: str, value: float, now: float) -> None:
        self.plant.set_fault(actuator, name, value, now)

    def payload_problem(self, value: float) -> str:
        return self.plant.payload_problem(value)

    def active_faults(self) -> list[str]:
        return self.plant.active_faults()

    def fault_parameter(self, name: str) -> tuple[str, str]:
        if name == TIP_PAYLOAD:
            return self.actuators[0], name.removeprefix("fault.")
        actuator, _, fault = name.removeprefix("fault.").partition(".")
        return actuator, fault


class PlantSim(Node):
    def __init__(self) -> None:
        super().__init__("plant_sim")
        self.params = declare(self, PlantSimParameters, self._on_parameter)
        self.fault_params = Parameters(self, FAULT_PARAMETERS, self._on_parameter)
        self.can_bus = None
        self.rtf = self.params.real_time_factor
        self.machine = load_machine_config(self.params.config)
        self.excitation = self.params.excitation
        self.publish_clock = self.params.publish_clock
        self._pending: dict[str, float] = {}
        self.refused = ""
        if self.machine.planned:
            self.source = self._crane_source()
        else:
            if self.excitation == "trajectory":
                raise InputError(f"parameter excitation=trajectory: config {self.params.config} has no planner: section (nothing plans its trajectories)")
            self.source = SamSource(self.machine, self.params.seed)
        self.add_on_set_parameters_callback(self._refuse_fault)
        if len(self.source.actuators) > 1:
            # faults name their cylinder: fault.<actuator>.<name>, declared once the config says which cylinders there are
            self.cylinder_params = Parameters(self, {
                f"fault.{actuator}.{name}": Spec(0.0, f"[{unit}] size of {name} in {actuator}'s cylinder from the moment it is set; "
                                                      "0: none", read_only=False)
                for actuator in self.source.actuators for name, unit in sorted(INJECTION_UNITS.items())
                if name not in self.source.not_per_cylinder
            }, self._on_parameter)
        # faults given at start act from the start
        for params in (self.fault_params, getattr(self, "cylinder_params", None)):
            for name, value in (params.values.items() if params else ()):
                if name.startswith("fault.") and value:
                    refusal = self._fault_refusal(name, value)
                    if refusal:
                        raise InputError(f"parameter {refusal}")
                    self._pending[name] = value
        self.variance = self.machine.sensors.pressure_noise_std ** 2

        # one publisher per sample topic; valve commands are only published when the plant's own loop makes them
        types = topics.sensor_topics(self.source.actuators, mobile=self.source.mobile)
        self.publishers_by_topic = {
            name: self.create_publisher(JointState if types[name] == topics.JOINT_STATE_TYPE else FluidPressure, relative(name), SENSOR_QOS,
                                        qos_overriding_options=QoSOverridingOptions.with_default_policies())
            for name in self.source.topics if self._publishes(name)
        }
        self.layout = SampleLayout(self.source.actuators, [a.joint for a in self.machine.actuators if a.name in self.source.actuators],
                                   mobile=self.source.mobile)
        self.pub_block = (self.create_publisher(PointCloud2, relative(topics.SAMPLE_BLOCK), SENSOR_QOS,
                                                qos_overriding_options=QoSOverridingOptions.with_default_policies())
                          if self.params.sample_blocks else None)
        self.deadman = ValveDeadman(self.source.actuators, self.params.command_timeout)
        if self.excitation == "topic":
            self.create_subscription(JointState, relative(topics.VALVE_COMMANDS), self._on_command, SENSOR_QOS,
                                     qos_overriding_options=QoSOverridingOptions.with_default_policies())
        self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, CLOCK_QOS) if self.publish_clock else None
        interface = self.params.can_interface
        if interface:
            import can

            from hydro_ros.can.codec import MachineBus

            self.can_codec = MachineBus(self.machine)
            self.can_bus = can.Bus(interface=interface, channel=self.params.can_channel)
            self.can_counter = 0
        self.pub_diag = self.create_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)

        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.start_wall = time.monotonic()
        self.stamp_origin_ns = 0 if self.publish_clock else self.get_clock().now().nanoseconds
        self.lag_s = 0.0
        self.command_stale = False
        self.create_timer(self.params.tick_period, self._tick, clock=self.steady)
        self.create_timer(1.0, self._diagnose, clock=self.steady)
        self.get_logger().info(
            f"simulating {self.machine.name} ({', '.join(self.source.actuators)}) at {self.machine.sample_rate_hz:.0f} Hz, "
            f"x{self.rtf:g} real time, excitation={self.excitation}"
        )

    def _crane_source(self) -> CraneSource:
        from hydro_ros.models.crane import load_crane

        crane, config = load_crane(self.machine.source)
        start_joints = None
        if self.excitation == "trajectory":
            from hydro_ros.planning.serving import path_start_state

            path = self.params.initial_path or next(iter(config.paths))
            if path not in config.paths:
                raise InputError(f"parameter initial_path={path!r}: not a path of {config.name} ({', '.join(config.paths)})")
            start_joints = dict(zip(crane.names, path_start_state(config, path, self.params.initial_extension).tolist()))
        source = CraneSource(self.machine, crane, config, self.params.seed, start_joints)
        if self.excitation == "trajectory":
            source.plant.hold()
            self.create_subscription(JointTrajectory, self.params.trajectory_topic, self._on_trajectory, 10)
        return source

    def _publishes(self, topic: str) -> bool:
        """Whether a sensor topic is this node's to publish (valve commands are not when they come from outside)."""
        if topic == topics.VALVE_COMMANDS and self.excitation == "topic":
            return False
        return publishes_sensor_topic(self.params.sensor_topics, topic)

    def _fault_refusal(self, name: str, value: float) -> str:
        """Why a fault.<name> parameter cannot be set on this plant ("" if it can): on several actuators a fault names its
        cylinder (an arm's payload hangs at its tip, fault.payload_mass); an arm does not simulate every fault."""
        fault = name.rsplit(".", 1)[-1]
        try:
            Injection(fault, value)
        except InputError as exc:
            return f"{name} refused: {exc}"
        from hydro_ros.models.sam import DELAY_BUFFER

        if fault == "valve_delay" and value * self.machine.sample_rate_hz >= DELAY_BUFFER:
            return f"{name} refused: {value:g} s is beyond the {DELAY_BUFFER / self.machine.sample_rate_hz:.2f} s of commands the plant keeps"
        if name == TIP_PAYLOAD and self.source.tip_payload:
            problem = self.source.payload_problem(value)
            return f"{name} refused: {problem}" if problem else ""
        if fault in self.source.not_per_cylinder:
            return f"{name} refused: {self.source.not_per_cylinder[fault]}"
        if len(self.source.actuators) > 1 and name.count(".") == 1:
            return (f"{name} refused: on a machine of several actuators a fault names its cylinder, fault.<actuator>.{fault} "
                    f"(actuators: {', '.join(self.machine.actuator_names)})")
        return ""

    def _refuse_fault(self, parameters: list) -> SetParametersResult:
        for change in parameters:
            if change.name.startswith("fault.") and change.value:
                refusal = self._fault_refusal(change.name, change.value)
                if refusal:
                    return SetParametersResult(successful=False, reason=refusal)
        return SetParametersResult(successful=True)

    def _on_parameter(self, name: str, value: float) -> None:
        if name.startswith("fault."):
            self._pending[name] = value

    def _on_command(self, msg: JointState) -> None:
        accepted, refused = checked_valve_commands(list(msg.name), list(msg.position), self.source.actuators)
        if refused:
            self.get_logger().error(f"{topics.VALVE_COMMANDS} refused: {refused}: neutral", throttle_duration_sec=2.0)
        self.deadman.command({**dict.fromkeys(refused, 0.0), **accepted}, time.monotonic())

    def _on_trajectory(self, msg: JointTrajectory) -> None:
        plant = self.source.plant
        if not msg.points:
            plant.hold()
            self.get_logger().info("empty trajectory: holding the joints where they are")
            return
        try:
            path = self._planar_path(msg)
        except InputError as exc:
            self.refused = f"trajectory refused: {exc}"
            self.get_logger().error(self.refused)
            return
        self.refused = ""
        plant.follow(path)
        self.get_logger().info(f"working a {path.time[-1]:.1f} s trajectory of {len(path.time)} points as a cycle")

    def _planar_path(self, msg: JointTrajectory) -> _Path:
        """The received trajectory's columns of the crane's planar joints; InputError with the reason it cannot be worked."""
        plant = self.source.plant
        names = plant.arm.joint_names
        missing = [name for name in names if name not in msg.joint_names]
        if missing:
            raise InputError(f"joint(s) {', '.join(missing)} missing")
        order = [list(msg.joint_names).index(name) for name in names]
        if any(len(p.positions) != len(msg.joint_names) for p in msg.points):
            raise InputError("a point's positions do not match its joint names")
        positions = np.array([[p.positions[i] for i in order] for p in msg.points], dtype=float)
        times = np.array([p.time_from_start.sec + p.time_from_start.nanosec * 1e-9 for p in msg.points])
        if not np.all(np.isfinite(positions)) or np.any(np.diff(times) <= 0):
            raise InputError("non-finite positions or times not increasing")
        gap = float(np.max(np.abs(positions[0] - plant.joints())))
        if gap > self.params.start_tolerance:
            raise InputError(f"starts {gap:.3f} from the joints (start_tolerance {self.params.start_tolerance:g})")
        return _Path(names, times, positions)

    def _apply_pending(self) -> None:
        now = self.source.time
        for name, value in self._pending.items():
            actuator, fault = self.source.fault_parameter(name)
            try:
                self.source.set_fault(actuator, fault, value, now)
            except InputError as exc:  # what only the plant can judge (a payload its arm cannot hold): not applied, said
                self.get_logger().error(f"parameter {name} = {value:g} not applied: {exc}")
                continue
            self.get_logger().info(f"fault {actuator}:{fault} = {value:g} from t = {now:.3f} s")
        self._pending.clear()

    def _tick(self) -> None:
        if self._pending:
            self._apply_pending()
        rate = self.machine.sample_rate_hz
        due = int((time.monotonic() - self.start_wall) * self.rtf * rate) - self.source.sample_index
        if due <= 0:
            return
        limit = int(MAX_CATCH_UP_S * rate)
        self.lag_s = max(0.0, (due - limit) / rate)
        n = min(due, limit)
        commands = None
        if self.excitation == "topic":
            now = time.monotonic()
            outputs = self.deadman.outputs(now)
            self.command_stale = not self.deadman.fresh(now)
            commands = np.repeat(np.array([outputs[a] for a in self.source.actuators])[None], n, axis=0)
        self._publish(self.source.step(n, commands))

    def _publish(self, block: Samples) -> None:
        origin = self.stamp_origin_ns
        publishers = self.publishers_by_topic
        if publishers:
            for k in range(len(block.times)):
                stamp = origin + int(round(block.times[k] * 1e9))
                for topic, payload in self.source.payloads(block, k, stamp, self.variance):
                    publisher = publishers.get(topic)
                    if publisher is not None:
                        publisher.publish(payload)
        if self.pub_block is not None:
            stamps = origin + np.round(np.asarray(block.times) * 1e9).astype(np.int64)
            self.pub_block.publish(encode_sample_block(int(stamps[0]), self.machine.name, self.layout.field_names, stamps,
                                                       self.layout.rows(block)))
        if self.can_bus is not None:
            self._send_frames(block)
        if self.pub_clock is not None:
            msg = ClockMsg()
            stamp = origin + int(round(block.times[-1] * 1e9))
            msg.clock.sec, msg.clock.nanosec = divmod(stamp, 1_000_000_000)
            self.pub_clock.publish(msg)

    def _send_frames(self, block: Samples) -> None:
        import can

        from hydro_ros.can.codec import sample_values

        for k in range(len(block.times)):
            for frame_id, data in self.can_codec.encode_cycle(sample_values(block, k, self.source.joints), self.can_counter):
                self.can_bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=self.can_codec.is_extended(frame_id)))
            self.can_counter = (self.can_counter + 1) % 16

    def destroy_node(self) -> None:
        if self.can_bus is not None:
            self.can_bus.shutdown()
        super().destroy_node()

    def _diagnose(self) -> None:
        status = DiagnosticStatus(name="hydro_ros/plant_sim", hardware_id=machine_instance(self, self.machine.name))
        sim_time = self.source.time
        wall = time.monotonic() - self.start_wall
        achieved = sim_time / wall if wall > 0 else 0.0
        problems = []
        if self.lag_s > 0.0:
            problems.append(f"behind real time by {self.lag_s:.2f} s")
        if self.excitation == "topic" and self.command_stale:
            problems.append("valve command stale, valve held closed")
        if self.refused:
            problems.append(self.refused)
        status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        status.message = "; ".join(problems) or "ok"
        status.values = [
            KeyValue(key="sim_time_s", value=f"{sim_time:.3f}"),
            KeyValue(key="real_time_factor", value=f"{achieved:.2f}"),
            KeyValue(key="active_faults", value=",".join(self.source.active_faults()) or "none"),
        ]
        array = DiagnosticArray(status=namespaced_statuses(self, [status]))
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(array)


@dataclass
class _Path:
    """A received trajectory's planar columns, as the crane plant takes them."""

    joint_names: list[str]
    time: np.ndarray
    positions: np.ndarray


def main(args: list[str] | None = None) -> None:
    run_node(PlantSim, args)


if __name__ == "__main__":
    main()
