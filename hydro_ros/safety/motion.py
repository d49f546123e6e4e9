"""Authority to move: the executor's heartbeat rule and the valve deadman of every consumer of valve commands.

Timing, in one place (docs/monitoring.md "The safety core"):

- the monitor publishes ``/fdi/halt`` every ``HEARTBEAT_PERIOD_S`` and at once on every change;
- :class:`MotionAuthority` lets the executor move only on a ``false`` from the trusted monitor whose *source* stamp is
  at most ``HEARTBEAT_TIMEOUT_S`` old, newer than any heartbeat taken before from that publisher, and with no ``true``
  (from anyone) received since. A latched sample replayed to a late joiner, a message delivered late, a replayed or
  spoofed one never authorises motion. The executor stops (neutral) within ``HEARTBEAT_TIMEOUT_S`` plus one control
  period of the monitor's last confirmation, and at its next control step after a ``true``;
- :class:`ValveDeadman` sends a valve neutral when its last command is older than ``VALVE_COMMAND_TIMEOUT_S``
  (can_bridge, plant_sim, crane_sim: one default, each node's ``command_timeout`` parameter).

Invariants, tested on random event sequences (test/test_safety_core.py):

M1  ``why_not`` is "" at time t only if the last heartbeat taken came from the trusted monitor, said ``false``, was
    stamped within ``[t - timeout, t + skew]``, and no ``true`` arrived after it.
M2  A message never moves the authority from "stop" to "move" unless it is a fresh, new ``false`` from the trusted monitor.
D1  A valve's output is non-neutral at t only if its last command arrived within ``[t - timeout, t]`` and is that value.
"""

from __future__ import annotations

from dataclasses import dataclass

HEARTBEAT_PERIOD_S = 0.1  # /fdi/halt is re-published this often
HEARTBEAT_TIMEOUT_S = 0.5  # a confirmation older than this (by its source stamp) does not authorise motion
CLOCK_SKEW_S = 0.05  # a source stamp this far in the receiver's future is still taken (clocks of one host, or chrony-synced)
VALVE_COMMAND_TIMEOUT_S = 0.2  # a valve whose last command is older than this is commanded neutral


@dataclass(frozen=True)
class Heartbeat:
    """A ``/fdi/halt`` message as received: its value, whether it came from the trusted monitor, its publisher, the
    publisher's sequence number (0: the middleware gives none) and its source stamp [ns, system clock]."""

    halt: bool
    trusted: bool
    publisher: bytes
    sequence: int
    source_ns: int


class MotionAuthority:
    def __init__(self, require_monitor: bool = True, timeout_s: float = HEARTBEAT_TIMEOUT_S, skew_s: float = CLOCK_SKEW_S) -> None:
        self.require_monitor = require_monitor
        self.timeout_ns = int(timeout_s * 1e9)
        self.skew_ns = int(skew_s * 1e9)
        self.halted = False  # a true was received and no confirmation has come after it
        self.halt_reason = ""
        self.confirmed_ns: int | None = None  # source stamp of the last heartbeat taken from the monitor
        self._sequence: dict[bytes, int] = {}  # publisher -> the last sequence number taken from it
        self.refused: dict[str, int] = {}  # why -> heartbeats not taken

    def receive(self, beat: Heartbeat, now_ns: int) -> str:
        """Take one /fdi/halt message at ``now_ns`` (system clock); returns why it was not taken as a heartbeat, or ""."""
        if beat.halt:
            # a halt from anyone stops motion; only a confirmation from the monitor resumes it
            self.halted = True
            self.halt_reason = "halt requested on /fdi/halt" + ("" if beat.trusted else " (not by the monitor)")
            return "" if beat.trusted else self._refuse("a halt from another node: it stops, but cannot confirm")
        if not beat.trusted:
            return self._refuse("a false from a node other than the monitor")
        age = now_ns - beat.source_ns
        if age > self.timeout_ns:
            return self._refuse(f"a false stamped {age * 1e-9:.2f} s ago (latched, replayed or delivered late)")
        if age < -self.skew_ns:
            return self._refuse(f"a false stamped {-age * 1e-9:.2f} s in the future")
        last = self._sequence.get(beat.publisher)
        if beat.sequence and last is not None and beat.sequence <= last:
            return self._refuse("a false with a sequence number already taken (a replay)")
        if self.confirmed_ns is not None and beat.source_ns < self.confirmed_ns and not beat.sequence:
            return self._refuse("a false older than the last heartbeat taken")
        self._sequence[beat.publisher] = beat.sequence
        self.confirmed_ns = beat.source_ns
        self.halted = False
        return ""

    def why_not(self, now_ns: int) -> str:
        """Why the machine may not move at ``now_ns`` (system clock); "" when it may."""
        if self.halted:
            return self.halt_reason
        if not self.require_monitor:
            return ""
        if self.confirmed_ns is None:
            return "no heartbeat from the condition monitor on /fdi/halt (require_monitor)"
        age = now_ns - self.confirmed_ns
        if age > self.timeout_ns:
            return f"condition monitor silent for {age * 1e-9:.2f} s (require_monitor)"
        if age < -self.skew_ns:
            return "the monitor's last heartbeat is stamped in the future (clock stepped back)"
        return ""

    def clear_halt(self) -> None:
        """An operator's lifecycle action (deactivate) clears a halt; motion still needs a fresh heartbeat."""
        self.halted = False
        self.confirmed_ns = None

    def _refuse(self, why: str) -> str:
        kind = why.split(" stamped")[0]  # counted by kind, without the age
        self.refused[kind] = self.refused.get(kind, 0) + 1
        return why


class ValveDeadman:
    """The last command of each valve, and neutral for every valve whose command is older than the timeout."""

    def __init__(self, valves: list[str], timeout_s: float = VALVE_COMMAND_TIMEOUT_S) -> None:
        self.valves = list(valves)
        self.timeout_s = float(timeout_s)
        self._last: dict[str, tuple[float, float]] = {}  # valve -> (command, arrival time [s, monotonic])

    def command(self, commands: dict[str, float], now_s: float) -> None:
        for valve, value in commands.items():
            if valve in self.valves:
                self._last[valve] = (float(value), now_s)

    def neutral(self, valves: list[str] | None = None) -> None:
        """Forget the commands of ``valves`` (all by default): they stay neutral until the next command."""
        for valve in self.valves if valves is None else valves:
            self._last.pop(valve, None)

    def expired(self, now_s: float) -> list[str]:
        """Valves that had a command and whose last one is now older than the timeout."""
        return [v for v, (_, at) in self._last.items() if now_s - at > self.timeout_s]

    def fresh(self, now_s: float) -> bool:
        """Whether any valve's command is fresh (False: every valve held neutral by the deadman)."""
        return any(0.0 <= now_s - at <= self.timeout_s for _, at in self._last.values())

    def outputs(self, now_s: float) -> dict[str, float]:
        """Every valve's command at ``now_s``: the last one while it is fresh, neutral (0) otherwise."""
        out = {}
        for valve in self.valves:
            value, at = self._last.get(valve, (0.0, -float("inf")))
            out[valve] = value if 0.0 <= now_s - at <= self.timeout_s else 0.0
        return out
