"""Model-discrepancy workflow (`hydro-ros discrepancy`): calibrate, localise, name, add and verify.

The model is simulated with the bag's own inputs in 2 s segments, each started from the measured
state (multiple shooting): drift of the open-loop position cannot swamp the comparison, yet
every effect acts through the full dynamics. What no sensor gives is estimated: the friction's
bristle state from the force balance at the start, the commands a valve delay still applies from
the recording before the start (before the bag, its first command held). The error of a segment
simulation against the measurement is normalised per channel (p_A, p_B per 0.1 MPa - the sensor
noise -, piston position per 1 mm) and its RMS is the gap.

1. calibrate: flow coefficients (one gain for the supply notches P-A, P-B, one for the return
   notches A-T, B-T) and oil bulk modulus, within the tolerance of an identified valve
   (flow +-5 %, bulk modulus +-30 %), on the first 60 % of the data: a bounded linear fit to the
   load-independent continuity rows commissioning identifies on (models.identification);
2. localise: the error by channel, by regime (extending, retracting, at rest; pressure level;
   position) and in 5 s windows, for the forward simulation and for the load-independent one
   (the reduced model of P-II driven by the measured motion);
3. name, by forward selection (``select``): each effect of the contract vocabulary, in each of its
   physical forms (names.EFFECT_FORMS: a dead zone with or without rescaling, an orifice or a
   laminar leak, a transport delay or a lag, Coulomb or Stribeck friction), is fitted as a
   one-parameter extension on the fit data - screened on a quarter of the segments, the best two
   families fitted again on all - and scored with the Bayesian information criterion on an
   effective sample count (one independent sample per 0.1 s, INFERRED). An effect is significant
   if it lowers BIC by more than 10 and the squared error by at least 30 % (60 % on top of others);
   the most significant family is added, in the form that fits best after the joint fit of 4 (the
   family's first unless another is better by more than BIC_MARGIN);
4. refine, after each addition: the named effects and the calibration are fitted jointly (each
   effect was fitted with the others held, and calibration can absorb part of an effect: air
   lowers the bulk modulus). Selection goes on until nothing is significant, or the effect added
   does not lower the held-out gap by 5 %; a backward check then drops any effect the others
   have made unnecessary. The report keeps the path: what was tried, in which order, and how
   much each step closed the gap;
5. add and verify: the config with the effects (and their forms) is written as model.yaml and
   the gap is measured before and after on the last 40 % of the data, on which no value is fitted
   (it only decides when selection stops).
"""

from __future__ import annotations

import base64
import html
import itertools
import math
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from numba import njit
from scipy.optimize import minimize, minimize_scalar

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.reader import BagData
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import EFFECT_FORMS, Effect, first_form
from hydro_ros.fdi.parity import flow_balance
from hydro_ros.models.identification import SEGMENT_MIN_S, FlowRegression, group_calibration, stretch_rows
from hydro_ros.models.sam import DELAY_BUFFER, N_STATES, Param, SamModel, simulate_segments
from hydro_ros.models.valve import spool_opening, spool_positions
from hydro_ros.workflows.plots import plot_discrepancy, plot_gap_localisation

SEGMENT_S = 2.0
# RK4 step of the workflow's simulations: 0.25 ms, where a machine config asks for 0.1 ms (10 per 1 kHz
# sample). Measured on a 36 s recording: 0.9 kPa at most against 0.1 ms steps, the gap equal to 4
# digits, 2.3x faster; the stability limit is ~0.6 ms (models/sam.py).
SIMULATION_STEP_S = 2.5e-4
FORCE_SAMPLES = 10  # each side of a segment start: the pressures that estimate the friction state
SCALES = np.array([1e5, 1e5, 1e-3])  # p_A, p_B [Pa], piston position [m]: one unit of normalised error
FIT_SHARE = 0.6
DECORRELATION_S = 0.1
BIC_MARGIN = 10.0
MIN_REDUCTION = 0.3

# one-parameter extensions and their search ranges (units of names.INJECTION_UNITS)
EFFECT_RANGES: dict[str, tuple[float, float]] = {
    "internal_leakage": (0.0, 6.0),
    "external_leakage_a": (0.0, 6.0),
    "external_leakage_b": (0.0, 6.0),
    "valve_deadzone": (0.0, 0.25),
    "spool_offset": (-0.08, 0.08),
    "valve_delay": (0.0, 0.15),
    "valve_flow_gain": (-0.5, 0.5),
    "entrained_air": (0.0, 0.05),
    "coulomb_friction": (0.0, 6000.0),
    "viscous_friction": (0.0, 3.0e5),
    "payload_mass": (-300.0, 400.0),
    "pressure_sensor_bias_a": (-1.0e6, 1.0e6),
    "pressure_sensor_bias_b": (-1.0e6, 1.0e6),
}
assert set(EFFECT_RANGES) == {e.value for e in Effect}


