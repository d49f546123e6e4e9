"""fdi_node: condition monitoring of every actuator of the machine config, live or on a replayed bag.

Subscribes to the contract's measured topics as raw CDR (no message objects at 1 kHz), aligns the
topics on their sample stamps and runs :class:`hydro_ros.fdi.monitor.FdiMonitor` on blocks of
complete samples every ``process_period``. Publishes one DiagnosticStatus per actuator
(``hydro_ros/fdi/<actuator>``), the latched ``/fdi/halt`` and decimated ``/fdi/residuals``
(sensor_msgs/JointState: name = ``<actuator>/<quantity>``, position = value in MPa, stamp = the
sample time). Services: ``~/acknowledge``, ``~/reset`` (std_srvs/Trigger), ``~/self_test``
(diagnostic_msgs/SelfTest).

Robustness: a sample whose topics do not all arrive within ``sync_window`` is processed as a gap
(the filter holds, no residual); stamps at or before the last processed one are dropped and
counted; a topic silent for ``stale_timeout`` makes its actuators STALE (no alarm is raised from stale
data): of wall time, or under ``use_sim_time`` of the data's own clock (the node's /clock time against the
topic's last stamp, so a replay slower than real time is not stale) with a steady watchdog of
STEADY_WATCHDOG_S of wall time, so a stopped /clock is a stale monitor, never a frozen "all clear". A time
jump of the input (clock step, bag loop, sim-time reset) restarts the filters on the new time base; a single
stray stamp is dropped. An actuator is ``ok`` only while it is really monitored: until a window of data is evaluated (start, reset, time jump) and while a
reading is invalid (non-finite, implausible, frozen: ``hydro_ros/sensors/<actuator>`` names it) it
is STALE ``not_monitored``; when samples arrive incomplete it is WARN ``overloaded``. All counters
are in the diagnostic values.

Halt and alarms are decided by the safety core (:class:`hydro_ros.safety.supervisor.MonitorSupervisor`); this node
feeds it what the monitor knows after every processing tick and publishes its decisions. ``/fdi/halt`` is a heartbeat
(every ``HEARTBEAT_PERIOD_S`` and at once on a change): ``false`` only while every actuator is vouched for (armed,
fresh, valid, not overloaded, its evidence explained, evaluated on a window of samples since its last gap, time jump,
invalid reading, overload, restart or reset); ``true`` otherwise, so a late subscriber of the latch reads ``true``
from a blind monitor. The reason ("paused: ..." for a hold, "stop: ..." for a severe fault) is the machine-wide status
``hydro_ros/fdi_halt`` on /diagnostics.

Acknowledge silences an alarm (``acknowledged`` in its status), never clears it: a latched fault stays
until a reset. A reset re-arms the filters and keeps every fault that was latched shown (``rechecking``)
until the re-armed monitor has evaluated a window: a fault still present is reported throughout, one
that is gone is cleared. The services stay cheap so a burst of calls is answered between two
processing ticks: the self-test's simulated healthy machine is evaluated once per node, an
acknowledgement is logged only when it silences something new.
"""

from __future__ import annotations

import math
import time
from collections import deque
from dataclasses import dataclass
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from diagnostic_msgs.srv import SelfTest
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rclpy.qos_overriding_options import QoSOverridingOptions
from sensor_msgs.msg import FluidPressure, JointState, PointCloud2
from std_msgs.msg import Bool
from std_srvs.srv import Trigger

from hydro_ros.bags.align import ContractAligner, SampleLayout
from hydro_ros.bags.cdr import CdrError, header_stamp_ns
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.samples import PER_ACTUATOR
from hydro_ros.fdi.alarm_log import AlarmLog
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.residuals import GENERATORS
from hydro_ros.fdi.settings import unset_threshold
from hydro_ros.nodes.common import (
    HALT_QOS,
    MACHINE_ID,
    SENSOR_QOS,
    SERVICE_QOS,
    machine_instance,
    namespaced_statuses,
    relative,
    run_node,
)
from hydro_ros.nodes.parameters import declare, declared, parameter, specs_of
from hydro_ros.safety.motion import HEARTBEAT_PERIOD_S
from hydro_ros.safety.supervisor import ERROR, OK, STALE, WARN, ActuatorView, AlarmEvent, Halt, MonitorSupervisor
from hydro_ros.safety.timing import SampleTiming

