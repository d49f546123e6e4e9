"""Write contract bags: ROS 2 bag directory, MCAP storage (zstd chunks), CDR messages."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.writer import CompressionFormat, CompressionMode
from rosbags.typesys import Stores, get_typestore

from hydro_ros.bags import topics
from hydro_ros.bags.cdr import encode_fluid_pressure, encode_joint_state
from hydro_ros.sim.sensors import Measurements

TYPESTORE = get_typestore(Stores.ROS2_KILTED)


class BagExistsError(FileExistsError):
    pass


class ContractBagWriter:
    """Context manager writing one machine's sensor topics; ground truth goes into custom_data."""

    def __init__(self, path: str | Path, *, actuators: dict[str, str], pressure_variance: float) -> None:
        """``actuators`` maps actuator name -> joint name (machine config order)."""
        self.path = Path(path)
        if self.path.exists():
            raise BagExistsError(f"bag {self.path}: already exists, refusing to overwrite")
        self.actuators = actuators
        self.variance = pressure_variance
        self._writer = Writer(self.path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._connections: dict[str, Any] = {}
        self.messages = 0

    def __enter__(self) -> "ContractBagWriter":
        self._writer.open()
        for topic, msgtype in topics.sensor_topics(list(self.actuators)).items():
            self._connections[topic] = self._writer.add_connection(topic, msgtype, typestore=TYPESTORE)
        return self

    def __exit__(self, *exc: object) -> None:
        self._writer.close()

    def set_truth(self, truth: dict[str, Any]) -> None:
        self._writer.set_custom_data(topics.TRUTH_KEY, json.dumps(truth, sort_keys=True))

    def write(self, actuator: str, block: Measurements) -> None:
        """Write one actuator's block of samples; stamps (and bag log times) are sample times."""
        joint = self.actuators[actuator]
        conn = self._connections
        write = self._writer.write
        for k in range(len(block.times)):
            stamp = int(round(block.times[k] * 1e9))
            write(conn[topics.JOINT_STATES], stamp, encode_joint_state(
                stamp, "", [joint], [float(block.joint_position[k])], [float(block.joint_velocity[k])], []))
            write(conn[topics.pressure_a(actuator)], stamp, encode_fluid_pressure(
                stamp, actuator, float(block.pressure_a[k]), self.variance))
            write(conn[topics.pressure_b(actuator)], stamp, encode_fluid_pressure(
                stamp, actuator, float(block.pressure_b[k]), self.variance))
            write(conn[topics.SUPPLY_PRESSURE], stamp, encode_fluid_pressure(
                stamp, "supply", float(block.supply_pressure[k]), self.variance))
            write(conn[topics.VALVE_COMMANDS], stamp, encode_joint_state(
                stamp, "", [actuator], [float(block.valve_command[k])], [], []))
        self.messages += 5 * len(block.times)
