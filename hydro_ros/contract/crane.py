"""What the planner reads of a machine, parsed once into frozen dataclasses (P-V Section 2, P-VI Sections 2-3).

A planar chain of three joints redundant in one of them along a planar tip path, optionally on a slewing base, each
joint driven by a cylinder (a triangle mount or a linear mapping), masses on its links, the pump and valves of its
hydraulics, the planner's grid and the tip paths it plans along. It is read from the machine's one description: the
chain and its masses in ``arm:`` (with ``arm.slew``), each cylinder in ``actuators:`` (the monitor's: its bore and mount),
and a ``planner:`` section beside them (which joint is redundant, the rate limits, hydraulics, grid, paths), as
``config/k70m.yaml`` and ``config/excavator.yaml`` are. The crane form of earlier releases (``kind: crane``) is read
converted (``contract.upgrade``).

A missing or non-numeric entry is a one-line ConfigError naming its key; every rule the sections break is refused
first, all at once (``check.planner_problems``, what ``hydro-ros machine check`` lists). SI units throughout.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hydro_ros.contract.check import PLANNER_CONTROLLER, PLANNER_PLANT, defaults, planner_problems, refuse_problems
from hydro_ros.contract.config import ConfigError, with_overrides
from hydro_ros.contract.machine import Section, parse_arm, parse_mount
from hydro_ros.contract.schema import Arm, ArmLink, Slew
from hydro_ros.contract.upgrade import machine_form

# the planner's controller and plant sections over their defaults (declared with their rules in ``check``)
CONTROLLER_DEFAULTS = defaults(PLANNER_CONTROLLER)
PLANT_DEFAULTS = defaults(PLANNER_PLANT)


@dataclass(frozen=True)
class CraneJoint:
    """A joint, its limits and how it drives its cylinder (stroke measured from the retracted end)."""

    name: str
    q_min: float
    """[rad] or [m] (a linear joint)"""
    q_max: float
    mapping: str
    """``linear`` (c = ratio (q - q_min)) or ``triangle`` (the cylinder is a side of a triangle of sides la, lb)"""
    ratio: float
    """[m/rad] or [-] of a linear mapping"""
    la: float
    """[m] a triangle's side from the joint to the cylinder's base"""
    lb: float
    """[m] a triangle's side from the joint to the rod's end"""
    theta_at_min: float
    """[rad] the triangle's angle at the joint when q = q_min"""
    sign: float
    """+1 when the angle grows with q, -1 when it shrinks"""
    area_a: float
    """[m^2] piston side"""
    area_b: float
    """[m^2] rod side"""
    pump_area_extend: float
    """[m^2] the area the pump fills while the cylinder extends"""
    pump_area_retract: float
    """[m^2] while it retracts (0: lowered by gravity, rod side to tank)"""
    differential: bool
    """a differential spool: the pump fills only A_A - A_B on extension"""
    velocity_max: float
    """[m/s] of the cylinder"""
    acceleration_max: float
    """[m/s^2] of the cylinder"""
    constant_force: float | None
    """[N] an identified constant in place of the joint's dynamics (P-VI's slewing base), or None"""


@dataclass(frozen=True)
class ExtensionFriction:
    coulomb: float = 0.0
    """[N]"""
    tanh_gain: float = 2000.0
    """[s/m] smoothing of the friction's sign"""
    steps: tuple[tuple[float, float], ...] = ()
    """[m] ramps of one more coulomb per metre between two extensions, where the telescope's pads change"""


@dataclass(frozen=True)
class DpSettings:
    grid: tuple[int, int, int]
    """the redundant cylinder's position, velocity and control grid sizes"""
    sample_time: float
    """[s] of the stages"""
    filter_cutoff: float
    """[Hz] of the zero-phase low-pass of the planned reference"""