@dataclass
class Recording:
    """The bag's single-actuator signals the workflow needs.

    ``earlier_commands`` are the valve commands recorded before ``times[0]``: a part cut from a
    recording keeps them, because a valve delay still applies them after the cut.
    """

    times: np.ndarray
    joint: np.ndarray
    joint_rate: np.ndarray
    pressure_a: np.ndarray
    pressure_b: np.ndarray
    command: np.ndarray
    supply: np.ndarray
    earlier_commands: np.ndarray = field(default_factory=lambda: np.empty(0))

    def part(self, part: slice) -> Recording:
        first = range(len(self.times))[part].start
        earlier = np.concatenate([self.earlier_commands, self.command[:first]])[-DELAY_BUFFER:]
        return Recording(*(getattr(self, f.name)[part] for f in fields(self) if f.name != "earlier_commands"), earlier)

    def commands_before(self, index: int) -> np.ndarray:
        """The DELAY_BUFFER valve commands before sample ``index``, oldest first; before the recording the first is held."""
        known = np.concatenate([self.earlier_commands, self.command[max(index - DELAY_BUFFER, 0):index]])[-DELAY_BUFFER:]
        held = np.full(max(DELAY_BUFFER - len(known), 0), known[0] if len(known) else self.command[0])
        return np.concatenate([held, known])

    def flow_regression(self, model: SamModel) -> FlowRegression:
        """The load-independent continuity rows (models.identification) over the recording's gapless stretches."""
        gapless = np.concatenate([[True], np.diff(self.times) < 1.5 / model.sample_rate])
        starts = np.flatnonzero(~gapless)
        bounds = np.concatenate([[0], starts, [len(self.times)]])
        return FlowRegression.concatenate([
            stretch_rows(model, self.joint[a:b], self.pressure_a[a:b], self.pressure_b[a:b], self.command[a:b], self.supply[a:b])
            for a, b in itertools.pairwise(bounds) if b - a >= SEGMENT_MIN_S * model.sample_rate])

    @classmethod
    def from_bag(cls, data: BagData, machine: Machine) -> Recording:
        actuator = machine.first
        samples = data.samples(SampleLayout([actuator.name], [actuator.joint]))
        signals = (*(getattr(samples, quantity)[:, 0] for quantity in ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command")),
               samples.supply_pressure)
        good = np.all(np.isfinite(np.stack(signals)), axis=0)
        if good.sum() < 0.9 * len(good):
            raise InputError(f"bag {data.path}: {np.count_nonzero(~good)} of {len(good)} samples incomplete")
        return cls(data.times[good], *(signal[good] for signal in signals))


def simulate_recording(machine: Machine, rec: Recording, every: int = 1) -> np.ndarray:
    """Normalised error (n, 3) of 2 s segment simulations started from the measured state; with ``every`` > 1
    of every that many-th segment only (the rows of the others left out), for screening."""
    model = SamModel(machine)
    model.substeps = max(1, math.ceil(1.0 / (model.sample_rate * SIMULATION_STEP_S) - 1e-9))
    piston = model.piston_from_joint(rec.joint)
    velocity = model.piston_velocity(rec.joint, rec.joint_rate)
    bias = np.array([model.effects.get("pressure_sensor_bias_a", 0.0), model.effects.get("pressure_sensor_bias_b", 0.0)])
    segment = int(round(SEGMENT_S * model.sample_rate))
    firsts = np.arange(0, len(rec.times), segment * every)
    ends = np.minimum(firsts + segment, len(rec.times))
    starts = np.empty((len(firsts), N_STATES))
    for row, start in enumerate(firsts):
        around = slice(max(start - FORCE_SAMPLES, 0), start + FORCE_SAMPLES + 1)  # the force needs less noise than one sample has
        z = model.bristle_state(piston[start], velocity[start], np.mean(rec.pressure_a[around]) - bias[0],
                                np.mean(rec.pressure_b[around]) - bias[1])
        starts[row] = [rec.pressure_a[start] - bias[0], rec.pressure_b[start] - bias[1], rec.command[start], 0.0,
                       piston[start], velocity[start], z]
    histories = np.stack([rec.commands_before(start) for start in firsts])
    states = simulate_segments(model, starts, rec.command, firsts, ends, histories)
    predicted = np.stack([states[:, 0] + bias[0], states[:, 1] + bias[1], states[:, 4]], axis=1)
    measured = np.stack([rec.pressure_a, rec.pressure_b, piston], axis=1)
    error = (measured - predicted) / SCALES
    if every > 1:
        error = error[np.concatenate([np.arange(first, end) for first, end in zip(firsts, ends)])]
    return np.where(np.isfinite(error), error, 1e3)  # a diverged segment is a very bad fit, not a crash


SMOOTH_SAMPLES = 100  # 0.1 s: white sensor noise averages out, model error (slow) stays


def smooth(error: np.ndarray) -> np.ndarray:
    """0.1 s moving mean of the error, so the gap measures the model, not the sensor noise."""
    kernel = np.ones(SMOOTH_SAMPLES) / SMOOTH_SAMPLES
    return np.stack([np.convolve(error[:, i], kernel, mode="valid") for i in range(error.shape[1])], axis=1)


def gap(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(smooth(error) ** 2)))


