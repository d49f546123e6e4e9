"""Parity-equation residuals for pressure-compensated mobile valves (P-IV style, thesis §4.4).

P-IV is known only from the thesis summary, so this design is INFERRED from its statements: no
Kalman filter; a reduced-order, load-independent model (motion measured); the pilot pressures as
the measure of the main-spool position; the measured pressure upstream of the main spool in
place of the supply; thresholds from statistics of fault-free modelling errors as functions of
the operating point.

Residuals are in equation-error form (no integration, so no drift), one per chamber, as flows:

    r_QA = Q_A(s_pil, p_comp, p_A) - A_A x' - (V_A / B_A) p_A'
    r_QB = Q_B(s_pil, p_comp, p_B) + A_B x' - (V_B / B_B) p_B'

s_pil is the main spool that the pilot pressures drive: their difference over p_pil,max (a pilot at
tank read as zero, ``models.valve.pilot_drive``) through the spool's second-order model (P-I eq. 15,
as identification uses it) and the nominal dead zone. Why the spool's dynamics and not the pilot
pressure itself: the pilot transmitters' noise read straight through the dead zone is rectified at its
edge, where a held cylinder's loop keeps its spool, into a false flow; on the nominal crane at work the
held cylinders' fault-free 5 s mean residuals spread 0.04-0.07 L/min without the spool's model, 0.01-0.02
with it (max 0.24 -> 0.11). The pressures under the notches' square root are low-passed for 10 ms
(``ORIFICE_FILTER_S``); the compression term takes them raw. A leak out of a chamber shows as a
positive residual of that chamber equal to the leak flow. The derivative needs no filter: its 5 s
mean telescopes to a difference of pressures 5 s apart.

Where a notch meters on a drop of a few times the transmitters' noise (a compensator at its supply
limit lifting a load, or stalled there), the root misreads the flow: its mean over the noise lies below
the root of the mean (the root is concave), and a drop within the noise is read as a flow of either
sign. Neither averages out in 5 s. So each sample also gives the root's curvature over one standard
deviation sigma of the low-passed drop's noise, |Q(p + sigma) + Q(p - sigma) - 2 Q(p)| / 2: the
expected bias where the drop is a few sigma, and the size of the misreading where it is inside the
noise; its 5 s mean is added to the thresholds (``ParityThresholds``). It is 0.001 L/min in most windows
and 0.4 L/min on the mobile SAM stalled with 300 kg, where the fault-free 5 s mean residual reached
-0.28 L/min (4 false alarms/h on commissioned thresholds without it, measured).

Isolation evidence beyond the crossing signs (the signs while metering are shared: a B leak's with a compensator
sensor bias on retraction, an internal leak's with a pilot sensor bias and a locked spool, a velocity bias's with
the spool faults), each built into the signature table by simulation (``hydro-ros fdi fit``) for every actuator:

- closed-valve code (``ParityResiduals.closed_mean``, ``ParityThresholds.closed_code``): each chamber's mean residual
  over its last 2 s of samples with the modelled spool within half its dead zone, against thresholds fitted on
  fault-free plants. A leak and a velocity bias flow with the valve closed; a sensor bias of the pilot or
  compensator pressure and a main-spool fault act through the metering notches, which are shut. The internal leak
  shows there as A up and B down with equal magnitudes, the velocity bias as A down and B up at the area ratio,
  a held B's leak as B up; a 0.3 MPa pilot bias opens the real spool near the dead zone's edge and shows B alone.
- "Large" (``passes_nothing``): both chambers' 5 s mean |residual| >= 0.8 of their modelled valve flow - the valve
  passes none of what its pilots say, a locked main spool.

Not named on the mobile SAM (bench/results/fdi_parity_eval.md): a locked or eroded compensator is never detected -
the measured compensator pressure is the model's metering supply, so the model follows whatever the compensator
does and the residual cannot see it (P-IV built no compensator model, thesis §6.4). Left unnamed, detected: a
pilot-balance offset of 0.025-0.05 of travel keeps the real spool inside its overlap when closed and crosses like a
velocity bias while metering (0110, quiet closed); a 0.15 MPa pilot bias does not open the closed spool and crosses
like the internal leak (1001); a 0.3 MPa compensator bias crosses on retraction only (0010, the B leak's); a 0.15
main-spool erosion alternates between partial patterns. A B leak is named where the machine holds B pressurised at
rest (0.7 MPa on average while closed on a plant where it is); where B rests near 0.1 MPa its flow stays under the
closed-valve threshold (0.22 L/min) and it shares the compensator bias's retraction pattern.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.isolation import JUDGED_A, JUDGED_B, NO_CLOSED_CODE, crossing_code
from hydro_ros.models.sam import Param, SamModel, chambers
from hydro_ros.models.valve import chamber_valve_flows, pilot_drive, spool_opening, spool_track

CLOSED_SHARE = 0.5  # a sample is "closed" where the modelled spool is within this share of its dead zone (INFERRED: P-IV gives no
# rule; half keeps a pilot transmitter's bias of 0.3 MPa of the mobile SAM's 2.5 MPa, 0.12 of travel, or a spool offset of 0.05
# from opening a spool the model holds closed, where at the dead zone's edge either opens it and reads as a leak)
FLOW_UNIT = 1.0 / 60000.0  # [m^3/s] per L/min: residuals are reported in L/min
ORIFICE_FILTER_S = 0.01  # [s] the pressures under the orifice law's root are low-passed this long (first order): the root of
# a difference of two transmitters' noise (0.1 MPa each) is biased low where the notch meters on little (a compensator at its
# supply limit lifting a load): -0.4 L/min on the mobile SAM with 300 kg at full command. The rate term keeps the raw ones


@njit(cache=True)
def flow_balance(s, neutral, piston, velocity, p_a, p_b, rate_a, rate_b, orifice_a, orifice_b, metering_supply, p, poly,
                 centre) -> tuple[float, float, float, float]:
    """Equation error per chamber [L/min]: valve flow at opening s (``neutral``: the opening the valve's own lands leave,
    valve.chamber_valve_flows; chambers at ``orifice_a``, ``orifice_b``, fed at ``metering_supply``) minus what motion
    and compression (at ``p_a``, ``p_b``) take; and the two valve flows [L/min]."""
    q_a, q_b = chamber_valve_flows(s, neutral, orifice_a, orifice_b, metering_supply, p[Param.TANK], poly, centre, p[Param.LAMINAR_BAND], 1.0)
    volume_a, volume_b, bulk_a, bulk_b = chambers(p, piston, p_a, p_b, 0.0)  # no entrained air in the monitor's model
    return ((q_a - p[Param.AREA_A] * velocity - volume_a / bulk_a * rate_a) / FLOW_UNIT,
            (q_b + p[Param.AREA_B] * velocity - volume_b / bulk_b * rate_b) / FLOW_UNIT, q_a / FLOW_UNIT, q_b / FLOW_UNIT)


@njit(cache=True)
def parity_residuals(piston, velocity, p_a, p_b, drive, compensator, orifice, valid, previous, params, poly, centre, dt,
                     noise, residual_out, opening_out, flow_out, bias_out):
    """Per sample and actuator: (r_QA, r_QB) [L/min], the pilot-measured opening, |modelled valve flow| per chamber
    [L/min] and the flow's curvature over +-``noise`` [Pa] of the chamber pressures [L/min]; arrays (n, A[, 2])."""
    for a in range(piston.shape[1]):
        p = params[a]
        for k in range(piston.shape[0]):
            if not valid[k, a]:
                residual_out[k, a, 0] = 0.0
                residual_out[k, a, 1] = 0.0
                opening_out[k, a] = 0.0
                flow_out[k, a, 0] = 0.0
                flow_out[k, a, 1] = 0.0
                bias_out[k, a, 0] = 0.0
                bias_out[k, a, 1] = 0.0
                continue
            s = spool_opening(drive[k, a], 0.0, p[Param.DEADZONE], 1.0, False)
            neutral = spool_opening(drive[k, a], 0.0, p[Param.VALVE_OVERLAP], 1.0, False)
            rate_a = (p_a[k, a] - previous[a, 0]) / dt if previous[a, 2] > 0.5 else 0.0
            rate_b = (p_b[k, a] - previous[a, 1]) / dt if previous[a, 2] > 0.5 else 0.0
            previous[a, 0] = p_a[k, a]
            previous[a, 1] = p_b[k, a]
            previous[a, 2] = 1.0
            r_a, r_b, q_a, q_b = flow_balance(
                s, neutral, piston[k, a], velocity[k, a], p_a[k, a], p_b[k, a], rate_a, rate_b, orifice[k, a, 0], orifice[k, a, 1],
                orifice[k, a, 2], p, poly[a], centre[a])
            residual_out[k, a, 0] = r_a
            residual_out[k, a, 1] = r_b
            flow_out[k, a, 0] = abs(q_a)
            flow_out[k, a, 1] = abs(q_b)
            opening_out[k, a] = abs(s)
            up_a, up_b = chamber_valve_flows(s, neutral, orifice[k, a, 0] + noise, orifice[k, a, 1] + noise, orifice[k, a, 2],
                                             p[Param.TANK], poly[a], centre[a], p[Param.LAMINAR_BAND], 1.0)
            down_a, down_b = chamber_valve_flows(s, neutral, orifice[k, a, 0] - noise, orifice[k, a, 1] - noise, orifice[k, a, 2],
                                                 p[Param.TANK], poly[a], centre[a], p[Param.LAMINAR_BAND], 1.0)
            bias_out[k, a, 0] = abs((up_a + down_a) / FLOW_UNIT - 2.0 * q_a) / 2.0
            bias_out[k, a, 1] = abs((up_b + down_b) / FLOW_UNIT - 2.0 * q_b) / 2.0


