"""Write contract bags: ROS 2 bag directory (metadata.yaml + one MCAP file), CDR messages.

The MCAP file is written with the `mcap` library in the layout `ros2 bag record` produces:
schema and channel records precede the messages in the data section and chunks are closed
every ~1 MB, so a bag cut short by a crash loses only its last chunk (rosbags' writer keeps
schemas and channels for the summary at the end, which a truncated file never reaches).
metadata.yaml follows rosbag2 version 9; ground truth goes into its custom_data.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import yaml
from mcap.writer import CompressionType, Writer
from rosbags.typesys import Stores, get_typestore

from hydro_ros.bags.cdr import encode_fluid_pressure, encode_joint_state
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.samples import Samples

TYPESTORE = get_typestore(Stores.ROS2_KILTED)


class BagExistsError(InputError, FileExistsError):
    pass


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
    return payloads + (
        encode_fluid_pressure(stamp, actuator, float(block.pilot_pressure_1[k]), 0.0),
        encode_fluid_pressure(stamp, actuator, float(block.pilot_pressure_2[k]), 0.0),
        encode_fluid_pressure(stamp, actuator, float(block.compensator_pressure[k]), variance),
        encode_fluid_pressure(stamp, "ls", float(block.ls_pressure[k]), variance),
    )


def sample_topics(actuator: str, *, mobile: bool = False) -> tuple[str, ...]:
    base = (topics.JOINT_STATES, topics.pressure_a(actuator), topics.pressure_b(actuator), topics.SUPPLY_PRESSURE, topics.VALVE_COMMANDS)
    if not mobile:
        return base
    return base + tuple(topics.actuator_pressure(actuator, q) for q in topics.MOBILE_VALVE_PRESSURES) + (topics.LS_PRESSURE,)


class ContractBagWriter:
    """Context manager writing one machine's sensor topics."""

    def __init__(self, path: str | Path, *, actuators: dict[str, str], pressure_variance: float, mobile: bool = False) -> None:
        """``actuators`` maps actuator name -> joint name (machine config order)."""
        self.path = Path(path)
        if self.path.exists():
            raise BagExistsError(f"bag {self.path}: already exists, refusing to overwrite")
        self.actuators = actuators
        self.variance = pressure_variance
        self.file = self.path / f"{self.path.name}.mcap"
        self.custom_data: dict[str, str] = {}
        self.messages = 0
        self._counts: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.mobile = mobile
        self._types = topics.sensor_topics(list(actuators), mobile=mobile)
        self._first = None
        self._last = 0

    def __enter__(self) -> "ContractBagWriter":
        self.path.mkdir(parents=True)
        self._stream = self.file.open("wb")
        self._mcap = Writer(self._stream, compression=CompressionType.ZSTD)
        self._mcap.start(profile="ros2", library="hydro_ros")
        schemas: dict[str, int] = {}
        for topic, msgtype in self._types.items():
            if msgtype not in schemas:
                definition, _ = TYPESTORE.generate_msgdef(msgtype, ros_version=2)
                schemas[msgtype] = self._mcap.register_schema(msgtype, "ros2msg", definition.encode())
            self._channels[topic] = self._mcap.register_channel(topic, "cdr", schemas[msgtype])
            self._counts[topic] = 0
        return self

    def __exit__(self, *exc: object) -> None:
        self._mcap.finish()
        self._stream.close()
        self._write_metadata()

    def set_truth(self, truth: dict[str, Any]) -> None:
        self.custom_data[topics.TRUTH_KEY] = json.dumps(truth, sort_keys=True)

    def _write_metadata(self) -> None:
        start = self._first or 0
        duration = {"nanoseconds": self._last - start}
        starting = {"nanoseconds_since_epoch": start}
        info = {
            "version": 9,
            "storage_identifier": "mcap",
            "duration": duration,
            "starting_time": starting,
            "message_count": self.messages,
            "topics_with_message_count": [
                {
                    "message_count": self._counts[topic],
                    "topic_metadata": {
                        "name": topic,
                        "type": msgtype,
                        "serialization_format": "cdr",
                        "offered_qos_profiles": [],
                        "type_description_hash": TYPESTORE.hash_rihs01(msgtype),
                    },
                }
                for topic, msgtype in self._types.items()
            ],
            "compression_format": "",
            "compression_mode": "",
            "relative_file_paths": [self.file.name],
            "files": [{"path": self.file.name, "starting_time": starting, "duration": duration, "message_count": self.messages}],
            "custom_data": self.custom_data,
            "ros_distro": "kilted",
        }
        (self.path / "metadata.yaml").write_text(yaml.safe_dump({"rosbag2_bagfile_information": info}, sort_keys=False))

    def write_machine_sample(
        self,
        stamp: int,
        joints: tuple[list[float], list[float]],
        pressures: tuple[list[float], list[float]],
        supply_pressure: float,
        commands: list[float],
    ) -> None:
        """One sample of a multi-joint machine: one JointState with every joint, per-actuator pressures."""
        channels, add = self._channels, self._mcap.add_message
        names = list(self.actuators)
        payloads = [
            (topics.JOINT_STATES, encode_joint_state(stamp, "", list(self.actuators.values()), joints[0], joints[1], [])),
            (topics.SUPPLY_PRESSURE, encode_fluid_pressure(stamp, "supply", supply_pressure, self.variance)),
            (topics.VALVE_COMMANDS, encode_joint_state(stamp, "", names, commands, [], [])),
        ]
        for actuator, p_a, p_b in zip(names, *pressures):
            payloads.append((topics.pressure_a(actuator), encode_fluid_pressure(stamp, actuator, p_a, self.variance)))
            payloads.append((topics.pressure_b(actuator), encode_fluid_pressure(stamp, actuator, p_b, self.variance)))
        for topic, payload in payloads:
            add(channels[topic], stamp, payload, stamp)
            self._counts[topic] += 1
        self.messages += len(payloads)
        self._first = self._first if self._first is not None else stamp
        self._last = stamp

    def write(self, actuator: str, block: Samples) -> None:
        """Write one actuator's block of samples; stamps (and bag log times) are sample times."""
        joint = self.actuators[actuator]
        channels = self._channels
        names = sample_topics(actuator, mobile=self.mobile)
        ids = [channels[name] for name in names]
        add = self._mcap.add_message
        for k in range(len(block.times)):
            stamp = int(round(block.times[k] * 1e9))
            payloads = sample_payloads(block, k, stamp, actuator, joint, self.variance)
            for channel, payload in zip(ids, payloads):
                add(channel, stamp, payload, stamp)
        n = len(block.times)
        for name in names:
            self._counts[name] += n
        self.messages += len(names) * n
        if n:
            self._first = self._first if self._first is not None else int(round(block.times[0] * 1e9))
            self._last = int(round(block.times[-1] * 1e9))
