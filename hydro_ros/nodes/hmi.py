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
import logging
import os
import sys
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import rclpy
from aiohttp import web
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node
from sensor_msgs.msg import JointState
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger

from hydro_ros.bags.cdr import CdrError, decode_joint_state
from hydro_ros.contract import topics
from hydro_ros.contract.config import default_config_path, read_config
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.hmi.server import GUARD_KEY, QuietBadRequests, create_app, foxglove_gate
from hydro_ros.hmi.state import HmiState, StatusReport
from hydro_ros.nodes.common import (
    LATCHED_QOS,
    LATEST_ONLY_QOS,
    MACHINE_ID,
    machine_instance,
    namespaced_statuses,
    own_statuses,
    relative,
    run_node,
    without_node_name,
)
from hydro_ros.nodes.foxglove_live import FoxgloveLive
from hydro_ros.nodes.parameters import declare, declared, parameter, specs_of

TOKEN_ENV = "HYDRO_ROS_HMI_TOKEN"


class WebServerThread:
    """An aiohttp application on its own event loop thread; bind errors surface in the constructor."""

    def __init__(self, app: web.Application, host: str, port: int, ssl_context: Any = None) -> None:
        self.loop = asyncio.new_event_loop()
        logging.getLogger("aiohttp.server").addFilter(QuietBadRequests())
        # open websockets (a page) are closed within half a second on shutdown, not aiohttp's default minute
        self.runner = web.AppRunner(app, access_log=None, handle_signals=False, shutdown_timeout=0.5)
        self.loop.run_until_complete(self.runner.setup())
        site = web.TCPSite(self.runner, host, port, ssl_context=ssl_context)
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


@dataclass
class HmiNodeParameters:
    """hmi's parameters, each declared once with its unit, range and description."""

    machine_id: str = declared(MACHINE_ID)
    config: str = parameter(str(default_config_path("sam")), "machine config (YAML): its actuators get tiles before their first status",
                            existing_file=True)
    host: str = parameter("127.0.0.1", "address the page listens on; beyond loopback only with a token on a trusted network")
    port: int = parameter(8080, "TCP port of the page (0: any free port)", 0, 65535)
    operator_token: str = parameter("", "token for operator actions; prefer HYDRO_ROS_HMI_TOKEN in the environment, since anyone on "
                                        "the graph can read a parameter; empty and no variable: the page is read-only")
    update_rate: float = parameter(5.0, "[Hz] page state pushes", 0.1, 50.0)
    plot_window: float = parameter(60.0, "[s] residual history on the page", 1.0, 3600.0)
    plot_rate: float = parameter(10.0, "[Hz] residual points kept per second", 0.1, 100.0)
    stale_timeout: float = parameter(3.0, "[s] an actuator without a status this long shows STALE", 0.1, 600.0)
    action_timeout: float = parameter(5.0, "[s] wait for fdi_node to answer an acknowledge", 0.1, 60.0)
    alarm_log: str = parameter("", "fdi_node's alarm log (its parameter alarm_log), shown paged on the page; empty: none")
    allowed_hosts: str = parameter("", "comma-separated host names the page may be reached by besides loopback and host (the Host "
                                       "header is checked against DNS rebinding); e.g. the machine's name on the plant network")
    foxglove_port: int = parameter(8765, "TCP port of the read-only Foxglove WebSocket server (0: any free port, -1: no server; "
                                         "needs the optional foxglove-sdk)", -1, 65535)
    foxglove_host: str = parameter("127.0.0.1", "address the Foxglove server listens on")
    foxglove_origins: str = parameter("", "comma-separated Origin values a browser may connect to the Foxglove server from (e.g. "
                                          "https://app.foxglove.dev); clients without an Origin (the desktop app) and loopback origins "
                                          "are always admitted, any other origin refused (a hostile page in the operator's browser)")
    foxglove_rate: float = parameter(10.0, "[Hz] rate the 1 kHz sensor topics are sampled at for Foxglove", 0.1, 100.0)
    foxglove_tls_cert: str = parameter("", "PEM certificate for TLS on the Foxglove server (with foxglove_tls_key); empty: plain",
                                       existing_file=True)
    foxglove_tls_key: str = parameter("", "PEM private key of foxglove_tls_cert", existing_file=True)
    fdi_node: str = parameter("fdi_node", "name of the monitor node (relative: in this node's namespace)")
    trajectory_server: str = parameter("trajectory_server", "name of the trajectory server node (relative: in this node's namespace)")


