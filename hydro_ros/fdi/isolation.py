"""Fault isolation by residual-sign patterns: P-II Table 3 and its procedure (P-II Section 3.5).

A pattern code packs the four threshold-crossing flags as bits (r_pA up, r_pA down, r_pB up,
r_pB down), written like the paper's columns: "0110" = r_pA below its negative threshold and r_pB
above its positive one. Each observation (code, pA > pB, both residuals large, valve-command
sign) selects the table rows it matches; the candidate set is intersected over successive
observations, which is the paper's ambiguity resolution: after the valve command changes sign a
valve fault flips its pattern while an internal leak keeps it, so only one cause survives.

A method may add the crossing code of its residuals over the samples at which the valve was closed
(``closed_code``: :meth:`hydro_ros.fdi.residuals.ParityResiduals.closed_code`). A row with ``closed``
codes (those its fault was seen to make while closed) matches an observation only with one of them; an
observation without a closed code (too few closed samples yet, or a method without the evidence) matches
every row, and one of a single chamber (the other masked: cavitating at rest) is compared on that chamber
alone. Towards partial patterns a closed crossing counts like a main one: a row is compatible where
its closed codes together contain every closed crossing seen. So a crossing while the valve is closed,
which a fault acting only through the metering valve cannot make, overrules an earlier cause that lacks
it, and a quiet closed window (a leak too small to cross at rest) does not.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.names import Fault

A_UP, A_DOWN, B_UP, B_DOWN = 8, 4, 2, 1
NO_CLOSED_CODE = -1  # a closed code not known (too few closed-valve samples yet, or no evidence of the kind)
JUDGED_A, JUDGED_B = 16, 32  # a closed code's flags: the chamber had enough closed-valve samples to judge (masked otherwise)


def closed_parts(closed_code: int) -> tuple[int, int]:
    """(crossing bits, bits of the judged chambers) of a closed code: a chamber not judged has no crossing, known or not."""
    judged = (A_UP | A_DOWN if closed_code & JUDGED_A else 0) | (B_UP | B_DOWN if closed_code & JUDGED_B else 0)
    return closed_code & judged, judged


def code_string(code: int) -> str:
    return format(code, "04b")


def crossing_code(mean_residual: np.ndarray, threshold: np.ndarray) -> np.ndarray:
    """(..., 2) mean residuals against +-threshold -> the crossing pattern bits of the signature tables (int8)."""
    return (
        A_UP * (mean_residual[..., 0] > threshold[..., 0])
        + A_DOWN * (mean_residual[..., 0] < -threshold[..., 0])
        + B_UP * (mean_residual[..., 1] > threshold[..., 1])
        + B_DOWN * (mean_residual[..., 1] < -threshold[..., 1])
    ).astype(np.int8)


@dataclass(frozen=True)
class PatternRow:
    """One row of a signature table; None is the paper's "0/1" (don't care)."""

    fault: Fault
    code: int
    pa_gt_pb: bool | None = None
    large: bool | None = None
    command_positive: bool | None = None
    closed: frozenset[int] | None = None  # the crossing codes over closed-valve samples the fault makes; None: any

    def matches(self, code: int, pa_gt_pb: bool, large: bool, direction: int, closed_code: int | None = None) -> bool:
        if code != self.code:
            return False
        if self.closed is not None and closed_code is not None:
            bits, judged = closed_parts(closed_code)
            if not any(closed & judged == bits for closed in self.closed):
                return False
        if self.pa_gt_pb is not None and self.pa_gt_pb != pa_gt_pb:
            return False
        if self.large is not None and self.large != large:
            return False
        return not (self.command_positive is not None and direction != 0 and self.command_positive != (direction > 0))

    def contains(self, code: int, closed_code: int | None) -> bool:
        """Whether the row's patterns contain every crossing seen: a partial pattern on its way to this row's."""
        if self.code & code != code:
            return False
        if self.closed is None or closed_code is None:
            return True
        bits, _ = closed_parts(closed_code)
        every = 0
        for closed in self.closed:
            every |= closed
        return every & bits == bits


# P-II Table 3, rows 1-10, plus the simultaneous A+B leak of the fault tree (INFERRED row: both
# residuals negative). Rows 3/4 (internal A->B / B->A) both map to the contract's
# internal_leakage; the valve rows keep the paper's case 1 / case 2 split by command sign.
UKF_TABLE: tuple[PatternRow, ...] = (
    PatternRow(Fault.EXTERNAL_LEAKAGE_A, A_DOWN, large=False),
    PatternRow(Fault.EXTERNAL_LEAKAGE_B, B_DOWN, large=False),
    PatternRow(Fault.EXTERNAL_LEAKAGE_AB, A_DOWN | B_DOWN),
    PatternRow(Fault.INTERNAL_LEAKAGE, A_DOWN | B_UP, pa_gt_pb=True, large=False),
    PatternRow(Fault.INTERNAL_LEAKAGE, A_UP | B_DOWN, pa_gt_pb=False, large=False),
    PatternRow(Fault.SPOOL_TOO_SMALL_OPENING, A_DOWN | B_UP, large=False, command_positive=True),
    PatternRow(Fault.SPOOL_TOO_SMALL_OPENING, A_UP | B_DOWN, large=False, command_positive=False),
    PatternRow(Fault.SPOOL_TOO_LARGE_OPENING, A_UP | B_DOWN, large=False, command_positive=True),
    PatternRow(Fault.SPOOL_TOO_LARGE_OPENING, A_DOWN | B_UP, large=False, command_positive=False),
    PatternRow(Fault.SPOOL_STUCK_CLOSED, A_DOWN | B_UP, large=True, command_positive=True),
    PatternRow(Fault.SPOOL_STUCK_CLOSED, A_UP | B_DOWN, large=True, command_positive=False),
)


def signature_rows(entries: list[dict]) -> tuple[PatternRow, ...]:
    """Rows from config entries {fault, code: "0110", pa_gt_pb, large, command_positive, closed: ["0000", "0010"]} (null
    or absent = X)."""
    if not isinstance(entries, list):
        raise InputError(f"fdi.parity_signatures: {entries!r}: expected a list of entries")
    rows = []
    for entry in entries:
        if not isinstance(entry, dict):
            raise InputError(f"fdi.parity_signatures: bad entry {entry!r}: expected a mapping (fault, code, ...)")
        try:
            closed = entry.get("closed")
            rows.append(PatternRow(Fault(entry["fault"]), _code_bits(entry["code"]), entry.get("pa_gt_pb"),
                                   entry.get("large"), entry.get("command_positive"),
                                   None if closed is None else frozenset(_code_bits(c) for c in closed)))
        except (KeyError, TypeError, ValueError, OverflowError) as exc:
            raise InputError(f"fdi.parity_signatures: bad entry {entry!r} ({exc})") from None
    return tuple(rows)


def _code_bits(code: str | int | float) -> int:
    # the config loader turns numeric-looking strings into numbers: "0110" arrives as 110.0
    text = str(int(code)) if isinstance(code, (int, float)) else str(code)
    return int(text, 2)


def matching_faults(table: tuple[PatternRow, ...], code: int, pa_gt_pb: bool, large: bool, direction: int,
                    closed_code: int | None = None) -> frozenset[Fault]:
    return frozenset(row.fault for row in table if row.matches(code, pa_gt_pb, large, direction, closed_code))


def compatible_faults(table: tuple[PatternRow, ...], code: int, closed_code: int | None = None) -> frozenset[Fault]:
    """Faults whose patterns contain every crossing seen: a partial pattern on its way to theirs."""
    return frozenset(row.fault for row in table if row.contains(code, closed_code))


@dataclass
class Alarm:
    """A change of an actuator's alarm: first detection, or its cause becoming known."""

    time_s: float
    actuator: str
    fault: Fault
    code: str

    def to_json(self) -> dict[str, object]:
        return {"time_s": round(self.time_s, 4), "actuator": self.actuator, "fault": self.fault.value, "code": self.code}


