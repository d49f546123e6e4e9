"""Helpers for tests that run nodes as real processes on a private localhost DDS domain."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor

from hydro_ros.processes import free_port, node_output, node_process, spin_until  # noqa: F401 - the tests take them from here


@contextmanager
def probe_node(name: str) -> Iterator[rclpy.node.Node]:
    rclpy.init()
    node = rclpy.create_node(name)
    try:
        yield node
    finally:
        node.destroy_node()
        rclpy.shutdown()


@contextmanager
def spinning(node: rclpy.node.Node) -> Iterator[rclpy.node.Node]:
    """Spin a node on a background thread, for tests whose main thread waits on something else (a browser)."""
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    thread = threading.Thread(target=executor.spin, daemon=True)
    thread.start()
    try:
        yield node
    finally:
        executor.shutdown()
        thread.join(timeout=5)


def wait_for(done: Callable[[], bool], timeout: float, period: float = 0.05) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if done():
            return True
        time.sleep(period)
    return False


def port_open(port: int, host: str = "127.0.0.1") -> bool:
    try:
        with socket.create_connection((host, port), timeout=0.5):
            return True
    except OSError:
        return False


def change_state(node: rclpy.node.Node, lifecycle_node: str, transition_id: int) -> bool:
    """Ask a lifecycle node (its full name) for a transition; True when it succeeded."""
    from lifecycle_msgs.msg import Transition
    from lifecycle_msgs.srv import ChangeState

    client = node.create_client(ChangeState, f"{lifecycle_node}/change_state")
    assert client.wait_for_service(20.0), f"{lifecycle_node}/change_state not offered"
    future = client.call_async(ChangeState.Request(transition=Transition(id=transition_id)))
    assert spin_until(node, future.done, 10)
    node.destroy_client(client)
    return future.result().success


def answered(node: rclpy.node.Node, ask: Callable[[], Any], attempts: int = 3, timeout: float = 5.0) -> Any:
    """The result of an idempotent service call, asked again when no answer comes: DDS may report a service before the
    server's response writer has matched this client, and then the first response is lost (seen in loaded full runs)."""
    for _ in range(attempts):
        future = ask()
        if spin_until(node, future.done, timeout):
            return future.result()
    raise AssertionError(f"no answer to {attempts} requests of {timeout:g} s")


def lifecycle_state(node: rclpy.node.Node, lifecycle_node: str) -> str:
    from lifecycle_msgs.srv import GetState

    client = node.create_client(GetState, f"{lifecycle_node}/get_state")
    assert client.wait_for_service(20.0), f"{lifecycle_node}/get_state not offered"
    result = answered(node, lambda: client.call_async(GetState.Request()))
    node.destroy_client(client)
    return result.current_state.label
