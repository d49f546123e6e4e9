"""Contract bags: readable by rosbags and mcap, CDR identical to rosbags', damage tolerated."""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader

from hydro_ros.bags.align import ContractAligner, SampleLayout
from hydro_ros.bags.cdr import (
    CdrError,
    decode_fluid_pressure,
    decode_joint_state,
    decode_sample_block,
    encode_fluid_pressure,
    encode_joint_state,
    encode_joint_trajectory,
    encode_sample_block,
)
from hydro_ros.bags.reader import BagError, mcap_files, read_bag
from hydro_ros.bags.writer import TYPESTORE, BagExistsError, ContractBagWriter
from hydro_ros.contract import topics
from hydro_ros.contract.names import Injection
from hydro_ros.sim.scenario import Scenario, run_blocks


@pytest.fixture(scope="module")
def leak_bag(tmp_path_factory, sam_config) -> Path:
    path = tmp_path_factory.mktemp("bags") / "leak"
    scenario = Scenario(6.0, [Injection("external_leakage_a", 1.0, 2.0), Injection("pressure_sensor_bias_b", 3e5, 4.0)], seed=3)
    with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
        writer.set_truth(scenario.truth(sam_config))
        for _, _, block in run_blocks(sam_config, scenario):
            writer.write_block("boom", block)
    return path


