"""The trajectory database: one SQLite file of paths, solutions, energies, limits, DP policy tables
and joint trajectories (what ``hydro-ros db build`` precomputes and ``trajectory_server`` serves).

SQLite in WAL mode, so the server reads while a build writes. One solution is one row written in
one transaction: a build killed part-way keeps every committed row and the next build skips them.
Opening checks the schema version and runs ``PRAGMA quick_check``, so a corrupt or foreign file is
refused with a one-line error instead of serving damaged data. Arrays are stored as compressed
``.npz`` blobs (NumPy's own format: no pickle, no code on load).
"""

from __future__ import annotations

import hashlib
import io
import json
import sqlite3
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.crane import CraneConfig, parse_planning
from hydro_ros.contract.errors import DatabaseError
from hydro_ros.planning.trajectory import JointTrajectoryData

SCHEMA_VERSION = 2  # 2: DP position nodes span each stage's feasible window (dp.DpGrid)
_BUSY_TIMEOUT_S = 5.0

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS machines (
    machine TEXT PRIMARY KEY,
    config TEXT NOT NULL                -- the machine config (JSON) the solutions were computed with
);
CREATE TABLE IF NOT EXISTS paths (
    machine TEXT NOT NULL REFERENCES machines(machine),
    path_id TEXT NOT NULL,
    definition TEXT NOT NULL,           -- the path's config entry (JSON)
    PRIMARY KEY (machine, path_id)
);
CREATE TABLE IF NOT EXISTS solutions (
    machine TEXT NOT NULL,
    path_id TEXT NOT NULL,
    method TEXT NOT NULL,
    cost TEXT,                          -- DP stage cost, NULL for the pseudo-inverses and collocation
    inputs_hash TEXT NOT NULL,          -- config + path + grid + method: a rebuild recomputes on change
    grid TEXT NOT NULL,                 -- JSON [N_c, N_v, N_u]
    start_position REAL NOT NULL,       -- extension cylinder stroke at t = 0, m
    cp_energy_J REAL NOT NULL,
    ls_energy_J REAL NOT NULL,
    limits_ok INTEGER NOT NULL,
    record TEXT NOT NULL,               -- dp compare's method record (JSON)
    trajectory BLOB NOT NULL,           -- npz: time, positions, velocities, accelerations, extension
    policy BLOB,                        -- npz: cost_to_go, policy (DP methods only)
    seconds REAL NOT NULL,
    created REAL NOT NULL,
    PRIMARY KEY (machine, path_id, method),
    FOREIGN KEY (machine, path_id) REFERENCES paths(machine, path_id)
);
"""


@dataclass(frozen=True)
class StoredSolution:
    machine: str
    path_id: str
    method: str
    cost: str | None
    grid: tuple[int, int, int]
    start_position: float
    record: dict[str, Any]
    trajectory: JointTrajectoryData
    has_policy: bool


def inputs_hash(config: CraneConfig, path_id: str, method: str, grid: tuple[int, int, int],
                certificate: dict[str, Any] | None = None) -> str:
    """What a solution depends on, as the planner read it (the chain, its cylinders and limits, the hydraulics, the DP's
    sample time and filter, the path, and what a DP is held to, ``certify.certificate_inputs``):
    a change to a cylinder's bore or mount in ``actuators:`` counts, the monitor's valves and sensors, another path and the
    controller's and plant's settings do not. A DP stored before it was held to a certificate is planned again."""
    read = [[asdict(joint) for joint in config.joints], asdict(config.arm), config.redundant, config.base_rotation, config.gravity,
            asdict(config.extension_friction), dict(config.hydraulics), config.dp.sample_time, config.dp.filter_cutoff]
    planned = [read, config.path(path_id), path_id, method, list(grid)] + ([] if certificate is None else [{"certificate": certificate}])
    payload = json.dumps(planned, sort_keys=True, default=str)
    return hashlib.sha256(payload.encode()).hexdigest()[:16]


def pack_arrays(**arrays: np.ndarray) -> bytes:
    buffer = io.BytesIO()
    np.savez_compressed(buffer, **arrays)
    return buffer.getvalue()


def unpack_arrays(blob: bytes, where: str) -> dict[str, np.ndarray]:
    try:
        with np.load(io.BytesIO(blob), allow_pickle=False) as data:
            return {key: data[key] for key in data.files}
    except (ValueError, OSError, EOFError) as exc:
        raise DatabaseError(f"{where}: stored arrays unreadable ({exc})") from None


class TrajectoryDatabase:
    """Open (and, for ``writable``, create) a trajectory database; one connection, one thread."""

    def __init__(self, path: str | Path, *, writable: bool = False, check: bool = True) -> None:
        self.path = Path(path)
        if not writable and not self.path.is_file():
            raise DatabaseError(f"database {self.path}: no such file (build it with hydro-ros db build)")
        if writable and not self.path.parent.is_dir():
            raise DatabaseError(f"database {self.path}: directory {self.path.parent} does not exist")
        uri = f"file:{self.path.resolve()}?mode={'rwc' if writable else 'ro'}"
        try:
            self.connection = sqlite3.connect(uri, uri=True, timeout=_BUSY_TIMEOUT_S, isolation_level=None)
            self.connection.execute("PRAGMA foreign_keys = ON")
            if writable:
                self.connection.execute("PRAGMA journal_mode = WAL")
                self.connection.execute("PRAGMA synchronous = NORMAL")  # WAL + NORMAL: durable at each checkpoint, never corrupt
            self._check_schema(writable, check)
        except sqlite3.Error as exc:
            raise DatabaseError(f"database {self.path}: {self._reason(exc)}") from None

    def _reason(self, exc: sqlite3.Error) -> str:
        text = str(exc)
        if "locked" in text or "busy" in text:
            return f"locked by another process for more than {_BUSY_TIMEOUT_S:.0f} s ({text})"
        if "not a database" in text or "malformed" in text:
            return f"corrupt or not an SQLite file ({text})"
        return text

    def _check_schema(self, writable: bool, check: bool) -> None:
        tables = {row[0] for row in self.connection.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        if not tables and writable:
            with self.transaction():
                for statement in _SCHEMA.split(";"):
                    if statement.strip():
                        self.connection.execute(statement)
                self.connection.execute("INSERT INTO meta VALUES ('schema_version', ?)", (str(SCHEMA_VERSION),))
                self.connection.execute("INSERT INTO meta VALUES ('created', ?)", (time.strftime("%Y-%m-%dT%H:%M:%S"),))
            return
        if "meta" not in tables:
            raise DatabaseError(f"database {self.path}: not a hydro_ros trajectory database (no meta table)")
        row = self.connection.execute("SELECT value FROM meta WHERE key = 'schema_version'").fetchone()
        if row is None or row[0] != str(SCHEMA_VERSION):
            found = row[0] if row else "none"
            raise DatabaseError(f"database {self.path}: schema version {found}, this hydro_ros reads {SCHEMA_VERSION} "
                                "(a catalog is derived data: remove the file and run `hydro-ros db build` again)")
        if check:
            result = self.connection.execute("PRAGMA quick_check").fetchone()[0]
            if result != "ok":
                raise DatabaseError(f"database {self.path}: integrity check failed ({result})")

    def transaction(self) -> _Transaction:
        return _Transaction(self.connection)

    def close(self) -> None:
        self.connection.close()

    def __enter__(self) -> TrajectoryDatabase:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- writing ---------------------------------------------------------------------------
    def add_machine(self, config: CraneConfig) -> None:
        """Store the machine config and its path definitions (replacing older ones)."""
        machine = config.name
        with self.transaction():
            self.connection.execute(
                "INSERT INTO machines VALUES (?, ?) ON CONFLICT(machine) DO UPDATE SET config = excluded.config",
                (machine, json.dumps(dict(config.mapping), sort_keys=True)),
            )
            for path_id, definition in config.paths.items():
                self.connection.execute(
                    "INSERT INTO paths VALUES (?, ?, ?) ON CONFLICT(machine, path_id) DO UPDATE SET definition = excluded.definition",
                    (machine, path_id, json.dumps(definition, sort_keys=True)),
                )

    def put_solution(self, entry: dict[str, Any]) -> None:
        """Write one computed solution (``catalog.compute_entry``'s result) in one transaction."""
        record = entry["record"]
        with self.transaction():
            self.connection.execute(
                "INSERT OR REPLACE INTO solutions VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?, ?)",
                (
                    entry["machine"], entry["path_id"], entry["method"], entry["cost"], entry["inputs_hash"],
                    json.dumps(list(entry["grid"])), entry["start_position"], record["cp_energy_J"], record["ls_energy_J"],
                    int(record["limits_ok"]), json.dumps(record, sort_keys=True), entry["trajectory"], entry["policy"],
                    entry["seconds"], time.time(),
                ),
            )

    # -- reading ---------------------------------------------------------------------------
    def _rows(self, query: str, parameters: tuple = ()) -> list[tuple[Any, ...]]:
        """A read query's rows; a file damaged, replaced or locked under us is a DatabaseError naming it."""
        try:
            return self.connection.execute(query, parameters).fetchall()
        except sqlite3.Error as exc:
            raise DatabaseError(f"database {self.path}: {self._reason(exc)}") from None

    def _row(self, query: str, parameters: tuple = ()) -> tuple[Any, ...] | None:
        rows = self._rows(query, parameters)
        return rows[0] if rows else None

    def data_version(self) -> int:
        """SQLite's data_version: changes when another connection commits (a build adding solutions)."""
        return int(self._rows("PRAGMA data_version")[0][0])

    def committed(self) -> dict[tuple[str, str, str], str]:
        """(machine, path, method) -> inputs hash of every stored solution."""
        rows = self._rows("SELECT machine, path_id, method, inputs_hash FROM solutions")
        return {(m, p, meth): h for m, p, meth, h in rows}

    def machine_config(self, machine: str) -> CraneConfig:
        row = self._row("SELECT config FROM machines WHERE machine = ?", (machine,))
        if row is None:
            raise DatabaseError(f"database {self.path}: no machine {machine!r}")
        try:
            return parse_planning(json.loads(row[0]), Path(self.path))
        except ConfigError as exc:
            raise DatabaseError(f"database {self.path}: machine {machine!r}: {exc}") from None

    def machines(self) -> list[str]:
        return [row[0] for row in self._rows("SELECT machine FROM machines ORDER BY machine")]

    def catalog(self) -> list[dict[str, Any]]:
        """Every stored path with its solutions' energies and limit flags (the server's latched catalog)."""
        entries: dict[tuple[str, str], dict[str, Any]] = {}
        for machine, path_id, definition in self._rows("SELECT machine, path_id, definition FROM paths ORDER BY machine, path_id"):
            definition = json.loads(definition)
            entries[(machine, path_id)] = {
                "machine": machine,
                "path": path_id,
                "description": definition.get("description", ""),
                "duration_s": float(sum(float(segment["duration"]) for segment in definition.get("segments", []))),
                "solutions": {},
            }
        rows = self._rows(
            "SELECT machine, path_id, method, cost, cp_energy_J, ls_energy_J, limits_ok, start_position, grid, created "
            "FROM solutions ORDER BY machine, path_id, method"
        )
        for machine, path_id, method, cost, cp, ls, ok, start, grid, created in rows:
            entry = entries.get((machine, path_id))
            if entry is None:
                continue
            entry["solutions"][method] = {
                "cost": cost,
                "cp_energy_J": cp,
                "ls_energy_J": ls,
                "limits_ok": bool(ok),
                "start_extension_m": start,
                "grid": json.loads(grid),
                "created": created,
            }
        return list(entries.values())

    def paths_of(self, machine: str | None = None) -> list[str]:
        query = "SELECT path_id FROM paths" + (" WHERE machine = ?" if machine else "") + " ORDER BY path_id"
        return [row[0] for row in self._rows(query, (machine,) if machine else ())]

    def solution(self, path_id: str, method: str, machine: str | None = None) -> StoredSolution:
        # length(), not IS NOT NULL: SQLite answers it from the row header instead of reading the whole blob
        query = (
            "SELECT machine, path_id, method, cost, grid, start_position, record, trajectory, coalesce(length(policy), 0) > 0 "
            "FROM solutions WHERE path_id = ? AND method = ?" + (" AND machine = ?" if machine else "")
        )
        rows = self._rows(query, (path_id, method, machine) if machine else (path_id, method))
        if not rows:
            known = self.paths_of(machine)
            if path_id not in known:
                raise KeyError(f"path {path_id!r}: not in the database (stored: {', '.join(known) or 'none'})")
            methods = [r[0] for r in self._rows("SELECT method FROM solutions WHERE path_id = ?", (path_id,))]
            raise KeyError(f"path {path_id!r}: no {method!r} solution (stored: {', '.join(methods) or 'none'})")
        if len(rows) > 1:
            raise KeyError(f"path {path_id!r}: stored for several machines, name one")
        machine, path_id, method, cost, grid, start, record, blob, has_policy = rows[0]
        arrays = unpack_arrays(blob, f"database {self.path}: {path_id}/{method} trajectory")
        config = self.machine_config(machine)
        trajectory = JointTrajectoryData(
            joint_names=config.joint_names,
            time=arrays["time"],
            positions=arrays["positions"],
            velocities=arrays["velocities"],
            accelerations=arrays["accelerations"],
            extension=arrays["extension"],
        )
        return StoredSolution(machine, path_id, method, cost, tuple(json.loads(grid)), start, json.loads(record), trajectory, bool(has_policy))

    def policy(self, machine: str, path_id: str, method: str) -> dict[str, np.ndarray]:
        row = self._row("SELECT policy FROM solutions WHERE machine = ? AND path_id = ? AND method = ?", (machine, path_id, method))
        if row is None or row[0] is None:
            raise KeyError(f"path {path_id!r}: {method!r} has no stored DP policy")
        return unpack_arrays(row[0], f"database {self.path}: {path_id}/{method} policy")

    def rows(self) -> Iterator[tuple[Any, ...]]:
        """(machine, path, method, cost, CP J, LS J, limits ok, seconds, created) for ``db list``."""
        yield from self._rows(
            "SELECT machine, path_id, method, cost, cp_energy_J, ls_energy_J, limits_ok, seconds, created "
            "FROM solutions ORDER BY machine, path_id, cp_energy_J"
        )


class _Transaction:
    """BEGIN IMMEDIATE ... COMMIT, rolled back on any exception (the connection is in autocommit mode)."""

    def __init__(self, connection: sqlite3.Connection) -> None:
        self.connection = connection

    def __enter__(self) -> None:
        self.connection.execute("BEGIN IMMEDIATE")

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.connection.execute("ROLLBACK" if exc_type else "COMMIT")
