"""``hydro-ros fdi run|eval|fit`` and ``hydro-ros commission``: the monitor over a bag, scored, fitted, commissioned."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from hydro_ros.cli.common import COUNT, add_config, add_out, add_quiet, at_least_one, number, output_file, write_json
from hydro_ros.contract.config import plain_data
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config


def register(sub: argparse._SubParsersAction) -> None:
    fdi = sub.add_parser("fdi", help="the monitor offline: over a bag, scored on simulated faults, its parity method fitted")
    verbs = fdi.add_subparsers(dest="fdi_command", required=True)
    run = verbs.add_parser("run", help="fault detection and isolation over a bag (contract JSON + residual plot)")
    run.add_argument("--bag", required=True, help="contract bag directory or .mcap file")
    add_config(run)
    run.add_argument("--method", choices=("ukf", "parity"), default=None, help="residual generator (default: the config's fdi.method)")
    add_out(run, "output JSON; the residual plot goes beside it as .png")
    add_quiet(run)
    run.set_defaults(func=cmd_fdi_run)

    ev = verbs.add_parser("eval", help="score the FDI on simulated faults with plant-model mismatch (table, JSON, plot)")
    add_config(ev)
    add_out(ev, "directory for fdi_eval.json, fdi_eval.md and fdi_eval.png")
    ev.add_argument("--seeds", type=COUNT, default=5, help="mismatched plants per fault type and size")
    ev.add_argument("--calibration-seeds", type=COUNT, default=10, help="fault-free training plants for the threshold constant")
    ev.add_argument("--duration", type=number(float, 20.0, 1e6, above=True, unit="s (the onset is at 20 s)"),
                    default=90.0, help="seconds per fault run (onset at 20 s)")
    ev.add_argument("--fault-free-minutes", type=number(float, 0.0, 1e5, above=True, unit="min"),
                    default=60.0, help="total fault-free minutes for the false-alarm rate")
    ev.add_argument("--workers", type=COUNT, default=2, help="parallel processes")
    add_quiet(ev)
    ev.set_defaults(func=cmd_fdi_eval)

    fit = verbs.add_parser("fit", help="fit the parity method: statistical thresholds and the signature table (mobile valves); "
                                       "on a crane config the thresholds from its cylinders at work")
    add_config(fit, "machine config with valve.type mobile, e.g. config/sam_mobile.yaml or config/k70m.yaml")
    fit.add_argument("--train", type=COUNT, default=8, help="fault-free training plants (2 min each)")
    fit.add_argument("--held-out", type=COUNT, default=8, help="fault-free plants that set the threshold factor")
    fit.add_argument("--signature-seeds", type=COUNT, default=6, help="plants per fault for the signature table (the closed-valve "
                                                                  "codes a fault makes on some plants only, a held B's leak, need several)")
    fit.add_argument("--write", action="store_true", help="write the result into the config's fitted block")
    add_quiet(fit)
    fit.set_defaults(func=cmd_fdi_fit)

    com = sub.add_parser("commission", help="identify the monitor's model and threshold from fault-free recordings of the machine",
                         description="Per-notch flow-coefficient polynomials, bulk moduli and centre leakage from the "
                                     "continuity equations (load-independent), then c0 on the held-out last third.")
    com.add_argument("--bag", action="append", required=True, help="a fault-free recording of normal operation (repeat for more)")
    add_config(com, "the machine config the commissioned one extends, e.g. config/sam.yaml")
    add_out(com, "the commissioned machine config to write (extends --config)")
    com.add_argument("--report", help="directory for commissioning.json, commissioning.png and coverage.png (where the "
                     "recordings worked, and what to record next)")
    com.add_argument("--force", action="store_true", help="accept a commissioned threshold above the config's own (refused "
                                                          "otherwise: it would hide faults the config's threshold shows)")
    add_quiet(com)
    com.set_defaults(func=cmd_commission)


def cmd_fdi_run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.fdi.offline import prepare, run_monitor
    from hydro_ros.workflows.plots import plot_fdi

    machine = load_machine_config(args.config)
    out = output_file(args.out)
    data, monitor, samples = prepare(args.bag, machine, args.method)
    with tqdm(total=len(samples), unit="sample", desc="fdi", disable=args.quiet) as bar:
        run = run_monitor(monitor, samples, progress=bar.update)
    run.data = data
    result = run.to_json()
    plot = plot_fdi(run, out.with_suffix(".png"))
    result["plot"] = str(plot)
    write_json(out, result)
    for message in result.get("errors", []):
        print(f"hydro-ros fdi: warning: {message}", file=sys.stderr)
    for name, actuator in result["actuators"].items():
        first = actuator["first_detection_s"]
        print(f"{name}: {actuator['fault']}" + (f" (first detection {first} s)" if first is not None else " (nothing detected)"))
    return 0


def cmd_fdi_eval(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.fdi_evaluation import evaluate, markdown_table, plot_summary

    machine = load_machine_config(args.config)
    at_least_one(args, "seeds", "calibration_seeds", "workers")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    with tqdm(unit="run", desc="fdi eval", disable=args.quiet) as bar:
        summary = evaluate(machine, seeds=args.seeds, calibration_seeds=args.calibration_seeds, duration_s=args.duration,
                           fault_free_minutes=args.fault_free_minutes, workers=args.workers, progress=bar.update)
    write_json(out / "fdi_eval.json", summary.to_json())
    table = markdown_table(summary)
    (out / "fdi_eval.md").write_text(table)
    plot_summary(summary, out / "fdi_eval.png")
    print(table)
    return 0


def cmd_fdi_fit(args: argparse.Namespace) -> int:
    from hydro_ros.studies.fdi_evaluation import build_parity_signatures, fit_parity_thresholds, write_fitted_block

    machine = load_machine_config(args.config)
    if args.train < 1 or args.held_out < 1:
        raise InputError("--train and --held-out must be >= 1")
    if machine.planned:
        return fdi_fit_crane(args, machine)
    print(f"fitting parity thresholds on {args.train} fault-free mismatched plants, checking on {args.held_out} others ...")
    thresholds, report = fit_parity_thresholds(machine, range(100, 100 + args.train), range(300, 300 + args.held_out))
    print(f"threshold factor {thresholds.factor:g} ({report['false_alarms_per_hour']:.2f} false alarms/h held out)"
          if "false_alarms_per_hour" in report else f"no factor met the target: {report['tried']}")
    if "closed_factor" in report:
        print(f"closed-valve evidence factors {', '.join(f'{f:g}' for f in report['closed_factor'])} (A, B: no held-out crossing)")
    print("building the signature table by simulating the P-IV fault list ...")
    rows = build_parity_signatures(machine, thresholds, range(100, 100 + args.signature_seeds))
    for row in rows:
        print(f"  {row['fault']:34s} {row['code']}  command {'any' if row['command_positive'] is None else ('+' if row['command_positive'] else '-')}"
              f"  large {row['large']}  closed {row.get('closed', 'any')}")
    if args.write:
        closed = (f", closed-valve factors {', '.join(f'{f:g}' for f in report['closed_factor'])} for none there"
                  if "closed_factor" in report else "")
        write_fitted_block(Path(args.config), thresholds, rows,
                           f"parity thresholds from {args.train} fault-free mismatched plants, factor {thresholds.factor:g} for <= 1 false "
                           f"alarm/h on {report['held_out_hours']:.2f} h held out{closed}; signature table by simulation of the P-IV fault "
                           f"list on {args.signature_seeds} plants per fault.")
        print(f"written to {args.config}")
    return 0


def fdi_fit_crane(args: argparse.Namespace, machine) -> int:
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
    with tqdm(total=runs, unit="run", desc="fdi fit", disable=args.quiet) as bar:
        thresholds, report = fit_crane_thresholds(machine, trajectories, train=range(100, 100 + args.train),
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

    from hydro_ros.workflows.commissioning import commission, load_recordings, write_config
    from hydro_ros.workflows.plots import plot_commissioning, plot_coverage

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
        plot_coverage(recordings, block["model"]["fdi"]["coverage"], block["record_next"], machine, report_dir / "coverage.png")
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
    for actuator, motions in block["record_next"].items():
        if motions:
            print(f"{actuator}: detection holds outside what the recordings held; to cover more, record {'; '.join(motions)}")
    return 0
