"""Damaged and foreign bags: every reader says what it skipped in one line and goes on with what is intact, or refuses
by name where going on could mislead; never a traceback."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.writer import Writer
from sensor_msgs.msg import JointState

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.nodes.common import SENSOR_QOS
from test.conftest import REPO, SAM_CONFIG
from test.ros_graph import probe_node, spin_until

CLI = [sys.executable, "-m", "hydro_ros.cli"]
REFUSAL_BOUND_S = 10.0  # [s] a damaged config refused: a hang or an expansion would take far longer


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory) -> Path:
    bag = tmp_path_factory.mktemp("damaged") / "short"
    made = subprocess.run([*CLI, "sim", "--config", str(SAM_CONFIG), "--duration", "3", "--out", str(bag), "--quiet"],
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    return bag


def _metadata(bag: Path) -> dict:
    return yaml.safe_load((bag / "metadata.yaml").read_text())


def test_discrepancy_refuses_a_bag_with_a_missing_part_unless_told_to_go_on(short_bag, tmp_path):
    bag = tmp_path / "split"
    shutil.copytree(short_bag, bag)
    meta = _metadata(bag)
    meta["rosbag2_bagfile_information"]["relative_file_paths"].append("split_1.mcap")  # a part that never arrived
    (bag / "metadata.yaml").write_text(yaml.safe_dump(meta))
    refused = subprocess.run([*CLI, "discrepancy", "--bag", str(bag), "--config", str(SAM_CONFIG), "--out", str(tmp_path / "out"),
                              "--quiet"], capture_output=True, text=True, timeout=300)
    assert refused.returncode == 1 and "Traceback" not in refused.stderr
    assert len(refused.stderr.strip().splitlines()) == 1 and "split_1.mcap" in refused.stderr and "--partial-ok" in refused.stderr


def _with_foreign_topic(source: Path, target: Path) -> Path:
    """A copy of a bag with one more topic whose message package no machine here has (rosbag2's own test_msgs)."""
    target.mkdir()
    mcap = next(source.glob("*.mcap"))
    with mcap.open("rb") as stream:
        messages = list(make_reader(stream).iter_messages())
    with (target / mcap.name).open("wb") as out:
        writer = Writer(out)
        writer.start("ros2", "test")
        ids: dict[int, int] = {}
        foreign = writer.register_channel("/test_topic", "cdr", writer.register_schema("test_msgs/msg/BasicTypes", "ros2msg", b"bool bool_value"))
        for schema, channel, message in messages:
            if channel.id not in ids:
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                          writer.register_schema(schema.name, schema.encoding, schema.data))
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
            writer.add_message(foreign, message.log_time, b"\x00\x01\x00\x00\x01", message.publish_time)
        writer.finish()
    meta = _metadata(source)
    meta["rosbag2_bagfile_information"]["topics_with_message_count"].append(
        {"topic_metadata": {"name": "/test_topic", "type": "test_msgs/msg/BasicTypes", "serialization_format": "cdr"}, "message_count": 1})
    (target / "metadata.yaml").write_text(yaml.safe_dump(meta))
    return target


