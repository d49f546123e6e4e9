"""Read a contract bag into aligned numpy arrays, fast and without ROS.

Reads the MCAP file sequentially (so a truncated or corrupt file yields everything before the
damage), decodes the fixed-layout types in compiled batches (hydro_ros.bags.mcap_scan), and aligns every topic on the sample stamps
of /joint_states with the aligner the live monitor uses (hydro_ros.bags.align). Damage is reported in ``BagData.errors`` and never raises past what was read.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hydro_ros.bags.align import PER_JOINT, Column, SampleLayout, place_at_keys
from hydro_ros.bags.cdr import CdrError, decode_joint_state, decode_sample_block
from hydro_ros.bags.mcap_scan import (
    McapDamage,
    McapScanner,
    MessageBatch,
    decode_fluid_pressures,
    decode_joint_states,
    same_bytes,
)
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.samples import Samples

# each quantity's SI unit as the contract carries it (a prismatic joint's position is in m, its rate in m/s)
UNITS_OF = {"joint_position": "rad or m", "joint_velocity": "rad/s or m/s", "pressure_a": "Pa", "pressure_b": "Pa",
            "pilot_pressure_1": "Pa", "pilot_pressure_2": "Pa", "compensator_pressure": "Pa", "supply_pressure": "Pa",
            "ls_pressure": "Pa", "valve_command": "fraction of full opening"}


class BagError(InputError):
    """The bag cannot be read at all (missing, not a bag, no contract topic)."""


@dataclass
class BagData:
    """Samples aligned on the /joint_states stamps; NaN where a topic had no sample."""

    path: Path
    stamps_ns: np.ndarray
    joint_position: dict[str, np.ndarray] = field(default_factory=dict)
    joint_velocity: dict[str, np.ndarray] = field(default_factory=dict)
    pressure_a: dict[str, np.ndarray] = field(default_factory=dict)
    pressure_b: dict[str, np.ndarray] = field(default_factory=dict)
    pilot_pressure_1: dict[str, np.ndarray] = field(default_factory=dict)
    pilot_pressure_2: dict[str, np.ndarray] = field(default_factory=dict)
    compensator_pressure: dict[str, np.ndarray] = field(default_factory=dict)
    ls_pressure: np.ndarray | None = None
    supply_pressure: np.ndarray | None = None
    valve_command: dict[str, np.ndarray] = field(default_factory=dict)
    truth: dict[str, Any] | None = None
    message_count: int = 0
    topic_counts: dict[str, int] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)

    @property
    def times(self) -> np.ndarray:
        """Seconds from the first sample (contract: JSON times are relative to it)."""
        if len(self.stamps_ns) == 0:
            return np.zeros(0)
        return (self.stamps_ns - self.stamps_ns[0]) * 1e-9

    @property
    def complete(self) -> bool:
        return not self.errors

    def stats(self) -> dict[str, dict[str, Any]]:
        """Per topic and field, the finite values' min / mean / max in SI units and their count: what checks a CAN map's
        units (a chamber pressure of 300 Pa was bar read as Pa; a joint at 90 rad was degrees read as rad)."""
        out: dict[str, dict[str, Any]] = {}
        for quantity, unit in UNITS_OF.items():
            series = getattr(self, quantity)
            for name, values in ({"": series} if isinstance(series, np.ndarray) else series or {}).items():
                finite = np.asarray(values, dtype=float)
                finite = finite[np.isfinite(finite)]
                field_name = {"joint_velocity": "velocity"}.get(quantity, "position" if quantity in PER_JOINT or quantity == "valve_command"
                                                                 else "fluid_pressure")
                out[f"{SampleLayout.source((quantity, name))} {field_name}"] = {
                    "unit": unit, "samples": int(len(finite)),
                    **({"min": float(finite.min()), "mean": float(finite.mean()), "max": float(finite.max())} if len(finite) else {})}
        return out

    def samples(self, layout: SampleLayout) -> Samples:
        """The bag's samples of a machine's actuators (times from the first sample); BagError names a missing topic."""
        rows = []
        for column in layout.columns:
            quantity, name = column
            source = getattr(self, quantity)
            values = source if quantity == "supply_pressure" else source.get(name)
            if values is None:
                raise BagError(f"bag {self.path}: no {SampleLayout.source(column)}")
            rows.append(values)
        return layout.samples(self.times, np.stack(rows, axis=1).reshape(len(self.stamps_ns), len(rows)))


def _natural(path: Path) -> list:
    # rosbag2 numbers split files name_0.mcap, name_1.mcap, ..., name_10.mcap: 10 comes after 9
    return [int(part) if part.isdigit() else part for part in re.split(r"(\d+)", path.name)]


def mcap_files(path: Path, errors: list[str] | None = None) -> list[Path]:
    """Every storage file of a bag, in recording order: a bag split over several files is read whole.

    The order is metadata.yaml's ``relative_file_paths`` where it lists them, else the files' numbering;
    a listed file that is missing is reported in ``errors``.
    """
    if path.is_file():
        return [path]
    if not path.is_dir():
        raise BagError(f"bag {path}: no such file or directory")
    # a part still in its own directory is what a recording killed mid-part left behind (bags/writer.py)
    present = sorted([*path.glob("*.mcap"), *path.glob("*/*.mcap")], key=_natural)
    if not present:
        raise BagError(f"bag {path}: no .mcap file in the directory (only MCAP storage is supported)")
    meta = _metadata(path)
    listed = [path / name for name in meta.get("relative_file_paths") or [] if str(name).endswith(".mcap")]
    if errors is not None:
        if (path / "metadata.yaml").exists() and not meta:
            errors.append(f"{path / 'metadata.yaml'}: not a rosbag2 metadata mapping; the .mcap files are read without it")
        errors += [f"{file}: listed in metadata.yaml but missing" for file in listed if not file.is_file()]
    ordered = [file for file in listed if file.is_file()]
    return ordered + [file for file in present if file not in ordered]


def _metadata(path: Path) -> dict[str, Any]:
    """The rosbag2_bagfile_information mapping of a bag directory, or {} where it cannot be read."""
    try:
        info = yaml.safe_load((path / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    except (OSError, yaml.YAMLError, KeyError, TypeError):
        return {}
    return info if isinstance(info, dict) else {}


def bag_topics(path: Path) -> dict[str, str]:
    """Topic -> message type as metadata.yaml lists them ({} for a bare file or unreadable metadata)."""
    topics_meta = _metadata(path).get("topics_with_message_count") or [] if path.is_dir() else []
    try:
        return {str(entry["topic_metadata"]["name"]): str(entry["topic_metadata"]["type"]) for entry in topics_meta}
    except (KeyError, TypeError):
        return {}


def bag_info(path: str | Path) -> dict[str, Any]:
    """What a bag holds, from its files themselves: per file and topic the messages and log-time span,
    the metadata's claims beside them, and every damage or disagreement found."""
    path = Path(path)
    errors: list[str] = []
    files = mcap_files(path, errors)
    listed = {name: int(count) for name, count in _listed_counts(path).items()}
    types = bag_topics(path)
    per_topic: dict[str, dict[str, Any]] = {}
    file_rows = []
    for file in files:
        with file.open("rb") as stream:
            scanner = McapScanner(stream)
            count, first, last = 0, None, None
            try:
                for topic, schema, log_time, _ in scanner.iter_messages():
                    row = per_topic.setdefault(topic, {"type": types.get(topic, schema), "messages": 0})
                    row["messages"] += 1
                    count += 1
                    first = log_time if first is None else min(first, log_time)
                    last = log_time if last is None else max(last, log_time)
            except McapDamage as exc:
                errors.append(f"{file}: {exc}")
            errors += [f"{file}: {damage}" for damage in scanner.skipped]
        file_rows.append({"path": str(file.relative_to(path) if path.is_dir() else file.name), "bytes": file.stat().st_size,
                          "messages": count, "start_s": None if first is None else first * 1e-9,
                          "end_s": None if last is None else last * 1e-9})
    for topic, claimed in listed.items():
        found = per_topic.get(topic, {}).get("messages", 0)
        if found != claimed:
            errors.append(f"{topic}: metadata.yaml says {claimed} messages, the files hold {found}")
    starts = [row["start_s"] for row in file_rows if row["start_s"] is not None]
    ends = [row["end_s"] for row in file_rows if row["end_s"] is not None]
    return {"bag": str(path), "files": file_rows, "duration_s": (max(ends) - min(starts)) if starts else 0.0,
            "messages": sum(row["messages"] for row in file_rows), "topics": dict(sorted(per_topic.items())),
            "ground_truth": _read_truth(path, []) is not None, "errors": errors}


