"""Every problem of a machine config at once, each naming its key path, value, unit and the rule it breaks.

:func:`config_problems` runs on the merged mapping before it is typed (``machine.parse_machine`` refuses
a config with any), so every command that reads a machine says the same thing. ``hydro-ros machine
check`` prints the list, and :func:`annotated_values` the values the file marks as not measured.
The rules of a value the typed machine holds are declared on its dataclass field (:mod:`hydro_ros.contract.schema`);
the tables here read them off, and add the rules of what is checked but not typed there (mounts by kind, the crane
form, the planner's sections).
"""

from __future__ import annotations

import difflib
import math
import re
from functools import cache
from pathlib import Path
from typing import Any

import numpy as np

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.names import Injection
from hydro_ros.contract.schema import (
    PRESSURE,
    Arm,
    ArmLink,
    Cylinder,
    Excitation,
    Fluid,
    Friction,
    LinkMass,
    Load,
    Mems,
    Rule,
    Sensors,
    Simulation,
    Valve,
    nonnegative,
    positive,
    rules_of,
)

DP_GRID_MIN = 3
"""points per axis of the DP grid: a velocity and a control axis need their ends and zero"""

NOTCHES = ("PA", "PB", "AT", "BT")
ANNOTATIONS = ("PLACEHOLDER", "INFERRED")


CAN = {"latency_limit": Rule("s", 1.0e-3, 1.0, hint="how late a sensor cycle may reach the host (hydro_ros.can.clock)")}
# each section's rules as its dataclass's fields declare them (contract.schema)
TOP = {"sample_rate_hz": positive("Hz", 1.0e5), "supply_pressure": PRESSURE, "tank_pressure": nonnegative("Pa", 1.0e7)}
CYLINDER = rules_of(Cylinder)
TRIANGLE = {"l1": positive("m", 50.0), "l2": positive("m", 50.0), "l3": positive("m", 50.0), "theta_offset": Rule("rad", -7.0, 7.0),
            "sign": Rule("", -1.0, 1.0)}
LINEAR = {"ratio": Rule("m per joint unit", -100.0, 100.0), "theta_offset": Rule("joint unit", -100.0, 100.0)}
VALVE = rules_of(Valve)
MOBILE_VALVE = rules_of(Valve, "mobile")
FLUID = rules_of(Fluid)
FRICTION = rules_of(Friction)
LOAD = rules_of(Load)
SENSORS = rules_of(Sensors)
MEMS = rules_of(Mems)
SIMULATION = rules_of(Simulation)
EXCITATION = rules_of(Excitation)
PAIRS = {"sensors": ("pressure_range", "joint_range"), "excitation": ("joint_range", "move_speed", "rest_time")}

CAN_QUANTITIES = {"joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command", "pilot_pressure_1", "pilot_pressure_2",
                  "compensator_pressure", "valve_request"}
ACTUATOR_KEYS = {"joint", "can_slot", "cylinder", "mount", "valve", "fluid", "friction", "load"}
VALVE_KEYS = set(VALVE) | set(MOBILE_VALVE) | {"type", "command_range", "kv_poly", "centre_leakage"}
SECTION_KEYS = {"sensors": set(SENSORS) | {"pressure_range", "joint_range", "motion_sensor", "mems"}, "simulation": set(SIMULATION),
                "excitation": set(EXCITATION) | set(PAIRS["excitation"])}
# a crane config also holds its planner's sections (contract/crane.py types them)
CRANE_LINKS = {"lift_length": positive("m", 50.0), "tilt_offset": Rule("m", -10.0, 10.0), "extension_base": positive("m", 50.0),
               "lift_joint_x": Rule("m", -50.0, 50.0), "lift_joint_y": Rule("m", -50.0, 50.0)}
CRANE_JOINT = {"min": Rule("rad or m", -7.0, 50.0), "max": Rule("rad or m", -7.0, 50.0)}
CRANE_CYLINDER = {"ratio": Rule("m per joint unit", -100.0, 100.0), "la": nonnegative("m", 50.0), "lb": nonnegative("m", 50.0),
                  "theta_at_min": Rule("rad", -7.0, 7.0), "sign": Rule("", -1.0, 1.0),
                  "area_a": positive("m^2", 1.0, hint="SI: a 120 mm bore is 1.13e-2"), "area_b": nonnegative("m^2", 1.0),
                  "pump_area_extend": nonnegative("m^2", 1.0), "pump_area_retract": nonnegative("m^2", 1.0),
                  "velocity_max": positive("m/s", 10.0), "acceleration_max": positive("m/s^2", 100.0), "constant_force": Rule("N")}
CRANE_MASS = {"s": Rule("m", -50.0, 50.0), "mass": nonnegative("kg", 1.0e6)}
CRANE_FRICTION = {"coulomb": nonnegative("N"), "tanh_gain": positive("s/m")}
CRANE_DP = {"sample_time": positive("s", 10.0), "filter_cutoff": positive("Hz", 1.0e3)}
CRANE_CHOICES = {"mapping": ("linear", "triangle"), "spool": ("non_differential", "differential"), "link": ("lift", "boom")}
ARM = rules_of(Arm)
RANGE_LIMIT = {"revolute": Rule("rad", -7.0, 7.0, hint="radians: 90 deg is 1.571"), "prismatic": Rule("m", -50.0, 50.0, hint="metres")}
ARM_LINK = rules_of(ArmLink)
LINK_MASS = rules_of(LinkMass)
RANGE_SLACK = 1e-3  # [m] a joint range may reach this far past the cylinder's ends (rounding of data-sheet values)
HYDRAULICS = {"supply_pressure_cp": PRESSURE, "tank_pressure": nonnegative("Pa", 1.0e7), "ls_margin": nonnegative("Pa", 1.0e7),
              "compensator_drop": nonnegative("Pa", 1.0e7), "efficiency": Rule("-", 0.0, 1.0, open_low=True),
              "drive_threshold": positive("m/s", 1.0), "pump_flow_max": positive("m^3/s", 1.0), "supply_pressure_max": PRESSURE}
