"""Write ROS 2 bags: a bag directory of MCAP files and one metadata.yaml, CDR messages.

The files are written by rosbags' MCAP writer (rosdep key python3-rosbags-pip), which puts the
schema and channel records into the first chunk and closes a chunk every 1 MB, so a file cut short
by a crash still reads up to its last closed chunk. A bag may be split by duration or size, as
`ros2 bag record` does: each part is written by its own rosbags writer and moved into the bag
directory as ``<name>_<i>.mcap`` when it closes; the bag's metadata.yaml (rosbag2 version 9, with
every topic's offered QoS profiles and type hash and the custom data) is rewritten after every part,
so a recording killed mid-part keeps the metadata of the parts it finished. The part being written
lives in ``<name>_<i>/`` until then; the reader reads it too.
"""

from __future__ import annotations

import json
import shutil
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime
from rosbags.rosbag2 import CompressionFormat, CompressionMode, StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from hydro_ros.bags.cdr import encode_fluid_pressure, encode_joint_state
from hydro_ros.bags.mcap_scan import zstd
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.samples import Samples

TYPESTORE = get_typestore(Stores.ROS2_KILTED)
_NO_TIME = QosTime(0, 0)
# what the package's own publishers offer on the sensor topics (nodes/common.SENSOR_QOS)
SENSOR_QOS = Qos(QosHistory.KEEP_LAST, topics.SENSOR_QUEUE_DEPTH, QosReliability.RELIABLE, QosDurability.VOLATILE,
                 _NO_TIME, _NO_TIME, QosLiveliness.AUTOMATIC, _NO_TIME, False)


def _checksummed_zstd(data: bytes) -> bytes:
    return zstd.compress(data, options={zstd.CompressionParameter.checksum_flag: 1})


class BagExistsError(InputError, FileExistsError):
    pass


@dataclass
class _Topic:
    name: str
    msgtype: str
    qos: tuple[Qos, ...]
    count: int = 0


@dataclass
class _Part:
    writer: Writer
    directory: Path
    connections: dict[int, Any] = field(default_factory=dict)  # topic handle -> rosbags connection
    first: int | None = None
    last: int = 0
    messages: int = 0
    payload_bytes: int = 0


