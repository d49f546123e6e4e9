"""recorder: the contract topics of a running machine into a bag, for machines without the ros2 CLI.

``hydro-ros bag record`` runs it. Each topic is subscribed with raw CDR (nothing is deserialised) and
with the reliability its publishers offer, so a best-effort driver is recorded too; the publishers'
QoS goes into the bag's ``offered_qos_profiles``. Log time is the message's header stamp
(docs/interface.md section 2). The bag is split by recording (wall) time, as ``ros2 bag record --max-bag-duration``
does, since header stamps need not arrive in order across topics, and/or by size (bags/writer.py).
Stopping with Ctrl-C or SIGTERM closes the open part and writes metadata.yaml.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import rclpy
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness, QosReliability, QosTime

from hydro_ros.bags.cdr import CdrError, header_stamp_ns
from hydro_ros.bags.writer import BagWriter
from hydro_ros.contract import topics
from hydro_ros.contract.machine import Machine
from hydro_ros.nodes.common import SENSOR_QOS, message_class, relative, stop_signals

DISCOVERY_S = 2.0  # wait for publishers before subscribing, so their QoS is known
BLOCK_LOOK_S = 1.0  # [s] how often the graph is asked for publishers that came late (sample blocks, slow discovery)


def _offered(info: Any) -> Qos:
    """rclpy's TopicEndpointInfo QoS as rosbags' Qos (the rmw enum values are the same numbers)."""
    qos = info.qos_profile

    def duration(value: Any) -> QosTime:
        return QosTime(*divmod(int(value.nanoseconds), 1_000_000_000))

    return Qos(QosHistory(int(qos.history)), int(qos.depth), QosReliability(int(qos.reliability)), QosDurability(int(qos.durability)),
               duration(qos.deadline), duration(qos.lifespan), QosLiveliness(int(qos.liveliness)),
               duration(qos.liveliness_lease_duration), bool(qos.avoid_ros_namespace_conventions))


class Recorder(Node):
    def __init__(self, writer: BagWriter, wanted: dict[str, str]) -> None:
        super().__init__("recorder")
        self.writer = writer
        self.wanted = wanted
        self.counts: dict[str, int] = {}
        self.dropped: dict[str, int] = {}  # per topic: messages without a readable header
        self._handles: dict[str, int] = {}
        self._subscribed: dict[str, Any] = {}

    def subscribe_all(self) -> None:
        """Subscribe to each wanted topic once a publisher offers it, with a QoS that matches what it offers (a reliable
        subscription never matches a best-effort publisher: subscribing before the publisher is known lost every
        message of a loaded machine's slow discovery)."""
        for topic, type_name in self.wanted.items():
            if topic in self._subscribed:
                continue
            name = self.resolve_topic_name(relative(topic))
            offered = self.get_publishers_info_by_topic(name)
            if not offered:
                continue
            qos = SENSOR_QOS
            if all(info.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for info in offered):
                qos = QoSProfile(depth=SENSOR_QOS.depth, reliability=ReliabilityPolicy.BEST_EFFORT)
            self._handles[topic] = self.writer.add_topic(topic, type_name, [_offered(info) for info in offered[:1]])
            self.counts[topic] = 0
            self._subscribed[topic] = self.create_subscription(
                message_class(type_name), relative(topic), lambda data, t=topic: self._on_message(t, data), qos, raw=True)

    def list_unseen(self) -> None:
        """List each wanted topic no publisher offered in the bag, with 0 messages. Without subscribing: a subscription
        created while the node is being stopped is of no use, and one made just before destroy_node is the suspect of a
        recorder that crashed (SIGSEGV) on SIGTERM under load."""
        for topic, type_name in self.wanted.items():
            if topic not in self._handles:
                self._handles[topic] = self.writer.add_topic(topic, type_name)
                self.counts[topic] = 0

    def take_sample_blocks(self) -> None:
        """Subscribe to /hydraulics/sample_block once a node publishes it."""
        if topics.SAMPLE_BLOCK not in self.wanted and self.get_publishers_info_by_topic(self.resolve_topic_name(relative(topics.SAMPLE_BLOCK))):
            self.wanted[topics.SAMPLE_BLOCK] = topics.POINT_CLOUD2_TYPE
            self.subscribe_all()

    def _on_message(self, topic: str, data: bytes) -> None:
        try:
            stamp = header_stamp_ns(data)
        except CdrError as exc:  # not a message of the contract's: nothing to file it under
            self.dropped[topic] = self.dropped.get(topic, 0) + 1
            self.get_logger().error(f"{topic}: message not recorded: {exc}", throttle_duration_sec=10.0)
            return
        self.writer.write(self._handles[topic], stamp, data)
        self.counts[topic] += 1


def record(machine: Machine, out: Path, *, duration_s: float | None, split_duration_s: float | None,
           split_size_bytes: int | None, outputs: bool, progress: Any = None, ros_args: Sequence[str] = ()) -> dict[str, Any]:
    """Record until ``duration_s`` of wall time has passed (None: until Ctrl-C / SIGTERM). ``ros_args``: what followed
    --ros-args on the command line (a namespace, remaps). /hydraulics/sample_block is recorded where a node publishes it
    (a crane's bridge or simulator at 1 kHz sends its samples that way)."""
    wanted = topics.sensor_topics(machine.actuator_names, mobile=machine.mobile)
    if outputs:
        wanted.update({topics.DIAGNOSTICS: "diagnostic_msgs/msg/DiagnosticArray"})
    rclpy.init(args=["hydro-ros", *ros_args], signal_handler_options=SignalHandlerOptions.NO)
    began = time.monotonic()
    try:
        with stop_signals() as stop, BagWriter(out, split_size_bytes=split_size_bytes) as writer:
            # SIGTERM ends a recording as Ctrl-C does: the loop ends, the open part is closed
            writer.custom_data["hydro_ros.recorded"] = f"{machine.name} ({machine.source})"
            node = Recorder(writer, wanted)
            try:
                end = began + DISCOVERY_S
                while time.monotonic() < end and not stop.is_set():
                    rclpy.spin_once(node, timeout_sec=0.1)
                node.subscribe_all()
                started = time.monotonic()
                stop_at = math.inf if duration_s is None else started + duration_s
                next_split = math.inf if split_duration_s is None else started + split_duration_s
                next_look = started
                while rclpy.ok() and not stop.is_set() and time.monotonic() < stop_at:
                    rclpy.spin_once(node, timeout_sec=0.1)
                    if time.monotonic() >= next_look:  # a publisher discovered late, or started after the recorder, is recorded
                        node.take_sample_blocks()
                        node.subscribe_all()
                        next_look += BLOCK_LOOK_S
                    if time.monotonic() >= next_split:
                        writer.split()
                        next_split += split_duration_s
                    if progress is not None:
                        progress(writer.messages)
            finally:
                node.list_unseen()
                counts = dict(node.counts)
                node.destroy_node()
    finally:
        if rclpy.ok():
            rclpy.shutdown()
    return {"bag": str(out), "files": writer.files, "messages": writer.messages, "topics": counts,
            "seconds": round(time.monotonic() - began, 3)}
