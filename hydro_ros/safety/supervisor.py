"""The monitor's supervisor: which actuators it vouches for, which alarms stay latched, and what ``/fdi/halt`` says.

fdi_node feeds it what the monitor knows after each processing tick (:class:`ActuatorView` per actuator) and the
events around it (a time jump or restart of the filters, an operator's acknowledgement or reset); it answers with each
actuator's level and message, the alarm-log events and the halt decision (:class:`Halt`). It holds no ROS object and
no monitor, so its invariants are tested on random event sequences (test/test_safety_core.py):

I1  "All clear" (halt false) only while every actuator is vouched: its inputs fresh, not overloaded, regularly
    timed, inside what commissioning saw, every reading valid, the monitor armed and its evidence explained, and at least ``rearm_samples`` valid
    samples evaluated since the actuator's last disturbance (a gap in its inputs, an invalid reading, an overload,
    irregular sample times, a time jump, a restart or reset of the filters, the node's own start). A first sample after a gap is never "all clear".
I2  Not vouched is a halt (``kind`` "hold", with the reason): the absence of confirmation trips, so a late subscriber
    of the latched ``/fdi/halt`` reads ``true`` from a blind monitor.
I3  A severe fault (latched by the monitor, restored from the alarm log after a restart, or held through a reset) is
    a halt (``kind`` "fault") until an accepted reset, at most one per ``reset_min_interval_s``, and a clean recheck:
    the re-armed monitor has isolated the actuator's fault again or vouches for it without one.
I4  An acknowledgement silences (it is shown) and never clears a fault or changes the halt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

OK, WARN, ERROR, STALE = 0, 1, 2, 3  # diagnostic_msgs/DiagnosticStatus levels
UNISOLATED = "unisolated"  # contract.names.Fault.UNISOLATED: a fault detected, its cause not yet known


@dataclass(frozen=True)
class ActuatorView:
    """What the monitor knows of one actuator after a processing tick (the defaults: nothing seen yet, blind)."""

    fresh: bool = False  # every input topic of the actuator arrived within the stale timeout
    overloaded: bool = False  # samples arrive incomplete: the input outruns the node
    timing: str = ""  # why the samples' stamps are not regular enough to trust ("" while they are: safety.timing)
    coverage: str = ""  # why the monitor's window lies outside what commissioning saw ("" while inside: fdi.coverage)
    sensor_problems: tuple[str, ...] = ()  # readings invalid within the health hold time (the supply is substituted, not here)
    armed: bool = False  # the monitor has evaluated a full window since its start, reset or restart
    explained: bool = False  # armed, and its evidence explained: a fault latched or no threshold crossing now
    fault: str | None = None  # the monitor's latched fault (a contract fault name), None while there is none
    fault_level: int = OK  # WARN for a minor fault, ERROR for a severe one
    samples: int = 0  # samples of this actuator evaluated in this tick
    valid_tail: int = 0  # of them, how many at the end were valid (== samples: all valid)


@dataclass(frozen=True)
class Held:
    """A fault shown although the monitor has not (re-)isolated it."""

    level: int
    fault: str
    rechecking: bool  # held through a reset until re-checked; False: restored from the alarm log, until a reset


@dataclass(frozen=True)
class ActuatorState:
    level: int
    message: str  # the fault name, "ok", or why it is not monitored: "stale", "overloaded", "not_monitored"
    hold: str  # why the monitor does not vouch for it ("" while it does)


@dataclass(frozen=True)
class Halt:
    """The halt output: ``kind`` "clear" (halt false), "hold" (not vouched: paused) or "fault" (a severe fault: stop)."""

    halt: bool
    kind: str
    reason: str


@dataclass(frozen=True)
class AlarmEvent:
    """A change of an actuator's latched fault, for the alarm log: raised, changed or cleared."""

    event: str
    actuator: str
    fault: str  # the fault now (or, when cleared, the one before)
    before: str
    level: int