def _listed_counts(path: Path) -> dict[str, Any]:
    entries = _metadata(path).get("topics_with_message_count") or [] if path.is_dir() else []
    try:
        return {str(entry["topic_metadata"]["name"]): entry["message_count"] for entry in entries}
    except (KeyError, TypeError):
        return {}


def _read_truth(path: Path, errors: list[str]) -> dict[str, Any] | None:
    meta = path / "metadata.yaml" if path.is_dir() else path.parent / "metadata.yaml"
    if not meta.is_file():
        errors.append(f"{meta}: missing, no ground truth")
        return None
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        custom = info.get("custom_data") or {}
        return json.loads(custom[topics.TRUTH_KEY]) if topics.TRUTH_KEY in custom else None
    except (yaml.YAMLError, KeyError, TypeError, AttributeError, json.JSONDecodeError) as exc:
        errors.append(f"{meta}: unreadable metadata ({type(exc).__name__})")
        return None


class _Series:
    __slots__ = ("stamps", "values")

    def __init__(self) -> None:
        self.stamps: list[np.ndarray] = []
        self.values: list[np.ndarray] = []

    def add(self, stamps: np.ndarray, values: np.ndarray) -> None:
        self.stamps.append(np.asarray(stamps, dtype=np.int64))
        self.values.append(np.asarray(values, dtype=float))

    def extend(self, other: _Series) -> None:
        self.stamps += other.stamps
        self.values += other.values

    def at_keys(self, keys: np.ndarray) -> np.ndarray:
        """The values at the sorted unique ``keys`` stamps, NaN where there is none; the parts are let go as they are placed
        (a long bag is aligned in little more memory than its columns)."""
        column = np.full(len(keys), np.nan)
        self.stamps.reverse()
        self.values.reverse()
        while self.stamps:
            place_at_keys(column, keys, self.stamps.pop(), self.values.pop())
        return column


