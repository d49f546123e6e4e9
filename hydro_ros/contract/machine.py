"""The machine config of a valve-controlled machine (docs/interface.md section 3), parsed once into frozen dataclasses.

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
from dataclasses import MISSING, asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from hydro_ros.contract.check import config_problems, list_entry, refuse_problems
from hydro_ros.contract.config import ConfigError, read_config, unshared, with_overrides
from hydro_ros.contract.names import EFFECT_FORMS, first_form
from hydro_ros.contract.schema import (
    GROUP,
    RULE,
    Arm,
    ArmLink,
    Cylinder,
    Excitation,
    Fluid,
    Friction,
    LinkMass,
    Load,
    Mems,
    Mount,
    Sensors,
    Simulation,
    Slew,
    Valve,
)
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


def _given(declaration: type, section: Section) -> dict[str, Any]:
    """The numbers ``section`` gives for ``declaration``'s ruled fields (``schema.ruled``, the class's own group): each one
    a field without a default requires, and each other one present."""
    out: dict[str, Any] = {}
    for item in fields(declaration):
        if RULE not in item.metadata or item.metadata[GROUP]:
            continue
        if item.name in section.node or (item.default is MISSING and item.default_factory is MISSING):
            value = section.number(item.name)
            out[item.name] = int(value) if isinstance(item.default, int) and not isinstance(item.default, bool) else value
    return out


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
            **_given(Sensors, sensors),
            pressure_range=sensors.numbers("pressure_range", 2),  # type: ignore[arg-type]
            motion_sensor=_choice(sensors, "motion_sensor", ("encoder", "mems"), "encoder"),
            mems=Mems(**_given(Mems, sensors.section("mems"))) if sensors.node.get("motion_sensor") == "mems" else None,
            joint_range=sensors.numbers("joint_range", 2) if "joint_range" in sensors.node else (-math.pi, math.pi),  # type: ignore[arg-type]
        ),
        simulation=Simulation(**_given(Simulation, simulation)),
        excitation=Excitation(
            **_given(Excitation, excitation),
            joint_range=excitation.numbers("joint_range", 2) if "joint_range" in excitation.node else defaults.joint_range,  # type: ignore[arg-type]
            move_speed=excitation.numbers("move_speed", 2) if "move_speed" in excitation.node else defaults.move_speed,  # type: ignore[arg-type]
            rest_time=excitation.numbers("rest_time", 2) if "rest_time" in excitation.node else defaults.rest_time,  # type: ignore[arg-type]
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
        cylinder=Cylinder(**_given(Cylinder, cylinder)),
        mount=parse_mount(mount),
        valve=Valve(
            type=valve_type,
            **_given(Valve, valve),
            kv_poly=dict({notch: kv_poly.numbers(notch, 4) for notch in NOTCHES}),
            centre_leakage=dict({notch: leakage.number(notch) for notch in NOTCHES}),
            compensator_pressure_drop=valve.number("compensator_pressure_drop") if mobile else 0.0,
            pilot_pressure_max=valve.number("pilot_pressure_max") if mobile else 0.0,
            deadzone=valve.number("deadzone", 0.0) if mobile else 0.0,
        ),
        fluid=Fluid(**_given(Fluid, fluid)),
        friction=Friction(**_given(Friction, friction)),
        load=None if arm is not None else Load(**_given(Load, section.section("load"))),
    )


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
            **_given(ArmLink, link),
            joint_range=link.numbers("range", 2),  # type: ignore[arg-type]
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
    return Arm(links=tuple(parsed), origin=origin, slew=slew, **_given(Arm, section))  # type: ignore[arg-type]


def _link_mass(section: Section, index: int) -> LinkMass:
    return LinkMass(name=section.text("name", f"mass{index}"), **_given(LinkMass, section))


def parse_mount(section: Section) -> Mount:
    kind = _choice(section, "kind", ("triangle", "linear"), "triangle")
    if kind == "linear":
        return Mount(0.0, 0.0, 0.0, section.number("theta_offset"), kind, 1.0, section.number("ratio"))
    sign = section.number("sign", 1.0)
    if sign not in (1.0, -1.0):
        raise ConfigError(f"config {section.source}: {section._name('sign')} = {sign:g}: expected 1 or -1")
    l1, l2, l3, theta_offset = (section.number(k) for k in ("l1", "l2", "l3", "theta_offset"))
    return Mount(l1, l2, l3, theta_offset, kind, sign)
