"""What the operator's HMI shows, kept apart from ROS and HTTP so it is tested with plain pytest.

The node feeds it what arrives on the graph (diagnostic statuses, residuals, the halt request,
joint states, the trajectory catalog and results); the web server reads it as JSON. Everything is
guarded by one lock: the ROS executor writes from its thread, the web server reads from its own.

Times: ``*_wall`` values are this process's wall clock (s since the epoch, what the operator's
clock shows); ``*_stamp_s`` values are message stamps (sim time during a bag replay).
"""

from __future__ import annotations

import json
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from typing import Any

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.topics import FDI_HALT_STATUS, FDI_STATUS_PREFIX

LEVEL_NAMES = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
HEALTHY_MESSAGES = ("ok", "stale", "not_monitored", "overloaded")  # fdi_node's messages that name no fault
TILE_VALUES = ("pattern", "method", "first_detection_stamp_s", "stale_topics", "invalid_sensors")  # status values a tile shows
MAX_ALARMS = 200
MAX_ACTIONS = 50
MAX_REFUSALS = 20  # refused requests without the token: their own short list, so they never push out operator actions
MAX_DETAIL_CHARS = 160


@dataclass(frozen=True)
class StatusReport:
    """One DiagnosticStatus, without the ROS types."""

    name: str
    level: int
    message: str
    hardware_id: str
    values: dict[str, str]


@dataclass
class Tile:
    actuator: str
    machine: str
    level: str
    fault: str
    since_wall: float  # when level or fault last changed
    detected_stamp_s: float | None
    diag_stamp_s: float | None  # header stamp of the DiagnosticArray that carried the status
    received_wall: float | None  # None: a configured actuator not heard of yet
    values: dict[str, str]


@dataclass
class ShownAlarm:
    id: int
    actuator: str
    fault: str
    level: str
    raised_wall: float
    detected_stamp_s: float | None
    cleared_wall: float | None = None
    acknowledged_wall: float | None = None

    @property
    def active(self) -> bool:
        return self.cleared_wall is None


@dataclass
class Residuals:
    """Decimated /fdi/residuals rows within the plot window: [stamp_s, value per channel]."""

    names: list[str] = field(default_factory=list)
    rows: deque = field(default_factory=deque)  # (sequence number, row)
    sequence: int = 0  # of the newest row; never decreases
    reset_at: int = 0  # sequence when the window was last cleared


def clip(text: str, limit: int = MAX_DETAIL_CHARS) -> str:
    """Printable and bounded: what a request puts on the page or in the log."""
    printable = "".join(ch if ch.isprintable() else "?" for ch in str(text)[: limit + 1])
    return printable if len(printable) <= limit else printable[: limit - 3] + "..."


