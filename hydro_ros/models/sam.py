"""The 7-state SAM plant model of P-I eqs. (18)-(19), with P-II's flow polynomials and bulk modulus.

State y = [p_A, p_B, x_s, x_s', x, x', z] (chamber pressures [Pa], normalised spool position and
rate, piston position [m] and velocity [m/s], LuGre bristle deflection [m]).

Deviations from the printed equations, each for a stated reason:
* corrections of typos in the printed equations: the spool eq. uses K*omega_n^2 as eq. (15) does
  (eqs. (19), (22) print K*omega_n), the B-chamber volume uses A_B (eq. (22) prints A_A), the s < 0
  opening is -(x_s + offset) (eqs. (10)-(11) print -x_s + offset), and centre leakage is laminar in
  m^3/(s Pa) (eqs. (13)-(14) and App. 2 print the unit m^3/(s Pa^0.5) for a linear law);
* the boom is integrated through the full eq. (7), x'' = (F - F_ext)/m_red + r' v^2 / r^2,
  rather than eq. (19)'s x'' = (F - F_ext)/m_red, so the rigid-body energy is consistent;
* gravity torques tau = g cos(joint) (m L) are INFERRED (P-I eqs. (16), (21) name the torques but give no
  expressions), with the boom's centre of gravity at `boom_cog_distance` and its parallel-axis inertia included;
* end stops are stiff penalty springs and pressures are floored at a cavitation pressure.

Integration: classic fixed-step RK4 with `simulation.substeps` steps per sensor sample (0.1 ms
at 1 kHz). Near zero pressure drop the orifice law is linearised inside `laminar_band`, which
bounds the stiffest eigenvalue at ~5e3 1/s (RK4 limit ~0.6 ms); test_sam_model.py shows that
halving the step changes pressures by < 1 kPa and position by < 1 um over a 10 s manoeuvre.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
from numba import njit, prange

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES, Machine
from hydro_ros.contract.names import Effect, Fault, Injection
from hydro_ros.contract.schema import Load
from hydro_ros.models.chamber import effective_bulk_modulus, leak_coefficient, leak_flow
from hydro_ros.models.friction import bristle_rate, friction_force, stribeck_curve
from hydro_ros.models.kinematics import (
    MOUNT_KINDS,
    mount_arm,
    mount_joint,
    mount_piston,
    torque_arm,
    torque_arm_derivative,
    triangle_angle,
)
from hydro_ros.models.serial_arm import machine_load
from hydro_ros.models.valve import (
    PILOT_TANK_SIGMAS,
    chamber_valve_flows,
    compensator_pressure,
    spool_acceleration,
    spool_opening,
)

STATE_NAMES = ("p_a", "p_b", "spool", "spool_rate", "piston", "piston_velocity", "bristle")
N_STATES = len(STATE_NAMES)
DELAY_BUFFER = 4096  # samples of valve-command history kept for the valve_delay effect

class Param(IntEnum):
    """The layout of a cylinder's parameter vector (``SamModel.base``, one row per actuator in the arm's models).

    numba reads the members as compile-time constants, so ``p[Param.AREA_A]`` costs what a literal index does."""

    AREA_A = 0
    AREA_B = 1
    STROKE = 2
    V0_A = 3
    V0_B = 4
    MOUNT_L1 = 5
    MOUNT_L2 = 6
    MOUNT_L3 = 7
    THETA_OFFSET = 8
    SPOOL_OMEGA = 9
    SPOOL_DAMPING = 10
    LAMINAR_BAND = 11
    OIL_MODULUS = 12
    HOSE_MODULUS = 13
    HOSE_VOLUME = 14
    AIR_FRACTION = 15
    VISCOUS = 16
    STATIC = 17
    COULOMB = 18
    STRIBECK = 19
    BRISTLE = 20
    BOOM_MASS = 21
    BOOM_LENGTH = 22
    BOOM_COG = 23
    LEFT_MASS = 24
    RIGHT_MASS = 25
    LOAD_DISTANCE = 26
    PAYLOAD = 27
    SUPPLY = 28
    TANK = 29
    K_INTERNAL = 30
    K_EXTERNAL_A = 31
    K_EXTERNAL_B = 32
    OFFSET = 33
    OPENING_GAIN = 34
    FLOW_GAIN = 35
    STUCK = 36
    DEADZONE = 37
    DELAY_SAMPLES = 38
    STOP_LOWER = 39
    STOP_UPPER = 40
    STOP_STIFFNESS = 41
    STOP_DAMPING = 42
    CAVITATION = 43
    GRAVITY = 44
    VALVE_MOBILE = 45
    COMP_DROP = 46
    COMP_LOCKED = 47
    PILOT_MAX = 48
    DEADZONE_PLAIN = 49
    LAMINAR_INTERNAL = 50
    LAMINAR_EXTERNAL_A = 51
    LAMINAR_EXTERNAL_B = 52
    LAG_SAMPLES = 53
    MOUNT_KIND = 54
    MOUNT_SIGN = 55
    MOUNT_RATIO = 56
    VALVE_OVERLAP = 57


N_PARAMS = len(Param)


@njit(cache=True)
def chamber_volumes(p: np.ndarray, piston: Any) -> tuple[Any, Any]:
    """The two chambers' oil volumes at piston position ``piston`` (a number or an array), P-I eqs. (8)-(9) (B's with A_B)."""
    return p[Param.V0_A] + p[Param.AREA_A] * piston, p[Param.V0_B] + p[Param.AREA_B] * (p[Param.STROKE] - piston)


@njit(cache=True)
def chambers(p: np.ndarray, piston: float, p_a: float, p_b: float, air_fraction: float) -> tuple[float, float, float, float]:
    """The continuity equations' coefficients, one kernel for the plant, the UKF, the parity equations and the steady
    state: each chamber's volume and effective bulk modulus (P-II eq. 19; ``air_fraction``: entrained free air, an
    effect the plant may carry and the monitor's model has not, 0 there)."""
    volume_a, volume_b = chamber_volumes(p, piston)
    return (volume_a, volume_b,
            effective_bulk_modulus(p_a, volume_a, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], air_fraction),
            effective_bulk_modulus(p_b, volume_b, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], air_fraction))