def _with(machine: Machine, effects: dict[str, float], calibration: dict[str, float], forms: dict[str, str] | None = None) -> Machine:
    actuator = machine.first
    valve, fluid = actuator.valve, actuator.fluid
    gain = {notch: calibration.get(f"{NOTCH_GROUP[notch]}_flow_gain", 1.0) for notch in valve.kv_poly}
    return machine.with_overrides({
        "actuators": {actuator.name: {
            "valve": {"kv_poly": {n: [c * gain[n] for c in valve.kv_poly[n]] for n in valve.kv_poly}},
            "fluid": {"oil_bulk_modulus": fluid.oil_bulk_modulus * calibration.get("bulk_factor", 1.0)},
        }},
        "effects": effects,
        "effect_forms": {name: form for name, form in (forms or {}).items() if name in effects and form is not None},
    })


# an identified valve's flow, per notch group (P-I's GSA ranks the supply notches first, then the return
# notches: one common gain left their difference to be taken for an effect), and the oil's bulk modulus
CALIBRATION_TOLERANCE = {"supply_flow_gain": 0.05, "return_flow_gain": 0.05, "bulk_factor": 0.3}
NO_CALIBRATION = {name: 1.0 for name in CALIBRATION_TOLERANCE}
NOTCH_GROUP = {"PA": "supply", "PB": "supply", "AT": "return", "BT": "return"}


def _calibration(z: np.ndarray) -> dict[str, float]:
    """Unconstrained coordinates -> factors within their tolerance (tanh keeps the search inside)."""
    return {name: 1.0 + tolerance * math.tanh(zi) for (name, tolerance), zi in zip(CALIBRATION_TOLERANCE.items(), z)}


def _calibration_coordinates(calibration: dict[str, float]) -> list[float]:
    """Inverse of _calibration, kept off the bounds where tanh is flat and a simplex step moves nothing."""
    return [math.atanh(float(np.clip((calibration[name] - 1.0) / tolerance, -0.9, 0.9)))
            for name, tolerance in CALIBRATION_TOLERANCE.items()]


def calibrate(machine: Machine, rec: Recording) -> dict[str, float]:
    """Supply- and return-notch flow gains within +-5 % and the bulk-modulus factor within +-30 % (ordinary calibration
    error), fitted to the load-independent continuity rows that commissioning identifies on: no simulation, and a
    load-side effect (friction, payload) cannot pull the valve's calibration."""
    model = SamModel(machine)
    regression = rec.flow_regression(model)
    if not len(regression.flows):
        raise InputError(f"discrepancy: no stretch of {SEGMENT_MIN_S:g} s of complete samples to calibrate on")
    groups = {group: tuple(n for n in NOTCH_GROUP if NOTCH_GROUP[n] == group) for group in ("supply", "return")}
    return group_calibration(model, regression, groups, CALIBRATION_TOLERANCE["bulk_factor"], CALIBRATION_TOLERANCE["supply_flow_gain"])


