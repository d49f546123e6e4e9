"""The machine bus: DBC codec, frame checks, cycle grouping, log conversion; fuzzed with hypothesis."""

from __future__ import annotations

import can
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hydro_ros.bags.reader import read_bag
from hydro_ros.can.clock import BLOCK_CYCLES
from hydro_ros.can.codec import CounterCheck, CycleAssembler, FrameError, MachineBus, crc8, cycle_values, sample_values
from hydro_ros.can.convert import convert_log
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import Injection
from hydro_ros.sim.scenario import Scenario, run_blocks
from test.conftest import REPO


@pytest.fixture(scope="module")
def bus(sam_config):
    return MachineBus(sam_config)


def _cycle_frames(bus, sample, counter):
    return bus.encode_cycle(sample, counter)


def test_crc8_is_sae_j1850():
    # CRC-8/SAE-J1850 check value of "123456789" is 0x4B (catalogue of parametrised CRCs)
    from hydro_ros.can import codec

    assert codec._crc8(0x1D, b"123456789") == 0x4B
    assert codec._crc8(0x2F, b"123456789") == 0xDF  # CRC-8/AUTOSAR (8H2F), E2E profile 2


def test_a_cycle_round_trips_within_signal_resolution(bus):
    sample = {"joint_position": {"boom_joint": -0.4321}, "joint_velocity": {"boom_joint": 0.123},
              "pressure_a": {"boom": 7.25e6}, "pressure_b": {"boom": 3.1e6}, "valve_command": {"boom": -0.37},
              "supply_pressure": 1.0e7}
    assembler = CycleAssembler(bus.expected, bus.clock())
    released = []
    for frame_id, data in bus.encode_cycle(sample, counter=5):
        name, counter, values = bus.decode(frame_id, data)
        assert counter == 5
        released += assembler.add(name, counter, values, 1000)
    assert len(released) == 1 and released[0].complete(bus.expected)
    values = cycle_values(bus, released[0])
    assert values["joint_position"]["boom_joint"] == pytest.approx(-0.4321, abs=1e-7)
    assert values["joint_velocity"]["boom_joint"] == pytest.approx(0.123, abs=1e-4)
    assert values["pressure_a"]["boom"] == pytest.approx(7.25e6, abs=500)
    assert values["valve_command"]["boom"] == pytest.approx(-0.37, abs=1 / 30000)
    assert values["supply_pressure"] == pytest.approx(1.0e7, abs=500)


def test_bad_frames_are_rejected_by_kind(bus):
    frame_id, data = bus.encode_cycle({"joint_position": {"boom_joint": 0.0}, "joint_velocity": {"boom_joint": 0.0},
                                       "pressure_a": {"boom": 5e6}, "pressure_b": {"boom": 1e6}, "valve_command": {"boom": 0.0},
                                       "supply_pressure": 1e7}, 0)[2]
    with pytest.raises(FrameError) as unknown:
        bus.decode(0x7FF, data)
    assert unknown.value.kind == "unknown_id"
    with pytest.raises(FrameError) as short:
        bus.decode(frame_id, data[:6])
    assert short.value.kind == "wrong_dlc"
    flipped = bytearray(data)
    flipped[1] ^= 0x10
    with pytest.raises(FrameError) as corrupt:
        bus.decode(frame_id, bytes(flipped))
    assert corrupt.value.kind == "bad_checksum"


def test_counter_gaps_and_incomplete_cycles_are_counted(bus):
    check = CounterCheck()
    for counter in (0, 1, 2, 5, 6, 6):
        check("CYL1_PRESSURE", counter)
    assert check.gaps["CYL1_PRESSURE"] == 2  # 2 -> 5 and 6 -> 6
    assembler = CycleAssembler(bus.expected, bus.clock(), horizon=2)
    released = []
    for counter in range(5):  # only one of the four frames of each cycle arrives
        released += assembler.add("SUPPLY_STATE", counter, {"SUPPLY_P_S": 1e7, "SUPPLY_P_LS": 0.0}, counter)
    assert assembler.incomplete == len(released) == 3 and not any(c.complete(bus.expected) for c in released)


@settings(max_examples=3000, deadline=None)
@given(frame_id=st.one_of(st.integers(0, 0x7FF), st.sampled_from([0x101, 0x111, 0x121, 0x140])),
       data=st.binary(min_size=0, max_size=8))
def test_random_frames_never_crash_and_never_pass_unchecked(bus, frame_id, data):
    try:
        _name, counter, values = bus.decode(frame_id, data)
    except FrameError as exc:
        assert exc.kind in ("unknown_id", "wrong_dlc", "bad_checksum", "undecodable")
        return
    # a random frame only gets through with a valid checksum, and then with finite, in-range values
    assert data[7] == crc8(frame_id, data) and 0 <= counter < 16
    assert all(np.isfinite(v) for v in values.values())