SLEW_DRIVES = {"rack": {"ratio": positive("m/rad", 10.0, hint="the plungers' stroke per radian: the pinion's radius"),
                        "area": positive("m^2", 1.0, hint="SI: a 115 mm plunger is 1.04e-2")},
               "motor": {"displacement": positive("m^3/rad", 1.0, hint="a 100 cm^3/rev motor is 1.59e-5 m^3/rad")}}
PLANNER_FRICTION = {"coulomb": nonnegative("N"), "tanh_gain": positive("s/m")}
PLANNER_ACTUATOR = {"velocity_max": positive("m/s", 10.0), "acceleration_max": positive("m/s^2", 100.0)}
# the planner's optional sections, each key over its default: the closed loop's settings (P-VI App. A; K_p,
# eps_p, eps_v and the rate are NOT GIVEN: our choices)
PLANNER_CONTROLLER = {
    "rate": Rule("Hz", 0.0, 1.0e3, open_low=True, hint="as trajectory_executor's rate", default=100.0),
    "position_gain": Rule("1/s", 0.0, 1.0e3, open_low=True, default=2.0),
    "position_deadband": Rule("m", 0.0, 1.0, default=0.005),
    "velocity_deadband": Rule("m/s", 0.0, 1.0, default=0.002),
    "settle_time": Rule("s", 0.0, 60.0, hint="the final reference is held this long after the trajectory", default=1.0),
    "log_rate": Rule("Hz", 0.0, 1.0e4, open_low=True, hint="of the recorded signals", default=100.0),
}
# the simulated machine's (``sim.closed_loop_crane``), PLACEHOLDERS. The mobile valves' static table (a controller inverts
# it): dead zone as a fraction of the command (P-VI App. A: ~53 %) and the velocity at full command per unit of the
# cylinder's velocity limit; the plant spreads both per valve.
PLANNER_PLANT = {
    "valve_dead_zone": Rule("", 0.0, 0.95, hint="a fraction of the command", default=0.53),
    "full_command_velocity_factor": Rule("", 0.0, 10.0, open_low=True, hint="per unit of the cylinder's velocity_max", default=1.25),
    "valve_dead_zone_spread": Rule("", 0.0, 0.5, default=0.02),
    "valve_gain_spread": Rule("", 0.0, 0.5, default=0.05),
    "valve_delay": Rule("s", 0.0, 5.0, default=0.15),
    "spool_time_constant": Rule("s", 0.0, 5.0, open_low=True, default=0.03),
    "motion_time_constant": Rule("s", 0.0, 5.0, open_low=True, default=0.05),
    "payload": Rule("kg", 0.0, 1.0e6, default=200.0),
    "coulomb_friction": Rule("N", 0.0, 1.0e7, default=1500.0),
    "ls_time_constant": Rule("s", 0.0, 10.0, open_low=True, default=0.20),
    "time_step": Rule("s", 0.0, 0.1, open_low=True, default=0.002),
}
CATALOG_KEYS = ("methods", "grid")


def defaults(rules: dict[str, Rule]) -> dict[str, float]:
    """An optional section's values when it gives none."""
    return {key: rule.default for key, rule in rules.items() if rule.default is not None}


PLANNER_KEYS = {"redundant", "actuators", "friction", "hydraulics", "dp", "paths", "controller", "plant", "catalog"}
TOP_KEYS = set(TOP) | {"machine", "actuators", "sensors", "simulation", "excitation", "effects", "effect_forms", "can", "fdi", "arm",
                       "planner"}

# Every numeric rule of the machine form by the section it checks, with what the section is: `hydro-ros machine check`
# applies them, docs/reference/config.md is generated from them (hydro_ros.tooling.docgen).
REFERENCE: tuple[tuple[str, dict[str, Rule], str], ...] = (
    ("", TOP, "the machine: its sample rate and supply"),
    ("actuators.<name>.cylinder", CYLINDER, "the cylinder's data sheet"),
    ("actuators.<name>.mount (kind: triangle)", TRIANGLE,
     "a cylinder between two links: length = sqrt(l1^2 + l2^2 - 2 l1 l2 cos(sign q + theta_offset)), stroke = length - l3"),
    ("actuators.<name>.mount (kind: linear)", LINEAR, "a telescope or rack: stroke = ratio (q + theta_offset)"),
    ("actuators.<name>.valve", VALVE, "the valve's data sheet (type proportional or mobile; kv_poly, centre_leakage per notch)"),
    ("actuators.<name>.valve (type: mobile)", MOBILE_VALVE, "a pressure-compensated, pilot-operated valve"),
    ("actuators.<name>.fluid", FLUID, "the oil and the lines"),
    ("actuators.<name>.friction", FRICTION, "LuGre friction of the cylinder"),
    ("actuators.<name>.load", LOAD, "a boom of its own (no arm:), P-I eqs. 20-21"),
    ("arm", ARM, "the links the cylinders move, base to tip (origin [x, y] m; links; slew)"),
    ("arm.links[]", ARM_LINK, "a link: joint (its actuator's), kind revolute or prismatic, range [low, high] (rad or m), masses"),
    ("arm.links[].masses[]", LINK_MASS, "a mass fixed on the link (name optional)"),
    ("arm.slew.drive (kind: rack)", SLEW_DRIVES["rack"], "a slewing base's rack and pinion (arm.slew: joint, range [rad], drive)"),
    ("arm.slew.drive (kind: motor)", SLEW_DRIVES["motor"], "a slewing base's hydraulic motor"),
    ("sensors", SENSORS, "the transmitters and encoders (pressure_range, joint_range: [low, high]; mems)"),
    ("sensors.mems", MEMS, "P-III's MEMS motion sensor"),
    ("simulation", SIMULATION, "the simulated plant"),
    ("excitation", EXCITATION, "the simulated operator (joint_range, move_speed, rest_time: [low, high])"),
    ("can", CAN, "the machine bus (dbc, map)"),
    ("planner.actuators.<name>", PLANNER_ACTUATOR,
     "each cylinder's rate limits, both required (spool: non_differential or differential, lowered_by_gravity: false or true; the "
     "slew, keyed by its joint: its drive's units and constant_force N)"),
    ("planner.friction", PLANNER_FRICTION, "on the redundant joint, P-VI eqs. A3-A4 (steps: [[from, to], ...])"),
    ("planner.hydraulics", HYDRAULICS, "the energy model, P-V eqs. 36-41: ls_margin, compensator_drop, efficiency, drive_threshold "
                                       "required; supply_pressure_cp and tank_pressure default to the machine's"),
    ("planner.dp", CRANE_DP, "the DP, every key required (grid: [positions, velocities, controls], each >= 3)"),
    ("planner.controller", PLANNER_CONTROLLER, "optional: the closed loop's settings (P-VI App. A; NOT GIVEN there), each over its default"),
    ("planner.plant", PLANNER_PLANT, "optional: the simulated machine's and its valve table's (PLACEHOLDERS), each over its default"),
)

