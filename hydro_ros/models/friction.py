"""LuGre seal friction, P-I eq. (17) (Canudas de Wit 1995), reconstructed as the standard LuGre model consistent with
the seventh state equation of P-I eq. (19)."""

from __future__ import annotations

import math

from numba import njit


@njit(cache=True)
def stribeck_curve(velocity: float, coulomb: float, static: float, stribeck_velocity: float) -> float:
    """g(v) = F_C + (F_S - F_C) exp(-(v/v_s)^2), floored so a frictionless setup stays finite."""
    ratio = velocity / stribeck_velocity
    return max(coulomb + (static - coulomb) * math.exp(-ratio * ratio), 1e-9)


@njit(cache=True)
def bristle_rate(velocity: float, z: float, bristle_stiffness: float, g: float) -> float:
    """z' = v - sigma0 |v| z / g(v)."""
    return velocity - bristle_stiffness * abs(velocity) * z / g


@njit(cache=True)
def friction_force(
    velocity: float,
    z: float,
    z_rate: float,
    bristle_stiffness: float,
    bristle_damping: float,
    viscous: float,
) -> float:
    """F_mu = sigma0 z + sigma1 z' + b v."""
    return bristle_stiffness * z + bristle_damping * z_rate + viscous * velocity