class _JointStateChannel:
    """Decodes one JointState channel; names are checked per message against the first one's."""

    def __init__(self) -> None:
        self.names: list[str] | None = None
        self.reference: np.ndarray | None = None
        self.series: dict[str, tuple[_Series, _Series]] = {}

    def add(self, batch: MessageBatch, bad: list[int]) -> None:
        buf, starts, ends = batch.buffer, batch.starts, batch.ends
        if self.names is None:
            for k in range(len(starts)):
                try:
                    _, names, _, _ = decode_joint_state(bytes(buf[starts[k] : ends[k]]))
                except CdrError:
                    continue
                self.names = names
                _, ranges, _, _, _ = decode_joint_states(buf, starts[k : k + 1], ends[k : k + 1], 1)
                self.reference = buf[ranges[0, 0] : ranges[0, 1]].copy()
                break
            if self.names is None:
                bad[0] += len(starts)
                return
        stamps, ranges, position, velocity, ok = decode_joint_states(buf, starts, ends, len(self.names))
        same = same_bytes(buf, ranges, self.reference) & ok
        stamps = stamps[same]  # one array for every joint's position and velocity
        for j, name in enumerate(self.names):
            pos, vel = self.series.setdefault(name, (_Series(), _Series()))
            pos.add(stamps, position[same, j])
            vel.add(stamps, velocity[same, j])
        for k in np.flatnonzero(~same):  # other names or malformed: the per-message decoder decides
            try:
                stamp, names, pos_values, vel_values = decode_joint_state(bytes(buf[starts[k] : ends[k]]))
            except CdrError:
                bad[0] += 1
                continue
            for i, name in enumerate(names):
                pos, vel = self.series.setdefault(name, (_Series(), _Series()))
                pos.add([stamp], [pos_values[i] if i < len(pos_values) else np.nan])
                vel.add([stamp], [vel_values[i] if i < len(vel_values) else np.nan])


def _add_blocks(batch: MessageBatch, blocks: dict[Column, _Series], bad: list[int]) -> None:
    """The columns of sample blocks (field ``<joint or actuator>/<quantity>``, or a machine-wide quantity)."""
    for k in range(len(batch.starts)):
        try:
            names, stamps, rows = decode_sample_block(bytes(batch.buffer[batch.starts[k] : batch.ends[k]]))
        except CdrError:
            bad[0] += 1
            continue
        for j, name in enumerate(names):
            owner, _, quantity = name.rpartition("/")
            blocks.setdefault((quantity, owner), _Series()).add(stamps, rows[:, j])