def refine(machine: Machine, calibration: dict[str, float], named: dict[str, float], forms: dict[str, str], rec: Recording,
           max_evaluations: int = 60) -> tuple[dict[str, float], dict[str, float]]:
    """The named effects and the calibration fitted jointly, from the one-at-a-time values.

    Each effect was fitted with the calibration held, and the calibration was fitted with no effect:
    where the two overlap (entrained air lowers the effective bulk modulus, a valve delay and the flow
    gain both shape the pressure transients) the first fit lets calibration absorb part of the effect.
    Where it absorbed it up to its tolerance (a spool offset pushed flow gain and bulk modulus to both
    bounds; a leak in A pushed all three), tanh is flat and the simplex cannot walk back: the joint fit
    starts from whichever of the separate calibration and none fits better with the effects added,
    with each factor at most 90 % of its tolerance away from 1.
    """
    if not named:
        return calibration, named
    start_gap, calibration = min(((gap(simulate_recording(_with(machine, named, c, forms), rec)), c) for c in (calibration, NO_CALIBRATION)),
                                 key=lambda scored: scored[0])
    names = list(named)
    ranges = [EFFECT_RANGES[n] for n in names]

    def unpack(z: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
        effects = {n: float(np.clip(named[n] + zi * (high - low), low, high))
                   for n, zi, (low, high) in zip(names, z[len(CALIBRATION_TOLERANCE):], ranges)}
        return _calibration(z[:len(CALIBRATION_TOLERANCE)]), effects

    def cost(z: np.ndarray) -> float:
        calibrated, effects = unpack(z)
        return gap(simulate_recording(_with(machine, effects, calibrated, forms), rec))

    start = np.concatenate([_calibration_coordinates(calibration), np.zeros(len(names))])
    # ~1.5 % flow, ~9 % bulk modulus, 5 % of each effect's range
    steps = np.concatenate([np.full(len(CALIBRATION_TOLERANCE), 0.3), np.full(len(names), 0.05)])
    simplex = np.vstack([start] + [start + np.eye(len(start))[i] * steps[i] for i in range(len(start))])
    result = minimize(cost, start, method="Nelder-Mead",
                      options={"maxfev": max_evaluations, "xatol": 1e-3, "fatol": 1e-4, "initial_simplex": simplex})
    if result.fun > start_gap:  # the start kept off the bounds never got back to what the bound had
        return calibration, named
    return unpack(result.x)


def _bic(error: np.ndarray, parameters: int, sample_rate: float) -> float:
    n_eff = max(len(error) / (DECORRELATION_S * sample_rate), 1.0)
    return n_eff * math.log(gap(error) ** 2) + parameters * math.log(n_eff)


@njit(cache=True)
def _equation_error(piston, velocity, p_a, p_b, spool, supply, params, poly, centre, dt, out):
    """Per sample (Q_A model - A_A x' - V_A/B p_A', same for B) [L/min] at the spool the command drives."""
    for k in range(piston.shape[0]):
        s = spool_opening(spool[k], 0.0, params[Param.DEADZONE], 1.0, False, params[Param.DEADZONE_PLAIN] < 0.5)
        neutral = spool_opening(spool[k], 0.0, params[Param.VALVE_OVERLAP], 1.0, False)
        dpa = (p_a[k] - p_a[k - 1]) / dt if k > 0 else 0.0
        dpb = (p_b[k] - p_b[k - 1]) / dt if k > 0 else 0.0
        out[k, 0], out[k, 1], _, _ = flow_balance(s, neutral, piston[k], velocity[k], p_a[k], p_b[k], dpa, dpb, p_a[k], p_b[k],
                                                   supply[k], params, poly, centre)


def load_independent_error(machine: Machine, rec: Recording) -> np.ndarray:
    """Flow errors [L/min] of the load-independent model (P-II's reduced model as equation error):
    measured motion and pressures in, no load, friction or mass involved - so what remains here is
    a valve, leak or bulk-modulus matter, and what appears only in the forward simulation is load-side."""
    model = SamModel(machine)
    p = model.base
    piston = model.piston_from_joint(rec.joint)
    velocity = model.piston_velocity(rec.joint, rec.joint_rate)
    out = np.empty((len(rec.times), 2))
    supply = np.full(len(rec.times), p[Param.SUPPLY])
    dt = 1.0 / model.sample_rate
    spool = spool_positions(np.asarray(rec.command, dtype=float), p[Param.SPOOL_OMEGA], p[Param.SPOOL_DAMPING], dt, 10)
    _equation_error(piston, velocity, rec.pressure_a, rec.pressure_b, spool, supply, p, model.poly, model.centre_leakage, dt, out)
    return out


REGIMES = ("extending", "retracting", "at_rest", "low_pressure", "high_pressure", "lower_stroke", "upper_stroke")


def regimes(rec: Recording) -> dict[str, np.ndarray]:
    moving = np.abs(rec.joint_rate) > 0.01
    mean_p = 0.5 * (rec.pressure_a + rec.pressure_b)
    return {"extending": moving & (rec.joint_rate > 0), "retracting": moving & (rec.joint_rate < 0), "at_rest": ~moving,
            "low_pressure": mean_p < np.median(mean_p), "high_pressure": mean_p >= np.median(mean_p),
            "lower_stroke": rec.joint < np.median(rec.joint), "upper_stroke": rec.joint >= np.median(rec.joint)}


def localise(rec: Recording, error: np.ndarray, channels: tuple[str, ...] = ("p_a", "p_b", "position")) -> dict[str, Any]:
    """Where the error concentrates: RMS of its 0.1 s mean per channel, per regime and per 5 s window."""
    error = smooth(error)
    rec = rec.part(slice(SMOOTH_SAMPLES - 1, None))
    out: dict[str, Any] = {"by_channel": {c: float(np.sqrt(np.mean(error[:, i] ** 2))) for i, c in enumerate(channels)}}
    out["by_regime"] = {name: {c: float(np.sqrt(np.mean(error[mask, i] ** 2))) if mask.any() else None for i, c in enumerate(channels)}
                        for name, mask in regimes(rec).items()}
    edges = np.arange(rec.times[0], rec.times[-1] + 5.0, 5.0)
    index = np.digitize(rec.times, edges) - 1
    out["by_time"] = [{"t_s": float(edges[k]), "rms": float(np.sqrt(np.mean(error[index == k] ** 2)))} for k in range(len(edges) - 1)
                      if np.any(index == k)]
    return out


def _signature(rec: Recording, before: np.ndarray, after: np.ndarray) -> float:
    """How much of the per-regime error profile the effect removes (1 = all of it where it was)."""
    gains, weights = [], []
    for mask in regimes(rec.part(slice(SMOOTH_SAMPLES - 1, None))).values():
        if mask.sum() < 100:
            continue
        b, a = np.mean(before[mask] ** 2), np.mean(after[mask] ** 2)
        gains.append((b - a) / b)
        weights.append(b)
    return float(np.average(gains, weights=weights)) if gains else 0.0


CALIBRATION_BAND = 0.1  # a flow-gain "effect" this small is calibration (the +-5 % above plus margin)


@dataclass
class Candidate:
    name: str
    form: str | None  # names.EFFECT_FORMS of the family, None where it has one form
    value: float
    bic_gain: float
    reduction: float
    signature: float
    required_reduction: float = MIN_REDUCTION

    @property
    def significant(self) -> bool:
        if self.name == "valve_flow_gain" and abs(self.value) < CALIBRATION_BAND:
            return False
        return self.bic_gain > BIC_MARGIN and self.reduction >= self.required_reduction


SCREEN_EVERY = 4  # candidates are screened on every fourth 2 s segment of the fit data,
SCREEN_KEEP = 2  # and every form of the best two families fitted again on all of it and scored
MAX_EFFECTS = 3
HELD_OUT_GAIN = 0.05  # an effect added must lower the held-out gap by 5 %, or selection stops


def candidate_effects(named: dict[str, float]) -> list[tuple[str, str | None]]:
    """(family, form) of every effect not named yet: each form of a family with several (names.EFFECT_FORMS)."""
    return [(name, form) for name in EFFECT_RANGES if name not in named for form in (list(EFFECT_FORMS.get(name, ())) or [None])]


def progress_steps() -> int:
    """Progress units of one run at most: calibration, and per selection step the screened candidates, the re-fits
    (every form of SCREEN_KEEP families) and the joint fit."""
    return 1 + MAX_EFFECTS * (len(candidate_effects({})) + SCREEN_KEEP * max(map(len, EFFECT_FORMS.values())) + 1)


def fit_effects(machine: Machine, calibration: dict[str, float], rec: Recording, named: dict[str, float], forms: dict[str, str],
                progress: Callable[[int], None] | None = None) -> tuple[list[Candidate], list[dict[str, Any]]]:
    """Each effect family and form not named yet as a one-parameter extension of the model with ``named``.

    Screened on every SCREEN_EVERY-th segment (a quarter of the simulation each); every form of the SCREEN_KEEP
    best families is fitted again on all segments, from a bracket around its screened value, and scored.
    Returns the scored candidates, best first, and the screening table.
    """
    rate = SamModel(machine).sample_rate
    base = simulate_recording(_with(machine, named, calibration, forms), rec)
    base_bic = _bic(base, len(named), rate)

    def error_with(name: str, form: str | None, value: float, every: int = 1) -> np.ndarray:
        return simulate_recording(_with(machine, {**named, name: value}, calibration, {**forms, name: form}), rec, every)

    screened = []
    for name, form in candidate_effects(named):
        low, high = EFFECT_RANGES[name]
        result = minimize_scalar(lambda value, name=name, form=form: gap(error_with(name, form, value, SCREEN_EVERY)), bounds=(low, high),
                                 method="bounded", options={"maxiter": 10, "xatol": 2e-3 * (high - low)})
        screened.append({"name": name, "form": form, "value": float(result.x), "screen_gap": float(result.fun)})
        if progress is not None:
            progress(1)
    families = list(dict.fromkeys(row["name"] for row in sorted(screened, key=lambda row: row["screen_gap"])))[:SCREEN_KEEP]
    out = []
    for row in [row for row in screened if row["name"] in families]:  # every form of them: screening hardly tells forms apart
        name, form = row["name"], row["form"]
        low, high = EFFECT_RANGES[name]
        span = 0.1 * (high - low)
        result = minimize_scalar(lambda value, name=name, form=form: gap(error_with(name, form, value)),
                                 bounds=(max(low, row["value"] - span), min(high, row["value"] + span)),
                                 method="bounded", options={"maxiter": 8, "xatol": 1e-3 * (high - low)})
        error = error_with(name, form, float(result.x))
        bic = _bic(error, len(named) + 1, rate)
        # a second effect on top of a first must explain more of what is left (it competes with the rest of the mismatch)
        out.append(Candidate(name, form, float(result.x), base_bic - bic, 1.0 - (gap(error) / gap(base)) ** 2,
                             _signature(rec, smooth(base), smooth(error)), MIN_REDUCTION if not named else 2 * MIN_REDUCTION))
        if progress is not None:
            progress(1)
    return sorted(out, key=lambda c: (-c.bic_gain, -c.signature)), screened


@dataclass(frozen=True)
class BackwardCheck:
    """One named effect's place beside the others: the information criterion's loss without it."""

    effect: str
    bic_gain: float
    kept: bool

    def to_json(self) -> dict[str, Any]:
        return {"effect": self.effect, "bic_gain": self.bic_gain, "kept": self.kept}


def backward_check(machine: Machine, calibration: dict[str, float], named: dict[str, float], forms: dict[str, str],
                   rec: Recording) -> list[BackwardCheck]:
    """Whether each named effect still earns its place beside the others: the information criterion without it
    (the others at their joint values) must be worse by more than BIC_MARGIN."""
    rate = SamModel(machine).sample_rate
    full_bic = _bic(simulate_recording(_with(machine, named, calibration, forms), rec), len(named), rate)
    rows = []
    for name in named:
        rest = {other: value for other, value in named.items() if other != name}
        gain = _bic(simulate_recording(_with(machine, rest, calibration, forms), rec), len(rest), rate) - full_bic
        rows.append(BackwardCheck(name, gain, gain > BIC_MARGIN))
    return rows


@dataclass
class SelectionStep:
    """One forward step of :func:`select`: every candidate fitted on top of the effects named so far, the one added (None:
    none was significant) and what adding it did to the held-out gap."""

    candidates: list[Candidate]
    screened: list[dict[str, Any]]  # each family and form's value and gap on the screening segments (fit_effects)
    held_out_gap_before: float
    added: str | None = None
    form: str | None = None  # the added family's form, chosen after the joint fit
    separate_value: float | None = None  # the added effect fitted alone
    joint_values: dict[str, float] = field(default_factory=dict)  # every named effect fitted jointly with it
    joint_calibration: dict[str, float] = field(default_factory=dict)
    forms_jointly: dict[str, float] = field(default_factory=dict)  # form -> fit gap, where several forms were tried jointly
    fit_gap_after: float | None = None
    held_out_gap_after: float | None = None
    kept: bool = False  # lowered the held-out gap by HELD_OUT_GAIN

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"candidates": [c.__dict__ | {"significant": c.significant} for c in self.candidates],
                               "screened": self.screened, "held_out_gap_before": self.held_out_gap_before}
        if self.added is not None:
            out |= {"added": self.added, "form": self.form, "separate_value": self.separate_value, "joint_values": self.joint_values,
                    "joint_calibration": self.joint_calibration, "forms_jointly": self.forms_jointly,
                    "fit_gap_after": self.fit_gap_after, "held_out_gap_after": self.held_out_gap_after, "kept": self.kept}
        return out


