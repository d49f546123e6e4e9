"""``hydro-ros fleet analyse``, ``hydro-ros alarms export`` and ``hydro-ros demo``: the machines in service, their alarm
logs, and the whole chain shown once."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydro_ros.cli.common import COUNT, PORT, add_out, add_quiet, number, output_file, write_json
from hydro_ros.contract.errors import InputError


def register(sub: argparse._SubParsersAction) -> None:
    fleet = sub.add_parser("fleet", help="a fleet's recordings: leak trends per cylinder and when each needs service")
    verbs = fleet.add_subparsers(dest="fleet_command", required=True)
    analyse = verbs.add_parser(
        "analyse", help="every machine's recordings: alarms, leak estimates, trends, projected service dates",
        description="DIR holds one folder per machine, named by its id, with its config as machine.yaml and its recordings "
        "(bag folders or .mcap files) below it. Each recording is analysed once (keyed by its content hash in OUT/fleet.sqlite) "
        "on local processes or a Dask cluster; OUT/fleet.json, fleet.csv and fleet.html are written from everything analysed.")
    analyse.add_argument("dir", help="the fleet folder")
    add_out(analyse, "output folder (the store lives here: a rerun analyses only new recordings)")
    analyse.add_argument("--scheduler", default=None, help="Dask scheduler address (default: local processes)")
    analyse.add_argument("--workers", type=COUNT, default=None, help="local processes (default: one per core)")
    analyse.add_argument("--service-limit", type=number(float, 0.0, 1000.0, above=True, unit="L/min"),
                         default=0.5, help="[L/min at 10 MPa] a leak that needs service")
    add_quiet(analyse)
    analyse.set_defaults(func=cmd_fleet_analyse)

    alarms = sub.add_parser("alarms", help="fdi_node's alarm log")
    verbs = alarms.add_subparsers(dest="alarms_command", required=True)
    export = verbs.add_parser("export", help="every event of an alarm log as CSV and/or JSON, oldest first",
                              description="Read fdi_node's SQLite alarm log (parameter alarm_log) without writing to it.")
    export.add_argument("--db", required=True, help="the alarm log file")
    export.add_argument("--out", action="append", required=True, help="a file to write, .csv or .json (repeatable)")
    export.set_defaults(func=cmd_alarms_export)

    demo = sub.add_parser("demo", help="the main job: simulate a developing leak and run it through the nodes")
    demo.add_argument("--out", default="out/demo", help="directory for the bag and plots")
    demo.add_argument("--config", default=None, help="machine config (default: the installed sam.yaml)")
    demo.add_argument("--duration", type=number(float, 0.0, 86400.0, above=True, unit="s"), default=60.0, help="simulated seconds")
    demo.add_argument("--hmi-port", type=PORT, default=8080, help="port of the operator HMI on localhost (0: any free port)")
    demo.add_argument("--linger", type=number(float, 0.0, 86400.0, unit="s"), default=0.0, help="seconds to keep the graph and the HMI up after the replay")
    demo.set_defaults(func=cmd_demo)


def cmd_fleet_analyse(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from hydro_ros.workflows.fleet import analyse

    if not args.service_limit > 0:
        raise InputError(f"--service-limit {args.service_limit}: must be > 0 L/min")
    if args.workers is not None and args.workers < 1:
        raise InputError(f"--workers {args.workers}: must be >= 1")
    with tqdm(unit="recording", desc="fleet", disable=args.quiet) as bar:
        report = analyse(Path(args.dir), Path(args.out), scheduler=args.scheduler, workers=args.workers, limit=args.service_limit,
                         progress=lambda _: bar.update())
    flagged = [f"{name}/{actuator}" for name, machine in report.machines.items() for actuator in machine.flagged]
    print(json.dumps({"fleet": str(Path(args.out) / "fleet.json"), "recordings": report.recordings, "analysed": report.analysed,
                      "already_analysed": report.already_analysed, "duplicates": len(report.duplicates),
                      "unreadable": len(report.unreadable), "foreign": len(report.foreign), "flagged": flagged,
                      "ran_on": report.ran_on}))
    return 0


def cmd_alarms_export(args: argparse.Namespace) -> int:
    import csv

    from hydro_ros.fdi.alarm_log import COLUMNS, read_events

    outputs = [output_file(out) for out in args.out]
    unknown = [str(out) for out in outputs if out.suffix not in (".csv", ".json")]
    if unknown:
        raise InputError(f"--out {', '.join(unknown)}: the format follows the suffix, .csv or .json")
    events, _ = read_events(args.db, newest_first=False)
    for out in outputs:
        if out.suffix == ".json":
            write_json(out, events, indent=1)
            continue
        with open(out, "w", newline="") as stream:
            writer = csv.DictWriter(stream, fieldnames=COLUMNS)
            writer.writeheader()
            writer.writerows(dict(event, evidence=json.dumps(event["evidence"], sort_keys=True)) for event in events)
    print(json.dumps({"events": len(events), "written": [str(out) for out in outputs]}))
    return 0


def cmd_demo(args: argparse.Namespace) -> int:
    from hydro_ros.demo import run_demo

    return run_demo(Path(args.out), config_path=args.config, duration=args.duration, hmi_port=args.hmi_port, linger=args.linger)
