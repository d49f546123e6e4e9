"""A SAM test bed written apart from the model under test: test data that models/sam.py has not been fitted to.

The discrepancy workflow fits ``SamModel``; data from ``SamPlant`` (hidden_effects) share its code, its forms and
its integrator, so a form the two agree on by construction is never tested. This plant is written again from the
physics of P-I and P-II (one boom on a double-acting cylinder in a triangle mount, a proportional valve, chambers
with oil and hose compliance, LuGre friction, leaks), with its own layout and, where the papers leave a choice, its
own forms:

* the boom is integrated in joint space, J theta'' = r F - tau_g (P-I eq. 16), not as the piston's reduced mass;
* each notch's flow coefficient is a table read off the data sheet's curve (the config's polynomial) at
  ``NOTCH_TABLE_OPENINGS``, linear between its points, as a valve maker publishes it: not P-II's cubic;
* the orifice law is regularised smoothly, Q ~ dp / (dp^2 + delta^2)^(1/4), not linearised inside a band;
* the valve's centre leakage acts near the spool's centre (P-I eqs. 13-14: |x_s| < 0.01), blended over a
  narrow band so the integrator meets no step; an overlap does not widen it (the model's did until this plant
  showed it, docs/discrepancy.md);
* a chamber near vapour pressure loses stiffness smoothly (its bulk modulus falls to zero at the vapour
  pressure) instead of being clamped;
* scipy's LSODA integrates the whole run, the operator a continuous proportional law on the joint error.

Its numbers are not the config's either: ``RIG_DEVIATIONS`` is how this machine differs from config/sam.yaml,
within what an identified valve and a handbook fluid leave open.

Effects, in the vocabulary's names: ``valve_deadzone`` as a plain overlap (the opening is |x_s| - d and each
notch's table is read at that shifted opening, the form an outside tester wrote), ``valve_flow_gain``,
``spool_offset`` and the three leaks through an orifice (L/min at 10 MPa).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.integrate import solve_ivp
from scipy.signal import lfilter

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES, Machine
from hydro_ros.contract.samples import Samples
from hydro_ros.sim.excitation import OperatorReference

SEED = 3
# this machine against config/sam.yaml: each notch within P-II's identification error and a valve's day-to-day
# drift (+-3 %), the fluid within a handbook's spread, the seals' friction as a worn cylinder has it
RIG_DEVIATIONS = {"PA": 1.025, "PB": 0.985, "AT": 1.015, "BT": 0.975, "oil_bulk_modulus": 1.12, "hose_bulk_modulus": 0.9,
                  "centre_leakage": 0.8, "static": 1.15, "coulomb": 1.2, "viscous": 1.25}
EFFECTS = ("valve_deadzone", "valve_flow_gain", "spool_offset", "internal_leakage", "external_leakage_a", "external_leakage_b")
NOTCH_TABLE_OPENINGS = np.array([0.02, 0.05, 0.15, 0.3, 0.5, 0.75, 1.0])  # [-] the data sheet's points (held below the first)
ORIFICE_SMOOTHING = 1.0e4  # [Pa] delta of the regularised orifice law: below it the flow turns laminar
CENTRE_BAND = 0.01  # P-I eqs. 13-14: the centre leakage acts for |x_s| below this
CENTRE_BLEND = 0.002  # ... faded in and out over this much spool travel
VAPOUR_KNEE = 2.0e5  # [Pa] below this a chamber's bulk modulus falls linearly to zero at the vapour pressure
VAPOUR_PRESSURE = -9.5e4  # [Pa] gauge
LEAK_DROP = 1.0e7  # [Pa] leaks are quoted in L/min at 10 MPa
# 9 kPa at most from a run 1000x tighter over 10 s of moves (the noise is 100 kPa), 5 s per simulated minute
RTOL, ATOL = 1e-5, [100.0, 100.0, 1e-6, 1e-4, 1e-7, 1e-6, 1e-9]
INTEGRATION_CHUNK_S = 1.0  # the run is integrated a second at a time, so the dense states stay small


@dataclass(frozen=True)
class BoomRig:
    """Every number of the rig, SI, with the effects folded in."""

    area_a: float
    area_b: float
    stroke: float
    dead_volume_a: float
    dead_volume_b: float
    l1: float
    l2: float
    l3: float
    theta_offset: float
    spool_omega: float
    spool_damping: float
    notch_table: dict[str, np.ndarray]  # per notch at NOTCH_TABLE_OPENINGS [m^3/(s Pa^0.5)], flow gain included
    centre_leakage: dict[str, float]  # [m^3/(s Pa)]
    overlap: float  # [-] plain overlap of the spool lands
    spool_offset: float  # [-]
    leaks: dict[str, float]  # orifice coefficients [m^3/(s Pa^0.5)]: "internal", "a", "b"
    oil_modulus: float
    hose_modulus: float
    hose_volume: float
    viscous: float
    static: float
    coulomb: float
    stribeck_velocity: float
    bristle_stiffness: float
    inertia: float  # [kg m^2] about the boom joint
    gravity_moment: float  # [N m] at a horizontal boom
    supply: float
    tank: float
    stop_lower: float
    stop_upper: float
    stop_stiffness: float
    stop_damping: float
    gain: float  # operator's [1/rad]
    max_command: float

    def piston_and_arm(self, joint: float) -> tuple[float, float]:
        """P-I eqs. (3) and (5): the piston position and dx/dtheta at one joint position."""
        theta = joint + self.theta_offset
        length = math.sqrt(self.l1 * self.l1 + self.l2 * self.l2 - 2.0 * self.l1 * self.l2 * math.cos(theta))
        return length - self.l3, self.l1 * self.l2 * math.sin(theta) / length


def rig_numbers(machine: Machine, deviations: dict[str, float] | None = None) -> Machine:
    """``machine`` with this rig's numbers: the config's scaled by ``deviations`` (default RIG_DEVIATIONS)."""
    deviations = RIG_DEVIATIONS if deviations is None else deviations
    actuator = machine.first
    valve, fluid, friction = actuator.valve, actuator.fluid, actuator.friction
    return machine.with_overrides({"actuators": {actuator.name: {
        "valve": {"kv_poly": {n: [c * deviations.get(n, 1.0) for c in valve.kv_poly[n]] for n in NOTCHES},
                  "centre_leakage": {n: valve.centre_leakage[n] * deviations.get("centre_leakage", 1.0) for n in NOTCHES}},
        "fluid": {name: getattr(fluid, name) * deviations.get(name, 1.0) for name in ("oil_bulk_modulus", "hose_bulk_modulus")},
        "friction": {name: getattr(friction, name) * deviations.get(name, 1.0) for name in ("static", "coulomb", "viscous")},
    }}})


def boom_rig(machine: Machine, effects: dict[str, float] | None = None, deviations: dict[str, float] | None = None) -> BoomRig:
    """The rig of ``machine``'s first actuator with ``deviations`` (default RIG_DEVIATIONS) and ``effects``."""
    effects = dict(effects or {})
    unknown = sorted(set(effects) - set(EFFECTS))
    if unknown:
        raise InputError(f"independent plant: cannot simulate {', '.join(unknown)} (it has {', '.join(EFFECTS)})")
    if not 0.0 <= effects.get("valve_deadzone", 0.0) < 1.0:
        raise InputError(f"independent plant: valve_deadzone {effects['valve_deadzone']} outside [0, 1)")
    rig = rig_numbers(machine, deviations)
    actuator = rig.first
    cylinder, mount, valve, fluid, friction, load = (actuator.cylinder, actuator.mount, actuator.valve, actuator.fluid,
                                                     actuator.friction, actuator.load)
    if load is None or mount.kind != "triangle" or mount.sign != 1.0 or valve.mobile:
        raise InputError(f"independent plant: {machine.source} is not a SAM boom (triangle mount, proportional valve, its own load)")
    area_a = math.pi * cylinder.piston_diameter ** 2 / 4.0
    flow_gain = 1.0 + effects.get("valve_flow_gain", 0.0)
    leak = {key: effects.get(name, 0.0) / 60000.0 / math.sqrt(LEAK_DROP)
            for key, name in (("internal", "internal_leakage"), ("a", "external_leakage_a"), ("b", "external_leakage_b"))}
    return BoomRig(
        area_a=area_a, area_b=area_a - math.pi * cylinder.rod_diameter ** 2 / 4.0, stroke=cylinder.stroke,
        dead_volume_a=cylinder.dead_volume_a, dead_volume_b=cylinder.dead_volume_b,
        l1=mount.l1, l2=mount.l2, l3=mount.l3, theta_offset=mount.theta_offset,
        spool_omega=valve.natural_frequency, spool_damping=valve.damping,
        notch_table={n: notch_table(valve.kv_poly[n], 1.0 if n in ("PA", "BT") else -1.0) * flow_gain for n in NOTCHES},
        centre_leakage=dict(valve.centre_leakage),
        overlap=effects.get("valve_deadzone", 0.0), spool_offset=effects.get("spool_offset", 0.0), leaks=leak,
        oil_modulus=fluid.oil_bulk_modulus, hose_modulus=fluid.hose_bulk_modulus, hose_volume=fluid.hose_volume,
        viscous=friction.viscous, static=friction.static, coulomb=friction.coulomb, stribeck_velocity=friction.stribeck_velocity,
        bristle_stiffness=friction.bristle_stiffness,
        inertia=load.boom_mass * (load.boom_length ** 2 / 12.0 + load.boom_cog_distance ** 2)
        + (load.left_mass + load.right_mass) * load.load_distance ** 2,
        gravity_moment=rig.simulation.gravity * ((load.left_mass - load.right_mass) * load.load_distance
                                                 + load.boom_mass * load.boom_cog_distance),
        supply=rig.supply_pressure, tank=rig.tank_pressure,
        stop_lower=rig.simulation.end_stop_lower,
        stop_upper=cylinder.stroke if rig.simulation.end_stop_upper is None else rig.simulation.end_stop_upper,
        stop_stiffness=rig.simulation.end_stop_stiffness, stop_damping=rig.simulation.end_stop_damping,
        gain=rig.excitation.gain, max_command=rig.excitation.max_command,
    )