def read_bag(path: str | Path) -> BagData:
    """Every readable message of every file of the bag; what could not be read is listed in ``errors``."""
    path = Path(path)
    errors: list[str] = []
    files = mcap_files(path, errors)
    truth = _read_truth(path, errors)
    joint_channels: dict[tuple[int, int], tuple[str, _JointStateChannel]] = {}
    pressures: dict[str, _Series] = {}
    blocks: dict[Column, _Series] = {}  # /hydraulics/sample_block columns: where a bag has them, they are its samples
    counts: dict[str, int] = {}
    total = 0
    for index, file in enumerate(files):
        bad = [0]
        scanner = None
        try:
            with file.open("rb") as stream:
                scanner = McapScanner(stream)
                for batch in scanner.batches():
                    channel = scanner.channels.get(batch.channel_id)
                    if channel is None:
                        bad[0] += len(batch.starts)
                        continue
                    counts[channel.topic] = counts.get(channel.topic, 0) + len(batch.starts)
                    if channel.schema == topics.FLUID_PRESSURE_TYPE:
                        stamps, values, ok = decode_fluid_pressures(batch.buffer, batch.starts, batch.ends)
                        pressures.setdefault(channel.topic, _Series()).add(stamps[ok], values[ok])
                        bad[0] += int(np.count_nonzero(~ok))
                    elif channel.schema == topics.JOINT_STATE_TYPE and channel.topic in (topics.JOINT_STATES, topics.VALVE_COMMANDS):
                        key = (index, batch.channel_id)
                        if key not in joint_channels:
                            joint_channels[key] = (channel.topic, _JointStateChannel())
                        joint_channels[key][1].add(batch, bad)
                    elif channel.topic == topics.SAMPLE_BLOCK:
                        _add_blocks(batch, blocks, bad)
        except Exception as exc:  # any damage (McapDamage, zstd, struct) ends this file, not the caller
            done = scanner.messages if scanner is not None else 0
            errors.append(f"{file}: damaged after {done} messages ({exc})")
        if scanner is not None:
            total += scanner.messages
            errors += [f"{file}: {damage}" for damage in scanner.skipped]
            if scanner.counted is not None and scanner.messages < scanner.counted:
                errors.append(f"{file}: {scanner.counted - scanner.messages} of the {scanner.counted} messages its summary counts "
                              "could not be read")
        if bad[0]:
            errors.append(f"{file}: {bad[0]} undecodable messages")
    joint: dict[str, dict[str, _Series]] = {}
    valves: dict[str, _Series] = {}
    for topic, decoded in joint_channels.values():
        for name, (pos, vel) in decoded.series.items():
            if topic == topics.VALVE_COMMANDS:
                valves.setdefault(name, _Series()).extend(pos)
            else:
                entry = joint.setdefault(name, {"position": _Series(), "velocity": _Series()})
                entry["position"].extend(pos)
                entry["velocity"].extend(vel)
    if not joint and not blocks:
        if total == 0 and errors:
            raise BagError(errors[-1])
        raise BagError(f"bag {path}: no {topics.JOINT_STATES} samples; not a contract bag")

    series: dict[Column, _Series] = {}
    for name, entry in joint.items():
        series[("joint_position", name)] = entry["position"]
        series[("joint_velocity", name)] = entry["velocity"]
    for name, valve in valves.items():
        series[("valve_command", name)] = valve
    for topic, pressure in pressures.items():
        parts = topic.strip("/").split("/")
        if topic == topics.SUPPLY_PRESSURE:
            series[("supply_pressure", "")] = pressure
        elif topic == topics.LS_PRESSURE:
            series[("ls_pressure", "")] = pressure
        elif len(parts) == 3 and parts[0] == "hydraulics" and parts[2] in ("pressure_a", "pressure_b", *topics.MOBILE_VALVE_PRESSURES):
            series[(parts[2], parts[1])] = pressure
    series.update(blocks)
    # a bag's samples are the /joint_states stamps; each column is placed and let go in turn (a long bag in bounded memory)
    keys = np.concatenate([stamps for column in series if column[0] == "joint_position" for stamps in series[column].stamps]
                          or [np.zeros(0, dtype=np.int64)])
    if len(keys) > 1 and not np.all(keys[1:] > keys[:-1]):  # one joint's stamps in order need no sort
        keys = np.unique(keys)
    data = BagData(path=path, stamps_ns=keys, truth=truth, message_count=total, topic_counts=counts, errors=errors)
    for quantity, name in list(series):
        values = series.pop((quantity, name)).at_keys(keys)
        if quantity in ("supply_pressure", "ls_pressure"):
            setattr(data, quantity, values)
        else:
            getattr(data, quantity)[name] = values
    return data