@dataclass
class Isolator:
    """Latched detection and isolation state of one actuator (until acknowledged)."""

    actuator: str
    table: tuple[PatternRow, ...] = UKF_TABLE
    settle_s: float = 1.0  # evidence must persist this long before it narrows the cause (INFERRED)
    detected_at: float | None = None
    latched_code: int = 0
    candidates: frozenset[Fault] = field(default_factory=frozenset)
    history: list[str] = field(default_factory=list)
    _pending: tuple[float, int, int | None, frozenset[Fault]] | None = None

    @property
    def fault(self) -> Fault | None:
        """None before detection; the isolated fault, or ``unisolated`` while ambiguous."""
        if self.detected_at is None:
            return None
        if len(self.candidates) == 1:
            return next(iter(self.candidates))
        return Fault.UNISOLATED

    def observe(self, time_s: float, code: int, pa_gt_pb: bool, large: bool, direction: int,
                closed_code: int | None = None) -> list[Alarm]:
        """Feed one change of the evidence (at ``time_s``; ``closed_code`` None: none over closed-valve samples); returns
        alarms for changes of the fault.

        Detection is immediate (first crossing, as the papers time it). A pattern narrows the
        cause only once it has held for ``settle_s``, so the few hundred milliseconds in which
        one residual has crossed and the other is still on its way (P-II: r_pB led r_pA by 3 s
        for the internal leak) do not pass for an external leak.
        """
        alarms = self.advance(time_s)
        before = self.fault
        if code != 0 and self.detected_at is None:
            self.detected_at = time_s
        self.latched_code |= code
        self._pending = ((time_s, code, closed_code, matching_faults(self.table, code, pa_gt_pb, large, direction, closed_code))
                         if code else None)
        after = self.fault
        if after is not None and after != before:
            alarms.append(Alarm(time_s, self.actuator, after, code_string(self.latched_code)))
        return alarms

    def advance(self, time_s: float) -> list[Alarm]:
        """Let time pass: a pending pattern that has held for ``settle_s`` narrows the candidates."""
        if self._pending is None or time_s - self._pending[0] < self.settle_s:
            return []
        since, code, closed_code, exact = self._pending
        self._pending = None
        before = self.fault
        partial = compatible_faults(self.table, code, closed_code)
        if not self.candidates or (exact and all(row.large for row in self.table if row.fault in exact)):
            # "large" residuals single out the faults whose every row demands them (P-II: the stuck spool; parity: the
            # locked main spool) whatever came before: the first windows of such a fault are not yet large
            self.candidates = exact or partial
        elif exact and self.candidates & exact:
            self.candidates = self.candidates & exact
        elif exact and not self.candidates & partial:
            self.candidates = exact  # the evidence contradicts the earlier cause: trust the newest
        elif not exact and self.candidates & partial:
            self.candidates = self.candidates & partial
        # else: a partial pattern on the way between two full ones (e.g. a valve fault flipping) -> keep
        closed = "" if closed_code is None else " closed {} of {}".format(*(code_string(part) for part in closed_parts(closed_code)))
        self.history.append(f"{since:.3f}s {code_string(code)}{closed} -> {','.join(sorted(f.value for f in exact or partial))}")
        after = self.fault
        if after != before:
            return [Alarm(since + self.settle_s, self.actuator, after, code_string(self.latched_code))]
        return []

    def acknowledge(self) -> None:
        """Operator acknowledgement: clear the latch; a persisting fault is detected again."""
        self.detected_at = None
        self.latched_code = 0
        self.candidates = frozenset()
        self.history.clear()
        self._pending = None
