"""What a machine config's values may be, declared once on the dataclass fields that hold them.

The sections of a machine config are the dataclasses below (:mod:`hydro_ros.contract.machine` parses a file into them
and a ``Machine``). A field a config gives as a number carries its :class:`Rule`
(unit, plausible range, what a value outside usually means) in its metadata (:func:`ruled`); its default is the
field's. :mod:`hydro_ros.contract.check` reads its tables off the fields (:func:`rules_of`), the parser reads the
numbers they name, and docs/reference/config.md is written from the same tables. The ranges are physical
plausibility for heavy-duty hydraulics in SI units, wide on purpose: they catch a value in the wrong unit (a bore in
mm, a pressure in bar) or with the wrong sign, not a design.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from typing import Any

RULE = "hydro_ros.rule"
GROUP = "hydro_ros.rule_group"


@dataclass(frozen=True)
class Rule:
    unit: str
    low: float | None = None  # inclusive unless open_low
    high: float | None = None
    open_low: bool = False
    hint: str = ""  # what a value outside usually means
    default: float | None = None  # the value an optional section's key takes when not given

    def broken(self, value: float) -> str | None:
        if not math.isfinite(value):
            return "must be finite"
        if self.low is not None and (value < self.low or (self.open_low and value == self.low)):
            return f"must be {'>' if self.open_low else '>='} {self.low:g} {self.unit}".rstrip() + (f" ({self.hint})" if self.hint else "")
        if self.high is not None and value > self.high:
            return f"must be <= {self.high:g} {self.unit}".rstrip() + (f" ({self.hint})" if self.hint else "")
        return None


def positive(unit: str, high: float | None = None, hint: str = "") -> Rule:
    return Rule(unit, 0.0, high, open_low=True, hint=hint)


def nonnegative(unit: str, high: float | None = None, hint: str = "") -> Rule:
    return Rule(unit, 0.0, high, hint=hint)


PRESSURE = Rule("Pa", 1.0e5, 7.0e7, hint="SI: 10 MPa is 10.0e+6; a smaller value looks like MPa or bar")


def ruled(rule: Rule, group: str = "") -> dict[str, Any]:
    """The metadata of a dataclass field a config gives as a number (``field(metadata=ruled(...))``), checked by ``rule``;
    ``group`` names a set of a class's fields that are checked apart (a mobile valve's)."""
    return {RULE: rule, GROUP: group}


def rules_of(declaration: type, group: str = "") -> dict[str, Rule]:
    """The rules of ``declaration``'s ruled fields of ``group``, in field order, each with its field's default where that
    is a number the rule accepts (a mobile valve's compensator drop defaults to 0 only as "no compensator": required
    where there is one): a config section's table."""
    return {item.name: _with_default(item.metadata[RULE], item.default)
            for item in fields(declaration) if RULE in item.metadata and item.metadata[GROUP] == group}


def _with_default(rule: Rule, default: Any) -> Rule:
    if isinstance(default, (int, float)) and rule.broken(float(default)) is None:
        return replace(rule, default=float(default))
    return rule


@dataclass(frozen=True)
class Cylinder:
    piston_diameter: float = field(metadata=ruled(Rule("m", 0.005, 1.0, hint="SI: an 80 mm bore is 0.080")))
    rod_diameter: float = field(metadata=ruled(positive("m", 1.0, hint="SI: a 45 mm rod is 0.045")))
    stroke: float = field(metadata=ruled(positive("m", 20.0, hint="SI: metres")))
    """x_max of P-I eqs. (8)-(9)"""
    dead_volume_a: float = field(metadata=ruled(nonnegative("m^3", 0.1)))
    """V0A"""
    dead_volume_b: float = field(metadata=ruled(nonnegative("m^3", 0.1)))
    """V0B"""


