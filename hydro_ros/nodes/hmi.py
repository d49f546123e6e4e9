"""hmi: the operator's web page for the machine, served from the ROS graph (no ROS needed in the browser).

Subscribes to /diagnostics, /fdi/residuals, the latched /fdi/halt, /joint_states and the trajectory
server's latched ``catalog`` and ``result``; serves http://<host>:<port>/ (``hydro_ros.hmi.server``)
with per-actuator health tiles, the alarm list, residual plots, the halt state and the catalog.
Operator actions call ``<fdi_node>/acknowledge`` (std_srvs/Trigger) and publish on
``<trajectory_server>/request``; they need the operator token (parameter ``operator_token`` or the
environment variable ``HYDRO_ROS_HMI_TOKEN``; without one the page is read-only).

The web server runs on its own asyncio thread; rclpy spins in the main thread as every node here does.
/joint_states arrives at 1 kHz: only its newest sample is taken, raw, once per update (no callback per message).
"""

from __future__ import annotations

import asyncio
import ipaddress
import json
import os
import threading
from typing import Any

import rclpy
from aiohttp import web
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from hydro_ros.bags.cdr import CdrError, decode_joint_state
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path, read_config
from hydro_ros.contract.errors import InputError
from hydro_ros.hmi.server import create_app
from hydro_ros.hmi.state import HmiState, StatusReport
from hydro_ros.nodes.common import LATCHED_QOS, run_node

TOKEN_ENV = "HYDRO_ROS_HMI_TOKEN"
# the page shows the newest joint state only: a shallow best-effort queue, nothing to catch up on
LATEST_ONLY_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.BEST_EFFORT)


class WebServerThread:
    """An aiohttp application on its own event loop thread; bind errors surface in the constructor."""

    def __init__(self, app: web.Application, host: str, port: int) -> None:
        self.loop = asyncio.new_event_loop()
        self.runner = web.AppRunner(app, access_log=None, handle_signals=False)
        self.loop.run_until_complete(self.runner.setup())
        site = web.TCPSite(self.runner, host, port)
        try:
            self.loop.run_until_complete(site.start())
        except OSError as exc:
            self.loop.run_until_complete(self.runner.cleanup())
            self.loop.close()
            raise InputError(f"parameters host={host!r} port={port}: cannot listen ({exc.strerror or exc})") from None
        self.port = int(self.runner.addresses[0][1])
        self.thread = threading.Thread(target=self.loop.run_forever, name="hmi-http", daemon=True)
        self.thread.start()

    def run(self, coroutine: Any) -> asyncio.Future:
        """Schedule a coroutine on the server's loop from another thread."""
        return asyncio.run_coroutine_threadsafe(coroutine, self.loop)

    def close(self) -> None:
        self.run(self.runner.cleanup()).result(timeout=5.0)
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(timeout=5.0)
        self.loop.close()


