"""Time-aligned sensor samples of a machine: what the simulator measures and what the FDI reads."""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np


@dataclass
class Samples:
    """Arrays of one length n: (n,) for one actuator, (n, A) for A actuators (supply is (n,))."""

    times: np.ndarray
    joint_position: np.ndarray
    joint_velocity: np.ndarray
    pressure_a: np.ndarray
    pressure_b: np.ndarray
    supply_pressure: np.ndarray
    valve_command: np.ndarray

    def __len__(self) -> int:
        return len(self.times)

    def as_columns(self) -> "Samples":
        """One actuator's (n,) arrays as (n, 1) columns, the monitor's layout."""
        column = {f.name: np.asarray(getattr(self, f.name)) for f in fields(self)}
        for name in ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command"):
            column[name] = column[name].reshape(len(self.times), -1)
        return Samples(**column)

    def slice(self, part: slice) -> "Samples":
        return Samples(**{f.name: np.asarray(getattr(self, f.name))[part] for f in fields(self)})