@njit(cache=True)
def first_order_lag(x, smoothing, state):
    """(n, A, C) samples low-passed per channel, y += smoothing (x - y), from ``state`` (A, C; NaN: start at the first sample;
    updated)."""
    out = np.empty_like(x)
    for a in range(x.shape[1]):
        for c in range(x.shape[2]):
            y = state[a, c]
            for k in range(x.shape[0]):
                y = x[k, a, c] if np.isnan(y) else y + smoothing * (x[k, a, c] - y)
                out[k, a, c] = y
            state[a, c] = y
    return out


class ParityGenerator:
    """Residual generator of the parity method for the actuators of a machine."""

    def __init__(self, models: list[SamModel]) -> None:
        missing = [m.actuator for m in models if not m.mobile_valve]
        if missing:
            raise InputError(
                f"fdi method parity: actuator(s) {', '.join(missing)} have proportional valves without pilot "
                "pressures; the parity method needs a mobile-valve machine (valve.type: mobile) - use --method ukf"
            )
        self.params = np.stack([m.base for m in models])
        self.poly = np.stack([m.poly for m in models])
        self.centre = np.stack([m.centre_leakage for m in models])
        self.pilot_max = self.params[:, Param.PILOT_MAX]
        self.tank_band = models[0].pilot_tank_band
        self.dt = 1.0 / models[0].sample_rate
        self.substeps = models[0].substeps
        self.previous = np.zeros((len(models), 3))
        self.spool = np.zeros((len(models), 3))  # per actuator: position, velocity, started
        self.orifice_smoothing = 1.0 - np.exp(-self.dt / ORIFICE_FILTER_S)
        self.orifice = np.full((len(models), 3), np.nan)  # per actuator: the low-passed p_A, p_B, p_comp (NaN: not started)
        # [Pa] sigma of a notch's drop between two transmitters after the low-pass (white noise: variance x a / (2 - a))
        a = self.orifice_smoothing
        self.drop_noise = np.sqrt(2.0 * a / (2.0 - a)) * (models[0].machine.sensors.pressure_noise_std or 0.0)

    def reset(self) -> None:
        self.previous[:] = 0.0
        self.spool[:] = 0.0
        self.orifice[:] = np.nan

    def run(self, piston: np.ndarray, velocity: np.ndarray, p_a: np.ndarray, p_b: np.ndarray, pilot_1: np.ndarray,
            pilot_2: np.ndarray, compensator: np.ndarray, valid: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(n, A, 2) residuals, (n, A) openings, (n, A, 2) |valve flows|, (n, A, 2) the roots' noise bias [L/min], and (n, A)
        whether the valve was closed (the modelled spool within ``CLOSED_SHARE`` of its dead zone)."""
        n, n_act = piston.shape
        residual = np.empty((n, n_act, 2))
        opening = np.empty((n, n_act))
        flow = np.empty((n, n_act, 2))
        bias = np.empty((n, n_act, 2))
        drive = pilot_drive(np.nan_to_num(pilot_1), np.nan_to_num(pilot_2), self.pilot_max, self.tank_band)
        for a in range(n_act):
            if n and self.spool[a, 2] < 0.5:
                self.spool[a] = (drive[0, a], 0.0, 1.0)
            p = self.params[a]
            drive[:, a] = spool_track(np.ascontiguousarray(drive[:, a]), p[Param.SPOOL_OMEGA], p[Param.SPOOL_DAMPING], self.dt, self.substeps,
                                      self.spool[a, :2])
        arrays = [np.ascontiguousarray(np.nan_to_num(v), dtype=float) for v in (piston, velocity, p_a, p_b, drive, compensator)]
        orifice = first_order_lag(np.stack(arrays[2:4] + arrays[5:6], axis=2), self.orifice_smoothing, self.orifice)
        parity_residuals(*arrays, orifice, np.ascontiguousarray(valid), self.previous, self.params, self.poly, self.centre, self.dt,
                         self.drop_noise, residual, opening, flow, bias)
        closed = valid & (np.abs(drive) < CLOSED_SHARE * self.params[:, Param.DEADZONE])
        return residual, opening, flow, bias, closed


# [L/min] bins of a chamber's 5 s mean |valve flow| (``bins: flow``; the crane's fit and every commissioning). The first reaches
# 1 L/min: a held cylinder's chamber sees its centre leakage there, 0.3-0.7 L/min at the crane's holding pressures, and the
# mismatched plants' centre leakage (+-30 %) moved a lift's B by 0.3 L/min at rest where a bin below 0.3 L/min, fitted on the
# few samples the nominal crane put in it, allowed 0.3
FLOW_EDGES = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 1000.0)
# the operating point's channels: 5 s means of the opening, of |Q_A|, |Q_B| and of the roots' noise bias in A, B [L/min]
OPENING, FLOW_A, FLOW_B, NOISE_A, NOISE_B = range(5)
POINT_CHANNELS = 5
BINS = ("opening", "flow")


@dataclass
class ParityThresholds:
    """Threshold per chamber: |mu_bin| + c sigma_bin + k |Q|_mean + noise bias_mean [L/min].

    The statistical part is P-IV's, per bin of the operating point, fitted on fault-free data with ``c``
    set on held-out data (``hydro-ros fdi fit``, ``hydro-ros commission``): one c, or one per bin where
    the held-out data reach different factors at rest and in motion. The operating point is the 5 s
    mean opening (``bins: opening``) or each chamber's 5 s mean |modelled valve flow| (``bins: flow``,
    edges in L/min). The flow is the better one where the valve meters against a varying load: it
    follows the load pressure through the orifice law, and a window in which a joint moved for a second
    and held for four is not taken for one at rest. The flow part is the model's own uncertainty: a notch
    coefficient off by a fraction k puts k times that chamber's valve flow into its residual, so
    ``flow_fraction`` times the chamber's 5 s mean |valve flow| is allowed on top, also on plants whose
    notches are further off than any the statistics saw. ``floor`` [L/min] bounds every threshold from
    below (commissioning's, whose spread is the machine's own). ``closed`` ({mean, std, factor}, each per chamber) is the
    threshold of the closed-valve evidence (``closed_code``), fitted like the rest on fault-free plants; without it
    there is no such evidence. The 5 s mean of the roots' noise bias
    (``parity_residuals``) is added as it is: what the transmitters' noise can put into the residual where a
    notch meters on a drop within a few sigma of it. Operating points are (..., 5): the mean opening, the two
    chambers' mean |valve flow| and their mean noise bias [L/min].
    """

    edges: tuple[float, ...]  # bin edges of the operating point, len = bins + 1
    mean: tuple[tuple[float, float], ...]  # per bin (chamber A, chamber B)
    std: tuple[tuple[float, float], ...]
    factor: float | tuple[float, ...]  # c, or one c per bin
    flow_fraction: float = 0.0  # k [-]
    bins: str = "opening"
    floor: float = 0.0  # [L/min] no threshold below this
    closed: dict[str, Any] | None = None  # {mean, std [L/min], factor: c} per chamber (A, B) of the closed-valve means

    @classmethod
    def from_config(cls, section: dict[str, Any] | None) -> ParityThresholds | None:
        if not section:
            return None
        try:
            factor = section["factor"]
            thresholds = cls(tuple(float(v) for v in section["edges"]), tuple(tuple(map(float, m)) for m in section["mean"]),
                             tuple(tuple(map(float, s)) for s in section["std"]),
                             tuple(map(float, factor)) if isinstance(factor, (list, tuple)) else float(factor),
                             float(section.get("flow_fraction", 0.0)), str(section.get("bins", "opening")),
                             float(section.get("floor", 0.0)), _closed_statistics(section.get("closed")))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"fdi.parity_thresholds: malformed ({exc})") from None
        if isinstance(thresholds.factor, tuple) and len(thresholds.factor) != len(thresholds.edges) - 1:
            raise InputError(f"fdi.parity_thresholds.factor: {len(thresholds.factor)} values for {len(thresholds.edges) - 1} bins")
        if thresholds.bins not in BINS:
            raise InputError(f"fdi.parity_thresholds.bins {thresholds.bins!r}: expected {' or '.join(BINS)}")
        if not 0.0 <= thresholds.flow_fraction < 1.0:
            raise InputError(f"fdi.parity_thresholds.flow_fraction {thresholds.flow_fraction}: expected 0 <= k < 1 (a share of the valve flow)")
        if not thresholds.floor >= 0.0:
            raise InputError(f"fdi.parity_thresholds.floor {thresholds.floor}: expected >= 0 L/min")
        if len(thresholds.mean) != len(thresholds.edges) - 1 or len(thresholds.std) != len(thresholds.mean):
            raise InputError(f"fdi.parity_thresholds: {len(thresholds.edges)} edges need {len(thresholds.edges) - 1} rows of mean and "
                             f"std (have {len(thresholds.mean)} and {len(thresholds.std)})")
        return thresholds

    @classmethod
    def from_statistics(cls, residual: np.ndarray, operating_point: np.ndarray, edges: tuple[float, ...], factor: float,
                        flow_fraction: float = 0.0, bins: str = "opening", minimum: int = 100) -> ParityThresholds:
        """Mean and spread of fault-free 5 s mean residuals (n, 2) per bin of the (n, 5) operating points.

        A bin with fewer than ``minimum`` samples (an operating point the data never reached) borrows
        the spread of all of them. Windows masked throughout are left out.
        """
        index = _bin_index(edges, bins, operating_point)
        judged = residual != 0.0  # a window masked throughout (a cavitating chamber) means exactly 0: nothing of the spread
        mean, std = [], []
        for b in range(len(edges) - 1):
            columns = [residual[(index[:, c] == b) & judged[:, c], c] if np.count_nonzero((index[:, c] == b) & judged[:, c]) >= minimum
                       else residual[judged[:, c], c] for c in range(2)]
            mean.append(tuple(float(column.mean()) for column in columns))
            std.append(tuple(float(column.std()) for column in columns))
        return cls(tuple(edges), tuple(mean), tuple(std), factor, flow_fraction, bins)

    @classmethod
    def probe(cls) -> dict[str, Any]:
        """Config of thresholds nothing crosses: a monitor that only records its residuals."""
        return {"edges": [0.0, 1.5], "mean": [[0.0, 0.0]], "std": [[1.0, 1.0]], "factor": 1e12}

    def _offset_and_spread(self, operating_point: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        index = _bin_index(self.edges, self.bins, operating_point)
        chamber = np.arange(2)
        return (np.abs(np.asarray(self.mean))[index, chamber] + self.flow_fraction * operating_point[..., FLOW_A:FLOW_B + 1]
                + operating_point[..., NOISE_A:NOISE_B + 1],
                np.asarray(self.std)[index, chamber])

    def factor_reached(self, residual: np.ndarray, operating_point: np.ndarray) -> float:
        """The largest factor c the 5 s mean residuals (n, 2) at operating points (n, 5) reach: |r| = |mu| + c sigma + k |Q| + bias."""
        return float(self.factors_reached(residual, operating_point).max())

    def factors_reached(self, residual: np.ndarray, operating_point: np.ndarray) -> np.ndarray:
        """The largest factor reached per bin (0 where no sample fell)."""
        offset, spread = self._offset_and_spread(operating_point)
        reached = ((np.abs(residual) - offset) / spread).reshape(-1)
        out = np.zeros(len(self.edges) - 1)
        np.maximum.at(out, _bin_index(self.edges, self.bins, operating_point).reshape(-1), reached)
        return out

    def to_config(self) -> dict[str, Any]:
        return {"bins": self.bins, "edges": list(self.edges), "mean": [list(m) for m in self.mean], "std": [list(s) for s in self.std],
                "factor": list(self.factor) if isinstance(self.factor, tuple) else self.factor, "flow_fraction": self.flow_fraction,
                **({"floor": self.floor} if self.floor else {}),
                **({"closed": {key: list(self.closed[key]) for key in ("mean", "std", "factor")}} if self.closed else {})}

    @property
    def closed_threshold(self) -> np.ndarray | None:
        """[L/min] (A, B) the closed-valve means' thresholds, None without closed statistics."""
        if not self.closed:
            return None
        return np.abs(np.asarray(self.closed["mean"])) + np.asarray(self.closed["factor"]) * np.asarray(self.closed["std"])

    def closed_code(self, closed_mean: np.ndarray) -> np.ndarray:
        """(..., 2) closed-valve mean residuals (NaN: not judged) -> (...) their crossing codes of the closed thresholds with
        the judged chambers' flags (``isolation.JUDGED_A``, ``JUDGED_B``), ``NO_CLOSED_CODE`` where neither was judged or
        the thresholds have no closed statistics."""
        threshold = self.closed_threshold
        if threshold is None:
            return np.full(closed_mean.shape[:-1], NO_CLOSED_CODE, dtype=np.int8)
        code = crossing_code(np.nan_to_num(closed_mean), np.broadcast_to(threshold, closed_mean.shape))
        judged = np.isfinite(closed_mean)
        flags = JUDGED_A * judged[..., 0] + JUDGED_B * judged[..., 1]
        return np.where(judged.any(axis=-1), code + flags, NO_CLOSED_CODE).astype(np.int8)

    def __call__(self, operating_point: np.ndarray) -> np.ndarray:
        """(..., 5) operating points -> (..., 2) thresholds."""
        offset, spread = self._offset_and_spread(operating_point)
        factor = (np.asarray(self.factor)[_bin_index(self.edges, self.bins, operating_point)] if isinstance(self.factor, tuple)
                  else self.factor)
        return np.maximum(offset + factor * spread, self.floor)


