"""Read a contract bag into aligned numpy arrays, fast and without ROS.

Reads the MCAP file sequentially (so a truncated or corrupt file yields everything before the
damage), decodes the fixed-layout types by hand, and aligns every topic on the sample stamps
of /joint_states. Damage is reported in ``BagData.errors`` and never raises past what was read.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from mcap.reader import NonSeekingReader

from hydro_ros.bags import topics
from hydro_ros.bags.cdr import CdrError, decode_fluid_pressure, decode_joint_state


class BagError(ValueError):
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


def mcap_file(path: Path) -> Path:
    if path.is_file():
        return path
    if not path.is_dir():
        raise BagError(f"bag {path}: no such file or directory")
    files = sorted(path.glob("*.mcap"))
    if not files:
        raise BagError(f"bag {path}: no .mcap file in the directory (only MCAP storage is supported)")
    return files[0]


def _read_truth(path: Path, errors: list[str]) -> dict[str, Any] | None:
    meta = path / "metadata.yaml" if path.is_dir() else path.parent / "metadata.yaml"
    if not meta.is_file():
        errors.append(f"{meta}: missing, no ground truth")
        return None
    try:
        info = yaml.safe_load(meta.read_text())["rosbag2_bagfile_information"]
        custom = info.get("custom_data") or {}
        return json.loads(custom[topics.TRUTH_KEY]) if topics.TRUTH_KEY in custom else None
    except (yaml.YAMLError, KeyError, TypeError, json.JSONDecodeError) as exc:
        errors.append(f"{meta}: unreadable metadata ({type(exc).__name__})")
        return None


class _Series:
    __slots__ = ("stamps", "values")

    def __init__(self) -> None:
        self.stamps: list[int] = []
        self.values: list[Any] = []


def read_bag(path: str | Path) -> BagData:
    path = Path(path)
    file = mcap_file(path)
    errors: list[str] = []
    truth = _read_truth(path, errors)
    joint: dict[str, dict[str, _Series]] = {}
    valves: dict[str, _Series] = {}
    pressures: dict[str, _Series] = {}
    counts: dict[str, int] = {}
    total = 0
    bad = 0
    try:
        with file.open("rb") as stream:
            for schema, channel, message in NonSeekingReader(stream, validate_crcs=True).iter_messages(log_time_order=False):
                total += 1
                topic = channel.topic
                counts[topic] = counts.get(topic, 0) + 1
                try:
                    if schema is not None and schema.name == topics.FLUID_PRESSURE_TYPE:
                        stamp, value, _ = decode_fluid_pressure(message.data)
                        series = pressures.setdefault(topic, _Series())
                        series.stamps.append(stamp)
                        series.values.append(value)
                    elif schema is not None and schema.name == topics.JOINT_STATE_TYPE:
                        stamp, names, position, velocity = decode_joint_state(message.data)
                        if topic == topics.VALVE_COMMANDS:
                            for i, name in enumerate(names):
                                series = valves.setdefault(name, _Series())
                                series.stamps.append(stamp)
                                series.values.append(position[i] if i < len(position) else np.nan)
                        elif topic == topics.JOINT_STATES:
                            for i, name in enumerate(names):
                                entry = joint.setdefault(name, {"position": _Series(), "velocity": _Series()})
                                entry["position"].stamps.append(stamp)
                                entry["position"].values.append(position[i] if i < len(position) else np.nan)
                                entry["velocity"].stamps.append(stamp)
                                entry["velocity"].values.append(velocity[i] if i < len(velocity) else np.nan)
                except CdrError as exc:
                    bad += 1
                    if bad == 1:
                        errors.append(f"{file}: message on {topic} at log time {message.log_time} undecodable ({exc})")
    except Exception as exc:  # noqa: BLE001 - any damage to the stream ends reading, not the caller
        errors.append(f"{file}: damaged after {total} messages ({type(exc).__name__}: {exc})".strip())
    if bad > 1:
        errors.append(f"{file}: {bad} undecodable messages in all")
    if not joint:
        if total == 0 and errors:
            raise BagError(errors[-1])
        raise BagError(f"bag {path}: no {topics.JOINT_STATES} samples; not a contract bag")

    base = np.array(sorted({s for entry in joint.values() for s in entry["position"].stamps}), dtype=np.int64)

    def aligned(series: _Series) -> np.ndarray:
        out = np.full(len(base), np.nan)
        stamps = np.asarray(series.stamps, dtype=np.int64)
        index = np.searchsorted(base, stamps)
        ok = (index < len(base)) & (base[np.minimum(index, len(base) - 1)] == stamps)
        out[index[ok]] = np.asarray(series.values, dtype=float)[ok]
        return out

    data = BagData(path=path, stamps_ns=base, truth=truth, message_count=total, topic_counts=counts, errors=errors)
    for name, entry in joint.items():
        data.joint_position[name] = aligned(entry["position"])
        data.joint_velocity[name] = aligned(entry["velocity"])
    for name, series in valves.items():
        data.valve_command[name] = aligned(series)
    for topic, series in pressures.items():
        if topic == topics.SUPPLY_PRESSURE:
            data.supply_pressure = aligned(series)
            continue
        parts = topic.strip("/").split("/")
        if len(parts) == 3 and parts[0] == "hydraulics" and parts[2] in ("pressure_a", "pressure_b"):
            getattr(data, parts[2])[parts[1]] = aligned(series)
    return data
