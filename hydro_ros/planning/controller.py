"""The P-VI Appendix A motion controller: what turns a joint trajectory into valve commands.

One controller per cylinder (eqs. A1-A2): the desired cylinder velocity plus a P term on the
position error, through the inverse of the valve's static dead-zone table (DZI). Tracking and
regulation modes (P-VI App. A), INFERRED reading of its wording: outside the position band
eps_p the controller regulates; inside it, a desired velocity below eps_v leaves the valve closed
so that numerically small references do not move the cylinder and raise the LS pressure. K_p,
eps_p, eps_v and the rate are NOT GIVEN: ``planner.controller`` in the machine config holds our choices.

The simulated closed loop (``hydro_ros.workflows.execution``) and the ``trajectory_executor`` node of a
real crane run this same code.
"""

from __future__ import annotations

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.models.crane import Crane
from hydro_ros.models.crane_hydraulics import nominal_valve_table
from hydro_ros.planning.trajectory import JointTrajectoryData


class MotionController:
    """P-VI Appendix A: I = DZI(v_d + K_p e) with tracking / regulation switching, per cylinder."""

    def __init__(self, settings: dict[str, float], dead_zone: float, full_velocity: np.ndarray) -> None:
        self.gain = settings["position_gain"]
        self.position_band = settings["position_deadband"]
        self.velocity_band = settings["velocity_deadband"]
        self.dead_zone = dead_zone
        self.full_velocity = full_velocity

    @classmethod
    def for_crane(cls, crane: Crane, config: CraneConfig) -> MotionController:
        """The controller of ``config`` inverting the nominal valve table of its cylinders."""
        return cls(dict(config.controller), *nominal_valve_table(crane, config))

    def inverse_table(self, velocity: np.ndarray) -> np.ndarray:
        """DZI: the command whose steady-state velocity is ``velocity`` (the nominal table, eq. A1)."""
        fraction = np.clip(np.abs(velocity) / self.full_velocity, 0.0, 1.0)
        return np.where(velocity == 0.0, 0.0, np.sign(velocity) * (self.dead_zone + (1.0 - self.dead_zone) * fraction))

    def command(self, position_ref: np.ndarray, velocity_ref: np.ndarray, position: np.ndarray) -> np.ndarray:
        error = position_ref - position
        command = self.inverse_table(velocity_ref + self.gain * error)
        idle = (np.abs(error) <= self.position_band) & (np.abs(velocity_ref) < self.velocity_band)
        return np.where(idle, 0.0, command)


class CylinderReference:
    """A joint trajectory as cylinder strokes and velocities (k x cylinder), read at any time since its
    start: interpolated inside, the last stroke at rest after the end."""

    def __init__(self, crane: Crane, trajectory: JointTrajectoryData) -> None:
        self.time = trajectory.time
        self.strokes = np.stack([c.stroke(trajectory.positions[:, i]) for i, c in enumerate(crane.cylinders)], axis=-1)
        self.velocities = np.stack(
            [c.arm(trajectory.positions[:, i])[0] * trajectory.velocities[:, i] for i, c in enumerate(crane.cylinders)], axis=-1
        )

    @classmethod
    def hold(cls, crane: Crane, positions: np.ndarray) -> CylinderReference:
        """Stay at the joint positions ``positions``, at rest."""
        held = np.vstack([positions, positions])
        zeros = np.zeros_like(held)
        return cls(crane, JointTrajectoryData(list(crane.names), np.array([0.0, 0.1]), held, zeros, zeros, np.zeros(2)))

    @property
    def duration(self) -> float:
        return float(self.time[-1])

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        columns = range(self.strokes.shape[1])
        stroke = np.array([np.interp(t, self.time, self.strokes[:, i]) for i in columns])
        velocity = np.array([np.interp(t, self.time, self.velocities[:, i], right=0.0) for i in columns])
        return stroke, velocity
