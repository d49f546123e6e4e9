"""The safety core's invariants on random event sequences (Hypothesis stateful tests).

Each machine keeps its own account of the world (which inputs are fresh, which faults exist, what the monitor has
latched, which messages were published and delivered) and checks the core's decisions against it after every step.
The account is written from the documented rules (hydro_ros/safety/*.py, docs/monitoring.md "The safety core"), not
from the core's internals, and liveness checks make sure a core that always halts (or never) fails too.
"""

from __future__ import annotations

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from hydro_ros.safety.motion import CLOCK_SKEW_S, HEARTBEAT_TIMEOUT_S, Heartbeat, MotionAuthority, ValveDeadman
from hydro_ros.safety.supervisor import ERROR, OK, WARN, ActuatorView, MonitorSupervisor

ACTUATORS = ("boom", "arm", "bucket")
REARM = 40  # samples the monitor needs to arm, and each actuator after a disturbance
RESET_INTERVAL = 5.0
SEVERE, MINOR = "spool_stuck_closed", "external_leakage_b"
# Hypothesis' sequences: 2500 + 2000 + 600 = 5100 per run of the fast tier
SUPERVISOR_RUNS, AUTHORITY_RUNS, DEADMAN_RUNS = 2500, 2000, 600
STEPS = 20

actuators = st.sampled_from(ACTUATORS)