class BagWriter:
    """Context manager writing one bag directory, split into parts by log-time duration and/or size.

    The size is that of the messages before compression: the file of a part is smaller (zstd), and
    it is known only chunk by chunk.

    ``add_topic`` returns a handle for ``write``; topics may be added at any time (a recorder finds
    them as they appear). Nothing is overwritten: an existing path is refused.
    """

    def __init__(self, path: str | Path, *, split_duration_s: float | None = None, split_size_bytes: int | None = None) -> None:
        self.path = Path(path)
        if self.path.exists():
            raise BagExistsError(f"bag {self.path}: already exists, refusing to overwrite")
        for name, value in (("split duration", split_duration_s), ("split size", split_size_bytes)):
            if value is not None and not value > 0:
                raise InputError(f"bag {self.path}: {name} {value} must be > 0")
        self._split_ns = None if split_duration_s is None else int(split_duration_s * 1e9)
        self._split_bytes = split_size_bytes
        self.custom_data: dict[str, str] = {}
        self.messages = 0
        self._topics: list[_Topic] = []
        self._files: list[dict[str, Any]] = []
        self._qos_yaml: dict[str, Any] = {}  # rosbags' own serialisation of each topic's QoS, from the parts' metadata
        self._part: _Part | None = None

    def __enter__(self) -> BagWriter:
        self.path.mkdir(parents=True)
        self._open_part()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        if self._part is None:
            return
        if self._part.messages == 0 and self._files:  # a split just before the end: no empty last file
            part, self._part = self._part, None
            part.writer.close()
            shutil.rmtree(part.directory)
        else:
            self._close_part()

    @property
    def files(self) -> list[str]:
        return [entry["path"] for entry in self._files]

    def add_topic(self, topic: str, msgtype: str, qos: Sequence[Qos] = ()) -> int:
        if msgtype not in TYPESTORE.types:
            raise InputError(f"topic {topic}: message type {msgtype} is not a ROS 2 Kilted type rosbags knows")
        self._topics.append(_Topic(topic, msgtype, tuple(qos)))
        return len(self._topics) - 1

    def write(self, handle: int, stamp: int, data: bytes) -> None:
        """One message; ``stamp`` (ns) is its log time."""
        part = self._part
        if part.first is None:
            part.first = stamp
        elif (self._split_ns is not None and stamp - part.first >= self._split_ns) or (
            self._split_bytes is not None and part.payload_bytes >= self._split_bytes
        ):
            self.split()
            part = self._part
            part.first = stamp
        connection = part.connections.get(handle)
        if connection is None:
            topic = self._topics[handle]
            connection = part.connections[handle] = part.writer.add_connection(
                topic.name, topic.msgtype, typestore=TYPESTORE, offered_qos_profiles=topic.qos)
        part.writer.write(connection, stamp, data)
        part.last = max(part.last, stamp)
        part.messages += 1
        part.payload_bytes += len(data)
        self._topics[handle].count += 1
        self.messages += 1

    def split(self) -> None:
        """Close the open part (when it holds anything) and continue in a new one."""
        if self._part.messages:
            self._close_part()
            self._open_part()

    def _open_part(self) -> None:
        directory = self.path / f"{self.path.name}_{len(self._files)}"
        writer = Writer(directory, version=9, storage_plugin=StoragePlugin.MCAP)
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        writer.open()
        # rosbags leaves the chunk CRC at 0; a zstd frame checksum lets every reader see a damaged chunk
        writer.storage.compressor = _checksummed_zstd
        self._part = _Part(writer, directory)

    def _close_part(self) -> None:
        part, self._part = self._part, None
        part.writer.close()
        name = f"{part.directory.name}.mcap"
        (part.directory / name).replace(self.path / name)
        part_topics = yaml.safe_load((part.directory / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
        shutil.rmtree(part.directory)
        first = part.first or 0
        self._files.append({"path": name, "starting_time": {"nanoseconds_since_epoch": first},
                            "duration": {"nanoseconds": part.last - first if part.messages else 0},
                            "message_count": part.messages})
        self._qos_yaml.update({entry["topic_metadata"]["name"]: entry["topic_metadata"]["offered_qos_profiles"]
                               for entry in part_topics["topics_with_message_count"]})
        self._write_metadata()

    def _write_metadata(self) -> None:
        written = [entry for entry in self._files if entry["message_count"]]
        start = min((entry["starting_time"]["nanoseconds_since_epoch"] for entry in written), default=0)
        end = max((entry["starting_time"]["nanoseconds_since_epoch"] + entry["duration"]["nanoseconds"] for entry in written), default=0)
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": {"nanoseconds": end - start},
            "starting_time": {"nanoseconds_since_epoch": start},
            "message_count": sum(entry["message_count"] for entry in self._files),
            "topics_with_message_count": [
                {
                    "message_count": topic.count,
                    "topic_metadata": {
                        "name": topic.name,
                        "type": topic.msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": self._qos_yaml.get(topic.name, []),
                        "type_description_hash": TYPESTORE.hash_rihs01(topic.msgtype),
                    },
                }
                for topic in self._topics
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": self.files,
            "files": self._files,
            "custom_data": self.custom_data,
            "ros_distro": "kilted",
        }
        temporary = self.path / "metadata.yaml.tmp"
        temporary.write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))
        temporary.replace(self.path / "metadata.yaml")


def sample_payloads(block: Samples, k: int, stamp: int, actuator: str, joint: str, variance: float) -> tuple[bytes, ...]:
    """CDR of sample ``k`` for the topics of :func:`sample_topics`, in that order."""
    payloads = (
        encode_joint_state(stamp, "", [joint], [float(block.joint_position[k])], [float(block.joint_velocity[k])], []),
        encode_fluid_pressure(stamp, actuator, float(block.pressure_a[k]), variance),
        encode_fluid_pressure(stamp, actuator, float(block.pressure_b[k]), variance),
        encode_fluid_pressure(stamp, "supply", float(block.supply_pressure[k]), variance),
        encode_joint_state(stamp, "", [actuator], [float(block.valve_command[k])], [], []),
    )
    if not block.mobile:
        return payloads
    # the load-sensing line sees the pressure the compensator works against
    return (*payloads, encode_fluid_pressure(stamp, actuator, float(block.pilot_pressure_1[k]), 0.0),
            encode_fluid_pressure(stamp, actuator, float(block.pilot_pressure_2[k]), 0.0),
            encode_fluid_pressure(stamp, actuator, float(block.compensator_pressure[k]), variance),
            encode_fluid_pressure(stamp, "ls", float(block.ls_pressure[k]), variance))


def sample_topics(actuator: str, *, mobile: bool = False) -> tuple[str, ...]:
    base = (topics.JOINT_STATES, topics.pressure_a(actuator), topics.pressure_b(actuator), topics.SUPPLY_PRESSURE, topics.VALVE_COMMANDS)
    if not mobile:
        return base
    return base + tuple(topics.actuator_pressure(actuator, q) for q in topics.MOBILE_VALVE_PRESSURES) + (topics.LS_PRESSURE,)