@dataclass(frozen=True)
class Selection:
    """What forward selection and the backward check kept (:func:`select`)."""

    named: dict[str, float]  # effect -> its value, fitted jointly
    forms: dict[str, str]  # effect -> its form, for families with several
    calibration: dict[str, float]  # the calibration fitted jointly with them
    steps: list[SelectionStep]
    backward: list[BackwardCheck]
    dropped: list[str]

    def to_json(self) -> dict[str, Any]:
        return {"steps": [step.to_json() for step in self.steps], "backward": [check.to_json() for check in self.backward],
                "dropped": self.dropped}


@dataclass(frozen=True)
class NamedEffect:
    name: str
    value: float
    form: str | None = None  # None: the family has one form

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "parameters": {"value": self.value} | ({"form": self.form} if self.form is not None else {})}


@dataclass(frozen=True)
class Gap:
    """A gap of the model before and after the named effects (``GAP_METRIC``)."""

    before: float
    after: float


GAP_METRIC = "rms of the 0.1 s mean error of 2 s segment simulations; p_A, p_B per 0.1 MPa, position per 1 mm"


@dataclass
class DiscrepancyReport:
    """What ``hydro-ros discrepancy`` found; :meth:`to_json` is DIR/report.json (the contract's fields first)."""

    effects: list[NamedEffect]  # empty: the data show no significant missing effect
    fit_gap: Gap
    validation_gap: Gap  # on the held-out part, no value fitted on it
    uncalibrated_validation_gap: float
    calibration: dict[str, float]
    selection: Selection
    separate_effects: dict[str, float]  # each effect's value fitted alone, when it was added
    localisation: dict[str, Any]  # localise() of the fit part (forward and load-independent) and the validation part
    fit_s: float
    validation_s: float
    plots: list[str]  # validation.png, localisation.png
    bag_errors: list[str]
    partial: bool  # computed on what could be read, not on the whole recording
    html: str = ""

    def to_json(self) -> dict[str, Any]:
        return {
            "effects": [effect.to_json() for effect in self.effects],
            "gap": {"metric": GAP_METRIC, "before": self.fit_gap.before, "after": self.fit_gap.after},
            "validation_gap": {"before": self.validation_gap.before, "after": self.validation_gap.after},
            "uncalibrated_validation_gap": self.uncalibrated_validation_gap,
            "calibration": self.calibration,
            "joint_fit": {"calibration": self.selection.calibration, "effects": self.selection.named,
                          "separate_effects": self.separate_effects},
            "selection": self.selection.to_json(),
            "localisation": self.localisation, "fit_s": self.fit_s, "validation_s": self.validation_s, "plots": self.plots,
            "bag_errors": self.bag_errors, "partial": self.partial, "html": self.html,
        }


