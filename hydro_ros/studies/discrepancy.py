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
   (flow +-5 %, bulk modulus +-30 %), on the first 60 % of the data;
2. localise: the error by channel, by regime (extending, retracting, at rest; pressure level;
   position) and in 5 s windows, for the forward simulation and for the load-independent one
   (the reduced model of P-II driven by the measured motion);
3. name: each effect of the contract vocabulary is fitted as a one-parameter extension on the
   fit data and scored with the Bayesian information criterion on an effective sample count
   (one independent sample per 0.1 s, INFERRED); an effect is significant if it lowers BIC by
   more than 10 and the squared error by at least 30 %; the most significant is named, and a
   second one only if it is significant on top of the first;
4. refine: the named effects and the calibration are fitted jointly (each effect was fitted with
   the calibration held, and calibration can absorb part of an effect: air lowers the bulk modulus);
5. add and verify: the config with the effects is written as model.yaml and the gap is measured
   before and after on the last 40 % of the data, which no fit has seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml
from numba import njit
from scipy.optimize import minimize, minimize_scalar

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.reader import BagData
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Effect
from hydro_ros.fdi.parity import flow_balance
from hydro_ros.models.kinematics import piston_position, torque_arm
from hydro_ros.models.sam import (
    DEADZONE,
    DELAY_BUFFER,
    MOUNT_L1,
    MOUNT_L2,
    MOUNT_L3,
    SPOOL_DAMPING,
    SPOOL_OMEGA,
    SUPPLY,
    THETA_OFFSET,
    SamModel,
    SamPlant,
)
from hydro_ros.models.valve import spool_opening, spool_positions
from hydro_ros.studies.plots import plot_discrepancy

