"""Fault isolation by residual-sign patterns: P-II Table 3 (digest section 4.9) and its procedure.

A pattern code packs the four threshold-crossing flags as bits (r_pA up, r_pA down, r_pB up,
r_pB down), written like the paper's columns: "0110" = r_pA below its negative threshold and r_pB
above its positive one. Each observation (code, pA > pB, both residuals large, valve-command
sign) selects the table rows it matches; the candidate set is intersected over successive
observations, which is the paper's ambiguity resolution: after the valve command changes sign a
valve fault flips its pattern while an internal leak keeps it, so only one cause survives.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.names import Fault

A_UP, A_DOWN, B_UP, B_DOWN = 8, 4, 2, 1


def code_string(code: int) -> str:
    return format(code, "04b")


@dataclass(frozen=True)
class PatternRow:
    """One row of a signature table; None is the paper's "0/1" (don't care)."""

    fault: Fault
    code: int
    pa_gt_pb: bool | None = None
    large: bool | None = None
    command_positive: bool | None = None

    def matches(self, code: int, pa_gt_pb: bool, large: bool, direction: int) -> bool:
        if code != self.code:
            return False
        if self.pa_gt_pb is not None and self.pa_gt_pb != pa_gt_pb:
            return False
        if self.large is not None and self.large != large:
            return False
        if self.command_positive is not None and direction != 0 and self.command_positive != (direction > 0):
            return False
        return True


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
    """Rows from config entries {fault, code: "0110", pa_gt_pb, large, command_positive} (null = X)."""
    rows = []
    for entry in entries:
        try:
            code = entry["code"]
            # the config loader turns numeric-looking strings into numbers: "0110" arrives as 110.0
            text = str(int(code)) if isinstance(code, (int, float)) else str(code)
            rows.append(PatternRow(Fault(entry["fault"]), int(text, 2), entry.get("pa_gt_pb"),
                                   entry.get("large"), entry.get("command_positive")))
        except (KeyError, ValueError) as exc:
            raise InputError(f"fdi.parity_signatures: bad entry {entry!r} ({exc})") from None
    return tuple(rows)


def matching_faults(table: tuple[PatternRow, ...], code: int, pa_gt_pb: bool, large: bool, direction: int) -> frozenset[Fault]:
    return frozenset(row.fault for row in table if row.matches(code, pa_gt_pb, large, direction))


def compatible_faults(table: tuple[PatternRow, ...], code: int) -> frozenset[Fault]:
    """Faults whose pattern contains every crossing seen: a partial pattern on its way to theirs."""
    return frozenset(row.fault for row in table if row.code & code == code)


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
    _pending: tuple[float, int, frozenset[Fault]] | None = None

    @property
    def fault(self) -> Fault | None:
        """None before detection; the isolated fault, or ``unisolated`` while ambiguous."""
        if self.detected_at is None:
            return None
        if len(self.candidates) == 1:
            return next(iter(self.candidates))
        return Fault.UNISOLATED

    def observe(self, time_s: float, code: int, pa_gt_pb: bool, large: bool, direction: int) -> list[Alarm]:
        """Feed one change of the evidence (at ``time_s``); returns alarms for changes of the fault.

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
        self._pending = (time_s, code, matching_faults(self.table, code, pa_gt_pb, large, direction)) if code else None
        after = self.fault
        if after is not None and after != before:
            alarms.append(Alarm(time_s, self.actuator, after, code_string(self.latched_code)))
        return alarms

    def advance(self, time_s: float) -> list[Alarm]:
        """Let time pass: a pending pattern that has held for ``settle_s`` narrows the candidates."""
        if self._pending is None or time_s - self._pending[0] < self.settle_s:
            return []
        since, code, exact = self._pending
        self._pending = None
        before = self.fault
        partial = compatible_faults(self.table, code)
        if not self.candidates or (exact and all(f == Fault.SPOOL_STUCK_CLOSED for f in exact)):
            # "large" residuals in both chambers single out the stuck spool whatever came before
            self.candidates = exact or partial
        elif exact and self.candidates & exact:
            self.candidates = self.candidates & exact
        elif exact and not self.candidates & partial:
            self.candidates = exact  # the evidence contradicts the earlier cause: trust the newest
        elif not exact and self.candidates & partial:
            self.candidates = self.candidates & partial
        # else: a partial pattern on the way between two full ones (e.g. a valve fault flipping) -> keep
        self.history.append(f"{since:.3f}s {code_string(code)} -> {','.join(sorted(f.value for f in exact or partial))}")
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
