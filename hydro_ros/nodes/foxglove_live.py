"""Foxglove live: a read-only Foxglove WebSocket server (foxglove-sdk) inside the hmi node.

foxglove_bridge is C++ and does not install everywhere; this serves the contract topics to Foxglove
with their ros2msg schemas, forwarding the raw CDR the node receives (nothing is deserialised).
/diagnostics, /fdi/residuals (already decimated by fdi_node) and /fdi/halt go out as they arrive;
the 1 kHz sensor streams are sampled at ``rate_hz`` (the newest message of each, as the HMI page
samples /joint_states), a rate a person can watch. Read-only: the server offers no capability, so
clients can neither publish nor call services (the SDK answers a client advertise with an error
status). It listens on loopback only; the hmi node's gate admits clients (Host and Origin checks, a
connection cap, TLS when a certificate and key are given). foxglove-sdk is an optional extra (no rosdep key).
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.node import Node

from hydro_ros.bags.writer import TYPESTORE
from hydro_ros.contract import topics
from hydro_ros.contract.extras import optional_module
from hydro_ros.nodes.common import LATCHED_QOS, LATEST_ONLY_QOS, message_class, relative

FORWARDED = {topics.DIAGNOSTICS: ("diagnostic_msgs/msg/DiagnosticArray", 50), topics.FDI_RESIDUALS: (topics.JOINT_STATE_TYPE, 50),
             topics.FDI_HALT: ("std_msgs/msg/Bool", LATCHED_QOS)}


class FoxgloveLive:
    """The server, one channel per topic, and the subscriptions that feed it."""

    def __init__(self, node: Node, sampler: Node, sensor_topics: dict[str, str], *, rate_hz: float) -> None:
        foxglove = optional_module("foxglove")
        self.node = node
        self.context = foxglove.Context()
        # on loopback only: clients reach it through the hmi's gate (hmi.server.foxglove_gate), which checks Host and
        # Origin and caps the connections (the SDK has no hook for either), and carries the TLS
        self.server = foxglove.start_server(name=f"hydro_ros {node.get_fully_qualified_name()}", host="127.0.0.1", port=0,
                                            capabilities=[], context=self.context)
        self.port = self.server.port
        self.forwarded = 0
        self.channels: dict[str, Any] = {}
        for topic, (msgtype, qos) in FORWARDED.items():
            channel = self._channel(topic, msgtype, foxglove)
            node.create_subscription(message_class(msgtype), relative(topic), lambda data, c=channel: self._log(c, data), qos, raw=True)
        self._sampled = []
        for topic, msgtype in sensor_topics.items():
            channel = self._channel(topic, msgtype, foxglove)
            subscription = sampler.create_subscription(message_class(msgtype), relative(topic), lambda _: None, LATEST_ONLY_QOS, raw=True)
            self._sampled.append((channel, subscription, message_class(msgtype)))
        node.create_timer(1.0 / rate_hz, self._sample)

    def _channel(self, topic: str, msgtype: str, foxglove: Any) -> Any:
        definition, _ = TYPESTORE.generate_msgdef(msgtype, ros_version=2)
        name = self.node.resolve_topic_name(relative(topic))
        channel = foxglove.Channel(name, schema=foxglove.Schema(name=msgtype, encoding="ros2msg", data=definition.encode()),
                                   message_encoding="cdr", context=self.context)
        self.channels[name] = channel
        return channel

    def _log(self, channel: Any, data: bytes) -> None:
        channel.log(data, log_time=time.time_ns())
        self.forwarded += 1

    def _sample(self) -> None:
        for channel, subscription, msg_type in self._sampled:
            with subscription.handle:
                taken = subscription.handle.take_message(msg_type, True)
            if taken is not None:
                self._log(channel, taken[0])

    def close(self) -> None:
        self.server.stop()
