"""`hydro-ros db build`: precompute every (path, method) of a crane config into the trajectory database.

Work units are independent (one path, one method), so they run in parallel: local processes by
default, or the workers of a Dask cluster when a scheduler address is given (``distributed``'s
executor has the ``concurrent.futures`` interface, so one loop serves both). Workers only compute;
this process alone writes, one transaction per finished unit, so a killed build keeps every
committed unit and the next build skips what is stored with the same inputs.
"""

from __future__ import annotations

import ctypes
import multiprocessing
import os
import signal
import sys
import time
from collections.abc import Callable
from concurrent.futures import Executor, Future, ProcessPoolExecutor, as_completed
from contextlib import ExitStack
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import BuildError, InputError
from hydro_ros.contract.extras import optional_module
from hydro_ros.models.crane import Crane
from hydro_ros.planning.certify import CERTIFIED, certificate_inputs, served_plan
from hydro_ros.planning.database import TrajectoryDatabase, inputs_hash, pack_arrays
from hydro_ros.planning.problem import METHODS, Problem, method_record
from hydro_ros.planning.trajectory import joint_trajectory

# what a catalog holds unless the config's `catalog.methods` says otherwise: the served optimum for
# each supply, the two conventional baselines the operator compares against
DEFAULT_METHODS = ("dp_cp", "dp_ls", "pinv_actuator", "pinv_joint")


@dataclass(frozen=True)
class WorkUnit:
    config: CraneConfig
    path_id: str
    method: str
    grid: tuple[int, int, int]

    @property
    def key(self) -> tuple[str, str, str]:
        return (self.config.name, self.path_id, self.method)

    @property
    def inputs_hash(self) -> str:
        return inputs_hash(self.config, self.path_id, self.method, self.grid, certificate_inputs(self.method))


def plan_units(config: CraneConfig, *, methods: tuple[str, ...] | None = None, grid: tuple[int, int, int] | None = None,
               paths: tuple[str, ...] | None = None) -> list[WorkUnit]:
    """The catalog of a config: its paths (or ``paths``) times the methods, on the DP grid."""
    methods = tuple(methods or config.catalog.get("methods") or DEFAULT_METHODS)
    unknown = [method for method in methods if method not in METHODS]
    if unknown:
        raise InputError(f"method(s) {', '.join(unknown)}: unknown (known: {', '.join(METHODS)})")
    grid = tuple(int(n) for n in (grid or config.catalog.get("grid") or config.dp.grid))
    path_ids = tuple(paths or config.paths)
    missing = [path_id for path_id in path_ids if path_id not in config.paths]
    if missing:
        raise InputError(f"path(s) {', '.join(missing)}: not in config {config.source}")
    return [WorkUnit(config, path_id, method, grid) for path_id in path_ids for method in methods]


def compute_entry(unit: WorkUnit) -> dict[str, Any]:
    """Solve one unit (runs in a worker): the row ``TrajectoryDatabase.put_solution`` writes."""
    crane = Crane(unit.config)
    problem = Problem.build(crane, unit.config, unit.path_id, grid=unit.grid)
    plan = served_plan(problem, unit.method)
    joints = joint_trajectory(crane, problem.samples, plan.trajectory)
    trajectory = pack_arrays(
        time=joints.time, positions=joints.positions, velocities=joints.velocities, accelerations=joints.accelerations,
        extension=joints.extension,
    )
    policy = None
    if plan.solution is not None:
        # float32 halves the blob; the cost-to-go's relative precision (6e-8) is far below the grid's
        policy = pack_arrays(cost_to_go=plan.solution.cost_to_go.astype(np.float32), policy=plan.solution.policy)
    cost = METHODS[unit.method][0]
    return {
        "machine": crane.name,
        "path_id": unit.path_id,
        "method": unit.method,
        "cost": cost.value if cost else None,
        "inputs_hash": unit.inputs_hash,
        "grid": unit.grid,
        "start_position": problem.start,
        "record": method_record(plan),
        "trajectory": trajectory,
        "policy": policy,
        "seconds": plan.seconds,
    }


