"""A serial arm of valve-controlled cylinders written apart from the model under test: the plant on which the claims
about real machines (commissioning, false alarms, leaks named) are tested for a machine with an ``arm:``.

The monitor's model (models/sam.py) and the package's arm simulator (sim/arm_cylinders.py) share their valve,
chamber and friction equations. This plant shares none of them. It is written from the physics again, with forms
a machine maker's own simulation would pick where the papers leave a choice:

* **links**: the planar serial chain's equations of motion from each mass's Jacobian, M(q) q'' = R(q) F - G(q) -
  sum m J^T (J' q'), every mass a point with its own rotational inertia, the payload a point at the tip whose mass
  steps when the operator picks or drops a load;
* **valve**: each notch's flow coefficient is a measured table (six openings, linear between them), not a polynomial:
  the data sheet's curve with each point and each notch off by what an identified valve of that type shows; the
  orifice regularised smoothly (Q ~ dp / (dp^2 + delta^2)^(1/4)); laminar centre leakage near the spool's centre;
* **lines**: a hose between the valve and each cylinder port with a laminar resistance (Hagen-Poiseuille), so the
  transmitter at the port reads the valve's pressure less the line's drop; the hose's oil and wall add their own
  compliance to the chamber's (the line's RC time, ~50 us, is far below a sample, so it settles at once);
* **chambers**: each volume's own compliance (chamber oil; line oil and wall), softened toward vapour pressure;
* **friction**: a Stribeck curve with a smooth stick (tanh), no bristle states (the monitor's family is LuGre);
* **oil temperature**: each day starts at its own (drawn per run, within ``RigSpread.oil_warmer``) and warms through
  the run; the viscosity follows (Andrade, ~3 %/K), and with it the viscous friction, the centre and leak flows
  (laminar) and the hoses' resistance: the terms a fit holds fixed drift from one day to the next and within one;
* **supply**: a pressure-compensated pump whose pressure droops with the flow drawn;
* **integrator**: an adaptive Dormand-Prince 5(4) per sample interval, the operator's command held over the interval
  as a sampled controller holds it;
* **sensors**: transmitters with noise, a zero offset of their own (drawn per rig) and a 12-bit quantisation; an
  encoder quantised to its
  resolution, its rate the differenced angle through a second-order Butterworth low-pass at the config's cut-off;
* **operator**: its own: each joint moves to random targets within 80 % of its range along a ramp of a drawn speed,
  the lever proportional to the error with a drawn gain (so some moves run at full opening), joints at once; the gain
  at most what closes the error in ``OPERATOR_RESPONSE`` at the data sheet's lever per joint speed (a heavier hand
  made the K70M's lift hunt at 2.5 Hz through cavitation, an operator no crane has).

Its numbers start from the config's (a machine described by its data sheet), each drawn off by ``RigSpread`` for a
``rig`` seed: a given machine is one rig seed; a given day's work on it is one run seed (the operator's moves, the
oil's start and the noise draw from both, so two machines never work the same day).

Faults, in the vocabulary's names, per actuator, from an onset time: ``external_leakage_a``, ``external_leakage_b``,
``internal_leakage`` (L/min at 10 MPa and the day's starting viscosity, laminar); ``spool_too_small_opening`` and
``spool_too_large_opening`` (the solenoid's drive of the spool weakened or strengthened by that fraction: the spool
moves less or more for the same command; the notches open fully at most, so a strengthened drive changes nothing once
the command reaches 1 / (1 + size)), ``spool_stuck_closed`` (1: the spool held at its centre).

A machine without an ``arm:`` whose one actuator carries its ``load`` (the SAM) is the one-link arm that load
describes (P-I eqs. 20-21: the boom's mass at its centre of gravity with its inertia about it, m_L and m_R at +-L),
moved within the joint range its mount and end stops allow.

A planned machine (the K70M) is the chain its ``arm:`` describes (the telescope a prismatic link sliding on the tilt
link, its cylinder on a linear mount, its pads' Coulomb force, ``planner.friction``, as a Stribeck curve on it); its
slewing base is held still. Its mobile valves: the main spool's overlap drawn per rig, the opening beyond it
rescaled to full travel; a pressure compensator whose spring holds ``COMPENSATOR_RISE`` more drop at full opening and
whose check closes when the load is above what the supply can hold; the pilot stage a first-order lag
(``PILOT_LAG``) whose pressures are measured with the compensator's. ``ArmWork.path`` (a planned joint trajectory)
is worked forwards and back with drawn holds, the lever the path's speed needs on the data sheet's valve plus the
operator's correction, past the overlap at once.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from numba import njit
from scipy.signal import butter, lfilter

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.crane import parse_planning
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES, Machine
from hydro_ros.contract.samples import Samples

FAULTS = ("external_leakage_a", "external_leakage_b", "internal_leakage", "spool_too_small_opening", "spool_too_large_opening",
          "spool_stuck_closed")
LEAKS = FAULTS[:3]  # sized in L/min at 10 MPa; the spool faults by a fraction
_FAULT_COUNT = len(FAULTS)
TABLE_OPENINGS = np.array([0.0, 0.1, 0.2, 0.4, 0.6, 0.8, 1.0])  # the flow table's spool openings [-]
ORIFICE_SMOOTHING = 2.0e4  # [Pa] the orifice turns laminar below this drop
CENTRE_BAND, CENTRE_BLEND = 0.012, 0.004  # [-] centre leakage acts for |x_s| below the band, faded over the blend
VAPOUR_KNEE, VAPOUR_PRESSURE = 3.0e5, -9.0e4  # [Pa] a chamber's stiffness falls to zero at vapour pressure below the knee
LEAK_DROP = 1.0e7  # [Pa] leaks are quoted in L/min at 10 MPa
HOSE_DIAMETER, HOSE_LENGTH = 0.0127, 2.5  # [m] a 1/2" line from the valve to each port
OIL_VISCOSITY = 0.035  # [Pa s] at the reference temperature (ISO VG 46 near 45 degC)
VISCOSITY_PER_KELVIN = 0.03  # [1/K] Andrade: mu ~ exp(-k dT)
WARMING_TIME = 900.0  # [s] the oil's approach to its working temperature
STICK_VELOCITY = 1.0e-3  # [m/s] the tanh of the smooth stick
SUPPLY_DROOP = 0.6e6  # [Pa] the compensator's droop at the valve's nominal flow per notch
TRANSMITTER_LSB = 25.0e6 / 4096  # [Pa] 12 bits over the transmitter's span
ZERO_OFFSET = 2.0e4  # [Pa] a transmitter's zero, drawn within +- this
RTOL = 1e-5
LINE_ITERATIONS = 4
SAMPLE_SUBSTEP_MAX = 4  # the first step into a sample (its command just changed) is at most a quarter of its period
SMALLEST_STEP = 1.0e-9  # [s] a step this small means the integration has failed
OPERATOR_SPEED = (0.05, 0.35)  # [rad/s] the reference's ramp per move
OPERATOR_GAIN = (3.0, 9.0)  # [1/rad] lever per joint error, per move ...
# ... at most what closes the error in this time at the data sheet's lever per joint speed: 7.3 (0.33 s) made the K70M's
# lift cycle at 2.5 Hz through cavitation on the half-cycle path, 4.0 (0.6 s) still hunted, 3.2 (0.75 s) never did
OPERATOR_RESPONSE = 0.75  # [s]
OPERATOR_REST = (0.5, 4.0)  # [s] between moves
OPERATOR_SPAN = 0.8  # targets within this share of each joint's range, about its middle
PILOT_LAG = 0.03  # [s] a mobile valve's pilot stage: its pressure follows the command as a first-order lag
COMPENSATOR_RISE = 0.15  # [-] a compensator's spring holds this much more drop at full opening than at none
CYCLE_HOLD = (2.0, 6.0)  # [s] a path's work cycle rests this long at either end (the grapple closing or opening)


@dataclass(frozen=True)
class RigSpread:
    """How far one built machine is from its data sheet (each a relative 1-sigma, or a +-range where named)."""

    notch_gain: float = 0.06  # per notch
    table_point: float = 0.03  # per point of a notch's flow table
    oil_bulk_modulus: float = 0.15
    hose_bulk_modulus: float = 0.2
    centre_leakage: float = 0.2
    spool_bandwidth: tuple[float, float] = (0.75, 1.0)  # x the data sheet's natural frequency
    friction: tuple[float, float] = (0.7, 1.6)  # x the config's coulomb, static and viscous terms
    oil_warmer: tuple[float, float] = (-6.0, 10.0)  # [K] a day's start against the reference temperature
    overlap_spread: float = 0.1  # a mobile valve's main spool overlap against the data sheet's
    line_resistance_scale: float = 1.0  # not a spread: x the hoses' laminar resistance (0: the valve at the cylinder's ports)


@dataclass(frozen=True)
class ArmWork:
    """One run of the rig: its duration, the operator's seed, payload steps at the tip and faults per actuator."""

    duration_s: float
    seed: int
    payload_steps: tuple[tuple[float, float], ...] = ()  # (time [s], tip payload from then [kg])
    faults: tuple[tuple[str, str, float, float], ...] = ()  # (actuator, fault, size (L/min at 10 MPa for a leak), onset [s])
    lever_limit: float = 1.0  # [-] the operator never pushes a lever further than this
    warming_k: float = 15.0  # [K] the oil's rise toward its working temperature
    oil_start_k: float | None = None  # [K] the day's start against the reference (None: drawn for the day)
    path: Any = None  # a joint trajectory (joint_names, time, positions) worked forwards and back in place of the moves


