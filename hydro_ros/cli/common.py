"""What the command families share: the arguments every command spells the same way, and the checks of their values."""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import shutil
import tempfile
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from hydro_ros.contract.check import DP_GRID_MIN
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.names import parse_injection


def number(kind: type, low: float, high: float, *, above: bool = False, unit: str = "") -> Any:
    """An argparse type: a finite ``kind`` (int or float) in [low, high] (``above``: greater than low), refused with the
    range otherwise. NaN, inf, -1 or 1e308 as a duration reached the simulator and hung or crashed there."""
    def parse(text: str) -> int | float:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not math.isfinite(value) or value < low or value > high or (above and value == low):
            shown = (str(low), str(high)) if kind is int else (f"{low:g}", f"{high:g}")
            bounds = f"{'(' if above else '['}{shown[0]}, {shown[1]}]"
            raise argparse.ArgumentTypeError(f"{text} is outside {bounds}{' ' + unit if unit else ''}")
        return value

    parse.__name__ = kind.__name__  # argparse names the expected type in its messages
    return parse


SECONDS = number(float, 0.0, 1e6, above=True, unit="s")  # a duration: more than nothing, under twelve days
SEED = number(int, 0, 2**32 - 1)
COUNT = number(int, 1, 1_000_000)
PORT = number(int, 0, 65535)


def add_config(parser: argparse.ArgumentParser, help: str = "machine config, e.g. config/sam.yaml") -> None:
    parser.add_argument("--config", required=True, help=help)


def add_out(parser: argparse.ArgumentParser, help: str, *, required: bool = True) -> None:
    """``--out``: where a command writes its file or folder (``--json`` is only ever a print format)."""
    parser.add_argument("--out", required=required, default=None, help=help)


def add_quiet(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def add_actuator(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--actuator", default=None, help=f"the cylinder to {what}, on a machine of several")


def add_grid(parser: argparse.ArgumentParser, default: str) -> None:
    parser.add_argument("--grid", type=number(int, DP_GRID_MIN, 100_000), nargs=3, metavar=("N_C", "N_V", "N_U"), help=f"DP grid (default: {default})")


def output_file(value: str, flag: str = "--out") -> Path:
    """A file to write, in a directory that exists."""
    out = Path(value)
    if not out.parent.is_dir():
        raise InputError(f"{flag} {out}: directory {out.parent} does not exist")
    return out


def new_output(value: str, flag: str = "--out") -> Path:
    """A file or folder to create, refused if something is there."""
    out = Path(value)
    if out.exists():
        raise InputError(f"{flag} {out}: already exists, refusing to overwrite")
    return out


OUTPUT_OPTIONS = ("out", "plot", "report", "summary")  # what a command writes: checked before its work starts
PLOT_SUFFIXES = (".png", ".pdf", ".svg")


def check_output(value: str, flag: str) -> None:
    """Refuse, before any work, an output that cannot be written: under a file, where nothing can be created (tried in
    the nearest folder that exists: a probe made and removed), a plot in a format matplotlib does not write."""
    out = Path(value)
    if flag == "--plot" and out.suffix.lower() not in PLOT_SUFFIXES:
        raise InputError(f"{flag} {out}: a plot is written as {', '.join(PLOT_SUFFIXES)}, not {out.suffix or 'without a suffix'}")
    existing = next(parent for parent in out.absolute().parents if parent.exists())
    if not existing.is_dir():
        raise InputError(f"{flag} {out}: {existing} is a file, not a folder")
    try:  # where the command will write (a folder it makes, or its file), tried and removed again
        with tempfile.TemporaryDirectory(dir=existing):
            pass
    except OSError as exc:
        raise InputError(f"{flag} {out}: cannot be written in {existing} ({exc.strerror or exc})") from None


def write_json(path: Path, data: Any, indent: int = 2) -> None:
    path.write_text(json.dumps(data, indent=indent) + "\n")


def at_least_one(args: argparse.Namespace, *names: str) -> None:
    for name in names:
        if getattr(args, name) < 1:
            raise InputError(f"--{name.replace('_', '-')} {getattr(args, name)}: must be >= 1")


def injections(texts: Sequence[str], kind: str, timed: bool) -> list:
    out = []
    for text in texts:
        if not timed and "@" in text:
            raise InputError(f"--{kind} {text!r}: effects are present from t = 0; use --fault NAME=VALUE@T for timed faults")
        try:
            out.append(parse_injection(text))
        except InputError as exc:
            raise InputError(f"--{kind} {exc}") from None
    return out


def one_actuator(machine, name: str | None, study: str):  # a Machine, kept lazy
    """The machine restricted to the actuator a one-cylinder study looks at: named with --actuator where there are several."""
    if name is None:
        if len(machine.actuators) > 1:
            raise InputError(f"--actuator: {study} looks at one cylinder and {machine.name} has {len(machine.actuators)} "
                             f"({', '.join(machine.actuator_names)}); name one")
        return machine
    from hydro_ros.models.serial_arm import machine_load

    machine.actuator(name)  # an unknown name is said first, on its own
    try:
        return machine.only(name, machine_load(machine, name))
    except ValueError as exc:
        raise InputError(f"--actuator {name}: {study} looks at one cylinder carrying its share of the arm, and {exc}") from None


@contextlib.contextmanager
def bag_or_nothing(out: str | Path) -> Iterator[None]:
    """A bag folder this command creates is removed if the run fails, so the rerun is not refused as an existing bag."""
    existed = Path(out).exists()
    try:
        yield
    except BaseException:
        if not existed:
            shutil.rmtree(out, ignore_errors=True)
        raise