class HmiState:
    def __init__(self, *, plot_window_s: float = 60.0, plot_period_s: float = 0.1, stale_timeout_s: float = 3.0,
                 clock: Callable[[], float] = time.time) -> None:
        if not (plot_window_s > 0 and plot_period_s >= 0 and stale_timeout_s > 0):
            raise InputError(f"HMI windows must be positive (plot_window {plot_window_s}, plot_period {plot_period_s}, "
                             f"stale_timeout {stale_timeout_s})")
        self.plot_window_s = plot_window_s
        self.plot_period_s = plot_period_s
        self.stale_timeout_s = stale_timeout_s
        self.clock = clock
        self.lock = threading.Lock()
        self.tiles: dict[str, Tile] = {}
        self.alarms: deque[ShownAlarm] = deque(maxlen=MAX_ALARMS)
        self._next_alarm = 1
        self.residuals = Residuals()
        self.halt: bool | None = None
        self.halt_since_wall: float | None = None
        self.halt_kind = ""  # the monitor's FDI_HALT_STATUS: "hold" (paused: the monitor cannot vouch) or "fault" (stop)
        self.halt_reason = ""
        self.joints: dict[str, float] = {}
        self.joint_stamp_s: float | None = None
        self.catalog: list[dict[str, Any]] | None = None
        self.catalog_error = ""
        self.result: dict[str, Any] | None = None
        self.actions: deque[dict[str, Any]] = deque(maxlen=MAX_ACTIONS)
        self.refusals: deque[dict[str, Any]] = deque(maxlen=MAX_REFUSALS)

    def expect(self, machine: str, actuators: list[str]) -> None:
        """Tiles for the configured actuators before their first status: a monitor that never starts shows."""
        now = self.clock()
        with self.lock:
            for actuator in actuators:
                self.tiles.setdefault(actuator, Tile(actuator, machine, "STALE", "waiting for /diagnostics", now, None, None, None, {}))

    # -- inputs (ROS executor thread) ------------------------------------------------------
    def on_diagnostics(self, stamp_s: float, reports: list[StatusReport]) -> None:
        now = self.clock()
        with self.lock:
            for report in reports:
                if report.name == FDI_HALT_STATUS:
                    self.halt_kind, self.halt_reason = report.values.get("kind", ""), report.message
                    continue
                if not report.name.startswith(FDI_STATUS_PREFIX):
                    continue
                actuator = report.name[len(FDI_STATUS_PREFIX):]
                if not actuator or "/" in actuator:  # self-test statuses are not actuators
                    continue
                level = LEVEL_NAMES.get(report.level, f"level {report.level}")
                tile = self.tiles.get(actuator)
                changed = tile is None or (tile.level, tile.fault) != (level, report.message)
                self.tiles[actuator] = Tile(
                    actuator=actuator, machine=report.hardware_id, level=level, fault=report.message,
                    since_wall=now if changed else tile.since_wall,
                    detected_stamp_s=_float_or_none(report.values.get("first_detection_stamp_s", "")),
                    diag_stamp_s=stamp_s, received_wall=now,
                    values={k: report.values[k] for k in TILE_VALUES if k in report.values},
                )
                if changed:
                    self._track_alarm(actuator, level, report.message, now)

    def _track_alarm(self, actuator: str, level: str, fault: str, now: float) -> None:
        active = next((a for a in self.alarms if a.actuator == actuator and a.active), None)
        if level in ("WARN", "ERROR") and fault not in HEALTHY_MESSAGES:
            if active is None:
                detected = self.tiles[actuator].detected_stamp_s
                self.alarms.appendleft(ShownAlarm(self._next_alarm, actuator, fault, level, now, detected))
                self._next_alarm += 1
            else:  # the same alarm, isolated further (unisolated -> a fault name) or escalated
                active.fault, active.level = fault, level
        elif level == "OK" and active is not None:
            active.cleared_wall = now

    def on_residuals(self, stamp_s: float, names: list[str], values: list[float]) -> None:
        with self.lock:
            buffer = self.residuals
            newest = buffer.rows[-1][1][0] if buffer.rows else None
            if names != buffer.names or (newest is not None and stamp_s < newest):
                # a new layout, or time ran backwards (a replay restarted): the old window is not comparable
                buffer.names = list(names)
                buffer.rows.clear()
                buffer.reset_at = buffer.sequence
            elif newest is not None and stamp_s - newest < self.plot_period_s:
                return
            buffer.sequence += 1
            buffer.rows.append((buffer.sequence, [stamp_s, *(_finite_or_none(v) for v in values)]))
            while buffer.rows and buffer.rows[0][1][0] < stamp_s - self.plot_window_s:
                buffer.rows.popleft()

    def on_halt(self, halt: bool) -> None:
        with self.lock:
            if halt != self.halt:
                self.halt, self.halt_since_wall = halt, self.clock()

    def on_joint_state(self, stamp_s: float, names: list[str], positions: list[float]) -> None:
        with self.lock:
            self.joints = {n: _finite_or_none(p) for n, p in zip(names, positions)}
            self.joint_stamp_s = stamp_s

    def on_catalog(self, text: str) -> None:
        try:
            catalog = json.loads(text, parse_constant=_no_constant)
            if not isinstance(catalog, list) or not all(isinstance(e, dict) and "path" in e for e in catalog):
                raise ValueError("expected a JSON list of {path, solutions}")
        except ValueError as exc:
            with self.lock:
                self.catalog_error = f"catalog: malformed ({exc})"
            return
        with self.lock:
            self.catalog, self.catalog_error = catalog, ""

    def on_result(self, text: str) -> None:
        try:
            result = json.loads(text, parse_constant=_no_constant)
        except ValueError:
            result = {"ok": False, "error": f"result: malformed JSON {text[:60]!r}"}
        with self.lock:
            self.result = result if isinstance(result, dict) else {"ok": False, "error": "result: not a JSON object"}
            self.result["received_wall"] = self.clock()

    # -- operator actions (web server thread) ----------------------------------------------
    def record_action(self, action: str, ok: bool, detail: str, client: str, *, authenticated: bool = True) -> None:
        """An operator action's outcome. A request refused before its token was checked goes to the
        refusals, where a repeat of the newest (same client, action and reason) only counts up."""
        entry = {"wall": self.clock(), "action": clip(action), "ok": ok, "detail": clip(detail), "client": clip(client, 64)}
        with self.lock:
            if authenticated:
                self.actions.appendleft(entry)
                return
            newest = self.refusals[0] if self.refusals else None
            if newest and all(newest[key] == entry[key] for key in ("action", "detail", "client")):
                newest["count"] += 1
                newest["wall"] = entry["wall"]
            else:
                self.refusals.appendleft(dict(entry, count=1))

    def unacknowledged(self) -> list[int]:
        """Ids of the active alarms nobody acknowledged yet (an acknowledgement applies to what was shown)."""
        with self.lock:
            return [a.id for a in self.alarms if a.active and a.acknowledged_wall is None]

    def mark_acknowledged(self, ids: list[int]) -> int:
        """Stamp these alarms acknowledged, active or not: the FDI node may clear them before its answer arrives."""
        now = self.clock()
        with self.lock:
            marked = [a for a in self.alarms if a.id in ids and a.acknowledged_wall is None]
            for alarm in marked:
                alarm.acknowledged_wall = now
            return len(marked)

    def catalog_methods(self, path: str) -> list[str] | None:
        """The methods stored for a path, or None when the path is not in the catalog."""
        with self.lock:
            entry = next((e for e in self.catalog or () if e.get("path") == path), None)
            return None if entry is None else sorted(entry.get("solutions", {}))

    # -- views (web server thread) ---------------------------------------------------------
    def _status(self) -> dict[str, Any]:
        now = self.clock()
        tiles = []
        for tile in sorted(self.tiles.values(), key=lambda t: t.actuator):
            view = asdict(tile)
            age = None if tile.received_wall is None else now - tile.received_wall
            if age is not None and age > self.stale_timeout_s:  # fdi_node itself went silent
                view.update(level="STALE", fault=f"no /diagnostics for {age:.0f} s")
            tiles.append(view)
        return {
            "wall": now,
            "tiles": tiles,
            "alarms": [dict(asdict(a), active=a.active) for a in self.alarms],
            "halt": self.halt,
            "halt_since_wall": self.halt_since_wall,
            "halt_kind": self.halt_kind,
            "halt_reason": self.halt_reason,
            "joints": self.joints,
            "joint_stamp_s": self.joint_stamp_s,
            "catalog": self.catalog,
            "catalog_error": self.catalog_error,
            "result": self.result,
            "actions": list(self.actions),
            "refusals": [dict(entry) for entry in self.refusals],
        }

    def snapshot(self) -> tuple[dict[str, Any], int]:
        """Everything, with the whole residual window; and the cursor for the next update()."""
        with self.lock:
            view = self._status()
            rows = [row for _, row in self.residuals.rows]
            view["residuals"] = {"names": self.residuals.names, "rows": rows, "reset": True, "window_s": self.plot_window_s}
            return view, self.residuals.sequence

    def update(self, cursor: int) -> tuple[dict[str, Any], int]:
        """The status, and the residual rows appended since `cursor`; the whole window if it was reset since."""
        with self.lock:
            view = self._status()
            reset = cursor <= self.residuals.reset_at  # the client may hold rows from before the reset
            fresh = [row for seq, row in self.residuals.rows if reset or seq > cursor]
            view["residuals"] = {"names": self.residuals.names, "rows": fresh, "reset": reset, "window_s": self.plot_window_s}
            return view, self.residuals.sequence


def _float_or_none(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None


def _no_constant(_name: str) -> None:
    """NaN / Infinity in a peer's JSON become null: the browser's JSON.parse rejects them."""
    return None


def _finite_or_none(value: float) -> float | None:
    """JSON has no NaN: a missing residual is drawn as a gap. Four digits are more than a plot resolves."""
    return float(f"{value:.4g}") if math.isfinite(value) else None