MAX_LISTED = 5  # problems named in one error line; `hydro-ros machine check` lists all


def refuse_problems(problems: list[str], source: Path | str) -> None:
    """One ConfigError line with the first problems, if there are any."""
    if problems:
        listed = "; ".join(problems[:MAX_LISTED]) + (f"; and {len(problems) - MAX_LISTED} more" if len(problems) > MAX_LISTED else "")
        raise ConfigError(f"config {source}: {listed} (hydro-ros machine check {source} lists each)")


class _Problems:
    def __init__(self) -> None:
        self.found: list[str] = []

    def add(self, path: str, message: str) -> None:
        self.found.append(f"{path}: {message}")

    def unknown(self, node: dict[str, Any], path: str, known: set[str]) -> None:
        for key in node:
            if str(key) not in known:
                near = difflib.get_close_matches(str(key), sorted(known), n=1, cutoff=0.6)
                self.add(_join(path, key), "unknown key" + (f" (did you mean {near[0]}?)" if near else f" (known: {', '.join(sorted(known))})"))

    def numbers(self, node: Any, path: str, rules: dict[str, Rule], required: tuple[str, ...] = ()) -> dict[str, float]:
        """The numbers of ``node`` checked against ``rules``; missing required ones and non-numbers reported."""
        if not isinstance(node, dict):
            self.add(path, "missing" + (f" ({', '.join(required)} required)" if required else "") if node is None else "must be a mapping")
            return {}
        values = {}
        for key, rule in rules.items():
            if key not in node:
                if key in required:
                    self.add(_join(path, key), f"missing [{rule.unit}]" if rule.unit else "missing")
                continue
            value = _number(node[key])
            if value is None:
                self.add(_join(path, key), f"{node[key]!r} is not a number")
                continue
            broken = rule.broken(value)
            if broken:
                self.add(_join(path, key), f"{value:g} {rule.unit}: {broken}".replace("  ", " "))
            values[key] = value
        return values

    def pair(self, node: dict[str, Any], path: str, key: str) -> None:
        if key not in node:
            return
        value = node[key]
        numbers = [_number(v) for v in value] if isinstance(value, (list, tuple)) else []
        if len(numbers) != 2 or None in numbers:
            self.add(_join(path, key), f"{value!r}: expected [low, high]")
        elif not all(math.isfinite(n) for n in numbers):  # type: ignore[arg-type]
            self.add(_join(path, key), f"{value!r}: must be finite")
        elif not numbers[0] < numbers[1]:  # type: ignore[operator]
            self.add(_join(path, key), f"{value!r}: low must be below high")


def _join(path: str, key: Any) -> str:
    return f"{path}.{key}" if path else str(key)


def _number(value: Any) -> float | None:
    if isinstance(value, bool):
        return None
    try:
        return float(value)
    except (TypeError, ValueError):
        return None