@njit(cache=True)
def metering_supply(s: float, p_a: float, p_b: float, p: np.ndarray) -> float:
    """Pressure feeding the metering notches: supply, or the compensator's for a mobile valve."""
    if p[Param.VALVE_MOBILE] > 0.5:
        return compensator_pressure(s, p_a, p_b, p[Param.SUPPLY], p[Param.COMP_DROP], p[Param.COMP_LOCKED] > 0.5)
    return p[Param.SUPPLY]


@njit(cache=True)
def valve_openings(spool: float, p: np.ndarray) -> tuple[float, float]:
    """The opening the notches see (every overlap, the offset, spool faults) and the one the valve's own lands leave
    (its configured overlap only), where its centre leakage is decided (valve.chamber_valve_flows)."""
    stuck = p[Param.STUCK] > 0.5
    return (spool_opening(spool, p[Param.OFFSET], p[Param.DEADZONE], p[Param.OPENING_GAIN], stuck, p[Param.DEADZONE_PLAIN] < 0.5),
            spool_opening(spool, p[Param.OFFSET], p[Param.VALVE_OVERLAP], p[Param.OPENING_GAIN], stuck))


@njit(cache=True)
def hydraulic_rates(y: np.ndarray, reference: float, p: np.ndarray, poly: np.ndarray, centre: np.ndarray, dy: np.ndarray) -> None:
    """dy[0:4]: the chambers' pressure rates and the spool's, for the piston motion y[4], y[5] whatever moves it."""
    p_a = y[0]
    p_b = y[1]
    x = y[4]
    v = y[5]
    # valve (eqs. 10-15)
    s, neutral = valve_openings(y[2], p)
    q_a, q_b = chamber_valve_flows(s, neutral, p_a, p_b, metering_supply(s, p_a, p_b, p), p[Param.TANK], poly, centre, p[Param.LAMINAR_BAND],
                                   p[Param.FLOW_GAIN])
    # cylinder leakages (eqs. 41-43)
    band = p[Param.LAMINAR_BAND]
    q_int = leak_flow(p[Param.K_INTERNAL], p_a - p_b, band, p[Param.LAMINAR_INTERNAL] > 0.5)
    q_ext_a = leak_flow(p[Param.K_EXTERNAL_A], p_a - p[Param.TANK], band, p[Param.LAMINAR_EXTERNAL_A] > 0.5)
    q_ext_b = leak_flow(p[Param.K_EXTERNAL_B], p_b - p[Param.TANK], band, p[Param.LAMINAR_EXTERNAL_B] > 0.5)
    # chambers (eqs. 8-9 with P-II eq. 19)
    volume_a, volume_b, bulk_a, bulk_b = chambers(p, x, p_a, p_b, p[Param.AIR_FRACTION])
    dy[0] = bulk_a / volume_a * (q_a - q_int - q_ext_a - p[Param.AREA_A] * v)
    dy[1] = bulk_b / volume_b * (q_b + q_int - q_ext_b + p[Param.AREA_B] * v)
    # spool (eq. 15)
    dy[2] = y[3]
    dy[3] = spool_acceleration(y[2], y[3], reference, p[Param.SPOOL_OMEGA], p[Param.SPOOL_DAMPING])


@njit(cache=True)
def end_stop_force(x: float, v: float, p: np.ndarray) -> float:
    """Penalty force of the end stops on the piston [N]."""
    if x < p[Param.STOP_LOWER]:
        return max(p[Param.STOP_STIFFNESS] * (p[Param.STOP_LOWER] - x) - p[Param.STOP_DAMPING] * v, 0.0)
    if x > p[Param.STOP_UPPER]:
        return min(p[Param.STOP_STIFFNESS] * (p[Param.STOP_UPPER] - x) - p[Param.STOP_DAMPING] * v, 0.0)
    return 0.0