def test_replay_skips_a_topic_whose_type_is_not_installed_and_plays_the_rest(short_bag, tmp_path, ros_domain):
    bag = _with_foreign_topic(short_bag, tmp_path / "foreign")
    joint_states: list[JointState] = []
    with probe_node("probe") as node:
        node.create_subscription(JointState, "/joint_states", joint_states.append, SENSOR_QOS)
        player = subprocess.Popen([*CLI, "bag", "replay", str(bag), "--rate", "0.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        assert spin_until(node, lambda: len(joint_states) > 100, 30), "nothing played"
        _, stderr = player.communicate(timeout=60)
    assert player.returncode == 0, stderr
    assert "Traceback" not in stderr and stderr.count("test_msgs/msg/BasicTypes") == 1 and "skipped" in stderr


def test_replay_of_a_bag_whose_metadata_is_not_a_mapping_says_so_and_fails(short_bag, tmp_path, ros_domain):
    bag = tmp_path / "listmeta"
    shutil.copytree(short_bag, bag)
    (bag / "metadata.yaml").write_text("- just\n- a list\n")
    played = subprocess.run([*CLI, "bag", "replay", str(bag), "--rate", "20"], capture_output=True, text=True, timeout=120)
    assert played.returncode == 1 and "Traceback" not in played.stderr
    assert "not a rosbag2 metadata mapping" in played.stderr


def test_a_damaged_first_chunk_costs_only_its_own_messages(short_bag, tmp_path):
    """The first chunk holds the channel and schema records; the file's summary repeats them. A flipped byte there
    (its CRC fails) loses that chunk's messages and no others: the rest of the bag is read and monitored."""
    from mcap.reader import make_reader

    from hydro_ros.bags.reader import read_bag

    bag = tmp_path / "flipped"
    shutil.copytree(short_bag, bag)
    mcap = next(bag.glob("*.mcap"))
    with mcap.open("rb") as stream:
        chunks = [index for index in make_reader(stream).get_summary().chunk_indexes]
    assert len(chunks) >= 2
    data = bytearray(mcap.read_bytes())
    data[chunks[0].chunk_start_offset + 200] ^= 0xFF
    mcap.write_bytes(bytes(data))
    whole, damaged = read_bag(short_bag), read_bag(bag)
    assert damaged.errors and "damaged chunk" in damaged.errors[0]
    assert 0 < len(damaged.stamps_ns) < len(whole.stamps_ns) and damaged.stamps_ns[-1] == whole.stamps_ns[-1]
    monitored = subprocess.run([*CLI, "fdi", "run", "--bag", str(bag), "--config", str(SAM_CONFIG), "--out", str(tmp_path / "fdi.json"), "--quiet"],
                               capture_output=True, text=True, timeout=120)
    assert monitored.returncode == 0 and "Traceback" not in monitored.stderr, monitored.stderr
    assert "damaged chunk" in monitored.stderr


def test_a_config_saying_a_key_twice_is_refused_naming_it(tmp_path):
    """PyYAML keeps the last of two equal keys: a value the user wrote would be lost unsaid."""
    text = (REPO / "config" / "boom_arm.yaml").read_text().replace("          along: 0.9 ", "          along: 0.9\n          along: 0.5 ", 1)
    twice = tmp_path / "twice.yaml"
    twice.write_text(text)
    with pytest.raises(ConfigError, match=r"not valid YAML \(duplicate key 'along' \(line \d+\)\)"):
        load_machine_config(twice)
    assert load_machine_config(REPO / "config" / "k70m.yaml").planned  # YAML merge keys (<<) are not duplicates


@pytest.mark.parametrize("case", ["binary", "not_utf8", "folder", "oversized", "alias_bomb"])
def test_a_config_that_cannot_be_one_is_refused_in_one_line_at_once(tmp_path, case):
    """Every command and node reads configs through contract.config: a binary, a Latin-1 file, a folder, 10 MB of YAML and
    a 'billion laughs' of aliases are refused in one line naming the file, in well under a second."""
    import time

    path = tmp_path / "machine.yaml"
    if case == "binary":
        path.write_bytes(bytes(range(256)) * 4)
    elif case == "not_utf8":
        path.write_bytes("machine: säge\n".encode("latin-1"))
    elif case == "folder":
        path.mkdir()
    elif case == "oversized":
        path.write_text("machine: big\nnotes:\n" + "".join(f"  - line {k} of a very long list of notes\n" for k in range(300_000)))
    else:
        lines = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
        lines += [f"a{k}: &a{k} [{', '.join([f'*a{k - 1}'] * 10)}]" for k in range(1, 9)]
        path.write_text("machine: bomb\n" + "\n".join(lines) + "\n")
    started = time.monotonic()
    with pytest.raises(ConfigError) as refused:
        load_machine_config(path)
    message = str(refused.value)
    # refused before it is expanded (minutes and gigabytes), also beside the live tests: a bound, not a speed
    assert str(path) in message and "\n" not in message and time.monotonic() - started < REFUSAL_BOUND_S
    expected = {"binary": "not UTF-8", "not_utf8": "not UTF-8", "folder": "is a folder", "oversized": "MB, more than",
                "alias_bomb": "aliases expand"}[case]
    assert expected in message, message


def test_a_damaged_schema_record_in_the_first_chunk_costs_nothing_the_summary_repeats(short_bag, tmp_path):
    """Writers that put schemas and channels inside uncompressed chunks without CRCs (and in the summary again): a byte
    flipped in the first chunk's schema name stopped the whole bag at 0 messages ('utf-8' codec can't decode)."""
    from mcap.writer import CompressionType

    from hydro_ros.bags.reader import read_bag

    source = next(short_bag.glob("*.mcap"))
    target = tmp_path / "flipped"
    target.mkdir()
    with source.open("rb") as stream, (target / "flipped.mcap").open("wb") as out:
        writer = Writer(out, compression=CompressionType.NONE, enable_crcs=False)
        writer.start("ros2", "test")
        ids: dict[int, int] = {}
        for schema, channel, message in make_reader(stream).iter_messages():
            if channel.id not in ids:
                ids[channel.id] = writer.register_channel(channel.topic, channel.message_encoding,
                                                          writer.register_schema(schema.name, schema.encoding, schema.data))
            writer.add_message(ids[channel.id], message.log_time, message.data, message.publish_time)
        writer.finish()
    meta = _metadata(short_bag)
    meta["rosbag2_bagfile_information"]["relative_file_paths"] = ["flipped.mcap"]
    (target / "metadata.yaml").write_text(yaml.safe_dump(meta))
    data = bytearray((target / "flipped.mcap").read_bytes())
    first_schema = data.find(b"sensor_msgs/msg/")
    assert first_schema < data.rfind(b"sensor_msgs/msg/")  # the chunk's copy, not the summary's
    data[first_schema + 3] = 0xFF  # not UTF-8 any more
    (target / "flipped.mcap").write_bytes(bytes(data))
    whole, damaged = read_bag(short_bag), read_bag(target)
    assert damaged.message_count == whole.message_count and damaged.topic_counts == whole.topic_counts
    done = subprocess.run([*CLI, "fdi", "run", "--bag", str(target), "--config", str(SAM_CONFIG), "--out", str(tmp_path / "fdi.json"),
                           "--quiet"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


FUZZ_EXAMPLES = os.environ.get("FUZZ_EXAMPLES")  # more, and freshly drawn, when set (e.g. 2500); else 60 of a fixed draw
_SERIES = ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command")


@pytest.fixture(scope="module")
def intact(short_bag):
    from hydro_ros.bags.reader import read_bag

    return read_bag(short_bag)


@settings(max_examples=int(FUZZ_EXAMPLES or 60), deadline=None, derandomize=not FUZZ_EXAMPLES,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_a_randomly_damaged_bag_loses_what_was_damaged_and_says_so_never_invents_a_sample(short_bag, intact, tmp_path, data):
    """Random damage to the bag's MCAP file (cut short, bytes flipped, a run zeroed, a piece repeated): read_bag returns
    only samples the intact bag holds, each with the intact bag's values, and lists an error whenever it lost any; or it
    refuses the file in one line. Never another exception (FUZZ_EXAMPLES draws more)."""
    import tempfile

    from hydro_ros.bags.reader import read_bag
    from hydro_ros.contract.errors import InputError

    whole = intact
    mcap = next(short_bag.glob("*.mcap"))
    original = bytearray(mcap.read_bytes())
    size = len(original)
    kind = data.draw(st.sampled_from(("cut", "flip", "zero", "repeat")), label="damage")
    at = data.draw(st.integers(8, size - 1), label="offset")
    if kind == "cut":
        damaged = original[:at]
    elif kind == "flip":
        damaged = original.copy()
        for offset in data.draw(st.lists(st.integers(0, size - 1), min_size=1, max_size=8), label="flipped"):
            damaged[offset] ^= data.draw(st.integers(1, 255), label="mask")
    elif kind == "zero":
        length = data.draw(st.integers(1, 4096), label="length")
        damaged = original[:at] + bytes(min(length, size - at)) + original[at + length:]
    else:
        length = data.draw(st.integers(1, 4096), label="length")
        damaged = original[:at] + original[at:at + length] + original[at:]
    bag = Path(tempfile.mkdtemp(dir=tmp_path)) / "damaged"
    shutil.copytree(short_bag, bag)
    next(bag.glob("*.mcap")).write_bytes(bytes(damaged))
    try:
        read = read_bag(bag)
    except InputError as refused:
        assert "\n" not in str(refused).strip() and str(refused), refused
        return
    index = {stamp: k for k, stamp in enumerate(whole.stamps_ns)}
    assert all(stamp in index for stamp in read.stamps_ns), "a sample the intact bag does not hold"
    rows = np.array([index[stamp] for stamp in read.stamps_ns], dtype=int)
    for name in _SERIES:
        for actuator, series in getattr(read, name).items():
            theirs = getattr(whole, name)[actuator][rows]
            known = np.isfinite(series)
            assert np.array_equal(series[known], theirs[known]), (name, actuator, "a value the intact bag does not hold")
    if len(read.stamps_ns) < len(whole.stamps_ns) or any(np.isnan(s).sum() > np.isnan(getattr(whole, n)[a]).sum()
                                                         for n in _SERIES for a, s in getattr(read, n).items()):
        assert read.errors, "samples lost without a word"