def _orifice(dp: float) -> float:
    """sqrt(|dp|) sgn(dp), turned laminar below ORIFICE_SMOOTHING without a kink."""
    return dp / (dp * dp + ORIFICE_SMOOTHING * ORIFICE_SMOOTHING) ** 0.25


def notch_table(poly: list[float], side: float) -> np.ndarray:
    """|K_v| of one notch at NOTCH_TABLE_OPENINGS: P-II's polynomials take the signed spool position (PA and BT open
    for x_s > 0, PB and AT for x_s < 0)."""
    return np.abs(np.polyval(np.asarray(poly, dtype=float), side * NOTCH_TABLE_OPENINGS))


def _coefficient(table: np.ndarray, opening: float) -> float:
    return float(np.interp(opening, NOTCH_TABLE_OPENINGS, table))


def valve_flows(rig: BoomRig, spool: float, p_a: float, p_b: float) -> tuple[float, float]:
    """Flows into chambers A and B [m^3/s]: notches past the overlap, centre leakage near the spool's centre."""
    shifted = spool + rig.spool_offset
    opening = min(max(abs(shifted) - rig.overlap, 0.0), 1.0)
    table = rig.notch_table  # each notch's coefficient at the opening it has
    q_a = q_b = 0.0
    if opening > 0.0 and shifted > 0.0:
        q_a = _coefficient(table["PA"], opening) * opening * _orifice(rig.supply - p_a)
        q_b = -_coefficient(table["BT"], opening) * opening * _orifice(p_b - rig.tank)
    elif opening > 0.0:
        q_a = -_coefficient(table["AT"], opening) * opening * _orifice(p_a - rig.tank)
        q_b = _coefficient(table["PB"], opening) * opening * _orifice(rig.supply - p_b)
    near_centre = min(max((CENTRE_BAND + 0.5 * CENTRE_BLEND - abs(shifted)) / CENTRE_BLEND, 0.0), 1.0)
    if near_centre > 0.0:
        leak = rig.centre_leakage
        q_a += near_centre * (leak["PA"] * (rig.supply - p_a) - leak["AT"] * (p_a - rig.tank))
        q_b += near_centre * (leak["PB"] * (rig.supply - p_b) - leak["BT"] * (p_b - rig.tank))
    return q_a, q_b


