"""The machine's bus map checked against its DBC as can_bridge will read it: `machine check` names each problem in one
line, with the key that caused it; the unit conversions of the map (bar, kPa, psi, deg, mm, %) are exact."""

from __future__ import annotations

import math

import pytest
import yaml

from hydro_ros.can.codec import BusMapError, MachineBus
from hydro_ros.cli import main as cli
from hydro_ros.contract.machine import load_machine_config
from test.conftest import REPO

HEADER = 'VERSION ""\n\nNS_ :\n\nBS_:\n\nBU_: ECU BRIDGE\n\n'
MESSAGES = {
    "BOOM_ANGLE": (0x100, ['ANGLE : 0|16@1- (0.01,0) [-180|180] "deg"', 'SPOOL : 16|16@1- (0.01,0) [-100|100] "%"',
                           'RATE : 32|16@1- (0.01,0) [-300|300] "deg/s"']),
    "BOOM_HYD": (0x101, ['HEAD : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'ROD : 16|16@1+ (1,0) [0|65535] "kPa"']),
    "PUMP": (0x102, ['P_SUPPLY : 0|16@1+ (0.1,0) [0|6553.5] "psi"']),
}
MAP = {"supply_pressure": "PUMP.P_SUPPLY",
       "actuators": {"boom": {"joint_position": "BOOM_ANGLE.ANGLE", "joint_velocity": "BOOM_ANGLE.RATE",
                              "valve_command": "BOOM_ANGLE.SPOOL", "pressure_a": "BOOM_HYD.HEAD", "pressure_b": "BOOM_HYD.ROD"}}}


def _dbc(messages: dict) -> str:
    lines = [HEADER]
    for name, (frame_id, signals) in messages.items():
        lines.append(f"BO_ {frame_id} {name}: 8 ECU\n" + "".join(f" SG_ {s} BRIDGE\n" for s in signals) + "\n")
    return "".join(lines)


def _machine(tmp_path, messages: dict = MESSAGES, can_map: dict = MAP, write_dbc: bool = True):
    text = yaml.safe_load((REPO / "config" / "sam.yaml").read_text())
    text["can"] = {"dbc": "boom.dbc", "map": can_map}
    config = tmp_path / "boom.yaml"
    config.write_text(yaml.safe_dump(text, sort_keys=False))
    if write_dbc:
        (tmp_path / "boom.dbc").write_text(_dbc(messages))
    return config


def _problems(config) -> list[str]:
    try:
        MachineBus(load_machine_config(config))
    except BusMapError as exc:
        return exc.problems
    return []


def test_a_good_map_converts_every_unit_exactly(tmp_path):
    bus = MachineBus(load_machine_config(_machine(tmp_path)))
    signals = bus.per_actuator["boom"]
    assert signals["joint_position"].scale == pytest.approx(math.pi / 180)
    assert signals["joint_velocity"].scale == pytest.approx(math.pi / 180)
    assert signals["valve_command"].scale == 0.01
    assert signals["pressure_a"].scale == 1e5 and signals["pressure_b"].scale == 1e3
    assert bus.machine_wide["supply_pressure"].scale == pytest.approx(6894.757)
    # a cycle through the frames: 100 bar, 2000 kPa, 1500 psi, 30 deg, 50 %
    sample = {"joint_position": {"boom_joint": math.radians(30)}, "joint_velocity": {"boom_joint": math.radians(10)},
              "valve_command": {"boom": 0.5}, "pressure_a": {"boom": 1e7}, "pressure_b": {"boom": 2e6},
              "supply_pressure": 1500 * 6894.757}
    decoded = {}
    for frame_id, data in bus.encode_cycle(sample, 0):
        name, _, values = bus.decode(frame_id, data)
        decoded[name] = values
    assert decoded["BOOM_ANGLE"]["ANGLE"] == pytest.approx(30.0, abs=0.01) and decoded["BOOM_ANGLE"]["SPOOL"] == pytest.approx(50.0)
    assert decoded["BOOM_HYD"]["HEAD"] == pytest.approx(100.0) and decoded["BOOM_HYD"]["ROD"] == pytest.approx(2000.0)
    assert decoded["PUMP"]["P_SUPPLY"] == pytest.approx(1500.0, abs=0.1)


def _with(**changes) -> dict:
    messages = dict(MESSAGES)
    messages.update(changes)
    return messages


def _map(**actuator) -> dict:
    return {**MAP, "actuators": {"boom": {**MAP["actuators"]["boom"], **actuator}}}


CASES = {
    "a message the DBC lacks": (MESSAGES, _map(pressure_a="CYL_HYD.HEAD"), "no message 'CYL_HYD' (named by can.map.actuators.boom.pressure_a)"),
    "a signal the message lacks": (MESSAGES, _map(pressure_b="BOOM_HYD.ROD_SIDE"), "BOOM_HYD has no signal 'ROD_SIDE'"),
    "one signal for two quantities": (MESSAGES, _map(pressure_b="BOOM_HYD.HEAD"),
                                      "BOOM_HYD.HEAD is named by both can.map.actuators.boom.pressure_a and can.map.actuators.boom.pressure_b"),
    "the supply mapped onto a chamber": (MESSAGES, {**MAP, "supply_pressure": "BOOM_HYD.HEAD"},
                                         "BOOM_HYD.HEAD is named by both can.map.supply_pressure and can.map.actuators.boom.pressure_a"),
    "a unit-less pressure": (_with(BOOM_HYD=(0x101, ['HEAD : 0|16@1+ (0.01,0) [0|655.35] ""', 'ROD : 16|16@1+ (1,0) [0|65535] "kPa"'])),
                             MAP, "BOOM_HYD.HEAD is in '', not a unit of pressure_a"),
    "an angle in degrees labelled rad": (_with(BOOM_ANGLE=(0x100, ['ANGLE : 0|16@1- (0.01,0) [-180|180] "rad"',
                                                                   'SPOOL : 16|16@1- (0.01,0) [-100|100] "%"',
                                                                   'RATE : 32|16@1- (0.01,0) [-300|300] "deg/s"'])),
                                         MAP, "BOOM_ANGLE.ANGLE in 'rad' reaches 180 rad, more than two turns"),
    "a pressure in bar labelled Pa": (_with(BOOM_HYD=(0x101, ['HEAD : 0|16@1+ (0.01,0) [0|655.35] "Pa"', 'ROD : 16|16@1+ (1,0) [0|65535] "kPa"'])),
                                      MAP, "BOOM_HYD.HEAD in 'Pa' reaches only 655.4 SI, under a tenth"),
    "two messages with one id": (_with(PUMP=(0x101, ['P_SUPPLY : 0|16@1+ (0.1,0) [0|6553.5] "psi"'])), MAP,
                                 "frame id 0x101 is both BOOM_HYD and PUMP"),
    "overlapping signals": (_with(BOOM_HYD=(0x101, ['HEAD : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'ROD : 8|16@1+ (1,0) [0|65535] "kPa"'])),
                            MAP, "cannot load"),
    "a signal beyond its DLC": (_with(PUMP=(0x102, ['P_SUPPLY : 56|16@1+ (0.1,0) [0|6553.5] "psi"'])), MAP, "cannot load"),
}


@pytest.mark.parametrize("case", list(CASES))
def test_each_bad_map_is_refused_in_one_line_naming_it(tmp_path, case, capsys):
    messages, can_map, expected = CASES[case]
    config = _machine(tmp_path, messages, can_map)
    problems = _problems(config)
    assert any(expected in p for p in problems), problems
    assert all("\n" not in p for p in problems)
    assert cli(["machine", "check", str(config), "--quiet"]) == 1
    out = capsys.readouterr().out
    assert expected in out and "ok" not in out.splitlines()[-1]


def test_a_missing_dbc_is_named_beside_the_config(tmp_path, capsys):
    config = _machine(tmp_path, write_dbc=False)
    assert cli(["machine", "check", str(config), "--quiet"]) == 1
    assert f"dbc {tmp_path / 'boom.dbc'}: cannot load" in capsys.readouterr().out


def test_the_shipped_configs_pass_their_own_bus_check():
    for name in ("sam", "sam_mobile", "sam_mems", "boom_arm", "k70m"):
        MachineBus(load_machine_config(REPO / "config" / f"{name}.yaml"))
