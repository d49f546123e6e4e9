"""Hydraulics of a crane's cylinders in steady state (P-V, P-VI): pump flow and driven-chamber pressures.

The per-cylinder laws are numba ufuncs, so the DP kernel calls the very functions that NumPy
evaluation and the closed-loop plant use.
"""

from __future__ import annotations

import numpy as np
from numba import vectorize

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.models.crane import Crane, Motion


@vectorize(["float64(float64, float64, float64)"], cache=True)
def pump_flow(velocity: float, area_extend: float, area_retract: float) -> float:
    """One cylinder's share of Q_p (P-V eq. 27, P-VI eq. 37) with the exact Heaviside step."""
    if velocity > 0.0:
        return velocity * area_extend
    return -velocity * area_retract


@vectorize(["float64(float64, float64, float64, float64, float64, float64, float64, float64)"], cache=True)
def driven_pressure(
    force: float,
    velocity: float,
    area_a: float,
    area_b: float,
    differential: float,
    compensator_drop: float,
    tank_pressure: float,
    threshold: float,
) -> float:
    """Pressure of the chamber the pump drives, P-VI eq. 41; 0 when idle or over-running.

    Back-pressures with all valve-coefficient ratios 1 (PLACEHOLDER: P-VI gives no valve coefficients):
    extension (A_B/A_A)^2 Delta p_c (eq. 23), retraction (A_A/A_B)^2 Delta p_c (eq. 24); the
    differential spool extends by eqs. 27-28 and retracts like the non-differential one (INFERRED).
    """
    if force * velocity <= 0.0:
        return 0.0
    if velocity > threshold:
        if differential > 0.0:
            net = area_a - area_b
            p_b = force / net + (area_b * area_b * area_a / net**3 + area_a / net) * compensator_drop
            return force / area_a + p_b * area_b / area_a
        back = (area_b / area_a) ** 2 * compensator_drop + tank_pressure
        return force / area_a + area_b / area_a * back
    if velocity < -threshold:
        if area_b <= 0.0:
            return 0.0  # single-acting: lowering drains to tank under the load
        back = (area_a / area_b) ** 2 * compensator_drop + tank_pressure
        return -force / area_b + area_a / area_b * back
    return 0.0


def cylinder_table(crane: Crane) -> np.ndarray:
    """Per-cylinder constants for the kernels: area_a, area_b, differential, pump areas, acceleration limit."""
    return np.array(
        [
            [c.area_a, c.area_b, float(c.differential), c.pump_area_extend, c.pump_area_retract, c.acceleration_max]
            for c in crane.cylinders
        ]
    )


def total_pump_flow(crane: Crane, motion: Motion) -> np.ndarray:
    return sum(pump_flow(v, c.pump_area_extend, c.pump_area_retract) for c, v in zip(crane.cylinders, motion.v))


def ls_supply_pressure(crane: Crane, motion: Motion) -> np.ndarray:
    """p_s = max driven chamber pressure + Delta p_LS (P-VI eq. 40)."""
    h = crane.hydraulics
    pressures = [
        driven_pressure(
            f, v, c.area_a, c.area_b, float(c.differential), h["compensator_drop"], h["tank_pressure"], h["drive_threshold"]
        )
        for c, f, v in zip(crane.cylinders, motion.force, motion.v)
    ]
    return np.maximum.reduce([np.asarray(p, dtype=float) for p in pressures]) + h["ls_margin"]


def nominal_valve_table(crane: Crane, config: CraneConfig) -> tuple[float, np.ndarray]:
    """Dead zone and velocity at full command (m/s per cylinder) of the machine's valves (``planner.plant``)."""
    plant = config.plant
    factor = float(plant["full_command_velocity_factor"])
    return float(plant["valve_dead_zone"]), factor * np.array([c.velocity_max for c in crane.cylinders])
