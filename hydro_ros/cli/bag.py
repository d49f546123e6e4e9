"""``hydro-ros bag record|replay|info|convert``: contract bags from a live graph or a CAN log, onto a graph, described."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from hydro_ros.cli.common import SECONDS, add_config, add_quiet, bag_or_nothing, new_output, number
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config


def register(sub: argparse._SubParsersAction) -> None:
    bag = sub.add_parser("bag", help="contract bags: record, replay, info, convert a CAN log")
    verbs = bag.add_subparsers(dest="bag_command", required=True)
    rec = verbs.add_parser("record", help="record a running machine's contract topics into a bag, like ros2 bag record",
                           description="Subscribe to the config's sensor topics (raw CDR, each with the reliability its "
                           "publishers offer) and write them into a contract bag, log time = header stamp. Ctrl-C or SIGTERM "
                           "stops and closes the bag.")
    add_config(rec, "machine config: which topics the machine has")
    rec.add_argument("--out", required=True, help="bag directory to create")
    rec.add_argument("--duration", type=SECONDS, default=None, help="stop after S seconds of wall time (default: until Ctrl-C)")
    rec.add_argument("--split-duration", type=SECONDS, default=None, metavar="S", help="start a new file every S seconds of log time")
    rec.add_argument("--split-size", type=number(float, 0.0, 1e6, above=True, unit="MB"), default=None, metavar="MB",
                     help="start a new file after MB megabytes of messages (before compression)")
    rec.add_argument("--outputs", action="store_true", help="also record /diagnostics")
    add_quiet(rec)
    rec.set_defaults(func=cmd_bag_record)

    replay = verbs.add_parser("replay", help="play a contract bag onto ROS topics, like ros2 bag play")
    replay.add_argument("bag", help="bag directory")
    replay.add_argument("--rate", type=number(float, 0.0, 1000.0, above=True), default=1.0, help="playback rate (1 = recorded speed)")
    replay.add_argument("--loop", action="store_true", help="start again at the end")
    replay.add_argument("--clock", action="store_true", help="publish /clock with the bag's log times (for use_sim_time nodes; off "
                        "by default, as ros2 bag play)")
    replay.add_argument("--no-clock", action="store_true", help=argparse.SUPPRESS)  # the old spelling: /clock is now off by default
    replay.set_defaults(func=cmd_bag_replay)

    info = verbs.add_parser("info", help="files, topics, message counts and damage of a bag, read from the files",
                            description="Read every file of a bag (split bags whole) and report its messages per topic; "
                            "exits 1 when a file is damaged or disagrees with metadata.yaml.")
    info.add_argument("bag", help="bag directory or .mcap file")
    info.add_argument("--json", action="store_true", help="print JSON")
    info.add_argument("--stats", action="store_true", help="also each topic's and field's min / mean / max in SI units (reads "
                                                           "every message): check a CAN map's units on a converted log")
    info.set_defaults(func=cmd_bag_info)

    convert = verbs.add_parser("convert", help="a machine's CAN log (candump .log, .asc, .blf) -> contract bag",
                               description="Decode a CAN log through the machine config's signal map (can: dbc, map); bad "
                               "frames are counted, never written.")
    convert.add_argument("logfile", help="candump .log, Vector .asc or .blf")
    add_config(convert, "machine config (its can: section maps the DBC's signals)")
    convert.add_argument("--dbc", default=None, help="the bus's DBC file, instead of the config's can.dbc")
    convert.add_argument("--out", required=True, help="bag directory to create (must not exist)")
    convert.set_defaults(func=cmd_bag_convert)


def cmd_bag_record(args: argparse.Namespace) -> int:
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


def cmd_bag_replay(args: argparse.Namespace) -> int:
    from hydro_ros.bags.reader import bag_info
    from hydro_ros.nodes.bag_player import replay

    info = bag_info(args.bag)  # before ROS starts: a bag with nothing to play is refused in one line
    if not info["messages"]:
        raise InputError(f"bag {args.bag}: nothing to play ({info['errors'][0] if info['errors'] else 'no messages'})")

    return replay(args.bag, rate=args.rate, loop=args.loop, clock=args.clock, ros_args=args.ros_args)


def cmd_bag_info(args: argparse.Namespace) -> int:
    from hydro_ros.bags.reader import bag_info

    info = bag_info(args.bag)
    if info["errors"] and not info["messages"]:
        raise InputError(f"bag {args.bag}: nothing readable ({info['errors'][0]})")
    if args.stats:
        from hydro_ros.bags.reader import read_bag

        info["stats"] = read_bag(args.bag).stats()
    if args.json:
        print(json.dumps(info, indent=1))
    else:
        print(f"bag {info['bag']}: {info['messages']} messages over {info['duration_s']:.3f} s in {len(info['files'])} file(s)"
              f"{', with ground truth' if info['ground_truth'] else ''}")
        for row in info["files"]:
            print(f"  {row['path']}: {row['messages']} messages, {row['bytes']} bytes")
        for topic, row in info["topics"].items():
            print(f"  {topic} [{row['type']}]: {row['messages']}")
        for field_name, row in info.get("stats", {}).items():
            values = f"min {row['min']:.6g}, mean {row['mean']:.6g}, max {row['max']:.6g}" if row["samples"] else "no finite value"
            print(f"  {field_name} [{row['unit']}]: {values} ({row['samples']} samples)")
        for error in info["errors"]:
            print(f"  error: {error}")
    return 1 if info["errors"] else 0


def cmd_bag_convert(args: argparse.Namespace) -> int:
    from hydro_ros.can.convert import convert_log

    machine = load_machine_config(args.config)
    new_output(args.out)
    with bag_or_nothing(args.out):
        report = convert_log(args.logfile, machine, args.out, dbc=args.dbc)
    print(json.dumps({"bag": str(args.out), **report.to_json()}))
    return 0
