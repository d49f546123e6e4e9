"""Identification of a valve-controlled cylinder's flow model from recordings, load-independently.

Per chamber, continuity

    A_A x' = Q_PA(s, p_S - p_A) + Q_AT(s, p_A - p_T) - (V_A / B_o + V_h / B_h) p_A'

holds at every sample whatever the load, the friction or the payload (P-II's reduced model, the
monitor's). Each notch's flow is P-II's form K_v(s) |s| sqrt(dp) with K_v a cubic in s, so all
sixteen polynomial coefficients, the oil compliance 1/B_o, the hose capacitance V_h/B_h and the
four centre-leakage coefficients enter linearly: the rows of one least-squares problem, no
simulation. Motion and pressures are low-passed without phase (filtfilt) and the same filter is
applied to every regressor, so the differentiated pressures carry no sensor noise into the fit.
The spool follows its drive through the valve's own second-order model (the SAM measures no spool;
a mobile valve's drive is its pilot pressures) and opens through the valve's dead zone. Inside the
centre band the notches' laminar centre leakage (P-I eqs. 13-14) takes their place, and pressure
relaxation after each stop identifies it. Samples near the end stops or with a chamber near
cavitation are left out: the model's laws change there. Turbulent leak columns of chamber A,
chamber B and across the piston let a fit tell a leak from the valve.

Two users, one set of rows: commissioning (``hydro_ros.workflows.commissioning``) fits every column;
the discrepancy workflow's calibration fits one gain per notch group and the oil's bulk modulus
within their tolerance (``group_calibration``), so an effect is left for the effect to explain.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import binary_erosion
from scipy.optimize import lsq_linear
from scipy.signal import butter, filtfilt

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES
from hydro_ros.contract.samples import Samples
from hydro_ros.models.chamber import leak_coefficient
from hydro_ros.models.sam import Param, SamModel, chamber_volumes
from hydro_ros.models.valve import CENTRE_BAND, pilot_drive, spool_openings, spool_positions

FILTER_HZ = 8.0  # zero-phase low-pass of motion, pressures and regressors: far below the 1 kHz noise, above the boom's motion
SEGMENT_MIN_S = 2.0  # a stretch of complete samples shorter than this is not used (the filter's edges)
STOP_MARGIN = 5.0e-3  # [m] samples this close to an end stop are left out (the stop's force, not the valve, moves the piston)
PRESSURE_FLOOR = 5.0e5  # [Pa] ... and those with a chamber below this (near cavitation the chamber law changes)
EXCLUSION_GUARD_S = 0.3  # [s] ... and those this close to a left-out one: a cavitating chamber's pressure jumps by MPa
# in milliseconds, and the low-pass spreads that rate into its neighbours. Measured on the crane's lift (its B cavitates
# while lowering): a fault-free cylinder fitted leaks of 0.19 L/min (B, internal) without the guard, <= 0.04 with 0.3 s
OPEN = 0.1  # a notch counts as open beyond this opening
# Long recordings in bounded memory: the rows are low-passed at FILTER_HZ, so one every 1/ROW_RATE_HZ carries what the
# others do (6x the cut-off), and a long stretch is computed in blocks of BLOCK_S read with EDGE_S more on each side,
# where the filter's and the simulated spool's start settle (each well under a second)
ROW_RATE_HZ = 50.0
BLOCK_S = 60.0
EDGE_S = 2.0
CORRELATION_S = 0.5  # [s] rows closer than this are one observation (the rows are low-passed at FILTER_HZ; INFERRED)
LEAKS = ("external_leakage_a", "external_leakage_b", "internal_leakage")
COLUMNS = ([f"{notch}_c{3 - k}" for notch in NOTCHES for k in range(4)] + ["oil_compliance", "hose_capacitance"]
           + [f"{notch}_centre" for notch in NOTCHES] + list(LEAKS))
VALVE_AND_FLUID = len(COLUMNS) - len(LEAKS)
OIL_COMPLIANCE, HOSE_CAPACITANCE = COLUMNS.index("oil_compliance"), COLUMNS.index("hose_capacitance")
CENTRE = slice(COLUMNS.index("PA_centre"), COLUMNS.index("PA_centre") + len(NOTCHES))


@dataclass
class FlowRegression:
    """Rows of the continuity equations of one actuator over some recordings, and what they saw."""

    regressors: np.ndarray  # (rows, len(COLUMNS)), filtered
    flows: np.ndarray  # (rows,) A x' per row [m^3/s], filtered
    open_s: dict[str, float]  # per notch: seconds seen open beyond OPEN
    widest: dict[str, float]  # per notch: largest opening seen
    seconds: float

    @classmethod
    def concatenate(cls, parts: Sequence[FlowRegression]) -> FlowRegression:
        if not parts:
            return cls(np.empty((0, len(COLUMNS))), np.empty(0), dict.fromkeys(NOTCHES, 0.0), dict.fromkeys(NOTCHES, 0.0), 0.0)
        return cls(np.vstack([p.regressors for p in parts]), np.concatenate([p.flows for p in parts]),
                   {n: sum(p.open_s[n] for p in parts) for n in NOTCHES},
                   {n: max(p.widest[n] for p in parts) for n in NOTCHES}, sum(p.seconds for p in parts))


def stretches(valid: np.ndarray, minimum: int) -> list[slice]:
    """Contiguous runs of valid samples at least ``minimum`` long."""
    edges = np.flatnonzero(np.diff(np.concatenate([[0], valid.astype(np.int8), [0]])))
    return [slice(a, b) for a, b in zip(edges[::2], edges[1::2]) if b - a >= minimum]


def _signed_root(dp: np.ndarray) -> np.ndarray:
    return np.sign(dp) * np.sqrt(np.abs(dp))


def stretch_rows(model: SamModel, joint: np.ndarray, p_a: np.ndarray, p_b: np.ndarray, drive: np.ndarray,
                 feed: np.ndarray) -> FlowRegression:
    """The continuity rows of one contiguous stretch of samples at the model's rate, ROW_RATE_HZ of them per second.

    ``drive`` is what moves the spool (the valve command, or a mobile valve's pilot pressures over
    their maximum), ``feed`` the pressure upstream of the metering notches (supply or compensator).
    """
    signals = np.stack([np.asarray(s, dtype=float) for s in (joint, p_a, p_b, drive, feed)], axis=1)
    block, edge = int(BLOCK_S * model.sample_rate), int(EDGE_S * model.sample_rate)
    parts = []
    for start in range(0, len(signals), block):
        begin, end = max(start - edge, 0), min(start + block + edge, len(signals))
        parts.append(_block_rows(model, signals[begin:end], slice(start - begin, min(start + block, len(signals)) - begin), start))
    return FlowRegression.concatenate(parts)


def _block_rows(model: SamModel, signals: np.ndarray, inner: slice, first: int) -> FlowRegression:
    """The rows of the samples ``inner`` of ``signals`` (joint, p_A, p_B, drive, feed), the first of them sample ``first``
    of its stretch (the row grid of ROW_RATE_HZ is the stretch's)."""
    p = model.base
    dt = 1.0 / model.sample_rate
    b, a = butter(2, FILTER_HZ / (model.sample_rate / 2.0))
    joint, p_a, p_b, drive, feed = signals.T

    def low_pass(x: np.ndarray) -> np.ndarray:
        return filtfilt(b, a, x, axis=0)

    x = low_pass(model.piston_from_joint(np.ascontiguousarray(joint)))
    velocity = np.gradient(x, dt)
    p_a, p_b, supply = low_pass(p_a), low_pass(p_b), low_pass(feed)
    rate_a, rate_b = np.gradient(p_a, dt), np.gradient(p_b, dt)
    position = spool_positions(np.ascontiguousarray(drive), p[Param.SPOOL_OMEGA], p[Param.SPOOL_DAMPING], dt, model.substeps)
    spool = spool_openings(position, p[Param.DEADZONE], p[Param.DEADZONE_PLAIN] < 0.5)
    opening = np.abs(spool)
    powers = np.stack([spool ** 3, spool ** 2, spool, np.ones_like(spool)], axis=1)
    extending, retracting = spool > 0.0, spool < 0.0
    zero = np.zeros_like(powers)
    pa_notch = powers * (extending * opening * _signed_root(supply - p_a))[:, None]
    at_notch = -powers * (retracting * opening * _signed_root(p_a - p[Param.TANK]))[:, None]
    pb_notch = powers * (retracting * opening * _signed_root(supply - p_b))[:, None]
    bt_notch = -powers * (extending * opening * _signed_root(p_b - p[Param.TANK]))[:, None]
    volume_a, volume_b = chamber_volumes(p, x)
    across = _signed_root(p_a - p_b)
    centre = (np.abs(spool_openings(position, p[Param.VALVE_OVERLAP], True)) < CENTRE_BAND).astype(float)  # valve.chamber_valve_flows
    nothing = np.zeros_like(x)
    chamber_a = np.hstack([pa_notch, zero, at_notch, zero, np.stack(
        [-volume_a * rate_a, -rate_a, centre * (supply - p_a), nothing, -centre * (p_a - p[Param.TANK]), nothing,
         -_signed_root(p_a), nothing, -across], axis=1)])
    chamber_b = np.hstack([zero, pb_notch, zero, bt_notch, np.stack(
        [-volume_b * rate_b, -rate_b, nothing, centre * (supply - p_b), nothing, -centre * (p_b - p[Param.TANK]),
         nothing, -_signed_root(p_b), across], axis=1)])
    keep = ((np.minimum(p_a, p_b) > PRESSURE_FLOOR + max(p[Param.CAVITATION], 0.0))
            & (x > p[Param.STOP_LOWER] + STOP_MARGIN) & (x < p[Param.STOP_UPPER] - STOP_MARGIN))
    guard = int(EXCLUSION_GUARD_S * model.sample_rate)
    keep = binary_erosion(keep, np.ones(2 * guard + 1, dtype=bool), border_value=1)
    keep[:inner.start] = False  # the edges only let the filter and the spool settle
    keep[inner.stop:] = False
    every = max(int(round(model.sample_rate / ROW_RATE_HZ)), 1)
    row = keep & ((first - inner.start + np.arange(len(x))) % every == 0)
    seen = {"PA": extending, "BT": extending, "PB": retracting, "AT": retracting}
    return FlowRegression(np.vstack([low_pass(chamber_a)[row], low_pass(chamber_b)[row]]),
                          np.concatenate([low_pass(p[Param.AREA_A] * velocity)[row], low_pass(-p[Param.AREA_B] * velocity)[row]]),
                          {n: float(np.count_nonzero(keep & seen[n] & (opening > OPEN))) * dt for n in NOTCHES},
                          {n: float(opening[keep & seen[n]].max(initial=0.0)) for n in NOTCHES}, (inner.stop - inner.start) * dt)


def flow_regression(model: SamModel, samples: Samples, column: int = 0) -> FlowRegression:
    """The continuity rows of one actuator (column ``column`` of ``samples``) over its complete stretches."""
    p = model.base

    def channel(values: np.ndarray | None) -> np.ndarray:
        return np.asarray(values, dtype=float).reshape(len(samples), -1)[:, column]

    if model.mobile_valve:
        if not samples.mobile:
            raise InputError(f"actuator {model.actuator}: a mobile valve is identified from its pilot and compensator "
                             "pressures, and the recording has none")
        # the pilot pressures are what drives the main spool, the compensator's pressure is what feeds its notches
        drive = pilot_drive(channel(samples.pilot_pressure_1), channel(samples.pilot_pressure_2), p[Param.PILOT_MAX], model.pilot_tank_band)
        feed = channel(samples.compensator_pressure)
    else:
        drive = channel(samples.valve_command)
        feed = np.asarray(samples.supply_pressure, dtype=float).reshape(len(samples))
    signals = np.stack([channel(samples.joint_position), channel(samples.pressure_a), channel(samples.pressure_b), drive, feed],
                       axis=1)
    return FlowRegression.concatenate([stretch_rows(model, *signals[part].T) for part in
                                       stretches(np.all(np.isfinite(signals), axis=1), int(SEGMENT_MIN_S * model.sample_rate))])


def nominal_coefficients(model: SamModel) -> np.ndarray:
    """The model's own values of the valve and fluid columns (leaks zero)."""
    p = model.base
    coefficients = np.zeros(len(COLUMNS))
    coefficients[:4 * len(NOTCHES)] = model.poly.reshape(-1)
    coefficients[OIL_COMPLIANCE] = 1.0 / p[Param.OIL_MODULUS]
    coefficients[HOSE_CAPACITANCE] = p[Param.HOSE_VOLUME] / p[Param.HOSE_MODULUS]
    coefficients[CENTRE] = model.centre_leakage
    return coefficients


def rms_flow_error(regression: FlowRegression, coefficients: np.ndarray) -> float:
    """RMS equation error [L/min] of the rows with these coefficients."""
    return float(np.sqrt(np.mean((regression.flows - regression.regressors @ coefficients) ** 2)) * 60000.0)


@dataclass(frozen=True)
class LeakFit:
    """The three leak terms [L/min at 10 MPa] fitted to what some coefficients leave unexplained, with standard errors."""

    leaks: dict[str, float]
    errors: dict[str, float]

    def worst(self) -> tuple[str, float, float]:
        """(name, value, standard error) of the largest leak."""
        name = max(self.leaks, key=lambda n: self.leaks[n])
        return name, self.leaks[name], self.errors[name]


def leak_fit(regression: FlowRegression, coefficients: np.ndarray) -> LeakFit:
    """The leak columns fitted to the rows' flow that ``coefficients`` (valve and fluid) leave unexplained.

    The standard errors are the ordinary least-squares ones widened by how many rows make one independent observation
    (one per CORRELATION_S of recording): what a short recording or a model's form errors leave uncertain."""
    columns = [COLUMNS.index(name) for name in LEAKS]
    design = regression.regressors[:, columns]
    unexplained = regression.flows - regression.regressors @ np.asarray(coefficients)
    rows = len(unexplained)
    if rows < len(LEAKS) + 1:
        return LeakFit(dict.fromkeys(LEAKS, math.nan), dict.fromkeys(LEAKS, math.nan))
    scale = np.abs(design).max(axis=0)
    scale[scale == 0.0] = 1.0
    solution, *_ = np.linalg.lstsq(design / scale, unexplained, rcond=None)
    residual = unexplained - (design / scale) @ solution
    independent = max(regression.seconds / CORRELATION_S, len(LEAKS) + 1.0)
    covariance = np.linalg.pinv((design / scale).T @ (design / scale)) * float(residual @ residual) / (rows - len(LEAKS))
    covariance *= max(rows / independent, 1.0)
    unit = leak_coefficient(1.0)
    return LeakFit({name: float(solution[k] / scale[k] / unit) for k, name in enumerate(LEAKS)},
                   {name: float(math.sqrt(max(covariance[k, k], 0.0)) / scale[k] / unit) for k, name in enumerate(LEAKS)})


def least_squares(regression: FlowRegression, columns: list[int]) -> tuple[np.ndarray, float]:
    """Coefficients of the chosen columns (others zero) and the RMS equation error [L/min]. The centre leakages are
    held >= 0: on a valve whose centre barely leaks (a mobile valve's overlapped spool) the fit's noise about zero
    would otherwise make a healthy machine's fit non-physical."""
    design = regression.regressors[:, columns]
    scale = np.abs(design).max(axis=0)
    scale[scale == 0.0] = 1.0
    centre = np.isin(columns, np.arange(len(COLUMNS))[CENTRE])
    solution, *_ = np.linalg.lstsq(design / scale, regression.flows, rcond=None)
    if np.any(solution[centre] < 0.0):
        low = np.where(centre, 0.0, -np.inf)
        solution = lsq_linear(design / scale, regression.flows, bounds=(low, np.full(len(columns), np.inf)), method="bvls").x
    coefficients = np.zeros(len(COLUMNS))
    coefficients[columns] = solution / scale
    return coefficients, rms_flow_error(regression, coefficients)


def group_calibration(model: SamModel, regression: FlowRegression, groups: dict[str, tuple[str, ...]],
                      bulk_tolerance: float, gain_tolerance: float) -> dict[str, float]:
    """One flow gain per group of notches and the oil bulk-modulus factor, the rest nominal, each within its tolerance.

    The nominal polynomials scaled per group, the oil compliance and what stays nominal (hose, centre
    leakage) make three columns of one linear fit; a value beyond its tolerance is held at the bound
    and the others fitted again (a bounded linear least-squares problem).
    """
    nominal = nominal_coefficients(model)
    design, names = [], []
    for group, notches in groups.items():
        column = np.zeros(len(COLUMNS))
        for notch in notches:
            k = NOTCHES.index(notch)
            column[4 * k:4 * k + 4] = nominal[4 * k:4 * k + 4]
        design.append(regression.regressors @ column)
        names.append(f"{group}_flow_gain")
    fixed = nominal.copy()
    fixed[:4 * len(NOTCHES)] = 0.0
    fixed[OIL_COMPLIANCE] = 0.0
    design.append(regression.regressors[:, OIL_COMPLIANCE] * nominal[OIL_COMPLIANCE])
    target = regression.flows - regression.regressors @ fixed
    matrix = np.stack(design, axis=1)
    # factors 1 + z: gains within +-gain_tolerance, the compliance factor 1/bulk_factor within the bulk tolerance
    low = np.array([1.0 - gain_tolerance] * len(names) + [1.0 / (1.0 + bulk_tolerance)])
    high = np.array([1.0 + gain_tolerance] * len(names) + [1.0 / (1.0 - bulk_tolerance)])
    solution = lsq_linear(matrix, target, bounds=(low, high)).x
    return {**dict(zip(names, (float(v) for v in solution[:-1]))), "bulk_factor": float(1.0 / solution[-1])}
