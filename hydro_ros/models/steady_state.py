"""Closed-form references for the SAM model: P-I eqs. (39)-(40) and the hydraulic natural frequency."""

from __future__ import annotations

import math

from hydro_ros.models.sam import Param, SamModel, chambers
from hydro_ros.models.valve import BT, PA, flow_coefficient


def extension_steady_pressures(model: SamModel, spool: float, external_force: float) -> tuple[float, float]:
    """P-I eqs. (39) and (40), with (39)'s F_ext term F_ext A_A^2 K_BT^2 as its derivation gives (a typo in the
    printed eq. (39): A_A A_B K_BT^2).

    Steady extension with PA and BT open by ``spool`` > 0 and friction lumped into F_ext.
    """
    p = model.base
    a_a, a_b, p_s, p_t = p[Param.AREA_A], p[Param.AREA_B], p[Param.SUPPLY], p[Param.TANK]
    k_pa = flow_coefficient(model.poly, PA, spool)
    k_bt = flow_coefficient(model.poly, BT, spool)
    denominator = a_a**3 * k_bt**2 + a_b**3 * k_pa**2
    p_a = (external_force * a_a**2 * k_bt**2 + a_b**3 * k_pa**2 * p_s + a_a**2 * a_b * k_bt**2 * p_t) / denominator
    p_b = (-external_force * k_pa**2 * a_b**2 + a_a * a_b**2 * k_pa**2 * p_s + a_a**3 * k_bt**2 * p_t) / denominator
    return p_a, p_b


def hydraulic_natural_frequency(model: SamModel, x: float, p_a: float = 0.0, p_b: float = 0.0) -> float:
    """omega_h / (2 pi) [Hz] of the closed-valve cylinder at piston position ``x``.

    omega_h^2 = (B_A A_A^2 / V_A + B_B A_B^2 / V_B) / m_reduced (INFERRED formula, not in
    P-I, to check its Section 2.1's <= 4.5 Hz; Merritt's two-chamber hydraulic spring against the boom's reduced mass).
    """
    p = model.base
    volume_a, volume_b, bulk_a, bulk_b = chambers(p, x, p_a, p_b, 0.0)
    stiffness = bulk_a * p[Param.AREA_A] ** 2 / volume_a + bulk_b * p[Param.AREA_B] ** 2 / volume_b
    reduced_mass = model.inertia() / model.torque_arm_at(x) ** 2
    return math.sqrt(stiffness / reduced_mass) / (2.0 * math.pi)