@dataclass(frozen=True)
class Mount:
    """How the piston follows the joint. ``triangle``: cylinder length = sqrt(l1^2 + l2^2 - 2 l1 l2 cos(theta)),
    x = length - l3 (P-I eq. 3), theta = sign joint + theta_offset; ``linear``: x = ratio (joint + theta_offset)."""

    l1: float
    """[m] upper cylinder joint to boom joint"""
    l2: float
    """[m] lower cylinder joint to boom joint"""
    l3: float
    """[m] cylinder length at x = 0"""
    theta_offset: float
    """[rad] theta = sign joint position + theta_offset (linear: [joint unit] added to the joint)"""
    kind: str = "triangle"
    """``triangle`` (a cylinder between two links) or ``linear`` (a telescope, a rack)"""
    sign: float = 1.0
    """+1: the triangle opens as the joint opens; -1: as it closes (P-VI's tilt)"""
    ratio: float = 1.0
    """linear: [m per joint unit]"""


@dataclass(frozen=True)
class Valve:
    type: str
    """``proportional`` (servo-solenoid, P-I..P-III) or ``mobile`` (pressure-compensated, pilot-operated, P-IV)"""
    natural_frequency: float = field(metadata=ruled(positive("rad/s", 1.0e4)))
    """spool omega_n"""
    damping: float = field(metadata=ruled(positive("", 100.0)))
    """spool damping ratio"""
    laminar_band: float = field(metadata=ruled(positive("Pa", 1.0e7)))
    """|dp| below this uses a linearised orifice law"""
    nominal_flow: float = field(metadata=ruled(positive("m^3/s", 0.1, hint="SI: 24 L/min is 4.0e-4")))
    """rated flow per notch at ``nominal_pressure_drop``"""
    nominal_pressure_drop: float = field(metadata=ruled(Rule("Pa", 1.0e4, 7.0e7)))
    kv_poly: Mapping[str, tuple[float, ...]]
    """per notch (PA, PB, AT, BT): K_v(xs) = c3 xs^3 + c2 xs^2 + c1 xs + c0 [m^3/(s Pa^0.5)] (P-II Table 1)"""
    centre_leakage: Mapping[str, float]
    """per notch: [m^3/(s Pa)] laminar leakage near the centre (P-I eqs. 13-14)"""
    compensator_pressure_drop: float = field(default=0.0, metadata=ruled(Rule("Pa", 1.0e4, 1.0e7), group="mobile"))
    """mobile valves: regulated drop over the metering notch"""
    pilot_pressure_max: float = field(default=0.0, metadata=ruled(Rule("Pa", 1.0e4, 1.0e7), group="mobile"))
    """mobile valves: pilot pressure at full command"""
    deadzone: float = field(default=0.0, metadata=ruled(Rule("", 0.0, 0.9, hint="a fraction of the spool's travel"), group="mobile"))
    """main-spool overlap as a fraction of travel"""

    @property
    def mobile(self) -> bool:
        return self.type == "mobile"


@dataclass(frozen=True)
class Fluid:
    oil_bulk_modulus: float = field(metadata=ruled(Rule("Pa", 1.0e7, 1.0e10, hint="SI: 1.4 GPa is 1.4e+9")))
    """B_o of P-II eq. (19)"""
    hose_bulk_modulus: float = field(metadata=ruled(Rule("Pa", 1.0e6, 1.0e11)))
    """B_h"""
    hose_volume: float = field(metadata=ruled(nonnegative("m^3", 0.1)))
    """V_h"""


@dataclass(frozen=True)
class Friction:
    """LuGre (P-I eq. 17)."""

    viscous: float = field(metadata=ruled(nonnegative("N s/m")))
    """b"""
    static: float = field(metadata=ruled(nonnegative("N")))
    """F_S"""
    coulomb: float = field(metadata=ruled(nonnegative("N")))
    """F_C"""
    stribeck_velocity: float = field(metadata=ruled(positive("m/s", 10.0)))
    """v_s"""
    bristle_stiffness: float = field(metadata=ruled(nonnegative("N/m")))
    """sigma0"""


