"""plant_sim: the machine of a config in (scaled) real time on the contract topics.

A crane config (``kind: crane``) is refused: ``crane_sim`` simulates cranes.

Publishes the measured topics of contract section 1 (raw CDR, the same bytes a bag holds),
optionally /clock. Valve commands come from the simulated operator (`excitation: operator`,
then they are published on /hydraulics/valve_commands as the machine would) or from that topic
(`excitation: topic`). Faults and effects are injected at run time by setting the parameters
`fault.<name>` (units: `hydro-ros sim --help`). Health on /diagnostics as `hydro_ros/plant_sim`.
"""

from __future__ import annotations

import math
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from rosgraph_msgs.msg import Clock as ClockMsg
from sensor_msgs.msg import FluidPressure, JointState

from hydro_ros.bags.writer import sample_payloads, sample_topics
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path, read_config
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import INJECTION_UNITS, Injection
from hydro_ros.nodes.common import CLOCK_QOS, SENSOR_QOS, relative, run_node
from hydro_ros.nodes.parameters import Parameters, Spec
from hydro_ros.sim.scenario import Scenario, start

COMMAND_TIMEOUT_S = 0.5  # a valve command older than this closes the valve (fail safe)
MAX_CATCH_UP_S = 0.25  # simulate at most this much per tick; beyond it the node reports lag


PARAMETERS = {
    "config": Spec(str(default_config_path("sam")), "machine config (YAML) of the simulated machine (not a crane)", existing_file=True),
    "seed": Spec(0, "seed of the operator's moves and the sensor noise", 0),
    "excitation": Spec("operator", "where valve commands come from: the simulated operator, or /hydraulics/valve_commands",
                       choices=("operator", "topic")),
    "real_time_factor": Spec(1.0, "[-] simulated seconds per wall second", 0.01, 100.0),
    "publish_clock": Spec(False, "publish /clock from the simulation time (stamps then start at 0)"),
    "tick_period": Spec(0.01, "[s] wall time between simulation steps (each publishes the samples due)", 0.001, 1.0),
    "can_interface": Spec("", "python-can interface that also carries the sensors as CAN frames (socketcan, udp_multicast); "
                              "empty: none"),
    "can_channel": Spec("", "channel of can_interface (can0, a multicast address)"),
    **{f"fault.{name}": Spec(0.0, f"[{unit}] size of the fault or effect {name} from the moment it is set; 0: none",
                             read_only=False) for name, unit in sorted(INJECTION_UNITS.items())},
}