def _bulk_modulus(rig: BoomRig, pressure: float, volume: float) -> float:
    """P-II eq. (19), softened near vapour pressure."""
    modulus = 1.0 / (1.0 / rig.oil_modulus + rig.hose_volume / (volume * rig.hose_modulus))
    if pressure < VAPOUR_KNEE:
        modulus *= max(pressure - VAPOUR_PRESSURE, 0.0) / (VAPOUR_KNEE - VAPOUR_PRESSURE)
    return modulus


def command(rig: BoomRig, reference: float, joint: float) -> float:
    """The operator's lever: proportional to the joint error, saturated."""
    return min(max(rig.gain * (reference - joint), -rig.max_command), rig.max_command)


def rates(rig: BoomRig, y: np.ndarray, u: float) -> list[float]:
    """d/dt of [p_A, p_B, spool, spool rate, joint, joint rate, bristle deflection] under the command u."""
    p_a, p_b, spool, spool_rate, joint, joint_rate, z = y
    x, arm = rig.piston_and_arm(joint)
    v = arm * joint_rate
    q_a, q_b = valve_flows(rig, spool, p_a, p_b)
    q_internal = rig.leaks["internal"] * _orifice(p_a - p_b)
    volume_a = rig.dead_volume_a + rig.area_a * x
    volume_b = rig.dead_volume_b + rig.area_b * (rig.stroke - x)
    dp_a = _bulk_modulus(rig, p_a, volume_a) / volume_a * (q_a - q_internal - rig.leaks["a"] * _orifice(p_a - rig.tank) - rig.area_a * v)
    dp_b = _bulk_modulus(rig, p_b, volume_b) / volume_b * (q_b + q_internal - rig.leaks["b"] * _orifice(p_b - rig.tank) + rig.area_b * v)
    spool_acceleration = rig.spool_omega ** 2 * (u - spool) - 2.0 * rig.spool_damping * rig.spool_omega * spool_rate
    # LuGre (P-I eq. 17), its bristle damping 2 sqrt(sigma0 m_reduced) with the reduced mass J / r^2
    g = rig.coulomb + (rig.static - rig.coulomb) * math.exp(-(v / rig.stribeck_velocity) ** 2)
    dz = v - rig.bristle_stiffness * abs(v) * z / g
    friction = rig.bristle_stiffness * z + 2.0 * math.sqrt(rig.bristle_stiffness * rig.inertia) / abs(arm) * dz + rig.viscous * v
    stop = 0.0
    if x < rig.stop_lower:
        stop = max(rig.stop_stiffness * (rig.stop_lower - x) - rig.stop_damping * v, 0.0)
    elif x > rig.stop_upper:
        stop = min(rig.stop_stiffness * (rig.stop_upper - x) - rig.stop_damping * v, 0.0)
    force = p_a * rig.area_a - p_b * rig.area_b - friction + stop
    joint_acceleration = (arm * force - rig.gravity_moment * math.cos(joint)) / rig.inertia
    return [dp_a, dp_b, spool_rate, spool_acceleration, joint_rate, joint_acceleration, dz]


