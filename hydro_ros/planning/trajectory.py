"""Extension trajectories, their full crane motion and their evaluation (energies, limits, tip error).

Every method of the comparison hands over the extension cylinder's position samples; velocity and
acceleration follow by the forward differences of the DP's Euler model (c_{k+1} = c_k + T_s v_k,
v_{k+1} = v_k + T_s a_k), and the other joints by inverse kinematics, so all methods are scored by
one function on the same footing.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from scipy.ndimage import gaussian_filter1d

from hydro_ros.models.crane import Crane, Motion
from hydro_ros.models.crane_hydraulics import ls_supply_pressure, total_pump_flow
from hydro_ros.planning.costs import Cost, stage_power
from hydro_ros.planning.paths import PathSamples

# limits hold to 0.5 % after the 5 Hz filter and the differencing (claims are checked against this)
LIMIT_TOLERANCE = 0.005


@dataclass(frozen=True)
class ExtensionTrajectory:
    """Extension cylinder position, velocity and acceleration at t_k, k = 0..N."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray
    sample_time: float

    @classmethod
    def from_positions(cls, position: np.ndarray, sample_time: float, final_velocity: float = 0.0) -> ExtensionTrajectory:
        position = np.asarray(position, dtype=float)
        velocity = np.append(np.diff(position) / sample_time, final_velocity)
        acceleration = np.append(np.diff(velocity) / sample_time, 0.0)
        return cls(position, velocity, acceleration, sample_time)

    def filtered(self, cutoff_hz: float) -> ExtensionTrajectory:
        """Zero-phase low-pass of the position with -3 dB at ``cutoff_hz`` (P-VI: 5 Hz, filter type NOT GIVEN).

        INFERRED choice: a Gaussian kernel. Its impulse response is non-negative, so the filtered
        extension velocity and acceleration are averages of the DP's and stay within the limits
        the DP enforced (a Butterworth's ringing pushed a bang-bang acceleration 3 % over its
        limit). Edges are padded with the end values, which keeps the rest-to-rest ends at rest;
        the other joints are recomputed by IK afterwards, so the tip path stays exact.
        """
        sigma_s = math.sqrt(math.log(2.0)) / (2.0 * math.pi * cutoff_hz)
        smooth = gaussian_filter1d(self.position, sigma_s / self.sample_time, mode="nearest", truncate=6.0)
        return ExtensionTrajectory.from_positions(smooth, self.sample_time, final_velocity=0.0)


def crane_motion(crane: Crane, samples: PathSamples, trajectory: ExtensionTrajectory, *, forces: bool = True) -> Motion:
    """Joint and cylinder motion of every sample (vectorised over k)."""
    return crane.motion(
        tuple(samples.position.T),
        tuple(samples.velocity.T),
        tuple(samples.acceleration.T),
        trajectory.position,
        trajectory.velocity,
        trajectory.acceleration,
        forces=forces,
    )


class Evaluation(TypedDict):
    """One trajectory scored: energies over the stages, peaks, the tip error and each limit kind kept or not."""
    cp_energy_J: float
    ls_energy_J: float
    actuator_energy_J: float
    extension_velocity_cost: float
    pump_flow_peak_m3s: float
    ls_supply_pressure_peak_Pa: float
    tip_error_max_m: float
    final_velocity: float
    limits: dict[str, bool]
    limit_margins: dict[str, float]  # the largest use of a limit kind, 1.0 at the limit


def evaluate(crane: Crane, samples: PathSamples, trajectory: ExtensionTrajectory) -> Evaluation:
    """Energies (sum over stages k < N of T_s times the stage power), limit checks and tip error."""
    motion = crane_motion(crane, samples, trajectory)
    ts = trajectory.sample_time
    stages = slice(0, samples.stages)
    checks = crane.limit_checks(motion, tolerance=LIMIT_TOLERANCE)
    checks["acceleration"][-1] = True  # a_N is not applied: the motion ends at t_N
    q = np.stack(motion.q, axis=-1)
    tip_error = np.linalg.norm(crane.forward(q) - samples.position, axis=-1)
    flow = total_pump_flow(crane, motion)
    supply = ls_supply_pressure(crane, motion)
    return {
        "cp_energy_J": float(ts * stage_power(Cost.CP, crane, motion)[stages].sum()),
        "ls_energy_J": float(ts * stage_power(Cost.LS, crane, motion)[stages].sum()),
        "actuator_energy_J": float(ts * stage_power(Cost.ACTUATOR, crane, motion)[stages].sum()),
        "extension_velocity_cost": float(ts * stage_power(Cost.EXTENSION, crane, motion)[stages].sum()),
        "pump_flow_peak_m3s": float(np.nanmax(flow)),
        "ls_supply_pressure_peak_Pa": float(np.nanmax(supply[stages])),
        "tip_error_max_m": float(np.nanmax(tip_error)) if np.isfinite(tip_error).all() else float("inf"),
        "final_velocity": float(np.abs(np.stack(motion.qd, axis=-1)[-1]).max()),
        "limits": {kind: bool(mask.all()) for kind, mask in checks.items()},
        "limit_margins": _margins(crane, motion),
    }


def _margins(crane: Crane, motion: Motion) -> dict[str, float]:
    """Largest use of each limit kind as a fraction of the limit (1.0 = at the limit)."""
    velocity = max(float(np.nanmax(np.abs(v))) / c.velocity_max for c, v in zip(crane.cylinders, motion.v))
    acceleration = max(float(np.nanmax(np.abs(a[:-1]))) / c.acceleration_max for c, a in zip(crane.cylinders, motion.a))
    return {"velocity": velocity, "acceleration": acceleration}


@dataclass(frozen=True)
class JointTrajectoryData:
    """A stored joint trajectory: t_k, joint positions / velocities / accelerations (k x joint)."""

    joint_names: list[str]
    time: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray
    accelerations: np.ndarray
    extension: np.ndarray  # extension cylinder stroke at t_k (the DP state)


def joint_trajectory(crane: Crane, samples: PathSamples, trajectory: ExtensionTrajectory) -> JointTrajectoryData:
    """Every joint along the path: the extension as planned, the others by inverse kinematics."""
    motion = crane_motion(crane, samples, trajectory, forces=False)
    return JointTrajectoryData(
        joint_names=list(crane.names),
        time=samples.time,
        positions=np.stack(motion.q, axis=-1),
        velocities=np.stack(motion.qd, axis=-1),
        accelerations=np.stack(motion.qdd, axis=-1),
        extension=trajectory.position,
    )


def joint_table(crane: Crane, samples: PathSamples, trajectory: ExtensionTrajectory) -> dict[str, Any]:
    """The joint trajectory as JSON-ready lists (positions, velocities, accelerations per joint)."""
    data = joint_trajectory(crane, samples, trajectory)
    return {
        "joint_names": data.joint_names,
        "time_s": data.time.tolist(),
        "positions": data.positions.tolist(),
        "velocities": data.velocities.tolist(),
        "accelerations": data.accelerations.tolist(),
    }
