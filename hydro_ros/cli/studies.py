"""``hydro-ros gsa`` and ``hydro-ros discrepancy``: the model's sensitivities, and what it lacks against a measured bag."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hydro_ros.cli.common import COUNT, add_actuator, add_config, add_out, add_quiet, number, one_actuator, output_file, write_json
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config


def register(sub: argparse._SubParsersAction) -> None:
    gsa = sub.add_parser("gsa", help="Sobol' sensitivity of the SAM model (P-I): parameters and leakages")
    add_config(gsa)
    gsa.add_argument("--samples", type=number(int, 2, 2**20), default=1024, help="Sobol' base sample N (power of two); runs = N (k + 2)")
    gsa.add_argument("--workers", type=COUNT, default=2, help="parallel processes")
    add_out(gsa, "output JSON; the plot goes beside it as .png")
    add_actuator(gsa, "study")
    add_quiet(gsa)
    gsa.set_defaults(func=cmd_gsa)

    disc = sub.add_parser("discrepancy", help="find, name and add what the model is missing against a measured bag")
    disc.add_argument("--bag", required=True, help="measured contract bag")
    add_config(disc, "the model's machine config")
    add_out(disc, "directory for report.json, model.yaml and plots")
    add_actuator(disc, "compare")
    disc.add_argument("--partial-ok", action="store_true", help="go on with what is intact of a damaged or incomplete bag "
                      "(refused by default: an effect named from part of a recording can be wrong)")
    add_quiet(disc)
    disc.set_defaults(func=cmd_discrepancy)


def cmd_gsa(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.studies.gsa import LEAKS, PARAMETERS, interaction, plot_indices, ranking, sobol_indices

    machine = one_actuator(load_machine_config(args.config), args.actuator, "gsa")
    if args.samples < 2 or args.samples & (args.samples - 1):
        raise InputError(f"--samples {args.samples}: must be a power of two >= 2 (Sobol' sequence)")
    if args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    out = output_file(args.out)
    results = {}
    for name, space in (("parameters", PARAMETERS), ("leakages", LEAKS)):
        runs = args.samples * (len(space) + 2)
        with tqdm(total=runs, unit="run", desc=f"gsa {name}", disable=args.quiet) as bar:
            results[name] = sobol_indices(machine, space, args.samples, workers=args.workers, progress=bar.update)
        results[name]["ranking_4s"] = {o: ranking(results[name], o) for o in ("p_a", "p_b", "velocity")}
        results[name]["interaction_4s"] = {o: interaction(results[name], o) for o in ("p_a", "p_b", "velocity")}
    plot = plot_indices(results, out.with_suffix(".png"))
    results["plot"] = str(plot)
    write_json(out, results)
    for name in ("parameters", "leakages"):
        for output, order in results[name]["ranking_4s"].items():
            print(f"{name} {output} at 4 s (first order): {' > '.join(order)}")
    return 0


def cmd_discrepancy(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.workflows.discrepancy import progress_steps, run

    machine = one_actuator(load_machine_config(args.config), args.actuator, "discrepancy")
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
    write_json(out / "report.json", report.to_json())
    names = ", ".join(e.name for e in report.effects) or "none"
    print(f"named effect(s): {names}; validation gap {report.validation_gap.before:.2f} -> {report.validation_gap.after:.2f}")
    return 0