@njit(cache=True)
def _rhs(y: np.ndarray, reference: float, p: np.ndarray, poly: np.ndarray, centre: np.ndarray, dy: np.ndarray) -> None:
    hydraulic_rates(y, reference, p, poly, centre, dy)
    p_a = y[0]
    p_b = y[1]
    x = y[4]
    v = y[5]
    z = y[6]
    # boom (eqs. 7, 16, 20, 21)
    theta = triangle_angle(x, p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3])
    arm = torque_arm(theta, p[Param.MOUNT_L1], p[Param.MOUNT_L2])
    arm_rate = torque_arm_derivative(theta, p[Param.MOUNT_L1], p[Param.MOUNT_L2])
    left = p[Param.LEFT_MASS] + p[Param.PAYLOAD]
    inertia = (
        p[Param.BOOM_MASS] * (p[Param.BOOM_LENGTH] ** 2 / 12.0 + p[Param.BOOM_COG] ** 2)
        + (left + p[Param.RIGHT_MASS]) * p[Param.LOAD_DISTANCE] ** 2
    )
    gravity_torque = p[Param.GRAVITY] * math.cos(theta - p[Param.THETA_OFFSET]) * (
        (left - p[Param.RIGHT_MASS]) * p[Param.LOAD_DISTANCE] + p[Param.BOOM_MASS] * p[Param.BOOM_COG]
    )
    reduced_mass = inertia / (arm * arm)
    g = stribeck_curve(v, p[Param.COULOMB], p[Param.STATIC], p[Param.STRIBECK])
    z_rate = bristle_rate(v, z, p[Param.BRISTLE], g)
    bristle_damping = 2.0 * math.sqrt(p[Param.BRISTLE] * reduced_mass)
    friction = friction_force(v, z, z_rate, p[Param.BRISTLE], bristle_damping, p[Param.VISCOUS])
    force = p_a * p[Param.AREA_A] - p_b * p[Param.AREA_B] - friction + end_stop_force(x, v, p)
    dy[4] = v
    dy[5] = (force - gravity_torque / arm) / reduced_mass + arm_rate * v * v / (arm * arm)
    dy[6] = z_rate


@njit(cache=True)
def _rk4(y: np.ndarray, reference: float, p: np.ndarray, poly: np.ndarray, centre: np.ndarray, h: float, work: np.ndarray) -> None:
    k1 = work[0]
    k2 = work[1]
    k3 = work[2]
    k4 = work[3]
    tmp = work[4]
    _rhs(y, reference, p, poly, centre, k1)
    for i in range(N_STATES):
        tmp[i] = y[i] + 0.5 * h * k1[i]
    _rhs(tmp, reference, p, poly, centre, k2)
    for i in range(N_STATES):
        tmp[i] = y[i] + 0.5 * h * k2[i]
    _rhs(tmp, reference, p, poly, centre, k3)
    for i in range(N_STATES):
        tmp[i] = y[i] + h * k3[i]
    _rhs(tmp, reference, p, poly, centre, k4)
    for i in range(N_STATES):
        y[i] += h / 6.0 * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i])
    floor = p[Param.CAVITATION]
    if y[0] < floor:
        y[0] = floor
    if y[1] < floor:
        y[1] = floor


@njit(cache=True)
def _integrate_samples(
    y: np.ndarray,
    params: np.ndarray,
    poly: np.ndarray,
    centre: np.ndarray,
    commands: np.ndarray,
    references: np.ndarray,
    closed_loop: bool,
    gain: float,
    max_command: float,
    delay_buffer: np.ndarray,
    delay_position: int,
    lag_state: np.ndarray,
    sample_time: float,
    substeps: int,
    states_out: np.ndarray,
    commands_out: np.ndarray,
) -> int:
    work = np.empty((5, N_STATES))
    h = sample_time / substeps
    size = delay_buffer.shape[0]
    for k in range(params.shape[0]):
        p = params[k]
        if closed_loop:
            theta = triangle_angle(y[4], p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3])
            u = gain * (references[k] - (theta - p[Param.THETA_OFFSET]))
        else:
            u = commands[k]
        u = min(max(u, -max_command), max_command)
        commands_out[k] = u
        delay_buffer[delay_position % size] = u
        applied = delay_buffer[(delay_position - int(p[Param.DELAY_SAMPLES])) % size]
        delay_position += 1
        if p[Param.LAG_SAMPLES] > 0.0:
            lag_state[0] += (applied - lag_state[0]) * (1.0 - math.exp(-1.0 / p[Param.LAG_SAMPLES]))
            applied = lag_state[0]
        else:
            lag_state[0] = applied  # a lag switched on later starts from the command
        for _ in range(substeps):
            _rk4(y, applied, p, poly, centre, h, work)
        states_out[k] = y
    return delay_position


