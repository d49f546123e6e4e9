"""The methods DP is compared with (P-V Section 6, P-VI Section 6): SNS pseudo-inverses and direct collocation.

- ``pseudo_inverse``: instantaneous minimum-norm velocities in actuator space (P-V "Act. p-inv.",
  P-VI "P-inv. (a.)"; optionally weighted by the pump areas, P-V "weighted") or joint space
  (P-VI "P-inv. (j.)"), with the joint-limit saturation of Flacco, De Luca & Khatib (SNS) moved to
  actuator space: no cylinder may cross its velocity bound or, within the step, its stroke. With
  one redundant joint SNS is exact as a clip of the extension velocity (``_least_norm_within``),
  without task scaling, so the path holds (INFERRED: the papers cite SNS, not its details). Only
  the extension is integrated; the other joints come from IK, so the tip path is exact.
  Acceleration limits are not claimed. Being instantaneous, the method can steer into a state
  from which no velocity keeps every bound; it then splits the conflict and reports the step.
- ``direct_collocation``: the reduced problem (state: extension position and velocity, control:
  its acceleration) transcribed by trapezoidal collocation and solved by IPOPT through CasADi, in
  place of DIDO / fmincon. The node count is bootstrapped 20 -> 30 -> 60 -> 90 as P-V did with DIDO,
  each solution seeding the next; the first is seeded with the joint-space pseudo-inverse. The
  pump flow's Heaviside steps are written with a smooth |v| (sum (A_ext + A_ret)/2 |v| +
  (A_ext - A_ret)/2 v, identical to eq. 27 away from v = 0).
- ``multistart_seeds``: initial guesses for the direct method that take the extension to different parts of its
  feasible window, to test P-V's reading that the problem has local minima a global method escapes.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np
from scipy.interpolate import CubicHermiteSpline

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.extras import optional_module
from hydro_ros.models.crane import Crane
from hydro_ros.planning.dp import extension_windows
from hydro_ros.planning.paths import PathSamples, TipPath
from hydro_ros.planning.trajectory import ExtensionTrajectory

BOOTSTRAP_NODES = (20, 30, 60, 90)
SMOOTH_ABS = 1e-4  # m/s: |v| ~ sqrt(v^2 + SMOOTH_ABS^2) in the direct method's pump flow
REPEATS_TO = 0.05  # of the extension window: a multistart seed via a share this close to the start's repeats one to it


def _least_norm_within(offset: np.ndarray, slope: np.ndarray, scale: np.ndarray, weights: np.ndarray,
                       low: np.ndarray, high: np.ndarray) -> tuple[float, bool]:
    """The extension velocity v minimising sum w_i ((offset_i + slope_i v) / scale_i)^2 with every
    cylinder velocity offset_i + slope_i v within [low_i, high_i]; and whether the bounds met at all.

    Every crane here has one redundant joint, so the cylinder velocities that track the tip are
    affine in the extension velocity: SNS (saturate the most critical component, re-solve the rest)
    then reduces to clipping the least-norm v to the interval all bounds leave. Saturating one
    component at a time found that interval's end only when the most critical component was the
    binding one; on the P-V triangle it was not, and the arm crossed a stroke limit.
    Where the bounds leave no interval, v splits the gap between the two that conflict.
    """
    a, b = offset / scale, slope / scale
    best = -float(np.sum(weights * a * b) / np.sum(weights * b * b))
    moving = np.abs(slope) > 1e-12
    ends = np.stack([(low - offset)[moving] / slope[moving], (high - offset)[moving] / slope[moving]])
    lowest, highest = float(np.max(ends.min(axis=0), initial=-np.inf)), float(np.min(ends.max(axis=0), initial=np.inf))
    still = ~moving
    fixed_ok = bool(np.all((offset[still] >= low[still] - 1e-12) & (offset[still] <= high[still] + 1e-12)))
    if lowest > highest:
        return 0.5 * (lowest + highest), False
    return min(max(best, lowest), highest), fixed_ok


def pseudo_inverse(
    crane: Crane, samples: PathSamples, start_position: float, *, space: str = "actuator", weighted: bool = False
) -> tuple[ExtensionTrajectory, dict[str, Any]]:
    """SNS pseudo-inverse run along the path from rest at ``start_position`` (extension stroke)."""
    if space not in ("actuator", "joint"):
        raise InputError(f"pseudo-inverse space {space!r} (actuator or joint)")
    ts = float(samples.time[1] - samples.time[0])
    n = samples.stages
    position = np.empty(n + 1)
    position[0] = start_position
    previous = np.zeros(len(crane.cylinders))
    saturated_steps = failed_steps = 0
    v_max = np.array([c.velocity_max for c in crane.cylinders])
    s_max = np.array([c.stroke_max for c in crane.cylinders])
    for k in range(n):
        tip, tip_vel, tip_acc = samples.at(k)
        # cylinder velocities at extension velocity 0 and 1: tracking the tip makes them affine in it
        motion = crane.motion(tip, tip_vel, tip_acc, position[k], np.array([0.0, 1.0]), 0.0, forces=False)
        velocity = np.array([np.broadcast_to(value, (2,)) for value in motion.v], dtype=float)
        offset, slope = velocity[:, 0], velocity[:, 1] - velocity[:, 0]
        stroke = np.array([np.ravel(value)[0] for value in motion.c], dtype=float)  # position level: one value
        low = np.maximum(-v_max, -stroke / ts)
        high = np.minimum(v_max, (s_max - stroke) / ts)
        if space == "actuator":
            scale = np.ones_like(offset)
            areas = np.array([c.pump_area_extend if p >= 0 else c.pump_area_retract for c, p in zip(crane.cylinders, previous)])
            weights = np.maximum(areas, 1e-6) if weighted else np.ones_like(offset)
        else:
            q = np.array([np.ravel(value)[0] for value in motion.q], dtype=float)
            scale = np.array([float(cylinder.arm(qi)[0]) for cylinder, qi in zip(crane.cylinders, q)])  # joint rates
            weights = np.ones_like(offset)
        extension_velocity, ok = _least_norm_within(offset, slope, scale, weights, low, high)
        cylinder_velocity = offset + slope * extension_velocity
        saturated_steps += int(ok and bool(np.any(np.isclose(cylinder_velocity, low) | np.isclose(cylinder_velocity, high))))
        failed_steps += int(not ok)
        previous = cylinder_velocity
        position[k + 1] = position[k] + ts * extension_velocity
    trajectory = ExtensionTrajectory.from_positions(position, ts, final_velocity=0.0)
    return trajectory, {"saturated_steps": saturated_steps, "unsatisfiable_steps": failed_steps}


def _casadi_math() -> SimpleNamespace:
    ca = optional_module("casadi")

    return SimpleNamespace(
        cos=ca.cos, sin=ca.sin, atan2=ca.atan2, acos=ca.acos, sqrt=ca.sqrt, tanh=ca.tanh, clip_unit=lambda value: value
    )


def direct_collocation(
    crane: Crane,
    path: TipPath,
    samples: PathSamples,
    start_position: float,
    initial_guess: ExtensionTrajectory,
    *,
    nodes: tuple[int, ...] = BOOTSTRAP_NODES,
) -> tuple[ExtensionTrajectory, dict[str, Any]]:
    """Minimum CP energy by trapezoidal direct collocation + IPOPT, bootstrapped over ``nodes``."""
    ca = optional_module("casadi")

    xp = _casadi_math()
    h = crane.hydraulics
    guess_time, guess_c, guess_v = samples.time, initial_guess.position, initial_guess.velocity
    stats: dict[str, Any] = {"nodes": list(nodes), "ipopt": []}
    for count in nodes:
        times = np.linspace(0.0, path.duration, count + 1)
        step = path.duration / count
        position, velocity, acceleration = path.evaluate(times)
        opti = ca.Opti()
        c = opti.variable(count + 1)
        v = opti.variable(count + 1)
        a = opti.variable(count + 1)
        opti.subject_to(c[1:] == c[:-1] + 0.5 * step * (v[1:] + v[:-1]))
        opti.subject_to(v[1:] == v[:-1] + 0.5 * step * (a[1:] + a[:-1]))
        opti.subject_to(c[0] == start_position)
        opti.subject_to(v[0] == 0.0)
        opti.subject_to(v[-1] == 0.0)
        columns = [[ca.DM(values[:, axis]) for axis in range(3)] for values in (position, velocity, acceleration)]
        motion = crane.motion(*columns, c, v, a, xp=xp, forces=False)
        flow = 0.0
        decision = ca.vertcat(c, v, a)
        for cylinder, qi, vi, ai in zip(crane.cylinders, motion.q, motion.v, motion.a):
            for value, low, high in (
                (qi, cylinder.q_min, cylinder.q_max),
                (vi, -cylinder.velocity_max, cylinder.velocity_max),
                (ai, -cylinder.acceleration_max, cylinder.acceleration_max),
            ):
                if ca.depends_on(value, decision):  # the base follows the path alone: nothing to decide
                    opti.subject_to(opti.bounded(low, value, high))
            mean = 0.5 * (cylinder.pump_area_extend + cylinder.pump_area_retract)
            half = 0.5 * (cylinder.pump_area_extend - cylinder.pump_area_retract)
            flow = flow + mean * ca.sqrt(vi * vi + SMOOTH_ABS**2) + half * vi
        power = h["supply_pressure_cp"] * flow / h["efficiency"]
        opti.minimize(0.5 * step * (ca.sum1(power[:-1]) + ca.sum1(power[1:])))
        opti.set_initial(c, np.interp(times, guess_time, guess_c))
        opti.set_initial(v, np.interp(times, guess_time, guess_v))
        opti.set_initial(a, np.gradient(np.interp(times, guess_time, guess_v), times))
        opti.solver("ipopt", {"print_time": False}, {"print_level": 0, "sb": "yes", "max_iter": 3000, "tol": 1e-8})
        try:
            solution = opti.solve()
            guess_c, guess_v = np.asarray(solution.value(c)).ravel(), np.asarray(solution.value(v)).ravel()
            status = solution.stats()["return_status"]
        except RuntimeError:
            guess_c, guess_v = np.asarray(opti.debug.value(c)).ravel(), np.asarray(opti.debug.value(v)).ravel()
            status = opti.stats()["return_status"]
        guess_time = times
        stats["ipopt"].append({"nodes": count, "status": status})
    # the collocation polynomial between nodes: cubic Hermite through (c, v), sampled at T_s
    reconstruction = CubicHermiteSpline(guess_time, guess_c, guess_v)
    trajectory = ExtensionTrajectory.from_positions(reconstruction(samples.time), float(samples.time[1]), final_velocity=0.0)
    stats["converged"] = all(entry["status"] == "Solve_Succeeded" for entry in stats["ipopt"])
    return trajectory, stats


def multistart_seeds(
    crane: Crane, samples: PathSamples, start_position: float, shares: tuple[float, ...]
) -> dict[str, ExtensionTrajectory]:
    """Initial guesses for ``direct_collocation`` from rest at ``start_position`` that differ in where they take the extension.

    Each is written as a share of the extension window (``extension_windows``: 0 its least, 1 its greatest stroke at which
    every joint keeps its position limits), so every seed keeps the position limits though the window moves along the path.
    For each share s: ``to s`` blends (half a cosine) from the start's share to s at the end; ``via s`` reaches s halfway
    and blends back to the start's share, unless s is within ``REPEATS_TO`` of the start's share (it would nearly repeat
    ``to s``). The blends start and end at rest in share; the window's own motion is not.
    """
    if not shares or any(not 0.0 <= share <= 1.0 for share in shares):
        raise InputError(f"multistart shares {shares}: each in [0, 1] of the extension window")
    window = extension_windows(crane, samples)
    low, width = window[:, 0], window[:, 1] - window[:, 0]
    if not low[0] <= start_position <= window[0, 1]:
        raise InputError(f"multistart start {start_position:.4f} m: outside the path start's window "
                         f"[{low[0]:.4f}, {window[0, 1]:.4f}] m")
    start_share = (start_position - low[0]) / width[0] if width[0] > 0.0 else 0.0
    phase = samples.time / samples.time[-1]
    rise = 0.5 * (1.0 - np.cos(np.pi * phase))  # 0 -> 1 at rest at both ends
    rise_and_fall = 0.5 * (1.0 - np.cos(2.0 * np.pi * phase))  # 0 -> 1 at mid-path -> 0
    ts = float(samples.time[1] - samples.time[0])
    seeds = {}
    for share in shares:
        blends = [(f"to {share:g}", rise)]
        if abs(share - start_share) > REPEATS_TO:
            blends.append((f"via {share:g}", rise_and_fall))
        for label, blend in blends:
            profile = low + (start_share + (share - start_share) * blend) * width
            profile[0] = start_position  # the window's share of it is exact only to rounding
            seeds[label] = ExtensionTrajectory.from_positions(profile, ts, final_velocity=0.0)
    return seeds
