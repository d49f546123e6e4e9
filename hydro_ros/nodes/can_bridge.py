"""can_bridge: the machine's CAN bus (its config's can: dbc and map) -> the contract topics, with health.

A reader thread takes frames off a python-can bus (any interface: socketcan on a machine,
virtual / udp_multicast in tests) into a queue; a timer decodes them with the checked codec,
groups the frames of one sensor cycle by their rolling counter and publishes each cycle's values
stamped on the machine's clock (hydro_ros.can.clock: the bus's period, locked to the earliest arrivals; its
jitter, drift and lost cycles on /diagnostics as hydro_ros/can_bridge/clock), so consumers see consistent,
regularly sampled data. Bad frames are
counted by kind and never published. Per-message health goes to /diagnostics
(`hydro_ros/can_bridge/<MESSAGE>`: rate against the DBC cycle time, stale, counter gaps, checksum
and length errors) with a bus status (`hydro_ros/can_bridge/bus`: connection, error frames,
unknown ids, reconnects). A lost bus is reopened with exponential back-off.

With ``sample_blocks`` each decoding tick's complete cycles also go out as one message on
/hydraulics/sample_block, plant_sim's format, and ``sensor_topics`` can turn the per-sample topics off:
a crane's cycles at 1 kHz are more per-sample messages than rclpy carries (docs/crane_monitoring.md).

`forward_commands` (off by default: it drives a machine) sends /hydraulics/valve_commands as
VALVEn_REQUEST frames while the node is active; the bridge then leaves /hydraulics/valve_commands
to ROS and does not publish the applied commands it reads back. Deactivating (or shutting down)
sends a neutral request to every valve. A deadman guards the bus: a valve whose last command is older
than ``command_timeout`` gets neutral requests (again every ``command_timeout`` while none comes), so
a controller that dies (SIGKILL) cannot leave a valve open. A non-finite or out-of-range command is
refused, counted (``refused_commands``) and that valve sent neutral: nothing is clamped to a full opening.

A lifecycle node (ros2_socketcan's habit): configure reads the hardware parameters, loads the bus map
and opens the bus, and fails (FAILURE, the reason logged and on /diagnostics) when it cannot;
activate starts publishing and forwarding, deactivate stops them and sends the neutral requests,
cleanup closes the bus, so cleanup, a new ``channel`` and configure move the bridge to another bus.
``autostart`` (default true) runs configure and activate at start, for machines without a
lifecycle manager, and retries configure with ``reconnect_backoff`` while the bus cannot be opened.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass
from typing import Any

import can
import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.clock import Clock, ClockType
from rclpy.lifecycle import LifecycleNode, LifecycleState, TransitionCallbackReturn
from sensor_msgs.msg import FluidPressure, JointState, PointCloud2

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.cdr import encode_fluid_pressure, encode_joint_state, encode_sample_block
from hydro_ros.can.codec import MachineBus, cycle_row
from hydro_ros.can.stream import FrameStream
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.nodes.common import (
    MACHINE_ID,
    SAMPLE_BLOCKS,
    SENSOR_QOS,
    SENSOR_TOPICS,
    VALVE_COMMAND_TIMEOUT,
    checked_valve_commands,
    destroy_entities,
    machine_instance,
    namespaced_statuses,
    publishes_sensor_topic,
    relative,
    run_node,
)
from hydro_ros.nodes.parameters import declare, declared, parameter, specs_of
from hydro_ros.safety.motion import ValveDeadman

OK, WARN, ERROR, STALE = 0, 1, 2, 3
QUEUE_LIMIT = 200_000  # frames; beyond this the oldest are dropped and counted (the node is far behind)


class BusReader(threading.Thread):
    """Owns the python-can bus: receives into a deque, reconnects with back-off when it fails."""

    def __init__(self, open_bus: Any, backoff: tuple[float, float], extended_ids: frozenset[int] = frozenset(),
                 bus: can.BusABC | None = None) -> None:
        super().__init__(daemon=True, name="can-reader")
        self.open_bus = open_bus
        self.opened = bus  # the bus configure opened; reopened with open_bus once lost
        self.extended_ids = extended_ids  # 29-bit frames (J1939) among those this bridge sends
        self.backoff_min, self.backoff_max = backoff
        self.frames: collections.deque = collections.deque(maxlen=QUEUE_LIMIT)
        self.bus: can.BusABC | None = None
        self.connected = False
        self.reconnects = 0
        self.error_frames = 0
        self.last_error = ""
        self.received = 0
        self.stopping = threading.Event()
        self.lock = threading.Lock()

    def run(self) -> None:
        delay = self.backoff_min
        while not self.stopping.is_set():
            try:
                with self.lock:
                    self.bus, self.opened = self.opened or self.open_bus(), None
                self.connected = True
                delay = self.backoff_min
                while not self.stopping.is_set():
                    message = self.bus.recv(timeout=0.1)
                    if message is None:
                        if getattr(self.bus, "state", None) == can.BusState.ERROR:
                            raise can.CanOperationError("bus-off")
                        continue
                    if message.is_error_frame:
                        self.error_frames += 1
                        continue
                    self.received += 1
                    self.frames.append(message)
            except (can.CanError, OSError, ValueError) as exc:
                self.last_error = f"{type(exc).__name__}: {exc}"
            finally:
                self.connected = False
                with self.lock:
                    if self.bus is not None:
                        self.bus.shutdown()
                        self.bus = None
            if not self.stopping.wait(delay):
                self.reconnects += 1
                delay = min(delay * 2.0, self.backoff_max)

    def send(self, frame_id: int, data: bytes) -> bool:
        with self.lock:
            if self.bus is None:
                return False
            try:
                self.bus.send(can.Message(arbitration_id=frame_id, data=data, is_extended_id=frame_id in self.extended_ids))
                return True
            except can.CanError as exc:
                self.last_error = f"send: {exc}"
                return False


AT_CONFIGURE = " (read at configure: set it, then cleanup and configure)"
@dataclass
class CanBridgeParameters:
    """can_bridge's parameters, each declared once with its unit, range and description."""

    machine_id: str = declared(MACHINE_ID)
    config: str = parameter(str(default_config_path("sam")), "machine config (YAML) whose sensors are on the bus" + AT_CONFIGURE, existing_file=True,
                            read_only=False)
    dbc: str = parameter("", "DBC file of the bus; empty: the config's can.dbc" + AT_CONFIGURE, existing_file=True, read_only=False)
    interface: str = parameter("socketcan", "python-can interface (socketcan, pcan, kvaser, virtual, udp_multicast, ...)" + AT_CONFIGURE,
                               read_only=False)
    channel: str = parameter("can0", "channel of the interface" + AT_CONFIGURE, read_only=False)
    bitrate: int = parameter(500000, "[bit/s] bus bit rate (not used by virtual and udp_multicast)" + AT_CONFIGURE, 10000, 1000000, read_only=False)
    hardware_filters: bool = parameter(True, "let the interface pass only the DBC's sensor frames" + AT_CONFIGURE, read_only=False)
    forward_commands: bool = parameter(False, "while active, send /hydraulics/valve_commands as valve request frames (this drives "
                                              "the machine); deactivating sends neutral requests" + AT_CONFIGURE, read_only=False)
    command_timeout: float = declared(VALVE_COMMAND_TIMEOUT)
    sensor_topics: str = declared(SENSOR_TOPICS)
    sample_blocks: bool = declared(SAMPLE_BLOCKS)
    autostart: bool = parameter(True, "configure and activate at start, and retry configure (reconnect_backoff) while the bus cannot be "
                                      "opened; false: wait for a lifecycle manager")
    process_period: float = parameter(0.01, "[s] period of decoding the received frames", 0.001, 1.0)
    diagnostics_period: float = parameter(1.0, "[s] period of /diagnostics", 0.05, 60.0)
    stale_cycles: int = parameter(50, "[cycles] a message missing this many DBC cycles is STALE", 1, 100000)
    reconnect_backoff: list[float] = parameter([0.5, 10.0], "[s] first and longest wait before reopening a lost bus (doubling in between)")