@njit(parallel=True, cache=True)
def _integrate_segments(
    starts: np.ndarray,
    params: np.ndarray,
    poly: np.ndarray,
    centre: np.ndarray,
    commands: np.ndarray,
    firsts: np.ndarray,
    ends: np.ndarray,
    histories: np.ndarray,
    lags: np.ndarray,
    sample_time: float,
    substeps: int,
    states_out: np.ndarray,
) -> None:
    for segment in prange(starts.shape[0]):
        first, end = firsts[segment], ends[segment]
        y = starts[segment].copy()
        applied = np.empty(end - first)
        _integrate_samples(
            # max_command 1.0: the command range, as SamPlant's
            y, params[first:end], poly, centre, commands[first:end], commands[first:end], False, 0.0, 1.0,
            histories[segment].copy(), 0, lags[segment:segment + 1].copy(), sample_time, substeps, states_out[first:end], applied,
        )
        if not np.all(np.isfinite(states_out[first:end])):
            states_out[first:end] = np.nan  # a diverged segment, not a crash


@njit(cache=True)
def valve_and_leak_flows(states: np.ndarray, params: np.ndarray, poly: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Per-sample flows [Q_A, Q_B, Q_int, Q_extA, Q_extB] (m^3/s) of recorded states."""
    out = np.empty((states.shape[0], 5))
    for k in range(states.shape[0]):
        y = states[k]
        p = params[k]
        s, neutral = valve_openings(y[2], p)
        q_a, q_b = chamber_valve_flows(s, neutral, y[0], y[1], metering_supply(s, y[0], y[1], p), p[Param.TANK], poly, centre,
                                       p[Param.LAMINAR_BAND], p[Param.FLOW_GAIN])
        out[k, 0] = q_a
        out[k, 1] = q_b
        out[k, 2] = leak_flow(p[Param.K_INTERNAL], y[0] - y[1], p[Param.LAMINAR_BAND], p[Param.LAMINAR_INTERNAL] > 0.5)
        out[k, 3] = leak_flow(p[Param.K_EXTERNAL_A], y[0] - p[Param.TANK], p[Param.LAMINAR_BAND], p[Param.LAMINAR_EXTERNAL_A] > 0.5)
        out[k, 4] = leak_flow(p[Param.K_EXTERNAL_B], y[1] - p[Param.TANK], p[Param.LAMINAR_BAND], p[Param.LAMINAR_EXTERNAL_B] > 0.5)
    return out


@njit(cache=True)
def compensator_pressures(states: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Per-sample pressure upstream of the main spool (the compensator_pressure topic)."""
    out = np.empty(states.shape[0])
    for k in range(states.shape[0]):
        y = states[k]
        p = params[k]
        out[k] = metering_supply(valve_openings(y[2], p)[0], y[0], y[1], p)
    return out


# How an injection's level acts on the parameter slots: added (times a unit), a fractional growth or loss, a latch that
# switches on at 0.5, or seconds turned into samples (whole ones for a transport delay)
ADD, GROW, SHRINK, LATCH, DELAY_SAMPLES_OF, LAG_SAMPLES_OF = range(6)
LITRE_AT_10_MPA = leak_coefficient(1.0)
INJECTION_SLOTS: dict[str, tuple[tuple[int, int, float], ...]] = {
    Fault.EXTERNAL_LEAKAGE_A: ((Param.K_EXTERNAL_A, ADD, LITRE_AT_10_MPA),),
    Fault.EXTERNAL_LEAKAGE_B: ((Param.K_EXTERNAL_B, ADD, LITRE_AT_10_MPA),),
    Fault.EXTERNAL_LEAKAGE_AB: ((Param.K_EXTERNAL_A, ADD, LITRE_AT_10_MPA), (Param.K_EXTERNAL_B, ADD, LITRE_AT_10_MPA)),
    Fault.INTERNAL_LEAKAGE: ((Param.K_INTERNAL, ADD, LITRE_AT_10_MPA),),
    Fault.SPOOL_TOO_SMALL_OPENING: ((Param.OPENING_GAIN, SHRINK, 1.0),),
    Fault.SPOOL_TOO_LARGE_OPENING: ((Param.OPENING_GAIN, GROW, 1.0),),
    Fault.SPOOL_STUCK_CLOSED: ((Param.STUCK, LATCH, 1.0),),
    Effect.SPOOL_OFFSET: ((Param.OFFSET, ADD, 1.0),),
    Fault.PILOT_PRESSURE_SPOOL_OFFSET: ((Param.OFFSET, ADD, 1.0),),
    Fault.MAIN_SPOOL_LOCKING: ((Param.STUCK, LATCH, 1.0),),
    Fault.MAIN_SPOOL_EROSION: ((Param.FLOW_GAIN, GROW, 1.0),),
    Fault.COMPENSATOR_SPOOL_LOCKING: ((Param.COMP_LOCKED, LATCH, 1.0),),
    Fault.COMPENSATOR_SPOOL_EROSION: ((Param.COMP_DROP, SHRINK, 1.0),),
    Effect.VALVE_DEADZONE: ((Param.DEADZONE, ADD, 1.0),),
    Effect.VALVE_DELAY: ((Param.DELAY_SAMPLES, DELAY_SAMPLES_OF, 1.0),),
    Effect.VALVE_FLOW_GAIN: ((Param.FLOW_GAIN, GROW, 1.0),),
    Effect.ENTRAINED_AIR: ((Param.AIR_FRACTION, ADD, 1.0),),
    Effect.COULOMB_FRICTION: ((Param.STATIC, ADD, 1.0), (Param.COULOMB, ADD, 1.0)),
    Effect.VISCOUS_FRICTION: ((Param.VISCOUS, ADD, 1.0),),
    Effect.PAYLOAD_MASS: ((Param.PAYLOAD, ADD, 1.0),),
}
# an effect in a form other than its family's first acts on other slots (names.EFFECT_FORMS)
FORM_SLOTS: dict[tuple[str, str], tuple[tuple[int, int, float], ...]] = {
    (Effect.VALVE_DELAY, "lag"): ((Param.LAG_SAMPLES, LAG_SAMPLES_OF, 1.0),),
    (Effect.COULOMB_FRICTION, "stribeck"): ((Param.STATIC, ADD, 1.0),),  # the static level only: the Stribeck curve falls from it
}
# the form switches: the slot that says which form an effect family has
FORM_SWITCHES = {Effect.EXTERNAL_LEAKAGE_A: (Param.LAMINAR_EXTERNAL_A, "laminar"), Effect.EXTERNAL_LEAKAGE_B: (Param.LAMINAR_EXTERNAL_B, "laminar"),
                 Effect.INTERNAL_LEAKAGE: (Param.LAMINAR_INTERNAL, "laminar"), Effect.VALVE_DEADZONE: (Param.DEADZONE_PLAIN, "overlap")}


def _apply(params: np.ndarray, name: str, level: np.ndarray, sample_rate: float, form: str | None = None) -> None:
    """Add one injection's level (per row of ``params``) to the parameter matrix, in ``form``
    (``names.EFFECT_FORMS``; None: the form the parameters have, which is the family's first unless an
    effect of the config chose another: a fault injected on top of such an effect keeps its form)."""
    if form is not None and name in FORM_SWITCHES:
        slot, switched = FORM_SWITCHES[name]
        params[:, slot] = float(form == switched)
    for slot, action, unit in FORM_SLOTS.get((name, form), INJECTION_SLOTS.get(name, ())):
        if action == ADD:
            params[:, slot] += unit * level
        elif action == GROW:
            params[:, slot] *= 1.0 + level
        elif action == SHRINK:
            params[:, slot] *= 1.0 - level
        elif action == LATCH:
            params[:, slot] = np.maximum(params[:, slot], (level >= 0.5).astype(float))
        elif action == DELAY_SAMPLES_OF:
            params[:, slot] += np.round(level * sample_rate)
        else:
            params[:, slot] += level * sample_rate


SENSOR_INJECTIONS = frozenset(
    {"pressure_sensor_bias_a", "pressure_sensor_bias_b", "supply_pressure_sensor_bias", "velocity_sensor_bias",
     "pilot_pressure_sensor_bias", "compensator_pressure_sensor_bias"}
)


class SimulationDiverged(InputError, FloatingPointError):
    """The model left its physical range: a config, fault or effect value outside what it can simulate."""


@dataclass
class SamModel:
    """Parameters of one actuator of a SAM-type machine (docs/interface.md section 3) as the model's vector."""

    machine: Machine
    actuator: str | None = None  # None: the machine's first actuator
    base: np.ndarray = field(init=False)
    poly: np.ndarray = field(init=False)
    centre_leakage: np.ndarray = field(init=False)
    sample_rate: float = field(init=False)
    effects: dict[str, float] = field(init=False)
    substeps: int = field(init=False)
    joint_name: str = field(init=False)
    boom_refusal: str = field(init=False)  # why the boom's dynamics cannot move this cylinder alone, "" if they can

    def __post_init__(self) -> None:
        machine = self.machine
        act = machine.first if self.actuator is None else machine.actuator(self.actuator)
        self.actuator = act.name
        self.joint_name = act.joint
        cyl, mount, valve = act.cylinder, act.mount, act.valve
        fluid, fric = act.fluid, act.friction
        try:
            load = machine_load(machine, act.name)
            self.boom_refusal = ""
        except ValueError as exc:  # the monitor needs no load; only the boom's dynamics refuse (require_boom)
            load, self.boom_refusal = Load(*[math.nan] * 6), str(exc)
        sim = machine.simulation
        p = np.zeros(N_PARAMS)
        area_a = math.pi * cyl.piston_diameter ** 2 / 4.0
        p[Param.AREA_A] = area_a
        p[Param.AREA_B] = area_a - math.pi * cyl.rod_diameter ** 2 / 4.0
        p[Param.STROKE] = cyl.stroke
        p[Param.V0_A] = cyl.dead_volume_a
        p[Param.V0_B] = cyl.dead_volume_b
        p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3] = mount.l1, mount.l2, mount.l3
        p[Param.THETA_OFFSET] = mount.theta_offset
        p[Param.MOUNT_KIND], p[Param.MOUNT_SIGN], p[Param.MOUNT_RATIO] = MOUNT_KINDS.index(mount.kind), mount.sign, mount.ratio
        p[Param.SPOOL_OMEGA] = valve.natural_frequency
        p[Param.SPOOL_DAMPING] = valve.damping
        p[Param.LAMINAR_BAND] = valve.laminar_band
        p[Param.OIL_MODULUS] = fluid.oil_bulk_modulus
        p[Param.HOSE_MODULUS] = fluid.hose_bulk_modulus
        p[Param.HOSE_VOLUME] = fluid.hose_volume
        p[Param.VISCOUS] = fric.viscous
        p[Param.STATIC] = fric.static
        p[Param.COULOMB] = fric.coulomb
        p[Param.STRIBECK] = fric.stribeck_velocity
        p[Param.BRISTLE] = fric.bristle_stiffness
        p[Param.BOOM_MASS] = load.boom_mass
        p[Param.BOOM_LENGTH] = load.boom_length
        p[Param.BOOM_COG] = load.boom_cog_distance
        p[Param.LEFT_MASS] = load.left_mass
        p[Param.RIGHT_MASS] = load.right_mass
        p[Param.LOAD_DISTANCE] = load.load_distance
        p[Param.SUPPLY] = machine.supply_pressure
        p[Param.TANK] = machine.tank_pressure
        p[Param.OPENING_GAIN] = 1.0
        p[Param.FLOW_GAIN] = 1.0
        p[Param.STOP_LOWER] = sim.end_stop_lower
        p[Param.STOP_UPPER] = cyl.stroke if sim.end_stop_upper is None else min(sim.end_stop_upper, cyl.stroke)
        p[Param.STOP_STIFFNESS] = sim.end_stop_stiffness
        p[Param.STOP_DAMPING] = sim.end_stop_damping
        p[Param.CAVITATION] = sim.cavitation_pressure
        p[Param.GRAVITY] = sim.gravity
        if valve.mobile:
            p[Param.VALVE_MOBILE] = 1.0
            p[Param.COMP_DROP] = valve.compensator_pressure_drop
            p[Param.PILOT_MAX] = valve.pilot_pressure_max
            p[Param.DEADZONE] = valve.deadzone
            p[Param.VALVE_OVERLAP] = valve.deadzone
        self.sample_rate = machine.sample_rate_hz
        # `effects:` of a config (written by hydro-ros discrepancy) are part of the model from t = 0;
        # sensor biases among them belong to the sensors, not to the plant
        self.effects = dict(machine.effects)
        for name, value in self.effects.items():
            Injection(name, value)  # validates the name
            if name not in SENSOR_INJECTIONS:
                _apply(p.reshape(1, -1), name, np.array([value]), self.sample_rate, machine.effect_forms.get(name))
        self.base = p
        self.poly = np.array([valve.kv_poly[notch] for notch in NOTCHES], dtype=float)
        self.centre_leakage = np.array([valve.centre_leakage[notch] for notch in NOTCHES], dtype=float)
        self.substeps = sim.substeps

    def require_boom(self) -> None:
        """Refuse a cylinder this model's boom dynamics (P-I eqs. 20-21: a triangle that opens with its joint) do not move."""
        if self.boom_refusal:
            raise InputError(f"config {self.machine.source}: actuator {self.actuator}: {self.boom_refusal}")
        if self.base[Param.MOUNT_KIND] != MOUNT_KINDS.index("triangle") or self.base[Param.MOUNT_SIGN] != 1.0:
            raise InputError(f"config {self.machine.source}: actuator {self.actuator}'s mount is not a triangle opening with its joint: "
                             "the one-cylinder boom model does not move it (its arm's simulator does: hydro_ros.sim.arm_cylinders)")

    @property
    def mobile_valve(self) -> bool:
        return bool(self.base[Param.VALVE_MOBILE] > 0.5)

    @property
    def pilot_tank_band(self) -> float:
        """[Pa] pilot readings below this are the tank's (``valve.pilot_drive``): 3 sigma of the pilot transmitters' noise."""
        return PILOT_TANK_SIGMAS * (self.machine.sensors.pilot_pressure_noise_std or 0.0)

    def parameter_matrix(self, times: np.ndarray, injections: Sequence[Injection] = ()) -> np.ndarray:
        """Parameter vector per sample time, with every plant-side injection applied."""
        params = np.repeat(self.base[None, :], len(times), axis=0)
        for injection in injections:
            if injection.name in SENSOR_INJECTIONS:
                continue
            level = injection_levels(injection, times)
            _apply(params, injection.name, level, self.sample_rate)
        if np.any(params[:, Param.DELAY_SAMPLES] >= DELAY_BUFFER):
            raise InputError(f"valve_delay exceeds {DELAY_BUFFER / self.sample_rate:.2f} s")
        if np.any(params[:, Param.DEADZONE] >= 1.0):
            raise InputError("valve_deadzone must be < 1 (fraction of spool travel)")
        return params

    @property
    def mount(self) -> tuple[float, ...]:
        """The mount's parameters in the order of kinematics.mount_piston / mount_arm / mount_joint."""
        p = self.base
        return (int(p[Param.MOUNT_KIND]), p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3], p[Param.THETA_OFFSET], p[Param.MOUNT_SIGN],
                p[Param.MOUNT_RATIO])

    @property
    def end_stops(self) -> tuple[float, float]:
        """[m] the piston positions of the retracted and extended end stops."""
        return float(self.base[Param.STOP_LOWER]), float(self.base[Param.STOP_UPPER])

    def joint_from_piston(self, x: np.ndarray | float) -> np.ndarray:
        return np.array([mount_joint(v, *self.mount) for v in np.atleast_1d(np.asarray(x, dtype=float))])

    def piston_from_joint(self, joint: np.ndarray | float) -> np.ndarray | float:
        return mount_piston(joint, *self.mount)

    def piston_velocity(self, joint: np.ndarray | float, joint_velocity: np.ndarray | float) -> np.ndarray | float:
        """Eq. (4): the piston's velocity at a joint position and rate."""
        return mount_arm(joint, *self.mount) * joint_velocity

    def torque_arm_at(self, x: float) -> float:
        """dx/d(joint) at piston position x."""
        return float(mount_arm(mount_joint(x, *self.mount), *self.mount))

    def inertia(self, payload: float = 0.0) -> float:
        p = self.base
        return (
            p[Param.BOOM_MASS] * (p[Param.BOOM_LENGTH] ** 2 / 12.0 + p[Param.BOOM_COG] ** 2)
            + (p[Param.LEFT_MASS] + payload + p[Param.RIGHT_MASS]) * p[Param.LOAD_DISTANCE] ** 2
        )

    def load_force(self, x: float, payload: float = 0.0) -> float:
        """F_ext of eq. (21): the gravity load on the piston [N] at piston position x."""
        p = self.base
        theta = triangle_angle(x, p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3])
        torque = p[Param.GRAVITY] * math.cos(theta - p[Param.THETA_OFFSET]) * (
            (p[Param.LEFT_MASS] + payload - p[Param.RIGHT_MASS]) * p[Param.LOAD_DISTANCE] + p[Param.BOOM_MASS] * p[Param.BOOM_COG]
        )
        return torque / torque_arm(theta, p[Param.MOUNT_L1], p[Param.MOUNT_L2])

    def bristle_state(self, x: float, v: float, p_a: float, p_b: float) -> float:
        """LuGre bristle deflection z that carries the force the pressures leave over after the load and
        viscous friction (no acceleration), within its range |sigma0 z| <= g(v).

        z is never measured: a simulation started from measured data with z = 0 drops the friction
        that holds a boom at rest and sends a pressure transient through every start.
        """
        p = self.base
        force = p_a * p[Param.AREA_A] - p_b * p[Param.AREA_B] - self.load_force(x, p[Param.PAYLOAD]) - p[Param.VISCOUS] * v
        g = stribeck_curve(v, p[Param.COULOMB], p[Param.STATIC], p[Param.STRIBECK])
        return min(max(force, -g), g) / p[Param.BRISTLE]

    def resting_state(self, joint: float, p_b: float | None = None) -> np.ndarray:
        """State at rest at ``joint`` with chamber pressures balancing the load.

        p_B defaults to the centre-leakage equilibrium of the closed valve (eq. 14 = 0), or to
        10 % of supply when the valve has no centre leakage.
        """
        p = self.base
        x = self.piston_from_joint(joint)
        if p_b is None:
            cl = self.centre_leakage
            p_b = (cl[1] * p[Param.SUPPLY] + cl[3] * p[Param.TANK]) / (cl[1] + cl[3]) if cl[1] + cl[3] > 0.0 else 0.1 * p[Param.SUPPLY]
        p_a = (self.load_force(x) + p_b * p[Param.AREA_B]) / p[Param.AREA_A]
        return np.array([p_a, p_b, 0.0, 0.0, x, 0.0, 0.0])