@dataclass
class ArmRig:
    """Every number of one built arm, SI; per-cylinder arrays in the machine's actuator order."""

    machine: Machine
    cylinder: np.ndarray  # (A, C) see _C_* below
    flow_table: np.ndarray  # (A, 4, len(TABLE_OPENINGS)) [m^3/(s Pa^0.5)] per notch PA, PB, AT, BT
    centre: np.ndarray  # (A, 4) [m^3/(s Pa)] centre leakage per notch
    link: np.ndarray  # (N, 2) length, offset of the next joint
    prismatic: np.ndarray  # (N,) True where the link slides on its joint instead of turning
    mass: np.ndarray  # (K, 5) link index, mass, along, across, inertia
    origin: np.ndarray
    payload: float
    supply: float
    tank: float
    gravity: float
    oil_range: tuple[float, float]  # [K] where a day's start lies against the reference temperature
    zero_offsets: np.ndarray  # (2 A + 1,) [Pa] the transmitters' zeros: every chamber A, every chamber B, the supply
    # (and, with mobile valves, every compensator, then the load-sensing line)
    seed: int
    targets: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))  # (A, 2) joint range for the operator
    directions: np.ndarray = field(default_factory=lambda: np.zeros(0))  # (A,) +1 where extending raises the joint


# per-cylinder numbers in ArmRig.cylinder
(_C_AREA_A, _C_AREA_B, _C_STROKE, _C_V0A, _C_V0B, _C_L1, _C_L2, _C_L3, _C_OFFSET, _C_SIGN, _C_OMEGA, _C_ZETA,
 _C_HOSE_VOLUME, _C_HOSE_MODULUS, _C_OIL_MODULUS, _C_COULOMB, _C_STATIC, _C_STRIBECK, _C_VISCOUS, _C_STOP_LOW,
 _C_STOP_HIGH, _C_STOP_K, _C_STOP_D, _C_NOMINAL_FLOW, _C_LINEAR, _C_RATIO, _C_MOBILE, _C_OVERLAP, _C_COMPENSATOR,
 _C_PILOT_GAIN, _C_LINES) = range(31)
_CYLINDER_NUMBERS = 31
_STATES_PER_CYLINDER = 4  # p_A, p_B at the ports, spool, spool rate