def select(machine: Machine, calibration: dict[str, float], fit: Recording, held_out: Recording,
           progress: Callable[[int], None] | None = None) -> Selection:
    """Forward selection with re-fitting, then a backward check.

    Each step fits every candidate on top of the effects named so far, adds the most significant one, and
    fits the named effects and the calibration jointly again (each effect was fitted with the others held).
    It stops when no candidate is significant on the fit data, or when the one added does not lower the
    held-out gap by HELD_OUT_GAIN (the held-out part chooses when to stop; no value is fitted on it).
    """
    named: dict[str, float] = {}
    forms: dict[str, str] = {}
    joint = calibration
    rate = SamModel(machine).sample_rate
    held_out_gap = gap(simulate_recording(_with(machine, {}, calibration), held_out))
    steps: list[SelectionStep] = []
    for _ in range(MAX_EFFECTS):
        candidates, screened = fit_effects(machine, joint, fit, named, forms, progress)
        step = SelectionStep(candidates, screened, held_out_gap)
        steps.append(step)
        best = next((c for c in candidates if c.significant), None)
        if best is None:
            break
        # the family's forms are told apart after the joint fit: fitted alone, with the calibration held at
        # what it absorbed of the effect, the wrong form can fit better (an orifice leak came out laminar).
        # Another form replaces the family's first only by more than BIC_MARGIN: a 50 ms transport delay
        # and a 60 ms lag fit within 1 % of each other on the SAM's slow commands.
        trials = []
        for form in [c for c in candidates if c.name == best.name and (c is best or c.significant)]:
            trial_forms = {**forms, best.name: form.form} if form.form else dict(forms)
            trial_joint, trial_named = refine(machine, joint, {**named, best.name: form.value}, trial_forms, fit)
            error = simulate_recording(_with(machine, trial_named, trial_joint, trial_forms), fit)
            bic = _bic(error, len(named) + 1, rate) - (BIC_MARGIN if form.form == first_form(best.name) else 0.0)
            trials.append((bic, gap(error), form, trial_forms, trial_joint, trial_named))
        _, fit_gap, chosen, trial_forms, trial_joint, trial_named = min(trials, key=lambda trial: trial[0])
        if progress is not None:
            progress(1)
        trial_gap = gap(simulate_recording(_with(machine, trial_named, trial_joint, trial_forms), held_out))
        step.added, step.form, step.separate_value, step.joint_values, step.joint_calibration = (
            best.name, chosen.form, chosen.value, trial_named, trial_joint)
        step.forms_jointly = {str(t[2].form): t[1] for t in trials} if len(trials) > 1 else {}
        step.fit_gap_after, step.held_out_gap_after = fit_gap, trial_gap
        step.kept = trial_gap <= (1.0 - HELD_OUT_GAIN) * held_out_gap
        if not step.kept:
            break
        named, forms, joint, held_out_gap = trial_named, trial_forms, trial_joint, trial_gap
    backward = backward_check(machine, joint, named, forms, fit) if len(named) > 1 else []
    dropped = [check.effect for check in backward if not check.kept]
    if dropped:
        joint, named = refine(machine, joint, {n: v for n, v in named.items() if n not in dropped},
                              {n: f for n, f in forms.items() if n not in dropped}, fit)
        forms = {n: f for n, f in forms.items() if n in named}
    return Selection(named, forms, joint, steps, backward, dropped)


