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
from hydro_ros.planning.crane import Crane
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


def execute(config: dict[str, Any], trajectory: JointTrajectoryData, supply: str, *, seed: int = 0) -> Execution:
    """Run the trajectory on a ``CranePlant`` from its first point; hold the end for ``settle_time``."""
    settings = controller_settings(config)
    plant = CranePlant(config, supply, trajectory.positions[0], seed=seed)
    crane = plant.crane
    controller = MotionController(settings, plant.settings["valve_dead_zone"], plant.nominal_full_velocity)
    strokes_ref, velocities_ref = cylinder_reference(crane, trajectory)
    t_ref = trajectory.time
    dt = plant.dt
    control_every = max(int(round(1.0 / (settings["rate"] * dt))), 1)
    log_every = max(int(round(1.0 / (settings["log_rate"] * dt))), 1)
    steps = int(round((t_ref[-1] + settings["settle_time"]) / dt))
    rows: list[tuple] = []
    command = np.zeros(len(crane.cylinders))
    for k in range(steps + 1):
        t = k * dt
        if k % control_every == 0:
            reference = np.array([np.interp(t, t_ref, strokes_ref[:, i]) for i in range(strokes_ref.shape[1])])
            velocity = np.array([np.interp(t, t_ref, velocities_ref[:, i], right=0.0) for i in range(strokes_ref.shape[1])])
            command = controller.command(reference, velocity, plant.state.stroke)
        if k % log_every == 0:
            motion = plant.joint_motion()
            s = plant.state
            rows.append((t, motion.q, motion.qd, command.copy(), s.pressure_a.copy(), s.pressure_b.copy(), s.supply_pressure, s.pump_flow, s.energy))
        plant.step(command)
    time_s = np.array([row[0] for row in rows])
    positions = np.array([row[1] for row in rows], dtype=float)
    execution = Execution(
        supply=supply,
        time=time_s,
        joint_names=list(trajectory.joint_names),
        positions=positions,
        velocities=np.array([row[2] for row in rows], dtype=float),
        commands=np.array([row[3] for row in rows]),
        pressure_a=np.array([row[4] for row in rows]),
        pressure_b=np.array([row[5] for row in rows]),
        supply_pressure=np.array([row[6] for row in rows]),
        pump_flow=np.array([row[7] for row in rows]),
        tip=crane.forward(positions),
    )
    commanded_tip = crane.forward(trajectory.positions)
    joint_error = positions[: len(time_s)] - np.stack([np.interp(time_s, t_ref, trajectory.positions[:, i]) for i in range(positions.shape[1])], axis=-1)
    execution.summary = {
        "supply": supply,
        "energy_J": float(rows[-1][8]),
        "path_accuracy_iso9283_m": iso9283_path_accuracy(execution.tip, commanded_tip),
        "final_tip_error_m": float(np.linalg.norm(execution.tip[-1] - commanded_tip[-1])),
        "joint_error_max": dict(zip(trajectory.joint_names, np.abs(joint_error).max(axis=0).round(5).tolist())),
        "supply_pressure_peak_Pa": float(execution.supply_pressure.max()),
        "pump_flow_peak_m3s": float(execution.pump_flow.max()),
        "duration_s": float(time_s[-1]),
        "seed": seed,
    }
    return execution


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
