"""``hydro-ros``: the package's one command line (contract section 5).

Every sub-command exits 0 on success and non-zero with a one-line error naming the bad input.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import shutil
import sys
import time
from pathlib import Path
from typing import Callable, Iterator, Sequence

from hydro_ros.contract.config import plain_data, write_extending
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import INJECTION_UNITS, parse_injection


def _injections(texts: Sequence[str], kind: str, timed: bool) -> list:
    out = []
    for text in texts:
        if not timed and "@" in text:
            raise InputError(f"--{kind} {text!r}: effects are present from t = 0; use --fault NAME=VALUE@T for timed faults")
        try:
            out.append(parse_injection(text))
        except InputError as exc:
            raise InputError(f"--{kind} {exc}") from None
    return out


def _actuator_injections(args: argparse.Namespace, machine, machine_wide: dict[str, str]) -> tuple[dict[str, list], list, dict[str, list]]:
    """--fault / --effect of each actuator (ACTUATOR:NAME=VALUE@T[:RAMP]); a one-actuator machine may leave its actuator
    out. ``machine_wide``: names that act on the whole machine (a crane's payload), with where they act."""
    by_actuator: dict[str, list] = {}
    shared: list = []
    truth: dict[str, list] = {"faults": [], "effects": []}
    for kind, texts in (("fault", args.fault), ("effect", args.effect)):
        for text in texts:
            actuator, separator, spec = text.partition(":")
            if not separator or "=" in actuator:
                injection = _injections([text], kind, kind == "fault")[0]
                if injection.name in machine_wide:
                    shared.append(injection)
                    continue
                if len(machine.actuators) > 1:
                    form = "ACTUATOR:NAME=VALUE@T[:RAMP]" if kind == "fault" else "ACTUATOR:NAME=VALUE"
                    alone = "".join(f"; {name} alone is {where}" for name, where in machine_wide.items())
                    raise InputError(f"--{kind} {text!r}: on a machine of several actuators a {kind} names its cylinder: {form} "
                                     f"(actuators: {', '.join(machine.actuator_names)}{alone})")
                actuator, spec = machine.first.name, text
            if actuator not in machine.actuator_names:
                raise InputError(f"--{kind} {text!r}: no actuator {actuator!r} (actuators: {', '.join(machine.actuator_names)})")
            injection = _injections([spec], kind, kind == "fault")[0]
            by_actuator.setdefault(actuator, []).append(injection)
            truth[f"{kind}s"].append({"actuator": actuator, "name": injection.name, "value": injection.value,
                                      "onset_s": injection.onset_s, "ramp_s": injection.ramp_s})
    return by_actuator, shared, truth


def _one_actuator(machine, name: str | None, study: str):
    """The machine restricted to the actuator a one-cylinder study looks at: named with --actuator where there are several."""
    if name is None:
        if len(machine.actuators) > 1:
            raise InputError(f"--actuator: {study} looks at one cylinder and {machine.name} has {len(machine.actuators)} "
                             f"({', '.join(machine.actuator_names)}); name one")
        return machine
    return machine.only(name)


@contextlib.contextmanager
def _bag_or_nothing(out: str) -> Iterator[None]:
    """A bag folder this command creates is removed if the run fails, so the rerun is not refused as an existing bag."""
    existed = Path(out).exists()
    try:
        yield
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        raise


def cmd_sim(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.bags.writer import ContractBagWriter
    from hydro_ros.sim.scenario import MachineRun
    from hydro_ros.studies.plots import plot_bag

    machine = load_machine_config(args.config)
    if args.duration <= 0:
        raise InputError(f"--duration {args.duration}: must be > 0 s")
    given = [f"--{name}" for name in ("path", "method", "db", "hold") if getattr(args, name) is not None]
    if machine.crane:
        if given and args.path is None:
            raise InputError(f"{', '.join(given)}: only with --path (the stored trajectory the crane works)")
        with _bag_or_nothing(args.out):
            return _sim_crane(args, machine)
    if given:
        raise InputError(f"{', '.join(given)}: crane configs only ({args.config} is not a crane)")
    injections, _, truth = _actuator_injections(args, machine, {})
    plant = MachineRun(machine, injections, seed=args.seed)
    total = int(round(args.duration * machine.sample_rate_hz))
    with _bag_or_nothing(args.out):
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


def _sim_crane(args: argparse.Namespace, machine) -> int:
    """A crane's cylinders at work, under the simulated operator or working a stored path; faults name their cylinder
    (ACTUATOR:NAME=VALUE@T)."""
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.bags.writer import ContractBagWriter
    from hydro_ros.models.crane import load_crane
    from hydro_ros.sim.crane_cylinders import CraneCylinders, CraneRun
    from hydro_ros.studies.plots import plot_bag

    # a crane's payload hangs at its tip, on no one cylinder
    faults, payload, truth = _actuator_injections(args, machine, {"payload_mass": "at the tip"})
    _, crane_config = load_crane(args.config)
    trajectory, work = None, None
    method, hold = args.method or "dp_cp", 4.0 if args.hold is None else args.hold
    if hold < 0:
        raise InputError(f"--hold {hold}: must be >= 0 s")
    if args.path:
        from hydro_ros.planning.serving import executable_trajectory

        trajectory, _ = executable_trajectory(crane_config, args.path, method, database=args.db)
        work = {"path": args.path, "method": method, "hold_s": hold, "source": args.db or "planned"}
    run = CraneRun(args.duration, seed=args.seed, faults=faults, payload=payload, trajectory=trajectory, hold_s=hold)
    plant = CraneCylinders(machine, crane_config, run)
    writer = ContractBagWriter(args.out, actuators={a.name: a.joint for a in machine.actuators},
                               pressure_variance=machine.sensors.pressure_noise_std ** 2, mobile=machine.mobile)
    with writer, tqdm(total=int(round(args.duration * machine.sample_rate_hz)), unit="sample", desc="simulate", disable=args.quiet) as bar:
        writer.set_truth({"machine": machine.name, "config": machine.source.name, "seed": args.seed, "duration_s": args.duration,
                          "work_cycle": work,
                          **truth, "payload": [{"name": i.name, "value": i.value, "onset_s": i.onset_s, "ramp_s": i.ramp_s}
                                               for i in payload]})
        for _, block in plant.blocks():
            writer.write_machine_block(block)
            bar.update(len(block))
    plot = plot_bag(read_bag(args.out), Path(str(args.out).rstrip("/") + ".png"))
    print(json.dumps({"bag": str(args.out), "messages": writer.messages, "plot": str(plot)}))
    return 0


def cmd_fdi(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.fdi.offline import prepare, run_monitor
    from hydro_ros.studies.plots import plot_fdi

    machine = load_machine_config(args.config)
    out = Path(args.json)
    if not out.parent.is_dir():
        raise InputError(f"--json {out}: directory {out.parent} does not exist")
    data, monitor, samples = prepare(args.bag, machine, args.method)
    with tqdm(total=len(samples), unit="sample", desc="fdi", disable=args.quiet) as bar:
        run = run_monitor(monitor, samples, progress=bar.update)
    run.data = data
    result = run.to_json()
    plot = plot_fdi(run, out.with_suffix(".png"))
    result["plot"] = str(plot)
    out.write_text(json.dumps(result, indent=2) + "\n")
    for message in result.get("errors", []):
        print(f"hydro-ros fdi: warning: {message}", file=sys.stderr)
    for name, actuator in result["actuators"].items():
        print(f"{name}: {actuator['fault']} (first detection {actuator['first_detection_s']} s)")
    return 0


def cmd_fdi_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.fdi_evaluation import evaluate, markdown_table
    from hydro_ros.studies.plots import plot_fdi_evaluation

    machine = load_machine_config(args.config)
    for name in ("seeds", "calibration_seeds", "workers"):
        if getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} {getattr(args, name)}: must be >= 1")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tqdm(unit="run", desc="fdi-eval", disable=args.quiet) as bar:
        summary = evaluate(machine, seeds=args.seeds, calibration_seeds=args.calibration_seeds, duration_s=args.duration,
                           fault_free_minutes=args.fault_free_minutes, workers=args.workers, progress=bar.update)
    (out / "fdi_eval.json").write_text(json.dumps(summary, indent=2) + "\n")
    table = markdown_table(summary)
    (out / "fdi_eval.md").write_text(table)
    plot_fdi_evaluation(summary, out / "fdi_eval.png")
    print(table)
    return 0


def cmd_fdi_fit(args: argparse.Namespace) -> int:
    from hydro_ros.studies.fdi_evaluation import build_parity_signatures, fit_parity_thresholds, write_fitted_block

    machine = load_machine_config(args.config)
    if args.train < 1 or args.held_out < 1:
        raise InputError("--train and --held-out must be >= 1")
    if machine.crane:
        return _fdi_fit_crane(args, machine)
    print(f"fitting parity thresholds on {args.train} fault-free mismatched plants, checking on {args.held_out} others ...")
    thresholds, report = fit_parity_thresholds(machine, range(100, 100 + args.train), range(300, 300 + args.held_out))
    print(f"threshold factor {thresholds.factor:g} ({report['false_alarms_per_hour']:.2f} false alarms/h held out)"
          if "false_alarms_per_hour" in report else f"no factor met the target: {report['tried']}")
    print("building the signature table by simulating the P-IV fault list ...")
    rows = build_parity_signatures(machine, thresholds, range(100, 100 + args.signature_seeds))
    for row in rows:
        print(f"  {row['fault']:34s} {row['code']}  command {'any' if row['command_positive'] is None else ('+' if row['command_positive'] else '-')}")
    if args.write:
        write_fitted_block(Path(args.config), thresholds, rows,
                           f"parity thresholds from fault-free mismatched plants, factor {thresholds.factor:g} for <= 1 false alarm/h on "
                           f"{report['held_out_hours']:.2f} h held out; signature table by simulation of the P-IV fault list.")
        print(f"written to {args.config}")
    return 0


def _fdi_fit_crane(args: argparse.Namespace, machine) -> int:
    """A crane's thresholds from its cylinders at work (studies.crane_monitoring); the signature table stays the config's."""
    from tqdm import tqdm

    from hydro_ros.models.crane import load_crane
    from hydro_ros.studies.crane_monitoring import fit_crane_thresholds, path_trajectories
    from hydro_ros.studies.fdi_evaluation import write_fitted_block

    _, crane_config = load_crane(args.config)
    trajectories = path_trajectories(crane_config)
    runs = (args.train + args.held_out) * (1 + len(trajectories))
    print(f"fitting the crane's thresholds: {args.train} nominal cranes at work, the factor on {args.held_out} mismatched ones "
          f"(the operator and paths {', '.join(trajectories)} each, 90 s, payload steps) ...")
    with tqdm(total=runs, unit="run", desc="fdi-fit", disable=args.quiet) as bar:
        thresholds, report = fit_crane_thresholds(machine, crane_config, trajectories, train=range(100, 100 + args.train),
                                                  held_out=range(300, 300 + args.held_out), progress=bar.update)
    print(f"threshold factors per flow bin {', '.join(f'{c:.3g}' for c in thresholds.factor)} = {report['margin']:g} x the "
          f"factor reached held out ({report['held_out_hours']:.2f} h), at least {report['margin']:g} x {report['floor']:g}")
    if args.write:
        write_fitted_block(Path(args.config), thresholds, None,
                           f"the crane's parity thresholds, binned on each chamber's mean valve flow, from {args.train} nominal cranes at "
                           f"work; factor per bin = {report['margin']:g} x the largest reached in it on {args.held_out} mismatched ones "
                           f"({report['held_out_hours']:.2f} h, payload steps, every path), at least {report['margin']:g} x "
                           f"{report['floor']:g}.")
        print(f"written to {args.config}")
    return 0


def cmd_commission(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.commissioning import commission, load_recordings, write_config
    from hydro_ros.studies.plots import plot_commissioning

    config, out = Path(args.config), Path(args.out)
    if out.resolve() == config.resolve():
        raise InputError(f"--out {out}: is the config it extends; write the commissioned config beside it")
    if not out.parent.is_dir():
        raise InputError(f"--out {out}: directory {out.parent} does not exist")
    machine = load_machine_config(config)
    recordings = load_recordings(args.bag, machine)
    with tqdm(total=len(machine.actuators) + len(recordings), unit="step", desc="commission", disable=args.quiet) as bar:
        block, report = commission(machine, recordings, progress=lambda _: bar.update(), force=args.force)
    write_config(config, out, block)  # first: the config is what the machine needs, the report what people read
    if args.report:
        report_dir = Path(args.report)
        report_dir.mkdir(parents=True, exist_ok=True)
        (report_dir / "commissioning.json").write_text(json.dumps(plain_data(report), indent=2) + "\n")
        plot_commissioning(report, machine, report_dir / "commissioning.png")
    for actuator, fit in block["fit"].items():
        gains = ", ".join(f"{n} {g:.3f}" for n, g in fit["notch_gain"].items())
        kept = f" ({', '.join(fit['shape_kept'])} seen only narrow: a gain on the nominal polynomial)" if fit["shape_kept"] else ""
        print(f"{actuator}: notch gains {gains}{kept}; flow error {fit['rms_flow_error_l_min']['nominal']:.3f} -> "
              f"{fit['rms_flow_error_l_min']['commissioned']:.3f} L/min")
    threshold = report["threshold"]

    def values(value: float | list[float] | None) -> str:
        return "none" if value is None else ", ".join(f"{v:.3g}" for v in value) if isinstance(value, list) else f"{value:.4g}"

    print(f"threshold {threshold['parameter']} {values(threshold['value'])} (config had {values(threshold['before'])}; "
          f"{threshold['form']}); written to {out}")
    return 0


def cmd_can_convert(args: argparse.Namespace) -> int:
    from hydro_ros.can.convert import convert_log

    machine = load_machine_config(args.config)
    if Path(args.out).exists():
        raise InputError(f"--out {args.out}: already exists, refusing to overwrite")
    with _bag_or_nothing(args.out):
        report = convert_log(args.logfile, machine, args.out, dbc=args.dbc)
    print(json.dumps({"bag": str(args.out), **report.to_json()}))
    return 0


def cmd_gsa(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.gsa import LEAKS, PARAMETERS, interaction, ranking, sobol_indices
    from hydro_ros.studies.plots import plot_gsa

    machine = _one_actuator(load_machine_config(args.config), args.actuator, "gsa")
    if args.samples < 2 or args.samples & (args.samples - 1):
        raise InputError(f"--samples {args.samples}: must be a power of two >= 2 (Sobol' sequence)")
    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    out = Path(args.json)
    if not out.parent.is_dir():
        raise InputError(f"--json {out}: directory {out.parent} does not exist")
    results = {}
    for name, space in (("parameters", PARAMETERS), ("leakages", LEAKS)):
        runs = args.samples * (len(space) + 2)
        with tqdm(total=runs, unit="run", desc=f"gsa {name}", disable=args.quiet) as bar:
            results[name] = sobol_indices(machine, space, args.samples, workers=args.workers, progress=bar.update)
        results[name]["ranking_4s"] = {o: ranking(results[name], o) for o in ("p_a", "p_b", "velocity")}
        results[name]["interaction_4s"] = {o: interaction(results[name], o) for o in ("p_a", "p_b", "velocity")}
    plot = plot_gsa(results, out.with_suffix(".png"))
    results["plot"] = str(plot)
    out.write_text(json.dumps(results, indent=2) + "\n")
    for name in ("parameters", "leakages"):
        for output, order in results[name]["ranking_4s"].items():
            print(f"{name} {output} at 4 s (first order): {' > '.join(order)}")
    return 0


def cmd_discrepancy(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.studies.discrepancy import progress_steps, run

    machine = _one_actuator(load_machine_config(args.config), args.actuator, "discrepancy")
    data = read_bag(args.bag)
    if not data.complete and not args.partial_ok:
        raise InputError(f"bag {args.bag}: {data.errors[0]} ({len(data.errors)} problem(s)); an effect named from part of a "
                         "recording can be wrong: repair the bag, or name effects from what is intact with --partial-ok")
    for error in data.errors:
        print(f"hydro-ros discrepancy: warning: {error}", file=sys.stderr)
    out = Path(args.out)
    with tqdm(total=progress_steps(), unit="fit", desc="discrepancy", disable=args.quiet) as bar:
        report = run(data, machine, out, progress=bar.update)
        bar.update(bar.total - bar.n)
    (out / "report.json").write_text(json.dumps(report, indent=2) + "\n")
    names = ", ".join(e["name"] for e in report["effects"]) or "none"
    print(f"named effect(s): {names}; validation gap {report['validation_gap']['before']:.2f} -> {report['validation_gap']['after']:.2f}")
    return 0


def _dp_problem(args: argparse.Namespace):  # noqa: ANN202 - planning types imported lazily
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.problem import Problem

    out = Path(args.json)
    if not out.parent.is_dir():
        raise InputError(f"--json {out}: directory {out.parent} does not exist")
    crane, config = load_crane(args.config)
    return Problem.build(crane, config, args.path, grid=tuple(args.grid) if args.grid else None, start=args.start), out


def cmd_dp_solve(args: argparse.Namespace) -> int:
    from hydro_ros.planning.costs import Cost
    from hydro_ros.planning.problem import method_record, plan_dp
    from hydro_ros.planning.trajectory import joint_table

    problem, out = _dp_problem(args)
    plan = plan_dp(problem, Cost(args.cost), progress=not args.quiet)
    record = method_record(plan)
    result = {
        "machine": problem.crane.name,
        "path": problem.path.path_id,
        "cost": args.cost,
        "start_position_m": problem.start,
        "grid": list(problem.grid.shape),
        "stages": problem.samples.stages,
        **record,
        "trajectory": joint_table(problem.crane, problem.samples, plan.trajectory),
    }
    out.write_text(json.dumps(result, indent=1) + "\n")
    print(
        f"dp {args.cost} on {problem.path.path_id}: CP {record['cp_energy_J'] / 1e3:.1f} kJ, LS {record['ls_energy_J'] / 1e3:.1f} kJ, "
        f"limits {'ok' if record['limits_ok'] else 'VIOLATED'}, {plan.seconds:.1f} s"
    )
    return 0


def cmd_dp_compare(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.planning.problem import CONTRACT_METHODS, METHODS
    from hydro_ros.studies.dp_compare import compare, markdown_table
    from hydro_ros.studies.plots import plot_dp_compare

    problem, out = _dp_problem(args)
    methods = tuple(METHODS) if args.all_methods else CONTRACT_METHODS
    with tqdm(total=len(methods), unit="method", desc="dp compare", disable=args.quiet) as bar:

        def done(method: str) -> None:
            bar.set_postfix_str(method)
            bar.update(1)

        result = compare(problem, methods, progress=done)
    table = markdown_table(result)
    result["plot"] = str(plot_dp_compare(result, out.with_suffix(".png")))
    out.write_text(json.dumps(result, indent=2) + "\n")
    out.with_suffix(".md").write_text(table + "\n")
    print(table)
    return 0


def cmd_db_build(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.catalog import build, plan_units
    from hydro_ros.planning.database import TrajectoryDatabase

    _, config = load_crane(args.config)
    units = plan_units(
        config, methods=tuple(args.methods) if args.methods else None, grid=tuple(args.grid) if args.grid else None,
        paths=tuple(args.paths) if args.paths else None,
    )
    with TrajectoryDatabase(args.db, writable=True) as db, tqdm(total=len(units), unit="solution", desc="db build", disable=args.quiet) as bar:
        stored = db.committed()
        bar.update(sum(1 for unit in units if stored.get(unit.key) == unit.inputs_hash))

        def done(unit) -> None:  # noqa: ANN001
            bar.set_postfix_str(f"{unit.path_id}/{unit.method}")
            bar.update(1)

        report = build(db, units, scheduler=args.scheduler, workers=args.workers, progress=done)
    print(f"db build {args.db}: {report.summary()}")
    return 0


def cmd_db_list(args: argparse.Namespace) -> int:
    from hydro_ros.planning.database import TrajectoryDatabase

    with TrajectoryDatabase(args.db) as db:
        if args.json:
            print(json.dumps(db.catalog(), indent=2))
            return 0
        rows = list(db.rows())
    print(f"{'machine':10} {'path':12} {'method':16} {'CP kJ':>8} {'LS kJ':>8} {'limits':>6} {'solve s':>8}  created")
    for machine, path_id, method, _, cp, ls, ok, seconds, created in rows:
        stamp = time.strftime("%Y-%m-%d %H:%M", time.localtime(created))
        print(f"{machine:10} {path_id:12} {method:16} {cp / 1e3:8.1f} {ls / 1e3:8.1f} {'ok' if ok else 'NO':>6} {seconds:8.1f}  {stamp}")
    print(f"{len(rows)} solution(s)")
    return 0


def cmd_dp_execute(args: argparse.Namespace) -> int:
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.serving import executable_trajectory
    from hydro_ros.studies.execution import execute, write_bag

    out = Path(args.out)
    if out.exists():
        raise InputError(f"--out {out}: already exists, refusing to overwrite")
    _, config = load_crane(args.config)
    trajectory, planned = executable_trajectory(
        config, args.path, args.method, database=args.db, grid=tuple(args.grid) if args.grid else None,
        start_extension=args.start_extension,
    )
    execution = execute(config, trajectory, args.supply, seed=args.seed)
    summary = {"machine": config["machine"], "path": args.path, "method": args.method, "planned": planned, **execution.summary}
    write_bag(execution, out, {"machine": config["machine"], "execution": summary})
    if args.json:
        Path(args.json).write_text(json.dumps(summary, indent=2) + "\n")
    energy_key = "cp_energy_J" if args.supply == "cp" else "ls_energy_J"
    print(
        f"dp execute {args.path}/{args.method} on the {args.supply.upper()} crane: {summary['energy_J'] / 1e3:.1f} kJ "
        f"(planned {planned[energy_key] / 1e3:.1f} kJ), ISO 9283 path accuracy {summary['path_accuracy_iso9283_m']:.3f} m -> {out}"
    )
    return 0


def cmd_record(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.nodes.recorder import record

    machine = load_machine_config(args.config)
    for flag, value in (("--duration", args.duration), ("--split-duration", args.split_duration), ("--split-size", args.split_size)):
        if value is not None and not value > 0:
            raise InputError(f"{flag} {value}: must be > 0")
    split_bytes = None if args.split_size is None else int(args.split_size * 1e6)
    with tqdm(unit="msg", desc="record", disable=args.quiet) as bar:
        summary = record(machine, Path(args.out), duration_s=args.duration, split_duration_s=args.split_duration,
                         split_size_bytes=split_bytes, outputs=args.outputs, progress=lambda n: bar.update(n - bar.n),
                         ros_args=args.ros_args)
    print(json.dumps(summary))
    return 0


def cmd_bag_info(args: argparse.Namespace) -> int:
    from hydro_ros.bags.reader import bag_info

    info = bag_info(args.bag)
    if args.json:
        print(json.dumps(info, indent=1))
    else:
        print(f"bag {info['bag']}: {info['messages']} messages over {info['duration_s']:.3f} s in {len(info['files'])} file(s)"
              f"{', with ground truth' if info['ground_truth'] else ''}")
        for row in info["files"]:
            print(f"  {row['path']}: {row['messages']} messages, {row['bytes']} bytes")
        for topic, row in info["topics"].items():
            print(f"  {topic} [{row['type']}]: {row['messages']}")
        for error in info["errors"]:
            print(f"  error: {error}")
    return 1 if info["errors"] else 0


def cmd_machine_check(args: argparse.Namespace) -> int:
    from hydro_ros.contract.check import annotated_values, config_problems
    from hydro_ros.contract.config import read_config

    config = read_config(args.config, required=(), nonempty="machine")
    problems = config_problems(config)
    for problem in problems:
        print(f"{args.config}: {problem}")
    if not problems:
        from hydro_ros.fdi.settings import unset_threshold

        machine = load_machine_config(args.config)
        print(f"{args.config}: {machine.name}: {len(machine.actuators)} actuator(s) "
              f"({', '.join(f'{a.name} on {a.joint}' for a in machine.actuators)}), {machine.sample_rate_hz:g} Hz, "
              f"supply {machine.supply_pressure / 1e6:g} MPa: ok")
        advice = unset_threshold(machine)
        if advice:
            print(f"{args.config}: warning: {advice}")
        for warning in _reach_warnings(machine):
            print(f"{args.config}: warning: {warning}")
        if args.plot:
            from hydro_ros.studies.plots import plot_machine

            print(f"{args.config}: picture {plot_machine(machine, args.plot)}")
    notes = annotated_values(args.config)
    if notes and not args.quiet:
        print(f"{len(notes)} value(s) the file marks as not measured (replace them with your data sheet's or your measurement):")
        for note in notes:
            print(f"  {note}")
    return 1 if problems else 0


def _reach_warnings(machine) -> list[str]:
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
        if not machine.crane and (operator[0] < low or operator[1] > high):
            out.append(f"excitation.joint_range {list(operator)}: {reach}; the simulated operator drives it into the end stops")
    return out


def cmd_machine_threshold(args: argparse.Namespace) -> int:

    from hydro_ros.fdi.settings import FdiSettings
    from hydro_ros.studies.fdi_evaluation import MISMATCH_SPREAD, calibrate_threshold_constant

    machine = load_machine_config(args.config)
    if FdiSettings.from_machine(machine).method != "ukf":
        raise InputError(f"{args.config}: the parity method's thresholds are fitted by `hydro-ros fdi-fit`, not derived here")
    if args.variants < 1 or args.duration <= 0:
        raise InputError(f"--variants {args.variants} --duration {args.duration}: need at least one variant and a positive duration")
    c0 = calibrate_threshold_constant(machine, range(1000, 1000 + args.variants), args.duration, margin=args.margin)
    print(f"{machine.name}: threshold_constant {c0:.4f} MPa: {args.margin:g} x the largest fault-free 5 s mean residual above the "
          f"quadratic term on {args.variants} variants of this machine ({MISMATCH_SPREAD}), {args.duration:g} s each")
    if args.out:
        out = Path(args.out)
        if out.resolve() == Path(args.config).resolve():
            raise InputError(f"--out {out}: is the config itself; write a config that extends it")
        write_extending(Path(args.config), out, f"# {machine.name} with a threshold derived by `hydro-ros machine threshold` from "
                        f"{args.variants} simulated variants;\n# safe until `hydro-ros commission` identifies the machine. "
                        "Regenerate, do not edit.\n", {"fdi": {"threshold_constant": round(c0, 4)}})
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
    out.write_text(header + text.replace(f"machine: {args.like}\n", f"machine: {out.stem}\n", 1))
    print(f"{out}: written from {source.name}; next: hydro-ros machine check {out}")
    return 0


def cmd_fleet_analyse(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.fleet import analyse

    if not args.service_limit > 0:
        raise InputError(f"--service-limit {args.service_limit}: must be > 0 L/min")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    with tqdm(unit="recording", desc="fleet", disable=args.quiet) as bar:
        report = analyse(Path(args.dir), Path(args.out), scheduler=args.scheduler, workers=args.workers, limit=args.service_limit,
                         progress=lambda _: bar.update())
    flagged = [f"{name}/{actuator}" for name, machine in report["machines"].items() for actuator in machine["flagged"]]
    print(json.dumps({"fleet": str(Path(args.out) / "fleet.json"), "analysed": report["analysed"],
                      "already_analysed": report["already_analysed"], "unreadable": len(report["unreadable"]), "flagged": flagged,
                      "ran_on": report["ran_on"]}))
    return 0


def cmd_params(args: argparse.Namespace) -> int:
    from hydro_ros.nodes.bringup import machine_params

    load_machine_config(args.config)
    print(machine_params(Path(args.config)), end="")
    return 0


def cmd_alarms_export(args: argparse.Namespace) -> int:
    import csv

    from hydro_ros.fdi.alarm_log import COLUMNS, read_events

    if not (args.csv or args.json):
        raise InputError("alarms export: give --csv OUT and/or --json OUT")
    events, _ = read_events(args.db, newest_first=False)
    if args.json:
        Path(args.json).write_text(json.dumps(events, indent=1))
    if args.csv:
        with open(args.csv, "w", newline="") as out:
            writer = csv.DictWriter(out, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(dict(event, evidence=json.dumps(event["evidence"], sort_keys=True)) for event in events)
    print(json.dumps({"events": len(events), "csv": args.csv, "json": args.json}))
    return 0


def cmd_foxglove_layout(args: argparse.Namespace) -> int:
    from hydro_ros.hmi.foxglove_layout import foxglove_layout

    layout = foxglove_layout(load_machine_config(args.config), args.namespace)
    Path(args.out).write_text(json.dumps(layout, indent=2) + "\n")
    print(json.dumps({"layout": args.out, "panels": len(layout["configById"])}))
    return 0


def cmd_replay(args: argparse.Namespace) -> int:
    from hydro_ros.nodes.bag_player import replay

    return replay(args.bag, rate=args.rate, loop=args.loop, clock=args.clock, ros_args=args.ros_args)


def cmd_demo(args: argparse.Namespace) -> int:
    from hydro_ros.demo import run_demo

    return run_demo(Path(args.out), config_path=args.config, duration=args.duration, hmi_port=args.hmi_port, linger=args.linger)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hydro-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)

    units = "; ".join(f"{name}: {unit}" for name, unit in sorted(INJECTION_UNITS.items()))
    sim = sub.add_parser(
        "sim",
        help="simulate a scenario into a contract bag",
        description=f"Simulate the machine under its simulated operator into a contract bag. VALUE units: {units}.",
    )
    sim.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml")
    sim.add_argument("--duration", type=float, required=True, help="simulated seconds")
    sim.add_argument("--fault", action="append", default=[], metavar="NAME=VALUE@T[:RAMP]",
                     help="fault switched on at T s, developing linearly over RAMP s (repeatable); on a machine of several "
                          "actuators ACTUATOR:NAME=VALUE@T[:RAMP], e.g. lift:external_leakage_a=1.0@20")
    sim.add_argument("--effect", action="append", default=[], metavar="NAME=VALUE",
                     help="physical effect present from the start (repeatable); on a machine of several actuators "
                          "ACTUATOR:NAME=VALUE; on a crane payload_mass=KG (also as a timed --fault) at the tip")
    sim.add_argument("--seed", type=int, default=0, help="random seed of operator and sensor noise")
    sim.add_argument("--path", default=None, help="crane only: work this path id's trajectory (forwards, hold, back, hold) in "
                                                "place of the random operator")
    sim.add_argument("--method", default=None, help="crane only: the trajectory method of --path (default dp_cp)")
    sim.add_argument("--db", default=None, help="crane only: trajectory database --path is served from; default: plan it now")
    sim.add_argument("--hold", type=float, default=None, help="crane only: [s] hold at either end of the work cycle (default 4)")
    sim.add_argument("--out", required=True, help="bag directory to create (must not exist)")
    sim.add_argument("--quiet", action="store_true", help="no progress bar")
    sim.set_defaults(func=cmd_sim)

    fdi = sub.add_parser("fdi", help="fault detection and isolation over a bag (contract JSON + residual plot)")
    fdi.add_argument("--bag", required=True, help="contract bag directory or .mcap file")
    fdi.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml")
    fdi.add_argument("--method", choices=("ukf", "parity"), default=None, help="residual generator (default: the config's fdi.method)")
    fdi.add_argument("--json", required=True, help="output JSON; the residual plot goes beside it as .png")
    fdi.add_argument("--quiet", action="store_true", help="no progress bar")
    fdi.set_defaults(func=cmd_fdi)

    ev = sub.add_parser("fdi-eval", help="score the FDI on simulated faults with plant-model mismatch (table, JSON, plot)")
    ev.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml")
    ev.add_argument("--out", required=True, help="directory for fdi_eval.json, fdi_eval.md and fdi_eval.png")
    ev.add_argument("--seeds", type=int, default=5, help="mismatched plants per fault type and size")
    ev.add_argument("--calibration-seeds", type=int, default=10, help="fault-free training plants for the threshold constant")
    ev.add_argument("--duration", type=float, default=90.0, help="seconds per fault run (onset at 20 s)")
    ev.add_argument("--fault-free-minutes", type=float, default=60.0, help="total fault-free minutes for the false-alarm rate")
    ev.add_argument("--workers", type=int, default=2, help="parallel processes")
    ev.add_argument("--quiet", action="store_true", help="no progress bar")
    ev.set_defaults(func=cmd_fdi_eval)

    fit = sub.add_parser("fdi-fit", help="fit the parity method: statistical thresholds and the signature table (mobile valves); "
                                         "on a crane config the thresholds from its cylinders at work")
    fit.add_argument("--config", required=True, help="machine config with valve.type mobile, e.g. config/sam_mobile.yaml or "
                                                     "config/k70m.yaml")
    fit.add_argument("--train", type=int, default=8, help="fault-free training plants (2 min each)")
    fit.add_argument("--held-out", type=int, default=8, help="fault-free plants that set the threshold factor")
    fit.add_argument("--signature-seeds", type=int, default=2, help="plants per fault for the signature table")
    fit.add_argument("--write", action="store_true", help="write the result into the config's fitted block")
    fit.add_argument("--quiet", action="store_true", help="no progress bar")
    fit.set_defaults(func=cmd_fdi_fit)

    com = sub.add_parser("commission", help="identify the monitor's model and threshold from fault-free recordings of the machine",
                         description="Per-notch flow-coefficient polynomials, bulk moduli and centre leakage from the "
                                     "continuity equations (load-independent), then c0 on the held-out last third.")
    com.add_argument("--bag", action="append", required=True, help="a fault-free recording of normal operation (repeat for more)")
    com.add_argument("--config", required=True, help="the machine config the commissioned one extends, e.g. config/sam.yaml")
    com.add_argument("--out", required=True, help="the commissioned machine config to write (extends --config)")
    com.add_argument("--report", help="directory for commissioning.json and commissioning.png")
    com.add_argument("--force", action="store_true", help="accept a commissioned threshold above the config's own (refused "
                                                          "otherwise: it would hide faults the config's threshold shows)")
    com.add_argument("--quiet", action="store_true", help="no progress bar")
    com.set_defaults(func=cmd_commission)

    can_cmd = sub.add_parser("can", help="CAN bus tools")
    can_sub = can_cmd.add_subparsers(dest="can_command", required=True)
    convert = can_sub.add_parser("convert", help="a machine's CAN log (candump .log, .asc, .blf) -> contract bag",
                                 description="Decode a CAN log through the machine config's signal map (can: dbc, map); bad "
                                 "frames are counted, never written.")
    convert.add_argument("logfile", help="candump .log, Vector .asc or .blf")
    convert.add_argument("--config", required=True, help="machine config (its can: section maps the DBC's signals)")
    convert.add_argument("--dbc", default=None, help="the bus's DBC file, instead of the config's can.dbc")
    convert.add_argument("--out", required=True, help="bag directory to create (must not exist)")
    convert.set_defaults(func=cmd_can_convert)

    gsa = sub.add_parser("gsa", help="Sobol' sensitivity of the SAM model (P-I): parameters and leakages")
    gsa.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml")
    gsa.add_argument("--samples", type=int, default=1024, help="Sobol' base sample N (power of two); runs = N (k + 2)")
    gsa.add_argument("--workers", type=int, default=2, help="parallel processes")
    gsa.add_argument("--json", required=True, help="output JSON; the plot goes beside it as .png")
    gsa.add_argument("--actuator", default=None, help="the cylinder to study, on a machine of several")
    gsa.add_argument("--quiet", action="store_true", help="no progress bar")
    gsa.set_defaults(func=cmd_gsa)

    disc = sub.add_parser("discrepancy", help="find, name and add what the model is missing against a measured bag")
    disc.add_argument("--bag", required=True, help="measured contract bag")
    disc.add_argument("--config", required=True, help="the model's machine config")
    disc.add_argument("--out", required=True, help="directory for report.json, model.yaml and plots")
    disc.add_argument("--actuator", default=None, help="the cylinder to compare, on a machine of several")
    disc.add_argument("--partial-ok", action="store_true", help="go on with what is intact of a damaged or incomplete bag "
                      "(refused by default: an effect named from part of a recording can be wrong)")
    disc.add_argument("--quiet", action="store_true", help="no progress bar")
    disc.set_defaults(func=cmd_discrepancy)

    dp_cmd = sub.add_parser("dp", help="energy-optimal redundancy resolution of a crane path (P-V, P-VI)")
    dp_sub = dp_cmd.add_subparsers(dest="dp_command", required=True)
    for name, helptext in (
        ("solve", "DP on one cost: joint trajectory, energies and limits (JSON)"),
        ("compare", "DP on every cost, pseudo-inverses and direct collocation on one path (JSON, table, bar chart)"),
    ):
        cmd = dp_sub.add_parser(name, help=helptext)
        cmd.add_argument("--config", required=True, help="crane config: config/k70m.yaml or config/crane3dof.yaml")
        cmd.add_argument("--path", required=True, help="path id of the config (k70m: horizontal, vertical, half_cycle; crane3dof: triangle)")
        if name == "solve":
            cmd.add_argument("--cost", required=True, choices=["cp", "ls", "actuator", "extension", "velocity"], help="DP stage cost")
        else:
            cmd.add_argument("--all-methods", action="store_true", help="also P-V's DP (Act. velocity) and weighted pseudo-inverse")
        cmd.add_argument("--json", required=True, help="output JSON (compare: the table .md and plot .png go beside it)")
        cmd.add_argument("--grid", type=int, nargs=3, metavar=("N_C", "N_V", "N_U"), help="DP grid (default: the config's dp.grid)")
        cmd.add_argument("--start", choices=["smallest", "middle"], default="smallest", help="initial extension (P-VI's two configurations)")
        cmd.add_argument("--quiet", action="store_true", help="no progress bar")
        cmd.set_defaults(func=cmd_dp_solve if name == "solve" else cmd_dp_compare)

    db_cmd = sub.add_parser("db", help="the trajectory database the trajectory_server serves")
    db_sub = db_cmd.add_subparsers(dest="db_command", required=True)
    db_build = db_sub.add_parser("build", help="precompute the config's paths x methods into the database (resumes)",
                                 description="Solve every path of a crane config with every catalog method and store the "
                                 "solutions; what is already stored with the same inputs is skipped, so a killed build resumes.")
    db_build.add_argument("--config", required=True, help="crane config: config/k70m.yaml or config/crane3dof.yaml")
    db_build.add_argument("--db", required=True, help="SQLite file (created if missing)")
    db_build.add_argument("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler, e.g. tcp://host:8786 (default: local processes)")
    db_build.add_argument("--workers", type=int, default=None, help="local processes (default: one per core)")
    db_build.add_argument("--methods", nargs="+", default=None, help="methods (default: the config's catalog.methods)")
    db_build.add_argument("--paths", nargs="+", default=None, help="path ids (default: all of the config)")
    db_build.add_argument("--grid", type=int, nargs=3, metavar=("N_C", "N_V", "N_U"), help="DP grid (default: catalog.grid, else dp.grid)")
    db_build.add_argument("--quiet", action="store_true", help="no progress bar")
    db_build.set_defaults(func=cmd_db_build)
    db_list = db_sub.add_parser("list", help="show the stored catalog")
    db_list.add_argument("--db", required=True, help="SQLite file")
    db_list.add_argument("--json", action="store_true", help="the catalog as JSON (what trajectory_server latches)")
    db_list.set_defaults(func=cmd_db_list)

    execute = dp_sub.add_parser("execute", help="run a planned trajectory on the simulated crane (P-VI App. A controller) into a bag",
                                description="Execute one method's trajectory in closed loop on the crane plant (valve dead zone "
                                "and delay, payload, CP or LS pump) and write a contract bag with the measured energy and the "
                                "ISO 9283 path accuracy in its truth metadata.")
    execute.add_argument("--config", required=True, help="crane config: config/k70m.yaml or config/crane3dof.yaml")
    execute.add_argument("--path", required=True, help="path id of the config")
    execute.add_argument("--method", default="dp_cp", help="planning method of dp compare, e.g. dp_cp, dp_ls, pinv_joint (default dp_cp)")
    execute.add_argument("--supply", choices=["cp", "ls"], default="cp", help="pump of the simulated crane (default cp)")
    execute.add_argument("--db", default=None, help="take the solution from this trajectory database (default: plan it now)")
    execute.add_argument("--grid", type=int, nargs=3, metavar=("N_C", "N_V", "N_U"), help="DP grid when planning now (default: dp.grid)")
    execute.add_argument("--start-extension", type=float, default=None, metavar="M",
                         help="start with the extension cylinder at this stroke (re-planned from there)")
    execute.add_argument("--seed", type=int, default=0, help="seed of the plant's valve spread")
    execute.add_argument("--out", required=True, help="bag directory to create (must not exist)")
    execute.add_argument("--json", default=None, help="also write the summary here")
    execute.set_defaults(func=cmd_dp_execute)

    rec = sub.add_parser("record", help="record a running machine's contract topics into a bag, like ros2 bag record",
                         description="Subscribe to the config's sensor topics (raw CDR, each with the reliability its "
                         "publishers offer) and write them into a contract bag, log time = header stamp. Ctrl-C or SIGTERM "
                         "stops and closes the bag.")
    rec.add_argument("--config", required=True, help="machine config: which topics the machine has")
    rec.add_argument("--out", required=True, help="bag directory to create")
    rec.add_argument("--duration", type=float, default=None, help="stop after S seconds of wall time (default: until Ctrl-C)")
    rec.add_argument("--split-duration", type=float, default=None, metavar="S", help="start a new file every S seconds of log time")
    rec.add_argument("--split-size", type=float, default=None, metavar="MB", help="start a new file after MB megabytes of messages (before compression)")
    rec.add_argument("--outputs", action="store_true", help="also record /diagnostics")
    rec.add_argument("--quiet", action="store_true", help="no progress bar")
    rec.set_defaults(func=cmd_record)

    bag_cmd = sub.add_parser("bag", help="bag tools")
    bag_sub = bag_cmd.add_subparsers(dest="bag_command", required=True)
    info = bag_sub.add_parser("info", help="files, topics, message counts and damage of a bag, read from the files",
                              description="Read every file of a bag (split bags whole) and report its messages per topic; "
                              "exits 1 when a file is damaged or disagrees with metadata.yaml.")
    info.add_argument("bag", help="bag directory or .mcap file")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.set_defaults(func=cmd_bag_info)

    machine_cmd = sub.add_parser("machine", help="describe your own machine: check a config, start a new one",
                                 description="A machine config describes every actuator (cylinder, mount, valve, load), "
                                 "the sensors and the supply, in SI units.")
    machine_sub = machine_cmd.add_subparsers(dest="machine_command", required=True)
    check = machine_sub.add_parser("check", help="every problem of a machine config at once, and the values it marks as not measured",
                                   description="Exit 1 when the config breaks a rule (each printed with its key path, value, unit "
                                   "and rule); every other command refuses such a config with the same messages.")
    check.add_argument("config", help="machine config (YAML)")
    check.add_argument("--quiet", action="store_true", help="only the problems, not the PLACEHOLDER / INFERRED values")
    check.add_argument("--plot", default=None, help="draw the machine as configured (links at their reach, cylinders) to this PNG")
    check.set_defaults(func=cmd_machine_check)
    threshold = machine_sub.add_parser("threshold", help="a safe threshold before commissioning, derived from the machine's own "
                                       "description", description="Simulate fault-free variants of the machine (each notch, bulk "
                                       "modulus and friction drawn off its configured value, as an unidentified machine differs from "
                                       "its data sheet) and take a margin over the largest 5 s mean residual: the UKF monitor's "
                                       "fdi.threshold_constant until `hydro-ros commission` replaces it.")
    threshold.add_argument("config", help="machine config (YAML)")
    threshold.add_argument("--variants", type=int, default=8, help="simulated variants (default 8)")
    threshold.add_argument("--duration", type=float, default=120.0, help="[s] simulated per variant (default 120)")
    threshold.add_argument("--margin", type=float, default=1.25, help="factor over the largest excess (default 1.25)")
    threshold.add_argument("--out", default=None, help="write a config that extends CONFIG with this threshold")
    threshold.set_defaults(func=cmd_machine_threshold)
    new = machine_sub.add_parser("new", help="write a commented starting point for your machine's config",
                                 description="Copy a shipped config with its comments (units, where each value comes from).")
    new.add_argument("--like", required=True, choices=("sam", "boom_arm", "k70m"),
                     help="sam: one boom; boom_arm: several joints, each a cylinder; k70m: a redundant crane (the planner's)")
    new.add_argument("--out", required=True, help="the new config file")
    new.set_defaults(func=cmd_machine_new)

    fleet = sub.add_parser("fleet", help="a fleet's recordings: leak trends per cylinder and when each needs service")
    fleet_sub = fleet.add_subparsers(dest="fleet_command", required=True)
    fleet_analyse = fleet_sub.add_parser(
        "analyse", help="every machine's recordings: alarms, leak estimates, trends, projected service dates",
        description="DIR holds one folder per machine, named by its id, with its config as machine.yaml and its recordings "
        "(bag folders or .mcap files) below it. Each recording is analysed once (keyed by its content hash in OUT/fleet.sqlite) "
        "on local processes or a Dask cluster; OUT/fleet.json, fleet.csv and fleet.html are written from everything analysed.")
    fleet_analyse.add_argument("dir", help="the fleet folder")
    fleet_analyse.add_argument("--out", required=True, help="output folder (the store lives here: a rerun analyses only new recordings)")
    fleet_analyse.add_argument("--scheduler", default=None, help="Dask scheduler address (default: local processes)")
    fleet_analyse.add_argument("--workers", type=int, default=None, help="local processes (default: one per core)")
    fleet_analyse.add_argument("--service-limit", type=float, default=0.5, help="[L/min at 10 MPa] a leak that needs service")
    fleet_analyse.add_argument("--quiet", action="store_true", help="no progress bar")
    fleet_analyse.set_defaults(func=cmd_fleet_analyse)

    params = sub.add_parser("params", help="the commented params file of a machine's bring-up (can_bridge, fdi_node, hmi)",
                            description="Print the ros__parameters of the nodes launch/machine.launch.py starts, every "
                            "parameter with its unit, default and range, from the nodes' own tables.")
    params.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml or your own")
    params.set_defaults(func=cmd_params)

    alarms = sub.add_parser("alarms", help="fdi_node's alarm log")
    alarms_sub = alarms.add_subparsers(dest="alarms_command", required=True)
    export = alarms_sub.add_parser("export", help="every event of an alarm log as CSV and/or JSON, oldest first",
                                   description="Read fdi_node's SQLite alarm log (parameter alarm_log) without writing to it.")
    export.add_argument("--db", required=True, help="the alarm log file")
    export.add_argument("--csv", default=None, help="write CSV here")
    export.add_argument("--json", default=None, help="write JSON here")
    export.set_defaults(func=cmd_alarms_export)

    layout = sub.add_parser("foxglove-layout", help="a Foxglove layout for a machine: every actuator's status and residual plots",
                            description="Write the Foxglove layout of a machine config (import it in Foxglove: Layouts, Import).")
    layout.add_argument("--config", required=True, help="machine config, e.g. config/sam.yaml")
    layout.add_argument("--out", required=True, help="layout JSON to write")
    layout.add_argument("--namespace", default="", help="the machine's namespace (machine.launch.py's namespace argument)")
    layout.set_defaults(func=cmd_foxglove_layout)

    replay = sub.add_parser("replay", help="play a contract bag onto ROS topics, like ros2 bag play")
    replay.add_argument("bag", help="bag directory")
    replay.add_argument("--rate", type=float, default=1.0, help="playback rate (1 = recorded speed)")
    replay.add_argument("--loop", action="store_true", help="start again at the end")
    replay.add_argument("--clock", action="store_true", help="publish /clock with the bag's log times (for use_sim_time nodes; off "
                        "by default, as ros2 bag play)")
    replay.add_argument("--no-clock", action="store_true", help=argparse.SUPPRESS)  # the old spelling: /clock is now off by default
    replay.set_defaults(func=cmd_replay)

    demo = sub.add_parser("demo", help="the main job: simulate a developing leak and run it through the nodes")
    demo.add_argument("--out", default="out/demo", help="directory for the bag and plots")
    demo.add_argument("--config", default=None, help="machine config (default: the installed sam.yaml)")
    demo.add_argument("--duration", type=float, default=60.0, help="simulated seconds")
    demo.add_argument("--hmi-port", type=int, default=8080, help="port of the operator HMI on localhost (0: any free port)")
    demo.add_argument("--linger", type=float, default=0.0, help="seconds to keep the graph and the HMI up after the replay")
    demo.set_defaults(func=cmd_demo)
    return parser


ROS_COMMANDS = ("record", "replay")  # the commands that run a ROS node in this process take --ros-args as ros2 run does


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = argv[argv.index("--ros-args") + 1:] if "--ros-args" in argv else []
    args = parser.parse_args(argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv)
    args.ros_args = ros_args
    if "--ros-args" in argv and args.command not in ROS_COMMANDS:
        parser.error(f"--ros-args: only {', '.join(ROS_COMMANDS)} start ROS nodes")
    func: Callable[[argparse.Namespace], int] = args.func
    try:
        return func(args)
    except InputError as exc:  # bad input is one line; anything else is a bug and keeps its traceback
        print(f"hydro-ros {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
