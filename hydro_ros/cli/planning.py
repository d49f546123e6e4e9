"""``hydro-ros dp solve|compare|execute`` and ``hydro-ros db build|list``: energy-optimal trajectories, planned, compared,
executed on the simulated crane, stored for the trajectory_server."""

from __future__ import annotations

import argparse
import json
import math
import time

from hydro_ros.cli.common import COUNT, SECONDS, SEED, add_grid, add_out, add_quiet, new_output, number, output_file, write_json
from hydro_ros.contract.errors import InputError

CRANE_CONFIG = "machine config with a planner: section: config/k70m.yaml, config/crane3dof.yaml, config/excavator.yaml"


def tip_line(text: str) -> tuple[tuple[float, float], tuple[float, float]]:
    """An argparse type: ``X0,Y0:X1,Y1``, the tip's start and end [m], finite and apart."""
    try:
        ends = tuple(tuple(float(v) for v in end.split(",")) for end in text.split(":"))
    except ValueError:
        ends = ()
    if len(ends) != 2 or any(len(end) != 2 or not all(math.isfinite(v) for v in end) for end in ends):
        raise argparse.ArgumentTypeError(f"{text!r}: expected X0,Y0:X1,Y1 (the tip's start and end, finite metres)")
    if ends[0] == ends[1]:
        raise argparse.ArgumentTypeError(f"{text!r}: the line has no length")
    return ends[0], ends[1]  # type: ignore[return-value]


tip_line.__name__ = "line"  # argparse names the expected type in its messages


def register(sub: argparse._SubParsersAction) -> None:
    dp = sub.add_parser("dp", help="energy-optimal redundancy resolution of a crane path (P-V, P-VI)")
    verbs = dp.add_subparsers(dest="dp_command", required=True)
    for name, helptext in (
        ("solve", "DP on one cost: joint trajectory, energies and limits (JSON)"),
        ("compare", "DP on every cost, pseudo-inverses and direct collocation on one path (JSON, table, bar chart)"),
    ):
        cmd = verbs.add_parser(name, help=helptext)
        cmd.add_argument("--config", required=True, help=CRANE_CONFIG)
        cmd.add_argument("--path", required=True, help="path id of the config (k70m: horizontal, vertical, half_cycle; crane3dof: triangle), "
                         "or the id of the --line")
        cmd.add_argument("--line", type=tip_line, default=None, metavar="X0,Y0:X1,Y1",
                         help="plan a straight tip line in the plane instead of a config path: start and end [m], rest to rest "
                         "along a quintic over --duration")
        cmd.add_argument("--duration", type=SECONDS, default=None, metavar="S", help="[s] the --line's duration")
        if name == "solve":
            cmd.add_argument("--cost", required=True, choices=["cp", "ls", "actuator", "extension", "velocity"], help="DP stage cost")
        else:
            cmd.add_argument("--all-methods", action="store_true", help="also P-V's DP (Act. velocity) and weighted pseudo-inverse")
        add_out(cmd, "output JSON (compare: the table .md and plot .png go beside it)")
        add_grid(cmd, "the config's dp.grid")
        cmd.add_argument("--start", choices=["smallest", "middle"], default="smallest",
                         help="initial stroke of the redundant cylinder: the smallest feasible or the middle of its window "
                         "(P-VI's two configurations)")
        add_quiet(cmd)
        cmd.set_defaults(func=cmd_dp_solve if name == "solve" else cmd_dp_compare)

    execute = verbs.add_parser("execute", help="run a planned trajectory on the simulated crane (P-VI App. A controller) into a bag",
                               description="Execute one method's trajectory in closed loop on the crane plant (valve dead zone "
                               "and delay, payload, CP or LS pump) and write a contract bag with the measured energy and the "
                               "ISO 9283 path accuracy in its truth metadata.")
    execute.add_argument("--config", required=True, help=CRANE_CONFIG)
    execute.add_argument("--path", required=True, help="path id of the config")
    execute.add_argument("--method", default="dp_cp", help="planning method of dp compare, e.g. dp_cp, dp_ls, pinv_joint (default dp_cp)")
    execute.add_argument("--supply", choices=["cp", "ls"], default="cp", help="pump of the simulated crane (default cp)")
    execute.add_argument("--db", default=None, help="take the solution from this trajectory database (default: plan it now)")
    add_grid(execute, "dp.grid, when planning now")
    execute.add_argument("--start-extension", type=number(float, 0.0, 100.0, unit="m"), default=None, metavar="M",
                         help="start with the redundant cylinder (the K70M's telescope) at this stroke (re-planned from there)")
    execute.add_argument("--seed", type=SEED, default=0, help="seed of the plant's valve spread")
    add_out(execute, "bag directory to create (must not exist)")
    execute.add_argument("--summary", default=None, help="also write the summary as JSON here")
    execute.set_defaults(func=cmd_dp_execute)

    db = sub.add_parser("db", help="the trajectory database the trajectory_server serves")
    verbs = db.add_subparsers(dest="db_command", required=True)
    build = verbs.add_parser("build", help="precompute the config's paths x methods into the database (resumes)",
                             description="Solve every path of a machine config with every catalog method and store the "
                             "solutions; what is already stored with the same inputs is skipped, so a killed build resumes.")
    build.add_argument("--config", required=True, help=CRANE_CONFIG)
    build.add_argument("--db", required=True, help="SQLite file (created if missing)")
    build.add_argument("--scheduler", default=None, metavar="ADDRESS", help="Dask scheduler, e.g. tcp://host:8786 (default: local processes)")
    build.add_argument("--workers", type=COUNT, default=None, help="local processes (default: one per core)")
    build.add_argument("--methods", nargs="+", default=None, help="methods (default: the config's catalog.methods)")
    build.add_argument("--paths", nargs="+", default=None, help="path ids (default: all of the config)")
    add_grid(build, "catalog.grid, else dp.grid")
    add_quiet(build)
    build.set_defaults(func=cmd_db_build)
    listing = verbs.add_parser("list", help="show the stored catalog")
    listing.add_argument("--db", required=True, help="SQLite file")
    listing.add_argument("--json", action="store_true", help="print the catalog as JSON (what trajectory_server latches)")
    listing.set_defaults(func=cmd_db_list)