ALARM_LOG_STATUS = "hydro_ros/alarm_log"
MAX_PENDING_NS = 5_000_000_000  # samples waiting for a missing topic longer than this are given up
DRAIN_MAX = 200  # messages of one topic taken per callback at most, so one topic cannot starve the timers
OVERLOAD_WINDOW_S = 2.0  # [s] of wall time over which the share of incomplete samples is measured
STEADY_WATCHDOG_S = 2.0  # [s] of wall time without a message: stale under use_sim_time too (a stopped /clock freezes its time)
OVERLOAD_SHARE = 0.05  # more incomplete samples than this: the input outruns the node ("overloaded")


@dataclass
class FdiNodeParameters:
    """fdi_node's parameters, each declared once with its unit, range and description."""

    machine_id: str = declared(MACHINE_ID)
    config: str = parameter(str(default_config_path("sam")), "machine config (YAML) whose actuators are monitored", existing_file=True)
    method: str = parameter("", "residual generator; empty: the config's fdi.method", choices=("", *GENERATORS))
    input: str = parameter("topics", "where samples come from: the contract's per-sample sensor topics, or the sample blocks on "
                                     "/hydraulics/sample_block (every column, many samples a message: a crane at 1 kHz)",
                           choices=("topics", "sample_block"))
    process_period: float = parameter(0.02, "[s] period of aligning and filtering the queued samples", 0.001, 1.0)
    diagnostics_period: float = parameter(1.0, "[s] period of /diagnostics", 0.05, 60.0)
    residual_rate: float = parameter(50.0, "[Hz] rate of /fdi/residuals", 0.1, 1000.0)
    sync_window: float = parameter(0.05, "[s] how long a sample waits for all its topics before it counts as incomplete", 0.001, 1.0)
    stale_timeout: float = parameter(0.5, "[s] a sensor topic may be silent before its actuators are STALE (of the data's clock under "
                                     "use_sim_time, with a 2 s wall-clock watchdog)", 0.01, 60.0,
                                     read_only=False)
    time_jump_threshold: float = parameter(1.0, "[s] a stamp this far from the time base is a jump (held off, then followed)", 0.01, 3600.0,
                                           read_only=False)
    alarm_log: str = parameter("", "SQLite file of the alarm log (every alarm raised, changed, cleared, acknowledged, reset); latched "
                                   "alarms in it come back after a restart; empty: no log")
    reset_min_interval: float = parameter(5.0, "[s] at least this long between two accepted ~/reset calls (a reset cannot hide a present "
                                               "fault: it stays shown until re-checked)", 1.0, 3600.0, read_only=False)


PARAMETERS = specs_of(FdiNodeParameters)