class HmiNode(Node):
    def __init__(self) -> None:
        super().__init__("hmi")
        # the monitored machine: its actuators get tiles before their first status (a crane config has none)
        config = read_config(str(self.declare_parameter("config", str(default_config_path("sam"))).value), required=("machine",),
                             nonempty="machine")
        host = str(self.declare_parameter("host", "127.0.0.1").value)
        port = int(self.declare_parameter("port", 8080).value)
        token = str(self.declare_parameter("operator_token", "").value) or os.environ.get(TOKEN_ENV, "")
        update_rate = float(self.declare_parameter("update_rate", 5.0).value)
        plot_window = float(self.declare_parameter("plot_window", 60.0).value)
        plot_rate = float(self.declare_parameter("plot_rate", 10.0).value)
        stale_timeout = float(self.declare_parameter("stale_timeout", 3.0).value)
        self.action_timeout = float(self.declare_parameter("action_timeout", 5.0).value)
        fdi_node = str(self.declare_parameter("fdi_node", "/fdi_node").value).rstrip("/")
        server = str(self.declare_parameter("trajectory_server", "/trajectory_server").value).rstrip("/")
        for name, value in (("update_rate", update_rate), ("plot_rate", plot_rate), ("action_timeout", self.action_timeout)):
            if not value > 0:
                raise InputError(f"parameter {name}={value}: must be > 0")
        if not 0 <= port <= 65535:
            raise InputError(f"parameter port={port}: not a TCP port")

        self.state = HmiState(plot_window_s=plot_window, plot_period_s=1.0 / plot_rate, stale_timeout_s=stale_timeout)
        self.state.expect(str(config["machine"]), list(config.get("actuators") or {}))
        self.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, self._on_diagnostics, 50)
        self.create_subscription(JointState, topics.FDI_RESIDUALS, self._on_residuals, 50)
        self.create_subscription(Bool, topics.FDI_HALT, lambda m: self.state.on_halt(bool(m.data)), LATCHED_QOS)
        self.create_subscription(String, f"{server}/catalog", lambda m: self.state.on_catalog(m.data), LATCHED_QOS)
        self.create_subscription(String, f"{server}/result", lambda m: self.state.on_result(m.data), LATCHED_QOS)
        # /joint_states comes at 1 kHz and the page shows its newest sample: a node that is never spun holds a
        # depth-1 subscription, and the timer takes from it (as rclpy's wait_for_message does), so no callback
        # runs per message
        self._sampler = rclpy.create_node("hmi_joint_state_sampler", context=self.context)
        self._joint_states = self._sampler.create_subscription(JointState, topics.JOINT_STATES, lambda _: None, LATEST_ONLY_QOS,
                                                               raw=True)
        self.create_timer(1.0 / update_rate, self._sample_joint_state)
        self.acknowledge_client = self.create_client(Trigger, f"{fdi_node}/acknowledge")
        self.request_publisher = self.create_publisher(String, f"{server}/request", 10)

        app = create_app(self.state, self, token=token, update_period_s=1.0 / update_rate, log=self.get_logger().info)
        self.web = WebServerThread(app, host, port)
        self.url = f"http://{host if ':' not in host else f'[{host}]'}:{self.web.port}/"
        access = "operator actions need the token" if token else f"read-only: no operator token, set {TOKEN_ENV}"
        self.get_logger().info(f"HMI on {self.url} ({access})")
        if not _is_loopback(host):
            self.get_logger().warning(f"HMI listens on {host}, beyond this machine: use a token and a trusted network")

    # -- graph -> state ----------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        self.state.on_diagnostics(stamp, [
            StatusReport(s.name, s.level[0], s.message, s.hardware_id,  # `byte level` is bytes in rclpy
                         {v.key: v.value for v in s.values})
            for s in msg.status])

    def _on_residuals(self, msg: JointState) -> None:
        self.state.on_residuals(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9, list(msg.name), list(msg.position))

    def _sample_joint_state(self) -> None:
        with self._joint_states.handle:
            taken = self._joint_states.handle.take_message(JointState, True)
        if taken is None:
            return
        try:
            stamp, names, position, _ = decode_joint_state(taken[0])
        except CdrError as exc:
            self.get_logger().warning(f"{topics.JOINT_STATES}: undecodable message ({exc})", throttle_duration_sec=10.0)
            return
        self.state.on_joint_state(stamp * 1e-9, names, list(position))

    # -- operator actions (called on the web server's loop) ---------------------------------
    async def acknowledge(self) -> tuple[bool, str]:
        service = self.acknowledge_client.srv_name
        if not self.acknowledge_client.service_is_ready():
            return False, f"service {service} is not available (is fdi_node running?)"
        future = self.acknowledge_client.call_async(Trigger.Request())
        loop = asyncio.get_running_loop()
        answered: asyncio.Future = loop.create_future()
        future.add_done_callback(lambda f: loop.call_soon_threadsafe(_settle, answered, f))
        try:
            response = await asyncio.wait_for(answered, self.action_timeout)
        except asyncio.TimeoutError:
            self.acknowledge_client.remove_pending_request(future)
            return False, f"service {service} did not answer within {self.action_timeout:g} s"
        return bool(response.success), str(response.message)

    async def request_path(self, path: str, method: str) -> tuple[bool, str]:
        topic = self.request_publisher.topic_name
        if self.request_publisher.get_subscription_count() == 0:
            return False, f"no trajectory server subscribes to {topic}"
        self.request_publisher.publish(String(data=json.dumps({"path": path, "method": method})))
        return True, f"requested {path} ({method}) on {topic}; the answer appears under the catalog"

    def destroy_node(self) -> None:
        self.web.close()
        self._sampler.destroy_node()
        super().destroy_node()


def _settle(answered: asyncio.Future, future: Any) -> None:
    if answered.done():
        return
    if future.exception() is not None:
        answered.set_exception(future.exception())
    else:
        answered.set_result(future.result())


def _is_loopback(host: str) -> bool:
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def main(args: list[str] | None = None) -> None:
    run_node(HmiNode, args)


if __name__ == "__main__":
    main()
