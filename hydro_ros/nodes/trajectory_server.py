"""trajectory_server: serves the energy-optimal trajectories of the trajectory database.

Topics (contract section 1, relative to the node, so ``/trajectory_server/...`` by default):
``~/catalog`` (latched String, JSON list of the stored paths and their solutions' energies),
``~/request`` (String: a path id, or JSON ``{"path": ..., "method": ...}``), ``~/result`` (latched
String, JSON ``{"path", "ok", "error", ...}`` answering every request) and ``~/trajectory`` (latched
JointTrajectory, also published to ``output_topic`` when set).

A request is served from the manipulator's actual state: the latest ``/joint_states`` must be
younger than ``joint_state_timeout``; when it differs from the stored start the stored DP policy
runs forward from it (``hydro_ros.planning.serving``). Every failure (unknown path or method, no or
stale joint state, a start the path cannot be run from, a missing, locked or corrupt database)
is answered on ``~/result`` with ``ok: false`` and a one-line error; nothing is published on
``~/trajectory`` then. The database is opened lazily and re-checked every ``poll_period``, so
the server comes up before the first build and republishes the catalog when a build adds to it.
"""

from __future__ import annotations

import json
from typing import Any

from builtin_interfaces.msg import Duration
from rclpy.node import Node
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.nodes.common import LATCHED_QOS, SENSOR_QOS, relative, run_node
from hydro_ros.planning.database import DatabaseError, JointTrajectoryData, TrajectoryDatabase
from hydro_ros.planning.problem import METHODS
from hydro_ros.planning.serving import JointStateSample, Served, ServeError, TrajectoryService

_MAX_REQUEST_CHARS = 256