class FdiNode(Node):
    def __init__(self) -> None:
        super().__init__("fdi_node")
        self.params = declare(self, FdiNodeParameters, self._on_parameter)
        self.machine_config = load_machine_config(self.params.config)
        self.monitor = FdiMonitor(self.machine_config, self.params.method or None)
        if self.monitor.method == "ukf" and unset_threshold(self.machine_config):
            self.get_logger().warning(unset_threshold(self.machine_config))
        self.machine = machine_instance(self, self.machine_config.name)
        self.stale_timeout = self.params.stale_timeout
        self.alarm_log = AlarmLog(self.params.alarm_log, self.machine) if self.params.alarm_log else None
        if self.alarm_log is not None and self.alarm_log.error:
            self.get_logger().warning(f"alarm log: {self.alarm_log.error}; events are kept in memory and written once it opens")
        for aside in self.alarm_log.moved_aside if self.alarm_log else []:
            self.get_logger().warning(f"alarm log {self.alarm_log.path} was not an alarm log: moved aside to {aside}, a new one started")
        restored = {a.actuator: (a.level, a.fault) for a in (self.alarm_log.latched() if self.alarm_log else [])}
        # the safety core: vouching, latched and held alarms, the halt decision (hydro_ros.safety.supervisor)
        self.supervisor = MonitorSupervisor(self.monitor.actuators, self.monitor.startup + self.monitor.window,
                                            self.params.reset_min_interval, restored)
        for actuator, held in self.supervisor.held.items():
            self.get_logger().warning(f"{actuator}: {held.fault} latched before the restart (alarm log), until a reset")
        self._simulated_check: bool | None = None  # the self-test's simulated healthy machine, evaluated once
        actuators = self.monitor.actuators
        self.mobile = self.monitor.generator.needs_mobile_pressures
        self.layout = SampleLayout(actuators, self.monitor.joints, mobile=self.mobile)
        self.aligner = ContractAligner(self.layout, sync_window_ns=int(self.params.sync_window * 1e9), max_pending_ns=MAX_PENDING_NS,
                                       jump_ns=int(self.params.time_jump_threshold * 1e9))
        self._hold_until = -math.inf  # monotonic time until which detection holds (overload)
        rate = self.machine_config.sample_rate_hz
        self.timing = SampleTiming(1.0 / rate, int(self.monitor.settings.window_s * rate))
        self._jumps_seen = 0
        self._recent: deque[tuple[float, int, int]] = deque()  # (wall time, samples, incomplete) per processed block
        self.undecodable = 0
        index = self.layout.index

        self.last_arrival: dict[str, float] = {}
        self.last_stamp: dict[str, int] = {}  # [ns] the header stamp of each topic's last message
        self.sim_time = bool(self.get_parameter("use_sim_time").value)
        self.first_arrival: dict[str, float] = {}
        self.blocks = self.params.input == "sample_block"
        if self.blocks:
            self._subscribe_raw(PointCloud2, topics.SAMPLE_BLOCK, self.aligner.put_block)
        else:
            self._subscribe_contract_topics(actuators, index)

        self.pub_diag = self.create_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)
        self.pub_halt = self.create_publisher(Bool, relative(topics.FDI_HALT), HALT_QOS)
        self.pub_residuals = self.create_publisher(JointState, relative(topics.FDI_RESIDUALS), 10)
        self._residual_channels = topics.fdi_residual_channels(actuators, mobile=self.mobile)
        self.create_service(Trigger, "~/acknowledge", self._on_acknowledge, qos_profile=SERVICE_QOS)
        self.create_service(Trigger, "~/reset", self._on_reset, qos_profile=SERVICE_QOS)
        self.create_service(SelfTest, "~/self_test", self._on_self_test, qos_profile=SERVICE_QOS)

        self.steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.started = time.monotonic()
        self.samples = 0
        self.halt: Halt | None = None
        self._levels: list[tuple[int, str]] = []
        self._residual_interval_ns = int(1e9 / self.params.residual_rate)
        self._last_residual_ns = -(1 << 62)
        self.create_timer(self.params.process_period, self._process, clock=self.steady)
        self.create_timer(self.params.diagnostics_period, self._on_diagnostics_tick, clock=self.steady)
        self.create_timer(HEARTBEAT_PERIOD_S, self._publish_halt, clock=self.steady)
        self._publish_halt()  # a late subscriber of the latch reads the truth from the start: not vouched yet
        self.get_logger().info(f"monitoring {', '.join(actuators)} of {self.machine} with the {self.monitor.method} method")

    def _on_parameter(self, name: str, value: Any) -> None:
        if name == "stale_timeout":
            self.stale_timeout = value
        elif name == "time_jump_threshold":
            self.aligner.jump_ns = int(value * 1e9)
        elif name == "reset_min_interval":
            self.supervisor.reset_min_interval_s = value

    def _subscribe_contract_topics(self, actuators: list[str], index: Any) -> None:
        self._subscribe_raw(JointState, topics.JOINT_STATES, self.aligner.put_joint_states)
        self._subscribe_raw(JointState, topics.VALVE_COMMANDS, self.aligner.put_commands)
        self._subscribe_raw(FluidPressure, topics.SUPPLY_PRESSURE, lambda d, c=index("supply_pressure"): self.aligner.put_pressure(d, c))
        for actuator in actuators:
            quantities = ("pressure_a", "pressure_b", *(topics.MOBILE_VALVE_PRESSURES if self.mobile else ()))
            for quantity in quantities:
                self._subscribe_raw(FluidPressure, topics.actuator_pressure(actuator, quantity),
                                    lambda d, c=index(quantity, actuator): self.aligner.put_pressure(d, c))

    def _subscribe_raw(self, msg_type: Any, topic: str, handler: Any) -> None:
        def consume(data: bytes) -> None:
            try:
                handler(data)
                self.last_stamp[topic] = header_stamp_ns(data)
            except CdrError as exc:
                self.undecodable += 1
                self.get_logger().error(f"{topic}: message dropped: {exc}", throttle_duration_sec=10.0)

        def callback(data: bytes) -> None:
            self.last_arrival[topic] = time.monotonic()
            self.first_arrival.setdefault(topic, self.last_arrival[topic])
            consume(data)
            # take what else is queued now: the executor's overhead (a wait set per message, most of
            # this node's CPU at 1 kHz) is then paid once per burst, not once per message
            with subscription.handle:
                for _ in range(DRAIN_MAX):
                    taken = subscription.handle.take_message(msg_type, True)
                    if taken is None:
                        break
                    consume(taken[0])

        subscription = self.create_subscription(msg_type, relative(topic), callback, SENSOR_QOS, raw=True,
                                                qos_overriding_options=QoSOverridingOptions.with_default_policies())

    # processing -------------------------------------------------------------------------------
    def _process(self) -> None:
        if len(self.aligner.time_jumps) != self._jumps_seen:
            self._jumps_seen = len(self.aligner.time_jumps)
            self.monitor.restart()
            self.timing.restart()
            self.supervisor.disturb(f"a time jump of {self.aligner.time_jumps[-1]:+.3f} s")
            self.get_logger().warning(f"input time jumped by {self.aligner.time_jumps[-1]:+.3f} s: filters restart on the new "
                                      f"time base, detection re-arms after {self.monitor.settings.window_s:g} s of data")
        incomplete = self.aligner.incomplete
        stamps, rows = self.aligner.take()
        now = time.monotonic()
        self._recent.append((now, len(stamps), self.aligner.incomplete - incomplete))
        while self._recent and now - self._recent[0][0] > OVERLOAD_WINDOW_S:
            self._recent.popleft()
        valid_tail = np.zeros(len(self.monitor.actuators), dtype=int)
        self.timing.observe(stamps)
        if len(stamps):
            if self.timing.problem or any(self._overloaded(i) for i in range(len(self.monitor.actuators))):
                # no alarm from incomplete or irregularly timed data: detection holds while they come and one window after
                self._hold_until = now + self.monitor.settings.window_s
            result = self.monitor.process(self.layout.samples(stamps * 1e-9, rows), hold=now < self._hold_until)
            self.samples += len(stamps)
            for alarm in result.alarms:
                self.get_logger().warning(f"{alarm.actuator}: {alarm.fault.value} (pattern {alarm.code}) at stamp {alarm.time_s:.3f} s")
            self._publish_residuals(stamps, result)
            # valid samples at the end of the block, per actuator (all of them when none was invalid)
            invalid = ~result.valid[::-1]
            valid_tail = np.where(invalid.any(axis=0), np.argmax(invalid, axis=0), len(stamps))
        self._log_alarms(self.supervisor.observe({a: self._view(i, len(stamps), int(valid_tail[i]))
                                                  for i, a in enumerate(self.monitor.actuators)}))
        self._check_levels()

    def _view(self, index: int, samples: int, valid_tail: int) -> ActuatorView:
        """What the monitor knows of one actuator now, for the supervisor."""
        status = self.monitor.status(index)
        return ActuatorView(
            fresh=not self._stale_topics(index), overloaded=self._overloaded(index), timing=self.timing.problem,
            coverage=self.monitor.outside(index),
            sensor_problems=tuple(sorted(c for c in self.monitor.sensor_problems(index) if c != "supply_pressure")),
            armed=self.monitor.armed, explained=self.monitor.explained(index),
            fault=None if status.fault is None else status.fault.value, fault_level=status.level, samples=samples, valid_tail=valid_tail)

    def _publish_residuals(self, stamps: np.ndarray, result: Any) -> None:
        if stamps[-1] - self._last_residual_ns < self._residual_interval_ns:
            return
        self._last_residual_ns = int(stamps[-1])
        msg = JointState()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamps[-1]), 1_000_000_000)
        # layout of topics.fdi_residual_channels: actuator-major, chamber, then residual before threshold
        msg.name = self._residual_channels
        msg.position = np.stack([result.mean_residual[-1], result.threshold[-1]], axis=-1).ravel().tolist()
        self.pub_residuals.publish(msg)

    def _topics(self, index: int) -> tuple[str, ...]:
        """The topics one actuator's samples need."""
        if self.blocks:
            return (topics.SAMPLE_BLOCK,)
        actuator = self.monitor.actuators[index]
        needed = (topics.JOINT_STATES, topics.VALVE_COMMANDS, topics.SUPPLY_PRESSURE, topics.pressure_a(actuator), topics.pressure_b(actuator))
        if self.mobile:
            needed += tuple(topics.actuator_pressure(actuator, q) for q in topics.MOBILE_VALVE_PRESSURES)
        return needed

    def _stale_topics(self, index: int) -> list[str]:
        now = time.monotonic()
        if not self.sim_time:
            return [t for t in self._topics(index) if now - self.last_arrival.get(t, self.started) > self.stale_timeout]
        data_now = self.get_clock().now().nanoseconds
        watchdog = max(self.stale_timeout, STEADY_WATCHDOG_S)
        return [t for t in self._topics(index)
                if now - self.last_arrival.get(t, self.started) > watchdog
                or t not in self.last_stamp or (data_now - self.last_stamp[t]) * 1e-9 > self.stale_timeout]

    def _incomplete_share(self) -> float:
        samples = sum(n for _, n, _ in self._recent)
        return sum(k for _, _, k in self._recent) / samples if samples else 0.0

    def _overloaded(self, index: int) -> bool:
        """Too many incomplete samples, once every topic has been flowing for a whole measuring window
        (while subscriptions are still matching at start-up, samples are incomplete for another reason)."""
        needed = self._topics(index)
        if any(topic not in self.first_arrival for topic in needed):
            return False
        flowing = time.monotonic() - max(self.first_arrival[topic] for topic in needed)
        return flowing > 2 * OVERLOAD_WINDOW_S and self._incomplete_share() > OVERLOAD_SHARE

    def _check_levels(self) -> None:
        levels = [(state.level, state.message) for state in map(self.supervisor.state, self.monitor.actuators)]
        if levels != self._levels or self.supervisor.halt() != self.halt:
            self._levels = levels
            self._publish_diagnostics()
            self._publish_halt()

    def _log_alarms(self, events: list[AlarmEvent]) -> None:
        """Each actuator's latched fault against the last one logged: raised, changed or cleared."""
        if self.alarm_log is None:
            return
        for event in events:
            i = self.monitor.actuators.index(event.actuator)
            status = self.monitor.status(i)
            evidence = {"pattern": status.code, "mean_residual": self.monitor.last_mean_residual[i].round(5).tolist(),
                        "threshold": self.monitor.last_threshold[i].round(5).tolist(), "before": event.before}
            self.alarm_log.record(event.event, event.actuator, event.fault, event.level, stamp_s=status.detected_at, evidence=evidence)

    def _publish_halt(self) -> None:
        """The halt heartbeat, every HEARTBEAT_PERIOD_S and at once on a change: true on a severe fault and whenever the
        monitor cannot vouch for every actuator (the reason on /diagnostics, hydro_ros/fdi_halt); false only while it does."""
        halt = self.supervisor.halt()
        if halt != self.halt:
            if halt.kind == "fault" and (self.halt is None or self.halt.kind != "fault"):
                self.get_logger().error(f"severe fault: requesting halt on {topics.FDI_HALT}: {halt.reason}")
            elif self.halt is not None and halt.kind != self.halt.kind:
                self.get_logger().info(f"{topics.FDI_HALT}: {halt.reason}")
        self.halt = halt
        self.pub_halt.publish(Bool(data=halt.halt))

    def statuses(self) -> list[DiagnosticStatus]:
        out = []
        a = self.aligner
        # UKF residuals are chamber pressures [MPa]; parity residuals are chamber flows [L/min]
        labels = ("QA_L_min", "QB_L_min") if self.mobile else ("pA_MPa", "pB_MPa")
        for i, actuator in enumerate(self.monitor.actuators):
            status = self.monitor.status(i)
            stale = self._stale_topics(i)
            held = self.supervisor.held.get(actuator)
            state = self.supervisor.state(actuator)
            level, message = state.level, state.message
            problems = self.monitor.sensor_problems(i)
            values = {
                f"mean_r_{labels[0]}": f"{self.monitor.last_mean_residual[i, 0]:.5f}",
                f"mean_r_{labels[1]}": f"{self.monitor.last_mean_residual[i, 1]:.5f}",
                f"threshold_{labels[0]}": f"{self.monitor.last_threshold[i, 0]:.5f}",
                f"threshold_{labels[1]}": f"{self.monitor.last_threshold[i, 1]:.5f}",
                "pattern": status.code,
                "first_detection_stamp_s": "" if status.detected_at is None else f"{status.detected_at:.3f}",
                "method": self.monitor.method,
                "samples": str(self.samples),
                "gap_samples": str(self.monitor.invalid_samples),
                "incomplete_samples": str(a.incomplete),
                "out_of_order_dropped": str(a.out_of_order),
                "undecodable_messages": str(self.undecodable),
                "stale_topics": ",".join(stale),
                "armed": str(self.monitor.armed).lower(),
                "invalid_sensors": ",".join(f"{self._source(c, actuator)}:{p}" for c, p in problems.items()),
                "supply_substituted_samples": str(self.monitor.supply_substituted),
                "time_jumps": str(len(a.time_jumps)),
                "last_time_jump_s": f"{a.time_jumps[-1]:+.3f}" if a.time_jumps else "",
                "off_time_base_dropped": str(a.off_base),
                "incomplete_share": f"{self._incomplete_share():.3f}",
                "detection_held": str(time.monotonic() < self._hold_until).lower(),
                "restored_from_alarm_log": str(held is not None and not held.rechecking and status.fault is None).lower(),
                "rechecking": str(held is not None and held.rechecking and status.fault is None).lower(),
                "acknowledged": str(actuator in self.supervisor.acknowledged).lower(),
                "vouched": str(not state.hold).lower(),
                "held_outside_commissioned_share": f"{self.monitor.outside_held_samples[i] / max(self.monitor.evaluated_samples, 1):.3f}",
                "not_vouched_because": state.hold,
            }
            closed_threshold = self.monitor.generator.closed_threshold
            if closed_threshold is not None:  # the parity method's closed-valve evidence: empty until the valve was closed long enough
                for chamber, label in enumerate(labels):
                    mean = self.monitor.last_closed_mean[i, chamber]
                    values[f"closed_mean_r_{label}"] = f"{mean:.5f}" if np.isfinite(mean) else ""
                    values[f"closed_threshold_{label}"] = f"{closed_threshold[chamber]:.5f}"
            out.append(DiagnosticStatus(level=bytes([level]), name=f"{topics.FDI_STATUS_PREFIX}{actuator}", message=message,
                                        hardware_id=self.machine,
                                        values=[KeyValue(key=k, value=v) for k, v in values.items()]))
            # the sensors' own health: never OK while a reading is invalid, nor without fresh values to judge
            message = "; ".join(f"{self._source(c, actuator)} {p}" for c, p in problems.items())
            if stale:
                message = "; ".join(filter(None, [f"no fresh values on {', '.join(stale)}", message]))
            out.append(DiagnosticStatus(
                level=bytes([STALE if stale else WARN if problems else OK]), name=f"{topics.SENSOR_STATUS_PREFIX}{actuator}",
                hardware_id=self.machine, message=message or "ok",
                values=[KeyValue(key=self._source(c, actuator), value=p) for c, p in problems.items()]
                + [KeyValue(key=topic, value="stale") for topic in stale]))
        halt = self.supervisor.halt()
        out.append(DiagnosticStatus(level=bytes([{"clear": OK, "hold": WARN, "fault": ERROR}[halt.kind]]), name=topics.FDI_HALT_STATUS,
                                    message=halt.reason, hardware_id=self.machine,
                                    values=[KeyValue(key="halt", value=str(halt.halt).lower()), KeyValue(key="kind", value=halt.kind)]))
        if self.alarm_log is not None:
            log = self.alarm_log
            trouble = log.error or (f"{log.dropped} events dropped (queue full)" if log.dropped else "")
            values = {"file": str(log.path), "failed_writes": log.failed_writes, "pending_events": len(log.pending),
                      "dropped_events": log.dropped, "reopened": log.reopened, "moved_aside": ",".join(map(str, log.moved_aside)),
                      "restored_alarms": sum(not held.rechecking for held in self.supervisor.held.values())}
            out.append(DiagnosticStatus(
                level=bytes([WARN if trouble else OK]), name=ALARM_LOG_STATUS, hardware_id=self.machine,
                message=f"alarm log not written: {trouble}; {len(log.pending)} events kept in memory" if trouble else "ok",
                values=[KeyValue(key=k, value=str(v)) for k, v in values.items()]))
        return out

    def _source(self, channel: str, actuator: str) -> str:
        name = self.monitor.joints[self.monitor.actuators.index(actuator)] if channel.startswith("joint_") else actuator
        return SampleLayout.source((channel, "" if channel == "supply_pressure" else name))

    def _on_diagnostics_tick(self) -> None:
        if self.alarm_log is not None and self.alarm_log.pending:
            self.alarm_log.flush()  # what a full or missing disk held back
        self._publish_diagnostics()

    def _publish_diagnostics(self) -> None:
        array = DiagnosticArray(status=namespaced_statuses(self, self.statuses()))
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(array)

    # services -----------------------------------------------------------------------------------
    def _answer(self, response: Trigger.Response, message: str) -> Trigger.Response:
        """Operator actions are logged, and their effect on levels and halt is published at once."""
        self.get_logger().info(message)
        self._check_levels()
        self._publish_halt()
        response.success = True
        response.message = message
        return response

    def _on_acknowledge(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        """Silence the latched alarms the operator has seen; each stays shown, and halting, until a reset."""
        new, latched = self.supervisor.acknowledge()
        detail = "; ".join(f"{a}: {fault}" for a, fault in latched.items())
        if new:
            if self.alarm_log is not None:
                self.alarm_log.record("acknowledged", "", evidence={"detail": detail})
            return self._answer(response, f"acknowledged: {detail} (shown until a reset)")
        response.success = True
        response.message = f"acknowledged: {detail or 'no latched alarm'} (nothing new; shown until a reset)"
        return response

    def _on_reset(self, _request: Trigger.Request, response: Trigger.Response) -> Trigger.Response:
        before = "; ".join(f"{a}: {message}" for a, (_, message) in zip(self.monitor.actuators, self._levels)) or "no status yet"
        accepted, why_not, events = self.supervisor.reset(time.monotonic())
        if not accepted:
            response.success = False
            response.message = f"reset refused: {why_not}"
            self.get_logger().warning(response.message, throttle_duration_sec=1.0)
            return response
        self.monitor.reset()
        self._log_alarms(events)
        if self.alarm_log is not None:
            self.alarm_log.record("reset", "", evidence={"detail": before})
        return self._answer(response, f"filters, averages and latches reset (before: {before}); detection re-arms after "
                                      f"{self.monitor.settings.window_s:g} s of data, a latched fault stays shown until re-checked")

    def _simulated_healthy_machine(self) -> bool:
        """A short fault-free simulation of the first actuator, replayed on every actuator, through a fresh monitor of the
        same config: residuals within thresholds and no alarm. It depends on the config alone, so it runs once."""
        if self._simulated_check is None:
            from hydro_ros.sim.scenario import Scenario, run_blocks  # the monitor itself never needs the simulator

            probe = FdiMonitor(self.machine_config, self.monitor.method)
            n_act = len(probe.actuators)
            scenario = Scenario(probe.settings.window_s + 1.0, (), seed=0, actuator=probe.actuators[0])
            alarms = []
            for _, _, measured in run_blocks(self.machine_config, scenario):
                block = measured.as_columns()
                for name in PER_ACTUATOR:
                    if getattr(block, name) is not None:  # the other actuators replay the first one's samples
                        setattr(block, name, np.repeat(getattr(block, name), n_act, axis=1))
                result = probe.process(block)
                alarms += result.alarms
            converged = bool(np.all(np.abs(result.mean_residual[-1, 0]) < result.threshold[-1, 0]))
            self._simulated_check = converged and not alarms
        return self._simulated_check

    def _on_self_test(self, _request: SelfTest.Request, response: SelfTest.Response) -> SelfTest.Response:
        """The residual generator's own checks, a simulated healthy machine without alarm, sensor topics fresh."""
        # freshness is read at the request: the simulation below blocks this node's callbacks for a while
        n_act = len(self.monitor.actuators)
        fresh = [i for i in range(n_act) if not self._stale_topics(i)]
        checks = self.monitor.generator.self_check()
        checks.append(("residuals stay within thresholds on a simulated healthy machine, no alarm", self._simulated_healthy_machine()))
        checks.append((f"sensor topics fresh for {len(fresh)}/{n_act} actuators", len(fresh) == n_act))
        response.id = f"hydro_ros/fdi/{self.machine}"
        response.passed = bytes([all(ok for _, ok in checks)])  # `byte passed` in SelfTest.srv
        response.status = [
            DiagnosticStatus(level=bytes([0 if ok else 2]), name=f"hydro_ros/fdi/self_test/{name}", message="ok" if ok else "failed",
                             hardware_id=self.machine)
            for name, ok in checks
        ]
        return response


def main(args: list[str] | None = None) -> None:
    run_node(FdiNode, args)


if __name__ == "__main__":
    main()
