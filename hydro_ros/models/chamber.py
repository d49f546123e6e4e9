"""Cylinder chambers: effective bulk modulus and cylinder leakages.

P-II eq. (19) hose-compliant bulk modulus, extended with free entrained air (an effect of the
discrepancy vocabulary, not in the thesis), and P-I eqs. (41)-(43) turbulent leakages.
"""

from __future__ import annotations

import math

from numba import njit

ATMOSPHERE = 1.0e5  # [Pa] absolute pressure at which the free-air fraction is quoted
AIR_POLYTROPIC_EXPONENT = 1.4
LEAK_REFERENCE_DROP = 1.0e7  # [Pa] leak sizes are quoted at 10 MPa (P-I: 5.27e-9 -> 1 L/min)


@njit(cache=True)
def effective_bulk_modulus(
    pressure: float,
    volume: float,
    oil_modulus: float,
    hose_modulus: float,
    hose_volume: float,
    air_fraction: float,
) -> float:
    """1/B = 1/B_o + (V_h/V)/B_h [P-II eq. 19] + air term.

    Free air of volume fraction eps at atmospheric pressure, compressed polytropically, adds
    eps (p_atm/p_abs)^(1/n) / (n p_abs) to the compliance (Merritt-style model, INFERRED).
    """
    compliance = 1.0 / oil_modulus + hose_volume / (volume * hose_modulus)
    if air_fraction > 0.0:
        p_abs = max(pressure + ATMOSPHERE, 0.1 * ATMOSPHERE)
        n = AIR_POLYTROPIC_EXPONENT
        compliance += air_fraction * (ATMOSPHERE / p_abs) ** (1.0 / n) / (n * p_abs)
    return 1.0 / compliance


def leak_coefficient(flow_l_min_at_10mpa: float) -> float:
    """Turbulent leak coefficient K [m^3/(s Pa^0.5)] of a leak quoted in L/min at 10 MPa."""
    return flow_l_min_at_10mpa / 60000.0 / math.sqrt(LEAK_REFERENCE_DROP)


@njit(cache=True)
def leak_flow(coefficient: float, dp: float, laminar_band: float, laminar: bool = False) -> float:
    """Eqs. (41)-(43) in signed-root form so a reversed pressure drop reverses the leak; ``laminar``: the
    same flow at the reference drop, in proportion to the drop (a long narrow gap rather than an orifice)."""
    if coefficient == 0.0:
        return 0.0
    if laminar:
        return coefficient * dp / math.sqrt(LEAK_REFERENCE_DROP)
    if abs(dp) < laminar_band:
        return coefficient * dp / math.sqrt(laminar_band)
    return coefficient * math.copysign(math.sqrt(abs(dp)), dp)
