"""The monitor's alarm log: every alarm raised, changed, cleared, acknowledged and reset, in SQLite.

fdi_node owns the file (parameter ``alarm_log``); the HMI and ``hydro-ros alarms export`` read it.
Writes go through WAL with synchronous=FULL, so a committed event survives a crash or power loss of
the machine, and readers never block the writer. A failing write (a full disk, a read-only file) is
kept as ``error`` for the node's status and never raised: the monitor goes on monitoring.
The alarms still latched (raised or changed, and neither acknowledged nor reset since) come back
after a restart through :meth:`AlarmLog.latched`.
"""

from __future__ import annotations

import json
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydro_ros.contract.errors import InputError

EVENTS = ("raised", "changed", "cleared", "acknowledged", "reset")
SCHEMA = """
CREATE TABLE IF NOT EXISTS alarm_events (
    id INTEGER PRIMARY KEY AUTOINCREMENT,
    wall_time REAL NOT NULL,       -- [s] Unix time of the event
    stamp_s REAL,                  -- [s] sample stamp of the detection, where there is one
    machine TEXT NOT NULL,
    actuator TEXT NOT NULL,        -- '' for an event of the whole monitor (acknowledge, reset)
    event TEXT NOT NULL CHECK (event IN ('raised', 'changed', 'cleared', 'acknowledged', 'reset')),
    fault TEXT NOT NULL,           -- contract fault name, or '' where there is none
    level INTEGER NOT NULL,        -- DiagnosticStatus level: 1 WARN, 2 ERROR
    evidence TEXT NOT NULL         -- JSON: pattern, residuals, thresholds, detail
);
CREATE INDEX IF NOT EXISTS alarm_events_actuator ON alarm_events (machine, actuator, id);
"""
COLUMNS = ("id", "wall_time", "stamp_s", "machine", "actuator", "event", "fault", "level", "evidence")


@dataclass(frozen=True)
class LatchedAlarm:
    actuator: str
    fault: str
    level: int
    wall_time: float
    stamp_s: float | None
    evidence: dict[str, Any]


class AlarmLog:
    """Append-only events of one machine's monitor in the SQLite file ``path``."""

    def __init__(self, path: str | Path, machine: str, *, clock: Any = time.time) -> None:
        self.path = Path(path)
        self.machine = machine
        self.clock = clock
        self.error = ""  # the last write failure, '' while writes succeed
        self.failed_writes = 0
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(self.path, timeout=5.0, isolation_level=None, check_same_thread=False)
            self._db.execute("PRAGMA journal_mode=WAL")
            self._db.execute("PRAGMA synchronous=FULL")
            self._db.executescript(SCHEMA)
        except (sqlite3.Error, OSError) as exc:
            raise InputError(f"alarm log {self.path}: cannot open ({exc})") from None

    def record(self, event: str, actuator: str, fault: str = "", level: int = 0, *, stamp_s: float | None = None,
               evidence: dict[str, Any] | None = None) -> bool:
        """Append one event; False (and ``error`` set) when the write failed."""
        if event not in EVENTS:
            raise ValueError(f"alarm event {event!r}: expected one of {', '.join(EVENTS)}")
        try:
            self._db.execute(
                "INSERT INTO alarm_events (wall_time, stamp_s, machine, actuator, event, fault, level, evidence) "
                "VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                (self.clock(), stamp_s, self.machine, actuator, event, fault, int(level), json.dumps(evidence or {}, sort_keys=True)))
        except sqlite3.Error as exc:
            self.failed_writes += 1
            self.error = f"{self.path}: {exc}"
            return False
        self.error = ""
        return True

    def latched(self) -> list[LatchedAlarm]:
        """The alarms this machine's monitor had latched when it stopped."""
        latched: dict[str, LatchedAlarm] = {}
        for row in self._db.execute(
                "SELECT actuator, event, fault, level, wall_time, stamp_s, evidence FROM alarm_events WHERE machine = ? ORDER BY id",
                (self.machine,)):
            actuator, event, fault, level, wall_time, stamp_s, evidence = row
            if event in ("raised", "changed"):
                latched[actuator] = LatchedAlarm(actuator, fault, level, wall_time, stamp_s, json.loads(evidence))
            elif event == "cleared":
                latched.pop(actuator, None)
            elif event in ("acknowledged", "reset") and not actuator:
                latched.clear()
        return list(latched.values())

    def close(self) -> None:
        self._db.close()


def read_events(path: str | Path, *, offset: int = 0, limit: int | None = None, newest_first: bool = True) -> tuple[list[dict[str, Any]], int]:
    """Events of an alarm log (read-only, never creating the file) and the total count."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"alarm log {path}: no such file")
    try:
        db = sqlite3.connect(f"file:{path}?mode=ro", uri=True, timeout=5.0)
        try:
            total = db.execute("SELECT COUNT(*) FROM alarm_events").fetchone()[0]
            order = "DESC" if newest_first else "ASC"
            rows = db.execute(f"SELECT {', '.join(COLUMNS)} FROM alarm_events ORDER BY id {order} LIMIT ? OFFSET ?",
                              (-1 if limit is None else int(limit), int(offset))).fetchall()
        finally:
            db.close()
    except sqlite3.Error as exc:
        raise InputError(f"alarm log {path}: not readable ({exc})") from None
    return [dict(zip(COLUMNS, row), evidence=json.loads(row[-1])) for row in rows], total

