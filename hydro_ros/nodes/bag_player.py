"""bag_player: replay a contract bag onto its topics with /clock, rate and loop (like ros2 bag play).

Messages are published as the bag's raw CDR bytes, so a replay is byte-identical to the
recording. A bag split over several files is played whole, file after file. A damaged file is
played up to the damage, the error is logged and playback goes on with the next file; ``replay``
then exits non-zero.
"""

from __future__ import annotations

import time
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy._rclpy_pybind11 import RCLError
from rclpy.clock import Clock, ClockType
from rclpy.node import Node
from rosgraph_msgs.msg import Clock as ClockMsg

from hydro_ros.bags.mcap_scan import McapDamage, McapScanner
from hydro_ros.bags.reader import bag_topics, mcap_files
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.nodes.common import CLOCK_QOS, SENSOR_QOS, message_class, relative, run_node
from hydro_ros.nodes.parameters import declare, parameter, specs_of


@dataclass
class BagPlayerParameters:
    """bag_player's parameters, each declared once with its unit, range and description."""

    bag: str = parameter("", "bag directory (or one .mcap file) to play; a split bag is played whole")
    rate: float = parameter(1.0, "[-] playback speed, bag seconds per wall second", 0.01, 100.0)
    loop: bool = parameter(False, "start again at the end")
    publish_clock: bool = parameter(False, "publish /clock with each message's log time, for use_sim_time nodes (off by default, as in "
                                           "ros2 bag play without --clock)")
    tick_period: float = parameter(0.005, "[s] wall time between publishing the messages due", 0.0005, 1.0)
    start_delay: float = parameter(1.0, "[s] wait before the first message", 0.0, 60.0)


PARAMETERS = specs_of(BagPlayerParameters)


class BagPlayer(Node):
    def __init__(self, bag: str | None = None, rate: float | None = None, loop: bool | None = None, clock: bool | None = None) -> None:
        super().__init__("bag_player")
        given = {"bag": bag, "rate": None if rate is None else float(rate), "loop": loop, "publish_clock": clock}
        self.params = declare(self, BagPlayerParameters, defaults={name: value for name, value in given.items() if value is not None})
        if not self.params.bag:
            raise InputError("parameter bag: required (a bag directory or .mcap file)")
        self.path = Path(self.params.bag)
        self.rate = self.params.rate
        self.loop = self.params.loop
        self.errors: list[str] = []
        self.files = mcap_files(self.path, self.errors)
        for error in self.errors:
            self.get_logger().error(error)
        self.publishers_by_topic: dict[str, object] = {}
        self.skipped_topics: list[str] = []
        self.clock_pub = self.create_publisher(ClockMsg, topics.CLOCK, CLOCK_QOS) if self.params.publish_clock else None
        self.finished = False
        self.published = 0
        self.publish_errors = 0  # messages rmw would not send (a transient DDS failure): counted, said once, the rest played
        self._advertise()
        self._delay = self.params.start_delay
        self._restart()
        self.create_timer(self.params.tick_period, self._tick, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        for file in self.files:
            with file.open("rb") as stream:
                scanner = McapScanner(stream)
                try:
                    yield from scanner.iter_messages()
                except McapDamage as exc:  # damage ends this file's playback, not the node
                    scanner.skipped.append(f"damaged after {self.published} messages ({exc})")
                for damage in scanner.skipped:
                    self.errors.append(f"{file}: {damage}")
                    self.get_logger().error(self.errors[-1])

    def _advertise(self) -> None:
        """Create every publisher up front from the bag's metadata.yaml, where it lists the topics."""
        for topic, type_name in bag_topics(self.path).items():
            self._publisher(topic, type_name)

    def _restart(self) -> None:
        self._stream = self._messages()
        self._next = next(self._stream, None)
        self._bag_start = self._next[2] if self._next else 0
        self._wall_start = time.monotonic() + self._delay
        self._delay = 0.0

    def _publisher(self, topic: str, type_name: str):
        """The topic's publisher; None (with one warning) for a type this machine has no package for, or a record too
        damaged to name one: its messages are skipped and the rest plays, as ros2 bag play does."""
        if topic in self.publishers_by_topic:
            return self.publishers_by_topic[topic]
        try:
            pub = self.create_publisher(message_class(type_name), relative(topic), SENSOR_QOS)
        except (ImportError, AttributeError, ValueError) as exc:
            self.get_logger().warning(f"{topic}: message type {type_name!r} cannot be played here ({type(exc).__name__}: {exc}); "
                                      "its messages are skipped")
            self.skipped_topics.append(topic)
            pub = None
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
            publisher = self._publisher(topic, type_name)
            if publisher is not None:
                try:
                    publisher.publish(data)
                    self.published += 1
                except RCLError as exc:
                    self.publish_errors += 1
                    if self.publish_errors == 1:
                        self.get_logger().warning(f"{topic}: a message could not be published ({exc}); going on, the count is "
                                                  "given at the end")
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
                self.get_logger().info(f"played {self.published} messages from {self.path}"
                                       + (f"; {self.publish_errors} could not be published" if self.publish_errors else ""))


def replay(bag: str, *, rate: float = 1.0, loop: bool = False, clock: bool = False, ros_args: Sequence[str] = ()) -> int:
    """Play ``bag`` to the end (forever with ``loop``); returns 0, or 1 if the bag was damaged. ``ros_args``: what followed
    --ros-args on the command line (a namespace, remaps, a log level)."""
    rclpy.init(args=["hydro-ros", *ros_args])
    try:
        node = BagPlayer(bag, rate, loop, clock)
    except BaseException:  # a bag it cannot play: refused, and ROS shut down again
        rclpy.shutdown()
        raise
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