def build_rig(machine: Machine, rig_seed: int, spread: RigSpread | None = None) -> ArmRig:
    """The arm of ``machine`` as one built machine (``rig_seed``): the config's numbers drawn off by ``spread``. A slewing
    base (``arm.slew``) is held still."""
    spread = spread or RigSpread()
    arm, joint_coulomb = machine.arm, {}
    if machine.planned:
        planned = parse_planning(machine.mapping, machine.source)
        # the redundant joint's friction (the K70M telescope's pads, P-VI eqs. A3-A4's level), here a Stribeck curve on
        # the cylinder like the others
        joint_coulomb = {planned.joints[planned.redundant].name: planned.extension_friction.coulomb}
    if arm is not None:
        joints = [link.joint for link in arm.links]
        links = np.array([[link.length, link.offset] for link in arm.links])
        prismatic = np.array([link.kind == "prismatic" for link in arm.links])
        masses = [(index, m.mass, m.along, m.across, m.inertia) for index, link in enumerate(arm.links) for m in link.masses]
        origin, payload = np.asarray(arm.origin, dtype=float), arm.payload
        joint_ranges = {link.joint: link.joint_range for link in arm.links}
    elif len(machine.actuators) == 1 and machine.first.load is not None:
        load = machine.first.load
        joints = [machine.first.joint]
        links = np.array([[load.load_distance, 0.0]])
        masses = [(0, load.boom_mass, load.boom_cog_distance, 0.0, load.boom_mass * load.boom_length ** 2 / 12.0),
                  (0, load.left_mass, load.load_distance, 0.0, 0.0), (0, load.right_mass, -load.load_distance, 0.0, 0.0)]
        origin, payload, joint_ranges = np.zeros(2), 0.0, {}
        prismatic = np.zeros(1, dtype=bool)
    else:
        raise InputError(f"independent arm: {machine.source} has no arm: section and not one actuator with its load "
                         "(this plant moves the links of an arm)")
    rng = np.random.default_rng(rig_seed)
    rows, tables, centres, ranges = [], [], [], []
    for actuator in machine.actuators:
        if actuator.joint not in joints:
            raise InputError(f"independent arm: actuator {actuator.name} moves {actuator.joint}, which is not a link of the arm")
        c, m, v, f, fr = actuator.cylinder, actuator.mount, actuator.valve, actuator.fluid, actuator.friction
        area_a = math.pi * c.piston_diameter ** 2 / 4.0
        sim = machine.simulation
        friction = rng.uniform(*spread.friction)
        # a joint's own friction (the telescope's) reaches the cylinder through the mount's ratio
        pads = joint_coulomb.get(actuator.joint, 0.0) * (1.0 / m.ratio if m.kind == "linear" else 0.0)
        row = np.zeros(_CYLINDER_NUMBERS)
        row[[_C_AREA_A, _C_AREA_B, _C_STROKE, _C_V0A, _C_V0B]] = area_a, area_a - math.pi * c.rod_diameter ** 2 / 4.0, c.stroke, \
            c.dead_volume_a, c.dead_volume_b
        row[[_C_L1, _C_L2, _C_L3, _C_OFFSET, _C_SIGN]] = m.l1, m.l2, m.l3, m.theta_offset, m.sign
        row[_C_OMEGA] = v.natural_frequency * rng.uniform(*spread.spool_bandwidth)
        row[_C_ZETA] = v.damping
        row[_C_HOSE_VOLUME] = f.hose_volume
        row[_C_LINES] = spread.line_resistance_scale
        row[_C_HOSE_MODULUS] = f.hose_bulk_modulus * max(1.0 + spread.hose_bulk_modulus * rng.standard_normal(), 0.3)
        row[_C_OIL_MODULUS] = f.oil_bulk_modulus * max(1.0 + spread.oil_bulk_modulus * rng.standard_normal(), 0.3)
        row[[_C_COULOMB, _C_STATIC, _C_STRIBECK, _C_VISCOUS]] = friction * (fr.coulomb + pads), friction * (fr.static + 1.2 * pads), \
            fr.stribeck_velocity, friction * fr.viscous
        row[[_C_LINEAR, _C_RATIO]] = m.kind == "linear", m.ratio
        if v.mobile:
            row[[_C_MOBILE, _C_OVERLAP, _C_COMPENSATOR, _C_PILOT_GAIN]] = 1.0, \
                v.deadzone * max(1.0 + spread.overlap_spread * rng.standard_normal(), 0.5), \
                v.compensator_pressure_drop * max(1.0 + spread.notch_gain * rng.standard_normal(), 0.5), \
                1.0 + 0.5 * spread.notch_gain * rng.standard_normal()
        row[[_C_STOP_LOW, _C_STOP_HIGH, _C_STOP_K, _C_STOP_D]] = sim.end_stop_lower, \
            c.stroke if sim.end_stop_upper is None else sim.end_stop_upper, sim.end_stop_stiffness, sim.end_stop_damping
        row[_C_NOMINAL_FLOW] = v.nominal_flow
        rows.append(row)
        # the data sheet's curve (the config's polynomial) read at the table's openings, each notch and point off
        table = np.empty((4, len(TABLE_OPENINGS)))
        for k, notch in enumerate(NOTCHES):
            # P-II's polynomials take the signed spool position: PA and BT open for x_s > 0, PB and AT for x_s < 0
            side = 1.0 if notch in ("PA", "BT") else -1.0
            curve = np.polyval(np.asarray(v.kv_poly[notch], dtype=float), side * np.maximum(TABLE_OPENINGS, TABLE_OPENINGS[1]))
            table[k] = np.abs(curve) * (1.0 + spread.notch_gain * rng.standard_normal()) \
                * (1.0 + spread.table_point * rng.standard_normal(len(TABLE_OPENINGS)))
        tables.append(np.maximum(table, 0.0))
        centres.append([v.centre_leakage[n] * max(1.0 + spread.centre_leakage * rng.standard_normal(), 0.2) for n in NOTCHES])
        low, high = joint_ranges.get(actuator.joint) or _reachable(row, machine.sensors.joint_range)
        middle, half = 0.5 * (low + high), 0.5 * OPERATOR_SPAN * (high - low)
        ranges.append((middle - half, middle + half))
    if len({a.joint for a in machine.actuators}) != len(joints):
        raise InputError(f"independent arm: every link of {machine.source}'s arm needs its own actuator")
    order = [joints.index(a.joint) for a in machine.actuators]
    if order != sorted(order):
        raise InputError(f"independent arm: {machine.source}'s actuators must be listed base to tip, as the arm's links")
    return ArmRig(machine=machine, cylinder=np.array(rows), flow_table=np.array(tables), centre=np.array(centres),
                  link=links, prismatic=prismatic, mass=np.array(masses, dtype=float).reshape(-1, 5), origin=origin, payload=payload,
                  supply=machine.supply_pressure,
                  tank=machine.tank_pressure, gravity=machine.simulation.gravity, oil_range=spread.oil_warmer,
                  zero_offsets=rng.uniform(-ZERO_OFFSET, ZERO_OFFSET, (3 if machine.mobile else 2) * len(rows) + 1 + machine.mobile),
                  seed=rig_seed,
                  targets=np.array(ranges),
                  # the operator pushes the lever the way that moves the joint toward its target (a tilt whose
                  # cylinder closes the triangle as the joint opens is driven the other way)
                  directions=np.array([math.copysign(1.0, _piston(row, 0.5 * (low + high))[1]) for row, (low, high) in zip(rows, ranges)]))


def _reachable(row: np.ndarray, plausible: tuple[float, float]) -> tuple[float, float]:
    """The joint range whose piston stays a tenth of its travel inside the end stops (a machine without an arm: section)."""
    q = np.linspace(*plausible, 2001)
    x = np.array([_piston(row, angle)[0] for angle in q])
    margin = 0.1 * (row[_C_STOP_HIGH] - row[_C_STOP_LOW])
    inside = q[(x > row[_C_STOP_LOW] + margin) & (x < row[_C_STOP_HIGH] - margin)]
    if len(inside) < 2:
        raise InputError(f"independent arm: no joint angle within {plausible} keeps the piston inside its end stops")
    return float(inside.min()), float(inside.max())


@njit(cache=True)
def _orifice(dp):
    return dp / (dp * dp + ORIFICE_SMOOTHING * ORIFICE_SMOOTHING) ** 0.25


