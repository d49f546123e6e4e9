"""Every subcommand, walked from the parser (a new one is covered by itself), given each class of bad input in each of
its inputs, the others sound: refused in one line naming the input, exit code 1, no traceback, within seconds."""

from __future__ import annotations

import argparse
import signal
import time
from pathlib import Path

import can
import pytest

from hydro_ros.can.codec import MachineBus
from hydro_ros.cli import LEGACY, build_parser
from hydro_ros.cli import main as cli
from hydro_ros.contract.machine import load_machine_config
from test.conftest import REPO

SECONDS = 5.0
PLANNING = {"dp", "db"}  # commands of the crane's motion side read a crane config
OUTPUTS = {"--out", "--plot", "--report", "--summary"}
INPUT_FILES = {"--config", "config", "--bag", "bag", "logfile", "--dbc"}
NOT_FUZZED = {("demo",)}  # starts a graph of nodes; its numbers are argparse's (test_cli.py)


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        yield path, parser
        return
    for name, sub in subs[0].choices.items():
        yield from _commands(sub, (*path, name))


COMMANDS = [(path, parser) for path, parser in _commands(build_parser()) if path not in NOT_FUZZED]


@pytest.fixture(scope="module")
def sound(tmp_path_factory) -> dict[str, str]:
    """Inputs that work, for every option that is not the one under test."""
    folder = tmp_path_factory.mktemp("sound")
    log = folder / "bus.log"
    machine = load_machine_config(REPO / "config" / "sam.yaml")
    bus = MachineBus(machine)
    sample = {"joint_position": {"boom_joint": 0.1}, "joint_velocity": {"boom_joint": 0.0}, "pressure_a": {"boom": 6e6},
              "pressure_b": {"boom": 2e6}, "valve_command": {"boom": 0.0}, "supply_pressure": 1e7}
    writer = can.Logger(str(log))
    for k in range(50):
        for frame_id, data in bus.encode_cycle(sample, k % 16):
            writer.on_message_received(can.Message(timestamp=1.7e9 + k * 1e-3, arbitration_id=frame_id, data=data, is_extended_id=False))
    writer.stop()
    (folder / "fleet").mkdir()
    return {"--bag": str(REPO / "bags" / "fault_free"), "bag": str(REPO / "bags" / "fault_free"), "logfile": str(log),
            "dir": str(folder / "fleet"), "--path": "horizontal", "--cost": "cp", "--namespace": "m1", "--like": "sam",
            "--db": str(folder / "missing.db"), "folder": str(folder)}


def _bad_inputs(folder: Path) -> dict[str, list[tuple[str, str]]]:
    """Per class of input: (what, value)."""
    binary = folder / "binary.mcap"
    binary.write_bytes(b"\x89MCAP0\r\n" + bytes(range(256)) * 8)
    latin = folder / "latin1.yaml"
    latin.write_bytes("machine: b\xe9ton\n".encode("latin-1"))
    bomb = folder / "bomb.yaml"
    bomb.write_text("a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, "
        f"*{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}, *{chr(97 + i)}]\n" for i in range(8)))
    empty = folder / "empty"
    empty.write_bytes(b"")
    a_file = folder / "a_file"
    a_file.write_text("x")
    inputs = [("missing", str(folder / "missing")), ("a folder", str(folder)), ("empty", str(empty)), ("binary", str(binary)),
              ("not UTF-8", str(latin)), ("an alias bomb", str(bomb))]
    return {"input": inputs, "number": [("NaN", "nan"), ("negative", "-1"), ("huge", "1e308")],
            "output": [("under a file", str(a_file / "out")), ("under /proc", "/proc/hydro_ros_fuzz/out")]}