def run(data: BagData, machine: Machine, out: Path, progress: Callable[[int], None] | None = None) -> DiscrepancyReport:
    rec = Recording.from_bag(data, machine)
    split = int(FIT_SHARE * len(rec.times))
    fit, validation = rec.part(slice(0, split)), rec.part(slice(split, None))
    calibration = calibrate(machine, fit)
    if progress:
        progress(1)
    selection = select(machine, calibration, fit, validation, progress)
    named, forms, joint_calibration = selection.named, selection.forms, selection.calibration
    separate = {step.added: step.separate_value for step in selection.steps if step.kept and step.added and step.separate_value is not None}
    before_fit = simulate_recording(_with(machine, {}, calibration), fit)
    after_fit = simulate_recording(_with(machine, named, joint_calibration, forms), fit)
    raw_validation = simulate_recording(machine, validation)
    before_validation = simulate_recording(_with(machine, {}, calibration), validation)
    after_validation = simulate_recording(_with(machine, named, joint_calibration, forms), validation)
    model = _with(machine, named, joint_calibration, forms)
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.yaml").write_text(f"# model of hydro-ros discrepancy of cylinder {machine.first.name} alone (on an arm: its share of "
                                    "the arm as its load): calibrated flow gain and bulk modulus, named effects.\n# A study's model, "
                                    "not your machine's config: carry the named effects into its effects: section.\n"
                                    + yaml.safe_dump(model.to_yaml_mapping(), sort_keys=False))
    labels = {f"{name} ({forms[name]})" if name in forms else name: value for name, value in named.items()}
    plot = plot_discrepancy(validation, machine, before=before_validation, after=after_validation, effects=labels,
                            out=out / "validation.png", scales=SCALES)
    validation_localisation = {"before": localise(validation, before_validation), "after": localise(validation, after_validation)}
    where = plot_gap_localisation(validation_localisation["before"], validation_localisation["after"], out / "localisation.png")
    report = DiscrepancyReport(
        effects=[NamedEffect(name, value, forms.get(name)) for name, value in named.items()],
        fit_gap=Gap(gap(before_fit), gap(after_fit)), validation_gap=Gap(gap(before_validation), gap(after_validation)),
        uncalibrated_validation_gap=gap(raw_validation), calibration=calibration, selection=selection, separate_effects=separate,
        localisation={"forward": localise(fit, before_fit),
                      "load_independent_l_min": localise(fit, load_independent_error(_with(machine, {}, calibration), fit), ("q_a", "q_b")),
                      "validation": validation_localisation},
        fit_s=float(fit.times[-1] - fit.times[0]), validation_s=float(validation.times[-1] - validation.times[0]),
        plots=[str(plot), str(where)], bag_errors=list(data.errors), partial=not data.complete)
    report.html = str(write_html(report, data.path, out / "report.html"))
    return report