def dp_problem(args: argparse.Namespace):  # planning types imported lazily
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.problem import Problem

    out = output_file(args.out)
    if (args.line is None) != (args.duration is None):
        raise InputError("--line and --duration go together: a straight tip line and its duration [s]")
    crane, config = load_crane(args.config)
    if args.line is not None:
        if args.path in config.paths:
            raise InputError(f"--path {args.path}: the config's own path; give the --line an id of its own")
        (x0, y0), (x1, y1) = args.line
        config = config.with_paths({args.path: {
            "description": f"straight line ({x0:g}, {y0:g}) to ({x1:g}, {y1:g}) m, quintic rest-to-rest, {args.duration:g} s",
            "start": [x0, y0, 0.0], "segments": [{"type": "quintic", "to": [x1, y1, 0.0], "duration": args.duration}]}})
    return Problem.build(crane, config, args.path, grid=tuple(args.grid) if args.grid else None, start=args.start), out


def cmd_dp_solve(args: argparse.Namespace) -> int:
    from hydro_ros.planning.costs import Cost
    from hydro_ros.planning.problem import method_record, plan_dp
    from hydro_ros.planning.trajectory import joint_table

    problem, out = dp_problem(args)
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
    write_json(out, result, indent=1)
    print(
        f"dp {args.cost} on {problem.path.path_id}: CP {record['cp_energy_J'] / 1e3:.1f} kJ, LS {record['ls_energy_J'] / 1e3:.1f} kJ, "
        f"limits {'ok' if record['limits_ok'] else 'VIOLATED'}, {plan.seconds:.1f} s"
    )
    return 0


def cmd_dp_compare(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.planning.problem import CONTRACT_METHODS, METHODS
    from hydro_ros.studies.dp_compare import compare, markdown_table, plot_comparison

    problem, out = dp_problem(args)
    methods = tuple(METHODS) if args.all_methods else CONTRACT_METHODS
    with tqdm(total=len(methods), unit="method", desc="dp compare", disable=args.quiet) as bar:

        def done(method: str) -> None:
            bar.set_postfix_str(method)
            bar.update(1)

        result = compare(problem, methods, progress=done)
    table = markdown_table(result)
    result["plot"] = str(plot_comparison(result, out.with_suffix(".png")))
    write_json(out, result)
    out.with_suffix(".md").write_text(table + "\n")
    print(table)
    return 0


def cmd_dp_execute(args: argparse.Namespace) -> int:
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.serving import executable_trajectory
    from hydro_ros.workflows.execution import execute, write_bag

    out = new_output(args.out)
    summary_out = output_file(args.summary, "--summary") if args.summary else None  # refused before the run, not after it
    _, config = load_crane(args.config)
    trajectory, planned = executable_trajectory(
        config, args.path, args.method, database=args.db, grid=tuple(args.grid) if args.grid else None,
        start_extension=args.start_extension,
    )
    execution = execute(config, trajectory, args.supply, seed=args.seed)
    summary = {"machine": config.name, "path": args.path, "method": args.method, "planned": planned, **execution.summary}
    write_bag(execution, out, {"machine": config.name, "execution": summary})
    if summary_out:
        write_json(summary_out, summary)
    energy_key = "cp_energy_J" if args.supply == "cp" else "ls_energy_J"
    print(
        f"dp execute {args.path}/{args.method} on the {args.supply.upper()} crane: {summary['energy_J'] / 1e3:.1f} kJ "
        f"(planned {planned[energy_key] / 1e3:.1f} kJ), ISO 9283 path accuracy {summary['path_accuracy_iso9283_m']:.3f} m -> {out}"
    )
    return 0


def cmd_db_build(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.cli.machine import grid_problems
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.catalog import build, plan_units
    from hydro_ros.planning.database import TrajectoryDatabase
    from hydro_ros.planning.dp import grid_sizes

    _, config = load_crane(args.config)
    problems = [] if args.grid else grid_problems(config)
    if problems:
        raise InputError(f"{args.config}: {problems[0]}")
    units = plan_units(
        config, methods=tuple(args.methods) if args.methods else None, grid=tuple(args.grid) if args.grid else None,
        paths=tuple(args.paths) if args.paths else None,
    )
    for grid in {unit.grid for unit in units}:  # refused before the database file is made
        grid_sizes(grid)
    with TrajectoryDatabase(args.db, writable=True) as db, tqdm(total=len(units), unit="solution", desc="db build", disable=args.quiet) as bar:
        stored = db.committed()
        bar.update(sum(1 for unit in units if stored.get(unit.key) == unit.inputs_hash))

        def done(unit) -> None:
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