def _log_sample_run(config, path, seconds=12.0, injections=(), corrupt_every=0):
    """Write the plant's sensors as frames to a python-can log, as a machine recording would."""
    bus = MachineBus(config)
    writer = can.Logger(str(path))
    actuator, joint = config.first.name, config.first.joint
    k_total = 0
    try:
        for times, _, samples in run_blocks(config, Scenario(seconds, injections, seed=4)):
            for k in range(len(times)):
                for i, (frame_id, data) in enumerate(bus.encode_cycle(sample_values(samples, k, {actuator: joint}), k_total % 16)):
                    if corrupt_every and (k_total * 4 + i) % corrupt_every == 0:
                        data = bytes([data[0] ^ 0xFF]) + data[1:]
                    writer.on_message_received(can.Message(timestamp=1.7e9 + times[k] + i * 1e-5, arbitration_id=frame_id,
                                                           data=data, is_extended_id=False))
                k_total += 1
    finally:
        writer.stop()


@pytest.mark.parametrize("suffix", [".log", ".asc", ".blf"])
def test_logs_convert_to_bags_that_the_fdi_reads(sam_config, tmp_path, suffix):
    log = tmp_path / f"machine{suffix}"
    _log_sample_run(sam_config, log, seconds=3.0, corrupt_every=97)
    report = convert_log(log, sam_config, tmp_path / "bag")
    assert report.rejected["bad_checksum"] == pytest.approx(3000 * 4 / 97, abs=2)
    assert report.cycles == 3000 - report.incomplete_cycles and report.incomplete_cycles > 0
    data = read_bag(tmp_path / "bag")
    assert len(data.stamps_ns) == report.cycles and not data.errors
    assert np.all(np.diff(data.stamps_ns) > 0)
    assert np.all((data.pressure_a["boom"] > 0) & (data.pressure_a["boom"] < 2.5e7))


def test_a_leak_recorded_on_the_bus_is_found_in_the_converted_bag(sam_config, tmp_path):
    from hydro_ros.fdi.offline import analyse_bag

    log = tmp_path / "leak.blf"
    _log_sample_run(sam_config, log, seconds=16.0, injections=[Injection("external_leakage_a", 2.0, 8.0)])
    convert_log(log, sam_config, tmp_path / "bag")
    run = analyse_bag(tmp_path / "bag", sam_config)
    assert run.to_json()["actuators"]["boom"]["fault"] == "external_leakage_a"
    assert all(alarm.time_s > 8.0 for alarm in run.alarms)


def test_unreadable_logs_fail_clearly(sam_config, tmp_path):
    with pytest.raises(ValueError, match="no such file"):
        convert_log(tmp_path / "nope.log", sam_config, tmp_path / "bag")
    bad = tmp_path / "x.trc"
    bad.write_text("")
    with pytest.raises(ValueError, match="unsupported format"):
        convert_log(bad, sam_config, tmp_path / "bag")
    garbage = tmp_path / "garbage.log"
    garbage.write_text("this is not candump\n")
    with pytest.raises(ValueError, match=r"garbage.log"):
        convert_log(garbage, sam_config, tmp_path / "bag")


def test_mobile_machine_frames_carry_pilot_and_compensator_pressures(tmp_path):
    mobile = load_machine_config(REPO / "config" / "sam_mobile.yaml")
    log = tmp_path / "mobile.log"
    _log_sample_run(mobile, log, seconds=1.0)
    convert_log(log, mobile, tmp_path / "bag")
    data = read_bag(tmp_path / "bag")
    assert "boom" in data.pilot_pressure_1 and np.nanmax(data.compensator_pressure["boom"]) > 1e6


def test_the_crane_cylinders_frames_carry_every_cylinder_in_its_slot(k70m):
    """The K70M's three monitored cylinders in slots 2-4 of the four-slot DBC: one cycle carries every cylinder's joint,
    chamber, pilot and compensator pressures, and decodes back to them within the signals' resolution."""
    from hydro_ros.sim.arm_cylinders import ArmRun, simulate_arm

    machine = load_machine_config(REPO / "config" / "k70m.yaml")
    samples = simulate_arm(machine, ArmRun(0.2, seed=1))
    bus = MachineBus(machine)
    assert sorted(slot.number for slot in bus.slots) == [2, 3, 4] and len(bus.expected) == 10
    actuators = {a.name: a.joint for a in machine.actuators}
    assembler = CycleAssembler(bus.expected, bus.clock())
    for k in range(len(samples.times)):
        cycles = []
        for frame_id, data in bus.encode_cycle(sample_values(samples, k, actuators), k % 16):
            cycles += assembler.add(*bus.decode(frame_id, data), k)
        assert len(cycles) == 1 and cycles[0].complete(bus.expected)
        values = cycle_values(bus, cycles[0])
        for i, actuator in enumerate(actuators):
            assert values["pressure_a"][actuator] == pytest.approx(samples.pressure_a[k, i], abs=250)
            assert values["pilot_pressure_2"][actuator] == pytest.approx(samples.pilot_pressure_2[k, i], abs=50)
            assert values["compensator_pressure"][actuator] == pytest.approx(samples.compensator_pressure[k, i], abs=250)
            assert values["joint_position"][actuators[actuator]] == pytest.approx(samples.joint_position[k, i], abs=1e-7)


