"""Nodes as separate processes on the local graph, as the tests and the benchmarks start them."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

import psutil


@contextmanager
def node_process(module: str, *ros_args: str) -> Iterator[subprocess.Popen]:
    """``python -m module --ros-args ...`` in this environment (its ROS_DOMAIN_ID), terminated on leaving, killed if it
    will not end. Its output goes to a file, read with ``node_output``: a pipe nobody drains fills at 64 kB and then
    stops the node at its next log line."""
    with tempfile.TemporaryFile() as log:
        proc = subprocess.Popen([sys.executable, "-m", module, "--ros-args", *ros_args], env=dict(os.environ), stdout=log,
                                stderr=subprocess.STDOUT)
        proc.log = log
        try:
            yield proc
        finally:
            proc.terminate()
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.final_output = node_output(proc)


def node_output(proc: subprocess.Popen) -> str:
    """What a ``node_process`` has written, stdout and stderr: so far while it runs, all of it once it has ended. Read at
    an offset (pread), never by seeking: the node writes through the same open file, and a seek would move its writes."""
    if hasattr(proc, "final_output"):
        return proc.final_output
    descriptor = proc.log.fileno()
    return os.pread(descriptor, os.fstat(descriptor).st_size, 0).decode(errors="replace")


def free_port() -> int:
    """A TCP port on loopback nobody listens on now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def spin_until(node: Any, done: Callable[[], bool], timeout: float) -> bool:
    """Spin an rclpy node until ``done()`` or ``timeout`` seconds; whether it was done."""
    import rclpy

    end = time.monotonic() + timeout
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        if done():
            return True
    return False


def cpu_seconds(process: psutil.Process) -> float:
    times = process.cpu_times()
    return times.user + times.system


def live_cpu_share(domain: int, commands: list[list[str]], status: str, progress_key: str, measure_s: float
                   ) -> tuple[float, float, dict, dict]:
    """Start node processes (module, ROS args) on a private localhost domain, wait until the ``/diagnostics`` status
    ``status`` counts ``progress_key`` past 2000, then measure the last process's CPU time over ``measure_s``: (CPU
    share of one core, wall s, the status's values at the start and at the end)."""
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray

    os.environ.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    procs = [subprocess.Popen([sys.executable, "-m", c[0], "--ros-args", *c[1:]], env=dict(os.environ), stdout=subprocess.DEVNULL,
                              stderr=subprocess.DEVNULL) for c in commands]
    rclpy.init()
    node = rclpy.create_node("bench_probe")
    statuses: list = []
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: statuses.extend(s for s in m.status if s.name == status), 10)
    measured = psutil.Process(procs[-1].pid)
    try:
        end = time.monotonic() + 30.0
        while time.monotonic() < end and not any(int({v.key: v.value for v in s.values}[progress_key]) > 2000 for s in statuses):
            rclpy.spin_once(node, timeout_sec=0.1)
        cpu0, wall0, first = cpu_seconds(measured), time.monotonic(), statuses[-1]
        while time.monotonic() < wall0 + measure_s:
            rclpy.spin_once(node, timeout_sec=0.1)
        cpu1, wall1, last = cpu_seconds(measured), time.monotonic(), statuses[-1]
    finally:
        node.destroy_node()
        rclpy.shutdown()
        for proc in procs:
            proc.terminate()
            proc.wait(timeout=10)
    values = [{v.key: v.value for v in s.values} for s in (first, last)]
    return (cpu1 - cpu0) / (wall1 - wall0), wall1 - wall0, values[0], values[1]
