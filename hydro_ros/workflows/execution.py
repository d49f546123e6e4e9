"""Execute a joint trajectory on the simulated crane with the P-VI Appendix A controller
(``hydro_ros.planning.controller``) and measure it as P-VI's field tests did: pump output energy and
the ISO 9283 path accuracy of the tip (Table 4).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.crane import CraneConfig
from hydro_ros.models.crane import Crane
from hydro_ros.planning.controller import CylinderReference, MotionController
from hydro_ros.planning.database import JointTrajectoryData
from hydro_ros.sim.closed_loop_crane import CranePlant

_PATH_DENSITY = 20  # commanded-path points per trajectory sample for the ISO 9283 nearest-point search


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


def iso9283_path_accuracy(actual: np.ndarray, commanded: np.ndarray) -> float:
    """Largest distance from an actual tip point to the commanded path (ISO 9283 AT_p, not time-synchronised)."""
    fine = np.linspace(0.0, len(commanded) - 1.0, (len(commanded) - 1) * _PATH_DENSITY + 1)
    dense = np.stack([np.interp(fine, np.arange(len(commanded)), commanded[:, j]) for j in range(commanded.shape[1])], axis=-1)
    distance, _ = cKDTree(dense).query(actual)
    return float(distance.max())


class ClosedLoop:
    """Plant and controller stepped together; ``follow`` sets the trajectory, ``advance`` runs it."""

    def __init__(self, config: CraneConfig, supply: str, start: np.ndarray, *, seed: int = 0) -> None:
        self.settings = dict(config.controller)
        self.plant = CranePlant(config, supply, start, seed=seed)
        self.controller = MotionController.for_crane(self.plant.crane, config)
        self.control_every = max(int(round(1.0 / (self.settings["rate"] * self.plant.dt))), 1)
        self.steps = 0
        self.command = np.zeros(len(self.plant.crane.cylinders))
        self.reference = CylinderReference.hold(self.plant.crane, np.array(self.plant.joint_motion().q))
        self.started = 0.0

    @property
    def time(self) -> float:
        return self.steps * self.plant.dt

    def follow(self, trajectory: JointTrajectoryData) -> None:
        """Track ``trajectory`` from now on (its t = 0 is the current time)."""
        self.reference = CylinderReference(self.plant.crane, trajectory)
        self.started = self.time

    def advance(self, command: np.ndarray | None = None) -> None:
        """One plant step; ``command`` (valve commands of an outside controller) replaces this loop's own."""
        if command is not None:
            self.command = command
        elif self.steps % self.control_every == 0:
            stroke, velocity = self.reference.at(self.time - self.started)
            self.command = self.controller.command(stroke, velocity, self.plant.state.stroke)
        self.plant.step(self.command)
        self.steps += 1


def execute(config: CraneConfig, trajectory: JointTrajectoryData, supply: str, *, seed: int = 0) -> Execution:
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