def config_problems(config: dict[str, Any]) -> list[str]:
    """Every rule the merged machine config breaks, one ``key.path: value unit: rule`` line each."""
    found = _Problems()
    found.unknown(config, "", TOP_KEYS)
    top = found.numbers(config, "", TOP, required=tuple(TOP))
    if "supply_pressure" in top and "tank_pressure" in top and top["tank_pressure"] >= top["supply_pressure"]:
        found.add("tank_pressure", f"{top['tank_pressure']:g} Pa: must be below supply_pressure ({top['supply_pressure']:g} Pa)")
    actuators = config.get("actuators")
    if not isinstance(actuators, dict) or not actuators:
        found.add("actuators", "must name at least one actuator")
        actuators = {}
    simulation: dict[str, Any] = config["simulation"] if isinstance(config.get("simulation"), dict) else {}
    arm = "arm" in config
    for name, actuator in actuators.items():
        _actuator(found, f"actuators.{name}", actuator, arm, _number(simulation.get("end_stop_upper")))
    effects = config.get("effects")
    if isinstance(effects, dict):
        for name, value in effects.items():
            try:
                Injection(str(name), float(value))
            except (InputError, TypeError, ValueError) as exc:
                found.add(f"effects.{name}", str(exc))
    elif effects is not None:
        found.add("effects", "must be a mapping of effect names to values")
    if arm:
        _arm(found, config["arm"], actuators, simulation)
    joints = [a.get("joint") for a in actuators.values() if isinstance(a, dict) and isinstance(a.get("joint"), str)]
    for joint in sorted({j for j in joints if joints.count(j) > 1}, key=str):
        found.add("actuators", f"joint {joint!r} is driven by more than one actuator")
    for section, rules in (("sensors", SENSORS), ("simulation", SIMULATION), ("excitation", EXCITATION)):
        node = config.get(section, {} if section != "sensors" else None)
        if node is None:
            found.add(section, "missing")
            continue
        found.numbers(node, section, rules, required=("pressure_noise_std", "encoder_resolution") if section == "sensors" else ())
        if isinstance(node, dict):
            found.unknown(node, section, SECTION_KEYS[section])
            for key in PAIRS.get(section, ()):
                found.pair(node, section, key)
    can = config.get("can", {})
    if not isinstance(can, dict):
        found.add("can", "must be a mapping (dbc, map)")
    else:
        found.unknown(can, "can", {"dbc", "map", "latency_limit"})
        found.numbers(can, "can", CAN)
        if "map" in can and not isinstance(can["map"], dict):
            found.add("can.map", "must be a mapping (hydro_ros.can.codec names its keys)")
        elif isinstance(can.get("map"), dict):
            found.unknown(can["map"], "can.map", {"supply_pressure", "ls_pressure", "actuators", "counters", "checksums"})
            mapped = can["map"].get("actuators")
            if mapped is not None and not isinstance(mapped, dict):
                found.add("can.map.actuators", "must be a mapping of actuator names")
            for name, entry in (mapped if isinstance(mapped, dict) else {}).items():
                if name not in actuators:
                    found.add(f"can.map.actuators.{name}", f"no such actuator (actuators: {', '.join(map(str, actuators))})")
                elif isinstance(entry, dict):
                    found.unknown(entry, f"can.map.actuators.{name}", CAN_QUANTITIES)
    sensors = config.get("sensors")
    if isinstance(sensors, dict):
        if "pressure_range" not in sensors:
            found.add("sensors.pressure_range", "missing [Pa]")
        if sensors.get("motion_sensor", "encoder") not in ("encoder", "mems"):
            found.add("sensors.motion_sensor", f"{sensors['motion_sensor']!r}: expected encoder or mems")
        if sensors.get("motion_sensor") == "mems":
            found.numbers(sensors.get("mems"), "sensors.mems", MEMS, required=tuple(MEMS))
    return found.found


def crane_problems(config: dict[str, Any]) -> list[str]:
    """Every rule the crane form (``kind: crane``) breaks, checked before ``contract.upgrade`` converts it."""
    found = _Problems()
    _crane(found, config)
    return found.found


def planner_problems(config: dict[str, Any]) -> list[str]:
    """Every rule the planner's reading of a machine config with ``arm:`` and ``planner:`` breaks: the chain (three links, each
    on an actuator's cylinder and mount), which one is redundant, each actuator's rate limits, the grid and the paths. The
    monitor's sections (valves, sensors) are not the planner's to require."""
    found = _Problems()
    found.unknown(config, "", TOP_KEYS)
    top = found.numbers(config, "", {"supply_pressure": PRESSURE, "tank_pressure": TOP["tank_pressure"]}, required=("supply_pressure",))
    node = config.get("actuators")
    actuators: dict[str, Any] = node if isinstance(node, dict) else {}
    for name, actuator in actuators.items():
        path = f"actuators.{name}"
        if not isinstance(actuator, dict) or not isinstance(actuator.get("joint"), str):
            found.add(f"{path}.joint", "missing (its name in /joint_states)")
            continue
        # the planner needs the areas and the stroke; the dead volumes are the monitor's
        cylinder = found.numbers(actuator.get("cylinder"), f"{path}.cylinder", CYLINDER, required=("piston_diameter", "rod_diameter", "stroke"))
        if {"rod_diameter", "piston_diameter"} <= set(cylinder) and cylinder["rod_diameter"] >= cylinder["piston_diameter"]:
            found.add(f"{path}.cylinder.rod_diameter", f"{cylinder['rod_diameter']:g} m: must be smaller than piston_diameter")
        _mount(found, f"{path}.mount", actuator.get("mount"), cylinder.get("stroke"))
    simulation = config["simulation"] if isinstance(config.get("simulation"), dict) else {}
    if not isinstance(config.get("arm"), dict):
        found.add("arm", "missing: the planner plans the chain arm: describes (links base to tip, each on an actuator's joint)")
        return found.found
    _arm(found, config["arm"], actuators, simulation)
    links = config["arm"].get("links") if isinstance(config["arm"].get("links"), list) else []
    if len(links) != 3:
        found.add("arm.links", f"{len(links)} links: a planar tip path (x, y) fixes two joints, so the planner needs three, one of them "
                               "redundant" + (" (two have no redundancy to optimise)" if len(links) < 3 else " (more than one redundant "
                                                                                                            "degree of freedom is not planned)"))
    planner = config["planner"]
    if not isinstance(planner, dict):
        found.add("planner", "must be a mapping (redundant, actuators, hydraulics, dp, paths)")
        return found.found
    found.unknown(planner, "planner", PLANNER_KEYS)
    redundant = planner.get("redundant")
    if not isinstance(redundant, str) or redundant not in actuators:
        found.add("planner.redundant", f"{redundant!r}: must name the actuator whose stroke the planner chooses (one of "
                                       f"{', '.join(map(str, actuators))})")
    given = planner.get("actuators")
    limits: dict[str, Any] = given if isinstance(given, dict) else {}
    slew = config["arm"].get("slew")
    driven = [*actuators, *([slew["joint"]] if isinstance(slew, dict) and isinstance(slew.get("joint"), str) else [])]
    for name in driven:
        entry = limits.get(name)
        path = f"planner.actuators.{name}"
        found.numbers(entry, path, PLANNER_ACTUATOR | {"constant_force": Rule("N")}, required=tuple(PLANNER_ACTUATOR))
        if isinstance(entry, dict):
            found.unknown(entry, path, set(PLANNER_ACTUATOR) | ({"constant_force"} if name not in actuators else {"spool", "lowered_by_gravity"}))
            if name in actuators:
                _choice(found, entry, path, "spool", "non_differential")
                if not isinstance(entry.get("lowered_by_gravity", False), bool):
                    found.add(f"{path}.lowered_by_gravity", f"{entry['lowered_by_gravity']!r}: expected true or false")
    for name in limits:
        if name not in driven:
            found.add(f"planner.actuators.{name}", f"not an actuator or the slew (they are: {', '.join(map(str, driven))})")
    found.numbers(planner.get("friction", {}), "planner.friction", PLANNER_FRICTION)
    drives = actuators.get(redundant) if isinstance(redundant, str) else None
    redundant_link = next((link for link in links if isinstance(link, dict) and isinstance(drives, dict)
                           and link.get("joint") == drives.get("joint")), None)
    if "friction" in planner and redundant_link is not None and redundant_link.get("kind", "revolute") != "prismatic":
        found.add("planner.friction", f"the redundant joint {redundant_link.get('joint')} turns; the friction the planner models is a "
                                      "telescope's (N on a sliding joint, P-VI eqs. A3-A4): remove it")
    friction = planner.get("friction")
    steps = (friction.get("steps") or []) if isinstance(friction, dict) else []
    if isinstance(friction, dict):
        found.unknown(friction, "planner.friction", set(PLANNER_FRICTION) | {"steps"})
    if not (isinstance(steps, list) and all(isinstance(step, list) and len(step) == 2 and None not in map(_number, step) for step in steps)):
        found.add("planner.friction.steps", f"{steps!r}: expected a list of [from, to] positions of the redundant joint")
    _planning_sections(found, planner, "planner.")
    if "tank_pressure" in top and top["tank_pressure"] >= top.get("supply_pressure", math.inf):
        found.add("tank_pressure", f"{top['tank_pressure']:g} Pa: must be below supply_pressure")
    return found.found