def lagged_command(params: np.ndarray, history: np.ndarray) -> float:
    """Where a valve_delay lag has brought the command after ``history`` (oldest first) passed the transport delay."""
    arrived = history[:len(history) - int(params[Param.DELAY_SAMPLES])]
    if not len(arrived):
        return 0.0
    if params[Param.LAG_SAMPLES] <= 0.0:
        return float(arrived[-1])
    from scipy.signal import lfilter  # here, not at the top: scipy.signal costs every node that loads the model 0.7 s at start

    keep = math.exp(-1.0 / params[Param.LAG_SAMPLES])
    return float(lfilter([1.0 - keep], [1.0, -keep], arrived, zi=[keep * arrived[0]])[0][-1])


def simulate_segments(
    model: SamModel, starts: np.ndarray, commands: np.ndarray, firsts: np.ndarray, ends: np.ndarray, histories: np.ndarray
) -> np.ndarray:
    """Open-loop simulations of segments [first, end) of one recording's commands, each from its own start
    state, in parallel (multiple shooting).

    starts (S, 7) are the states at ``firsts``; histories (S, DELAY_BUFFER) the commands before each
    start, oldest first. Returns the states (n, 7) after each sample: NaN outside the segments and in a
    diverged one.
    """
    model.require_boom()
    params = model.parameter_matrix(np.zeros(1))[0]  # validates delay and dead zone once
    commands = np.ascontiguousarray(commands, dtype=float)
    if not np.all(np.isfinite(commands)):
        raise InputError("valve commands contain NaN or inf")
    lags = np.array([lagged_command(params, history) for history in histories])
    states = np.full((len(commands), N_STATES), np.nan)
    _integrate_segments(
        np.ascontiguousarray(starts, dtype=float), np.broadcast_to(params, (len(commands), N_PARAMS)), model.poly, model.centre_leakage,
        commands, np.asarray(firsts, dtype=np.int64), np.asarray(ends, dtype=np.int64), np.ascontiguousarray(histories, dtype=float), lags,
        1.0 / model.sample_rate, model.substeps, states,
    )
    return states