@njit(cache=True)
def _table(row, opening):
    """A notch's flow coefficient at ``opening`` in [0, 1], linear between the table's points: np.interp's arithmetic,
    bit for bit, without the arrays it allocates for a scalar (it ran 9 times in each evaluation of the rates)."""
    if opening != opening:
        return opening
    last = len(TABLE_OPENINGS) - 1
    if opening <= TABLE_OPENINGS[0]:
        return row[0]
    if opening >= TABLE_OPENINGS[last]:
        return row[last]
    j = 0
    while TABLE_OPENINGS[j + 1] <= opening:
        j += 1
    if TABLE_OPENINGS[j] == opening:
        return row[j]
    slope = (row[j + 1] - row[j]) / (TABLE_OPENINGS[j + 1] - TABLE_OPENINGS[j])
    value = slope * (opening - TABLE_OPENINGS[j]) + row[j]
    if value != value:  # np.interp's way out of a non-finite slope
        value = slope * (opening - TABLE_OPENINGS[j + 1]) + row[j + 1]
        if value != value and row[j] == row[j + 1]:
            value = row[j]
    return value


@njit(cache=True)
def _softening(pressure):
    """A chamber's stiffness falls to zero at vapour pressure below the knee."""
    return min(max((pressure - VAPOUR_PRESSURE) / (VAPOUR_KNEE - VAPOUR_PRESSURE), 0.0), 1.0)


@njit(cache=True)
def _piston(cyl, q):
    """Piston position and dx/dq: a triangle mount, or a linear one (a telescope's cylinder)."""
    if cyl[_C_LINEAR] > 0.5:
        return cyl[_C_RATIO] * (q + cyl[_C_OFFSET]), cyl[_C_RATIO]
    theta = cyl[_C_SIGN] * q + cyl[_C_OFFSET]
    length = math.sqrt(cyl[_C_L1] ** 2 + cyl[_C_L2] ** 2 - 2.0 * cyl[_C_L1] * cyl[_C_L2] * math.cos(theta))
    return length - cyl[_C_L3], cyl[_C_SIGN] * cyl[_C_L1] * cyl[_C_L2] * math.sin(theta) / length


@njit(cache=True)
def _mechanics(q, qd, link, prismatic, mass, payload, gravity):
    """M(q) and the generalised forces of gravity and of the velocity products, for the chain's point masses. A revolute
    joint turns everything beyond it about its pivot; a prismatic one slides its own link (and what rides on it) along
    the link's line."""
    n = len(q)
    pivot = np.zeros((n + 1, 2))
    pivot_rate = np.zeros((n + 1, 2))
    line = np.zeros((n, 2))  # each link's direction
    turn = np.zeros(n)  # each link's angular rate
    slide = np.zeros(n)
    slide_rate = np.zeros(n)
    phi, phid = 0.0, 0.0
    for j in range(n):
        if prismatic[j]:
            slide[j], slide_rate[j] = q[j], qd[j]
        else:
            phi += q[j]
            phid += qd[j]
        c, s = math.cos(phi), math.sin(phi)
        line[j, 0], line[j, 1], turn[j] = c, s, phid
        along, across = link[j, 0] + slide[j], link[j, 1]
        pivot[j + 1, 0] = pivot[j, 0] + along * c - across * s
        pivot[j + 1, 1] = pivot[j, 1] + along * s + across * c
        pivot_rate[j + 1, 0] = pivot_rate[j, 0] + slide_rate[j] * c - phid * (along * s + across * c)
        pivot_rate[j + 1, 1] = pivot_rate[j, 1] + slide_rate[j] * s + phid * (along * c - across * s)
    inertia = np.zeros((n, n))
    bias = np.zeros(n)
    weight = np.zeros(n)
    count = mass.shape[0] + 1
    jac = np.empty((2, n))
    jac_rate = np.empty((2, n))
    for k in range(count):
        if k < mass.shape[0]:
            j, m, along, across, rot = int(mass[k, 0]), mass[k, 1], mass[k, 2], mass[k, 3], mass[k, 4]
        else:
            j, m, along, across, rot = n - 1, payload, link[n - 1, 0], link[n - 1, 1], 0.0
        c, s = line[j, 0], line[j, 1]
        along += slide[j]
        x = pivot[j, 0] + along * c - across * s
        y = pivot[j, 1] + along * s + across * c
        xd = pivot_rate[j, 0] + slide_rate[j] * c - turn[j] * (along * s + across * c)
        yd = pivot_rate[j, 1] + slide_rate[j] * s + turn[j] * (along * c - across * s)
        jac[:] = 0.0
        jac_rate[:] = 0.0
        for i in range(j + 1):
            if prismatic[i]:  # sliding link i moves the point along that link's line
                jac[0, i], jac[1, i] = line[i, 0], line[i, 1]
                jac_rate[0, i], jac_rate[1, i] = -turn[i] * line[i, 1], turn[i] * line[i, 0]
            else:  # turning joint i moves the point about pivot i
                jac[0, i], jac[1, i] = -(y - pivot[i, 1]), x - pivot[i, 0]
                jac_rate[0, i], jac_rate[1, i] = -(yd - pivot_rate[i, 1]), xd - pivot_rate[i, 0]
        ax = 0.0
        ay = 0.0
        for i in range(n):
            ax += jac_rate[0, i] * qd[i]
            ay += jac_rate[1, i] * qd[i]
        for a in range(n):
            bias[a] += m * (jac[0, a] * ax + jac[1, a] * ay)
            weight[a] += m * gravity * jac[1, a]
            for b in range(n):
                inertia[a, b] += m * (jac[0, a] * jac[0, b] + jac[1, a] * jac[1, b])
                if a <= j and b <= j and not prismatic[a] and not prismatic[b]:
                    inertia[a, b] += rot
    return inertia, weight, bias


@njit(cache=True)
def _opening(c, spool):
    """The notches' opening: the spool's travel; a mobile valve's beyond its overlap, rescaled to its full travel."""
    travel = abs(spool)
    if c[_C_MOBILE] > 0.5:
        travel = max(travel - c[_C_OVERLAP], 0.0) / (1.0 - c[_C_OVERLAP])
    return min(travel, 1.0)


@njit(cache=True)
def _held_drop(c, opening):
    """What a mobile valve's compensator holds across its P notch: its spring's drop, rising with the opening."""
    return c[_C_COMPENSATOR] * (1.0 + COMPENSATOR_RISE * opening)


@njit(cache=True)
def _inlet_drop(c, opening, p_s, p_valve):
    """The drop across a P notch: the supply less the valve-side pressure, or what a mobile valve's compensator holds
    (a load above what the supply can hold closes its check)."""
    if c[_C_MOBILE] > 0.5:
        return max(min(_held_drop(c, opening), p_s - p_valve), 0.0)
    return p_s - p_valve