def test_cdr_matches_rosbags_serialiser():
    fp = TYPESTORE.types["sensor_msgs/msg/FluidPressure"]
    header = TYPESTORE.types["std_msgs/msg/Header"]
    stamp = TYPESTORE.types["builtin_interfaces/msg/Time"]
    msg = fp(header=header(stamp=stamp(sec=12, nanosec=345), frame_id="boomy"), fluid_pressure=8.5e6, variance=1e10)
    assert TYPESTORE.serialize_cdr(msg, fp.__msgtype__).tobytes() == encode_fluid_pressure(12_000_000_345, "boomy", 8.5e6, 1e10)
    js = TYPESTORE.types["sensor_msgs/msg/JointState"]
    msg = js(header=header(stamp=stamp(sec=1, nanosec=2), frame_id=""), name=["a", "joint_b"],
             position=np.array([1.5, -2.0]), velocity=np.array([0.25, 0.5]), effort=np.array([], dtype=float))
    ours = encode_joint_state(1_000_000_002, "", ["a", "joint_b"], [1.5, -2.0], [0.25, 0.5], [])
    assert TYPESTORE.serialize_cdr(msg, js.__msgtype__).tobytes() == ours
    assert decode_joint_state(ours) == (1_000_000_002, ["a", "joint_b"], (1.5, -2.0), (0.25, 0.5))
    assert decode_fluid_pressure(encode_fluid_pressure(5, "x", 1.0, 2.0)) == (5, 1.0, 2.0)
    jt, point = TYPESTORE.types["trajectory_msgs/msg/JointTrajectory"], TYPESTORE.types["trajectory_msgs/msg/JointTrajectoryPoint"]
    duration = TYPESTORE.types["builtin_interfaces/msg/Duration"]
    rng = np.random.default_rng(1)
    rows = [rng.normal(size=(3, 4)) for _ in range(3)]  # positions, velocities, accelerations of 3 points
    times_ns = [0, 50_000_000, 1_500_000_007]
    msg = jt(header=header(stamp=stamp(sec=3, nanosec=4), frame_id="base"), joint_names=["base", "lift", "tilt", "ext"],
             points=[point(positions=rows[0][k], velocities=rows[1][k], accelerations=rows[2][k], effort=np.array([], dtype=float),
                           time_from_start=duration(sec=t // 1_000_000_000, nanosec=t % 1_000_000_000)) for k, t in enumerate(times_ns)])
    ours = encode_joint_trajectory(3_000_000_004, "base", ["base", "lift", "tilt", "ext"], times_ns, *rows)
    assert TYPESTORE.serialize_cdr(msg, jt.__msgtype__).tobytes() == ours


def test_a_sample_block_is_a_standard_point_cloud_and_the_aligner_takes_its_columns():
    pc, field = TYPESTORE.types["sensor_msgs/msg/PointCloud2"], TYPESTORE.types["sensor_msgs/msg/PointField"]
    header, stamp = TYPESTORE.types["std_msgs/msg/Header"], TYPESTORE.types["builtin_interfaces/msg/Time"]
    layout = SampleLayout(["lift", "tilt"], ["lift", "tilt"], mobile=True)
    stamps = 7_000_000_001 + 1_000_000 * np.arange(10)
    rows = np.random.default_rng(2).normal(size=(10, len(layout.columns)))
    rows[3, 4] = np.nan  # a sensor's NaN travels as the gap it is
    ours = encode_sample_block(int(stamps[0]), "k70m", layout.field_names, stamps, rows)
    table = np.column_stack([(stamps - stamps[0]) * 1e-9, rows]).astype("<f8")
    names = ["t", *layout.field_names]
    msg = pc(header=header(stamp=stamp(sec=7, nanosec=1), frame_id="k70m"), height=1, width=10,
             fields=[field(name=n, offset=8 * k, datatype=8, count=1) for k, n in enumerate(names)], is_bigendian=False,
             point_step=8 * len(names), row_step=80 * len(names), data=np.frombuffer(table.tobytes(), dtype=np.uint8), is_dense=False)
    assert TYPESTORE.serialize_cdr(msg, pc.__msgtype__).tobytes() == ours
    fields, decoded_stamps, decoded = decode_sample_block(ours)
    assert fields == layout.field_names and np.array_equal(decoded_stamps, stamps)
    assert np.array_equal(decoded, rows, equal_nan=True)
    # the aligner takes a block in any field order, extra fields ignored, as the rows of its layout
    aligner = ContractAligner(layout, sync_window_ns=0)
    order = np.random.default_rng(3).permutation(len(layout.columns))
    aligner.put_block(encode_sample_block(int(stamps[0]), "", [*np.array(layout.field_names)[order], "base/joint_position"], stamps,
                                          np.column_stack([rows[:, order], np.zeros(10)])))
    taken_stamps, taken = aligner.take(final=True)
    assert np.array_equal(taken_stamps, stamps) and np.array_equal(taken, rows, equal_nan=True)
    with pytest.raises(CdrError, match="sample block lacks tilt/pilot_pressure_2"):
        missing = [f for f in layout.field_names if f != "tilt/pilot_pressure_2"]
        aligner.put_block(encode_sample_block(int(stamps[-1]) + 1, "", missing, stamps + 10**7, rows[:, : len(missing)]))
    wrong = TYPESTORE.serialize_cdr(pc(header=msg.header, height=1, width=10, fields=[field(name="t", offset=0, datatype=7, count=1)],
                                       is_bigendian=False, point_step=4, row_step=40, data=np.zeros(40, dtype=np.uint8), is_dense=True),
                                    pc.__msgtype__).tobytes()
    with pytest.raises(CdrError, match="field 't': datatype 7"):
        decode_sample_block(wrong)


def test_bag_is_readable_by_rosbags_with_contract_types(leak_bag, sam_config):
    with AnyReader([leak_bag]) as reader:
        types = {c.topic: c.msgtype for c in reader.connections}
        assert types == topics.sensor_topics(["boom"])
        first = {}
        for connection, log_time, raw in reader.messages():
            msg = reader.deserialize(raw, connection.msgtype)
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert stamp == log_time  # contract: bag log time = header.stamp
            first.setdefault(connection.topic, msg)
        assert list(first[topics.JOINT_STATES].name) == ["boom_joint"]
        assert list(first[topics.VALVE_COMMANDS].name) == ["boom"]
        assert 1e6 < first["/hydraulics/boom/pressure_a"].fluid_pressure < 25e6


def test_bag_is_readable_by_mcap_reader(leak_bag):
    with mcap_files(leak_bag)[0].open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert {s.name for s in summary.schemas.values()} == {topics.JOINT_STATE_TYPE, topics.FLUID_PRESSURE_TYPE}
        assert summary.statistics.message_count == 5 * 6000
        for channel in summary.channels.values():  # what ros2 bag play needs to offer the recorded QoS
            assert "reliability: reliable" in channel.metadata["offered_qos_profiles"], channel.topic


def test_reader_aligns_samples_and_keeps_truth(leak_bag):
    data = read_bag(leak_bag)
    assert data.complete and data.message_count == 30000
    assert len(data.times) == 6000 and data.times[1] == pytest.approx(0.001)
    for series in (data.pressure_a["boom"], data.pressure_b["boom"], data.supply_pressure, data.valve_command["boom"],
                   data.joint_position["boom_joint"]):
        assert np.all(np.isfinite(series))
    assert data.truth["faults"][0]["name"] == "external_leakage_a"
    # the supply transducer carries no injected bias: its mean is the configured supply pressure
    assert np.mean(data.supply_pressure) == pytest.approx(10e6, rel=2e-3)


def test_truncated_bag_returns_what_was_readable(leak_bag, tmp_path):
    damaged = tmp_path / "damaged"
    shutil.copytree(leak_bag, damaged)
    file = mcap_files(damaged)[0]
    raw = file.read_bytes()
    file.write_bytes(raw[: len(raw) // 2])
    data = read_bag(damaged)
    assert not data.complete
    assert "damaged after" in data.errors[0] and str(file) in data.errors[0]
    assert 0 < data.message_count < 30000
    assert len(data.times) > 500


def test_garbage_and_missing_bags_fail_clearly(tmp_path):
    with pytest.raises(BagError, match="no such file"):
        read_bag(tmp_path / "nope")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BagError, match=r"no .mcap file"):
        read_bag(tmp_path / "empty")
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "junk.mcap").write_bytes(b"this is not an mcap file at all" * 10)
    with pytest.raises(BagError, match=r"junk.mcap"):
        read_bag(junk)


def test_writer_refuses_to_overwrite(leak_bag):
    with pytest.raises(BagExistsError, match="already exists"):
        ContractBagWriter(leak_bag, actuators={"boom": "boom_joint"}, pressure_variance=1.0)


def _same_where_shared(data, full) -> bool:
    shared = np.isin(full.stamps_ns, data.stamps_ns)
    return np.array_equal(data.pressure_a["boom"], full.pressure_a["boom"][shared])


def test_flipped_byte_in_a_chunk_is_reported_and_every_intact_chunk_kept(leak_bag, tmp_path):
    source = mcap_files(leak_bag)[0].read_bytes()
    damaged = bytearray(source)
    damaged[len(source) // 2] ^= 0xFF  # inside a compressed chunk in the middle of the file
    target = tmp_path / "flipped.mcap"
    target.write_bytes(bytes(damaged))
    full = read_bag(leak_bag)
    data = read_bag(target)
    assert any("damaged chunk" in e for e in data.errors)
    assert 0 < len(data.stamps_ns) < len(full.stamps_ns)
    assert data.stamps_ns[-1] == full.stamps_ns[-1]  # the chunks after the damaged one are read too
    assert _same_where_shared(data, full)


def test_damaged_record_header_resumes_at_the_next_intact_chunk(leak_bag, tmp_path):
    source = mcap_files(leak_bag)[0].read_bytes()
    chunks, position = [], 8
    while source[position] != 0x02:  # walk the records to the footer; note where each chunk starts
        if source[position] == 0x06:
            chunks.append(position)
        position += 9 + int.from_bytes(source[position + 1 : position + 9], "little")
    assert len(chunks) >= 3
    chunk = chunks[1]
    damaged = bytearray(source)
    damaged[chunk + 8] = 0x7F  # the length's top byte: the header now claims a record larger than the file
    target = tmp_path / "header.mcap"
    target.write_bytes(bytes(damaged))
    full = read_bag(leak_bag)
    data = read_bag(target)
    assert any("skipped to the next intact chunk" in e for e in data.errors)
    assert len(data.stamps_ns) < len(full.stamps_ns) and data.stamps_ns[-1] == full.stamps_ns[-1]
    assert _same_where_shared(data, full)


def test_a_split_bag_is_read_whole_in_its_listed_order(leak_bag, tmp_path):
    """A recording split over two files (rosbag2's max_bag_size) reads like the single file it came from."""
    import yaml
    from mcap.writer import Writer

    split = tmp_path / "split"
    split.mkdir()
    with mcap_files(leak_bag)[0].open("rb") as stream:
        reader = make_reader(stream)
        messages = [(schema, channel, message) for schema, channel, message in reader.iter_messages()]
    cut = len(messages) // 2
    names = ["split_9.mcap", "split_10.mcap"]  # listed order, not name order
    for name, part in zip(names, (messages[:cut], messages[cut:])):
        with (split / name).open("wb") as out:
            writer = Writer(out)
            writer.start("ros2", "test")
            ids: dict[int, int] = {}
            for schema, channel, message in part:
                if channel.id not in ids:
                    schema_id = writer.register_schema(schema.name, schema.encoding, schema.data)
                    ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding, schema_id)
                writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
            writer.finish()
    meta = yaml.safe_load((leak_bag / "metadata.yaml").read_text())
    meta["rosbag2_bagfile_information"]["relative_file_paths"] = names
    (split / "metadata.yaml").write_text(yaml.safe_dump(meta))
    assert mcap_files(split) == [split / name for name in names]
    full, data = read_bag(leak_bag), read_bag(split)
    assert data.complete and data.message_count == full.message_count
    assert np.array_equal(data.stamps_ns, full.stamps_ns) and _same_where_shared(data, full)
    (split / names[1]).unlink()
    half = read_bag(split)
    assert any("listed in metadata.yaml but missing" in e for e in half.errors)
    assert 0 < len(half.stamps_ns) < len(full.stamps_ns)


def test_joint_states_with_changing_names_are_decoded_per_message(tmp_path):
    from mcap.writer import Writer

    from hydro_ros.bags.cdr import encode_joint_state
    from hydro_ros.bags.reader import read_bag
    from hydro_ros.bags.writer import TYPESTORE  # noqa: F401 - the schema text comes from the same store

    path = tmp_path / "names.mcap"
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start("ros2", "test")
        schema = writer.register_schema("sensor_msgs/msg/JointState", "ros2msg", b"")
        channel = writer.register_channel("/joint_states", "cdr", schema)
        for k in range(10):
            names, pos = (["a", "b"], [1.0 * k, 2.0 * k]) if k % 3 else (["b"], [-1.0])
            writer.add_message(channel, k, encode_joint_state(k, "", names, pos, [], []), k)
        writer.finish()
    data = read_bag(path)
    assert list(data.stamps_ns) == list(range(10))
    assert np.isnan(data.joint_position["a"][0]) and data.joint_position["a"][4] == 4.0
    assert data.joint_position["b"][3] == -1.0 and data.joint_position["b"][5] == 10.0


def test_split_by_size_is_read_whole_and_a_killed_recording_keeps_its_closed_parts(tmp_path, sam_config):
    from hydro_ros.bags.writer import SENSOR_QOS, BagWriter

    def fill(writer: BagWriter, seconds: float) -> None:
        handle = writer.add_topic(topics.pressure_a("boom"), topics.FLUID_PRESSURE_TYPE, [SENSOR_QOS])
        for k in range(int(seconds * 1000)):
            stamp = k * 1_000_000
            writer.write(handle, stamp, encode_fluid_pressure(stamp, "boom", 1e6 + k, 0.0))

    whole = BagWriter(tmp_path / "sized", split_size_bytes=100_000)
    with whole:
        fill(whole, 12.0)
    assert len(whole.files) >= 3
    assert [p.name for p in mcap_files(tmp_path / "sized")] == whole.files
    from hydro_ros.bags.reader import bag_info

    info = bag_info(tmp_path / "sized")
    assert info["errors"] == [] and info["messages"] == 12000

    killed = BagWriter(tmp_path / "killed", split_duration_s=4.0)
    killed.__enter__()
    fill(killed, 10.0)  # two closed parts, the third still open when the process dies
    info = bag_info(tmp_path / "killed")
    assert len(killed.files) == 2 and len(info["files"]) == 3
    assert 8000 <= info["messages"] < 10000  # the open part's unflushed chunk is all that is lost
    assert any("killed_2.mcap" in error for error in info["errors"]), info["errors"]  # the open part is said to be cut


def test_bag_info_stats_gives_each_field_in_si_units(tmp_path, sam_config, capsys):
    """The samples a simulation wrote, their extremes read back per topic and field by `bag info --stats`."""
    from hydro_ros.cli import main as cli

    path = tmp_path / "stats"
    blocks = [block for _, _, block in run_blocks(sam_config, Scenario(3.0, [], seed=2))]
    with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
        for block in blocks:
            writer.write_block("boom", block)
    pressure_b = np.concatenate([block.as_columns().pressure_b[:, 0] for block in blocks])
    angle = np.concatenate([block.as_columns().joint_position[:, 0] for block in blocks])
    stats = read_bag(path).stats()
    row = stats["/hydraulics/boom/pressure_b fluid_pressure"]
    assert row["unit"] == "Pa" and row["samples"] == len(pressure_b)
    assert (row["min"], row["max"]) == pytest.approx((pressure_b.min(), pressure_b.max()))
    assert stats["/joint_states name 'boom_joint' position"]["max"] == pytest.approx(angle.max())
    assert cli(["bag", "info", str(path), "--stats"]) == 0
    assert f"/hydraulics/boom/pressure_b fluid_pressure [Pa]: min {pressure_b.min():.6g}" in capsys.readouterr().out