class SupervisorMachine(RuleBasedStateMachine):
    """A simulated monitor of three actuators around a MonitorSupervisor, the alarm log kept by the test."""

    def __init__(self) -> None:
        super().__init__()
        self.now = 0.0
        self.log: dict[str, tuple[int, str]] = {}  # the alarm log: actuator -> (level, fault) latched
        self.supervisor = MonitorSupervisor(list(ACTUATORS), REARM, RESET_INTERVAL)
        self.fresh = dict.fromkeys(ACTUATORS, True)
        self.problem = dict.fromkeys(ACTUATORS, False)  # an invalid reading (NaN, out of range) in the next block
        self.overloaded = False
        self.irregular = False  # the samples' stamps irregular (safety.timing)
        self.outside = dict.fromkeys(ACTUATORS, False)  # the monitor's window outside what commissioning saw
        self.present: dict[str, str] = {}  # faults physically present: actuator -> fault
        self.latched: dict[str, str] = {}  # what the monitor has latched (until its reset)
        self.crossing = dict.fromkeys(ACTUATORS, False)  # a threshold crossing not yet latched
        self.seen = 0  # samples since the monitor's (re)start
        self.clean = dict.fromkeys(ACTUATORS, 0)  # the test's own count of valid samples since each disturbance
        self.severe_shown = dict.fromkeys(ACTUATORS, False)  # a severe fault shown, not yet cleared by reset + recheck
        self.reset_since = dict.fromkeys(ACTUATORS, False)  # an accepted reset since the severe fault was shown
        self.last_reset = -1e9
        self.unexplained = dict.fromkeys(ACTUATORS, True)

    # the world ---------------------------------------------------------------------------------------------------
    def _view(self, actuator: str, samples: int, invalid_at: int | None) -> ActuatorView:
        fault = self.latched.get(actuator)
        level = OK if fault is None else ERROR if fault == SEVERE else WARN
        armed = self.seen >= REARM
        return ActuatorView(
            fresh=self.fresh[actuator], overloaded=self.overloaded, timing="5% of the intervals off" if self.irregular else "",
            coverage="valve_command 0.95 outside 0..0.7" if self.outside[actuator] else "",
            sensor_problems=("pressure_a",) if invalid_at is not None else (),
            armed=armed, explained=armed and (fault is not None or not self.crossing[actuator]), fault=fault, fault_level=level,
            samples=samples, valid_tail=samples if invalid_at is None else samples - invalid_at - 1)

    def _record(self, events) -> None:
        for event in events:
            if event.event == "cleared":
                self.log.pop(event.actuator, None)
            else:
                self.log[event.actuator] = (event.level, event.fault)

    def _tick(self, samples: int, invalid_at: int | None) -> None:
        self.seen += samples
        views = {}
        for a in ACTUATORS:
            delivered = samples if self.fresh[a] else 0
            bad = invalid_at if (self.problem[a] and delivered) else None
            views[a] = self._view(a, delivered, bad)
            # the test's account of I1: what counts as clean data
            if not self.fresh[a] or self.overloaded or self.irregular or bad is not None:
                self.clean[a] = 0  # an invalid reading is shown (sensor_problems) for the block: nothing before it counts
            else:
                self.clean[a] += delivered
            self.problem[a] = False
        self._record(self.supervisor.observe(views))
        self.unexplained = {a: not views[a].explained for a in ACTUATORS}  # the evidence as last delivered (detection delay)
        for a in ACTUATORS:
            fault = self.latched.get(a)
            if fault == SEVERE:
                self.severe_shown[a], self.reset_since[a] = True, False
            elif self.severe_shown[a] and self.reset_since[a]:
                vouched = (self.fresh[a] and not self.overloaded and not self.irregular and not self.outside[a] and views[a].explained
                           and self.clean[a] >= REARM and not views[a].sensor_problems)
                if (fault not in (None, "unisolated")) or (fault is None and vouched):
                    self.severe_shown[a] = False  # re-checked after the reset: isolated anew, or vouched for without a fault

    def _monitor_detects(self) -> None:
        """The monitor latches a present fault once armed, on fresh data (unisolated first, then its cause)."""
        if self.seen < REARM or self.overloaded:
            return
        for a, fault in self.present.items():
            if not self.fresh[a]:
                continue
            if self.latched.get(a) is None:
                self.latched[a] = "unisolated"
            elif self.latched[a] == "unisolated":
                self.latched[a] = fault
            self.crossing[a] = False

    # rules -------------------------------------------------------------------------------------------------------
    @rule(samples=st.integers(1, 30), invalid_at=st.one_of(st.none(), st.integers(0, 29)), dt=st.floats(0.0, 0.5))
    def samples(self, samples: int, invalid_at: int | None, dt: float) -> None:
        self.now += dt
        self._monitor_detects()
        self._tick(samples, None if invalid_at is None else min(invalid_at, samples - 1))

    @rule(actuator=actuators)
    def gap(self, actuator: str) -> None:
        self.fresh[actuator] = False
        self._tick(0, None)

    @rule(actuator=actuators)
    def resume(self, actuator: str) -> None:
        self.fresh[actuator] = True

    @rule(actuator=actuators)
    def nan(self, actuator: str) -> None:
        self.problem[actuator] = True

    @rule(on=st.booleans())
    def overload(self, on: bool) -> None:
        self.overloaded = on
        self._tick(0, None)

    @rule(on=st.booleans())
    def timing(self, on: bool) -> None:
        self.irregular = on
        self._tick(0, None)

    @rule(actuator=actuators, on=st.booleans())
    def coverage(self, actuator: str, on: bool) -> None:
        self.outside[actuator] = on
        self._tick(0, None)

    @rule(forward=st.booleans())
    def time_jump(self, forward: bool) -> None:
        self.seen = 0  # the node restarts the filters on the new time base; latches stay
        self.supervisor.disturb(f"a time jump {'forward' if forward else 'back'}")
        self.clean = dict.fromkeys(ACTUATORS, 0)

    @rule(actuator=actuators, severe=st.booleans())
    def fault_appears(self, actuator: str, severe: bool) -> None:
        self.present[actuator] = SEVERE if severe else MINOR
        self.crossing[actuator] = True

    @rule(actuator=actuators)
    def fault_vanishes(self, actuator: str) -> None:
        self.present.pop(actuator, None)
        self.crossing[actuator] = False

    @rule(dt=st.floats(0.0, 10.0))
    def wait(self, dt: float) -> None:
        self.now += dt

    @rule()
    def acknowledge(self) -> None:
        before = (self.supervisor.halt(), [self.supervisor.state(a) for a in ACTUATORS])
        self.supervisor.acknowledge()
        # I4: an acknowledgement changes neither a level, a message nor the halt
        assert (self.supervisor.halt(), [self.supervisor.state(a) for a in ACTUATORS]) == before

    @rule()
    def reset(self) -> None:
        accepted, why_not, events = self.supervisor.reset(self.now)
        assert accepted == (self.now - self.last_reset >= RESET_INTERVAL), why_not
        if accepted:
            self.last_reset = self.now
            self._record(events)
            self.latched.clear()
            self.seen = 0
            self.clean = dict.fromkeys(ACTUATORS, 0)
            for a in ACTUATORS:
                self.reset_since[a] = True
                self.crossing[a] = a in self.present

    @rule(with_log=st.booleans())
    def restart(self, with_log: bool) -> None:
        """The node restarts: a new monitor (nothing latched, not armed), the log's latched faults restored or not."""
        restored = dict(self.log) if with_log else {}
        self.supervisor = MonitorSupervisor(list(ACTUATORS), REARM, RESET_INTERVAL, restored)
        self.latched.clear()
        self.seen = 0
        self.clean = dict.fromkeys(ACTUATORS, 0)
        self.last_reset = -1e9
        self.crossing = {a: a in self.present for a in ACTUATORS}
        for a in ACTUATORS:
            self.severe_shown[a] = with_log and restored.get(a, (OK, ""))[0] == ERROR
            self.reset_since[a] = False
        if not with_log:
            self.log.clear()

    # invariants --------------------------------------------------------------------------------------------------
    @invariant()
    def all_clear_only_when_vouched(self) -> None:  # I1
        halt = self.supervisor.halt()
        if not halt.halt:
            assert halt.kind == "clear"
            for a in ACTUATORS:
                assert self.fresh[a] and not self.overloaded and not self.irregular and not self.outside[a], a
                assert self.seen >= REARM and self.clean[a] >= REARM, (a, self.seen, self.clean[a])
                assert self.latched.get(a) != SEVERE and not self.severe_shown[a], a
                assert not self.unexplained[a], a

    @invariant()
    def severe_fault_halts_until_reset_and_recheck(self) -> None:  # I3
        halt = self.supervisor.halt()
        if any(self.severe_shown.values()):
            assert halt.halt and halt.kind == "fault", (halt, self.severe_shown)

    @invariant()
    def not_vouched_is_a_halt_with_its_reason(self) -> None:  # I2
        halt = self.supervisor.halt()
        assert halt.halt == (halt.kind != "clear") and halt.reason
        for a in ACTUATORS:
            state = self.supervisor.state(a)
            if not self.fresh[a] or self.overloaded or self.irregular or self.outside[a]:
                assert halt.halt and state.hold
                assert state.level != OK

    @invariant()
    def all_clear_when_everything_is_seen(self) -> None:  # liveness: a core that always halts fails here
        if (self.seen >= REARM and not self.overloaded and not self.irregular and not any(self.outside.values()) and not any(self.severe_shown.values())
                and all(self.fresh[a] and self.clean[a] >= REARM for a in ACTUATORS)
                and not any(self.unexplained.values()) and all(self.latched.get(a) in (None, MINOR) for a in ACTUATORS)):
            assert not self.supervisor.halt().halt, self.supervisor.halt()