PARAMETERS = specs_of(HmiNodeParameters)


HMI_STATUS = "hydro_ros/hmi"
REFUSAL_COUNTS = ("refused_hosts", "refused_origins", "refused_requests", "token_failures", "rate_limited")
OK, WARN = DiagnosticStatus.OK, DiagnosticStatus.WARN


class HmiNode(Node):
    def __init__(self) -> None:
        super().__init__("hmi")
        # the monitored machine: its actuators get tiles before their first status (a config without actuators has none)
        self.params = declare(self, HmiNodeParameters)
        config = read_config(self.params.config, required=("machine",), nonempty="machine")
        host, port = self.params.host, self.params.port
        token = self.params.operator_token or os.environ.get(TOKEN_ENV, "")
        update_rate, plot_rate = self.params.update_rate, self.params.plot_rate
        plot_window, stale_timeout = self.params.plot_window, self.params.stale_timeout
        self.action_timeout = self.params.action_timeout
        fdi_node = self.params.fdi_node.rstrip("/")
        server = self.params.trajectory_server.rstrip("/")

        self.state = HmiState(plot_window_s=plot_window, plot_period_s=1.0 / plot_rate, stale_timeout_s=stale_timeout)
        self.state.expect(str(config["machine"]), list(config.get("actuators") or {}))
        self.create_subscription(DiagnosticArray, relative(topics.DIAGNOSTICS), self._on_diagnostics, 50)
        self.create_subscription(JointState, relative(topics.FDI_RESIDUALS), self._on_residuals, 50)
        self.create_subscription(Bool, relative(topics.FDI_HALT), lambda m: self.state.on_halt(bool(m.data)), LATCHED_QOS)
        self.create_subscription(String, f"{server}/catalog", lambda m: self.state.on_catalog(m.data), LATCHED_QOS)
        self.create_subscription(String, f"{server}/result", lambda m: self.state.on_result(m.data), LATCHED_QOS)
        # /joint_states comes at 1 kHz and the page shows its newest sample: a node that is never spun holds a
        # depth-1 subscription, and the timer takes from it (as rclpy's wait_for_message does), so no callback
        # runs per message
        # named apart from this node: the process's node-name remap (launch's name) is not passed on, its other arguments are
        self._sampler = rclpy.create_node("hmi_joint_state_sampler", namespace=self.get_namespace(), context=self.context,
                                          use_global_arguments=False, cli_args=without_node_name(sys.argv))
        self._joint_states = self._sampler.create_subscription(JointState, relative(topics.JOINT_STATES), lambda _: None, LATEST_ONLY_QOS,
                                                               raw=True)
        self.create_timer(1.0 / update_rate, self._sample_joint_state)
        self.acknowledge_client = self.create_client(Trigger, f"{fdi_node}/acknowledge")
        self.request_publisher = self.create_publisher(String, f"{server}/request", 10)

        allowed = {name.strip() for name in self.params.allowed_hosts.split(",") if name.strip()}
        if not _is_wildcard(host):
            allowed.add(host)
        if not _is_wildcard(self.params.foxglove_host):
            allowed.add(self.params.foxglove_host)
        self.allowed_hosts = frozenset(allowed)
        app = create_app(self.state, self, token=token, update_period_s=1.0 / update_rate, log=self.get_logger().info,
                         allowed_hosts=self.allowed_hosts, alarm_log=Path(self.params.alarm_log) if self.params.alarm_log else None)
        self.guard = app[GUARD_KEY]
        self.machine = machine_instance(self, str(config["machine"]))
        self.pub_diag = self.create_publisher(DiagnosticArray, relative(topics.DIAGNOSTICS), 10)
        self.create_timer(1.0, self._publish_diagnostics)
        self.web = WebServerThread(app, host, port)
        self.foxglove = self._start_foxglove(config)
        self.url = f"http://{host if ':' not in host else f'[{host}]'}:{self.web.port}/"
        access = "operator actions need the token" if token else f"read-only: no operator token, set {TOKEN_ENV}"
        self.get_logger().info(f"HMI on {self.url} ({access})")
        if not _is_loopback(host):
            self.get_logger().warning(f"HMI listens on {host}, beyond this machine: use a token and a trusted network")

    def _start_foxglove(self, config: dict[str, Any]) -> FoxgloveLive | None:
        """The Foxglove server, or None with the reason logged: the HMI page never depends on it."""
        if self.params.foxglove_port < 0:
            return None
        try:
            machine = load_machine_config(self.params.config)
            sensors = topics.sensor_topics(machine.actuator_names, mobile=machine.mobile)
        except InputError:  # a machine described for the planner only (crane3dof: no valves or sensors): its joints, supply and commands
            sensors = topics.sensor_topics([])
        cert, key = self.params.foxglove_tls_cert, self.params.foxglove_tls_key
        try:
            if bool(cert) != bool(key):
                raise InputError("parameters foxglove_tls_cert and foxglove_tls_key: give both or neither")
            live = FoxgloveLive(self, self._sampler, sensors, rate_hz=self.params.foxglove_rate)
        except InputError as exc:
            self.get_logger().warning(f"no Foxglove server: {exc}")
            return None
        except RuntimeError as exc:  # foxglove-sdk could not start
            self.get_logger().warning(f"no Foxglove server: {exc}")
            return None
        context = None
        if cert:
            import ssl

            context = ssl.create_default_context(ssl.Purpose.CLIENT_AUTH)
            context.load_cert_chain(cert, key)
        origins = frozenset(o.strip().lower() for o in self.params.foxglove_origins.split(",") if o.strip())
        try:
            self.foxglove_gate = WebServerThread(foxglove_gate(live.port, allowed_hosts=self.allowed_hosts, allowed_origins=origins),
                                                 self.params.foxglove_host, self.params.foxglove_port, context)
        except InputError as exc:
            live.close()
            self.get_logger().warning(f"no Foxglove server: {exc}")
            return None
        live.port = self.foxglove_gate.port
        scheme = "wss" if cert else "ws"
        self.get_logger().info(f"Foxglove: {scheme}://{self.params.foxglove_host}:{live.port} (read-only, {len(live.channels)} topics)")
        return live

    def _publish_diagnostics(self) -> None:
        counts = dict(self.guard.counts)
        limited = sum(1 for client in list(self.guard.failures) if self.guard.wait_s(client) > 0)
        guessed = self.guard.guessed()
        level, message = ((WARN, "token guesses from many addresses: every check slowed" if guessed else
                           f"token guesses slowed from {limited} client(s)") if limited or guessed else (OK, "ok"))
        values = {"url": self.url, **{key: str(counts.get(key, 0)) for key in REFUSAL_COUNTS}, "clients_rate_limited": str(limited),
                  "foxglove_port": str(self.foxglove.port) if self.foxglove else "off",
                  "foxglove_forwarded": str(self.foxglove.forwarded) if self.foxglove else "0"}
        status = DiagnosticStatus(level=level, name=HMI_STATUS, message=message, hardware_id=self.machine,
                                  values=[KeyValue(key=key, value=value) for key, value in values.items()])
        array = DiagnosticArray(status=namespaced_statuses(self, [status]))
        array.header.stamp = self.get_clock().now().to_msg()
        self.pub_diag.publish(array)

    # -- graph -> state ----------------------------------------------------------------------
    def _on_diagnostics(self, msg: DiagnosticArray) -> None:
        stamp = msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9
        prefix = len(self.get_namespace().strip("/") + "/") if self.get_namespace() != "/" else 0
        self.state.on_diagnostics(stamp, [
            StatusReport(s.name[prefix:], s.level[0], s.message, s.hardware_id,  # `byte level` is bytes in rclpy
                         {v.key: v.value for v in s.values})
            for s in own_statuses(self, msg.status)])

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
        except TimeoutError:
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
        if self.foxglove is not None:
            self.foxglove_gate.close()
            self.foxglove.close()
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


def _is_wildcard(host: str) -> bool:
    return host in ("", "0.0.0.0", "::")


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
