"""``hydro-ros sim``: a machine under its simulated operator (or a crane working a stored path) into a contract bag."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydro_ros.cli.common import SECONDS, SEED, add_config, add_quiet, bag_or_nothing, injections, number
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import INJECTION_UNITS


def register(sub: argparse._SubParsersAction) -> None:
    units = "; ".join(f"{name}: {unit}" for name, unit in sorted(INJECTION_UNITS.items()))
    sim = sub.add_parser(
        "sim",
        help="simulate a scenario into a contract bag",
        description=f"Simulate the machine under its simulated operator into a contract bag. VALUE units: {units}.",
    )
    add_config(sim)
    sim.add_argument("--duration", type=SECONDS, required=True, help="simulated seconds")
    sim.add_argument("--fault", action="append", default=[], metavar="NAME=VALUE@T[:RAMP]",
                     help="fault switched on at T s, developing linearly over RAMP s (repeatable); on a machine of several "
                          "actuators ACTUATOR:NAME=VALUE@T[:RAMP], e.g. lift:external_leakage_a=1.0@20")
    sim.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                     help="physical effect present from the start (repeatable); on a machine of several actuators "
                          "ACTUATOR:NAME=VALUE; on a crane or an arm payload_mass=KG (also as a timed --fault) at the tip")
    sim.add_argument("--seed", type=SEED, default=0, help="random seed of operator and sensor noise")
    sim.add_argument("--path", default=None, help="crane only: work this path id's trajectory (forwards, hold, back, hold) in "
                                                "place of the random operator")
    sim.add_argument("--method", default=None, help="crane only: the trajectory method of --path (default dp_cp)")
    sim.add_argument("--db", default=None, help="crane only: trajectory database --path is served from; default: plan it now")
    sim.add_argument("--hold", type=number(float, 0.0, 3600.0, unit="s"), default=None, help="crane only: [s] hold at either end of the work cycle (default 4)")
    sim.add_argument("--out", required=True, help="bag directory to create (must not exist)")
    add_quiet(sim)
    sim.set_defaults(func=cmd_sim)


def actuatorinjections(args: argparse.Namespace, machine, machine_wide: dict[str, str]) -> tuple[dict[str, list], list, dict[str, list]]:
    """--fault / --effect of each actuator (ACTUATOR:NAME=VALUE@T[:RAMP]); a one-actuator machine may leave its actuator
    out. ``machine_wide``: names that act on the whole machine (a crane's or an arm's payload), with where they act; the
    truth lists them as ``payload``."""
    by_actuator: dict[str, list] = {}
    shared: list = []
    truth: dict[str, list] = {"faults": [], "effects": [], **({"payload": []} if machine_wide else {})}
    for kind, texts in (("fault", args.fault), ("effect", args.effect)):
        for text in texts:
            actuator, separator, spec = text.partition(":")
            named = bool(separator) and "=" not in actuator
            injection = injections([spec if named else text], kind, kind == "fault")[0]
            if injection.onset_s >= args.duration:
                raise InputError(f"--{kind} {text!r}: starts after the run's end ({args.duration:g} s)")
            if not named:
                if injection.name in machine_wide:
                    shared.append(injection)
                    truth["payload"].append({"name": injection.name, "value": injection.value, "onset_s": injection.onset_s,
                                             "ramp_s": injection.ramp_s})
                    continue
                if len(machine.actuators) > 1:
                    form = "ACTUATOR:NAME=VALUE@T[:RAMP]" if kind == "fault" else "ACTUATOR:NAME=VALUE"
                    alone = "".join(f"; {name} alone is {where}" for name, where in machine_wide.items())
                    raise InputError(f"--{kind} {text!r}: on a machine of several actuators {'an' if kind == 'effect' else 'a'} {kind} "
                                     f"names its cylinder: {form} "
                                     f"(actuators: {', '.join(machine.actuator_names)}{alone})")
                actuator = machine.first.name
            if actuator not in machine.actuator_names:
                raise InputError(f"--{kind} {text!r}: no actuator {actuator!r} (actuators: {', '.join(machine.actuator_names)})")
            by_actuator.setdefault(actuator, []).append(injection)
            truth[f"{kind}s"].append({"actuator": actuator, "name": injection.name, "value": injection.value,
                                      "onset_s": injection.onset_s, "ramp_s": injection.ramp_s})
    return by_actuator, shared, truth


def cmd_sim(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.bags.writer import ContractBagWriter
    from hydro_ros.sim.scenario import MachineRun
    from hydro_ros.workflows.plots import plot_bag

    machine = load_machine_config(args.config)
    if args.duration <= 0:
        raise InputError(f"--duration {args.duration}: must be > 0 s")
    given = [f"--{name}" for name in ("path", "method", "db", "hold") if getattr(args, name) is not None]
    if machine.planned:
        if given and args.path is None:
            raise InputError(f"{', '.join(given)}: only with --path (the stored trajectory the crane works)")
        with bag_or_nothing(args.out):
            return sim_crane(args, machine)
    if given:
        raise InputError(f"{', '.join(given)}: planned machines only ({args.config} has no planner: section)")
    # an arm's payload hangs at its tip (MachineRun takes it from any actuator's list)
    injections, payload, truth = actuatorinjections(args, machine, {"payload_mass": "at the tip"} if machine.arm is not None else {})
    injections.setdefault(machine.first.name, []).extend(payload)
    plant = MachineRun(machine, injections, seed=args.seed)
    total = int(round(args.duration * machine.sample_rate_hz))
    with bag_or_nothing(args.out):
        writer = ContractBagWriter(args.out, actuators={a.name: a.joint for a in machine.actuators},
                                   pressure_variance=machine.sensors.pressure_noise_std ** 2, mobile=machine.mobile)
        with writer, tqdm(total=total, unit="sample", desc="simulate", disable=args.quiet) as bar:
            writer.set_truth({"machine": machine.name, "config": machine.source.name, "seed": args.seed, "duration_s": args.duration,
                              "actuators": machine.actuator_names, **truth})
            for _, block in plant.blocks(args.duration, progress=bar.update):
                writer.write_machine_block(block)
    plot = plot_bag(read_bag(args.out), Path(str(args.out).rstrip("/") + ".png"))
    print(json.dumps({"bag": str(args.out), "messages": writer.messages, "plot": str(plot)}))
    return 0


def sim_crane(args: argparse.Namespace, machine) -> int:
    """A crane's cylinders at work, under the simulated operator or working a stored path; faults name their cylinder
    (ACTUATOR:NAME=VALUE@T)."""
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.bags.writer import ContractBagWriter
    from hydro_ros.models.crane import load_crane
    from hydro_ros.models.serial_arm import SerialArm
    from hydro_ros.sim.arm_cylinders import ArmCylinders, ArmRun
    from hydro_ros.workflows.plots import plot_bag

    # a crane's payload hangs at its tip, on no one cylinder
    faults, payload, truth = actuatorinjections(args, machine, {"payload_mass": "at the tip"})
    _, crane_config = load_crane(args.config)
    trajectory, work = None, None
    method, hold = args.method or "dp_cp", 4.0 if args.hold is None else args.hold
    if hold < 0:
        raise InputError(f"--hold {hold}: must be >= 0 s")
    if args.path:
        from hydro_ros.planning.serving import executable_trajectory

        trajectory, _ = executable_trajectory(crane_config, args.path, method, database=args.db)
        work = {"path": args.path, "method": method, "hold_s": hold, "source": args.db or "planned"}
    run = ArmRun(args.duration, seed=args.seed, faults=faults, payload=payload, trajectory=trajectory, hold_s=hold)
    plant = ArmCylinders(machine, SerialArm.of(machine), run)
    writer = ContractBagWriter(args.out, actuators={a.name: a.joint for a in machine.actuators},
                               pressure_variance=machine.sensors.pressure_noise_std ** 2, mobile=machine.mobile)
    with writer, tqdm(total=int(round(args.duration * machine.sample_rate_hz)), unit="sample", desc="simulate", disable=args.quiet) as bar:
        writer.set_truth({"machine": machine.name, "config": machine.source.name, "seed": args.seed, "duration_s": args.duration,
                          "work_cycle": work,
                          **truth})
        for _, block in plant.blocks():
            writer.write_machine_block(block)
            bar.update(len(block))
    plot = plot_bag(read_bag(args.out), Path(str(args.out).rstrip("/") + ".png"))
    print(json.dumps({"bag": str(args.out), "messages": writer.messages, "plot": str(plot)}))
    return 0
