"""The crane half of a machine config (``kind: crane``, P-V section 2, P-VI section 2), parsed once into frozen dataclasses.

A crane redundant in its telescope: a planar lift-tilt-extension chain, optionally on a slewing base, each joint driven
by a cylinder (a triangle mount or a linear mapping), point masses on its links, the pump and valves of its
hydraulics, the planner's grid and the tip paths it plans along. :func:`parse_crane` reads the mapping
:func:`hydro_ros.contract.config.read_config` returns; a missing or non-numeric entry is a one-line ConfigError naming
its key; every rule the sections break is refused first, all at once (``check.crane_problems``, what
``hydro-ros machine check`` lists). SI units throughout, as in ``config/k70m.yaml``.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hydro_ros.contract.check import crane_problems, list_entry
from hydro_ros.contract.config import ConfigError, with_overrides
from hydro_ros.contract.machine import Section, refuse_problems


@dataclass(frozen=True)
class CraneLinks:
    lift_length: float
    """[m] L1: lift joint to tilt joint"""
    tilt_offset: float
    """[m] L2: offset of the extension axis from the tilt joint"""
    extension_base: float
    """[m] L3: tilt joint to tip at zero extension"""
    lift_joint: tuple[float, float]
    """[m] (ox, oy): the lift joint from the base axis, horizontally and up"""


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
class PointMass:
    name: str
    link: str
    """``lift`` or ``boom`` (the tilt link with the telescope)"""
    s: float
    """[m] along the link from its joint"""
    moves_with_extension: bool
    """rides on the telescope (its s grows with the extension)"""
    mass: float
    """[kg]"""


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
    """the extension's position, velocity and control grid sizes"""
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
    links: CraneLinks
    joints: tuple[CraneJoint, ...]
    masses: tuple[PointMass, ...]
    extension_friction: ExtensionFriction
    hydraulics: Mapping[str, float]
    """pressures [Pa], flows [m^3/s] and the drive threshold [m/s] of the energy model (P-V eqs. 36-41)"""
    dp: DpSettings
    paths: Mapping[str, Mapping[str, Any]]
    """tip paths by id (``planning.paths.TipPath`` reads one)"""
    controller: Mapping[str, float]
    """overrides of ``planning.controller.CONTROLLER_DEFAULTS``"""
    plant: Mapping[str, float]
    """overrides of the simulated crane's defaults (``sim.closed_loop_crane.PLANT_DEFAULTS``) and its valve table"""
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
        """This crane with a nested patch in the file's terms merged in (a list, such as ``masses``, is replaced)."""
        return parse_crane(with_overrides(dict(self.mapping), dict(overrides)), self.source)

    def with_paths(self, paths: Mapping[str, Mapping[str, Any]]) -> CraneConfig:
        """This crane planning along ``paths`` instead of its own (a study's lines across the workspace)."""
        return replace(self, paths=dict(paths), mapping={**self.mapping, "paths": dict(paths)})


def _joint(section: Section) -> CraneJoint:
    cylinder = section.section("cylinder")
    return CraneJoint(
        name=section.text("name"),
        q_min=section.number("min"),
        q_max=section.number("max"),
        mapping=cylinder.text("mapping", "linear"),
        ratio=cylinder.number("ratio", 1.0),
        la=cylinder.number("la", 0.0),
        lb=cylinder.number("lb", 0.0),
        theta_at_min=cylinder.number("theta_at_min", 0.0),
        sign=cylinder.number("sign", 1.0),
        area_a=cylinder.number("area_a"),
        area_b=cylinder.number("area_b"),
        pump_area_extend=cylinder.number("pump_area_extend"),
        pump_area_retract=cylinder.number("pump_area_retract"),
        differential=cylinder.text("spool", "non_differential") == "differential",
        velocity_max=cylinder.number("velocity_max"),
        acceleration_max=cylinder.number("acceleration_max"),
        constant_force=cylinder.number("constant_force") if "constant_force" in cylinder.node else None,
    )


def _mass(section: Section) -> PointMass:
    link = section.text("link")
    return PointMass(name=section.text("name", link), link=link, s=section.number("s"),
                     moves_with_extension=bool(section.node.get("moves_with_extension", False)), mass=section.number("mass"))


def _entries(top: Section, name: str) -> list[Section]:
    entries = top.node.get(name) or []
    if not isinstance(entries, list):
        raise ConfigError(f"config {top.source}: {name} must be a list")
    return [Section(top.source, list_entry(name, index, entry), entry) for index, entry in enumerate(entries)]


def _numbers(section: Section) -> dict[str, float]:
    return {str(name): section.number(name) for name in section.node}


def parse_crane(config: Mapping[str, Any], source: Path) -> CraneConfig:
    """The crane of a config mapping; ConfigError names its problems (``check.crane_problems``)."""
    refuse_problems(crane_problems(dict(config)), source)
    top = Section(str(source), "", dict(config))
    links = top.section("links")
    friction = top.section("extension_friction", optional=True)
    dp = top.section("dp")
    grid = dp.numbers("grid", 3)
    return CraneConfig(
        name=top.text("machine"),
        source=source,
        base_rotation=bool(config.get("base_rotation", False)),
        gravity=top.number("gravity", 9.81),
        links=CraneLinks(lift_length=links.number("lift_length"), tilt_offset=links.number("tilt_offset", 0.0),
                         extension_base=links.number("extension_base"),
                         lift_joint=(links.number("lift_joint_x"), links.number("lift_joint_y"))),
        joints=tuple(_joint(entry) for entry in _entries(top, "joints")),
        masses=tuple(_mass(entry) for entry in _entries(top, "masses")),
        extension_friction=ExtensionFriction(coulomb=friction.number("coulomb", 0.0), tanh_gain=friction.number("tanh_gain", 2000.0),
                                             steps=tuple((float(low), float(high)) for low, high in friction.node.get("steps") or [])),
        hydraulics=_numbers(top.section("hydraulics")),
        dp=DpSettings(grid=(int(grid[0]), int(grid[1]), int(grid[2])), sample_time=dp.number("sample_time"),
                      filter_cutoff=dp.number("filter_cutoff")),
        paths=dict(top.section("paths").node),
        controller=_numbers(top.section("controller", optional=True)),
        plant=_numbers(top.section("plant", optional=True)),
        catalog=dict(top.section("catalog", optional=True).node),
        mapping=dict(config),
    )