class TrajectoryServer(Node):
    def __init__(self) -> None:
        super().__init__("trajectory_server")
        self.database_path = str(self.declare_parameter("database", "").value)
        self.output_topic = str(self.declare_parameter("output_topic", "").value)
        self.config_path = str(self.declare_parameter("config", "").value)
        self.default_method = str(self.declare_parameter("method", "dp_cp").value)
        self.joint_state_timeout = float(self.declare_parameter("joint_state_timeout", 0.5).value)
        self.tip_tolerance = float(self.declare_parameter("tip_tolerance", 0.05).value)
        poll_period = float(self.declare_parameter("poll_period", 1.0).value)
        if not self.database_path:
            raise InputError("parameter database: not set (path of the SQLite file hydro-ros db build writes)")
        if self.default_method not in METHODS:
            raise InputError(f"parameter method {self.default_method!r}: unknown (known: {', '.join(METHODS)})")
        self.machine = self._machine_of_config()

        self.catalog_pub = self.create_publisher(String, "~/catalog", LATCHED_QOS)
        self.result_pub = self.create_publisher(String, "~/result", LATCHED_QOS)
        self.trajectory_pub = self.create_publisher(JointTrajectory, "~/trajectory", LATCHED_QOS)
        self.output_pub = self.create_publisher(JointTrajectory, self.output_topic, LATCHED_QOS) if self.output_topic else None
        self.create_subscription(String, "~/request", self._on_request, 10)
        self.create_subscription(JointState, relative(topics.JOINT_STATES), self._on_joint_state, SENSOR_QOS)

        self.service: TrajectoryService | None = None
        self.database_error = "not opened yet"
        self.data_version: int | None = None
        self.joint_state: JointStateSample | None = None
        self.joint_state_time: Time | None = None
        self._poll()
        self.create_timer(poll_period, self._poll)

    def _machine_of_config(self) -> str | None:
        if not self.config_path:
            return None
        from hydro_ros.models.crane import load_crane

        _, config = load_crane(self.config_path)
        return str(config["machine"])

    # -- database ----------------------------------------------------------------------------
    def _poll(self) -> None:
        """Open the database if it is not, and republish the catalog when its content changed."""
        if self.service is None:
            try:
                self.service = TrajectoryService(TrajectoryDatabase(self.database_path), tip_tolerance=self.tip_tolerance)
                self.database_error = ""
                self.get_logger().info(f"database {self.database_path} opened")
            except DatabaseError as exc:
                if str(exc) != self.database_error:
                    self.get_logger().error(str(exc))
                    self.database_error = str(exc)
                    self._publish_catalog([])
                return
        try:
            version = self.service.db.data_version()
            if version != self.data_version:
                self.data_version = version
                self._publish_catalog(self._catalog())
        except DatabaseError as exc:  # the file was replaced or damaged under us: reopen on the next poll
            self._drop_database(str(exc))

    def _drop_database(self, reason: str) -> None:
        self.get_logger().error(reason)
        if self.service is not None:
            self.service.db.close()
        self.service = None
        self.database_error = reason
        self.data_version = None

    def _catalog(self) -> list[dict[str, Any]]:
        assert self.service is not None
        entries = self.service.catalog()
        return [entry for entry in entries if self.machine is None or entry["machine"] == self.machine]

    def _publish_catalog(self, entries: list[dict[str, Any]]) -> None:
        self.catalog_pub.publish(String(data=json.dumps(entries)))

    # -- inputs ------------------------------------------------------------------------------
    def _on_joint_state(self, msg: JointState) -> None:
        self.joint_state = JointStateSample(list(msg.name), list(msg.position), list(msg.velocity))
        self.joint_state_time = self.get_clock().now()

    def _parse_request(self, text: str) -> tuple[str, str]:
        text = text.strip()
        if not text or len(text) > _MAX_REQUEST_CHARS:
            raise ServeError(f"request {text[:40]!r}: expected a path id or JSON {{\"path\": ..., \"method\": ...}}")
        if text.startswith("{"):
            try:
                request = json.loads(text)
                return str(request["path"]), str(request.get("method", self.default_method))
            except (json.JSONDecodeError, KeyError, TypeError):
                raise ServeError(f"request {text[:40]!r}: JSON without a \"path\"") from None
        return text, self.default_method

    def _current_state(self) -> JointStateSample:
        if self.joint_state is None or self.joint_state_time is None:
            raise ServeError(f"joint state: nothing received on {topics.JOINT_STATES}; the trajectory must start at the actual state")
        age = (self.get_clock().now() - self.joint_state_time).nanoseconds * 1e-9
        if age > self.joint_state_timeout:
            raise ServeError(f"joint state: stale ({age:.2f} s old, limit {self.joint_state_timeout} s on {topics.JOINT_STATES})")
        return self.joint_state

    # -- requests ----------------------------------------------------------------------------
    def _on_request(self, msg: String) -> None:
        path_id = msg.data.strip()[:_MAX_REQUEST_CHARS]
        try:
            path_id, method = self._parse_request(msg.data)
            if self.service is None:
                self._poll()
            if self.service is None:
                raise ServeError(self.database_error)
            served = self.service.serve(path_id, method, self._current_state())
        except ServeError as exc:
            self._answer({"path": path_id, "ok": False, "error": str(exc)})
            return
        except DatabaseError as exc:  # damaged, replaced or locked under us: answer, reopen later
            self._drop_database(str(exc))
            self._answer({"path": path_id, "ok": False, "error": str(exc)})
            return
        self._publish_trajectory(served)
        self._answer(served.result())

    def _answer(self, result: dict[str, Any]) -> None:
        if not result["ok"]:
            self.get_logger().warning(f"request {result['path']!r}: {result['error']}")
        self.result_pub.publish(String(data=json.dumps(result)))

    def _publish_trajectory(self, served: Served) -> None:
        msg = trajectory_message(served.trajectory)
        msg.header.stamp = self.get_clock().now().to_msg()
        self.trajectory_pub.publish(msg)
        if self.output_pub is not None:
            self.output_pub.publish(msg)


def trajectory_message(data: JointTrajectoryData) -> JointTrajectory:
    msg = JointTrajectory()
    msg.joint_names = list(data.joint_names)
    for k, t in enumerate(data.time):
        point = JointTrajectoryPoint()
        point.positions = data.positions[k].tolist()
        point.velocities = data.velocities[k].tolist()
        point.accelerations = data.accelerations[k].tolist()
        seconds, nanoseconds = divmod(int(round(float(t) * 1e9)), 1_000_000_000)
        point.time_from_start = Duration(sec=seconds, nanosec=nanoseconds)
        msg.points.append(point)
    return msg


def main(args: list[str] | None = None) -> None:
    run_node(TrajectoryServer, args)


if __name__ == "__main__":
    main()
