"""``hydro-ros machine check|new|threshold``, ``hydro-ros params`` and ``hydro-ros foxglove layout``: a machine described,
checked, given a safe threshold, brought up."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

from hydro_ros.cli.common import COUNT, SECONDS, add_config, add_out, new_output, number, output_file, write_json
from hydro_ros.contract.config import write_extending
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config


def register(sub: argparse._SubParsersAction) -> None:
    machine = sub.add_parser("machine", help="describe your own machine: check a config, start a new one",
                             description="A machine config describes every actuator (cylinder, mount, valve, fluid, friction), "
                             "the links they move (arm: or each actuator's own load), "
                             "the sensors and the supply, in SI units.")
    verbs = machine.add_subparsers(dest="machine_command", required=True)
    check = verbs.add_parser("check", help="every problem of a machine config at once, and the values it marks as not measured",
                             description="Exit 1 when the config breaks a rule (each printed with its key path, value, unit "
                             "and rule); every other command refuses such a config with the same messages.")
    check.add_argument("config", help="machine config (YAML)")
    check.add_argument("--quiet", action="store_true", help="only the problems, not the PLACEHOLDER / INFERRED values")
    check.add_argument("--plot", default=None, help="draw the machine as configured (links at their reach, cylinders) to this PNG")
    check.set_defaults(func=cmd_machine_check)
    threshold = verbs.add_parser("threshold", help="a safe threshold before commissioning, derived from the machine's own "
                                 "description", description="Simulate fault-free builds of the machine and take a margin over "
                                 "the largest 5 s mean residual: the UKF monitor's fdi.threshold_constant until `hydro-ros "
                                 "commission` replaces it. An arm of revolute links on triangle-mounted cylinders is built by a "
                                 "plant written apart from the model (its own notch curves, lines, friction law, oil and "
                                 "sensors, every number drawn off the data sheet); any other machine by the model's own "
                                 "equations with its numbers drawn off, which is safe only for a machine like the model (the "
                                 "output says so).")
    threshold.add_argument("config", help="machine config (YAML)")
    threshold.add_argument("--variants", type=COUNT, default=8, help="simulated variants (default 8)")
    threshold.add_argument("--duration", type=SECONDS, default=120.0, help="[s] simulated per variant (default 120)")
    threshold.add_argument("--margin", type=number(float, 1.0, 100.0), default=1.25, help="factor over the largest excess (default 1.25)")
    add_out(threshold, "write a config that extends CONFIG with this threshold", required=False)
    threshold.set_defaults(func=cmd_machine_threshold)
    new = verbs.add_parser("new", help="write a commented starting point for your machine's config",
                           description="Copy a shipped config with its comments (where each value comes from); beside each value its unit "
                                       "and the range `machine check` accepts, from the declarations.")
    new.add_argument("--like", required=True, choices=("sam", "boom_arm", "k70m"),
                     help="sam: one boom; boom_arm: several joints, each a cylinder; k70m: a redundant crane (the planner's)")
    add_out(new, "the new config file")
    new.set_defaults(func=cmd_machine_new)

    upgrade = verbs.add_parser("upgrade", help="write a crane-form config (kind: crane) in the machine form",
                               description="Each cylinder once (actuators:), the chain once (arm:, its slewing base arm.slew), the "
                               "planner's limits, hydraulics, grid and paths in planner:; every number the planner and the "
                               "monitor read comes out the same, each value's comment (its source) beside its new key. The "
                               "old file is left as it is; --out must not exist.")
    upgrade.add_argument("config", help="crane-form config (YAML)")
    add_out(upgrade, "the machine-form config to write")
    upgrade.set_defaults(func=cmd_machine_upgrade)

    params = sub.add_parser("params", help="the commented params file of a machine's bring-up (can_bridge, fdi_node, hmi)",
                            description="Print the ros__parameters of the nodes launch/machine.launch.py starts, every "
                            "parameter with its unit, default and range, from the nodes' own tables.")
    add_config(params, "machine config, e.g. config/sam.yaml or your own")
    params.set_defaults(func=cmd_params)

    sros2 = sub.add_parser("sros2", help="SROS2 for a machine")
    sros2_verbs = sros2.add_subparsers(dest="sros2_command", required=True)
    policy = sros2_verbs.add_parser("policy", help="the SROS2 access-control policy of a machine in a namespace",
                                    description="Print config/sros2/policy.xml for the machine in NAMESPACE (machine.launch.py's "
                                    "namespace): every enclave with only the access it needs, its names in that namespace.")
    policy.add_argument("--namespace", default="", help="the machine's namespace (m1); empty: the root namespace")
    policy.set_defaults(func=cmd_sros2_policy)

    aggregator = sub.add_parser("aggregator", help="diagnostic_aggregator for machines on one graph")
    aggregator_verbs = aggregator.add_subparsers(dest="aggregator_command", required=True)
    grouped = aggregator_verbs.add_parser("config", help="an aggregator config grouping by machine, then by function",
                                          description="Print config/diagnostic_aggregator.yaml for the machines in the given "
                                          "namespaces: a group per machine, in it a group per function.")
    grouped.add_argument("--namespace", action="append", required=True,
                         help="a machine's namespace (m1), once per machine; '' for one in the root namespace")
    grouped.set_defaults(func=cmd_aggregator_config)

    foxglove = sub.add_parser("foxglove", help="Foxglove for a machine")
    verbs = foxglove.add_subparsers(dest="foxglove_command", required=True)
    layout = verbs.add_parser("layout", help="a Foxglove layout for a machine: every actuator's status and residual plots",
                              description="Write the Foxglove layout of a machine config (import it in Foxglove: Layouts, Import).")
    add_config(layout)
    add_out(layout, "layout JSON to write")
    layout.add_argument("--namespace", default="", help="the machine's namespace (machine.launch.py's namespace argument)")
    layout.set_defaults(func=cmd_foxglove_layout)


def cmd_machine_check(args: argparse.Namespace) -> int:
    from hydro_ros.contract.check import annotated_values, config_problems, crane_problems, planner_problems
    from hydro_ros.contract.config import read_config
    from hydro_ros.contract.upgrade import is_crane_form, upgraded

    config = read_config(args.config, required=(), nonempty="machine")
    problems = []
    if is_crane_form(config):  # checked in its own terms, then read converted as every tool reads it
        problems = crane_problems(config)
        if not problems:
            print(f"{args.config}: warning: in the crane form (kind: crane), read converted; `hydro-ros machine upgrade "
                  f"{args.config} --out NEW` writes it in the machine form")
            config, _ = upgraded(config, args.config)
    planned = "planner" in config
    # a config without sensors describes only what the planner needs (config/crane3dof.yaml, config/excavator.yaml)
    planner_only = planned and "sensors" not in config
    if not problems:
        problems = [] if planner_only else config_problems(config)
        if planned:
            problems += [problem for problem in planner_problems(config) if problem not in problems]
    for problem in problems:
        print(f"{args.config}: {problem}")
    if planned and not problems:
        problems += planner_checks(config, args.config)
        for problem in problems:
            print(problem if problem.startswith("config ") else f"{args.config}: {problem}")
        if planner_only and not problems:
            missing = config_problems(config)
            print(f"{args.config}: not monitored: the monitor would need " + "; ".join(missing[:3])
                  + (f"; and {len(missing) - 3} more" if len(missing) > 3 else "")
                  + " (valves, fluid, friction, sensors and a sample rate, as config/boom_arm.yaml has)")
    if not planner_only and not problems:
        from hydro_ros.can.codec import BusMapError, MachineBus
        from hydro_ros.fdi.settings import unset_threshold
        from hydro_ros.models.serial_arm import holding

        machine = load_machine_config(args.config)
        problems, corners = holding(machine)
        try:  # the bus as can_bridge and bag convert will read it: the DBC beside the config, the map against it
            MachineBus(machine)
        except BusMapError as exc:
            problems += exc.problems
        for problem in problems:
            print(f"{args.config}: {problem}")
    if not planner_only and not problems:
        print(f"{args.config}: {machine.name}: {len(machine.actuators)} actuator(s) "
              f"({', '.join(f'{a.name} on {a.joint}' for a in machine.actuators)}), {machine.sample_rate_hz:g} Hz, "
              f"supply {machine.supply_pressure / 1e6:g} MPa: ok")
        advice = unset_threshold(machine)
        if advice:
            print(f"{args.config}: warning: {advice}")
        for warning in [*reach_warnings(machine), *corners]:
            print(f"{args.config}: warning: {warning}")
        if args.plot:
            from hydro_ros.workflows.plots import plot_machine

            print(f"{args.config}: picture {plot_machine(machine, args.plot)}")
    notes = annotated_values(args.config)
    if notes and not args.quiet:
        print(f"{len(notes)} value(s) the file marks as not measured (replace them with your data sheet's or your measurement):")
        for note in notes:
            print(f"  {note}")
    return 1 if problems else 0


def planner_checks(config: dict, source: str) -> list[str]:
    """What the planner refuses of a config its checks accept: the chain (one redundant joint, two revolute ones solved for
    the tip), and each path sampled and reached (a point out of reach, or only with a stretched elbow, named with its
    time). Prints what it plans along when all is well."""
    from hydro_ros.contract.check import DP_GRID_MIN
    from hydro_ros.contract.crane import parse_planning
    from hydro_ros.models.crane import Crane
    from hydro_ros.planning.problem import Problem

    try:
        crane = Crane(parse_planning(config, Path(source).resolve()))
    except InputError as exc:
        return [str(exc)]
    problems = grid_problems(crane.config)
    for path_id in crane.config.paths:
        try:
            Problem.build(crane, crane.config, path_id, grid=(DP_GRID_MIN,) * 3)
        except InputError as exc:  # the path's own form, its reach, its start
            problems.append(str(exc) if str(exc).startswith("path") else f"path {path_id!r}: {exc}")
    if not problems:
        print(f"{source}: {crane.name}: planned along {', '.join(crane.config.paths)} (each within reach), redundant joint "
              f"{crane.extension.name}, the tip solved by {' and '.join(crane.solved_names)}"
              + (f", {crane.names[0]} turning the chain" if crane.base_rotation else "") + ": ok")
    return problems


def grid_problems(config) -> list[str]:
    """The DP grids a crane config plans on (``dp.grid``, and ``catalog.grid`` where given) as the planner would refuse
    them (an even velocity or control count), each named by its key, so that a check says so before a plan is asked for."""
    from hydro_ros.planning.dp import grid_sizes

    prefix = "planner." if "planner" in config.mapping else ""  # the machine form's section, or the crane form's top level
    problems = []
    for key, grid in (("dp.grid", config.dp.grid), ("catalog.grid", config.catalog.get("grid"))):
        if grid is None:
            continue
        if not (isinstance(grid, list | tuple) and len(grid) == 3 and all(isinstance(n, int) and not isinstance(n, bool) for n in grid)):
            problems.append(f"{prefix}{key} {grid!r}: expected three whole numbers [positions, velocities, controls]")
            continue
        try:
            grid_sizes(tuple(grid))
        except InputError as exc:
            problems.append(f"{prefix}{key}: {exc}")
    return problems


def reach_warnings(machine) -> list[str]:
    """Where the joint travel the cylinders allow and the ranges the config gives for it disagree."""
    from hydro_ros.models.kinematics import joint_reach
    from hydro_ros.models.sam import SamModel

    out = []
    plausible = machine.sensors.joint_range
    operator = machine.excitation.joint_range
    for actuator in machine.actuators:
        model = SamModel(machine, actuator.name)
        low, high = joint_reach(model.mount, *model.end_stops)
        reach = f"{actuator.name}'s cylinder moves its joint {low:.3f} to {high:.3f}"
        if low < plausible[0] or high > plausible[1]:
            out.append(f"sensors.joint_range {list(plausible)}: {reach}; a reading in that travel would be called implausible")
        if machine.arm is None and (operator[0] < low or operator[1] > high):
            out.append(f"excitation.joint_range {list(operator)}: {reach}; the simulated operator drives it into the end stops")
    if machine.arm is not None:
        for section, key in (("excitation", "joint_range"), ("simulation", "initial_joint_position")):
            if key in (machine.mapping.get(section) or {}):
                out.append(f"{section}.{key}: not used on an arm: its simulated operator moves each joint within 80 % of its "
                           "arm.links range, from the middle")
    return out


def cmd_machine_threshold(args: argparse.Namespace) -> int:
    from hydro_ros.fdi.settings import FdiSettings
    from hydro_ros.studies.fdi_evaluation import MISMATCH_SPREAD, safe_threshold_constant

    machine = load_machine_config(args.config)
    if FdiSettings.from_machine(machine).method != "ukf":
        raise InputError(f"{args.config}: the parity method's thresholds are fitted by `hydro-ros fdi fit`, not derived here")
    if args.variants < 1 or args.duration <= 0:
        raise InputError(f"--variants {args.variants} --duration {args.duration}: need at least one variant and a positive duration")
    c0, apart = safe_threshold_constant(machine, range(1000, 1000 + args.variants), args.duration, args.margin)
    if not apart:
        print(f"{machine.name}: threshold_constant {c0:.4f} MPa: {args.margin:g} x the largest fault-free 5 s mean residual above "
              f"the quadratic term on {args.variants} builds of this machine of {args.duration:g} s each by a plant written apart "
              "from the model (studies/independent_arm: its own links, notch curves, lines, friction law, oil and sensors)")
    else:
        print(f"{machine.name}: threshold_constant {c0:.4f} MPa: {args.margin:g} x the largest fault-free 5 s mean residual above "
              f"the quadratic term on {args.variants} variants of {args.duration:g} s each of the model's own equations "
              f"({MISMATCH_SPREAD}): safe only for a machine like the model, as no plant written apart can build this one "
              f"({apart}); commission it before trusting its silence")
    if args.out:
        out = Path(args.out)
        if out.resolve() == Path(args.config).resolve():
            raise InputError(f"--out {out}: is the config itself; write a config that extends it")
        write_extending(Path(args.config), out, f"# {machine.name} with a threshold derived by `hydro-ros machine threshold` from "
                        f"{args.variants} simulated {'builds' if not apart else 'variants'};\n# safe until `hydro-ros commission` "
                        "identifies the machine. Regenerate, do not edit.\n", {"fdi": {"threshold_constant": round(c0, 4)}})
        print(f"{out}: written")
    return 0


def cmd_machine_new(args: argparse.Namespace) -> int:
    from hydro_ros.contract.config import default_config_path

    out = Path(args.out)
    if out.exists():
        raise InputError(f"--out {out}: exists; choose a new file")
    if not out.parent.is_dir():
        raise InputError(f"--out {out}: directory {out.parent} does not exist")
    source = default_config_path(args.like)
    text = source.read_text()
    if "\nextends:" in "\n" + text:
        raise InputError(f"--like {args.like}: extends another config; start from the one it extends")
    header = (f"# Your machine, started from hydro_ros's {source.name} (`hydro-ros machine new --like {args.like}`).\n"
              f"# Replace every value with your machine's, then run `hydro-ros machine check {out}`.\n")
    text = text.replace(f"machine: {args.like}\n", f"machine: {out.stem}\n", 1)
    # the shipped machine's threshold is not yours: machine check then says how to derive one
    text = re.sub(r"(?m)^(\s*)threshold_constant:.*$", rf"\1# threshold_constant: yours from `hydro-ros machine threshold {out}`", text)
    out.write_text(header + with_accepted_ranges(text))
    print(f"{out}: written from {source.name}; next: hydro-ros machine check {out}")
    return 0


def with_accepted_ranges(text: str) -> str:
    """Each value a rule declares gets what `machine check` accepts beside its unit (``# [m; > 0, <= 20] ...``), from the
    declarations (``contract.schema``, check's tables). Left as written: a key whose section's kind decides its rule (a
    mount's theta_offset), the slew's rate limits (in its drive's units, not a cylinder's), and a line whose value holds
    a quote or a '#' (a YAML string the comment must not cut)."""
    import yaml

    from hydro_ros.contract.check import accepted, keyed_lines, rules_for

    slew = ((yaml.safe_load(text) or {}).get("arm") or {}).get("slew") or {}
    lines = text.splitlines()
    for index, key, comment in keyed_lines(text):
        rules = rules_for(key)
        code, hash_sign, _ = lines[index].partition("#")
        if (len(rules) != 1 or key.startswith(f"planner.actuators.{slew.get('joint')}.") or "'" in code or '"' in code
                or (hash_sign and not code.endswith((" ", "\t")))):
            continue
        rest = re.sub(r"^\[[^\]]*\]\s*", "", comment) if hash_sign else ""
        lines[index] = f"{code.rstrip():<31} # [{rules[0].unit or '-'}; {accepted(rules[0])}]" + (f" {rest}" if rest else "")
    return "\n".join(lines) + ("\n" if text.endswith("\n") else "")


def cmd_machine_upgrade(args: argparse.Namespace) -> int:
    from hydro_ros.contract.upgrade import upgraded_text

    out = new_output(args.out)
    out.write_text(upgraded_text(Path(args.config)))
    print(f"{out}: {args.config} in the machine form; next: hydro-ros machine check {out}")
    return 0


def cmd_aggregator_config(args: argparse.Namespace) -> int:
    from hydro_ros.nodes.bringup import aggregator_config

    print(aggregator_config(args.namespace), end="")
    return 0


def cmd_sros2_policy(args: argparse.Namespace) -> int:
    from hydro_ros.nodes.bringup import sros2_policy

    print(sros2_policy(args.namespace), end="")
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from hydro_ros.nodes.bringup import machine_params

    load_machine_config(args.config)
    print(machine_params(Path(args.config)), end="")
    return 0


def cmd_foxglove_layout(args: argparse.Namespace) -> int:
    from hydro_ros.hmi.foxglove_layout import foxglove_layout

    layout = foxglove_layout(load_machine_config(args.config), args.namespace)
    write_json(output_file(args.out), layout)
    print(json.dumps({"layout": args.out, "panels": len(layout["configById"])}))
    return 0
