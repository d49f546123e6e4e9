"""Serve stored trajectories, re-planned from the manipulator's actual state (no ROS here).

The thesis solved every path offline from one initial configuration and left on-line use open
(P-VI Section 5: the backward pass can be reused, only a new forward simulation is needed).
This closes it: when the current joint state differs from the stored start, a DP solution runs its
stored policy forward from the actual extension (``DpSolution.follow``: compiled, under a
millisecond for 200 stages), a pseudo-inverse simply runs again from there; a DP's result is filtered
(unless the filter would break a limit, ``problem.smoothed``), completed by IK and checked against every limit
before it is served. The redundant joint may be
anywhere; the tip must be at the path's start. ``prepare`` loads the tables and compiles the pass
before the first request, so the first re-plan is as fast as the rest. From the stored start a DP's trajectory is the
one stored, held to the certificate (``certify.certified``); a re-plan from another state follows the full grid's
policy and is not held to it (the certificate's refinement takes seconds, a re-plan milliseconds).
"""

from __future__ import annotations

import math
import time
from collections import OrderedDict
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import Crane
from hydro_ros.planning.certify import served_plan
from hydro_ros.planning.costs import Cost
from hydro_ros.planning.database import StoredSolution, TrajectoryDatabase
from hydro_ros.planning.dp import DpGrid, DpSolution, InfeasibleStart, start_position
from hydro_ros.planning.paths import path_from_config
from hydro_ros.planning.problem import METHODS, Problem, method_record, run_method, smoothed
from hydro_ros.planning.trajectory import JointTrajectoryData, joint_trajectory

# a state this close to the stored start (rad or m, rad/s or m/s) is served as stored
SAME_START_TOLERANCE = 1e-3


class ServeError(InputError):
    """A request that cannot be served; the message is the one-line error result."""


@dataclass(frozen=True)
class JointStateSample:
    """The manipulator's measured state, by joint name, and when it was measured (s, node clock)."""

    names: list[str]
    positions: list[float]
    velocities: list[float]


@dataclass
class Served:
    path_id: str
    method: str
    trajectory: JointTrajectoryData
    record: dict[str, Any]
    replanned: bool
    seconds: float

    def result(self) -> dict[str, Any]:
        return {
            "path": self.path_id,
            "ok": True,
            "error": None,
            "method": self.method,
            "replanned": self.replanned,
            "cp_energy_J": self.record["cp_energy_J"],
            "ls_energy_J": self.record["ls_energy_J"],
            "limits": self.record["limits"],
            "points": len(self.trajectory.time),
            "duration_s": float(self.trajectory.time[-1]),
            "seconds": round(self.seconds, 4),
        }


class _Context:
    """What re-planning a path needs: crane, samples, grid, and the DP tables once loaded."""

    def __init__(self, config: CraneConfig, stored: StoredSolution) -> None:
        self.crane = Crane(config)
        self.config = config
        self.problem = Problem.build(self.crane, config, stored.path_id, grid=stored.grid)
        self.solution: DpSolution | None = None