def injection_levels(injection: Injection, times: np.ndarray) -> np.ndarray:
    """Vectorised :meth:`Injection.level` over sample times."""
    times = np.asarray(times, dtype=float)
    fraction = np.clip((times - injection.onset_s) / injection.ramp_s, 0.0, 1.0) if injection.ramp_s > 0.0 else (times >= injection.onset_s).astype(float)
    return injection.value * fraction


class SamPlant:
    """A running SAM: state, time, injections, stepping in blocks of sensor samples.

    Inputs are either valve commands (open loop) or joint-position references that a simulated
    operator follows with a saturated proportional law (closed loop).
    """

    def __init__(
        self,
        model: SamModel,
        *,
        injections: Sequence[Injection] = (),
        initial_joint: float | None = None,
        operator_gain: float = 4.0,
        max_command: float = 1.0,
    ) -> None:
        model.require_boom()
        self.model = model
        self.injections: list[Injection] = list(injections)
        joint0 = model.machine.simulation.initial_joint_position if initial_joint is None else initial_joint
        self.state = model.resting_state(joint0)
        self.sample_index = 0
        self.operator_gain = operator_gain
        self.max_command = max_command
        self._delay_buffer = np.zeros(DELAY_BUFFER)
        self._delay_position = 0
        self._lag_state = np.zeros(1)

    def prime_command_history(self, commands: np.ndarray) -> None:
        """Commands applied before now, oldest first: what a valve delay replays at the start."""
        history = np.asarray(commands, dtype=float)[-DELAY_BUFFER:]
        slots = (self._delay_position - len(history) + np.arange(len(history))) % DELAY_BUFFER
        self._delay_buffer[slots] = history
        self._lag_state[0] = lagged_command(self.model.base, history)

    @property
    def sample_time(self) -> float:
        return 1.0 / self.model.sample_rate

    @property
    def time(self) -> float:
        return self.sample_index * self.sample_time

    def sample_times(self, n: int) -> np.ndarray:
        """Times at the end of the next ``n`` samples."""
        return (self.sample_index + 1 + np.arange(n)) * self.sample_time

    def advance(
        self,
        n: int,
        *,
        commands: np.ndarray | None = None,
        references: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step ``n`` samples; returns (times, states (n, 7), valve commands (n,))."""
        if (commands is None) == (references is None):
            raise ValueError("give exactly one of commands (open loop) or references (closed loop)")
        times = self.sample_times(n)
        params = self.model.parameter_matrix(times, self.injections)
        inputs = np.ascontiguousarray(commands if commands is not None else references, dtype=float)
        if inputs.shape != (n,):
            raise ValueError(f"expected {n} inputs, got shape {inputs.shape}")
        if not np.all(np.isfinite(inputs)):
            raise InputError("valve commands or references contain NaN or inf")
        states = np.empty((n, N_STATES))
        applied = np.empty(n)
        self._delay_position = _integrate_samples(
            self.state,
            params,
            self.model.poly,
            self.model.centre_leakage,
            inputs,
            inputs,
            references is not None,
            self.operator_gain,
            self.max_command,
            self._delay_buffer,
            self._delay_position,
            self._lag_state,
            self.sample_time,
            self.model.substeps,
            states,
            applied,
        )
        if not np.all(np.isfinite(self.state)):
            raise SimulationDiverged(f"SAM model diverged before t = {times[-1]:.3f} s (state {self.state})")
        self.sample_index += n
        return times, states, applied
