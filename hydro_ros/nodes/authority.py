"""Who may speak to a node that moves the machine: messages taken only from a configured source node.

A topic on a ROS graph takes messages from anyone. :class:`PinnedSource` pins one topic of a node to
the publishers of one named node (found through graph introspection) and checks every message's
publisher identity (``MessageInfo.publisher_gid``) against them; a message from any other publisher
is refused and that publisher is named (``foreign``). This stops a stray or careless node; a node
that takes the source's name is stopped only by SROS2 (config/sros2/policy.xml: each node in its
enclave, with only the access it needs).
"""

from __future__ import annotations

import time
from typing import Any

from rclpy.node import Node

UNKNOWN_NODE = "_NODE_NAME_UNKNOWN_"  # rmw's name for an endpoint whose node it has not been told of
GRAPH_REFRESH_S = 0.5  # at most this often the graph is asked again about an unknown publisher


def full_node_name(name: str, namespace: str) -> str:
    """``name`` (relative to ``namespace``, or absolute '/ns/node') as '/ns/node'."""
    if name.startswith("/"):
        return name
    return f"{namespace.rstrip('/')}/{name}"


class PinnedSource:
    """The publishers of node ``source`` on ``topic`` (fully resolved), and every other publisher seen."""

    def __init__(self, node: Node, topic: str, source: str) -> None:
        self.node = node
        self.topic = node.resolve_topic_name(topic)
        self.source = full_node_name(source, node.get_namespace())
        self._names: dict[bytes, str] = {}  # publisher gid -> its node's full name, as of the last refresh
        self._last_refresh = -float("inf")
        self.foreign: dict[str, int] = {}  # full node name -> messages refused from it
        self.refused = 0
        self.unidentified = 0  # messages from a publisher the graph did not (yet) list
        self.last_sender: str | None = None  # the node of the last message checked, None when unidentified

    def refresh(self) -> None:
        self._last_refresh = time.monotonic()
        # an endpoint whose node the graph does not know yet (its discovery info still on the way) stays unknown
        self._names = {bytes(info.endpoint_gid): full_node_name(info.node_name, info.node_namespace)
                       for info in self.node.get_publishers_info_by_topic(self.topic) if info.node_name != UNKNOWN_NODE}

    def accepts(self, info: dict[str, Any] | None) -> bool:
        """Whether the message with this ``MessageInfo`` came from the source; refused ones are counted and named."""
        gid = bytes(((info or {}).get("publisher_gid") or {}).get("data", b""))
        if gid not in self._names and time.monotonic() - self._last_refresh > GRAPH_REFRESH_S:
            self.refresh()
        name = self._names.get(gid)
        self.last_sender = name
        if name == self.source:
            return True
        if name is None:  # not (yet) in the graph: refused, but named only once the graph says whose it is
            self.unidentified += 1
            return False
        self.refused += 1
        self.foreign[name] = self.foreign.get(name, 0) + 1
        return False

    def others(self) -> list[str]:
        """Nodes other than the source publishing on the topic now."""
        return sorted({full_node_name(info.node_name, info.node_namespace)
                       for info in self.node.get_publishers_info_by_topic(self.topic) if info.node_name != UNKNOWN_NODE} - {self.source})