class TrajectoryService:
    """Reads a trajectory database and answers path requests (what ``trajectory_server`` wires to ROS)."""

    def __init__(self, database: TrajectoryDatabase, *, tip_tolerance: float = 0.05, cache_size: int = 8) -> None:
        self.db = database
        self.tip_tolerance = tip_tolerance
        self._contexts: OrderedDict[tuple[str, str, str], _Context] = OrderedDict()
        self._cache_size = cache_size
        self._solutions: dict[tuple[str, str], StoredSolution] = {}
        self._version: int | None = None

    def catalog(self) -> list[dict[str, Any]]:
        return self.db.catalog()

    def serve(self, path_id: str, method: str, current: JointStateSample | None) -> Served:
        began = time.perf_counter()
        if method not in METHODS:
            raise ServeError(f"method {method!r}: unknown (known: {', '.join(METHODS)})")
        stored = self._solution(path_id, method)
        if current is None:
            return Served(path_id, method, stored.trajectory, stored.record, False, time.perf_counter() - began)
        q, qd = self._ordered(stored.trajectory.joint_names, current)
        start = stored.trajectory.positions[0]
        if np.max(np.abs(q - start)) <= SAME_START_TOLERANCE and np.max(np.abs(qd)) <= SAME_START_TOLERANCE:
            return Served(path_id, method, stored.trajectory, stored.record, False, time.perf_counter() - began)
        trajectory, record = self._replan(stored, q, qd)
        return Served(path_id, method, trajectory, record, True, time.perf_counter() - began)

    def prepare(self) -> list[str]:
        """Load every stored DP solution's tables (as many as the cache holds) and run each forward pass
        once from its stored start, which compiles it; returns the "path/method" pairs prepared."""
        prepared = []
        for entry in self.db.catalog():
            for method in entry["solutions"]:
                stored = self._solution(entry["path"], method)
                if stored.has_policy and len(prepared) < self._cache_size:
                    try:
                        self._dp_solution(self._context(stored), stored).follow(stored.start_position)
                    except InfeasibleStart:  # tables that do not fit their own start: a request gets the error
                        continue
                    prepared.append(f"{entry['path']}/{method}")
        return prepared

    def _solution(self, path_id: str, method: str) -> StoredSolution:
        """The stored solution, read once per database content: a build that changes the file (SQLite's
        data_version) drops everything read or loaded from it before."""
        version = self.db.data_version()
        if version != self._version:
            self._version = version
            self._solutions.clear()
            self._contexts.clear()
        key = (path_id, method)
        if key not in self._solutions:
            try:
                self._solutions[key] = self.db.solution(path_id, method)
            except KeyError as exc:
                raise ServeError(str(exc.args[0])) from None
        return self._solutions[key]

    def _ordered(self, names: list[str], current: JointStateSample) -> tuple[np.ndarray, np.ndarray]:
        index = {name: i for i, name in enumerate(current.names)}
        missing = [name for name in names if name not in index]
        if missing:
            raise ServeError(f"joint state: joint(s) {', '.join(missing)} missing (has {', '.join(current.names) or 'none'})")
        q = np.array([current.positions[index[name]] for name in names], dtype=float)
        velocities = current.velocities if len(current.velocities) == len(current.names) else [0.0] * len(current.names)
        qd = np.array([velocities[index[name]] for name in names], dtype=float)
        if not (np.isfinite(q).all() and np.isfinite(qd).all()):
            raise ServeError(f"joint state: non-finite position or velocity ({dict(zip(names, q.round(4).tolist()))})")
        return q, qd

    def _context(self, stored: StoredSolution) -> _Context:
        key = (stored.machine, stored.path_id, stored.method)
        context = self._contexts.get(key)
        if context is None:
            context = _Context(self.db.machine_config(stored.machine), stored)
            self._contexts[key] = context
            while len(self._contexts) > self._cache_size:
                self._contexts.popitem(last=False)
        self._contexts.move_to_end(key)
        return context

    def _replan(self, stored: StoredSolution, q: np.ndarray, qd: np.ndarray) -> tuple[JointTrajectoryData, dict[str, Any]]:
        context = self._context(stored)
        crane, problem = context.crane, context.problem
        gap = float(np.linalg.norm(crane.forward(q) - problem.samples.position[0]))
        if gap > self.tip_tolerance:
            raise ServeError(
                f"joint state: the tip is {gap:.3f} m from the start of path {stored.path_id!r} "
                f"(tolerance {self.tip_tolerance} m); move it there first"
            )
        extension = crane.extension
        c0 = float(extension.stroke(q[crane.redundant]))
        v0 = float(extension.arm(q[crane.redundant])[0] * qd[crane.redundant])
        try:
            if stored.has_policy:
                extension_trajectory, evaluation, filtered = smoothed(problem, self._dp_solution(context, stored).follow(c0, v0))
                plan_record = None
            else:
                plan = run_method(replace(problem, start=c0), stored.method)
                extension_trajectory, evaluation = plan.trajectory, plan.evaluation
                plan_record = method_record(plan)
        except InfeasibleStart as exc:
            raise ServeError(f"from the current state (extension {c0:.3f} m): {exc}") from None
        claims = METHODS[stored.method][1]
        broken = [kind for kind in claims if not evaluation["limits"][kind]]
        if broken or not math.isfinite(evaluation["tip_error_max_m"]):
            raise ServeError(f"from the current state (extension {c0:.3f} m) path {stored.path_id!r} would break the {', '.join(broken) or 'reach'} limit")
        trajectory = joint_trajectory(crane, problem.samples, extension_trajectory)
        record = plan_record or {
            "cp_energy_J": evaluation["cp_energy_J"],
            "ls_energy_J": evaluation["ls_energy_J"],
            "limits": evaluation["limits"],
            "limits_ok": True,
            "info": {"filtered": filtered, "certificate": {"checked": False, "reason": "re-planned from another start on the full grid's policy"}},
        }
        return trajectory, record

    def _dp_solution(self, context: _Context, stored: StoredSolution) -> DpSolution:
        if context.solution is None:
            tables = self.db.policy(stored.machine, stored.path_id, stored.method)
            context.solution = DpSolution(
                context.crane,
                context.problem.samples,
                context.problem.grid,  # built for stored.grid
                Cost(stored.cost),
                True,
                tables["cost_to_go"],
                tables["policy"],
            )
        return context.solution


def path_start_state(config: CraneConfig, path_id: str, extension_stroke: float) -> np.ndarray:
    """Joint positions with the tip at the path's start and the extension cylinder at ``extension_stroke``; a negative
    stroke: where the DP starts it (the smallest feasible extension on the config's grid)."""
    crane = Crane(config)
    samples = path_from_config(config, path_id).sample(config.dp.sample_time)
    if extension_stroke < 0.0:
        extension_stroke = start_position(crane, samples, DpGrid.for_path(crane, samples, config.dp.grid))
    motion = crane.motion(tuple(samples.position[0]), (0.0,) * 3, (0.0,) * 3, extension_stroke, 0.0, 0.0, forces=False)
    if not bool(motion.reachable):
        raise ServeError(f"path {path_id!r}: extension {extension_stroke:.3f} m cannot reach the path start")
    return np.array([float(q) for q in motion.q])


def executable_trajectory(
    config: CraneConfig,
    path_id: str,
    method: str,
    *,
    database: str | None = None,
    grid: tuple[int, int, int] | None = None,
    start_extension: float | None = None,
) -> tuple[JointTrajectoryData, dict[str, Any]]:
    """A joint trajectory and its planned record: served from ``database``, else planned now."""
    names = config.joint_names
    if database is not None:
        current = None
        if start_extension is not None:
            current = JointStateSample(names, path_start_state(config, path_id, start_extension).tolist(), [0.0] * len(names))
        with TrajectoryDatabase(database) as db:
            served = TrajectoryService(db).serve(path_id, method, current)
        return served.trajectory, served.record
    crane = Crane(config)
    problem = Problem.build(crane, config, path_id, grid=grid)
    if start_extension is not None:
        problem = replace(problem, start=start_extension)
    plan = served_plan(problem, method)
    return joint_trajectory(crane, problem.samples, plan.trajectory), method_record(plan)