class PlantSim(Node):
    def __init__(self) -> None:
        super().__init__("plant_sim")
        self.params = Parameters(self, PARAMETERS, self._on_parameter)
        self.can_bus = None
        self.rtf = self.params["real_time_factor"]
        config_path = self.params["config"]
        if read_config(config_path, required=("machine",), nonempty="machine").get("kind") == "crane":
            raise InputError(f"parameter config={config_path}: a crane config; run crane_sim for a crane")
        self.machine = load_machine_config(config_path)
        self.actuator = self.machine.first.name
        self.joint = self.machine.first.joint
        self.excitation = self.params["excitation"]
        self.publish_clock = self.params["publish_clock"]
        self.run = start(self.machine, Scenario(float("inf"), (), seed=self.params["seed"], actuator=self.actuator))
        self.variance = self.machine.sensors.pressure_noise_std ** 2
        self._pending: dict[str, float] = {}

        # one publisher per sample topic, in sample_payloads' order; valve commands are only
        # published when the simulated operator makes them
        mobile = self.run.plant.model.mobile_valve
        types = topics.sensor_topics([self.actuator], mobile=mobile)
        self.publishers_in_order = [
            None if (name == topics.VALVE_COMMANDS and self.excitation != "operator")
            else self.create_publisher(JointState if types[name] == topics.JOINT_STATE_TYPE else FluidPressure, relative(name), SENSOR_QOS,
                                       qos_overriding_options=QoSOverridingOptions.with_default_policies())
            for name in sample_topics(self.actuator, mobile=mobile)
        ]
        self.command = 0.0
        self.command_wall = -math.inf
        if self.excitation == "topic":
            self.create_subscription(JointState, relative(topics.VALVE_COMMANDS), self._on_command, SENSOR_QOS,
                                     qos_overriding_options=QoSOverridingOptions.with_default_policies())
        self.pub_clock = self.create_publisher(ClockMsg, topics.CLOCK, CLOCK_QOS) if self.publish_clock else None
        interface = self.params["can_interface"]
        if interface:
            import can

            from hydro_ros.can.codec import MachineBus

            self.can_codec = MachineBus(self.machine)
            self.can_bus = can.Bus(interface=interface, channel=self.params["can_channel"])
            self.can_counter = 0
        self.pub_diag = self.create_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)

        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.start_wall = time.monotonic()
        self.stamp_origin_ns = 0 if self.publish_clock else self.get_clock().now().nanoseconds
        self.lag_s = 0.0
        self.command_stale = False
        self.create_timer(self.params["tick_period"], self._tick, clock=self.steady)
        self.create_timer(1.0, self._diagnose, clock=self.steady)
        self.get_logger().info(
            f"simulating {self.machine.name} ({self.actuator}) at {self.machine.sample_rate_hz:.0f} Hz, "
            f"x{self.rtf:g} real time, excitation={self.excitation}"
        )

    def _on_parameter(self, name: str, value: float) -> None:
        self._pending[name.removeprefix("fault.")] = value

    def _on_command(self, msg: JointState) -> None:
        if self.actuator in msg.name:
            value = msg.position[msg.name.index(self.actuator)] if len(msg.position) == len(msg.name) else math.nan
            if math.isfinite(value):
                self.command = max(-1.0, min(1.0, value))
                self.command_wall = time.monotonic()
            else:
                self.get_logger().warning(f"ignored valve command for {self.actuator}: {value!r} (NaN or missing)")

    def _apply_pending(self) -> None:
        now = self.run.plant.time
        for name, value in self._pending.items():
            for holder in (self.run.plant.injections, self.run.sensors.injections):
                holder[:] = [i for i in holder if i.name != name]
                if value != 0.0:
                    holder.append(Injection(name, value, onset_s=now))
            self.get_logger().info(f"fault {name} = {value:g} from t = {now:.3f} s")
        self._pending.clear()

    def _tick(self) -> None:
        if self._pending:
            self._apply_pending()
        rate = self.run.plant.model.sample_rate
        due = int((time.monotonic() - self.start_wall) * self.rtf * rate) - self.run.plant.sample_index
        if due <= 0:
            return
        limit = int(MAX_CATCH_UP_S * rate)
        self.lag_s = max(0.0, (due - limit) / rate)
        n = min(due, limit)
        commands: float | None = None
        if self.excitation == "topic":
            self.command_stale = time.monotonic() - self.command_wall > COMMAND_TIMEOUT_S
            commands = 0.0 if self.command_stale else self.command
        _, _, block = self.run.step(n, None if commands is None else np.full(n, commands))
        self._publish(block)

    def _publish(self, block) -> None:
        origin = self.stamp_origin_ns
        publishers = self.publishers_in_order
        for k in range(len(block.times)):
            stamp = origin + int(round(block.times[k] * 1e9))
            for publisher, payload in zip(publishers, sample_payloads(block, k, stamp, self.actuator, self.joint, self.variance)):
                if publisher is not None:
                    publisher.publish(payload)
        if self.can_bus is not None:
            self._send_frames(block)
        if self.pub_clock is not None:
            msg = ClockMsg()
            stamp = origin + int(round(block.times[-1] * 1e9))
            msg.clock.sec, msg.clock.nanosec = divmod(stamp, 1_000_000_000)
            self.pub_clock.publish(msg)

    def _send_frames(self, block) -> None:
        import can

        from hydro_ros.can.codec import sample_values

        for k in range(len(block.times)):
            for frame_id, data in self.can_codec.encode_cycle(sample_values(block, k, self.actuator, self.joint), self.can_counter):
                self.can_bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=False))
            self.can_counter = (self.can_counter + 1) % 16

    def destroy_node(self) -> None:
        if self.can_bus is not None:
            self.can_bus.shutdown()
        super().destroy_node()

    def _diagnose(self) -> None:
        status = DiagnosticStatus(name="hydro_ros/plant_sim", hardware_id=self.machine.name)
        sim_time = self.run.plant.time
        wall = time.monotonic() - self.start_wall
        achieved = sim_time / wall if wall > 0 else 0.0
        problems = []
        if self.lag_s > 0.0:
            problems.append(f"behind real time by {self.lag_s:.2f} s")
        if self.excitation == "topic" and self.command_stale:
            problems.append("valve command stale, valve held closed")
        status.level = DiagnosticStatus.WARN if problems else DiagnosticStatus.OK
        status.message = "; ".join(problems) or "ok"
        active = [f"{i.name}={i.value:g}" for i in self.run.plant.injections + self.run.sensors.injections]
        status.values = [
            KeyValue(key="sim_time_s", value=f"{sim_time:.3f}"),
            KeyValue(key="real_time_factor", value=f"{achieved:.2f}"),
            KeyValue(key="active_faults", value=",".join(sorted(set(active))) or "none"),
        ]
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(array)


def main(args: list[str] | None = None) -> None:
    run_node(PlantSim, args)


if __name__ == "__main__":
    main()