@dataclass(frozen=True)
class Load:
    boom_mass: float = field(metadata=ruled(nonnegative("kg", 1.0e6)))
    """m_B"""
    boom_length: float = field(metadata=ruled(positive("m", 100.0)))
    """L_B"""
    boom_cog_distance: float = field(metadata=ruled(Rule("m", -100.0, 100.0)))
    """boom centre of gravity from the joint, on the load side"""
    left_mass: float = field(metadata=ruled(nonnegative("kg", 1.0e6)))
    """m_L"""
    right_mass: float = field(metadata=ruled(nonnegative("kg", 1.0e6)))
    """m_R"""
    load_distance: float = field(metadata=ruled(Rule("m", -100.0, 100.0)))
    """L"""


@dataclass(frozen=True)
class LinkMass:
    """A mass fixed on a link (a prismatic link's masses slide with it)."""

    name: str
    mass: float = field(metadata=ruled(nonnegative("kg", 1.0e6)))
    along: float = field(metadata=ruled(Rule("m", -100.0, 100.0)))
    """its centre of gravity from the link's joint, along the link (a prismatic link: at zero extension)"""
    across: float = field(default=0.0, metadata=ruled(Rule("m", -100.0, 100.0)))
    """its centre of gravity to the left of the link's line"""
    inertia: float = field(default=0.0, metadata=ruled(nonnegative("kg m^2", 1.0e7)))
    """about its own centre of gravity (0: a point mass)"""


@dataclass(frozen=True)
class ArmLink:
    """A link of a planar serial arm and the joint it turns or slides on."""

    joint: str
    """its joint's name in /joint_states (an actuator's ``joint``)"""
    kind: str
    """``revolute`` (turns relative to the link before it) or ``prismatic`` (slides along the link before it)"""
    length: float = field(metadata=ruled(Rule("m", 0.0, 100.0, hint="SI: metres")))
    """from its joint to the next joint along the link (a prismatic link: at zero extension)"""
    joint_range: tuple[float, float]
    """[rad] or [m]: where the joint may go"""
    offset: float = field(default=0.0, metadata=ruled(Rule("m", -100.0, 100.0)))
    """the next joint to the left of the link's line"""
    masses: tuple[LinkMass, ...] = ()


@dataclass(frozen=True)
class Slew:
    """A base turning the planar links about the vertical axis (``arm.slew``), and what drives it: the P-VI crane's rack
    and pinion (two plungers: a stroke of ``ratio`` metres per radian on ``area`` either way) or a hydraulic motor (its
    ``displacement`` per radian as ``area``, ``ratio`` 1). Described for the planner (the flow and force of turning); the
    monitor and the simulators of the cylinders do not model it."""

    joint: str
    joint_range: tuple[float, float]
    """[rad]"""
    drive: str
    """``rack`` or ``motor``"""
    ratio: float
    """[m/rad] a rack's stroke per radian; 1 for a motor"""
    area: float
    """[m^2] a plunger's area, or [m^3/rad] a motor's displacement"""


@dataclass(frozen=True)
class Arm:
    """The links the cylinders move, base to tip (``arm:``): the simulator couples their dynamics."""

    links: tuple[ArmLink, ...]
    origin: tuple[float, float] = (0.0, 0.0)
    """[m] the first joint, horizontally and up from the base"""
    payload: float = field(default=0.0, metadata=ruled(nonnegative("kg", 1.0e6)))
    """at the tip of the last link"""
    slew: Slew | None = None
    """a slewing base under the first link, or None (a planar machine)"""