@dataclass
class BuildReport:
    computed: list[tuple[str, str, str]]
    skipped: list[tuple[str, str, str]]
    seconds: float
    scheduler: str
    # "path/method (why)" of each DP computed in this build that its certificate does not cover (``uncovered``)
    uncertified: list[str] = field(default_factory=list)

    def summary(self) -> str:
        rate = len(self.computed) / self.seconds if self.seconds > 0 else 0.0
        return (
            f"{len(self.computed)} solution(s) computed, {len(self.skipped)} already stored, "
            f"{self.seconds:.1f} s ({rate:.2f} per s) on {self.scheduler}"
            + (f"; not within {CERTIFIED:.1%} of the best feasible pseudo-inverse even refined: {', '.join(self.uncertified)}"
               if self.uncertified else "")
        )


def uncovered(entry: dict[str, Any]) -> str | None:
    """"path/method (why)" of a stored DP that its certificate does not cover; None for one it covers or a method without."""
    certificate = (entry["record"].get("info") or {}).get("certificate") or {}
    if not certificate.get("checked") or certificate["certified"]:
        return None
    why = f"{certificate['over_baseline']:+.2%}" + ("" if certificate["limits_kept"] else ", breaks a limit")
    return f"{entry['path_id']}/{entry['method']} ({why})"


def _single_threaded_worker() -> None:
    # processes times numba's default thread pool each would oversubscribe the cores
    import numba

    numba.set_num_threads(1)
    _die_with_parent()


def _die_with_parent() -> None:
    """A worker of a killed build must not go on computing (Linux: the parent's death sends SIGTERM)."""
    if sys.platform.startswith("linux"):
        pr_set_pdeathsig = 1
        ctypes.CDLL(None, use_errno=True).prctl(pr_set_pdeathsig, signal.SIGTERM)
    parent = multiprocessing.parent_process()
    if parent is not None and os.getppid() != parent.pid:  # the build died while this worker was still starting
        os._exit(1)


def build(
    db: TrajectoryDatabase,
    units: list[WorkUnit],
    *,
    scheduler: str | None = None,
    workers: int | None = None,
    progress: Callable[[WorkUnit], None] | None = None,
) -> BuildReport:
    """Compute the units not yet stored with the same inputs; commit each as it finishes."""
    began = time.perf_counter()
    for config in {id(unit.config): unit.config for unit in units}.values():
        db.add_machine(config)
    stored = db.committed()
    todo = [unit for unit in units if stored.get(unit.key) != unit.inputs_hash]
    skipped = [unit.key for unit in units if stored.get(unit.key) == unit.inputs_hash]
    computed: list[tuple[str, str, str]] = []
    above: list[str] = []

    def store(entry: dict[str, Any]) -> None:
        db.put_solution(entry)
        above.extend(filter(None, [uncovered(entry)]))

    with ExitStack() as stack:
        executor, name = work_executor(stack, scheduler, workers, len(todo))
        if executor is None:
            for unit in todo:
                store(compute_entry(unit))
                computed.append(unit.key)
                if progress:
                    progress(unit)
        else:
            futures: dict[Future, WorkUnit] = {executor.submit(compute_entry, unit): unit for unit in todo}
            for future in as_completed(futures):
                unit = futures[future]
                try:
                    entry = future.result()
                except InputError as exc:  # one unit refused by its input names itself; committed ones stay
                    raise BuildError(f"{unit.path_id}/{unit.method}: {type(exc).__name__}: {exc}") from exc
                store(entry)
                computed.append(unit.key)
                if progress:
                    progress(unit)
    return BuildReport(computed, skipped, time.perf_counter() - began, name, above)


def work_executor(stack: ExitStack, scheduler: str | None, workers: int | None, n_units: int) -> tuple[Executor | None, str]:
    """Where independent units of work run: the Dask cluster at ``scheduler``, else ``workers`` local processes (default
    one per core), else this process (None) for one unit or one worker; and its name for the report."""
    if scheduler:
        distributed = optional_module("distributed")
        try:
            client = stack.enter_context(distributed.Client(scheduler, timeout="10s"))
        except (OSError, TimeoutError) as exc:
            raise InputError(f"--scheduler {scheduler}: no Dask scheduler answers ({exc})") from None
        return stack.enter_context(client.get_executor()), f"Dask scheduler {scheduler}"
    count = workers if workers is not None else (os.cpu_count() or 1)
    if count <= 1 or n_units <= 1:
        return None, "1 local process"
    # spawn, not fork: a parent that has run a DP holds numba's OpenMP pool, which must not be forked
    pool = ProcessPoolExecutor(max_workers=count, mp_context=multiprocessing.get_context("spawn"), initializer=_single_threaded_worker)
    return stack.enter_context(pool), f"{count} local processes"