SEGMENT_S = 2.0
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
    earlier_commands: np.ndarray = field(default_factory=lambda: np.empty(0))

    def part(self, part: slice) -> "Recording":
        first = range(len(self.times))[part].start
        earlier = np.concatenate([self.earlier_commands, self.command[:first]])[-DELAY_BUFFER:]
        return Recording(*(getattr(self, f.name)[part] for f in fields(self) if f.name != "earlier_commands"), earlier)

    def commands_before(self, index: int) -> np.ndarray:
        """The DELAY_BUFFER valve commands before sample ``index``, oldest first; before the recording the first is held."""
        known = np.concatenate([self.earlier_commands, self.command[max(index - DELAY_BUFFER, 0):index]])[-DELAY_BUFFER:]
        held = np.full(max(DELAY_BUFFER - len(known), 0), known[0] if len(known) else self.command[0])
        return np.concatenate([held, known])

    @classmethod
    def from_bag(cls, data: BagData, machine: Machine) -> "Recording":
        actuator = machine.first
        samples = data.samples(SampleLayout([actuator.name], [actuator.joint]))
        signals = tuple(getattr(samples, quantity)[:, 0] for quantity in
                        ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command"))
        good = np.all(np.isfinite(np.stack(signals)), axis=0)
        if good.sum() < 0.9 * len(good):
            raise InputError(f"bag {data.path}: {np.count_nonzero(~good)} of {len(good)} samples incomplete")
        return cls(data.times[good], *(signal[good] for signal in signals))


def simulate(machine: Machine, rec: Recording) -> np.ndarray:
    """Normalised error (n, 3) of 2 s segment simulations started from the measured state."""
    model = SamModel(machine)
    p = model.base
    theta = rec.joint + p[THETA_OFFSET]
    piston = piston_position(theta, p[MOUNT_L1], p[MOUNT_L2], p[MOUNT_L3])
    velocity = torque_arm(theta, p[MOUNT_L1], p[MOUNT_L2]) * rec.joint_rate
    bias = np.array([model.effects.get("pressure_sensor_bias_a", 0.0), model.effects.get("pressure_sensor_bias_b", 0.0)])
    segment = int(round(SEGMENT_S * model.sample_rate))
    predicted = np.empty((len(rec.times), 3))
    for start in range(0, len(rec.times), segment):
        end = min(start + segment, len(rec.times))
        plant = SamPlant(model, initial_joint=float(rec.joint[start]))
        around = slice(max(start - FORCE_SAMPLES, 0), start + FORCE_SAMPLES + 1)  # the force needs less noise than one sample has
        z = model.bristle_state(piston[start], velocity[start], np.mean(rec.pressure_a[around]) - bias[0],
                                np.mean(rec.pressure_b[around]) - bias[1])
        plant.state[:] = [rec.pressure_a[start] - bias[0], rec.pressure_b[start] - bias[1], rec.command[start], 0.0,
                          piston[start], velocity[start], z]
        plant.prime_command_history(rec.commands_before(start))
        try:
            _, states, _ = plant.advance(end - start, commands=rec.command[start:end])
        except FloatingPointError:
            predicted[start:end] = np.nan
            continue
        predicted[start:end, :2] = states[:, :2] + bias
        predicted[start:end, 2] = states[:, 4]
    measured = np.stack([rec.pressure_a, rec.pressure_b, piston], axis=1)
    error = (measured - predicted) / SCALES
    return np.where(np.isfinite(error), error, 1e3)  # a diverged segment is a very bad fit, not a crash


SMOOTH_SAMPLES = 100  # 0.1 s: white sensor noise averages out, model error (slow) stays


def smooth(error: np.ndarray) -> np.ndarray:
    """0.1 s moving mean of the error, so the gap measures the model, not the sensor noise."""
    kernel = np.ones(SMOOTH_SAMPLES) / SMOOTH_SAMPLES
    return np.stack([np.convolve(error[:, i], kernel, mode="valid") for i in range(error.shape[1])], axis=1)


def gap(error: np.ndarray) -> float:
    return float(np.sqrt(np.mean(smooth(error) ** 2)))


def _with(machine: Machine, effects: dict[str, float], calibration: dict[str, float]) -> Machine:
    actuator = machine.first
    valve, fluid = actuator.valve, actuator.fluid
    gain = {notch: calibration.get(f"{NOTCH_GROUP[notch]}_flow_gain", 1.0) for notch in valve.kv_poly}
    return machine.with_overrides({
        "actuators": {actuator.name: {
            "valve": {"kv_poly": {n: [c * gain[n] for c in valve.kv_poly[n]] for n in valve.kv_poly}},
            "fluid": {"oil_bulk_modulus": fluid.oil_bulk_modulus * calibration.get("bulk_factor", 1.0)},
        }},
        "effects": effects,
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
    """Supply- and return-notch flow gains within +-5 % and bulk-modulus factor within +-30 % (ordinary calibration error)."""

    def cost(z: np.ndarray) -> float:
        return gap(simulate(_with(machine, {}, _calibration(z)), rec))

    start = np.zeros(len(CALIBRATION_TOLERANCE))
    simplex = np.vstack([start, 0.6 * np.eye(len(start))])  # steps of ~3 % flow and ~17 % bulk modulus
    result = minimize(cost, start, method="Nelder-Mead",
                      options={"maxfev": 45, "xatol": 0.05, "fatol": 1e-3, "initial_simplex": simplex})
    return _calibration(result.x)


def refine(machine: Machine, calibration: dict[str, float], named: dict[str, float], rec: Recording,
           max_evaluations: int = 100) -> tuple[dict[str, float], dict[str, float]]:
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
    start_gap, calibration = min(((gap(simulate(_with(machine, named, c), rec)), c) for c in (calibration, NO_CALIBRATION)),
                                 key=lambda scored: scored[0])
    names = list(named)
    ranges = [EFFECT_RANGES[n] for n in names]

    def unpack(z: np.ndarray) -> tuple[dict[str, float], dict[str, float]]:
        effects = {n: float(np.clip(named[n] + zi * (high - low), low, high))
                   for n, zi, (low, high) in zip(names, z[len(CALIBRATION_TOLERANCE):], ranges)}
        return _calibration(z[:len(CALIBRATION_TOLERANCE)]), effects

    def cost(z: np.ndarray) -> float:
        calibrated, effects = unpack(z)
        return gap(simulate(_with(machine, effects, calibrated), rec))

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
        s = spool_opening(spool[k], 0.0, params[DEADZONE], 1.0, False)
        dpa = (p_a[k] - p_a[k - 1]) / dt if k > 0 else 0.0
        dpb = (p_b[k] - p_b[k - 1]) / dt if k > 0 else 0.0
        out[k, 0], out[k, 1] = flow_balance(s, piston[k], velocity[k], p_a[k], p_b[k], dpa, dpb, supply[k], params, poly, centre)


def load_independent_error(machine: Machine, rec: Recording) -> np.ndarray:
    """Flow errors [L/min] of the load-independent model (P-II's reduced model as equation error):
    measured motion and pressures in, no load, friction or mass involved - so what remains here is
    a valve, leak or bulk-modulus matter, and what appears only in the forward simulation is load-side."""
    model = SamModel(machine)
    p = model.base
    theta = rec.joint + p[THETA_OFFSET]
    piston = piston_position(theta, p[MOUNT_L1], p[MOUNT_L2], p[MOUNT_L3])
    velocity = torque_arm(theta, p[MOUNT_L1], p[MOUNT_L2]) * rec.joint_rate
    out = np.empty((len(rec.times), 2))
    supply = np.full(len(rec.times), p[SUPPLY])
    dt = 1.0 / model.sample_rate
    spool = spool_positions(np.asarray(rec.command, dtype=float), p[SPOOL_OMEGA], p[SPOOL_DAMPING], dt, 10)
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


def fit_effects(machine: Machine, calibration: dict[str, float], rec: Recording, named: dict[str, float],
                progress: Callable[[int], None] | None = None) -> list[Candidate]:
    base = simulate(_with(machine, named, calibration), rec)
    base_bic = _bic(base, len(named), SamModel(machine).sample_rate)
    out = []
    for name, (low, high) in EFFECT_RANGES.items():
        if name in named:
            continue

        def cost(value: float, name: str = name) -> float:
            return gap(simulate(_with(machine, {**named, name: value}, calibration), rec))

        result = minimize_scalar(cost, bounds=(low, high), method="bounded", options={"maxiter": 14, "xatol": 1e-3 * (high - low)})
        error = simulate(_with(machine, {**named, name: float(result.x)}, calibration), rec)
        bic = _bic(error, len(named) + 1, SamModel(machine).sample_rate)
        # a second effect on top of a first must explain more of what is left (it competes with the rest of the mismatch)
        out.append(Candidate(name, float(result.x), base_bic - bic, 1.0 - (gap(error) / gap(base)) ** 2,
                             _signature(rec, smooth(base), smooth(error)), MIN_REDUCTION if not named else 2 * MIN_REDUCTION))
        if progress is not None:
            progress(1)
    return sorted(out, key=lambda c: (-c.bic_gain, -c.signature))


def run(data: BagData, machine: Machine, out: Path, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    rec = Recording.from_bag(data, machine)
    split = int(FIT_SHARE * len(rec.times))
    fit, validation = rec.part(slice(0, split)), rec.part(slice(split, None))
    calibration = calibrate(machine, fit)
    if progress:
        progress(1)
    named: dict[str, float] = {}
    rounds = []
    for _ in range(2):
        candidates = fit_effects(machine, calibration, fit, named, progress)
        rounds.append([c.__dict__ | {"significant": c.significant} for c in candidates])
        best = next((c for c in candidates if c.significant), None)
        if best is None:
            break
        named[best.name] = best.value
    separate = dict(named)
    joint_calibration, named = refine(machine, calibration, named, fit)
    if progress:
        progress(1)
    before_fit = simulate(_with(machine, {}, calibration), fit)
    after_fit = simulate(_with(machine, named, joint_calibration), fit)
    raw_validation = simulate(machine, validation)
    before_validation = simulate(_with(machine, {}, calibration), validation)
    after_validation = simulate(_with(machine, named, joint_calibration), validation)
    model = _with(machine, named, joint_calibration)
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.yaml").write_text("# model of hydro-ros discrepancy: calibrated flow gain and bulk modulus, named effects\n"
                                    + yaml.safe_dump(model.to_yaml_mapping(), sort_keys=False))
    plot = plot_discrepancy(validation, machine, before=before_validation, after=after_validation, effects=named,
                            out=out / "validation.png", scales=SCALES)
    return {
        "effects": [{"name": name, "parameters": {"value": value}} for name, value in named.items()],
        "gap": {"metric": "rms of the 0.1 s mean error of 2 s segment simulations; p_A, p_B per 0.1 MPa, position per 1 mm",
                "before": gap(before_fit), "after": gap(after_fit)},
        "validation_gap": {"before": gap(before_validation), "after": gap(after_validation)},
        "uncalibrated_validation_gap": gap(raw_validation),
        "calibration": calibration,
        "joint_fit": {"calibration": joint_calibration, "effects": named, "separate_effects": separate},
        "candidates": rounds,
        "localisation": {"forward": localise(fit, before_fit),
                         "load_independent_l_min": localise(fit, load_independent_error(_with(machine, {}, calibration), fit),
                                                            ("q_a", "q_b"))},
        "fit_s": float(fit.times[-1] - fit.times[0]), "validation_s": float(validation.times[-1] - validation.times[0]),
        "plots": [str(plot)],
        "bag_errors": list(data.errors),
        "partial": not data.complete,  # computed on what could be read, not on the whole recording
    }
