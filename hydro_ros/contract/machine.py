"""The machine config of a valve-controlled machine (contract section 3), parsed once into frozen dataclasses.

``load_machine_config`` reads the YAML (``extends`` and ``fitted`` merged, numbers coerced) and
returns a :class:`Machine`; every library takes the piece it needs (an :class:`Actuator`, its
:class:`Valve`, the :class:`Sensors`). SI units throughout, as in ``config/sam.yaml``. A variant
of a machine (model mismatch, a calibrated model, a named effect) is derived with
:meth:`Machine.with_overrides`, a patch in the file's own terms; :attr:`Machine.mapping` is the
merged file the machine was parsed from, which tools write back.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from hydro_ros.contract.check import config_problems, list_entry, refuse_problems
from hydro_ros.contract.config import ConfigError, read_config, unshared, with_overrides
from hydro_ros.contract.names import EFFECT_FORMS, first_form
from hydro_ros.contract.upgrade import machine_form

NOTCHES = ("PA", "PB", "AT", "BT")
VALVE_TYPES = ("proportional", "mobile")
_REQUIRED = ("machine", "sample_rate_hz", "actuators", "supply_pressure", "tank_pressure", "sensors")


class Section:
    """Typed reads of one mapping of the config; a missing or non-numeric entry names its full key."""

    def __init__(self, source: str, key: str, node: Any) -> None:
        if not isinstance(node, dict):
            raise ConfigError(f"config {source}: {key} must be a mapping")
        self.source, self.key, self.node = source, key, node

    def _name(self, name: str) -> str:
        return f"{self.key}.{name}" if self.key else name

    def number(self, name: str, default: float | None = None) -> float:
        if name not in self.node:
            if default is None:
                raise ConfigError(f"config {self.source}: missing key {self._name(name)}")
            return float(default)
        try:
            return float(self.node[name])
        except (TypeError, ValueError):
            raise ConfigError(f"config {self.source}: {self._name(name)} = {self.node[name]!r} is not a number") from None

    def numbers(self, name: str, count: int | None = None) -> tuple[float, ...]:
        value = self.node.get(name)
        try:
            out = tuple(float(v) for v in value)  # type: ignore[union-attr]  # None is refused as not a list, below
        except (TypeError, ValueError):
            raise ConfigError(f"config {self.source}: {self._name(name)} = {value!r} is not a list of numbers") from None
        if count is not None and len(out) != count:
            raise ConfigError(f"config {self.source}: {self._name(name)} needs {count} numbers, has {len(out)}")
        return out

    def text(self, name: str, default: str | None = None) -> str:
        if name not in self.node:
            if default is None:
                raise ConfigError(f"config {self.source}: missing key {self._name(name)}")
            return default
        return str(self.node[name])

    def section(self, name: str, *, optional: bool = False) -> Section:
        if name not in self.node and optional:
            return Section(self.source, self._name(name), {})
        if name not in self.node:
            raise ConfigError(f"config {self.source}: missing key {self._name(name)}")
        return Section(self.source, self._name(name), self.node[name] if self.node[name] is not None else {})


@dataclass(frozen=True)
class Cylinder:
    piston_diameter: float
    """[m]"""
    rod_diameter: float
    """[m]"""
    stroke: float
    """[m] x_max of P-I eqs. (8)-(9)"""
    dead_volume_a: float
    """[m^3] V0A"""
    dead_volume_b: float
    """[m^3] V0B"""


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
    natural_frequency: float
    """[rad/s] spool omega_n"""
    damping: float
    """[-] spool damping ratio"""
    laminar_band: float
    """[Pa] |dp| below this uses a linearised orifice law"""
    nominal_flow: float
    """[m^3/s] rated flow per notch at ``nominal_pressure_drop``"""
    nominal_pressure_drop: float
    """[Pa]"""
    kv_poly: Mapping[str, tuple[float, ...]]
    """per notch (PA, PB, AT, BT): K_v(xs) = c3 xs^3 + c2 xs^2 + c1 xs + c0 [m^3/(s Pa^0.5)] (P-II Table 1)"""
    centre_leakage: Mapping[str, float]
    """per notch: [m^3/(s Pa)] laminar leakage near the centre (P-I eqs. 13-14)"""
    compensator_pressure_drop: float = 0.0
    """[Pa] mobile valves: regulated drop over the metering notch"""
    pilot_pressure_max: float = 0.0
    """[Pa] mobile valves: pilot pressure at full command"""
    deadzone: float = 0.0
    """[-] main-spool overlap as a fraction of travel"""

    @property
    def mobile(self) -> bool:
        return self.type == "mobile"


@dataclass(frozen=True)
class Fluid:
    oil_bulk_modulus: float
    """[Pa] B_o of P-II eq. (19)"""
    hose_bulk_modulus: float
    """[Pa] B_h"""
    hose_volume: float
    """[m^3] V_h"""


@dataclass(frozen=True)
class Friction:
    """LuGre (P-I eq. 17)."""

    viscous: float
    """[N s/m] b"""
    static: float
    """[N] F_S"""
    coulomb: float
    """[N] F_C"""
    stribeck_velocity: float
    """[m/s] v_s"""
    bristle_stiffness: float
    """[N/m] sigma0"""


@dataclass(frozen=True)
class Load:
    boom_mass: float
    """[kg] m_B"""
    boom_length: float
    """[m] L_B"""
    boom_cog_distance: float
    """[m] boom centre of gravity from the joint, on the load side"""
    left_mass: float
    """[kg] m_L"""
    right_mass: float
    """[kg] m_R"""
    load_distance: float
    """[m] L"""


@dataclass(frozen=True)
class LinkMass:
    """A mass fixed on a link (a prismatic link's masses slide with it)."""

    name: str
    mass: float
    """[kg]"""
    along: float
    """[m] its centre of gravity from the link's joint, along the link (a prismatic link: at zero extension)"""
    across: float = 0.0
    """[m] its centre of gravity to the left of the link's line"""
    inertia: float = 0.0
    """[kg m^2] about its own centre of gravity (0: a point mass)"""


@dataclass(frozen=True)
class ArmLink:
    """A link of a planar serial arm and the joint it turns or slides on."""

    joint: str
    """its joint's name in /joint_states (an actuator's ``joint``)"""
    kind: str
    """``revolute`` (turns relative to the link before it) or ``prismatic`` (slides along the link before it)"""
    length: float
    """[m] from its joint to the next joint along the link (a prismatic link: at zero extension)"""
    joint_range: tuple[float, float]
    """[rad] or [m]: where the joint may go"""
    offset: float = 0.0
    """[m] the next joint to the left of the link's line"""
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
    payload: float = 0.0
    """[kg] at the tip of the last link"""
    slew: Slew | None = None
    """a slewing base under the first link, or None (a planar machine)"""


@dataclass(frozen=True)
class Actuator:
    name: str
    """the actuator's name in topics (``/hydraulics/<name>/...``) and in /hydraulics/valve_commands"""
    joint: str
    """its joint's name in /joint_states"""
    can_slot: int
    """its slot on the machine bus (JOINT<n>_STATE, CYL<n>_PRESSURE, ...)"""
    cylinder: Cylinder
    mount: Mount
    valve: Valve
    fluid: Fluid
    friction: Friction
    load: Load | None
    """what the cylinder carries as a boom of its own; None on a machine with an ``arm:``, whose links carry it
    (``models.serial_arm.equivalent_load`` gives a one-cylinder model its share)"""


@dataclass(frozen=True)
class Mems:
    """P-III's MEMS motion sensor (inclinometer + gyroscope, complementary filter)."""

    inclination_resolution: float
    """[rad]"""
    inclination_noise_std: float
    """[rad]"""
    gyro_resolution: float
    """[rad/s]"""
    gyro_noise_std: float
    """[rad/s]"""
    gyro_bias: float
    """[rad/s]"""
    k_p: float
    """[1/s] complementary-filter proportional gain"""
    k_i: float
    """[1/s^2] complementary-filter integral gain"""


@dataclass(frozen=True)
class Sensors:
    pressure_noise_std: float
    """[Pa] standard deviation of every chamber and supply pressure reading"""
    pressure_range: tuple[float, float]
    """[Pa] readings saturate here"""
    encoder_resolution: float
    """[rad] joint encoder quantisation"""
    velocity_filter_hz: float = 20.0
    """[Hz] first-order low-pass on the differentiated encoder angle"""
    motion_sensor: str = "encoder"
    """``encoder`` or ``mems`` (P-III)"""
    mems: Mems | None = None
    pilot_pressure_noise_std: float | None = None
    """[Pa] mobile valves: pilot and compensator pressure transducers"""
    joint_range: tuple[float, float] = (-math.pi, math.pi)
    """[rad] a joint reading outside this is implausible (a sensor fault, not motion)"""
    joint_velocity_max: float = 5.0
    """[rad/s] a joint rate reading beyond this is implausible"""
    frozen_s: float = 1.0
    """[s] a pressure reading repeating the same value this long, inside its range, is a frozen sensor"""
    pressure_rate_max: float = 5.0e9
    """[Pa/s] a pressure changing faster than this between two samples is implausible (a garbage frame, not hydraulics)"""


@dataclass(frozen=True)
class Simulation:
    """Numerical choices of the simulator, not machine data."""

    substeps: int = 10
    """[-] RK4 steps per sensor sample"""
    end_stop_lower: float = 0.0
    """[m] piston position of the retracted end stop"""
    end_stop_upper: float | None = None
    """[m] piston position of the extended end stop (None: the stroke)"""
    end_stop_stiffness: float = 1.0e8
    """[N/m]"""
    end_stop_damping: float = 2.0e6
    """[N s/m]"""
    cavitation_pressure: float = -9.0e4
    """[Pa] gauge floor of the chamber pressures"""
    initial_joint_position: float = 0.0
    """[rad]"""
    gravity: float = 9.81
    """[m/s^2]"""


@dataclass(frozen=True)
class Excitation:
    """The simulated operator: closed-loop random rest-to-rest moves of the joint."""

    joint_range: tuple[float, float] = (-0.5, 0.5)
    """[rad] targets are drawn uniformly from this range"""
    move_speed: tuple[float, float] = (0.05, 0.2)
    """[rad/s] reference speed of a move"""
    rest_time: tuple[float, float] = (0.5, 3.0)
    """[s] rest between moves"""
    gain: float = 4.0
    """[1/rad] joint error to valve command"""
    max_command: float = 1.0
    """[-] the operator never pushes the lever beyond this fraction"""


@dataclass(frozen=True)
class Machine:
    name: str
    """the machine's name (diagnostics hardware_id, bag truth)"""
    source: Path
    """the file it was read from"""
    sample_rate_hz: float
    """[Hz] sensor and filter rate"""
    supply_pressure: float
    """[Pa] p_S"""
    tank_pressure: float
    """[Pa] p_T"""
    actuators: tuple[Actuator, ...]
    sensors: Sensors
    simulation: Simulation
    excitation: Excitation
    effects: Mapping[str, float]
    """physical effects present from t = 0 (written by ``hydro-ros discrepancy``), contract effect names"""
    effect_forms: Mapping[str, str]
    """the physical form of an effect where it is not its family's first (``names.EFFECT_FORMS``)"""
    fdi: Mapping[str, Any]
    """the ``fdi:`` section; :class:`hydro_ros.fdi.settings.FdiSettings` types it with the method it tunes"""
    dbc: str
    """the machine bus description (DBC), relative to the config's directory"""
    can_latency_limit: float
    """[s] how late a sensor cycle's frames may reach the host and still be numbered right (``hydro_ros.can.clock``)"""
    can_map: Mapping[str, Any] | None
    """which DBC signal carries each quantity (``hydro_ros.can.codec``); None: hydro_ros's own bus layout"""
    arm: Arm | None
    """the links the cylinders move (``arm:``), None: each actuator is a boom of its own carrying its ``load``"""
    mapping: Mapping[str, Any] = field(repr=False, compare=False)
    """the merged file this machine was parsed from (plain dicts here and above: a Machine crosses process pools)"""

    @property
    def actuator_names(self) -> list[str]:
        return [a.name for a in self.actuators]

    @property
    def planned(self) -> bool:
        """A machine with a ``planner:`` section: it works the planner's paths (``contract.crane``), its cylinders moving the
        chain the planner plans."""
        return "planner" in self.mapping

    @property
    def first(self) -> Actuator:
        """The actuator of a one-actuator machine (the SAM), or the first of several."""
        return self.actuators[0]

    def actuator(self, name: str) -> Actuator:
        for actuator in self.actuators:
            if actuator.name == name:
                return actuator
        raise ConfigError(f"config {self.source}: no actuator {name!r} (known: {', '.join(self.actuator_names)})")

    @property
    def mobile(self) -> bool:
        """Whether the valves are pressure-compensated mobile valves (pilot and compensator pressures measured)."""
        return any(a.valve.mobile for a in self.actuators)

    def only(self, actuator: str, load: Load) -> Machine:
        """This machine with only ``actuator``, carrying ``load`` (a study of one cylinder on a machine of several: its own
        load, or its share of the arm, ``models.serial_arm.machine_load``)."""
        self.actuator(actuator)
        mapping = unshared(dict(self.mapping))
        mapping["actuators"] = {actuator: mapping["actuators"][actuator]}
        mapping["actuators"][actuator]["load"] = asdict(load)
        mapping.pop("arm", None)
        mapping.pop("planner", None)
        can_map = (mapping.get("can") or {}).get("map") or {}
        if "actuators" in can_map:
            can_map["actuators"] = {name: entry for name, entry in can_map["actuators"].items() if name == actuator}
        return parse_machine(mapping, self.source)

    def with_overrides(self, overrides: Mapping[str, Any]) -> Machine:
        """This machine with a nested patch in the config file's terms merged in (model mismatch, calibration, effects)."""
        return parse_machine(with_overrides(dict(self.mapping), overrides), self.source)

    def to_yaml_mapping(self) -> dict[str, Any]:
        """A deep, writable copy of the merged config (what ``yaml.safe_dump`` writes back)."""
        copied: dict[str, Any] = unshared(dict(self.mapping))
        return copied


def load_machine_config(path: str | Path) -> Machine:
    """Read and parse a valve-controlled machine's ``config/<machine>.yaml``; ConfigError names a bad key."""
    path = Path(path)
    return parse_machine(read_config(path, required=_REQUIRED, nonempty="actuators"), path.resolve())


def parse_machine(config: dict[str, Any], source: Path) -> Machine:
    config = machine_form(config, source)
    refuse_problems(config_problems(config), source)
    top = Section(str(source), "", config)
    missing = [key for key in _REQUIRED if key not in config]
    if missing:
        raise ConfigError(f"config {source}: missing key(s) {', '.join(missing)}")
    actuators = top.section("actuators")
    if not actuators.node:
        raise ConfigError(f"config {source}: no actuators")
    arm = parse_arm(top.section("arm")) if "arm" in config else None
    parsed = tuple(_actuator(actuators.section(name), str(name), index, arm) for index, name in enumerate(actuators.node, start=1))
    sensors = top.section("sensors")
    simulation = top.section("simulation", optional=True)
    excitation = top.section("excitation", optional=True)
    defaults = Excitation()
    effects = top.section("effects", optional=True)
    can = top.section("can", optional=True)
    return Machine(
        name=top.text("machine"),
        source=source,
        sample_rate_hz=top.number("sample_rate_hz"),
        supply_pressure=top.number("supply_pressure"),
        tank_pressure=top.number("tank_pressure"),
        actuators=parsed,
        sensors=Sensors(
            pressure_noise_std=sensors.number("pressure_noise_std"),
            pressure_range=sensors.numbers("pressure_range", 2),  # type: ignore[arg-type]
            encoder_resolution=sensors.number("encoder_resolution"),
            velocity_filter_hz=sensors.number("velocity_filter_hz", 20.0),
            motion_sensor=_choice(sensors, "motion_sensor", ("encoder", "mems"), "encoder"),
            mems=_mems(sensors.section("mems")) if sensors.node.get("motion_sensor") == "mems" else None,
            pilot_pressure_noise_std=sensors.number("pilot_pressure_noise_std") if "pilot_pressure_noise_std" in sensors.node else None,
            joint_range=sensors.numbers("joint_range", 2) if "joint_range" in sensors.node else (-math.pi, math.pi),  # type: ignore[arg-type]
            joint_velocity_max=sensors.number("joint_velocity_max", 5.0),
            frozen_s=sensors.number("frozen_s", 1.0),
            pressure_rate_max=sensors.number("pressure_rate_max", 5.0e9),
        ),
        simulation=Simulation(
            substeps=int(simulation.number("substeps", 10)),
            end_stop_lower=simulation.number("end_stop_lower", 0.0),
            end_stop_upper=simulation.number("end_stop_upper") if "end_stop_upper" in simulation.node else None,
            end_stop_stiffness=simulation.number("end_stop_stiffness", 1.0e8),
            end_stop_damping=simulation.number("end_stop_damping", 2.0e6),
            cavitation_pressure=simulation.number("cavitation_pressure", -9.0e4),
            initial_joint_position=simulation.number("initial_joint_position", 0.0),
            gravity=simulation.number("gravity", 9.81),
        ),
        excitation=Excitation(
            joint_range=excitation.numbers("joint_range", 2) if "joint_range" in excitation.node else defaults.joint_range,  # type: ignore[arg-type]
            move_speed=excitation.numbers("move_speed", 2) if "move_speed" in excitation.node else defaults.move_speed,  # type: ignore[arg-type]
            rest_time=excitation.numbers("rest_time", 2) if "rest_time" in excitation.node else defaults.rest_time,  # type: ignore[arg-type]
            gain=excitation.number("gain", defaults.gain),
            max_command=excitation.number("max_command", defaults.max_command),
        ),
        effects=dict({str(name): effects.number(name) for name in effects.node}),
        effect_forms=_effect_forms(top.section("effect_forms", optional=True)),
        fdi=dict(dict(top.section("fdi", optional=True).node)),
        dbc=can.text("dbc", "machine_bus.dbc"),
        can_latency_limit=can.number("latency_limit", 0.02),
        can_map=dict(can.node["map"]) if isinstance(can.node.get("map"), dict) else None,
        arm=arm,
        mapping=dict(config),
    )


def _effect_forms(section: Section) -> dict[str, str]:
    forms = {}
    for name in section.node:
        if str(name) not in EFFECT_FORMS:
            raise ConfigError(f"config {section.source}: {section._name(name)}: no effect with forms (those with: {', '.join(EFFECT_FORMS)})")
        forms[str(name)] = _choice(section, name, tuple(EFFECT_FORMS[str(name)]), first_form(str(name)) or "")
    return forms


def _choice(section: Section, name: str, allowed: tuple[str, ...], default: str) -> str:
    value = section.text(name, default)
    if value not in allowed:
        raise ConfigError(f"config {section.source}: {section._name(name)} {value!r}: expected {' or '.join(allowed)}")
    return value


def _actuator(section: Section, name: str, index: int, arm: Arm | None) -> Actuator:
    cylinder, mount, valve = section.section("cylinder"), section.section("mount"), section.section("valve")
    fluid, friction = section.section("fluid"), section.section("friction")
    valve_type = _choice(valve, "type", VALVE_TYPES, "proportional")
    mobile = valve_type == "mobile"
    kv_poly, leakage = valve.section("kv_poly"), valve.section("centre_leakage")
    return Actuator(
        name=name,
        joint=section.text("joint"),
        can_slot=int(section.number("can_slot", index)),
        cylinder=Cylinder(*(cylinder.number(k) for k in ("piston_diameter", "rod_diameter", "stroke", "dead_volume_a", "dead_volume_b"))),
        mount=parse_mount(mount),
        valve=Valve(
            type=valve_type,
            natural_frequency=valve.number("natural_frequency"),
            damping=valve.number("damping"),
            laminar_band=valve.number("laminar_band"),
            nominal_flow=valve.number("nominal_flow"),
            nominal_pressure_drop=valve.number("nominal_pressure_drop"),
            kv_poly=dict({notch: kv_poly.numbers(notch, 4) for notch in NOTCHES}),
            centre_leakage=dict({notch: leakage.number(notch) for notch in NOTCHES}),
            compensator_pressure_drop=valve.number("compensator_pressure_drop") if mobile else 0.0,
            pilot_pressure_max=valve.number("pilot_pressure_max") if mobile else 0.0,
            deadzone=valve.number("deadzone", 0.0) if mobile else 0.0,
        ),
        fluid=Fluid(*(fluid.number(k) for k in ("oil_bulk_modulus", "hose_bulk_modulus", "hose_volume"))),
        friction=Friction(*(friction.number(k) for k in ("viscous", "static", "coulomb", "stribeck_velocity", "bristle_stiffness"))),
        load=None if arm is not None else _load(section.section("load")),
    )


def _load(section: Section) -> Load:
    return Load(*(section.number(k) for k in ("boom_mass", "boom_length", "boom_cog_distance", "left_mass", "right_mass", "load_distance")))


def parse_arm(section: Section) -> Arm:
    links = section.node.get("links")
    if not isinstance(links, list):
        raise ConfigError(f"config {section.source}: arm.links must be a list of links, base to tip")
    parsed = []
    for index, node in enumerate(links):
        link = Section(section.source, list_entry("arm.links", index, node), node)
        masses = link.node.get("masses") or []
        parsed.append(ArmLink(
            joint=link.text("joint"),
            kind=_choice(link, "kind", ("revolute", "prismatic"), "revolute"),
            length=link.number("length"),
            joint_range=link.numbers("range", 2),  # type: ignore[arg-type]
            offset=link.number("offset", 0.0),
            masses=tuple(_link_mass(Section(section.source, list_entry(f"{link.key}.masses", m, mass), mass), m)
                         for m, mass in enumerate(masses)),
        ))
    origin = section.numbers("origin", 2) if "origin" in section.node else (0.0, 0.0)
    slew = None
    if "slew" in section.node:
        node = section.section("slew")
        drive = node.section("drive")
        kind = _choice(drive, "kind", ("rack", "motor"), "rack")
        slew = Slew(node.text("joint"), node.numbers("range", 2), kind,  # type: ignore[arg-type]
                    drive.number("ratio") if kind == "rack" else 1.0, drive.number("area" if kind == "rack" else "displacement"))
    return Arm(links=tuple(parsed), origin=origin, payload=section.number("payload", 0.0), slew=slew)  # type: ignore[arg-type]


def _link_mass(section: Section, index: int) -> LinkMass:
    return LinkMass(name=section.text("name", f"mass{index}"), mass=section.number("mass"), along=section.number("along"),
                    across=section.number("across", 0.0), inertia=section.number("inertia", 0.0))


def parse_mount(section: Section) -> Mount:
    kind = _choice(section, "kind", ("triangle", "linear"), "triangle")
    if kind == "linear":
        return Mount(0.0, 0.0, 0.0, section.number("theta_offset"), kind, 1.0, section.number("ratio"))
    sign = section.number("sign", 1.0)
    if sign not in (1.0, -1.0):
        raise ConfigError(f"config {section.source}: {section._name('sign')} = {sign:g}: expected 1 or -1")
    l1, l2, l3, theta_offset = (section.number(k) for k in ("l1", "l2", "l3", "theta_offset"))
    return Mount(l1, l2, l3, theta_offset, kind, sign)


def _mems(section: Section) -> Mems:
    return Mems(*(section.number(k) for k in ("inclination_resolution", "inclination_noise_std", "gyro_resolution", "gyro_noise_std",
                                                "gyro_bias", "k_p", "k_i")))