def resting_state(rig: BoomRig, joint: float) -> np.ndarray:
    """At rest at ``joint``: p_B where the centre leakage balances, p_A carrying the load, no friction."""
    leak = rig.centre_leakage
    p_b = (leak["PB"] * rig.supply + leak["BT"] * rig.tank) / (leak["PB"] + leak["BT"])
    p_a = (rig.gravity_moment * math.cos(joint) / rig.piston_and_arm(joint)[1] + p_b * rig.area_b) / rig.area_a
    return np.array([p_a, p_b, 0.0, 0.0, joint, 0.0, 0.0])


def simulate(rig: BoomRig, references: np.ndarray, sample_rate: float, start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """States (n, 7) at the sample times 1/rate .. n/rate, and per sample the operator's command at its start (what a
    sampled controller records for it; the lever itself moves continuously)."""
    last = len(references) - 1

    def right_hand_side(t: float, y: np.ndarray) -> list[float]:
        return rates(rig, y, command(rig, references[min(int(t * sample_rate), last)], y[4]))

    times = np.arange(len(references) + 1) / sample_rate
    chunk = int(round(INTEGRATION_CHUNK_S * sample_rate))
    pieces, y = [], start
    for first in range(0, len(references), chunk):
        span = times[first:min(first + chunk, len(references)) + 1]
        solution = solve_ivp(right_hand_side, (span[0], span[-1]), y, method="LSODA", t_eval=span, rtol=RTOL,
                             atol=ATOL, max_step=2.0 / sample_rate)
        if not solution.success:
            raise InputError(f"independent plant: integration failed at t = {span[0]:.3f} s ({solution.message})")
        pieces.append(solution.y.T[1:])
        y = pieces[-1][-1]
    states = np.vstack(pieces)
    joints = np.concatenate([[start[4]], states[:-1, 4]])
    return states, np.array([command(rig, reference, joint) for reference, joint in zip(references, joints)])


def measure(machine: Machine, rig: BoomRig, times: np.ndarray, states: np.ndarray, commands: np.ndarray,
            rng: np.random.Generator) -> Samples:
    """The rig's sensors: noisy pressure transmitters within their range, a quantising encoder, its angle differenced and
    low-passed (first order at the config's cut-off) into the joint rate."""
    sensors = machine.sensors
    rate = machine.sample_rate_hz
    angle = np.round(states[:, 4] / sensors.encoder_resolution) * sensors.encoder_resolution
    difference = np.diff(angle, prepend=angle[0]) * rate
    alpha = 1.0 / (1.0 + rate / (2.0 * math.pi * sensors.velocity_filter_hz))
    velocity = lfilter([alpha], [1.0, alpha - 1.0], difference)

    def transmitter(pressure: np.ndarray) -> np.ndarray:
        return np.clip(pressure + rng.normal(0.0, sensors.pressure_noise_std, len(pressure)), *sensors.pressure_range)

    return Samples(times=times, joint_position=angle, joint_velocity=velocity, pressure_a=transmitter(states[:, 0]),
                   pressure_b=transmitter(states[:, 1]), supply_pressure=transmitter(np.full(len(times), rig.supply)),
                   valve_command=commands)


def independent_plant_bag(machine: Machine, path: Path, effects: dict[str, float] | None = None, duration: float = 60.0,
                          seed: int = SEED, deviations: dict[str, float] | None = None) -> Path:
    """A contract bag of this rig with ``effects`` under the simulated operator (the package's, drawn for ``seed``)."""
    rig = boom_rig(machine, effects, deviations)
    rate = machine.sample_rate_hz
    rng = np.random.default_rng(seed)
    joint = machine.simulation.initial_joint_position
    references = OperatorReference(machine.excitation, rng, joint, rate).next(int(round(duration * rate)))
    states, commands = simulate(rig, references, rate, resting_state(rig, joint))
    samples = measure(machine, rig, np.arange(1, len(references) + 1) / rate, states, commands, rng)
    actuator = machine.first
    with ContractBagWriter(path, actuators={actuator.name: actuator.joint}, pressure_variance=machine.sensors.pressure_noise_std ** 2) as writer:
        writer.write_block(actuator.name, samples)
    return path



def nearest_model(machine: Machine, effects: dict[str, float] | None = None, deviations: dict[str, float] | None = None) -> Machine:
    """The model config closest to this rig: its numbers and its effects in the model's forms (a plain overlap, orifice
    leaks). What is left between the two is the forms each chose; its gap on the rig's data is a floor for a fitted model."""
    effects = dict(effects or {})
    return rig_numbers(machine, deviations).with_overrides(
        {"effects": effects, "effect_forms": {"valve_deadzone": "overlap"} if "valve_deadzone" in effects else {}})