class MonitorSupervisor:
    def __init__(self, actuators: list[str], rearm_samples: int, reset_min_interval_s: float,
                 restored: dict[str, tuple[int, str]] | None = None) -> None:
        """``restored``: actuator -> (level, fault) latched before a restart (the alarm log); shown until a reset."""
        self.actuators = list(actuators)
        self.rearm_samples = int(rearm_samples)
        self.reset_min_interval_s = float(reset_min_interval_s)
        self.views = {a: ActuatorView() for a in self.actuators}
        self.clean = dict.fromkeys(self.actuators, 0)  # valid samples evaluated since the last disturbance
        self.disturbance = dict.fromkeys(self.actuators, "the start")  # what the actuator re-arms from
        self.held = {a: Held(level, fault, False) for a, (level, fault) in (restored or {}).items() if a in self.views}
        self.acknowledged: dict[str, str] = {}  # actuator -> the fault the operator acknowledged (silenced, still shown)
        self.last_reset = -math.inf
        self._logged = {a: held.fault for a, held in self.held.items()}

    # inputs -------------------------------------------------------------------------------------------------------
    def observe(self, views: dict[str, ActuatorView]) -> list[AlarmEvent]:
        """One processing tick's views (every actuator); returns the alarm-log events it caused."""
        for actuator, view in views.items():
            self.views[actuator] = view
            why = self._disturbed(view)
            if why:
                self._disturb(actuator, why)
            elif view.valid_tail < view.samples:
                self._disturb(actuator, "an invalid reading")
                self.clean[actuator] = view.valid_tail
            else:
                self.clean[actuator] += view.samples
        self._release_rechecked()
        for actuator in self.actuators:
            if self.acknowledged.get(actuator) not in (None, self.latched(actuator)):
                del self.acknowledged[actuator]  # a new fault is a new alarm: it is heard again
        return self._alarm_events()

    def disturb(self, reason: str) -> None:
        """Every actuator re-arms from now: the filters restarted (time jump, restart)."""
        for actuator in self.actuators:
            self._disturb(actuator, reason)

    def acknowledge(self) -> tuple[bool, dict[str, str]]:
        """Silence the latched faults: (whether any was new, actuator -> fault). Changes no level and no halt."""
        latched = {a: self.latched(a) for a in self.actuators if self.latched(a)}
        new = bool(latched.items() - self.acknowledged.items())
        self.acknowledged.update(latched)
        return new, latched

    def reset(self, now_s: float) -> tuple[bool, str, list[AlarmEvent]]:
        """The operator's reset at ``now_s`` (a monotonic clock): (accepted, why not, events). Accepted, every fault
        latched now stays shown (rechecking) and every actuator re-arms; the caller resets the monitor's filters and latches."""
        since = now_s - self.last_reset
        if since < self.reset_min_interval_s:
            return False, f"the last one was {since:.1f} s ago (at most one per {self.reset_min_interval_s:g} s)", []
        self.last_reset = now_s
        self.held = {a: Held(self.state(a).level, self.latched(a), True) for a in self.actuators if self.latched(a)}
        self.acknowledged.clear()
        for actuator in self.actuators:
            # the monitor's latches are cleared by the reset: what it showed lives on in held
            self.views[actuator] = replace(self.views[actuator], fault=None, fault_level=OK, armed=False, explained=False)
        self.disturb("a reset")
        return True, "", self._alarm_events()

    # outputs ------------------------------------------------------------------------------------------------------
    def latched(self, actuator: str) -> str:
        """The fault shown for the actuator ("" when none): the monitor's, else one held from the log or through a reset."""
        view, held = self.views[actuator], self.held.get(actuator)
        if view.fault is not None and not (held is not None and view.fault == UNISOLATED):
            return view.fault
        return held.fault if held is not None else ""

    def hold(self, actuator: str) -> str:
        """Why the monitor does not vouch for the actuator now; "" while it does."""
        view = self.views[actuator]
        if not view.fresh:
            return "inputs stale"
        if view.overloaded:
            return "overloaded: samples arrive incomplete"
        if view.timing:
            return f"timing: {view.timing}"
        if view.coverage:
            return f"outside the commissioned range: {view.coverage}"
        if view.sensor_problems:
            return f"invalid readings: {', '.join(view.sensor_problems)}"
        if not view.armed or self.clean[actuator] < self.rearm_samples:
            return f"re-arming after {self.disturbance[actuator]}"
        if not view.explained:
            return "a threshold crossing not yet explained"
        return ""

    def vouched(self, actuator: str) -> bool:
        return not self.hold(actuator)

    def severe(self, actuator: str) -> bool:
        view, held = self.views[actuator], self.held.get(actuator)
        return (view.fault is not None and view.fault_level == ERROR) or (held is not None and held.level == ERROR)

    def state(self, actuator: str) -> ActuatorState:
        """Level and message: a latched or held fault first, then why it is not (fully) monitored."""
        view, held, hold = self.views[actuator], self.held.get(actuator), self.hold(actuator)
        if view.fault is not None and not (held is not None and view.fault == UNISOLATED):
            return ActuatorState(view.fault_level, view.fault, hold)
        if held is not None:
            return ActuatorState(max(held.level, view.fault_level if view.fault else OK), held.fault, hold)
        if not view.fresh:
            return ActuatorState(STALE, "stale", hold)
        if view.overloaded:
            return ActuatorState(WARN, "overloaded", hold)
        return ActuatorState(STALE, "not_monitored", hold) if hold else ActuatorState(OK, "ok", "")

    def halt(self) -> Halt:
        severe = [f"{a}: {self.latched(a)}" for a in self.actuators if self.severe(a)]
        if severe:
            return Halt(True, "fault", f"stop: severe fault ({'; '.join(severe)})")
        holds = [f"{a}: {self.hold(a)}" for a in self.actuators if self.hold(a)]
        if holds:
            return Halt(True, "hold", f"paused: monitor not vouching ({'; '.join(holds)})")
        return Halt(False, "clear", "all clear")

    # internals ----------------------------------------------------------------------------------------------------
    @staticmethod
    def _disturbed(view: ActuatorView) -> str:
        if not view.fresh:
            return "a gap in its inputs"
        if view.overloaded:
            return "an overload"
        if view.timing:
            return "irregular sample times"
        if view.sensor_problems:
            return "an invalid reading"
        return ""  # a restart of the filters (not armed) is disturbed by the caller, when it restarts them

    def _disturb(self, actuator: str, reason: str) -> None:
        self.clean[actuator] = 0
        self.disturbance[actuator] = reason

    def _release_rechecked(self) -> None:
        """A fault held through a reset is dropped once the re-armed monitor has isolated one again, or vouches for the
        actuator without one."""
        for actuator in list(self.held):
            held, view = self.held[actuator], self.views[actuator]
            if held.rechecking and ((view.fault is not None and view.fault != UNISOLATED)
                                    or (view.fault is None and self.vouched(actuator))):
                del self.held[actuator]

    def _alarm_events(self) -> list[AlarmEvent]:
        events = []
        for actuator in self.actuators:
            before, now = self._logged.get(actuator, ""), self.latched(actuator)
            if now != before:
                kind = "cleared" if not now else "changed" if before else "raised"
                events.append(AlarmEvent(kind, actuator, now or before, before, self.state(actuator).level if now else OK))
                self._logged[actuator] = now
        return events