# "Large" of the parity signature table: both chambers' 5 s mean |residual| at least this share of their mean |modelled valve flow|,
# each at least the first flow bin's edge: the valve passes (almost) nothing of what its pilots say it meters, as with a locked
# main spool (0.9-1.0 measured on the mobile SAM). INFERRED: above a main spool's erosion (0.3, its size) and the 0.3-0.4 that
# a 0.3 MPa pilot bias, an internal leak or a velocity bias give at median; they reach 0.8 in a few windows at small flows
LOCKED_SHARE = 0.8


def passes_nothing(mean_residual: np.ndarray, operating_point: np.ndarray) -> np.ndarray:
    """(..., 2) 5 s mean residuals at (..., 5) operating points -> (...) whether the valve passed almost none of its modelled flow."""
    flow = operating_point[..., FLOW_A:FLOW_B + 1]
    return np.all((np.abs(mean_residual) >= LOCKED_SHARE * flow) & (flow >= FLOW_EDGES[1]), axis=-1)


def closed_statistics(fitted: np.ndarray, held_out: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Per chamber of fault-free closed-valve means (n, 2) [L/min], NaN where not judged: their mean and spread, and the
    largest factor of the spread by which the held-out ones (m, 2) exceed |mean|; None where a chamber was never judged
    closed, or judged without spread (no evidence to fit a threshold on)."""
    if not np.isfinite(fitted).any(axis=0).all():
        return None
    mean, std = np.nanmean(fitted, axis=0), np.nanstd(fitted, axis=0)
    if not np.all(std > 0.0):
        return None
    excess = np.abs(held_out) - np.abs(mean)
    return mean, std, np.max(np.where(np.isfinite(excess), excess, 0.0), axis=0, initial=0.0) / std


def _closed_statistics(section: dict[str, Any] | None) -> dict[str, Any] | None:
    if not section:
        return None
    return {key: tuple(map(float, section[key])) for key in ("mean", "std", "factor")}


def _bin_index(edges: tuple[float, ...], bins: str, operating_point: np.ndarray) -> np.ndarray:
    """(..., 2) bin of each chamber: both the opening's, or each its own mean flow's."""
    value = np.repeat(operating_point[..., OPENING:OPENING + 1], 2, axis=-1) if bins == "opening" else operating_point[..., FLOW_A:FLOW_B + 1]
    return np.clip(np.searchsorted(edges, value, side="right") - 1, 0, len(edges) - 2)