@njit(cache=True)
def _notch(c, table, spool, side):
    """One side's (0: A, 1: B) metering notch at ``spool``: its flow coefficient times its opening, and whether it meters
    from the supply (else to the tank). It does not depend on the pressures, so a line's iterations share it."""
    opening = _opening(c, spool)
    if spool > 0.0:
        return (_table(table[0], opening) * opening, True) if side == 0 else (_table(table[3], opening) * opening, False)
    if spool < 0.0:
        return (_table(table[2], opening) * opening, False) if side == 0 else (_table(table[1], opening) * opening, True)
    return 0.0, False


@njit(cache=True)
def _valve_flow(c, notch, from_supply, centre, spool, p_s, tank, side, p_valve, viscosity):
    """Flow into one side's line (0: A, 1: B) at the valve-side pressure ``p_valve``, through its notch (``_notch``)."""
    opening = _opening(c, spool)
    flow = 0.0
    if spool > 0.0 or spool < 0.0:
        flow = notch * _orifice(_inlet_drop(c, opening, p_s, p_valve)) if from_supply else -notch * _orifice(p_valve - tank)
    near = min(max((CENTRE_BAND + 0.5 * CENTRE_BLEND - (opening if c[_C_MOBILE] > 0.5 else abs(spool))) / CENTRE_BLEND, 0.0), 1.0) \
        / viscosity
    inlet, outlet = (centre[0], centre[2]) if side == 0 else (centre[1], centre[3])
    return flow + near * (inlet * (p_s - p_valve) - outlet * (p_valve - tank))


@njit(cache=True)
def _line_flow(c, table, centre, spool, p_s, tank, side, p_port, resistance, viscosity):
    """Flow through the valve and its line into a port: the valve-side pressure settles where the valve's flow equals the
    line's (its RC time, ~50 us, is far below a sample); a fixed point, contracting by R dQ/dp < 0.3."""
    notch, from_supply = _notch(c, table, spool, side)
    if resistance == 0.0:
        return _valve_flow(c, notch, from_supply, centre, spool, p_s, tank, side, p_port, viscosity)
    p_valve = p_port
    for _ in range(LINE_ITERATIONS):
        p_valve = p_port + resistance * _valve_flow(c, notch, from_supply, centre, spool, p_s, tank, side, p_valve, viscosity)
    return (p_valve - p_port) / resistance


@njit(cache=True)
def _rates(y, u, cyl, table, centre, link, prismatic, mass, payload, gravity, supply, tank, viscosity, leaks, dy, feed):
    """d/dt of the state: per cylinder [p_A, p_B, spool, spool rate] (at the cylinder's ports), then joints, then rates.
    Returns the supply pressure; ``feed`` gets each valve's pressure upstream of its P notches (a mobile valve's
    compensator pressure, else the supply)."""
    a = cyl.shape[0]
    base = _STATES_PER_CYLINDER * a
    q = y[base:base + a]
    qd = y[base + a:base + 2 * a]
    inertia, weight, bias = _mechanics(q, qd, link, prismatic, mass, payload, gravity)
    torque = np.zeros(a)
    # the pump's compensator droops with the flow the P notches draw at its set pressure
    drawn = 0.0
    for i in range(a):
        spool = y[_STATES_PER_CYLINDER * i + 2]
        opening = _opening(cyl[i], spool)
        side = 0 if spool > 0.0 else 1
        drawn += _table(table[i, side], opening) * opening \
            * _orifice(_inlet_drop(cyl[i], opening, supply, y[_STATES_PER_CYLINDER * i + side])) / cyl[i, _C_NOMINAL_FLOW]
    p_s = supply - SUPPLY_DROOP * drawn
    hoses = 128.0 * OIL_VISCOSITY * viscosity * HOSE_LENGTH / (math.pi * HOSE_DIAMETER ** 4)
    for i in range(a):
        c = cyl[i]
        resistance = hoses * c[_C_LINES]
        s0 = _STATES_PER_CYLINDER * i
        pa, pb, spool, spool_rate = y[s0], y[s0 + 1], y[s0 + 2], y[s0 + 3]
        x, arm = _piston(c, q[i])
        v = arm * qd[i]
        line_a = _line_flow(c, table[i], centre[i], spool, p_s, tank, 0, pa, resistance, viscosity)
        line_b = _line_flow(c, table[i], centre[i], spool, p_s, tank, 1, pb, resistance, viscosity)
        feed[i] = p_s
        if c[_C_MOBILE] > 0.5:  # the compensator holds its drop above the metered side's load (at centre: the higher)
            load = pa + resistance * line_a if spool > 0.0 else pb + resistance * line_b if spool < 0.0 \
                else max(pa + resistance * line_a, pb + resistance * line_b)
            feed[i] = min(load + _held_drop(c, _opening(c, spool)), p_s)
        internal = leaks[i, 2] * (pa - pb) / viscosity
        # each volume's own compliance: the chamber's oil, and the line's oil and wall
        hose = c[_C_HOSE_VOLUME] * (1.0 / c[_C_OIL_MODULUS] + 1.0 / c[_C_HOSE_MODULUS])
        capacity_a = (c[_C_V0A] + c[_C_AREA_A] * x) / c[_C_OIL_MODULUS] + hose
        capacity_b = (c[_C_V0B] + c[_C_AREA_B] * (c[_C_STROKE] - x)) / c[_C_OIL_MODULUS] + hose
        net_a = line_a - internal - leaks[i, 0] * (pa - tank) / viscosity - c[_C_AREA_A] * v
        net_b = line_b + internal - leaks[i, 1] * (pb - tank) / viscosity + c[_C_AREA_B] * v
        # the softening slows a chamber's fall toward vapour pressure, never its refilling
        dy[s0] = (_softening(pa) if net_a < 0.0 else 1.0) / capacity_a * net_a
        dy[s0 + 1] = (_softening(pb) if net_b < 0.0 else 1.0) / capacity_b * net_b
        dy[s0 + 2] = spool_rate
        dy[s0 + 3] = c[_C_OMEGA] ** 2 * (u[i] - spool) - 2.0 * c[_C_ZETA] * c[_C_OMEGA] * spool_rate
        stribeck = c[_C_COULOMB] + (c[_C_STATIC] - c[_C_COULOMB]) * math.exp(-(v / c[_C_STRIBECK]) ** 2)
        friction = stribeck * math.tanh(v / STICK_VELOCITY) + c[_C_VISCOUS] * viscosity * v
        stop = 0.0
        if x < c[_C_STOP_LOW]:
            stop = max(c[_C_STOP_K] * (c[_C_STOP_LOW] - x) - c[_C_STOP_D] * v, 0.0)
        elif x > c[_C_STOP_HIGH]:
            stop = min(c[_C_STOP_K] * (c[_C_STOP_HIGH] - x) - c[_C_STOP_D] * v, 0.0)
        torque[i] = arm * (pa * c[_C_AREA_A] - pb * c[_C_AREA_B] - friction + stop)
    qdd = np.linalg.solve(inertia, torque - weight - bias)
    for i in range(a):
        dy[base + i] = qd[i]
        dy[base + a + i] = qdd[i]
    return p_s


