"""bag_player: replay a contract bag onto its topics with /clock, rate and loop (like ros2 bag play).

Messages are published as the bag's raw CDR bytes, so a replay is byte-identical to the
recording. A bag split over several files is played whole, file after file. A damaged file is
played up to the damage, the error is logged and playback goes on with the next file; ``replay``
then exits non-zero.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Iterator

import rclpy
from mcap.reader import NonSeekingReader, make_reader
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg

from hydro_ros.bags.reader import mcap_files
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.nodes.common import CLOCK_QOS, SENSOR_QOS, message_class, run_node


class BagPlayer(Node):
    def __init__(self, bag: str | None = None, rate: float | None = None, loop: bool | None = None, clock: bool | None = None) -> None:
        super().__init__("bag_player")
        self.declare_parameter("bag", bag or "")
        self.declare_parameter("rate", 1.0 if rate is None else rate)
        self.declare_parameter("loop", bool(loop))
        self.declare_parameter("publish_clock", True if clock is None else clock)
        self.declare_parameter("tick_period", 0.005)
        # like `ros2 bag play --delay`: give subscribers time to match before the first message
        self.declare_parameter("start_delay", 1.0)
        self.path = Path(self.get_parameter("bag").value)
        self.rate = float(self.get_parameter("rate").value)
        if not (self.rate > 0 and math.isfinite(self.rate)):
            raise InputError(f"parameter rate={self.rate}: must be > 0")
        self.loop = bool(self.get_parameter("loop").value)
        self.errors: list[str] = []
        self.files = mcap_files(self.path, self.errors)
        for error in self.errors:
            self.get_logger().error(error)
        self.publishers_by_topic: dict[str, object] = {}
        self.clock_pub = self.create_publisher(ClockMsg, topics.CLOCK, CLOCK_QOS) if self.get_parameter("publish_clock").value else None
        self.finished = False
        self.published = 0
        self._advertise()
        self._delay = float(self.get_parameter("start_delay").value)
        self._restart()
        self.create_timer(float(self.get_parameter("tick_period").value), self._tick, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        for file in self.files:
            with file.open("rb") as stream:
                try:
                    for schema, channel, message in NonSeekingReader(stream, validate_crcs=True).iter_messages(log_time_order=False):
                        yield channel.topic, schema.name if schema else "", message.log_time, message.data
                except Exception as exc:  # noqa: BLE001 - damage ends this file's playback, not the node
                    error = f"{file}: damaged after {self.published} messages ({type(exc).__name__}: {exc})"
                    self.errors.append(error)
                    self.get_logger().error(error)

    def _advertise(self) -> None:
        """Create every publisher up front from the MCAP summary, when the file has one."""
        for file in self.files:
            try:
                with file.open("rb") as stream:
                    summary = make_reader(stream).get_summary()
            except Exception:  # noqa: BLE001 - a damaged summary only means publishers are made lazily
                continue
            if summary is None:
                continue
            for channel in summary.channels.values():
                schema = summary.schemas.get(channel.schema_id)
                if schema is not None:
                    self._publisher(channel.topic, schema.name)

    def _restart(self) -> None:
        self._stream = self._messages()
        self._next = next(self._stream, None)
        self._bag_start = self._next[2] if self._next else 0
        self._wall_start = time.monotonic() + self._delay
        self._delay = 0.0

    def _publisher(self, topic: str, type_name: str):
        pub = self.publishers_by_topic.get(topic)
        if pub is None:
            pub = self.create_publisher(message_class(type_name), topic, SENSOR_QOS)
            self.publishers_by_topic[topic] = pub
        return pub

    def _tick(self) -> None:
        if self.finished:
            return
        elapsed = time.monotonic() - self._wall_start
        if elapsed < 0.0:
            return
        play_until = self._bag_start + int(elapsed * self.rate * 1e9)
        last = None
        while self._next is not None and self._next[2] <= play_until:
            topic, type_name, log_time, data = self._next
            self._publisher(topic, type_name).publish(data)
            self.published += 1
            last = log_time
            self._next = next(self._stream, None)
        if last is not None and self.clock_pub is not None:
            msg = ClockMsg()
            msg.clock.sec, msg.clock.nanosec = divmod(last, 1_000_000_000)
            self.clock_pub.publish(msg)
        if self._next is None:
            if self.loop:
                self._restart()
            else:
                self.finished = True
                self.get_logger().info(f"played {self.published} messages from {self.path}")


def replay(bag: str, *, rate: float = 1.0, loop: bool = False, clock: bool = True) -> int:
    """Play ``bag`` to the end (forever with ``loop``); returns 0, or 1 if the bag was damaged."""
    rclpy.init()
    node = BagPlayer(bag, rate, loop, clock)
    try:
        while rclpy.ok() and not node.finished:
            rclpy.spin_once(node, timeout_sec=0.1)
    except KeyboardInterrupt:
        pass
    finally:
        errors = list(node.errors)
        node.destroy_node()
        if rclpy.ok():
            rclpy.shutdown()
    return 1 if errors else 0


def main(args: list[str] | None = None) -> None:
    run_node(BagPlayer, args)


if __name__ == "__main__":
    main()
