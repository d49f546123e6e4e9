"""A planning problem (crane, path, DP grid, start) and the methods that solve it, by name.

Every method starts from rest at the same extension (the smallest feasible one, P-V / P-VI's first
initial configuration, or P-VI's midpoint), runs the same path samples, and is scored by
``trajectory.evaluate`` (CP and LS energy, limits, tip error). DP references are low-pass filtered
at 5 Hz before scoring, as P-V computed its costs after filtering, unless the filter breaks a limit
(:func:`smoothed`). Serving, the catalog build and ``dp compare`` all plan through :func:`run_method`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any, NotRequired, TypedDict

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import Crane
from hydro_ros.planning.baselines import direct_collocation, pseudo_inverse
from hydro_ros.planning.costs import Cost
from hydro_ros.planning.dp import DpGrid, DpSolution, solve, start_position
from hydro_ros.planning.paths import PathSamples, TipPath, path_from_config
from hydro_ros.planning.trajectory import Evaluation, ExtensionTrajectory, evaluate

ALL_LIMITS = ("position", "velocity", "acceleration")

# method -> (DP cost or None, limits the method claims to keep); docs/interface.md section 5 names first
METHODS: dict[str, tuple[Cost | None, tuple[str, ...]]] = {
    "dp_cp": (Cost.CP, ALL_LIMITS),
    "dp_ls": (Cost.LS, ALL_LIMITS),
    "dp_actuator_energy": (Cost.ACTUATOR, ALL_LIMITS),
    "dp_extension": (Cost.EXTENSION, ALL_LIMITS),
    "pinv_actuator": (None, ("position", "velocity")),
    "pinv_joint": (None, ("position", "velocity")),
    "direct_cp": (None, ALL_LIMITS),
    "dp_velocity": (Cost.VELOCITY, ALL_LIMITS),  # P-V "DP (Act. velocity)"
    "pinv_actuator_weighted": (None, ("position", "velocity")),  # P-V "Act. p-inv. (Weighted)"
}
# the method names of docs/interface.md section 5, named rather than read off the dict order
CONTRACT_METHODS = ("dp_cp", "dp_ls", "dp_actuator_energy", "dp_extension", "pinv_actuator", "pinv_joint", "direct_cp")


@dataclass
class Problem:
    crane: Crane
    config: CraneConfig
    path: TipPath
    samples: PathSamples
    grid: DpGrid
    start: float
    filter_cutoff: float

    @classmethod
    def build(
        cls, crane: Crane, config: CraneConfig, path_id: str, *, grid: tuple[int, int, int] | None = None, start: str = "smallest"
    ) -> Problem:
        path = path_from_config(config, path_id)
        samples = path.sample(config.dp.sample_time)
        try:
            dp_grid = DpGrid.for_path(crane, samples, grid or config.dp.grid)
        except InputError as exc:
            raise InputError(f"path {path_id!r}: {exc}") from None
        return cls(crane, config, path, samples, dp_grid, start_position(crane, samples, dp_grid, start), config.dp.filter_cutoff)


@dataclass
class Plan:
    method: str
    trajectory: ExtensionTrajectory
    evaluation: Evaluation
    seconds: float
    solution: DpSolution | None = None
    info: dict[str, Any] | None = None


def smoothed(problem: Problem, raw: ExtensionTrajectory) -> tuple[ExtensionTrajectory, Evaluation, bool]:
    """A DP reference low-pass filtered, with its evaluation and True, unless the filter breaks a limit the DP kept: the
    filter averages the redundant cylinder's accelerations, which keeps them, but the joints solved for the tip follow it
    nonlinearly, and one of theirs can come out past its limit (up to 0.8 % on the excavator's lift_out with the actuator
    energy cost). Then the DP's own reference, whose every stage keeps every limit, and False."""
    filtered = raw.filtered(problem.filter_cutoff)
    evaluation = evaluate(problem.crane, problem.samples, filtered)
    if all(evaluation["limits"].values()):
        return filtered, evaluation, True
    unfiltered = evaluate(problem.crane, problem.samples, raw)
    if all(unfiltered["limits"].values()):
        return raw, unfiltered, False
    return filtered, evaluation, True