def _choice(found: _Problems, node: dict[str, Any], path: str, key: str, default: str | None = None) -> None:
    value = node.get(key, default)
    if value not in CRANE_CHOICES[key]:
        found.add(_join(path, key), f"{value!r}: expected {' or '.join(CRANE_CHOICES[key])}" if value is not None else "missing")


def list_entry(section: str, index: int, entry: Any) -> str:
    """A list entry's key path, by its name (or an arm link's joint) where it has one, as ``annotated_values`` names it."""
    label = entry.get("name", entry.get("joint")) if isinstance(entry, dict) else None
    return f"{section}[{label if isinstance(label, str) else index}]"


def _crane(found: _Problems, config: dict[str, Any]) -> None:
    """The planner's sections of a crane config: links, one joint per planar joint (and the base), masses, grid, paths."""
    found.numbers(config.get("links"), "links", CRANE_LINKS, required=("lift_length", "extension_base", "lift_joint_x", "lift_joint_y"))
    joints = config.get("joints")
    expected = 4 if config.get("base_rotation") else 3
    if not isinstance(joints, list) or len(joints) != expected:
        found.add("joints", f"{expected} joints expected (base_rotation: {bool(config.get('base_rotation'))}), found "
                            f"{len(joints) if isinstance(joints, list) else 'none'}")
        joints = joints if isinstance(joints, list) else []
    for index, joint in enumerate(joints):
        path = list_entry("joints", index, joint)
        limits = found.numbers(joint, path, CRANE_JOINT, required=("min", "max"))
        if not isinstance(joint, dict):
            continue
        if "name" not in joint:
            found.add(f"{path}.name", "missing (its name in /joint_states)")
        if {"min", "max"} <= set(limits) and not limits["min"] < limits["max"]:
            found.add(f"{path}.max", f"{limits['max']:g}: must be above min ({limits['min']:g})")
        cylinder = joint.get("cylinder")
        found.numbers(cylinder, f"{path}.cylinder", CRANE_CYLINDER,
                      required=("area_a", "area_b", "pump_area_extend", "pump_area_retract", "velocity_max", "acceleration_max"))
        if isinstance(cylinder, dict):
            found.unknown(cylinder, f"{path}.cylinder", set(CRANE_CYLINDER) | {"mapping", "spool"})
            _choice(found, cylinder, f"{path}.cylinder", "mapping", "linear")
            _choice(found, cylinder, f"{path}.cylinder", "spool", "non_differential")
            if index == len(joints) - 1 and cylinder.get("mapping", "linear") != "linear":
                found.add(f"{path}.cylinder.mapping", "the extension (last joint) needs a linear mapping")
    masses = config.get("masses")
    if masses is not None and not isinstance(masses, list):
        found.add("masses", f"{masses!r}: expected a list of masses (name, mass, joint, along)")
    for index, mass in enumerate(masses if isinstance(masses, list) else []):
        found.numbers(mass, list_entry("masses", index, mass), CRANE_MASS, required=tuple(CRANE_MASS))
        if isinstance(mass, dict):
            _choice(found, mass, list_entry("masses", index, mass), "link")
    friction = config.get("extension_friction") or {}
    found.numbers(friction, "extension_friction", CRANE_FRICTION)
    steps = (friction.get("steps") or []) if isinstance(friction, dict) else []
    if not (isinstance(steps, list) and all(isinstance(step, list) and len(step) == 2 and None not in map(_number, step) for step in steps)):
        found.add("extension_friction.steps", f"{steps!r}: expected a list of [from, to] extensions [m]")
    _planning_sections(found, config, "", required=("supply_pressure_cp", "tank_pressure"))


