"""The machine's clock for a bus's sensor cycles: stamps at the bus's regular period, not at the host's arrival times.

A sensor ECU samples at a fixed period; its frames reach the host late by a varying amount (arbitration, the ECU's
scheduling, the host's load). Stamped with arrival times, a joint rate differentiated from the angle is off by the
jitter (1-5 % measured on a loaded host, the size of what commissioning corrects). :class:`CycleClock` numbers the
cycles and stamps cycle ``n`` at ``t0 + n * period``; the phase and period follow the *earliest* arrivals (a frame is
never early, only late), so the lower envelope of the arrival times is the clock:

- locking: for the first block after a start or re-lock the clock's phase steps back to any earlier arrival (the
  envelope is found) and the cycles are stamped at the nominal period from the first arrival (one step at the
  lock, not a block of jitter; after a block that broke the lock, at their arrival times); then the period starts at
  the bus's nominal one and is trimmed by a phase-locked loop on each block's smallest latency (an ECU's oscillator drifts by tens of ppm):
  every ``block`` cycles part of that smallest latency is slewed out over the next block (never a step:
  a step would be a spike in a derived rate) and a share of it goes into the period (SLEW_GAIN,
  TRIM_GAIN: the smallest rate error over jittered and bursty arrivals, test_can_clock.py);
- the cycle-numbering rule: with a rolling counter a cycle is as many periods after the last one as its counter
  advanced (mod 16); without one, a cycle is the next one unless it arrives later than the next slot plus
  ``latency_limit``, then the slots it cannot belong to count as lost. A run of lost cycles that arrive inside the
  limit shows as a block whose smallest latency is half a period or more: the cycles are renumbered (counted as
  lost) there. A late cycle and a lost one are told apart up to the limit;
- after a silence of ``relock_after_s``, a step back in arrival time, or a block that arrived half a period or more
  *before* the clock (cycles counted lost that were only late), the clock re-locks.

The latency above the envelope is the bus's jitter. While a block's largest latency exceeds the limit on a bus without
counters (numbering is then uncertain) the clock is not locked and :meth:`CycleClock.stamp` gives arrival
times, so that a monitor that checks the regularity of its sample times holds rather than trusts them. Stamps only
increase.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

COUNTER_MODULO = 16
BLOCK_CYCLES = 200
PERIOD_TRIM_MAX = 5e-3  # an oscillator is off by tens of ppm; a trim beyond 0.5 % is not a clock
RELOCK_AFTER_S = 1.0
SLEW_GAIN, TRIM_GAIN = 0.5, 0.1  # of a block's smallest latency: slewed out over the next block, and into the period


@dataclass(frozen=True)
class ClockHealth:
    """The clock over its last full block."""

    jitter_p99_s: float  # 99th percentile of the arrival latency above the envelope
    jitter_max_s: float
    drift_ppm: float  # the trimmed period against the nominal one
    lost_cycles: int  # since the start
    relocks: int  # since the start
    locked: bool

    def values(self) -> dict[str, str]:
        return {"jitter_p99_ms": f"{self.jitter_p99_s * 1e3:.3f}", "jitter_max_ms": f"{self.jitter_max_s * 1e3:.3f}",
                "drift_ppm": f"{self.drift_ppm:.0f}", "lost_cycles": str(self.lost_cycles), "relocks": str(self.relocks),
                "clock_locked": str(self.locked)}


class CycleClock:
    """Stamps of a bus's sensor cycles on the machine's clock (see the module)."""

    def __init__(self, period_s: float, latency_limit_s: float, *, block: int = BLOCK_CYCLES,
                 relock_after_s: float = RELOCK_AFTER_S) -> None:
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"clock period {period_s!r} s: must be a positive number")
        if not (math.isfinite(latency_limit_s) and latency_limit_s > 0):
            raise ValueError(f"clock latency limit {latency_limit_s!r} s: must be a positive number")
        self.nominal_ns = period_s * 1e9
        self.limit_ns = latency_limit_s * 1e9
        self.block = block
        self.relock_ns = max(relock_after_s * 1e9, 2 * self.limit_ns)
        self.trim_ns = 0.0  # period correction, per cycle
        self.slew_ns = 0.0  # phase correction spread over the current block, per cycle
        self.phase_ns: float | None = None  # the machine-clock time of the last cycle
        self.acquiring = True  # the first block after a (re-)lock: the phase follows the earliest arrival
        self.origin_ns, self.count = 0, 0  # the first arrival after a (re-)lock, and the cycles counted since
        self.fresh_start = True
        self.last_arrival = 0
        self.last_counter: int | None = None
        self.last_stamp = -1
        self.lost = 0
        self.relocks = 0
        self._latencies: list[float] = []
        self.health = ClockHealth(0.0, 0.0, 0.0, 0, 0, False)

    @property
    def period_ns(self) -> float:
        return self.nominal_ns + self.trim_ns

    def stamp(self, arrival_ns: int, counter: int | None = None) -> int:
        """The stamp of a cycle whose first frame arrived at ``arrival_ns`` (its rolling counter, if any): the machine's
        clock while locked, else the arrival time; never before the last stamp."""
        if self.phase_ns is None or arrival_ns - self.last_arrival > self.relock_ns or arrival_ns < self.last_arrival - self.limit_ns:
            self._relock(arrival_ns, counter, fresh=True)
        else:
            step = self.period_ns + self.slew_ns
            if counter is not None and self.last_counter is not None:
                advance = (counter - self.last_counter) % COUNTER_MODULO or COUNTER_MODULO
            else:
                beyond = arrival_ns - (self.phase_ns + step) - self.limit_ns
                advance = 1 + max(0, math.ceil(beyond / step))
            self.lost += advance - 1
            self.count += advance
            self.phase_ns += advance * step
            self.last_arrival, self.last_counter = max(self.last_arrival, arrival_ns), counter
            if self.acquiring and arrival_ns < self.phase_ns:
                self.phase_ns = float(arrival_ns)
            self._latencies.append(arrival_ns - self.phase_ns)
            if len(self._latencies) >= self.block:
                self._close_block(arrival_ns, counter)
        if self.health.locked:
            stamp = int(round(self.phase_ns))
        elif self.acquiring and self.fresh_start:  # the nominal period from the first arrival: one step at the lock
            stamp = int(round(self.origin_ns + self.count * self.nominal_ns))
        else:
            stamp = int(arrival_ns)
        self.last_stamp = max(stamp, self.last_stamp + 1)
        return self.last_stamp

    def _relock(self, arrival_ns: int, counter: int | None, fresh: bool) -> None:
        """Lock anew on this arrival; ``fresh`` after a start or a silence, not after a block that broke the lock (until a
        block is good again those cycles keep their arrival times)."""
        if self.phase_ns is not None:
            self.relocks += 1
        self.fresh_start = fresh
        self.phase_ns, self.slew_ns, self._latencies, self.acquiring = float(arrival_ns), 0.0, [], True
        self.origin_ns, self.count = arrival_ns, 0
        self.last_arrival, self.last_counter = arrival_ns, counter
        self.health = replace(self.health, lost_cycles=self.lost, relocks=self.relocks, locked=False)

    def _close_block(self, arrival_ns: int, counter: int | None) -> None:
        counted = counter is not None
        latencies = np.asarray(self._latencies)
        self._latencies = []
        envelope = float(latencies.min())
        if envelope <= -0.5 * self.period_ns:  # arrived before the clock: cycles counted lost were only late
            self._relock(arrival_ns, counter, fresh=False)
            return
        # lost cycles: with counters only whole turns of the counter can go unseen, without them any number
        turn = COUNTER_MODULO if counted else 1
        whole = turn * math.floor(envelope / (turn * self.period_ns) + 0.5)
        if whole:  # cycles lost inside the latency limit: the whole block arrived a period late or more
            self.lost += whole
            self.phase_ns += whole * self.period_ns
            envelope -= whole * self.period_ns
            latencies -= whole * self.period_ns
        if not self.acquiring:
            bound = PERIOD_TRIM_MAX * self.nominal_ns
            self.trim_ns = min(max(self.trim_ns + TRIM_GAIN * envelope / self.block, -bound), bound)
            self.slew_ns = SLEW_GAIN * envelope / self.block
        self.acquiring = False
        above = latencies - envelope
        p99 = float(np.percentile(above, 99))
        # numbered by their counters, cycles that arrive in bursts (a sender that writes ten at a time) stay on their
        # slots: only without counters does a latency beyond the limit make the numbering uncertain
        self.health = ClockHealth(p99 * 1e-9, float(above.max()) * 1e-9, self.trim_ns / self.nominal_ns * 1e6, self.lost,
                                  self.relocks, counted or float(above.max()) <= self.limit_ns)