PARAMETERS = specs_of(CanBridgeParameters)


class CanBridge(LifecycleNode):
    """A lifecycle node, like ros2_socketcan's: configure opens the bus, activate publishes (and forwards
    valve commands), deactivate sends neutral valve requests, cleanup closes the bus."""

    def __init__(self) -> None:
        super().__init__("can_bridge")
        self.params = declare(self, CanBridgeParameters)
        backoff = self.params.reconnect_backoff
        if not 0 < backoff[0] <= backoff[1]:
            raise InputError(f"parameter reconnect_backoff={backoff}: expected [first, longest] with 0 < first <= longest")
        self.machine = machine_instance(self, load_machine_config(self.params.config).name)
        self.forward = False
        self.bus_name = f"{self.params.interface}:{self.params.channel}"
        # /diagnostics in every state: a bus that cannot be opened is reported while the node waits unconfigured
        self.pub_diag = self.create_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)
        self.configure_error = ""
        self.configure_attempts = 0
        self._retry = None
        self.active = False
        self.reader: BusReader | None = None
        self._entities: list[Any] = []  # publishers, timers and the subscription of the configured state
        self._request_counter = 0
        self.command_timeout = self.params.command_timeout
        self.deadman: ValveDeadman | None = None  # the forwarded valves' last commands (or neutral requests), from activation
        self.refused_commands = 0
        self.deadman_neutrals = 0
        self._autostarting = False
        # the bus status in every lifecycle state, as diagnostic_updater's periodic Updater publishes: unconfigured with
        # the last configure error, inactive, active (every message's rate and health), finalized
        self.create_timer(self.params.diagnostics_period, self._diagnose, clock=Clock(clock_type=ClockType.STEADY_TIME))
        if self.params.autostart:
            self._autostart(backoff[0])

    def _autostart(self, delay: float) -> None:
        """Configure and activate; while the bus cannot be opened, stay unconfigured, say so and try again."""
        if self._retry is not None:
            self.destroy_timer(self._retry)
            self._retry = None
        self._autostarting = True
        configured = self.trigger_configure() == TransitionCallbackReturn.SUCCESS
        self._autostarting = False
        if configured:
            self.trigger_activate()
            return
        self._diagnose()
        retry_in = min(delay, self.params.reconnect_backoff[1])
        self._retry = self.create_timer(retry_in, lambda: self._autostart(min(2.0 * retry_in, self.params.reconnect_backoff[1])),
                                        clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _state_status(self) -> DiagnosticStatus:
        """The bus status outside the active state: the lifecycle state, and the last configure error while unconfigured."""
        state = self._state_machine.current_state[1]
        if state == "unconfigured" and self.configure_error:
            level, message = ERROR, f"unconfigured: {self.configure_error}"
        elif state == "inactive":
            level, message = WARN, f"inactive: bus {self.bus_name} open and checked, nothing published or forwarded"
        else:
            level, message = WARN, f"{state}: waiting for a lifecycle transition"
        return self._status("hydro_ros/can_bridge/bus", level, message, {
            "lifecycle_state": state, "connected": str(self.reader is not None and self.reader.connected),
            "reconnects": str(self.configure_attempts), "last_error": self.configure_error})  # reconnects: configure attempts

    # life cycle ----------------------------------------------------------------------------------
    def on_configure(self, state: LifecycleState) -> TransitionCallbackReturn:
        """Read the hardware parameters, load the machine's bus map and open the bus; FAILURE (with the reason logged and
        on /diagnostics) when any of that fails, as ros2_socketcan does, so a lifecycle manager sees it."""
        self.configure_attempts += 1
        interface = self.params.interface
        self.bus_name = f"{interface}:{self.params.channel}"
        try:
            machine = load_machine_config(self.params.config)
            self.codec = MachineBus(machine, self.params.dbc or None)
            self.forward = self.params.forward_commands
            if self.forward and self.codec.requests_missing():
                raise InputError(f"parameter forward_commands=true: the bus map names no valve_request for "
                                 f"{', '.join(self.codec.requests_missing())} (can.map.actuators.<name>.valve_request)")
            kwargs: dict[str, Any] = {"interface": interface, "channel": self.params.channel}
            if interface not in ("virtual", "udp_multicast"):
                kwargs["bitrate"] = self.params.bitrate
            if self.params.hardware_filters:
                kwargs["can_filters"] = [{"can_id": frame_id, "can_mask": 0x1FFFFFFF if m.is_extended_frame else 0x7FF,
                                          "extended": bool(m.is_extended_frame)}
                                         for frame_id, m in self.codec.by_id.items() if m.name in self.codec.expected]
            opened = can.Bus(**kwargs)
        except (InputError, can.CanError, OSError, ValueError, ImportError, NotImplementedError) as exc:
            self.configure_error = f"bus {self.bus_name} cannot be opened: {type(exc).__name__}: {exc}"
            # a configure a person asked for is answered every time; autostart's retries once in 30 s
            self.get_logger().error(self.configure_error, throttle_duration_sec=30.0 if self._autostarting else 0.0)
            return TransitionCallbackReturn.FAILURE
        self.machine = machine_instance(self, machine.name)
        self.configure_error = ""
        backoff = self.params.reconnect_backoff
        extended = frozenset(frame_id for frame_id, message in self.codec.by_id.items() if message.is_extended_frame)
        self.reader = BusReader(lambda: can.Bus(**kwargs), (backoff[0], backoff[1]), extended, bus=opened)

        mobile = any(slot.mobile for slot in self.codec.slots)
        types = topics.sensor_topics([s.actuator for s in self.codec.slots], mobile=mobile)
        self.pubs = {name: self.create_lifecycle_publisher(JointState if kind == topics.JOINT_STATE_TYPE else FluidPressure,
                                                           relative(name), SENSOR_QOS)
                     for name, kind in types.items()
                     if publishes_sensor_topic(self.params.sensor_topics, name) and not (self.forward and name == topics.VALVE_COMMANDS)}
        self.layout = SampleLayout([slot.actuator for slot in self.codec.slots], [slot.joint for slot in self.codec.slots], mobile=mobile)
        self.pub_block = (self.create_lifecycle_publisher(PointCloud2, relative(topics.SAMPLE_BLOCK), SENSOR_QOS)
                          if self.params.sample_blocks else None)
        self._entities = [*self.pubs.values()] + ([self.pub_block] if self.pub_block else [])
        if self.forward:
            self._entities.append(self.create_subscription(JointState, relative(topics.VALVE_COMMANDS), self._forward, SENSOR_QOS))

        self.stream = FrameStream(self.codec)
        self.last_seen: dict[str, float] = {}
        self._window_start = time.monotonic()
        self._window_counts: collections.Counter = collections.Counter()
        self._rates: dict[str, float] = {}
        self.published_cycles = 0
        self.stale_cycles = self.params.stale_cycles
        self.started = time.monotonic()
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self._entities.append(self.create_timer(self.params.process_period, self._process, clock=steady))
        self.reader.start()
        self.get_logger().info(f"bus {self.bus_name} open ({self.codec.dbc_path.name}) for {self.machine}; "
                               f"forward_commands={self.forward}")
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self.active = True
        valves = [slot.actuator for slot in self.codec.slots]
        self.deadman = ValveDeadman(valves, self.command_timeout)
        self.deadman.command(dict.fromkeys(valves, 0.0), time.monotonic())  # neutral until a controller speaks
        self.get_logger().info("active: publishing" + (" and forwarding valve commands" if self.forward else ""))
        return super().on_activate(state)

    def on_deactivate(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_safe()
        return super().on_deactivate(state)

    def on_cleanup(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._close_bus()
        self.get_logger().info(f"bus {self.bus_name} closed")
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state: LifecycleState) -> TransitionCallbackReturn:
        self._stop_safe()
        self._close_bus()
        return TransitionCallbackReturn.SUCCESS

    def destroy_node(self) -> None:
        self._stop_safe()
        self._close_bus()
        super().destroy_node()

    def _stop_safe(self) -> None:
        """Leave the active state; a bridge that forwarded commands leaves every valve neutral."""
        if not self.active:
            return
        self.active = False
        if self.forward and self.reader is not None:
            sent = [self.reader.send(*self.codec.encode_request(slot.actuator, 0.0, self._request_counter)) for slot in self.codec.slots]
            self._request_counter = (self._request_counter + 1) % 16
            if all(sent):
                self.get_logger().info("neutral valve requests sent")
            else:
                self.get_logger().error(f"neutral valve requests could not be sent on {self.bus_name} ({self.reader.last_error})")

    def _close_bus(self) -> None:
        if self.reader is not None:
            self.reader.stopping.set()
            self.reader.join(timeout=2.0)
            self.reader = None
        destroy_entities(self, self._entities)

    # frames -> topics ----------------------------------------------------------------------------
    def _process(self) -> None:
        if self.reader is None:
            return
        frames = self.reader.frames
        now = time.monotonic()
        if self.forward and self.active:
            self._deadman(now)
        block: list[tuple[int, list[float]]] = []
        for _ in range(len(frames)):
            message = frames.popleft()
            name, cycles = self.stream.add(message.arbitration_id, bytes(message.data), message.timestamp)
            if name is None:
                continue
            self._window_counts[name] += 1
            self.last_seen[name] = now
            if not self.active:  # configured but inactive: the bus is read and checked, nothing is published
                continue
            for stamp, values in self.stream.complete(cycles):
                if self.pubs:
                    self._publish(values, stamp)
                if self.pub_block is not None:
                    block.append((stamp, cycle_row(values, self.layout.columns)))
                self.published_cycles += 1
        if block:
            stamps = np.array([stamp for stamp, _ in block], dtype=np.int64)
            self.pub_block.publish(encode_sample_block(int(stamps[0]), self.machine, self.layout.field_names, stamps,
                                                       np.array([row for _, row in block])))

    def _publish(self, values: dict[str, Any], stamp: int) -> None:
        pubs = self.pubs
        if values["joint_position"] and topics.JOINT_STATES in pubs:
            joints = list(values["joint_position"])
            pubs[topics.JOINT_STATES].publish(encode_joint_state(
                stamp, "", joints, [values["joint_position"][j] for j in joints], [values["joint_velocity"][j] for j in joints], []))
        if "supply_pressure" in values and topics.SUPPLY_PRESSURE in pubs:
            pubs[topics.SUPPLY_PRESSURE].publish(encode_fluid_pressure(stamp, "supply", values["supply_pressure"], 0.0))
            if topics.LS_PRESSURE in pubs:
                pubs[topics.LS_PRESSURE].publish(encode_fluid_pressure(stamp, "ls", values["ls_pressure"], 0.0))
        for quantity in ("pressure_a", "pressure_b", *topics.MOBILE_VALVE_PRESSURES):
            for actuator, value in values[quantity].items():
                topic = topics.actuator_pressure(actuator, quantity)
                if topic in pubs:
                    pubs[topic].publish(encode_fluid_pressure(stamp, actuator, value, 0.0))
        if values["valve_command"] and topics.VALVE_COMMANDS in pubs:
            actuators = list(values["valve_command"])
            pubs[topics.VALVE_COMMANDS].publish(encode_joint_state(
                stamp, "", actuators, [values["valve_command"][a] for a in actuators], [], []))

    def _forward(self, msg: JointState) -> None:
        if not self.active or self.reader is None:
            return
        accepted, refused = checked_valve_commands(list(msg.name), list(msg.position), [slot.actuator for slot in self.codec.slots])
        if refused:
            self.refused_commands += 1
            self.get_logger().error(f"{topics.VALVE_COMMANDS} refused: {'; '.join(f'{a} {why}' for a, why in refused.items())}: "
                                    "commanded neutral", throttle_duration_sec=2.0)
        commands = {**dict.fromkeys(refused, 0.0), **accepted}
        for slot in self.codec.slots:
            if slot.actuator in commands:
                self.reader.send(*self.codec.encode_request(slot.actuator, commands[slot.actuator], self._request_counter))
        self.deadman.command(commands, time.monotonic())
        self._request_counter = (self._request_counter + 1) % 16

    def _deadman(self, now: float) -> None:
        """Neutral requests for every valve whose last command is older than command_timeout (a dead or silent controller)."""
        stale = self.deadman.expired(now) if self.deadman is not None else []
        if not stale or self.reader is None:
            return
        for actuator in stale:
            self.reader.send(*self.codec.encode_request(actuator, 0.0, self._request_counter))
        self.deadman.command(dict.fromkeys(stale, 0.0), now)  # sent again every command_timeout while none comes
        self._request_counter = (self._request_counter + 1) % 16
        self.deadman_neutrals += 1
        self.get_logger().warning(f"no valve command for {self.command_timeout:g} s: {', '.join(stale)} "
                                  "commanded neutral", throttle_duration_sec=5.0)

    # health ------------------------------------------------------------------------------------
    def _diagnose(self) -> None:
        if not self.active or self.reader is None:
            array = DiagnosticArray(status=namespaced_statuses(self, [self._state_status()]))
            array.header.stamp = self.get_clock().now().to_msg()
            self.pub_diag.publish(array)
            return
        now = time.monotonic()
        elapsed = max(now - self._window_start, 1e-6)
        self._rates = {name: self._window_counts[name] / elapsed for name in self.codec.expected}
        self._window_start, self._window_counts = now, collections.Counter()
        statuses = []
        for name in sorted(self.codec.expected):
            cycle_s = max(self.codec.cycle_ms[name], 1) / 1000.0
            silent = now - self.last_seen.get(name, self.started)
            gaps = self.stream.counters.gaps.get(name, 0)
            expected_rate = 1.0 / cycle_s
            if silent > self.stale_cycles * cycle_s:
                level, message = STALE, f"no frame for {silent:.2f} s"
            elif self._rates[name] < 0.9 * expected_rate:
                level, message = WARN, f"{self._rates[name]:.0f} frames/s, DBC cycle {expected_rate:.0f}/s"
            else:
                level, message = OK, "ok"
            values = {"rate_hz": f"{self._rates[name]:.1f}", "expected_hz": f"{expected_rate:.1f}", "frames": str(self.stream.frames_per_message[name]),
                      "counter_gaps": str(gaps)}
            statuses.append(self._status(f"hydro_ros/can_bridge/{name}", level, message, values))
        reader = self.reader
        bus_level = OK if reader.connected else ERROR
        bus_values = {"connected": str(reader.connected), "frames_received": str(reader.received),
                      "error_frames": str(reader.error_frames), "reconnects": str(reader.reconnects),
                      "last_error": reader.last_error, "incomplete_cycles": str(self.stream.incomplete),
                      "published_cycles": str(self.published_cycles), "queue": str(len(reader.frames)),
                      "refused_commands": str(self.refused_commands), "deadman_neutrals": str(self.deadman_neutrals),
                      **{f"rejected_{kind}": str(n) for kind, n in sorted(self.stream.rejected.items())}}
        problems = [] if reader.connected else [f"bus {self.bus_name} down ({reader.last_error or 'connecting'})"]
        if sum(self.stream.rejected.values()):
            problems.append(f"{sum(self.stream.rejected.values())} bad frames")
            bus_level = max(bus_level, WARN)
        statuses.append(self._status("hydro_ros/can_bridge/bus", bus_level, "; ".join(problems) or "ok", bus_values))
        clock = self.stream.clock
        health = clock.health
        if health.locked:
            level, message = OK, "ok"
        elif clock.acquiring:
            level, message = OK, "locking"
        else:
            level, message = WARN, (f"not locked: a cycle arrived {health.jitter_max_s * 1e3:.1f} ms late, beyond can.latency_limit "
                                    f"{clock.limit_ns * 1e-6:.0f} ms on a bus without counters; samples carry arrival times")
        statuses.append(self._status("hydro_ros/can_bridge/clock", level, message,
                                     {**health.values(), "period_ms": f"{clock.period_ns * 1e-6:.6f}"}))
        array = DiagnosticArray(status=namespaced_statuses(self, statuses))
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(array)

    def _status(self, name: str, level: int, message: str, values: dict[str, str]) -> DiagnosticStatus:
        return DiagnosticStatus(level=bytes([level]), name=name, message=message, hardware_id=self.machine,
                                values=[KeyValue(key=k, value=v) for k, v in values.items()])


def main(args: list[str] | None = None) -> None:
    run_node(CanBridge, args)


if __name__ == "__main__":
    main()
