"""The crane form of a machine config (``kind: crane``: ``links``, ``joints``, ``masses``) in the machine form every tool reads.

Until this package's 2026-11 release a crane was described twice: its chain and cylinders for the planner in the crane
form, its cylinders again in ``actuators:`` for the monitor, kept consistent by a 1 mm check. The machine form describes
each cylinder once (``actuators:``), the chain once (``arm:``, with its slewing base in ``arm.slew``), and what only the
planner needs beside them (``planner:``). :func:`upgraded` converts the old form losslessly: every number the planner or
the monitor read comes out the same (the areas as the bores that give them; a triangle mapping as the mount that
gives its stroke), or it refuses in one line saying which value has no place in the machine form. ``hydro-ros machine
upgrade`` writes the result with the old file's per-value sources (PLACEHOLDER, INFERRED, thesis lines) kept.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import yaml

from hydro_ros.contract.check import crane_problems, keyed_lines, refuse_problems
from hydro_ros.contract.config import ConfigError

AGREEMENT = 1e-3  # [m] a crane-form joint's cylinder and its actuator's mount must give the same stroke to this
AREA_AGREEMENT = 1e-4  # relative: a crane-form area and the one its actuator's bore gives
PLANNER_SECTIONS = ("hydraulics", "dp", "paths", "controller", "plant", "catalog")


def is_crane_form(config: Mapping[str, Any]) -> bool:
    return config.get("kind") == "crane"


def machine_form(config: dict[str, Any], source: Path | str) -> dict[str, Any]:
    """``config`` in the machine form: as it is, or a crane form checked (``check.crane_problems``) and converted, with a
    warning saying how to write the file anew."""
    if not is_crane_form(config):
        return config
    refuse_problems(crane_problems(config), source)
    converted, _ = upgraded(config, str(source))
    warnings.warn(f"config {source}: the crane form (kind: crane) is read converted to the machine form; `hydro-ros machine "
                  f"upgrade {source} --out NEW.yaml` writes it so", FutureWarning, stacklevel=2)
    return converted


def upgraded(config: Mapping[str, Any], source: str) -> tuple[dict[str, Any], dict[str, str]]:
    """The machine form of a crane-form mapping, and where each old key path went (for carrying its comment); a value the
    conversion cannot place refused in one line."""
    try:
        return _upgraded(config, source)
    except (KeyError, TypeError, ValueError, AttributeError, ArithmeticError) as exc:  # what check.crane_problems leaves
        raise ConfigError(f"config {source}: the crane form cannot be converted: {type(exc).__name__} {exc} (every joint's "
                          "cylinder needs its mapping's numbers: la, lb, theta_at_min for a triangle; each actuator its joint, "
                          "cylinder and mount)") from None


def _upgraded(config: Mapping[str, Any], source: str) -> tuple[dict[str, Any], dict[str, str]]:
    moved: dict[str, str] = {}
    for key in ("arm", "planner"):
        if key in config:
            raise ConfigError(f"config {source}: {key}: is the machine form's; a crane-form file (kind: crane) describes its chain in "
                              "links:, joints: and masses: (remove one or the other)")
    joints = config.get("joints")
    links = config.get("links")
    if not isinstance(joints, list) or not isinstance(links, dict) or not all(isinstance(joint, dict) for joint in joints):
        raise ConfigError(f"config {source}: kind: crane without links: and a list of joints: cannot be converted "
                          "(hydro-ros machine check lists what is missing)")
    base_rotation = bool(config.get("base_rotation", False))
    if len(joints) != (4 if base_rotation else 3):
        raise ConfigError(f"config {source}: joints: {len(joints)} entries, a crane has {'4' if base_rotation else '3'} "
                          f"(base_rotation: {base_rotation})")
    out: dict[str, Any] = {key: value for key, value in config.items()
                           if key not in ("kind", "base_rotation", "gravity", "links", "joints", "masses", "extension_friction",
                                          *PLANNER_SECTIONS)}
    actuators = {name: dict(node) for name, node in (config.get("actuators") or {}).items()}
    on_joint = {node.get("joint"): name for name, node in actuators.items()}
    planner: dict[str, Any] = {"redundant": None, "actuators": {}}
    lift, tilt, extension = joints[-3:]
    for index, joint in enumerate(joints[-3:]):
        old = f"joints[{joint['name']}]"
        name = on_joint.get(joint["name"], joint["name"])
        cylinder = joint.get("cylinder") or {}
        mount = _mount(joint, cylinder, f"{old}.cylinder", source)
        bores = _bores(cylinder, f"{old}.cylinder", source)
        if name in actuators:
            _agree(actuators[name], mount, bores, joint, f"{old}.cylinder", source)
        else:
            actuators[name] = {"joint": joint["name"], "cylinder": {**bores, "stroke": _stroke(joint, mount)}, "mount": mount}
        for key, new in (("area_a", "cylinder.piston_diameter"), ("area_b", "cylinder.rod_diameter"), ("mapping", "mount"),
                         *((key, f"mount.{_MOUNT_KEYS[key]}") for key in _MOUNT_KEYS)):
            moved[f"{old}.cylinder.{key}"] = f"actuators.{name}.{new}"
        planner["actuators"][name] = _limits(cylinder, f"{old}.cylinder", source)
        for key in ("velocity_max", "acceleration_max", "spool", "pump_area_extend", "pump_area_retract"):
            moved[f"{old}.cylinder.{key}"] = f"planner.actuators.{name}.{_LIMIT_KEYS.get(key, key)}"
        if index == 2:
            planner["redundant"] = name
    out["actuators"] = actuators
    out["arm"] = _arm(config, links, (lift, tilt, extension), moved)
    if base_rotation:
        base = joints[0]
        cylinder = base.get("cylinder") or {}
        area = float(cylinder.get("area_a", 0.0))
        if any(float(cylinder.get(key, area)) != area for key in ("area_b", "pump_area_extend", "pump_area_retract")) or \
                cylinder.get("mapping", "linear") != "linear" or cylinder.get("spool", "non_differential") != "non_differential":
            raise ConfigError(f"config {source}: joints[{base['name']}].cylinder: a slewing base in the machine form is a rack with one "
                              "area both ways (area_a = area_b = the pump areas, mapping linear), or a motor")
        out["arm"]["slew"] = {"joint": base["name"], "range": [base["min"], base["max"]],
                              "drive": {"kind": "rack", "ratio": cylinder.get("ratio", 1.0), "area": area}}
        limits = {key: cylinder[key] for key in ("velocity_max", "acceleration_max", "constant_force") if key in cylinder}
        planner["actuators"][base["name"]] = limits
        old = f"joints[{base['name']}]"
        moved[f"{old}.cylinder.ratio"] = "arm.slew.drive.ratio"
        moved[f"{old}.cylinder.area_a"] = "arm.slew.drive.area"
        moved[f"{old}.min"] = moved[f"{old}.max"] = "arm.slew.range"
        for key in limits:
            moved[f"{old}.cylinder.{key}"] = f"planner.actuators.{base['name']}.{key}"
    if "extension_friction" in config:
        planner["friction"] = config["extension_friction"]
        for key in config["extension_friction"] or {}:
            moved[f"extension_friction.{key}"] = f"planner.friction.{key}"
    for section in PLANNER_SECTIONS:
        if section in config:
            planner[section] = config[section]
            moved[section] = f"planner.{section}"
    out["planner"] = planner
    simulation = out.get("simulation") or {}
    if "gravity" in config and float(simulation.get("gravity", config["gravity"])) != float(config["gravity"]):
        raise ConfigError(f"config {source}: gravity {config['gravity']} and simulation.gravity {simulation['gravity']} differ; the "
                          "machine form has one (simulation.gravity)")
    if "gravity" in config:
        out["simulation"] = {**simulation, "gravity": config["gravity"]}
        moved["gravity"] = "simulation.gravity"
    if "supply_pressure" not in out:
        out["supply_pressure"] = (config.get("hydraulics") or {}).get("supply_pressure_cp")
        out["tank_pressure"] = (config.get("hydraulics") or {}).get("tank_pressure", 0.0)
    return out, moved


_MOUNT_KEYS = {"la": "l1", "lb": "l2", "sign": "sign", "ratio": "ratio"}  # theta_at_min is another number than theta_offset
_LIMIT_KEYS = {"pump_area_extend": "spool", "pump_area_retract": "lowered_by_gravity"}


def _mount(joint: Mapping[str, Any], cylinder: Mapping[str, Any], path: str, source: str) -> dict[str, Any]:
    """The monitor's mount of a crane-form cylinder mapping: c = ratio (q - q_min) is x = ratio (q + theta_offset); a
    triangle's angle theta_at_min + sign (q - q_min) is sign q + theta_offset, its stroke measured from the shortest length
    over the range (l3)."""
    q_min, q_max = float(joint["min"]), float(joint["max"])
    if cylinder.get("mapping", "linear") == "linear":
        return {"kind": "linear", "ratio": float(cylinder.get("ratio", 1.0)), "theta_offset": -q_min}
    la, lb, sign = float(cylinder["la"]), float(cylinder["lb"]), float(cylinder.get("sign", 1.0))
    theta_offset = float(cylinder["theta_at_min"]) - sign * q_min
    lengths = [math.sqrt(la * la + lb * lb - 2.0 * la * lb * math.cos(sign * q + theta_offset))
               for q in (q_min + (q_max - q_min) * k / 200 for k in range(201))]
    if not lengths:
        raise ConfigError(f"config {source}: {path}: no range to convert")
    mount: dict[str, Any] = {"l1": la, "l2": lb, "l3": min(lengths), "theta_offset": theta_offset}
    if sign != 1.0:
        mount["sign"] = sign
    return mount


def _stroke(joint: Mapping[str, Any], mount: Mapping[str, Any]) -> float:
    q_min, q_max = float(joint["min"]), float(joint["max"])
    return abs(_piston(mount, q_max) - _piston(mount, q_min))


def _piston(mount: Mapping[str, Any], q: float) -> float:
    if mount.get("kind") == "linear":
        return float(mount["ratio"]) * (q + float(mount["theta_offset"]))
    la, lb = float(mount["l1"]), float(mount["l2"])
    return math.sqrt(la * la + lb * lb - 2.0 * la * lb * math.cos(float(mount.get("sign", 1.0)) * q + float(mount["theta_offset"]))) \
        - float(mount["l3"])


def _bores(cylinder: Mapping[str, Any], path: str, source: str) -> dict[str, float]:
    area_a, area_b = float(cylinder["area_a"]), float(cylinder["area_b"])
    if not 0.0 < area_b < area_a:
        raise ConfigError(f"config {source}: {path}: area_b {area_b:g} m^2 must lie between 0 and area_a {area_a:g} m^2 to be a "
                          "cylinder with a rod (the machine form describes bores)")
    return {"piston_diameter": math.sqrt(4.0 * area_a / math.pi), "rod_diameter": math.sqrt(4.0 * (area_a - area_b) / math.pi)}


def _agree(actuator: Mapping[str, Any], mount: Mapping[str, Any], bores: Mapping[str, float], joint: Mapping[str, Any], path: str,
           source: str) -> None:
    """A crane-form joint whose actuator the file describes as well: both must be the same cylinder (the old 1 mm check)."""
    own, cylinder = actuator.get("mount") or {}, actuator.get("cylinder") or {}
    for key in ("piston_diameter", "rod_diameter"):
        area = math.pi * float(cylinder.get(key, math.nan)) ** 2
        if not abs(area - math.pi * bores[key] ** 2) <= AREA_AGREEMENT * math.pi * bores["piston_diameter"] ** 2:
            raise ConfigError(f"config {source}: {path}: its areas and actuator {actuator.get('joint')}'s {key} describe different "
                              "cylinders; one cylinder, one description")
    span = [float(joint["min"]) + (float(joint["max"]) - float(joint["min"])) * k / 50 for k in range(51)]
    full = {"kind": own.get("kind", "triangle"), "sign": own.get("sign", 1.0), **own}
    # the piston as the monitor places it (from the actuator's l3) against the crane form's stroke from its shortest length
    gap = max(abs(_piston(full, q) - _piston(mount, q)) for q in span)
    if gap > AGREEMENT:
        raise ConfigError(f"config {source}: {path}: its mapping and actuator {actuator.get('joint')}'s mount differ by "
                          f"{gap * 1000:.1f} mm over the range; one cylinder, one geometry")


def _limits(cylinder: Mapping[str, Any], path: str, source: str) -> dict[str, Any]:
    """The planner's limits of a crane-form cylinder; its pump areas must be those the machine form derives (the piston
    side, or A_A - A_B for a differential spool; the rod side, or none when gravity lowers it)."""
    area_a, area_b = float(cylinder["area_a"]), float(cylinder["area_b"])
    differential = cylinder.get("spool", "non_differential") == "differential"
    lowered = float(cylinder["pump_area_retract"]) == 0.0
    derived = (area_a - area_b if differential else area_a, 0.0 if lowered else area_b)
    given = (float(cylinder["pump_area_extend"]), float(cylinder["pump_area_retract"]))
    if any(abs(g - d) > AREA_AGREEMENT * area_a for g, d in zip(given, derived)):
        raise ConfigError(f"config {source}: {path}: pump areas {given[0]:g}, {given[1]:g} m^2 are not the machine form's "
                          f"({derived[0]:g}, {derived[1]:g}: the piston side or A_A - A_B with spool: differential; the rod side "
                          "or 0 when lowered by gravity)")
    limits: dict[str, Any] = {"velocity_max": cylinder["velocity_max"], "acceleration_max": cylinder["acceleration_max"]}
    if differential:
        limits["spool"] = "differential"
    if lowered:
        limits["lowered_by_gravity"] = True
    return limits


def _arm(config: Mapping[str, Any], links: Mapping[str, Any], joints: tuple[Mapping[str, Any], ...],
         moved: dict[str, str]) -> dict[str, Any]:
    """The crane's lift link, its tilt link (the masses on the extension's axis, L2 from the tilt joint) and its telescope
    sliding on it from ``extension_base`` with the masses that ride on it."""
    lift, tilt, extension = joints
    offset = float(links.get("tilt_offset", 0.0))
    on: dict[str, list[dict[str, Any]]] = {"lift": [], "tilt": [], "telescope": []}
    index = {"lift": 0, "tilt": 1, "telescope": 2}
    for mass in config.get("masses") or []:
        link = "lift" if mass.get("link") == "lift" else "telescope" if mass.get("moves_with_extension", False) else "tilt"
        entry = {"name": mass.get("name", mass.get("link")), "mass": mass["mass"], "along": mass["s"]}
        if link != "lift" and offset:
            entry["across"] = offset
        moved[f"masses[{entry['name']}].s"] = f"arm.links[{joints[index[link]]['name']}].masses[{entry['name']}].along"
        moved[f"masses[{entry['name']}].mass"] = f"arm.links[{joints[index[link]]['name']}].masses[{entry['name']}].mass"
        on[link].append(entry)
    for key, new in (("lift_length", f"arm.links[{lift['name']}].length"), ("extension_base", f"arm.links[{extension['name']}].length"),
                     ("tilt_offset", f"arm.links[{extension['name']}].offset"), ("lift_joint_x", "arm.origin"), ("lift_joint_y", "arm.origin")):
        moved[f"links.{key}"] = new
    for joint in joints:
        moved[f"joints[{joint['name']}].min"] = moved[f"joints[{joint['name']}].max"] = f"arm.links[{joint['name']}].range"
    moved["links"] = moved["masses"] = "arm"  # a section's own comments go before the section it went to
    moved["joints"] = "actuators"
    return {"origin": [links["lift_joint_x"], links["lift_joint_y"]], "links": [
        {"joint": lift["name"], "kind": "revolute", "length": links["lift_length"], "range": [lift["min"], lift["max"]], "masses": on["lift"]},
        {"joint": tilt["name"], "kind": "revolute", "length": 0.0, "range": [tilt["min"], tilt["max"]], "masses": on["tilt"]},
        {"joint": extension["name"], "kind": "prismatic", "length": links["extension_base"], "offset": offset,
         "range": [extension["min"], extension["max"]], "masses": on["telescope"]}]}


def upgraded_text(path: Path) -> str:
    """The machine form of a crane-form file as YAML, each value's end-of-line comment (its source: PLACEHOLDER, INFERRED,
    a thesis line) beside the key it went to; ConfigError when the file is not in the crane form or cannot be converted."""
    try:
        text = path.read_text()
        config = yaml.safe_load(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise ConfigError(f"config {path}: not a readable YAML file ({type(exc).__name__})") from None
    if not isinstance(config, dict) or not is_crane_form(config):
        raise ConfigError(f"config {path}: not in the crane form (no kind: crane): nothing to upgrade")
    refuse_problems(crane_problems(config), path)
    converted, moved = upgraded(config, str(path))
    moved.setdefault("extension_friction", "planner.friction")
    old_lines = text.splitlines()
    header = old_lines[:next((i for i, line in enumerate(old_lines) if not line.startswith("#")), len(old_lines))]
    comments: dict[str, list[str]] = {}
    leading: dict[str, list[str]] = {}  # the full-line comments just above a key (a section's sources), after the header
    for index, key, comment in keyed_lines(text):
        if comment:
            comments.setdefault(_moved(key, moved), []).append(comment)
        above: list[str] = []
        while index - len(above) - 1 >= len(header) and old_lines[index - len(above) - 1].lstrip().startswith("#"):
            above.insert(0, old_lines[index - len(above) - 1].strip())
        if above:
            leading.setdefault(_moved(key, moved), []).extend(above)
    lines = yaml.dump(converted, Dumper=_BlockDumper, sort_keys=False, width=160).splitlines()
    for index, key, _ in reversed(keyed_lines("\n".join(lines))):
        if key in comments:
            lines[index] += "  # " + "; ".join(dict.fromkeys(comments.pop(key)))
        if key in leading:
            indent = " " * (len(lines[index]) - len(lines[index].lstrip(" -")))
            lines[index:index] = [indent + line for line in leading.pop(key)]
    note = [f"# Written in the machine form by `hydro-ros machine upgrade {path.name}` from the crane form (kind: crane): each",
            "# cylinder once in actuators:, the chain in arm:, the planner's limits, hydraulics, grid and paths in planner:."]
    left = [f"#   {key}: {'; '.join(texts)}" for key, texts in comments.items()]
    left += [f"#   {key}: {' '.join(text.lstrip('# ') for text in texts)}" for key, texts in leading.items()]
    if left:
        note += ["# Comments of the crane form with no key of their own here:", *left]
    return "\n".join([*header, *note, *lines]) + "\n"


class _BlockDumper(yaml.SafeDumper):
    """Mappings in block style, so each key has a line for its comment; lists of numbers in a line, as the files write
    ranges and points."""

    def increase_indent(self, flow: bool = False, indentless: bool = False) -> None:
        super().increase_indent(flow, False)  # a list's items indented under its key, as the shipped files write them

    def represent_list(self, data: Any) -> yaml.SequenceNode:
        flat = all(not isinstance(item, (dict, list)) for item in data)
        return self.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat)


_BlockDumper.add_representer(list, _BlockDumper.represent_list)


def _moved(key: str, moved: Mapping[str, str]) -> str:
    """Where an old key path went: itself, or its longest moved prefix's place with the rest kept."""
    parts = key.split(".")
    for end in range(len(parts), 0, -1):
        prefix = ".".join(parts[:end])
        if prefix in moved:
            return ".".join([moved[prefix], *parts[end:]])
    return key