def machine_payloads(stamp: int, actuators: dict[str, str], variance: float, positions: Any, velocities: Any, p_a: Any, p_b: Any,
                     supply_pressure: float, commands: Any, mobile: tuple[Any, Any, Any, float] | None,
                     held: dict[str, float] | None = None) -> list[tuple[str, bytes]]:
    """(topic, CDR bytes) of one sample of a machine with several actuators (``actuators``: actuator -> joint, in column
    order): every joint in one JointState, the pressures per actuator; ``mobile`` = (pilot 1, pilot 2, compensator, LS).
    ``held``: joints no actuator moves (a crane's base held still), joint -> position, listed first at rest."""
    names = list(actuators)
    held = held or {}
    out = [(topics.JOINT_STATES, encode_joint_state(stamp, "", [*held, *actuators.values()], [*held.values(), *map(float, positions)],
                                                    [*(0.0 for _ in held), *map(float, velocities)], [])),
           (topics.SUPPLY_PRESSURE, encode_fluid_pressure(stamp, "supply", supply_pressure, variance)),
           (topics.VALVE_COMMANDS, encode_joint_state(stamp, "", names, [float(c) for c in commands], [], []))]
    for i, actuator in enumerate(names):
        out.append((topics.pressure_a(actuator), encode_fluid_pressure(stamp, actuator, float(p_a[i]), variance)))
        out.append((topics.pressure_b(actuator), encode_fluid_pressure(stamp, actuator, float(p_b[i]), variance)))
        if mobile is not None:
            for quantity, values, noise in zip(topics.MOBILE_VALVE_PRESSURES, mobile[:3], (0.0, 0.0, variance)):
                out.append((topics.actuator_pressure(actuator, quantity), encode_fluid_pressure(stamp, actuator, float(values[i]), noise)))
    if mobile is not None:
        out.append((topics.LS_PRESSURE, encode_fluid_pressure(stamp, "ls", mobile[3], variance)))
    return out


def block_machine_payloads(block: Samples, k: int, stamp: int, actuators: dict[str, str], variance: float,
                           mobile: bool, held: dict[str, float] | None = None) -> list[tuple[str, bytes]]:
    """:func:`machine_payloads` of sample k of a block with (n, A) columns."""
    pressures = None
    if mobile:
        pressures = (block.pilot_pressure_1[k], block.pilot_pressure_2[k], block.compensator_pressure[k], float(block.ls_pressure[k]))
    return machine_payloads(stamp, actuators, variance, block.joint_position[k], block.joint_velocity[k], block.pressure_a[k],
                            block.pressure_b[k], float(block.supply_pressure[k]), block.valve_command[k], pressures, held)


class ContractBagWriter(BagWriter):
    """One machine's sensor topics, written from simulated or converted samples (one file)."""

    def __init__(self, path: str | Path, *, actuators: dict[str, str], pressure_variance: float, mobile: bool = False) -> None:
        """``actuators`` maps actuator name -> joint name (machine config order)."""
        super().__init__(path)
        self.actuators = actuators
        self.variance = pressure_variance
        self.mobile = mobile
        self._handles = {topic: self.add_topic(topic, msgtype, [SENSOR_QOS])
                         for topic, msgtype in topics.sensor_topics(list(actuators), mobile=mobile).items()}

    def set_truth(self, truth: dict[str, Any]) -> None:
        self.custom_data[topics.TRUTH_KEY] = json.dumps(truth, sort_keys=True)

    def write_machine_sample(
        self,
        stamp: int,
        joints: tuple[list[float], list[float]],
        pressures: tuple[list[float], list[float]],
        supply_pressure: float,
        commands: list[float],
    ) -> None:
        """One sample of a multi-joint machine: one JointState with every joint, per-actuator pressures."""
        for topic, payload in machine_payloads(stamp, self.actuators, self.variance, joints[0], joints[1], pressures[0], pressures[1],
                                               supply_pressure, commands, None):
            self.write(self._handles[topic], stamp, payload)

    def write_machine_block(self, block: Samples) -> None:
        """Samples of every actuator, (n, A) columns in the writer's actuator order, one JointState per sample."""
        for k in range(len(block.times)):
            stamp = int(round(block.times[k] * 1e9))
            for topic, payload in block_machine_payloads(block, k, stamp, self.actuators, self.variance, self.mobile):
                self.write(self._handles[topic], stamp, payload)

    def write_block(self, actuator: str, block: Samples) -> None:
        """One actuator's block of samples; stamps (and bag log times) are sample times."""
        handles = [self._handles[name] for name in sample_topics(actuator, mobile=self.mobile)]
        joint = self.actuators[actuator]
        for k in range(len(block.times)):
            stamp = int(round(block.times[k] * 1e9))
            for handle, payload in zip(handles, sample_payloads(block, k, stamp, actuator, joint, self.variance)):
                self.write(handle, stamp, payload)