def _planning_sections(found: _Problems, node: dict[str, Any], prefix: str, required: tuple[str, ...] = ()) -> None:
    """The hydraulics, the grid and the paths, in a crane config or a machine config's planner: section (``required``: the
    hydraulics' values it does not take from elsewhere)."""
    hydraulics = node.get("hydraulics")
    found.numbers(hydraulics, f"{prefix}hydraulics", HYDRAULICS,
                  required=(*required, "ls_margin", "compensator_drop", "efficiency", "drive_threshold"))
    if isinstance(hydraulics, dict):
        found.unknown(hydraulics, f"{prefix}hydraulics", set(HYDRAULICS))
    dp = node.get("dp")
    found.numbers(dp, f"{prefix}dp", CRANE_DP, required=tuple(CRANE_DP))
    grid = dp.get("grid") if isinstance(dp, dict) else None
    if not (isinstance(grid, list) and len(grid) == 3 and all(isinstance(n, int) and n >= DP_GRID_MIN for n in grid)):
        found.add(f"{prefix}dp.grid", f"{grid!r}: expected three whole numbers >= {DP_GRID_MIN} (the redundant cylinder's positions, "
                                      "velocities, controls)")
    if not isinstance(node.get("paths"), dict) or not node["paths"]:
        found.add(f"{prefix}paths", "must name at least one tip path")
    for section, rules in (("controller", PLANNER_CONTROLLER), ("plant", PLANNER_PLANT)):
        given = node.get(section) or {}  # an empty section (YAML null) is every default
        values = found.numbers(given, f"{prefix}{section}", rules)
        if isinstance(given, dict):
            found.unknown(given, f"{prefix}{section}", set(rules))
        if section == "plant":
            dead_zone = {key: values.get(key, rule.default) for key, rule in rules.items() if key.startswith("valve_dead_zone")}
            if (dead_zone["valve_dead_zone"] or 0.0) + (dead_zone["valve_dead_zone_spread"] or 0.0) >= 1.0:
                found.add(f"{prefix}plant.valve_dead_zone_spread", "with valve_dead_zone it reaches a whole command: a valve "
                                                                  "drawn at the spread's end would never open")
    catalog = node.get("catalog") or {}
    if isinstance(catalog, dict):
        found.unknown(catalog, f"{prefix}catalog", set(CATALOG_KEYS))
    else:
        found.add(f"{prefix}catalog", f"must be a mapping ({', '.join(CATALOG_KEYS)})")


def _slew(found: _Problems, node: Any) -> None:
    """A slewing base: its joint, its range and its drive (a rack and pinion or a motor)."""
    if not isinstance(node, dict):
        found.add("arm.slew", "must be a mapping (joint, range, drive)")
        return
    found.unknown(node, "arm.slew", {"joint", "range", "drive"})
    if not isinstance(node.get("joint"), str):
        found.add("arm.slew.joint", f"{node.get('joint')!r}: must be the slew's name in /joint_states")
    if "range" not in node:
        found.add("arm.slew.range", "missing [rad]")
    else:
        found.pair(node, "arm.slew", "range")
    drive = node.get("drive")
    kind = drive.get("kind", "rack") if isinstance(drive, dict) else None
    if kind not in SLEW_DRIVES:
        found.add("arm.slew.drive" + (".kind" if isinstance(drive, dict) else ""),
                  f"{kind!r}: expected a mapping of kind rack (ratio, area) or motor (displacement)")
        return
    found.numbers(drive, "arm.slew.drive", SLEW_DRIVES[kind], required=tuple(SLEW_DRIVES[kind]))
    if isinstance(drive, dict):
        found.unknown(drive, "arm.slew.drive", set(SLEW_DRIVES[kind]) | {"kind"})


def _arm(found: _Problems, node: Any, actuators: dict[str, Any], simulation: dict[str, Any]) -> None:
    """The links base to tip, each on an actuator's joint, its range inside the cylinder's stroke."""
    if not isinstance(node, dict):
        found.add("arm", "must be a mapping (origin, payload, links)")
        return
    found.unknown(node, "arm", set(ARM) | {"origin", "links", "slew"})
    if "slew" in node:
        _slew(found, node["slew"])
    found.numbers(node, "arm", ARM)
    if "origin" in node:
        origin = node["origin"]
        numbers = list(map(_number, origin)) if isinstance(origin, list) else []
        if len(numbers) != 2 or None in numbers or not all(math.isfinite(n) for n in numbers):  # type: ignore[arg-type]
            found.add("arm.origin", f"{origin!r}: expected [x, y], finite (m)")
    links = node.get("links")
    if not isinstance(links, list) or not links:
        found.add("arm.links", "must list the links, base to tip")
        return
    by_joint = {a.get("joint"): (name, a) for name, a in actuators.items() if isinstance(a, dict) and isinstance(a.get("joint"), str)}
    joints: list[str] = []
    for index, link in enumerate(links):
        path = list_entry("arm.links", index, link)
        values = found.numbers(link, path, ARM_LINK, required=("length",))
        if not isinstance(link, dict):
            continue
        found.unknown(link, path, set(ARM_LINK) | {"joint", "kind", "range", "masses"})
        kind = link.get("kind", "revolute")
        if kind not in ("revolute", "prismatic"):
            found.add(f"{path}.kind", f"{kind!r}: expected revolute or prismatic")
        joint = link.get("joint")
        if not isinstance(joint, str):
            found.add(f"{path}.joint", f"{joint!r}: must be the name of an actuator's joint")
            continue
        if joint in joints:
            found.add(f"{path}.joint", f"{joint!r}: has an earlier link already; each joint moves one link")
        joints.append(joint)
        if joint not in by_joint:
            found.add(f"{path}.joint", f"{joint!r}: no actuator drives it (actuators' joints: {', '.join(map(str, by_joint))})")
        elif kind == "prismatic" and isinstance(by_joint[joint][1].get("mount"), dict) and \
                by_joint[joint][1]["mount"].get("kind", "triangle") != "linear":
            found.add(f"{path}.kind", f"prismatic, but actuator {by_joint[joint][0]}'s mount is a triangle: a cylinder sliding a "
                                      "link moves with it (mount.kind: linear)")
        if "range" not in link:
            found.add(f"{path}.range", "missing [rad] or [m]: where the joint may go")
        else:
            found.pair(link, path, "range")
            limit = RANGE_LIMIT.get(kind) if isinstance(kind, str) else None
            ends = [v for v in (_number(v) for v in link["range"]) if v is not None] if isinstance(link["range"], list) else []
            whole = isinstance(link["range"], list) and len(ends) == len(link["range"]) == 2
            if limit and limit.high is not None and whole and any(abs(v) > limit.high for v in ends):
                found.add(f"{path}.range", f"{link['range']!r} {limit.unit}: must lie within +-{limit.high:g} ({limit.hint})")
        masses = link.get("masses") or []
        if not isinstance(masses, list):
            found.add(f"{path}.masses", "must be a list of masses")
            masses = []
        for m, mass in enumerate(masses):
            found.numbers(mass, list_entry(f"{path}.masses", m, mass), LINK_MASS, required=("mass", "along"))
            if isinstance(mass, dict):
                found.unknown(mass, list_entry(f"{path}.masses", m, mass), set(LINK_MASS) | {"name"})
                if "name" in mass and not isinstance(mass["name"], str):
                    found.add(f"{path}.masses[{m}].name", f"{mass['name']!r}: must be a name")
        if link.get("joint") in by_joint and "length" in values:
            _range_in_stroke(found, path, link, *by_joint[link["joint"]], simulation)
    for joint, (name, _) in by_joint.items():
        if joint not in joints:
            found.add(f"actuators.{name}.joint", f"{joint!r}: not a joint of arm.links")


