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
    # pressure-compensated mobile valves only (docs/interface.md section 1), else None
    pilot_pressure_1: np.ndarray | None = None
    pilot_pressure_2: np.ndarray | None = None
    compensator_pressure: np.ndarray | None = None
    ls_pressure: np.ndarray | None = None  # machine-wide, (n,)

    @property
    def mobile(self) -> bool:
        return self.pilot_pressure_1 is not None

    def __len__(self) -> int:
        return len(self.times)

    def as_columns(self) -> Samples:
        """One actuator's (n,) arrays as (n, 1) columns, the monitor's layout."""
        column = {f.name: getattr(self, f.name) for f in fields(self)}
        for name in PER_ACTUATOR:
            if column[name] is not None:
                column[name] = np.asarray(column[name]).reshape(len(self.times), -1)
        return Samples(**column)

    def slice(self, part: slice) -> Samples:
        return Samples(**{f.name: None if getattr(self, f.name) is None else np.asarray(getattr(self, f.name))[part]  # type: ignore[arg-type]
                          for f in fields(self)})  # the optional mobile columns stay None


PER_ACTUATOR = ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command",
                "pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")
