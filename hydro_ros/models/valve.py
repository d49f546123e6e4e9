"""4/3 proportional valve: spool dynamics and notch flows.

P-I eq. (15) spool dynamics (K*omega_n^2 u as in eq. (15): the state-space forms P-I eqs. (19), (22) and
P-II eq. (18) misprint it as K*omega_n u), P-I eqs. (10)-(14) notch and centre-leakage flows with the
opening for x_s + offset < 0 taken as -(x_s + offset) (eqs. (10)-(11) print -x_s + offset), and
P-II Table 1 flow-coefficient polynomials. Notch order in coefficient arrays: PA, PB, AT, BT.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

PA, PB, AT, BT = 0, 1, 2, 3
CENTRE_BAND = 0.01  # |spool| below which the laminar centre leakage acts (P-I eqs. 13-14)
PILOT_TANK_SIGMAS = 3.0  # a pilot reading within this many sigma of its transmitter's noise above zero is the tank's


def pilot_drive(pilot_1: np.ndarray, pilot_2: np.ndarray, pilot_max: np.ndarray | float, tank_band: float) -> np.ndarray:
    """A mobile valve's main-spool drive (fraction of full command) from its two pilot pressures [Pa].

    One pilot acts at a time and the other line is at tank, where a transmitter that cannot read below
    zero reports its noise rectified (+0.4 sigma on average). Taken as read, p_1 - p_2 shrinks every
    opening by that and the notch flows by a share that grows with the flow (measured on the crane: 2-4 %
    of each cylinder's flow, fitted as a leak by commissioning). A reading below ``tank_band`` is taken
    as zero; a tank line's real back pressure above it acts on both spool ends and cancels in the difference.
    """
    return (np.where(pilot_1 > tank_band, pilot_1, 0.0) - np.where(pilot_2 > tank_band, pilot_2, 0.0)) / pilot_max


@njit(cache=True)
def spool_acceleration(x_s: float, v_s: float, reference: float, omega_n: float, damping: float) -> float:
    """Eq. (15): x_s'' = omega_n^2 (reference - x_s) - 2 omega_n d_r x_s'."""
    return omega_n * omega_n * (reference - x_s) - 2.0 * omega_n * damping * v_s


@njit(cache=True)
def spool_track(command: np.ndarray, omega_n: float, damping: float, dt: float, substeps: int, state: np.ndarray) -> np.ndarray:
    """The spool of eq. (15) driven by sampled commands from ``state`` (position, velocity; updated): one position per sample."""
    out = np.empty(command.shape[0])
    x_s, v_s = state[0], state[1]
    h = dt / substeps
    for k in range(command.shape[0]):
        for _ in range(substeps):
            acceleration = spool_acceleration(x_s, v_s, command[k], omega_n, damping)
            x_s += h * v_s
            v_s += h * acceleration
        out[k] = x_s
    state[0], state[1] = x_s, v_s
    return out


@njit(cache=True)
def spool_positions(command: np.ndarray, omega_n: float, damping: float, dt: float, substeps: int) -> np.ndarray:
    """The spool of eq. (15) driven by sampled commands from rest at the first; one position per sample."""
    state = np.zeros(2)
    if command.shape[0]:
        state[0] = command[0]
    return spool_track(command, omega_n, damping, dt, substeps, state)


@njit(cache=True)
def flow_coefficient(poly: np.ndarray, notch: int, x_s: float) -> float:
    """P-II Table 1: K_v(x_s) = c3 x^3 + c2 x^2 + c1 x + c0 [m^3/(s Pa^0.5)], x_s signed."""
    c3 = poly[notch, 0]
    c2 = poly[notch, 1]
    c1 = poly[notch, 2]
    c0 = poly[notch, 3]
    return ((c3 * x_s + c2) * x_s + c1) * x_s + c0


@njit(cache=True)
def signed_root(dp: float, laminar_band: float) -> float:
    """sgn(dp) sqrt(|dp|), linear inside |dp| < laminar_band so the slope stays finite."""
    if abs(dp) < laminar_band:
        return dp / math.sqrt(laminar_band)
    return math.copysign(math.sqrt(abs(dp)), dp)


@njit(cache=True)
def spool_opening(x_s: float, offset: float, deadzone: float, opening_gain: float, stuck: bool, rescaled: bool = True) -> float:
    """Signed effective opening s in [-1.5, 1.5] seen by the notches.

    offset shifts the spool (eqs. 10-11, s = x_s + offset); deadzone is a spool overlap that
    keeps the notches closed for |s| < deadzone and, ``rescaled``, rescales so full travel still
    opens fully (else full travel opens 1 - deadzone, a plain overlap);
    opening_gain < 1 / > 1 emulates a spool jammed to a too small / too large opening
    (P-II section 4.2); a stuck spool sits at centre.
    """
    if stuck:
        return 0.0
    s = x_s + offset
    if deadzone > 0.0:
        magnitude = max(abs(s) - deadzone, 0.0) / (1.0 - deadzone if rescaled else 1.0)
        s = math.copysign(magnitude, s)
    s = opening_gain * min(max(s, -1.0), 1.0)
    return s


@njit(cache=True)
def spool_openings(x_s: np.ndarray, deadzone: float, rescaled: bool) -> np.ndarray:
    """spool_opening of a healthy spool per sample (identification regressors)."""
    out = np.empty(x_s.shape[0])
    for k in range(x_s.shape[0]):
        out[k] = spool_opening(x_s[k], 0.0, deadzone, 1.0, False, rescaled)
    return out


@njit(cache=True)
def chamber_valve_flows(
    s: float,
    neutral_opening: float,
    p_a: float,
    p_b: float,
    p_s: float,
    p_t: float,
    poly: np.ndarray,
    centre_leakage: np.ndarray,
    laminar_band: float,
    flow_gain: float,
) -> tuple[float, float]:
    """Eqs. (10)-(14): valve flows (Q_A, Q_B) into chambers A and B [m^3/s] at the opening s.

    The polynomial is evaluated at the opening clipped to its fitted range [-1, 1]; the opening
    magnitude |s| may exceed 1 for a too-large-opening fault. The centre leakage acts while
    ``neutral_opening``, the opening the valve's own lands leave (its configured overlap, not an
    effect's), is within CENTRE_BAND: it is a property of the valve as identified, over the band it was
    identified on (P-I eqs. 13-14: |x_s| < 0.01 on the SAM's zero-lapped valve, the neutral band on a
    mobile valve's overlapped one). Taken on ``s``, an overlap the model adds as an effect leaked
    ~1 L/min across all of its band: a boom held with the spool inside it drifted in the model, and a
    fit of the overlap was pushed below every command the boom was held at.
    """
    q_a = 0.0
    q_b = 0.0
    x_fit = min(max(s, -1.0), 1.0)
    opening = abs(s)
    if s > 0.0:
        q_a = flow_coefficient(poly, PA, x_fit) * opening * signed_root(p_s - p_a, laminar_band)
        q_b = -flow_coefficient(poly, BT, x_fit) * opening * signed_root(p_b - p_t, laminar_band)
    elif s < 0.0:
        q_a = -flow_coefficient(poly, AT, x_fit) * opening * signed_root(p_a - p_t, laminar_band)
        q_b = flow_coefficient(poly, PB, x_fit) * opening * signed_root(p_s - p_b, laminar_band)
    q_a *= flow_gain
    q_b *= flow_gain
    if abs(neutral_opening) < CENTRE_BAND:
        q_a += centre_leakage[PA] * (p_s - p_a) - centre_leakage[AT] * (p_a - p_t)
        q_b += centre_leakage[PB] * (p_s - p_b) - centre_leakage[BT] * (p_b - p_t)
    return q_a, q_b


@njit(cache=True)
def compensator_pressure(s: float, p_a: float, p_b: float, p_s: float, drop: float, locked: bool) -> float:
    """Pressure upstream of the main spool of a pressure-compensated valve (P-VI flow law, P-IV).

    The compensator holds the load pressure of the metering notch plus its drop, at most the
    supply; locked fully open it passes the supply. Compensator dynamics are not modelled (P-IV
    did not either).
    """
    if locked:
        return p_s
    if s > 0.0:
        load = p_a
    elif s < 0.0:
        load = p_b
    else:
        load = max(p_a, p_b)
    return min(load + drop, p_s)
