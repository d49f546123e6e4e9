"""hydro-ros as a user runs it: --help, one-line errors without traceback, sim writes a bag."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

from test.conftest import K70M, REPO, SAM_CONFIG

BAGS = REPO / "bags"

CLI = [sys.executable, "-m", "hydro_ros.cli"]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("sub", ["sim", "bag", "demo", "fdi", "commission", "dp", "machine"])
def test_every_subcommand_has_help(sub):
    result = run(sub, "--help")
    assert result.returncode == 0 and "usage: hydro-ros" in result.stdout


@pytest.mark.parametrize(
    "args, needle",
    [
        (["sim", "--config", "missing.yaml", "--duration", "1", "--out", "X"], "missing.yaml: no such file"),
        (["sim", "--config", str(SAM_CONFIG), "--duration", "1", "--fault", "bogus_leak=1@2", "--out", "X"], "unknown fault or effect 'bogus_leak'"),
        (["sim", "--config", str(SAM_CONFIG), "--duration", "1", "--fault", "internal_leakage=oops", "--out", "X"], "cannot parse"),
        (["sim", "--config", str(SAM_CONFIG), "--duration", "1", "--effect", "payload_mass=50@3", "--out", "X"], "effects are present from t = 0"),
        (["sim", "--config", str(SAM_CONFIG), "--duration", "1", "--path", "horizontal", "--out", "X"], "--path: planned machines only"),
        (["sim", "--config", str(K70M), "--duration", "1", "--hold", "2", "--out", "X"], "--hold: only with --path"),
        (["sim", "--config", str(K70M), "--duration", "1", "--path", "nowhere", "--out", "X"], "path 'nowhere': not in config k70m"),
        (["fdi", "run", "--bag", "nobag", "--config", str(SAM_CONFIG), "--out", "X"], "bag nobag: no such file or directory"),
        (["fdi", "run", "--bag", str(BAGS / "fault_free"), "--config", str(SAM_CONFIG), "--method", "parity", "--out", "X"], "pilot pressures"),
        (["fdi", "run", "--bag", str(BAGS / "fault_free"), "--config", str(SAM_CONFIG), "--out", "nodir/X.json"], "directory nodir does not exist"),
        (["bag", "convert", "missing.blf", "--config", str(SAM_CONFIG), "--out", "X"], "log missing.blf: no such file"),
    ],
)
def test_bad_input_gives_one_line_error(args, needle, tmp_path):
    result = subprocess.run([*CLI, *args], capture_output=True, text=True, cwd=tmp_path, timeout=120)
    assert result.returncode == 1
    assert needle in result.stderr
    assert "Traceback" not in result.stderr and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "X").exists()


def test_sim_writes_bag_and_plot(tmp_path):
    out = tmp_path / "bag"
    result = run("sim", "--config", str(SAM_CONFIG), "--duration", "2", "--fault", "internal_leakage=0.5@1",
                 "--effect", "payload_mass=50", "--seed", "4", "--out", str(out), "--quiet")
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    assert report["messages"] == 10000
    assert (out / "metadata.yaml").is_file() and (tmp_path / "bag.png").stat().st_size > 10000
    again = run("sim", "--config", str(SAM_CONFIG), "--duration", "2", "--out", str(out), "--quiet")
    assert again.returncode == 1 and "already exists" in again.stderr


def test_fdi_writes_contract_json_and_plot(tmp_path):
    out = tmp_path / "ext_a.json"
    result = run("fdi", "run", "--bag", str(BAGS / "external_leakage_a"), "--config", str(SAM_CONFIG), "--out", str(out), "--quiet")
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    boom = report["actuators"]["boom"]
    assert boom["fault"] == "external_leakage_a" and 10.0 < boom["first_detection_s"] < 16.0
    assert {"time_s", "actuator", "fault", "code"} <= set(report["alarms"][0])
    assert report["alarms"][-1]["fault"] == "external_leakage_a"
    assert out.with_suffix(".png").stat().st_size > 10000


def test_fdi_names_a_missing_topic(tmp_path):
    from mcap.writer import Writer

    from hydro_ros.bags.cdr import encode_joint_state

    bag = tmp_path / "joints_only.mcap"
    with bag.open("wb") as stream:
        writer = Writer(stream)
        writer.start("ros2", "test")
        channel = writer.register_channel("/joint_states", "cdr", writer.register_schema("sensor_msgs/msg/JointState", "ros2msg", b""))
        for k in range(100):
            writer.add_message(channel, k, encode_joint_state(k * 1_000_000, "", ["boom_joint"], [0.0], [0.0], []), k)
        writer.finish()
    result = run("fdi", "run", "--bag", str(bag), "--config", str(SAM_CONFIG), "--out", str(tmp_path / "x.json"))
    assert result.returncode == 1 and "no /hydraulics/boom/pressure_a" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (tmp_path / "x.json").exists()


@pytest.mark.parametrize(("old", "new"), [
    (["fdi", "--bag", str(BAGS / "fault_free"), "--config", str(SAM_CONFIG), "--json", "OUT"], "`fdi` is now `fdi run`"),
    (["fdi-eval", "--config", "missing.yaml", "--seeds", "1", "--out", "OUT"], "`fdi-eval` is now `fdi eval`"),
    (["can", "convert", "missing.blf", "--config", str(SAM_CONFIG), "--out", "OUT"], "`can convert` is now `bag convert`"),
])
def test_the_previous_releases_spellings_still_work_and_say_the_new_one(old, new, tmp_path):
    result = subprocess.run([*CLI, *[str(tmp_path / "x.json") if word == "OUT" else word for word in old]], capture_output=True,
                            text=True, cwd=tmp_path, timeout=120)
    assert new in result.stderr and "the old spelling works for one release" in result.stderr
    assert "invalid choice" not in result.stderr and "unrecognized arguments" not in result.stderr
    assert result.returncode == (0 if old[0] == "fdi" else 1), result.stderr


@pytest.mark.parametrize("argv, argument", [
    (["sim", "--config", "config/sam.yaml", "--duration", "nan", "--out", "x"], "--duration"),
    (["sim", "--config", "config/sam.yaml", "--duration", "inf", "--out", "x"], "--duration"),
    (["sim", "--config", "config/sam.yaml", "--duration", "10", "--seed", "-1", "--out", "x"], "--seed"),
    (["machine", "threshold", "config/sam.yaml", "--duration", "1e308", "--out", "x"], "--duration"),
    (["fdi", "eval", "--duration", "-1"], "--duration"), (["fdi", "eval", "--duration", "0"], "--duration"),
    (["fdi", "eval", "--config", "config/sam.yaml", "--seeds", "0", "--out", "x"], "--seeds"),
    (["dp", "execute", "--config", "config/k70m.yaml", "--path", "horizontal", "--start-extension", "nan"], "--start-extension"),
    (["bag", "record", "--config", "config/sam.yaml", "--out", "x", "--split-size", "inf"], "--split-size"),
    (["bag", "record", "--config", "config/sam.yaml", "--out", "x", "--duration", "inf"], "--duration"),
    (["demo", "--duration", "1e308"], "--duration"),
])
def test_numbers_that_mean_nothing_are_refused_with_their_range(argv, argument, capsys):
    from hydro_ros.cli import main as cli

    with pytest.raises(SystemExit) as exited:
        cli(argv)
    error = capsys.readouterr().err.strip().splitlines()[-1]
    assert exited.value.code == 1 and f"argument {argument}: " in error and "is outside" in error, error


def test_a_usage_error_and_a_refused_input_exit_alike(tmp_path, capsys):
    """One exit code for bad input, whoever finds it: argparse (an unknown option) or the command (a missing file)."""
    from hydro_ros.cli import main as cli

    with pytest.raises(SystemExit) as usage:
        cli(["sim", "--config", "config/sam.yaml", "--duration", "1", "--out", str(tmp_path / "x"), "--bogus"])
    assert usage.value.code == 1 and "unrecognized arguments: --bogus" in capsys.readouterr().err
    assert cli(["bag", "info", str(tmp_path / "missing")]) == 1
    assert "error:" in capsys.readouterr().err


@pytest.mark.slow  # two DP solves through the CLI (~14 s)
def test_dp_plans_a_straight_line_given_on_the_command_line_as_the_config_path_it_equals(tmp_path):
    """`dp solve --line` plans the K70M's horizontal path's own line (3.0, 0.5) -> (6.2, 0.5) m in 10 s as the config's
    path does, to the joule; a line out of reach, a point for a line and a config path's id are refused in one line."""
    energies = []
    for path, line in (("horizontal", ()), ("across", ("--line", "3.0,0.5:6.2,0.5", "--duration", "10"))):
        out = tmp_path / f"{path}.json"
        done = run("dp", "solve", "--config", str(K70M), "--path", path, *line, "--cost", "cp", "--grid", "60", "21", "31",
                   "--out", str(out), "--quiet")
        assert done.returncode == 0, done.stderr
        result = json.loads(out.read_text())
        energies.append((result["cp_energy_J"], result["ls_energy_J"]))
    assert energies[0] == pytest.approx(energies[1], rel=1e-9)
    for args, needle in ((("--path", "far", "--line", "30,0:31,0", "--duration", "5"), "is out of reach of k70m: no extension stroke reaches it"),
                         (("--path", "dot", "--line", "4,0.5:4,0.5", "--duration", "5"), "the line has no length"),
                         (("--path", "horizontal", "--line", "3,0.5:6,0.5", "--duration", "5"), "the config's own path"),
                         (("--path", "nodur", "--line", "3,0.5:6,0.5"), "--line and --duration go together")):
        done = run("dp", "solve", "--config", str(K70M), *args, "--cost", "cp", "--grid", "60", "21", "31", "--out", str(tmp_path / "x.json"))
        assert done.returncode == 1 and needle in done.stderr.strip().splitlines()[-1], (args, done.stderr)