class AuthorityMachine(RuleBasedStateMachine):
    """The monitor's heartbeats delivered late, out of order, replayed, latched to late joiners, spoofed."""

    def __init__(self) -> None:
        super().__init__()
        self.now = 10**12  # ns, system clock
        self.authority = MotionAuthority(require_monitor=True)
        self.clear = True  # the monitor's truth: vouching now
        self.unclear_since: int | None = None
        self.monitor_gid, self.sequence = b"monitor-1", 0
        self.published: list[Heartbeat] = []  # by the monitor, in order
        self.in_flight: list[Heartbeat] = []
        self.delivered: list[tuple[int, Heartbeat]] = []  # (arrival, message) at this executor

    def _deliver(self, beat: Heartbeat) -> None:
        self.authority.receive(beat, self.now)
        self.delivered.append((self.now, beat))

    @rule(dt_ms=st.integers(0, 700))
    def time_passes(self, dt_ms: int) -> None:
        self.now += dt_ms * 1_000_000

    @rule(clear=st.booleans())
    def monitor_state(self, clear: bool) -> None:
        if self.clear and not clear:
            self.unclear_since = self.now
        if clear:
            self.unclear_since = None
        self.clear = clear

    @rule(lost=st.booleans())
    def monitor_publishes(self, lost: bool) -> None:
        self.sequence += 1
        beat = Heartbeat(not self.clear, True, self.monitor_gid, self.sequence, self.now)
        self.published.append(beat)
        if not lost:
            self.in_flight.append(beat)

    @precondition(lambda self: self.in_flight)
    @rule(index=st.integers(0, 100))
    def deliver(self, index: int) -> None:  # in any order, any time after publication (late delivery)
        self._deliver(self.in_flight.pop(index % len(self.in_flight)))

    @precondition(lambda self: self.delivered)
    @rule(index=st.integers(0, 100))
    def replay(self, index: int) -> None:
        self._deliver(self.delivered[index % len(self.delivered)][1])

    @rule(halt=st.booleans(), stamp_offset_ms=st.integers(-2000, 2000), sequence=st.integers(0, 10**6))
    def spoofer(self, halt: bool, stamp_offset_ms: int, sequence: int) -> None:
        self._deliver(Heartbeat(halt, False, b"spoofer", sequence, self.now + stamp_offset_ms * 1_000_000))

    @rule(stamp_offset_ms=st.integers(-2000, 2000))
    def impostor_with_the_monitors_gid(self, stamp_offset_ms: int) -> None:
        """A message the graph cannot tell apart is not trusted (PinnedSource); only the sequence check remains."""
        self._deliver(Heartbeat(False, False, self.monitor_gid, self.sequence + 1, self.now + stamp_offset_ms * 1_000_000))

    @rule()
    def late_joiner(self) -> None:
        """A new executor: the latch hands it the monitor's last published message, whatever its age."""
        self.authority = MotionAuthority(require_monitor=True)
        self.delivered = []
        if self.published:
            self._deliver(self.published[-1])

    @rule()
    def monitor_restarts(self) -> None:
        self.monitor_gid, self.sequence = self.monitor_gid + b"'", 0

    @invariant()
    def motion_only_on_a_fresh_confirmation(self) -> None:  # M1
        if self.authority.why_not(self.now):
            return
        timeout, skew = int(HEARTBEAT_TIMEOUT_S * 1e9), int(CLOCK_SKEW_S * 1e9)
        firsts = {}  # a message delivered again (a replay) counts at its first delivery only
        for k, (_, b) in enumerate(self.delivered):
            firsts.setdefault((b.trusted, b.publisher, b.sequence, b.source_ns), k)
        confirmations = [k for k, (_, b) in enumerate(self.delivered) if firsts[(b.trusted, b.publisher, b.sequence, b.source_ns)] == k
                         and b.trusted and not b.halt and self.now - timeout <= b.source_ns <= self.now + skew]
        assert confirmations, "moving without a fresh confirmation from the monitor"
        assert not any(b.halt for _, b in self.delivered[confirmations[-1] + 1:]), "moving after a halt"

    @invariant()
    def stops_within_the_timeout_of_losing_sight(self) -> None:  # the end-to-end bound
        if self.unclear_since is not None and self.now > self.unclear_since + int(HEARTBEAT_TIMEOUT_S * 1e9):
            assert self.authority.why_not(self.now)

    @invariant()
    def moves_on_a_fresh_new_confirmation(self) -> None:  # liveness
        if self.delivered:
            _, last = self.delivered[-1]
            new = sum(1 for _, b in self.delivered if b.publisher == last.publisher and b.sequence == last.sequence) == 1
            newest = all(b.sequence < last.sequence for _, b in self.delivered[:-1] if b.publisher == last.publisher and b.trusted)
            if last.trusted and not last.halt and new and newest and 0 <= self.now - last.source_ns <= HEARTBEAT_TIMEOUT_S * 1e9:
                assert not self.authority.why_not(self.now), self.authority.why_not(self.now)