def _range_in_stroke(found: _Problems, path: str, link: dict[str, Any], name: str, actuator: dict[str, Any], simulation: dict[str, Any]) -> None:
    """The piston stays between its end stops over the joint's range (P-I eq. 3; a linear mount: x = ratio (q + offset))."""
    ends = [_number(v) for v in link.get("range") or []] if isinstance(link.get("range"), list) else []
    low_high = [v for v in ends if v is not None]
    mount, cylinder = actuator.get("mount"), actuator.get("cylinder")
    if len(ends) != 2 or len(low_high) != 2 or not isinstance(mount, dict) or not isinstance(cylinder, dict):
        return
    stroke, offset = _number(cylinder.get("stroke")), _number(mount.get("theta_offset"))
    if stroke is None or offset is None or not math.isfinite(stroke + offset):
        return
    pistons = []
    grid = [float(q) for q in np.linspace(low_high[0], low_high[1], 21)] if all(math.isfinite(v) for v in low_high) else []
    for q in grid:
        if mount.get("kind", "triangle") == "linear":
            ratio = _number(mount.get("ratio"))
            if ratio is None:
                return
            pistons.append(ratio * (q + offset))
        else:
            l1, l2, l3, sign = (_number(mount.get(k, 1.0 if k == "sign" else None)) for k in ("l1", "l2", "l3", "sign"))
            if l1 is None or l2 is None or l3 is None or sign not in (1.0, -1.0) or not all(math.isfinite(v) for v in (l1, l2, l3)):
                return  # a sign other than +-1 is _mount's to refuse
            theta = sign * q + offset
            pistons.append(math.sqrt(max(l1 * l1 + l2 * l2 - 2.0 * l1 * l2 * math.cos(theta), 0.0)) - l3)
    lower = _number(simulation.get("end_stop_lower", 0.0)) or 0.0
    upper = min(stroke, _number(simulation.get("end_stop_upper", stroke)) or stroke)
    if not pistons:
        return
    below = [(lower - x, q, x) for q, x in zip(grid, pistons)]
    above = [(x - upper, q, x) for q, x in zip(grid, pistons)]
    outside = [(q, x) for side in (below, above) for excess, q, x in [max(side)] if excess > RANGE_SLACK]  # the worst each way
    for q, x in outside:
        found.add(f"{path}.range", f"{q:g} puts actuator {name}'s piston at {x:g} m, outside its end stops {lower:g} to {upper:g} m "
                                   "(its stroke, or simulation.end_stop_lower / _upper)")


def _actuator(found: _Problems, path: str, node: Any, arm: bool, end_stop_upper: float | None) -> None:
    if not isinstance(node, dict):
        found.add(path, "must be a mapping")
        return
    found.unknown(node, path, ACTUATOR_KEYS)
    if "joint" not in node:
        found.add(f"{path}.joint", "missing (its name in /joint_states)")
    elif not isinstance(node["joint"], str):
        found.add(f"{path}.joint", f"{node['joint']!r}: must be a name" + (f" (quote a number: '{node['joint']}')"
                                                                          if isinstance(node["joint"], (int, float)) else ""))
    slot = node.get("can_slot")
    if slot is not None and not (isinstance(slot, (int, float)) and not isinstance(slot, bool) and math.isfinite(slot)
                                 and slot == int(slot) and 0 <= slot <= 255):
        found.add(f"{path}.can_slot", f"{slot!r}: expected a whole number 0-255 (the n of its CYLn_ and VALVEn_ messages)")
    cylinder = found.numbers(node.get("cylinder"), f"{path}.cylinder", CYLINDER, required=tuple(CYLINDER))
    if isinstance(node.get("cylinder"), dict):
        found.unknown(node["cylinder"], f"{path}.cylinder", set(CYLINDER))
    if {"rod_diameter", "piston_diameter"} <= set(cylinder) and cylinder["rod_diameter"] >= cylinder["piston_diameter"]:
        found.add(f"{path}.cylinder.rod_diameter", f"{cylinder['rod_diameter']:g} m: must be smaller than piston_diameter "
                                                   f"({cylinder['piston_diameter']:g} m)")
    _mount(found, f"{path}.mount", node.get("mount"), end_stop_upper or cylinder.get("stroke"))
    _valve(found, f"{path}.valve", node.get("valve"))
    if arm and "load" in node:
        found.add(f"{path}.load", "the arm: section describes the links; each actuator's load follows from it (remove load)")
    for key, rules in (("fluid", FLUID), ("friction", FRICTION)) + ((("load", LOAD),) if not arm else ()):
        found.numbers(node.get(key), f"{path}.{key}", rules, required=tuple(rules))
        if isinstance(node.get(key), dict):
            found.unknown(node[key], f"{path}.{key}", set(rules))


