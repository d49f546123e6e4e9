"""The monitor's alarm log: every alarm raised, changed, cleared, acknowledged and reset, in SQLite.

fdi_node owns the file (parameter ``alarm_log``); the HMI and ``hydro-ros alarms export`` read it.
Writes go through WAL with synchronous=FULL, so a committed event survives a crash or power loss of
the machine, and readers never block the writer.

The log never stops the monitor and never drops an event silently: an event is queued in memory
(at most ``MAX_PENDING``; beyond that the oldest are dropped and counted) and written in order as
soon as the file takes it, so a full disk, a read-only file system or a file that cannot be opened
is ``error`` on the node's status while monitoring goes on, and :meth:`AlarmLog.flush` (the node's
diagnostics tick) writes the queue once the disk allows. A file deleted or replaced under the node
is noticed before the next write and a new one opened; a file that is not an alarm log (corrupt) is
moved aside to ``<name>.corrupt-<unix time>`` and a new one started.
The alarms still latched (raised or changed, and not reset since) come back after a restart through
:meth:`AlarmLog.latched`; an acknowledgement silences an alarm, it does not clear it.
"""

from __future__ import annotations

import collections
import contextlib
import json
import sqlite3
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydro_ros.contract.errors import InputError

MAX_PENDING = 10_000  # events held in memory while the file cannot take them
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
        self.error = ""  # why the last open or write failed, '' while the file takes every event
        self.failed_writes = 0
        self.dropped = 0  # events lost because the queue was full (MAX_PENDING)
        self.reopened = 0  # files found deleted or replaced, and corrupt files moved aside
        self.moved_aside: list[Path] = []
        self.pending: collections.deque[tuple] = collections.deque()
        self._db: sqlite3.Connection | None = None
        self._identity: tuple[int, int] | None = None
        self._open()

    def _open(self) -> bool:
        """Open (or create) the file; a file that is not an alarm log is moved aside and a new one started."""
        self._close_db()
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            try:
                self._connect()
            except sqlite3.DatabaseError as exc:
                if not self.path.is_file() or isinstance(exc, sqlite3.OperationalError):
                    raise
                aside = self.path.with_name(f"{self.path.name}.corrupt-{int(self.clock())}")
                self._close_db()
                self.path.rename(aside)
                for suffix in ("-wal", "-shm"):
                    Path(f"{self.path}{suffix}").unlink(missing_ok=True)
                self.moved_aside.append(aside)
                self.reopened += 1
                self._connect()
        except (sqlite3.Error, OSError) as exc:
            self._close_db()
            self.error = f"{self.path}: cannot open ({exc})"
            return False
        self.error = ""
        return True

    def _connect(self) -> None:
        self._db = sqlite3.connect(self.path, timeout=5.0, isolation_level=None, check_same_thread=False)
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=FULL")
        self._db.executescript(SCHEMA)
        stat = self.path.stat()
        self._identity = (stat.st_dev, stat.st_ino)

    def _close_db(self) -> None:
        if self._db is not None:
            with contextlib.suppress(sqlite3.Error):
                self._db.close()
        self._db = None
        self._identity = None

    def _same_file(self) -> bool:
        try:
            stat = self.path.stat()
        except OSError:
            return False
        return (stat.st_dev, stat.st_ino) == self._identity

    def record(self, event: str, actuator: str, fault: str = "", level: int = 0, *, stamp_s: float | None = None,
               evidence: dict[str, Any] | None = None) -> bool:
        """Queue one event and write the queue; False (and ``error`` set) while the file does not take it."""
        if event not in EVENTS:
            raise ValueError(f"alarm event {event!r}: expected one of {', '.join(EVENTS)}")
        if len(self.pending) >= MAX_PENDING:
            self.pending.popleft()
            self.dropped += 1
        self.pending.append((self.clock(), stamp_s, self.machine, actuator, event, fault, int(level),
                             json.dumps(evidence or {}, sort_keys=True)))
        return self.flush()

    def flush(self) -> bool:
        """Write the queued events in order; True when none is left."""
        if self._db is None or not self._same_file():
            if self._db is not None:
                self.reopened += 1  # deleted or replaced under us: what went to the old file is in the old file
            if not self._open():
                self.failed_writes += bool(self.pending)
                return not self.pending
        while self.pending:
            try:
                self._db.execute(
                    "INSERT INTO alarm_events (wall_time, stamp_s, machine, actuator, event, fault, level, evidence) "
                    "VALUES (?, ?, ?, ?, ?, ?, ?, ?)", self.pending[0])
            except sqlite3.Error as exc:
                self.failed_writes += 1
                self.error = f"{self.path}: {exc}"
                return False
            self.pending.popleft()
        self.error = ""
        return True

    def latched(self) -> list[LatchedAlarm]:
        """The alarms this machine's monitor had latched when it stopped (none from a log that cannot be read)."""
        if self._db is None:
            return []
        latched: dict[str, LatchedAlarm] = {}
        for row in self._db.execute(
                "SELECT actuator, event, fault, level, wall_time, stamp_s, evidence FROM alarm_events WHERE machine = ? ORDER BY id",
                (self.machine,)):
            actuator, event, fault, level, wall_time, stamp_s, evidence = row
            if event in ("raised", "changed"):
                latched[actuator] = LatchedAlarm(actuator, fault, level, wall_time, stamp_s, json.loads(evidence))
            elif event == "cleared":
                latched.pop(actuator, None)
            elif event == "reset" and not actuator:
                latched.clear()
        return list(latched.values())

    def close(self) -> None:
        self.flush()
        self._close_db()


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

