"""A local polish of a DP answer in its own realised cost: the certificate's third way (issue 55).

The DP optimises its discrete problem: Euler steps between grid nodes, cost-to-go interpolated between them. Where the
optimum rides a joint limit that moves along the path, that problem itself is a few per cent worse than the continuous one
(docs/motion.md). The polish takes the DP's trajectory as it is scored (``trajectory.evaluate``) and moves it by a smooth
correction, a clamped cubic B-spline in time whose first two and last two coefficients are held at zero and which is
zero at the first two and last two samples (so the start, its rest and the end's rest stay exactly), to a local
minimum of the same realised cost under every joint and cylinder limit (SLSQP). What it returns is the DP's trajectory
corrected, never another method's; when SLSQP finds nothing better that keeps the limits, the DP's own, said so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from scipy.interpolate import BSpline
from scipy.optimize import minimize

from hydro_ros.models.crane import Crane
from hydro_ros.planning.costs import Cost, stage_power
from hydro_ros.planning.paths import PathSamples
from hydro_ros.planning.trajectory import ExtensionTrajectory, crane_motion, evaluate

POLISH_KNOTS = 24  # interior knots of the correction: a knot per 0.25-0.4 s on the K70M's paths
POLISH_ITERATIONS = 150
MARGIN_SLACK = 1e-6  # of a limit: what SLSQP's constraint tolerance leaves past a limit the DP rides
UNREACHABLE = -1.0  # a constraint value for a state the IK cannot reach (its motion is NaN)


def correction_basis(time: np.ndarray, knots: int) -> np.ndarray:
    """(len(time), knots) cubic B-splines on [t_0, t_N] that vanish with their slope at both ends, and at the first two
    and last two samples exactly: a trajectory's rest there (its first and last differences) stays as it was."""
    inner = np.linspace(time[0], time[-1], knots + 2)
    vector = np.r_[[time[0]] * 3, inner, [time[-1]] * 3]
    basis = BSpline.design_matrix(np.clip(time, time[0], time[-1]), vector, 3).toarray()[:, 2:-2]
    basis[:2] = basis[-2:] = 0.0
    return basis


def _limit_margins(crane: Crane, motion: Any) -> np.ndarray:
    """Every limit of every stage as a margin (>= 0 kept): positions over their span, velocities and accelerations over
    their limit."""
    margins = []
    for cylinder, q, v, a in zip(crane.cylinders, motion.q, motion.v, motion.a):
        span = cylinder.q_max - cylinder.q_min
        margins += [(q - cylinder.q_min) / span, (cylinder.q_max - q) / span, 1.0 - np.abs(v) / cylinder.velocity_max,
                    1.0 - np.abs(a[:-1]) / cylinder.acceleration_max]  # a_N is not applied
    out = np.concatenate(margins)
    return np.where(np.isfinite(out), out, UNREACHABLE)


def polish(crane: Crane, samples: PathSamples, trajectory: ExtensionTrajectory, cost: Cost, *, knots: int = POLISH_KNOTS,
           iterations: int = POLISH_ITERATIONS) -> tuple[ExtensionTrajectory, dict[str, Any]]:
    """``trajectory`` moved to a local minimum of its realised ``cost`` under every limit; with what the polish did."""
    ts = trajectory.sample_time
    stages = slice(0, samples.stages)
    basis = correction_basis(samples.time, knots)
    position = trajectory.position

    def moved(weights: np.ndarray) -> ExtensionTrajectory:
        return ExtensionTrajectory.from_positions(position + basis @ weights, ts, final_velocity=0.0)

    seen: dict[bytes, tuple[float, np.ndarray]] = {}

    def scored(weights: np.ndarray) -> tuple[float, np.ndarray]:
        """The realised cost and the limit margins at ``weights``: SLSQP asks for both at each point and each difference
        step, so one motion serves both."""
        key = weights.tobytes()
        if key not in seen:
            if len(seen) > 4 * len(weights):
                seen.clear()
            motion = crane_motion(crane, samples, moved(weights), forces=cost.depends_on_control)
            with np.errstate(invalid="ignore"):  # a state the IK cannot reach: NaN motion, its margins UNREACHABLE
                seen[key] = float(ts * stage_power(cost, crane, motion)[stages].sum()), _limit_margins(crane, motion)
        return seen[key]

    before, start_margins = scored(np.zeros(basis.shape[1]))
    floor = min(start_margins.min(), 0.0) - MARGIN_SLACK  # no limit used further than the DP's own trajectory used it
    scale = abs(before) if before else 1.0
    result = minimize(lambda w: scored(w)[0] / scale, np.zeros(basis.shape[1]), method="SLSQP",
                      constraints={"type": "ineq", "fun": lambda w: scored(w)[1]}, options={"maxiter": iterations, "ftol": 1e-7})
    candidate = moved(result.x)
    evaluation = evaluate(crane, samples, candidate)
    after, margins = scored(result.x)
    # judged here whatever SLSQP's status: it may stop on constraints it calls incompatible at a point that keeps them all
    kept = all(evaluation["limits"].values()) and evaluation["tip_error_max_m"] < 1e-6 and margins.min() >= floor
    info = {"before_J": before, "after_J": after, "iterations": int(result.nit), "status": result.message,
            "margin_min": float(margins.min()), "improved": bool(kept and after < before)}
    return (candidate if info["improved"] else trajectory), info
