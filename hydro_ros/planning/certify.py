"""The planner's certificate (issue 55): a DP trajectory that is served is never above the best baseline that keeps every
limit, in the DP's own realised energy, by more than CERTIFIED.

The full grid's DP can be a few per cent above a pseudo-inverse where the optimum rides a limit that moves along the path:
its velocity nodes are too coarse there (docs/motion.md). What the catalog stores and a path planned on request gets is
therefore :func:`served_plan`: the DP as :func:`problem.run_method` plans it, held to the certificate. What ``dp compare``
and the savings map compare is the DP as P-V ran it.
"""

from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.planning.costs import Cost
from hydro_ros.planning.dp import TUBE_HALF_WIDTH, TUBE_VELOCITY_PAD, DpGrid
from hydro_ros.planning.polish import POLISH_ITERATIONS, POLISH_KNOTS, polish
from hydro_ros.planning.problem import METHODS, Plan, Problem, plan_dp, run_method
from hydro_ros.planning.trajectory import Evaluation, ExtensionTrajectory, evaluate

CERTIFIED = 0.005  # the share above the best feasible baseline a DP's realised energy may be
CERTIFIED_COSTS = (Cost.CP, Cost.LS)  # the energies a baseline is scored in; the other costs have none to be held to
# the baselines a served DP is held to: the direct method takes minutes a path, so only the bench's certificate
# (bench/dp.py) holds the DP to it too
CERTIFYING_BASELINES = ("pinv_actuator", "pinv_joint", "pinv_actuator_weighted")


def keeps_every_limit(evaluation: Evaluation) -> bool:
    return all(evaluation["limits"].values()) and evaluation["tip_error_max_m"] < 1e-6


def certified(problem: Problem, plan: Plan, cost: Cost) -> Plan:
    """``plan``, a DP's in ``cost``, held to the certificate: its realised energy in that cost at most CERTIFIED above the
    best pseudo-inverse that keeps every limit. Where the full grid's DP is further above, or breaks a limit, the DP is
    planned again on a grid narrowed to a tube around that baseline (``DpGrid.around``); where neither is within, both
    are polished (``planning.polish``). The least of them that keeps every limit is returned (the full grid's where none
    does): always a DP's trajectory, never the baseline's. A refinement that fails is recorded and the best so far kept.
    ``info`` is the served candidate's own (the full grid's under ``info["full_grid"]`` when another is served), and
    ``info["certificate"]`` says what was tried and whether the bound was reached; the plan's solution stays the full
    grid's (its policy serves other starts, not held to the certificate)."""
    if cost not in CERTIFIED_COSTS:
        return _with(plan, {"checked": False, "reason": f"no baseline is scored in {cost.value}"})
    began = time.perf_counter()
    key = f"{cost.value}_energy_J"
    feasible = [p for p in (run_method(problem, method) for method in CERTIFYING_BASELINES) if keeps_every_limit(p.evaluation)]
    if not feasible:
        return _with(plan, {"checked": False, "reason": "no pseudo-inverse keeps every limit"})
    baseline = min(feasible, key=lambda p: p.evaluation[key])
    bound = baseline.evaluation[key] * (1.0 + CERTIFIED)
    served = ("full_grid", plan.trajectory, plan.evaluation, plan.info or {})
    tried: list[dict[str, Any]] = [{"candidate": "full_grid", "energy_J": plan.evaluation[key], "limits_kept": keeps_every_limit(plan.evaluation)}]
    record: dict[str, Any] = {"checked": True, "baseline": baseline.method, "baseline_J": baseline.evaluation[key]}

    def take(name: str, trajectory: ExtensionTrajectory, evaluation: Evaluation, info: dict[str, Any]) -> None:
        nonlocal served
        tried.append({"candidate": name, "energy_J": evaluation[key], "limits_kept": keeps_every_limit(evaluation)})
        if keeps_every_limit(evaluation) and (evaluation[key] < served[2][key] or not keeps_every_limit(served[2])):
            served = (name, trajectory, evaluation, info)

    def short(served_now: tuple) -> bool:
        return not keeps_every_limit(served_now[2]) or served_now[2][key] > bound

    sources = [("full_grid", plan.trajectory)]
    if short(served):
        try:
            tube = plan_dp(replace(problem, grid=DpGrid.around(problem.crane, problem.samples, baseline.trajectory, problem.grid.shape)), cost)
            sources.append(("tube", tube.trajectory))
            take("tube", tube.trajectory, tube.evaluation, tube.info or {})
        except (InputError, ValueError, np.linalg.LinAlgError) as exc:  # InfeasibleStart is an InputError
            tried.append({"candidate": "tube", "error": f"{type(exc).__name__}: {exc}"})
    if short(served):
        for source, trajectory in sources:
            name = f"{source}_polished"
            try:
                moved, info = polish(problem.crane, problem.samples, trajectory, cost)
            except (ValueError, np.linalg.LinAlgError) as exc:
                tried.append({"candidate": name, "error": f"{type(exc).__name__}: {exc}"})
                continue
            if info["improved"]:
                take(name, moved, evaluate(problem.crane, problem.samples, moved), {"polished_from": source, "polish": info})
            else:
                tried.append({"candidate": name, "improved": False, "status": info["status"]})
    name, trajectory, evaluation, info = served
    record |= {"tried": tried, "served": name, "served_J": evaluation[key], "over_baseline": evaluation[key] / record["baseline_J"] - 1.0,
               "limits_kept": keeps_every_limit(evaluation), "certified": not short(served),
               "seconds": round(time.perf_counter() - began, 3)}
    if name != "full_grid":
        info = info | {"full_grid": plan.info or {}}
    return replace(plan, trajectory=trajectory, evaluation=evaluation, seconds=plan.seconds + record["seconds"],
                   info=info | {"certificate": record})


def _with(plan: Plan, certificate: dict[str, Any]) -> Plan:
    return replace(plan, info=(plan.info or {}) | {"certificate": certificate})


def served_plan(problem: Problem, method: str) -> Plan:
    """``method`` planned on ``problem`` as it is served: a DP held to the certificate."""
    plan = run_method(problem, method)
    cost = METHODS[method][0]
    return certified(problem, plan, cost) if cost is not None else plan


def certificate_inputs(method: str) -> dict[str, Any] | None:
    """What ``method``'s served plans are held to and how (a stored plan's inputs name it: a database planned under
    another certificate is planned again); None for a method that is not held to one."""
    if METHODS[method][0] not in CERTIFIED_COSTS:
        return None
    return {"share": CERTIFIED, "baselines": list(CERTIFYING_BASELINES), "tube": [TUBE_HALF_WIDTH, TUBE_VELOCITY_PAD],
            "polish": [POLISH_KNOTS, POLISH_ITERATIONS]}
