"""Stage costs of the energy-optimal redundancy resolution (P-V Section 5, P-VI Sections 4.2-4.3).

- ``cp``: constant-pressure system, p_s Q_p / eta (P-V eq. 31, P-VI eq. 43); load-independent.
- ``ls``: load-sensing system, (max driven chamber pressure + Delta p_LS) Q_p / eta (P-V eqs. 32-35,
  P-VI eqs. 36, 40-41) with the steady-state chamber pressures of P-VI eqs. 23-28.
- ``actuator``: positive actuator power sum max(F_i v_i, 0) (P-VI "A. En.", P-V "Pos. actuator").
- ``extension``: extension cylinder velocity squared (P-VI "ext.").
- ``velocity``: sum of squared cylinder velocities (P-V "Act. velocity").

The hydraulic laws they price live in ``models/crane_hydraulics.py``.
"""

from __future__ import annotations

from enum import Enum

import numpy as np

from hydro_ros.models.crane import Crane, Motion
from hydro_ros.models.crane_hydraulics import ls_supply_pressure, total_pump_flow


class Cost(str, Enum):
    CP = "cp"
    LS = "ls"
    ACTUATOR = "actuator"
    EXTENSION = "extension"
    VELOCITY = "velocity"

    @property
    def depends_on_control(self) -> bool:
        """Whether the stage cost changes with the extension acceleration (through the forces)."""
        return self in (Cost.LS, Cost.ACTUATOR)


def stage_power(cost: Cost, crane: Crane, motion: Motion) -> np.ndarray:
    """The stage cost rate (W for the energy costs, m^2/s^2 for the velocity costs)."""
    h = crane.hydraulics
    if cost is Cost.CP:
        return h["supply_pressure_cp"] * total_pump_flow(crane, motion) / h["efficiency"]
    if cost is Cost.LS:
        return ls_supply_pressure(crane, motion) * total_pump_flow(crane, motion) / h["efficiency"]
    if cost is Cost.ACTUATOR:
        return sum(np.maximum(f * v, 0.0) for f, v in zip(motion.force, motion.v))
    if cost is Cost.EXTENSION:
        return motion.v[crane.redundant] ** 2
    return sum(v**2 for v in motion.v)