# Dormand-Prince 5(4)
_C = np.array([0.0, 1 / 5, 3 / 10, 4 / 5, 8 / 9, 1.0, 1.0])
_A = np.array([
    [0.0, 0.0, 0.0, 0.0, 0.0, 0.0],
    [1 / 5, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3 / 40, 9 / 40, 0.0, 0.0, 0.0, 0.0],
    [44 / 45, -56 / 15, 32 / 9, 0.0, 0.0, 0.0],
    [19372 / 6561, -25360 / 2187, 64448 / 6561, -212 / 729, 0.0, 0.0],
    [9017 / 3168, -355 / 33, 46732 / 5247, 49 / 176, -5103 / 18656, 0.0],
    [35 / 384, 0.0, 500 / 1113, 125 / 192, -2187 / 6784, 11 / 84],
])
_E = np.array([71 / 57600, 0.0, -71 / 16695, 71 / 1920, -17253 / 339200, 22 / 525, -1 / 40])


@njit(cache=True)
def _interval(y, span, h, u, cyl, table, centre, link, prismatic, mass, payload, gravity, supply, tank, viscosity, leaks, scale):
    """Advance ``y`` by ``span`` with the command ``u`` held; returns the last accepted step size."""
    k = np.zeros((7, len(y)))
    stage = np.empty(len(y))
    feed = np.empty(cyl.shape[0])
    t = 0.0
    _rates(y, u, cyl, table, centre, link, prismatic, mass, payload, gravity, supply, tank, viscosity, leaks, k[0], feed)
    while t < span:
        step = min(h, span - t)
        for s in range(1, 7):
            stage[:] = y
            for r in range(s):
                if _A[s, r] != 0.0:
                    stage += step * _A[s, r] * k[r]
            _rates(stage, u, cyl, table, centre, link, prismatic, mass, payload, gravity, supply, tank, viscosity, leaks, k[s], feed)
        error = 0.0
        for j in range(len(y)):
            e = 0.0
            for s in range(7):
                e += _E[s] * k[s, j]
            e = abs(step * e / (scale[j] + RTOL * max(abs(y[j]), abs(stage[j]))))
            error = max(error, e) if e == e else math.inf  # a NaN rejects the step
        if error <= 1.0:
            t += step
            y[:] = stage
            k[0] = k[6]  # the last stage is the new state's rate (first same as last)
            h = step * min(5.0, max(0.2, 0.9 * error ** -0.2 if error > 0.0 else 5.0))
        else:  # too large, or not a number: a fifth of the step at most
            h = step * (max(0.1, 0.9 * error ** -0.2) if error < math.inf else 0.2)
            if h < SMALLEST_STEP:
                raise ValueError("the step size fell below SMALLEST_STEP")
    return h


@njit(cache=True)
def _run(y, period, targets, speeds, gains, feedforward, lever, directions, overlaps, payloads, fault_rows, onsets, viscosity, cyl, table,
         centre, link, prismatic, mass, gravity, supply, tank, scale):
    """Every sample: the operator's command from the state at its start, held over the period; states at its end. A
    mobile valve's spool follows its pilot pressure, which follows the command through the pilot stage's lag."""
    n, a = targets.shape
    base = _STATES_PER_CYLINDER * a
    states = np.empty((n, len(y)))
    commands = np.empty((n, a))
    supplies = np.empty(n)
    feeds = np.empty((n, a))
    pilots = np.empty((n, a))
    reference = y[base:base + a].copy()
    u = np.zeros(a)
    pilot = np.zeros(a)  # a mobile valve's pilot pressure difference, a fraction of its maximum
    drive = np.zeros(a)  # what reaches the spool
    leaks = np.zeros((a, 3))
    on = np.zeros(_FAULT_COUNT)
    dy = np.empty(len(y))
    lag = 1.0 - math.exp(-period / PILOT_LAG)
    h = period / SAMPLE_SUBSTEP_MAX
    for k in range(n):
        time = k * period
        for i in range(a):
            step = speeds[k, i] * period
            reference[i] += min(max(targets[k, i] - reference[i], -step), step)
            wanted = directions[i] * gains[k, i] * (reference[i] - y[base + i]) + feedforward[k, i]
            # past a mobile valve's overlap at once: the operator's lever (or a controller's dead-zone jump)
            u[i] = min(max(wanted + math.copysign(overlaps[i], wanted) * min(abs(wanted) / 0.02, 1.0), -lever), lever)
            for f in range(_FAULT_COUNT):
                on[f] = fault_rows[i, f] if time >= onsets[i, f] else 0.0
            leaks[i] = on[:3]
            # a weak or strong solenoid moves the spool less or more for the same command; a stuck one not at all
            drive[i] = u[i] * (1.0 - on[3] + on[4])
            if cyl[i, _C_MOBILE] > 0.5:
                pilot[i] += lag * (drive[i] - pilot[i])
                drive[i] = pilot[i] * cyl[i, _C_PILOT_GAIN]
            if on[5] > 0.5:
                s0 = _STATES_PER_CYLINDER * i
                y[s0 + 2] = y[s0 + 3] = drive[i] = 0.0
        commands[k] = u
        pilots[k] = pilot
        h = _interval(y, period, min(h, period / SAMPLE_SUBSTEP_MAX), drive, cyl, table, centre, link, prismatic, mass, payloads[k],
                      gravity, supply, tank, viscosity[k], leaks, scale)
        states[k] = y
        supplies[k] = _rates(y, drive, cyl, table, centre, link, prismatic, mass, payloads[k], gravity, supply, tank, viscosity[k], leaks,
                             dy, feeds[k])
    return states, commands, supplies, feeds, pilots


