"""Execute a joint trajectory on the simulated crane with the P-VI Appendix A controller and measure
it as P-VI's field tests did: pump output energy and the ISO 9283 path accuracy of the tip (Table 4).

Controller (one per cylinder, eqs. A1-A2): the desired cylinder velocity plus a P term on the
position error, through the inverse of the valve's static dead-zone table (DZI). Tracking and
regulation modes (L11659-L11666), INFERRED reading of dp.md section 10: outside the position band
eps_p the controller regulates; inside it, a desired velocity below eps_v leaves the valve closed
so that numerically small references do not move the cylinder and raise the LS pressure. K_p,
eps_p, eps_v and the rate are NOT GIVEN: ``controller:`` in the crane config holds our choices.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.models.crane import Crane
from hydro_ros.planning.database import JointTrajectoryData
from hydro_ros.sim.crane import CranePlant

CONTROLLER_DEFAULTS = {
    "rate": 100.0,  # Hz
    "position_gain": 2.0,  # 1/s
    "position_deadband": 0.005,  # m
    "velocity_deadband": 0.002,  # m/s
    "settle_time": 1.0,  # s the final reference is held after the trajectory
    "log_rate": 100.0,  # Hz of the recorded signals
}
_PATH_DENSITY = 20  # commanded-path points per trajectory sample for the ISO 9283 nearest-point search


def controller_settings(config: dict[str, Any]) -> dict[str, float]:
    settings = dict(CONTROLLER_DEFAULTS)
    settings.update({key: float(value) for key, value in (config.get("controller") or {}).items()})
    return settings


class MotionController:
    """P-VI Appendix A: I = DZI(v_d + K_p e) with tracking / regulation switching, per cylinder."""

    def __init__(self, settings: dict[str, float], dead_zone: float, full_velocity: np.ndarray) -> None:
        self.gain = settings["position_gain"]
        self.position_band = settings["position_deadband"]
        self.velocity_band = settings["velocity_deadband"]
        self.dead_zone = dead_zone
        self.full_velocity = full_velocity

    def inverse_table(self, velocity: np.ndarray) -> np.ndarray:
        """DZI: the command whose steady-state velocity is ``velocity`` (the nominal table, eq. A1)."""
        fraction = np.clip(np.abs(velocity) / self.full_velocity, 0.0, 1.0)
        return np.where(velocity == 0.0, 0.0, np.sign(velocity) * (self.dead_zone + (1.0 - self.dead_zone) * fraction))

    def command(self, position_ref: np.ndarray, velocity_ref: np.ndarray, position: np.ndarray) -> np.ndarray:
        error = position_ref - position
        command = self.inverse_table(velocity_ref + self.gain * error)
        idle = (np.abs(error) <= self.position_band) & (np.abs(velocity_ref) < self.velocity_band)
        return np.where(idle, 0.0, command)


@dataclass
class Execution:
    """Signals at ``log_rate`` and the summary of one executed trajectory."""

    supply: str
    time: np.ndarray
    joint_names: list[str]
    positions: np.ndarray  # (k, joint)
    velocities: np.ndarray
    commands: np.ndarray  # valve commands (k, cylinder)
    pressure_a: np.ndarray
    pressure_b: np.ndarray
    supply_pressure: np.ndarray
    pump_flow: np.ndarray
    tip: np.ndarray  # (k, 3 or 2)
    energy_J: float  # pump output energy over the logged span
    summary: dict[str, Any] = field(default_factory=dict)


def cylinder_reference(crane: Crane, trajectory: JointTrajectoryData) -> tuple[np.ndarray, np.ndarray]:
    """Cylinder strokes and velocities (k x cylinder) of a joint trajectory."""
    strokes = np.stack([c.stroke(trajectory.positions[:, i]) for i, c in enumerate(crane.cylinders)], axis=-1)
    velocities = np.stack([c.arm(trajectory.positions[:, i])[0] * trajectory.velocities[:, i] for i, c in enumerate(crane.cylinders)], axis=-1)
    return strokes, velocities


def iso9283_path_accuracy(actual: np.ndarray, commanded: np.ndarray) -> float:
    """Largest distance from an actual tip point to the commanded path (ISO 9283 AT_p, not time-synchronised)."""
    fine = np.linspace(0.0, len(commanded) - 1.0, (len(commanded) - 1) * _PATH_DENSITY + 1)
    dense = np.stack([np.interp(fine, np.arange(len(commanded)), commanded[:, j]) for j in range(commanded.shape[1])], axis=-1)
    distance, _ = cKDTree(dense).query(actual)
    return float(distance.max())


class ClosedLoop:
    """Plant and controller stepped together; ``follow`` sets the trajectory, ``advance`` runs it."""

    def __init__(self, config: dict[str, Any], supply: str, start: np.ndarray, *, seed: int = 0) -> None:
        self.settings = controller_settings(config)
        self.plant = CranePlant(config, supply, start, seed=seed)
        self.controller = MotionController(self.settings, self.plant.settings["valve_dead_zone"], self.plant.nominal_full_velocity)
        self.control_every = max(int(round(1.0 / (self.settings["rate"] * self.plant.dt))), 1)
        self.steps = 0
        self.command = np.zeros(len(self.plant.crane.cylinders))
        self.t_ref = np.array([0.0])
        self.strokes_ref = self.plant.state.stroke[None, :].copy()
        self.velocities_ref = np.zeros_like(self.strokes_ref)
        self.started = 0.0

    @property
    def time(self) -> float:
        return self.steps * self.plant.dt

    def follow(self, trajectory: JointTrajectoryData) -> None:
        """Track ``trajectory`` from now on (its t = 0 is the current time)."""
        self.strokes_ref, self.velocities_ref = cylinder_reference(self.plant.crane, trajectory)
        self.t_ref = trajectory.time
        self.started = self.time

    def advance(self) -> None:
        if self.steps % self.control_every == 0:
            t = self.time - self.started
            columns = range(self.strokes_ref.shape[1])
            reference = np.array([np.interp(t, self.t_ref, self.strokes_ref[:, i]) for i in columns])
            velocity = np.array([np.interp(t, self.t_ref, self.velocities_ref[:, i], right=0.0) for i in columns])
            self.command = self.controller.command(reference, velocity, self.plant.state.stroke)
        self.plant.step(self.command)
        self.steps += 1


def execute(config: dict[str, Any], trajectory: JointTrajectoryData, supply: str, *, seed: int = 0) -> Execution:
    """Run the trajectory on a ``CranePlant`` from its first point; hold the end for ``settle_time``."""
    loop = ClosedLoop(config, supply, trajectory.positions[0], seed=seed)
    loop.follow(trajectory)
    plant, crane = loop.plant, loop.plant.crane
    log_every = max(int(round(1.0 / (loop.settings["log_rate"] * plant.dt))), 1)
    steps = int(round((trajectory.time[-1] + loop.settings["settle_time"]) / plant.dt))
    rows: list[tuple] = []
    for k in range(steps + 1):
        if k % log_every == 0:
            rows.append(log_row(loop))
        loop.advance()
    execution = execution_from_rows(supply, trajectory.joint_names, rows, crane)
    execution.summary = measures(crane, trajectory, execution, seed)
    return execution


def log_row(loop: ClosedLoop) -> tuple:
    motion = loop.plant.joint_motion()
    s = loop.plant.state
    return (loop.time, motion.q, motion.qd, loop.command.copy(), s.pressure_a.copy(), s.pressure_b.copy(), s.supply_pressure, s.pump_flow, s.energy)


def execution_from_rows(supply: str, joint_names: list[str], rows: list[tuple], crane: Crane) -> Execution:
    positions = np.array([row[1] for row in rows], dtype=float)
    return Execution(
        supply=supply,
        time=np.array([row[0] for row in rows]),
        joint_names=list(joint_names),
        positions=positions,
        velocities=np.array([row[2] for row in rows], dtype=float),
        commands=np.array([row[3] for row in rows]),
        pressure_a=np.array([row[4] for row in rows]),
        pressure_b=np.array([row[5] for row in rows]),
        supply_pressure=np.array([row[6] for row in rows]),
        pump_flow=np.array([row[7] for row in rows]),
        tip=crane.forward(positions),
        energy_J=float(rows[-1][8] - rows[0][8]),
    )


def measures(crane: Crane, trajectory: JointTrajectoryData, execution: Execution, seed: int) -> dict[str, Any]:
    """P-VI's field-test measures of one run: pump energy, ISO 9283 path accuracy, tracking errors, peaks."""
    commanded_tip = crane.forward(trajectory.positions)
    t = execution.time - execution.time[0]
    reference = np.stack([np.interp(t, trajectory.time, trajectory.positions[:, i]) for i in range(trajectory.positions.shape[1])], axis=-1)
    joint_error = np.abs(execution.positions - reference).max(axis=0)
    return {
        "supply": execution.supply,
        "energy_J": execution.energy_J,
        "path_accuracy_iso9283_m": iso9283_path_accuracy(execution.tip, commanded_tip),
        "final_tip_error_m": float(np.linalg.norm(execution.tip[-1] - commanded_tip[-1])),
        "joint_error_max": dict(zip(trajectory.joint_names, joint_error.round(5).tolist())),
        "supply_pressure_peak_Pa": float(execution.supply_pressure.max()),
        "pump_flow_peak_m3s": float(execution.pump_flow.max()),
        "duration_s": float(t[-1]),
        "seed": seed,
    }


def write_bag(execution: Execution, path: Path, truth: dict[str, Any], pressure_variance: float = 1e10) -> Path:
    """The executed run as a contract bag (every joint in one JointState, per-cylinder pressures)."""
    actuators = {name: name for name in execution.joint_names}  # a crane's cylinders are named after their joints
    with ContractBagWriter(path, actuators=actuators, pressure_variance=pressure_variance) as writer:
        for k, t in enumerate(execution.time):
            writer.write_machine_sample(
                int(round(t * 1e9)),
                (execution.positions[k].tolist(), execution.velocities[k].tolist()),
                (execution.pressure_a[k].tolist(), execution.pressure_b[k].tolist()),
                float(execution.supply_pressure[k]),
                execution.commands[k].tolist(),
            )
        writer.set_truth(truth)
    return path