def _mount(found: _Problems, path: str, node: Any, travel: float | None) -> None:
    if not isinstance(node, dict):
        found.add(path, "missing" if node is None else "must be a mapping")
        return
    kind = node.get("kind", "triangle")
    if kind not in ("triangle", "linear"):
        found.add(f"{path}.kind", f"{kind!r}: expected triangle or linear")
        return
    rules = TRIANGLE if kind == "triangle" else LINEAR
    found.unknown(node, path, set(rules) | {"kind"})
    values = found.numbers(node, path, rules, required=tuple(k for k in rules if k != "sign"))
    if "sign" in values and values["sign"] not in (1.0, -1.0):
        found.add(f"{path}.sign", f"{values['sign']:g}: expected 1 or -1")
    if kind == "triangle" and {"l1", "l2", "l3"} <= set(values) and travel is not None:
        shortest, longest = abs(values["l1"] - values["l2"]), values["l1"] + values["l2"]
        if values["l3"] < shortest or values["l3"] + travel > longest:
            found.add(path, f"the cylinder, {values['l3']:g} to {values['l3'] + travel:g} m long over its travel, cannot reach between "
                            f"mounts l1 = {values['l1']:g} m and l2 = {values['l2']:g} m from the joint (needs {shortest:g} to {longest:g} m)")


def _valve(found: _Problems, path: str, node: Any) -> None:
    if not isinstance(node, dict):
        found.add(path, "missing" if node is None else "must be a mapping")
        return
    found.unknown(node, path, VALVE_KEYS)
    kind = node.get("type", "proportional")
    if kind not in ("proportional", "mobile"):
        found.add(f"{path}.type", f"{kind!r}: expected proportional or mobile")
    rules = {**VALVE, **(MOBILE_VALVE if kind == "mobile" else {})}
    found.numbers(node, path, rules, required=tuple(k for k in rules if k != "deadzone"))
    for section, rule in (("kv_poly", None), ("centre_leakage", nonnegative("m^3/(s Pa)", 1.0e-6))):
        table = node.get(section)
        if not isinstance(table, dict):
            found.add(f"{path}.{section}", "missing: one entry per notch (PA, PB, AT, BT)")
            continue
        found.unknown(table, f"{path}.{section}", set(NOTCHES))
        for notch in NOTCHES:
            if notch not in table:
                found.add(f"{path}.{section}.{notch}", "missing")
            elif rule is not None:
                found.numbers(table, f"{path}.{section}", {notch: rule})
            else:
                poly = table[notch]
                numbers = [_number(c) for c in poly] if isinstance(poly, (list, tuple)) else []
                # a commissioned polynomial holds where the notch was seen open, so its value elsewhere is not checked
                if len(numbers) != 4 or None in numbers:
                    found.add(f"{path}.kv_poly.{notch}", f"{poly!r}: expected 4 numbers [c3, c2, c1, c0] (m^3/(s Pa^0.5))")


def keyed_lines(text: str) -> list[tuple[int, str, str]]:
    """(line index, key path, end-of-line comment) of every key in a YAML text, a list entry named by its ``name`` or
    ``joint`` (``joints[lift].cylinder.area_a``, ``arm.links[arm_joint]``)."""
    out: list[tuple[int, str, str]] = []
    stack: list[tuple[int, str]] = []  # (indent, key)
    for index, line in enumerate(text.splitlines()):
        match = re.match(r"^(\s*)(- )?([A-Za-z_][\w.]*|'[^']*'|\"[^\"]*\")\s*:(.*)$", line)
        if not match or line.lstrip().startswith("#"):
            continue
        indent, item, key, rest = len(match.group(1)), match.group(2), match.group(3).strip("'\""), match.group(4)
        while stack and stack[-1][0] >= indent:
            stack.pop()
        value, _, comment = rest.partition("#")
        if item and key in ("name", "joint"):
            stack.append((indent, f"[{value.strip()}]"))
        else:
            stack.append((indent + (2 if item else 0), key))
        out.append((index, "".join(k if k.startswith("[") or not i else f".{k}" for i, (_, k) in enumerate(stack)), comment.strip()))
    return out


@cache  # REFERENCE is fixed: compiled once, not for every key a file holds
def _reference_patterns() -> list[tuple[re.Pattern[str], dict[str, Rule]]]:
    out = []
    for section, rules, _ in REFERENCE:
        base = section.partition(" (")[0]
        pattern = "".join(r"[^.\[\]]+" if part == "<name>" else r"\[[^\]]*\]" if part == "[]" else re.escape(part)
                          for part in re.split(r"(<name>|\[\])", base))
        out.append((re.compile(rf"^{pattern}\.([^.\[\]]+)$" if base else r"^([^.\[\]]+)$"), rules))
    return out


def rules_for(key_path: str) -> list[Rule]:
    """The rules REFERENCE declares for a key path as ``keyed_lines`` writes it (``actuators.boom.cylinder.stroke``,
    ``arm.links[boom_joint].length``): one, or two where a section's kind decides (a linear or a triangle mount)."""
    return [rules[hit.group(1)] for pattern, rules in _reference_patterns() if (hit := pattern.match(key_path)) and hit.group(1) in rules]


def accepted(rule: Rule) -> str:
    """What a rule accepts, as docs/reference/config.md and `machine new` write it."""
    low = "" if rule.low is None else f"{'>' if rule.open_low else '>='} {rule.low:g}"
    high = "" if rule.high is None else f"<= {rule.high:g}"
    default = "" if rule.default is None else f"default {rule.default:g}"
    return ", ".join(part for part in (low, high, default) if part) or "finite"


def annotated_values(path: str | Path) -> list[str]:
    """``key.path: comment`` for every value whose comment in the file says PLACEHOLDER or INFERRED (this file only,
    not the one it extends)."""
    return [f"{key}: {comment}" for _, key, comment in keyed_lines(Path(path).read_text()) if any(word in comment for word in ANNOTATIONS)]