def write_html(report: DiscrepancyReport, bag: Path | str, out: Path) -> Path:
    """One self-contained page (plots inlined) of what the workflow found, for a person rather than a program."""

    def cell(value: Any) -> str:
        if isinstance(value, float):
            return f"{value:.4g}"
        return html.escape("-" if value is None else str(value))

    def table(header: list[str], rows: list[list[Any]]) -> str:
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in row) + "</tr>" for row in rows)
        return f"<table><tr>{head}</tr>{body}</table>"

    def image(path: str) -> str:
        encoded = base64.b64encode(Path(path).read_bytes()).decode()
        return f'<img alt="{html.escape(Path(path).name)}" src="data:image/png;base64,{encoded}">'

    effects = [[e.name, e.form, e.value] for e in report.effects]
    steps = []
    for number, step in enumerate(report.selection.steps, start=1):
        tried = ", ".join(f"{c.name}{' (' + c.form + ')' if c.form else ''}: BIC {-c.bic_gain:+.0f}, gap² {-c.reduction:+.0%}"
                          for c in step.candidates)
        steps.append([number, step.added or "none significant", step.form, step.separate_value,
                      step.joint_values.get(step.added) if step.added else None, step.held_out_gap_before, step.held_out_gap_after,
                      step.kept if step.added else None, tried])
    local = report.localisation["validation"]
    regimes = [[name, *(local[when]["by_regime"][name].get(channel) for when in ("before", "after") for channel in ("p_a", "p_b", "position"))]
               for name in local["before"]["by_regime"]]
    gap = report.validation_gap
    page = f"""<!DOCTYPE html><html><head><meta charset="utf-8"><title>hydro-ros discrepancy: {html.escape(str(bag))}</title>
<style>body{{font-family:sans-serif;max-width:1200px;margin:auto}}table{{border-collapse:collapse;margin:1em 0}}
td,th{{border:1px solid #999;padding:3px 6px;font-size:13px;vertical-align:top}}img{{max-width:100%}}</style></head><body>
<h1>Model discrepancy of {html.escape(str(bag))}</h1>
<p>Validation gap (last {report.validation_s:.0f} s, no value fitted on it) {gap.before:.3g} &rarr; {gap.after:.3g}
(uncalibrated {report.uncalibrated_validation_gap:.3g}); fitted on the first {report.fit_s:.0f} s.
{html.escape(GAP_METRIC)}.</p>
<h2>Named effects</h2>{table(["effect (family)", "form", "value"], effects) if effects else "<p>none: the data show no significant missing effect</p>"}
<h2>Selection path</h2>{table(["step", "added", "form", "fitted alone", "fitted jointly", "held-out gap before", "after", "kept",
                              "candidates re-fitted on all segments"], steps)}
<p>Backward check: {html.escape(", ".join(f"{r.effect} (BIC +{r.bic_gain:.0f} without it: {'kept' if r.kept else 'dropped'})"
                                         for r in report.selection.backward) or "one effect or none, nothing to check")}.</p>
<h2>Where the gap sits (validation part)</h2>{image(report.plots[1])}
{table(["regime", "p_A before", "p_B before", "position before", "p_A after", "p_B after", "position after"], regimes)}
<h2>Measured and simulated</h2>{image(report.plots[0])}
</body></html>"""
    out.write_text(page)
    return out
