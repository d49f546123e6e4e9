"""``hydro-ros``: the package's one command line, nouns then verbs.

As ``hydro-ros bag info`` or ``hydro-ros fdi run``; a file or folder a command writes is ``--out``, and ``--json`` only
ever asks for JSON on the screen.

Every command exits 0 on success and 1 with a one-line error naming the bad input, whether argparse or the command
found it (argparse's own code would be 2). The spellings of the previous
release (``fdi-eval``, ``record``, ``fdi --json``, ...) still work for one release, with a note saying the new one.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Sequence
from typing import NoReturn

from hydro_ros.cli import bag, fdi, machine, operations, planning, sim, studies
from hydro_ros.cli.common import OUTPUT_OPTIONS, check_output
from hydro_ros.contract.errors import InputError

FAMILIES = (sim, fdi, bag, studies, planning, machine, operations)
ROS_COMMANDS = (("bag", "record"), ("bag", "replay"))  # run a ROS node in this process: take --ros-args as ros2 run does
# the previous release's spellings: (its words, today's words, its options renamed); hidden from --help
LEGACY: tuple[tuple[tuple[str, ...], tuple[str, ...], dict[str, str]], ...] = (
    (("fdi-eval",), ("fdi", "eval"), {}),
    (("fdi-fit",), ("fdi", "fit"), {}),
    (("record",), ("bag", "record"), {}),
    (("replay",), ("bag", "replay"), {}),
    (("can", "convert"), ("bag", "convert"), {}),
    (("foxglove-layout",), ("foxglove", "layout"), {}),
    (("gsa",), ("gsa",), {"--json": "--out"}),
    (("dp", "solve"), ("dp", "solve"), {"--json": "--out"}),
    (("dp", "compare"), ("dp", "compare"), {"--json": "--out"}),
    (("dp", "execute"), ("dp", "execute"), {"--json": "--summary"}),
    (("alarms", "export"), ("alarms", "export"), {"--csv": "--out", "--json": "--out"}),
    (("fdi",), ("fdi", "run"), {"--json": "--out"}),  # the old `fdi --bag ...`: a verb-less fdi (last: `fdi run` is matched first)
)
FDI_VERBS = ("run", "eval", "fit", "-h", "--help")


class CommandParser(argparse.ArgumentParser):
    """argparse's parser whose usage errors exit 1, as every other refusal of bad input does (one exit code for a script)."""

    def error(self, message: str) -> NoReturn:
        self.print_usage(sys.stderr)
        self.exit(1, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    parser = CommandParser(prog="hydro-ros", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    for family in FAMILIES:
        family.register(sub)
    return parser


def today(argv: list[str]) -> tuple[list[str], list[str]]:
    """``argv`` in today's spelling, and a note for each old spelling it used."""
    for old, new, options in LEGACY:
        if tuple(argv[:len(old)]) != old or (old == ("fdi",) and (len(argv) == 1 or argv[1] in FDI_VERBS)):
            continue
        notes = [f"`{' '.join(old)}` is now `{' '.join(new)}`"] if old != new else []
        rest = []
        for word in argv[len(old):]:
            flag, equals, value = word.partition("=")
            if flag in options:
                notes.append(f"`{' '.join(new)} {flag}` is now `{options[flag]}`")
                word = options[flag] + equals + value
            rest.append(word)
        return [*new, *rest], notes
    return argv, []


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    ros_args = argv[argv.index("--ros-args") + 1:] if "--ros-args" in argv else []
    words, notes = today(argv[:argv.index("--ros-args")] if "--ros-args" in argv else argv)
    for note in notes:
        print(f"hydro-ros: note: {note} (the old spelling works for one release)", file=sys.stderr)
    args = parser.parse_args(words)
    args.ros_args = ros_args
    command = tuple(w for w in (args.command, getattr(args, f"{args.command}_command", None)) if w)
    if "--ros-args" in argv and command not in ROS_COMMANDS:
        parser.error(f"--ros-args: only {', '.join(' '.join(c) for c in ROS_COMMANDS)} start ROS nodes")
    func: Callable[[argparse.Namespace], int] = args.func
    outputs = [(dest, getattr(args, dest)) for dest in OUTPUT_OPTIONS if getattr(args, dest, None)]
    if command == ("db", "build"):
        outputs.append(("db", args.db))
    try:
        for dest, value in outputs:
            check_output(str(value), f"--{dest}")
        return func(args)
    except InputError as exc:  # bad input is one line; anything else is a bug and keeps its traceback
        print(f"hydro-ros {' '.join(command)}: error: {exc}", file=sys.stderr)
        return 1
    except OSError as exc:  # the machine's refusal (a full disk, a permission): one line too
        print(f"hydro-ros {' '.join(command)}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130