def _fill(parser: argparse.ArgumentParser, path: tuple[str, ...], sound: dict[str, str], folder: Path) -> dict[str, list[str]]:
    """The sound argv pieces of every required input (and of the number options: their defaults are sound already)."""
    config = str(REPO / "config" / ("k70m.yaml" if path[0] in PLANNING else "sam.yaml"))
    pieces: dict[str, list[str]] = {}
    for action in parser._actions:
        if isinstance(action, argparse._HelpAction) or not (action.required or not action.option_strings):
            continue
        name = action.option_strings[0] if action.option_strings else action.dest
        if name in ("--config", "config"):
            value = config
        elif name in OUTPUTS or (name == "--db" and path == ("db", "build")):
            value = str(folder / f"new_{len(pieces)}{'.csv' if path == ('alarms', 'export') else ''}")
        elif getattr(action.type, "__name__", None) in ("int", "float"):
            value = "1"
        elif action.choices:
            value = sorted(action.choices)[0]
        else:
            value = sound[name]
        count = action.nargs if isinstance(action.nargs, int) else 1
        pieces[name] = ([name] if action.option_strings else []) + [value] * count
    return pieces


def _cases():
    for path, parser in COMMANDS:
        for action in parser._actions:
            if isinstance(action, argparse._HelpAction) or (not action.option_strings and action.dest in ("command",)):
                continue
            name = action.option_strings[0] if action.option_strings else action.dest
            if name in INPUT_FILES or (name == "--db" and path in (("db", "list"), ("alarms", "export"))):
                kind = "input"
            elif name in OUTPUTS or (name == "--db" and path == ("db", "build")):
                kind = "output"
            elif getattr(action.type, "__name__", None) in ("int", "float"):
                kind = "number"
            else:
                continue
            yield pytest.param(path, name, kind, id=f"{' '.join(path)} {name}")


class _TooLong(Exception):
    pass


@pytest.mark.parametrize(("path", "name", "kind"), list(_cases()))
def test_every_bad_input_is_refused_in_one_line(path, name, kind, sound, tmp_path, capsys):
    parser = dict(COMMANDS)[path]
    bad = _bad_inputs(tmp_path)[kind]
    action = next(a for a in parser._actions if (a.option_strings[:1] or [a.dest])[0] == name)
    count = action.nargs if isinstance(action.nargs, int) else 1
    for what, value in bad:
        pieces = _fill(parser, path, sound, tmp_path)
        pieces[name] = ([name] if action.option_strings else []) + [value] * count
        positional = [p for key, p in pieces.items() if not key.startswith("-")]
        argv = [*path, *(v for p in positional for v in p), *(v for key, p in pieces.items() if key.startswith("-") for v in p)]

        def too_long(*_):
            raise _TooLong(f"{' '.join(argv)}: still running after {SECONDS:g} s")

        previous = signal.signal(signal.SIGALRM, too_long)
        signal.setitimer(signal.ITIMER_REAL, SECONDS)
        began = time.monotonic()
        try:
            code = cli(argv)
        except SystemExit as exited:
            code = exited.code
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, previous)
        err = capsys.readouterr().err.strip().splitlines()
        assert code == 1, (what, argv, code, err[-3:])
        assert err and "error" in err[-1] and (name.lstrip("-") in err[-1] or value in err[-1] or Path(value).name in err[-1]), \
            (what, argv, err[-3:])
        assert time.monotonic() - began < SECONDS


@pytest.mark.parametrize("old", [old for old, _, _ in LEGACY], ids=" ".join)
def test_the_previous_releases_spellings_refuse_bad_input_alike(old, tmp_path, capsys):
    """The older command forms go through the same checks: a missing input is one line and exit 1 there too."""
    argv = [*old, "--config", str(tmp_path / "missing.yaml"), "--bag", str(tmp_path / "missing"), "--db", str(tmp_path / "missing.db"),
            "--path", "horizontal", "--cost", "cp", "--out", str(tmp_path / "out.json"), str(tmp_path / "missing")]
    try:
        code = cli(argv)
    except SystemExit as exited:
        code = exited.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 1 and err and "error" in err[-1], (argv, code, err[-3:])
