"""The machine's bus map checked against its DBC as can_bridge will read it: `machine check` names each problem in one
line, with the key that caused it; the unit conversions of the map (bar, kPa, psi, deg, mm, %) are exact."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml
from cantools.autosar.end_to_end import compute_profile2_crc
from cantools.database.errors import EncodeError
from crccheck.crc import Crc8SaeJ1850
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from hydro_ros.can.codec import BusMapError, FrameError, MachineBus
from hydro_ros.cli import main as cli
from hydro_ros.contract.errors import InputError
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


# each checksum a map can name, on frames built by an independent encoder: cantools encodes the signals, the checksum comes
# from crccheck's catalogue CRCs, the J1939-71 formula written out, a plain sum, cantools' own AUTOSAR E2E profile 2
def _j1939_4bit(frame_id: int, data: bytes) -> int:
    total = sum(data) + (frame_id & 0xFF) + ((frame_id >> 8) & 0xFF) + ((frame_id >> 16) & 0xFF) + ((frame_id >> 24) & 0xFF)
    return ((total >> 4) + total) & 0x0F


CHECKSUMMED = {  # algorithm -> (DBC message, map entry, independent checksum of the frame with its checksum bits zero)
    "crc8_sae_j1850_id": ('SG_ P : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'CS : 56|8@1+ (1,0) [0|255] ""', {},
                          lambda fid, d: Crc8SaeJ1850.calc(bytes([fid & 0xFF, fid >> 8 & 0xFF]) + d[:7])),
    "crc8_sae_j1850": ('SG_ P : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'CS : 56|8@1+ (1,0) [0|255] ""', {},
                       lambda fid, d: Crc8SaeJ1850.calc(d[:7])),
    "j1939_4bit": ('SG_ P : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'CS : 60|4@1+ (1,0) [0|15] ""', {},
                   lambda fid, d: _j1939_4bit(fid, d)),
    "byte_sum": ('SG_ P : 0|16@1+ (0.01,0) [0|655.35] "bar"', 'CS : 56|8@1+ (1,0) [0|255] ""', {}, lambda fid, d: sum(d[:7]) & 0xFF),
    "autosar_e2e_p2": ('SG_ P : 16|16@1+ (0.01,0) [0|655.35] "bar"', 'CS : 0|8@1+ (1,0) [0|255] ""', {"data_id": 0x3A},
                       lambda fid, d: compute_profile2_crc(d, 0x3A)),
}


@pytest.mark.parametrize("algorithm", list(CHECKSUMMED))
def test_each_checksum_algorithm_accepts_independently_built_frames_and_refuses_a_flipped_bit(tmp_path, algorithm):
    import cantools

    signal, checksum, extra, independent = CHECKSUMMED[algorithm]
    messages = {**MESSAGES, "PUMP": (0x18FF1021 | 0x80000000, [signal.removeprefix("SG_ "), checksum])}
    can_map = {**MAP, "supply_pressure": "PUMP.P", "checksums": {"PUMP": {"signal": "CS", "algorithm": algorithm, **extra}}}
    bus = MachineBus(load_machine_config(_machine(tmp_path, messages, can_map)))
    db = cantools.database.load_string(_dbc(messages))
    message = db.get_message_by_name("PUMP")
    rng = np.random.default_rng(7)
    for value in rng.uniform(0, 600, 50):
        zeroed = message.encode({"P": round(value, 2), "CS": 0})
        data = message.encode({"P": round(value, 2), "CS": independent(message.frame_id, zeroed)})
        name, _, values = bus.decode(message.frame_id, data)
        assert name == "PUMP" and values["P"] == pytest.approx(round(value, 2))
        assert bus._frame("PUMP", {"P": round(value, 2)}, 0)[1] == data  # our encoder writes the same frame
        flipped = bytearray(data)
        flipped[2] ^= 0x10  # a data bit in every layout above
        with pytest.raises(FrameError) as refused:
            bus.decode(message.frame_id, bytes(flipped))
        assert refused.value.kind == "bad_checksum"


def test_a_checksum_the_map_cannot_use_is_refused_naming_it(tmp_path):
    messages = {**MESSAGES, "PUMP": (0x102, ['P_SUPPLY : 0|16@1+ (0.1,0) [0|6553.5] "psi"', 'CS : 56|8@1+ (1,0) [0|255] ""'])}
    for entry, expected in (({"signal": "CS", "algorithm": "crc32"}, "algorithm: 'crc32': expected one of"),
                            ({"signal": "CS", "algorithm": "j1939_4bit"}, "must be a raw 4-bit signal for j1939_4bit"),
                            ({"signal": "CS", "algorithm": "autosar_e2e_p2"}, "autosar_e2e_p2 needs data_id"),
                            ({"signal": "NOPE"}, "no signal PUMP.NOPE (named by can.map.checksums.PUMP)")):
        problems = _problems(_machine(tmp_path, messages, {**MAP, "checksums": {"PUMP": entry}}))
        assert any(expected in p for p in problems), (entry, problems)


UNITS = ("bar", "kPa", "MPa", "Pa", "psi", "deg", "rad", "deg/s", "rad/s", "%", "mm", "m", "", "V", "degC")
QUANTITIES = ("joint_position", "joint_velocity", "valve_command", "pressure_a", "pressure_b")


@settings(max_examples=80, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(signals=st.lists(st.tuples(st.sampled_from([(m, i) for m, (_, s) in MESSAGES.items() for i in range(len(s))]),
                                  st.sampled_from(UNITS), st.sampled_from((0.01, 0.1, 1.0, 10.0, 1e-6, 1e6, -0.01, 0.0)),
                                  st.sampled_from((0, 8, 16, 24, 48, 56, 60))), max_size=3),
       entries=st.lists(st.tuples(st.sampled_from((*QUANTITIES, "supply_pressure", "valve_request", "nonsense")),
                                  st.sampled_from(("BOOM_ANGLE.ANGLE", "BOOM_HYD.HEAD", "BOOM_HYD.ROD", "PUMP.P_SUPPLY", "PUMP",
                                                   "NOPE.X", "", None, 3, ["BOOM_HYD.HEAD"], {"a": 1}))), max_size=3))
def test_a_randomly_damaged_map_and_dbc_give_a_bus_or_one_line_per_problem(tmp_path_factory, signals, entries):
    """Signals of the DBC given other units, scales and start bits, map entries pointed elsewhere or at nonsense: either
    a bus that encodes and decodes a cycle to within one scale step, or problems of one line each; never a traceback."""
    messages = {name: (frame_id, list(lines)) for name, (frame_id, lines) in MESSAGES.items()}
    for (message, index), unit, scale, start in signals:
        name = messages[message][1][index].split(" : ")[0]
        signed = "-" if "@1-" in messages[message][1][index] else "+"
        messages[message][1][index] = f'{name} : {start}|16@1{signed} ({scale:g},0) [-1000|1000] "{unit}"'
    can_map = {"supply_pressure": MAP["supply_pressure"], "actuators": {"boom": dict(MAP["actuators"]["boom"])}}
    for quantity, target in entries:
        (can_map if quantity == "supply_pressure" else can_map["actuators"]["boom"])[quantity] = target
    config = _machine(tmp_path_factory.mktemp("map"), messages, can_map)
    try:
        bus = MachineBus(load_machine_config(config))
    except BusMapError as exc:
        assert exc.problems and all(p and "\n" not in p for p in exc.problems), exc.problems
        return
    except InputError as exc:  # the config itself refused (a map entry that is not a name)
        assert str(exc) and "\n" not in str(exc)
        return
    sample = {"joint_position": {"boom_joint": 0.3}, "joint_velocity": {"boom_joint": -0.1}, "valve_command": {"boom": 0.25},
              "pressure_a": {"boom": 8.0e6}, "pressure_b": {"boom": 3.0e6}, "supply_pressure": 16.0e6}
    try:
        frames = bus.encode_cycle(sample, 0)
    except EncodeError:  # a value beyond its signal's range: cantools refuses to encode it
        return
    decoded = {}
    for frame_id, data in frames:
        name, _, values = bus.decode(frame_id, data)
        assert name in bus.expected
        decoded[name] = values
    mapped = [("supply_pressure", bus.machine_wide.get("supply_pressure"), sample["supply_pressure"])] + [
        (quantity, signal, sample[quantity]["boom_joint" if quantity.startswith("joint_") else "boom"])
        for quantity, signal in bus.per_actuator["boom"].items() if quantity in sample]
    for quantity, signal, value in mapped:
        if signal is None:
            continue
        dbc = bus.db.get_message_by_name(signal.message).get_signal_by_name(signal.signal)
        ends = [dbc.minimum, dbc.maximum, dbc.offset + dbc.scale * (-(1 << 15) if dbc.is_signed else 0),
                dbc.offset + dbc.scale * ((1 << 15) - 1 if dbc.is_signed else (1 << 16) - 1)]
        low = max(e for e in (ends[0], min(ends[2:])) if e is not None)
        high = min(e for e in (ends[1], max(ends[2:])) if e is not None)
        sent = min(max(value / signal.scale, low), high)  # a sender saturates at what the signal carries
        assert abs(decoded[signal.message][signal.signal] - sent) <= 0.51 * abs(dbc.scale) + 1e-9 * abs(sent), quantity