def test_a_crane_log_converts_to_a_bag_of_every_cylinder(tmp_path):
    """A K70M recording on the bus (three cylinders in slots 2-4) becomes one contract bag with every cylinder, as
    `hydro-ros sim` writes it: the samples within the signals' resolution, a corrupt frame's cycle left out."""
    from hydro_ros.bags.align import SampleLayout
    from hydro_ros.sim.arm_cylinders import ArmRun, simulate_arm

    machine = load_machine_config(REPO / "config" / "k70m.yaml")
    samples = simulate_arm(machine, ArmRun(1.0, seed=2))
    bus = MachineBus(machine)
    actuators = {a.name: a.joint for a in machine.actuators}
    log = tmp_path / "crane.blf"
    writer = can.Logger(str(log))
    try:
        for k in range(len(samples.times)):
            for i, (frame_id, data) in enumerate(bus.encode_cycle(sample_values(samples, k, actuators), k % 16)):
                if k == 500 and i == 3:
                    data = bytes([data[0] ^ 0xFF]) + data[1:]
                writer.on_message_received(can.Message(timestamp=1.7e9 + samples.times[k] + i * 1e-5, arbitration_id=frame_id,
                                                       data=data, is_extended_id=False))
    finally:
        writer.stop()
    report = convert_log(log, machine, tmp_path / "bag")
    assert report.rejected["bad_checksum"] == 1 and report.incomplete_cycles == 1 and report.cycles == len(samples.times) - 1
    data = read_bag(tmp_path / "bag")
    layout = SampleLayout(machine.actuator_names, list(actuators.values()), mobile=True)
    read = data.samples(layout)
    kept = np.delete(np.arange(len(samples.times)), 500)
    assert read.pressure_a.shape == (len(kept), 3) and data.complete
    assert np.allclose(read.pressure_b, samples.pressure_b[kept], atol=250)
    assert np.allclose(read.compensator_pressure, samples.compensator_pressure[kept], atol=250)
    assert np.allclose(read.joint_position, samples.joint_position[kept], atol=1e-6)
    # stamped on the bus clock from its lock (the first block: arrival times) on, the lost cycle keeping its slot
    assert np.allclose(np.diff(read.times)[BLOCK_CYCLES:], np.diff(samples.times[kept])[BLOCK_CYCLES:], atol=1e-6)


def test_a_garbage_frame_with_a_valid_checksum_is_caught_by_its_rate_and_a_forward_jump_is_reported(sam_config, tmp_path):
    """A CYL1_PRESSURE frame of one cycle carries 21.4 MPa (checksum valid, inside the transmitters' range) where its
    neighbours read ~9: no cylinder changes 12 MPa in 1 ms, so the sample is rejected as an implausible change; a log
    whose second half is stamped an hour later reports the forward jump as it reports a backward one."""
    bus = MachineBus(sam_config)
    actuator, joint = sam_config.first.name, sam_config.first.joint
    log = tmp_path / "garbage.log"
    writer = can.Logger(str(log))
    pressure_id = bus.db.get_message_by_name("CYL1_PRESSURE").frame_id
    k_total = 0
    try:
        for times, _, samples in run_blocks(sam_config, Scenario(2.0, (), seed=4)):
            for k in range(len(times)):
                sample = sample_values(samples, k, {actuator: joint})
                frames = bus.encode_cycle(sample, k_total % 16)
                if k_total == 700:
                    garbage = dict(sample, pressure_a={actuator: 21.37e6})
                    frames = [f if f[0] != pressure_id else next(g for g in bus.encode_cycle(garbage, k_total % 16) if g[0] == pressure_id)
                              for f in frames]
                shift = 3600.0 if k_total >= 1000 else 0.0
                for i, (frame_id, data) in enumerate(frames):
                    writer.on_message_received(can.Message(timestamp=1.7e9 + shift + times[k] + i * 1e-5, arbitration_id=frame_id,
                                                           data=data, is_extended_id=False))
                k_total += 1
    finally:
        writer.stop()
    report = convert_log(log, sam_config, tmp_path / "bag").to_json()
    assert report["rejected_samples"]["implausible_change"] == 1, report
    assert report["forward_time_jumps"] == 1 and report["samples"] == 1999
    data = read_bag(tmp_path / "bag")
    assert np.max(np.abs(np.diff(data.pressure_a["boom"]))) < 3e6