@dataclass(frozen=True)
class CraneConfig:
    name: str
    source: Path
    """the file it was read from"""
    base_rotation: bool
    """a first joint turns the planar chain about the vertical axis"""
    gravity: float
    """[m/s^2] along -y"""
    arm: Arm
    """the planar chain and its masses, base to tip (the slewing base not among its links)"""
    joints: tuple[CraneJoint, ...]
    """the base (where it turns) and one per link of ``arm``"""
    redundant: int
    """the index in ``joints`` of the joint whose cylinder the planner chooses (the telescope of both papers' cranes)"""
    extension_friction: ExtensionFriction
    """on the redundant joint (P-VI eqs. A3-A4, the telescope's)"""
    hydraulics: Mapping[str, float]
    """pressures [Pa], flows [m^3/s] and the drive threshold [m/s] of the energy model (P-V eqs. 36-41)"""
    dp: DpSettings
    paths: Mapping[str, Mapping[str, Any]]
    """tip paths by id (``planning.paths.TipPath`` reads one)"""
    controller: Mapping[str, float]
    """the closed loop's settings: ``CONTROLLER_DEFAULTS`` with ``planner.controller`` over them"""
    plant: Mapping[str, float]
    """the simulated machine's and its valve table's: ``PLANT_DEFAULTS`` with ``planner.plant`` over them"""
    catalog: Mapping[str, Any]
    """what ``db build`` plans by default (its grid)"""
    mapping: Mapping[str, Any] = field(repr=False, compare=False)
    """the merged file this crane was parsed from"""

    @property
    def joint_names(self) -> list[str]:
        return [joint.name for joint in self.joints]

    def path(self, path_id: str) -> Mapping[str, Any]:
        if path_id not in self.paths:
            raise ConfigError(f"path {path_id!r}: not in config {self.name} (known: {', '.join(sorted(self.paths)) or 'none'})")
        return self.paths[path_id]

    def with_overrides(self, overrides: Mapping[str, Any]) -> CraneConfig:
        """This crane with a nested patch in the file's terms merged in (a list, such as ``arm.links``, is replaced)."""
        return parse_planning(with_overrides(dict(self.mapping), dict(overrides)), self.source)

    def with_paths(self, paths: Mapping[str, Mapping[str, Any]]) -> CraneConfig:
        """This crane planning along ``paths`` instead of its own (a study's lines across the workspace)."""
        return replace(self, paths=dict(paths), mapping={**self.mapping, "planner": {**self.mapping["planner"], "paths": dict(paths)}})


def _numbers(section: Section) -> dict[str, float]:
    return {str(name): section.number(name) for name in section.node}


def parse_planning(config: Mapping[str, Any], source: Path) -> CraneConfig:
    """The planner's view of a config mapping (a ``planner:`` section; the crane form converted, ``contract.upgrade``)."""
    config = machine_form(dict(config), source)
    if "planner" in config:
        return parse_planner(config, source)
    links = config["arm"].get("links") if isinstance(config.get("arm"), dict) else None
    joints = len(links) if isinstance(links, list) else len(config.get("actuators") or {})
    why = ("a planar tip path fixes two joints, so there is no redundancy to optimise" if joints <= 2 else
           f"its {joints} joints may be redundant along a tip path: describe them in arm: and say which one the planner chooses "
           "in a planner: section (as config/excavator.yaml does)")
    raise ConfigError(f"config {source}: nothing to plan (no planner: section): the planner needs one redundant degree of freedom "
                      f"along a planar tip path; {why}")


def _planning_sections(planner: Section) -> dict[str, Any]:
    """The sections both forms share: hydraulics, grid, paths, and the controller's, plant's and catalog's overrides."""
    dp = planner.section("dp")
    grid = dp.numbers("grid", 3)
    return {
        "hydraulics": _numbers(planner.section("hydraulics")),
        "dp": DpSettings(grid=(int(grid[0]), int(grid[1]), int(grid[2])), sample_time=dp.number("sample_time"),
                         filter_cutoff=dp.number("filter_cutoff")),
        "paths": dict(planner.section("paths").node),
        "controller": {**CONTROLLER_DEFAULTS, **_numbers(planner.section("controller", optional=True))},
        "plant": {**PLANT_DEFAULTS, **_numbers(planner.section("plant", optional=True))},
        "catalog": dict(planner.section("catalog", optional=True).node),
    }