@dataclass(frozen=True)
class Mems:
    """P-III's MEMS motion sensor (inclinometer + gyroscope, complementary filter)."""

    inclination_resolution: float = field(metadata=ruled(nonnegative("rad")))
    inclination_noise_std: float = field(metadata=ruled(nonnegative("rad")))
    gyro_resolution: float = field(metadata=ruled(nonnegative("rad/s")))
    gyro_noise_std: float = field(metadata=ruled(nonnegative("rad/s")))
    gyro_bias: float = field(metadata=ruled(Rule("rad/s", -1.0, 1.0)))
    k_p: float = field(metadata=ruled(positive("1/s")))
    """complementary-filter proportional gain"""
    k_i: float = field(metadata=ruled(nonnegative("1/s^2")))
    """complementary-filter integral gain"""


@dataclass(frozen=True)
class Sensors:
    pressure_noise_std: float = field(metadata=ruled(nonnegative("Pa", 1.0e7)))
    """standard deviation of every chamber and supply pressure reading"""
    pressure_range: tuple[float, float]
    """[Pa] readings saturate here"""
    encoder_resolution: float = field(metadata=ruled(nonnegative("rad", 0.5)))
    """joint encoder quantisation"""
    velocity_filter_hz: float = field(default=20.0, metadata=ruled(positive("Hz", 1.0e4)))
    """first-order low-pass on the differentiated encoder angle"""
    motion_sensor: str = "encoder"
    """``encoder`` or ``mems`` (P-III)"""
    mems: Mems | None = None
    pilot_pressure_noise_std: float | None = field(default=None, metadata=ruled(nonnegative("Pa", 1.0e7)))
    """mobile valves: pilot and compensator pressure transducers"""
    joint_range: tuple[float, float] = (-math.pi, math.pi)
    """[rad] a joint reading outside this is implausible (a sensor fault, not motion)"""
    joint_velocity_max: float = field(default=5.0, metadata=ruled(positive("rad/s", 100.0)))
    """a joint rate reading beyond this is implausible"""
    frozen_s: float = field(default=1.0, metadata=ruled(positive("s", 3600.0)))
    """a pressure reading repeating the same value this long, inside its range, is a frozen sensor"""
    pressure_rate_max: float = field(default=5.0e9, metadata=ruled(positive("Pa/s")))
    """a pressure changing faster than this between two samples is implausible (a garbage frame, not hydraulics)"""


@dataclass(frozen=True)
class Simulation:
    """Numerical choices of the simulator, not machine data."""

    substeps: int = field(default=10, metadata=ruled(Rule("", 1.0, 1000.0)))
    """RK4 steps per sensor sample"""
    end_stop_lower: float = field(default=0.0, metadata=ruled(nonnegative("m", 20.0)))
    """piston position of the retracted end stop"""
    end_stop_upper: float | None = field(default=None, metadata=ruled(positive("m", 20.0)))
    """piston position of the extended end stop (None: the stroke)"""
    end_stop_stiffness: float = field(default=1.0e8, metadata=ruled(positive("N/m")))
    end_stop_damping: float = field(default=2.0e6, metadata=ruled(nonnegative("N s/m")))
    cavitation_pressure: float = field(default=-9.0e4, metadata=ruled(Rule("Pa", -1.0e5, 0.0)))
    """gauge floor of the chamber pressures"""
    initial_joint_position: float = field(default=0.0, metadata=ruled(Rule("rad", -7.0, 7.0)))
    gravity: float = field(default=9.81, metadata=ruled(nonnegative("m/s^2", 100.0)))


@dataclass(frozen=True)
class Excitation:
    """The simulated operator: closed-loop random rest-to-rest moves of the joint."""

    joint_range: tuple[float, float] = (-0.5, 0.5)
    """[rad] targets are drawn uniformly from this range"""
    move_speed: tuple[float, float] = (0.05, 0.2)
    """[rad/s] reference speed of a move"""
    rest_time: tuple[float, float] = (0.5, 3.0)
    """[s] rest between moves"""
    gain: float = field(default=4.0, metadata=ruled(positive("1/rad")))
    """joint error to valve command"""
    max_command: float = field(default=1.0, metadata=ruled(Rule("", 0.0, 1.0, open_low=True)))
    """the operator never pushes the lever beyond this fraction"""