class DeadmanMachine(RuleBasedStateMachine):
    def __init__(self) -> None:
        super().__init__()
        self.now = 0.0
        self.deadman = ValveDeadman(["lift", "tilt"], timeout_s=0.2)
        self.last: dict[str, tuple[float, float]] = {}

    @rule(valve=st.sampled_from(["lift", "tilt", "unknown"]), value=st.floats(-1.0, 1.0))
    def command(self, valve: str, value: float) -> None:
        self.deadman.command({valve: value}, self.now)
        if valve != "unknown":
            self.last[valve] = (value, self.now)

    @rule(dt=st.floats(0.0, 0.5))
    def time_passes(self, dt: float) -> None:
        self.now += dt

    @invariant()
    def neutral_unless_fresh(self) -> None:  # D1, and its liveness
        for valve, output in self.deadman.outputs(self.now).items():
            value, at = self.last.get(valve, (0.0, -1e9))
            assert output == (value if self.now - at <= 0.2 else 0.0)


def _run(machine: type[RuleBasedStateMachine], examples: int) -> None:
    machine.TestCase.settings = settings(max_examples=examples, stateful_step_count=STEPS, deadline=None, database=None,
                                         suppress_health_check=[HealthCheck.too_slow])
    machine.TestCase().runTest()


def test_supervisor_invariants_on_random_sequences():
    _run(SupervisorMachine, SUPERVISOR_RUNS)


def test_motion_authority_invariants_on_random_sequences():
    _run(AuthorityMachine, AUTHORITY_RUNS)


def test_valve_deadman_on_random_sequences():
    _run(DeadmanMachine, DEADMAN_RUNS)


def test_sample_timing_holds_on_jittered_stamps_not_on_lost_samples():
    import numpy as np

    from hydro_ros.safety.timing import SampleTiming

    rng = np.random.default_rng(0)
    period = 1_000_000  # ns, 1 kHz
    timing = SampleTiming(1e-3, window=1000)
    regular = np.arange(5000) * period
    regular = np.delete(regular, [100, 101, 102, 2500])  # lost samples: gaps of whole periods, not a timing fault
    for block in np.array_split(regular, 50):
        assert timing.observe(block) == ""
    # arrival times of a loaded host: 15 % of intervals under 0.2 ms
    start = regular[-1] + period
    jittered = start + np.arange(2000) * period + rng.uniform(0, 1.5e6, 2000).astype(np.int64)
    problems = [timing.observe(block) for block in np.array_split(np.sort(jittered), 20)]
    assert "off the 1 ms period" in problems[-1]
    # regular again: held for a whole window more (no chatter), then clear
    start = jittered[-1] + 2 * period
    after = [timing.observe(block) for block in np.array_split(start + np.arange(3000) * period, 30)]
    assert after[0] and after[5] and after[-1] == ""