def parse_planner(config: Mapping[str, Any], source: Path) -> CraneConfig:
    """The planner's chain of a machine config with ``arm:`` and ``planner:``: each arm link's joint driven by the actuator on
    it (its cylinder's areas and mount), the limits ``planner.actuators`` gives; ConfigError names its problems
    (``check.planner_problems``)."""
    refuse_problems(planner_problems(dict(config)), source)
    top = Section(str(source), "", dict(config))
    planner = top.section("planner")
    arm = parse_arm(top.section("arm"))
    actuators = top.section("actuators")
    limits = planner.section("actuators")
    on_joint = {str(node["joint"]): str(name) for name, node in actuators.node.items()}
    joints = tuple(_actuated_joint(link, actuators.section(on_joint[link.joint]), limits.section(on_joint[link.joint]))
                   for link in arm.links)
    if arm.slew is not None:
        joints = (_slew_joint(arm.slew, limits.section(arm.slew.joint)), *joints)
    redundant = str(actuators.node[planner.text("redundant")]["joint"])
    friction = planner.section("friction", optional=True)
    hydraulics = dict(planner.section("hydraulics").node)
    for key, machine_key in (("supply_pressure_cp", "supply_pressure"), ("tank_pressure", "tank_pressure")):
        if key not in hydraulics:
            hydraulics[key] = top.number(machine_key)
    return CraneConfig(
        name=top.text("machine"),
        source=source,
        base_rotation=arm.slew is not None,
        gravity=top.section("simulation", optional=True).number("gravity", 9.81),
        arm=replace(arm, payload=0.0, slew=None),
        joints=joints,
        redundant=[joint.name for joint in joints].index(redundant),
        extension_friction=ExtensionFriction(coulomb=friction.number("coulomb", 0.0), tanh_gain=friction.number("tanh_gain", 2000.0),
                                             steps=tuple((float(low), float(high)) for low, high in friction.node.get("steps") or [])),
        **_planning_sections(Section(str(source), "planner", {**planner.node, "hydraulics": hydraulics})),
        mapping=dict(config),
    )


def _slew_joint(slew: Slew, limits: Section) -> CraneJoint:
    """The slewing base as the planner sees it: a linear mapping of its angle onto the drive's stroke, the same area either
    way (each direction its own plunger or the motor's two ports)."""
    low, high = slew.joint_range
    return CraneJoint(
        name=slew.joint, q_min=low, q_max=high, mapping="linear", ratio=slew.ratio, la=0.0, lb=0.0, theta_at_min=0.0, sign=1.0,
        area_a=slew.area, area_b=slew.area, pump_area_extend=slew.area, pump_area_retract=slew.area, differential=False,
        velocity_max=limits.number("velocity_max"), acceleration_max=limits.number("acceleration_max"),
        constant_force=limits.number("constant_force") if "constant_force" in limits.node else None,
    )


def _actuated_joint(link: ArmLink, actuator: Section, limits: Section) -> CraneJoint:
    """A link's joint as the planner sees it: the range, the mount's stroke (retracted end at the range's end where the
    cylinder is shortest), the cylinder's areas, the pump's areas and the planner's rate limits."""
    cylinder, mount = actuator.section("cylinder"), parse_mount(actuator.section("mount"))
    area_a = math.pi * cylinder.number("piston_diameter") ** 2 / 4.0
    area_b = area_a - math.pi * cylinder.number("rod_diameter") ** 2 / 4.0
    differential = limits.text("spool", "non_differential") == "differential"
    q_min, q_max = link.joint_range
    return CraneJoint(
        name=link.joint, q_min=q_min, q_max=q_max, mapping=mount.kind, ratio=mount.ratio, la=mount.l1, lb=mount.l2,
        theta_at_min=mount.sign * q_min + mount.theta_offset, sign=mount.sign, area_a=area_a, area_b=area_b,
        pump_area_extend=area_a - area_b if differential else area_a,
        pump_area_retract=0.0 if limits.node.get("lowered_by_gravity", False) is True else area_b,
        differential=differential, velocity_max=limits.number("velocity_max"), acceleration_max=limits.number("acceleration_max"),
        constant_force=None,
    )