def _operator(rig: ArmRig, work: ArmWork, n: int, rate: float, start: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per sample and joint: the target, the ramp speed and the lever's gain of the move under way."""
    rng = np.random.default_rng([work.seed, rig.seed])
    a = len(start)
    lever = [_lever_per_speed(rig, i, start[i]) for i in range(a)]
    targets, speeds, gains = np.empty((n, a)), np.empty((n, a)), np.empty((n, a))
    for i in range(a):
        k, current = 0, start[i]
        while k < n:
            target = current if k == 0 else rng.uniform(*rig.targets[i])  # a rest before the first move
            speed, gain = rng.uniform(*OPERATOR_SPEED), min(rng.uniform(*OPERATOR_GAIN), lever[i] / OPERATOR_RESPONSE)
            length = max(int((abs(target - current) / speed + rng.uniform(*OPERATOR_REST)) * rate), 1)
            targets[k:k + length, i], speeds[k:k + length, i], gains[k:k + length, i] = target, speed, gain
            k, current = k + length, target
    return targets, speeds, gains


def _path_operator(rig: ArmRig, work: ArmWork, n: int, rate: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per sample and joint: the path's position (worked forwards, held, backwards, held, again; each hold drawn), its
    lever gain and the lever its speed needs on the data sheet's valve (the operator's, or a controller's, feed-forward)."""
    path = work.path
    names = list(path.joint_names)
    joints = [a.joint for a in rig.machine.actuators]
    missing = [j for j in joints if j not in names]
    if missing:
        raise InputError(f"independent arm: the path has no {', '.join(missing)} (it moves {', '.join(names)})")
    time, positions = np.asarray(path.time, dtype=float), np.asarray(path.positions, dtype=float)[:, [names.index(j) for j in joints]]
    if len(time) < 2 or not np.all(np.diff(time) > 0.0):
        raise InputError("independent arm: the path's times must increase")
    rng = np.random.default_rng([work.seed, rig.seed, 17])
    t = np.arange(0.0, time[-1] + 0.5 / rate, 1.0 / rate)
    forwards = np.stack([np.interp(t, time, column) for column in positions.T], axis=1)
    cycle = []
    while sum(len(part) for part in cycle) < n:
        for part in (forwards, forwards[::-1]):
            cycle += [part, np.repeat(part[-1:], int(rng.uniform(*CYCLE_HOLD) * rate), axis=0)]
    targets = np.concatenate(cycle)[:n]
    velocity = np.gradient(targets, 1.0 / rate, axis=0)
    feedforward = np.empty_like(targets)
    for i in range(len(joints)):
        piston = velocity[:, i] * np.array([_piston(rig.cylinder[i], q)[1] for q in targets[:, i]])
        extend, retract = _full_lever_speeds(rig, i)
        feedforward[:, i] = np.where(piston > 0.0, piston / extend, piston / retract)
    lever = np.array([_lever_per_speed(rig, i, targets[0, i]) for i in range(len(joints))])
    gains = np.repeat(np.minimum(rng.uniform(*OPERATOR_GAIN, (1, len(joints))), lever[None, :] / OPERATOR_RESPONSE), n, axis=0)
    return targets, gains, feedforward, targets[0]


def _full_lever_speeds(rig: ArmRig, i: int) -> tuple[float, float]:
    """[m/s] actuator ``i``'s piston speed extending and retracting at full lever on the data sheet's valve."""
    v, row = rig.machine.actuators[i].valve, rig.cylinder[i]
    drop = math.sqrt(v.compensator_pressure_drop if v.mobile else 0.5 * (rig.supply - rig.tank))
    return (abs(float(np.polyval(v.kv_poly["PA"], 1.0))) * drop / row[_C_AREA_A],
            abs(float(np.polyval(v.kv_poly["PB"], -1.0))) * drop / row[_C_AREA_B])


def _lever_per_speed(rig: ArmRig, i: int, q: float) -> float:
    """[-/(rad/s) or -/(m/s)] the lever that moves joint ``i`` at unit speed about ``q`` (extending), by the data sheet."""
    return abs(_piston(rig.cylinder[i], q)[1]) / _full_lever_speeds(rig, i)[0]


def _resting_state(rig: ArmRig, joints: np.ndarray, payload: float) -> np.ndarray:
    """At rest at ``joints``: each chamber B at its centre-leakage balance, A holding the links' static load."""
    a = len(joints)
    y = np.zeros(_STATES_PER_CYLINDER * a + 2 * a)
    _, weight, _ = _mechanics(joints, np.zeros(a), rig.link, rig.prismatic, rig.mass, payload, rig.gravity)
    for i in range(a):
        c, centre = rig.cylinder[i], rig.centre[i]
        p_b = (centre[1] * rig.supply + centre[3] * rig.tank) / (centre[1] + centre[3])
        _, arm = _piston(c, joints[i])
        p_a = (weight[i] / arm + p_b * c[_C_AREA_B]) / c[_C_AREA_A]
        y[_STATES_PER_CYLINDER * i:_STATES_PER_CYLINDER * i + 2] = p_a, p_b
    y[_STATES_PER_CYLINDER * a:_STATES_PER_CYLINDER * a + a] = joints
    return y


class RigRun(NamedTuple):
    """One run of a rig, per sample: the first one period after rest."""

    times: np.ndarray
    states: np.ndarray  # (n, S)
    commands: np.ndarray  # (n, A)
    supplies: np.ndarray  # (n,)
    feeds: np.ndarray  # (n, A) each valve's pressure upstream of its P notches
    pilots: np.ndarray  # (n, A) a mobile valve's pilot pressure difference, a fraction of its maximum


def simulate(rig: ArmRig, work: ArmWork) -> RigRun:
    machine = rig.machine
    names = machine.actuator_names
    rate = machine.sample_rate_hz
    n = int(round(work.duration_s * rate))
    if n < 1 or not math.isfinite(work.duration_s):
        raise InputError(f"independent arm: duration {work.duration_s} s gives no sample")
    times = np.arange(1, n + 1) / rate
    payloads = np.full(n, rig.payload)
    for at, value in sorted(work.payload_steps):
        if not value >= 0.0:
            raise InputError(f"independent arm: payload {value} kg at {at} s must be >= 0")
        payloads[times >= at] = value
    fault_rows, onsets = np.zeros((len(names), len(FAULTS))), np.full((len(names), len(FAULTS)), np.inf)
    for actuator, fault, value, onset in work.faults:
        if actuator not in names or fault not in FAULTS:
            raise InputError(f"independent arm: cannot inject {fault} on {actuator} (it has {', '.join(FAULTS)} on {', '.join(names)})")
        column = FAULTS.index(fault)
        if fault == "spool_stuck_closed" and value not in (0.0, 1.0):
            raise InputError(f"independent arm: spool_stuck_closed {value} must be 1 (stuck) or 0 (free)")
        largest = 1.0 if fault == "spool_too_small_opening" else math.inf
        if not (math.isfinite(value) and 0.0 <= value <= largest):
            raise InputError(f"independent arm: {fault} {value} must be finite, >= 0" + (f" and <= {largest:g}" if largest < math.inf else ""))
        fault_rows[names.index(actuator), column] = value / 60000.0 / LEAK_DROP if column < 3 else value
        onsets[names.index(actuator), column] = onset
    if not 0.0 < work.lever_limit <= 1.0:
        raise InputError(f"independent arm: lever_limit {work.lever_limit} must be in (0, 1]")
    if work.path is None:
        start = rig.targets.mean(axis=1)
        targets, speeds, gains = _operator(rig, work, n, rate, start)
        feedforward = np.zeros_like(targets)
    else:
        targets, gains, feedforward, start = _path_operator(rig, work, n, rate)
        speeds = np.full_like(targets, np.inf)
    y = _resting_state(rig, start, payloads[0])
    overlaps = np.array([a.valve.deadzone for a in machine.actuators])
    day = np.random.default_rng([work.seed, rig.seed, 13]).uniform(*rig.oil_range) if work.oil_start_k is None else work.oil_start_k
    warmth = day + work.warming_k * (1.0 - np.exp(-times / WARMING_TIME))
    viscosity = np.exp(-VISCOSITY_PER_KELVIN * warmth)
    fault_rows[:, :3] *= viscosity[0]  # a leak's size holds at the day's starting viscosity
    scale = np.concatenate([np.tile([1000.0, 1000.0, 1e-5, 1e-3], len(names)), np.full(len(names), 1e-7),
                            np.full(len(names), 1e-6)])
    try:
        run = RigRun(times, *_run(y, 1.0 / rate, targets, speeds, gains, feedforward, work.lever_limit, rig.directions, overlaps, payloads,
                                  fault_rows, onsets, viscosity, rig.cylinder, rig.flow_table, rig.centre, rig.link, rig.prismatic, rig.mass,
                                  rig.gravity, rig.supply, rig.tank, scale))
    except ValueError as failed:
        raise InputError(f"independent arm: the integration failed (seed {work.seed}: {failed})") from None
    if not np.all(np.isfinite(run.states)):
        raise InputError(f"independent arm: the integration diverged (seed {work.seed})")
    return run


def measure(rig: ArmRig, run: RigRun, seed: int) -> Samples:
    """The rig's sensors, (n, A) columns in the machine's actuator order (a mobile valve's pilot and compensator
    pressures on transmitters of their own)."""
    times, states, commands, supplies = run.times, run.states, run.commands, run.supplies
    machine = rig.machine
    sensors = machine.sensors
    rate = machine.sample_rate_hz
    rng = np.random.default_rng([seed, rig.seed, 7])
    a = len(machine.actuators)
    base = _STATES_PER_CYLINDER * a
    angle = np.round(states[:, base:base + a] / sensors.encoder_resolution) * sensors.encoder_resolution
    difference = np.diff(angle, axis=0, prepend=angle[:1]) * rate
    b, den = butter(2, sensors.velocity_filter_hz / (0.5 * rate))
    velocity = lfilter(b, den, difference, axis=0)

    def transmitter(pressure: np.ndarray, zero: np.ndarray) -> np.ndarray:
        noisy = pressure + zero + rng.normal(0.0, sensors.pressure_noise_std, pressure.shape)
        return np.clip(np.round(noisy / TRANSMITTER_LSB) * TRANSMITTER_LSB, *sensors.pressure_range)

    chambers = states[:, :base].reshape(len(times), a, _STATES_PER_CYLINDER)
    zeros = rig.zero_offsets
    mobile = {}
    if machine.mobile:
        pilot_max = np.array([act.valve.pilot_pressure_max for act in machine.actuators])
        pilot_noise = sensors.pilot_pressure_noise_std
        if pilot_noise is None:
            raise InputError(f"independent arm: {machine.source} has mobile valves and no sensors.pilot_pressure_noise_std")

        def pilot_transmitter(pressure: np.ndarray) -> np.ndarray:
            return np.clip(pressure + rng.normal(0.0, pilot_noise, pressure.shape), 0.0, None)

        # the load-sensing line carries the highest load the compensators hold their drops above
        drops = np.array([act.valve.compensator_pressure_drop for act in machine.actuators])
        load_sensing = np.clip((run.feeds - drops).max(axis=1), 0.0, None)
        mobile = {"pilot_pressure_1": pilot_transmitter(pilot_max * np.clip(run.pilots, 0.0, None)),
                  "pilot_pressure_2": pilot_transmitter(pilot_max * np.clip(-run.pilots, 0.0, None)),
                  "compensator_pressure": transmitter(run.feeds, zeros[2 * a + 1:3 * a + 1]),
                  "ls_pressure": transmitter(load_sensing[:, None], zeros[3 * a + 1:])[:, 0]}
    return Samples(times=times, joint_position=angle, joint_velocity=velocity, pressure_a=transmitter(chambers[:, :, 0], zeros[:a]),
                   pressure_b=transmitter(chambers[:, :, 1], zeros[a:2 * a]),
                   supply_pressure=transmitter(supplies[:, None], zeros[2 * a:2 * a + 1])[:, 0], valve_command=commands, **mobile)


def recording(machine: Machine, rig_seed: int, work: ArmWork, spread: RigSpread | None = None) -> Samples:
    """What the machine's sensors record of one run of the built arm ``rig_seed``."""
    rig = build_rig(machine, rig_seed, spread)
    return measure(rig, simulate(rig, work), work.seed)


def recording_bag(machine: Machine, path: Path, rig_seed: int, work: ArmWork, spread: RigSpread | None = None,
                  start_s: float = 0.0) -> Path:
    """One run as a contract bag (every joint in one JointState, per-cylinder pressures), its truth in the metadata;
    stamped from ``start_s`` (a recorder's wall time)."""
    samples = recording(machine, rig_seed, work, spread)
    samples.times = samples.times + start_s
    with ContractBagWriter(path, actuators={a.name: a.joint for a in machine.actuators},
                           pressure_variance=machine.sensors.pressure_noise_std ** 2, mobile=machine.mobile) as writer:
        writer.set_truth({"plant": __name__, "machine": machine.name, "rig_seed": rig_seed, "seed": work.seed,
                          "duration_s": work.duration_s, "payload_steps": [list(p) for p in work.payload_steps],
                          "faults": [list(f) for f in work.faults]})
        writer.write_machine_block(samples)
    return path


def work_day(machine: Machine, seeds: Sequence[int], duration_s: float, extra_payload: float = 150.0) -> list[ArmWork]:
    """Runs of fault-free work, every other one picking up ``extra_payload`` kg at a drawn time and setting it down later."""
    base = machine.arm.payload if machine.arm is not None else 0.0
    runs = []
    for seed in seeds:
        rng = np.random.default_rng([seed, 11])
        steps: tuple[tuple[float, float], ...] = ()
        if seed % 2:
            pick = rng.uniform(0.2, 0.5) * duration_s
            steps = ((pick, base + extra_payload), (pick + rng.uniform(0.2, 0.4) * duration_s, base))
        runs.append(ArmWork(duration_s, seed, payload_steps=steps))
    return runs
