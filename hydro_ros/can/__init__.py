"""CAN bus of the machine: DBC codec with counter/checksum checks, log conversion (no ROS)."""

from hydro_ros.can.codec import FrameError, MachineBus
from hydro_ros.can.convert import convert_log

__all__ = ["FrameError", "MachineBus", "convert_log"]