def plan_dp(problem: Problem, cost: Cost, *, progress: bool = False, acceleration_limits: bool = True) -> Plan:
    began = time.perf_counter()
    solution = solve(problem.crane, problem.samples, cost, problem.grid, progress=progress, acceleration_limits=acceleration_limits)
    raw = solution.forward(problem.start)
    trajectory, evaluation, filtered = smoothed(problem, raw)
    seconds = time.perf_counter() - began
    unfiltered = evaluate(problem.crane, problem.samples, raw) if filtered else evaluation
    j0 = int(np.argmin(np.abs(problem.grid.velocities)))
    i0 = int(np.argmin(np.abs(problem.grid.positions[0] - problem.start)))
    info = {
        "predicted_cost": float(solution.cost_to_go[0, i0, j0]),
        "filtered": filtered,
        "unfiltered": {key: unfiltered[key] for key in ("cp_energy_J", "ls_energy_J", "limits")},
    }
    return Plan(f"dp_{cost.value}", trajectory, evaluation, seconds, solution, info)


def _plan_other(problem: Problem, method: str, seed: ExtensionTrajectory | None) -> Plan:
    began = time.perf_counter()
    if method == "direct_cp":
        if seed is None:
            seed, _ = pseudo_inverse(problem.crane, problem.samples, problem.start, space="joint")
        trajectory, info = direct_collocation(problem.crane, problem.path, problem.samples, problem.start, seed)
    else:
        space = "joint" if method == "pinv_joint" else "actuator"
        trajectory, info = pseudo_inverse(
            problem.crane, problem.samples, problem.start, space=space, weighted=method == "pinv_actuator_weighted"
        )
    seconds = time.perf_counter() - began
    return Plan(method, trajectory, evaluate(problem.crane, problem.samples, trajectory), seconds, info=info)


def run_method(problem: Problem, method: str, *, progress: bool = False, seed: ExtensionTrajectory | None = None) -> Plan:
    if method not in METHODS:
        raise InputError(f"method {method!r}: unknown (known: {', '.join(METHODS)})")
    cost, _ = METHODS[method]
    if cost is not None:
        plan = plan_dp(problem, cost, progress=progress)
        plan.method = method
        return plan
    return _plan_other(problem, method, seed)


class MethodRecord(TypedDict):
    """A plan as the comparisons, the savings map and the trajectory database keep it."""
    cp_energy_J: float
    ls_energy_J: float
    limits_ok: bool  # every limit the method claims to keep, kept, on the path
    limits_claimed: list[str]
    limits: dict[str, bool]
    limit_margins: dict[str, float]
    actuator_energy_J: float
    tip_error_max_m: float
    ls_supply_pressure_peak_Pa: float
    pump_flow_peak_m3s: float
    seconds: float
    info: NotRequired[dict[str, Any]]
    relative_cp: NotRequired[float]  # to the best of a comparison (studies.dp_compare)
    relative_ls: NotRequired[float]


def method_record(plan: Plan) -> MethodRecord:
    claims = METHODS[plan.method][1]
    evaluation = plan.evaluation
    record: MethodRecord = {
        "cp_energy_J": evaluation["cp_energy_J"],
        "ls_energy_J": evaluation["ls_energy_J"],
        "limits_ok": all(evaluation["limits"][kind] for kind in claims) and evaluation["tip_error_max_m"] < 1e-6,
        "limits_claimed": list(claims),
        "limits": evaluation["limits"],
        "limit_margins": evaluation["limit_margins"],
        "actuator_energy_J": evaluation["actuator_energy_J"],
        "tip_error_max_m": evaluation["tip_error_max_m"],
        "ls_supply_pressure_peak_Pa": evaluation["ls_supply_pressure_peak_Pa"],
        "pump_flow_peak_m3s": evaluation["pump_flow_peak_m3s"],
        "seconds": round(plan.seconds, 3),
    }
    if plan.info:
        record["info"] = plan.info
    return record
