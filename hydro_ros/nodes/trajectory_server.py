"""trajectory_server: serves the energy-optimal trajectories of the trajectory database.

Topics (docs/interface.md section 1, relative to the node, so ``/trajectory_server/...`` by default):
``~/catalog`` (latched String, JSON list of the stored paths and their solutions' energies),
``~/request`` (String: a path id, or JSON ``{"path": ..., "method": ..., "id": ...}``, or
``{"cancel": id}``), ``~/result`` (latched String, JSON ``{"path", "id", "ok", "error", ...}`` answering
every request, the id echoed) and ``~/trajectory`` (latched JointTrajectory, also published to
``output_topic`` when set, there volatile, in the form a ros2_control JointTrajectoryController
takes on its ``~/joint_trajectory``). A cancel of the trajectory last served publishes an empty
JointTrajectory, which such a controller (and crane_sim) takes as "stop the current one".

A request is served from the manipulator's actual state: the latest ``/joint_states`` must be
younger than ``joint_state_timeout``; when it differs from the stored start the stored DP policy
runs forward from it (``hydro_ros.planning.serving``); the tables are loaded and the forward pass
compiled when the database opens or changes, before the catalog is published. Every failure (unknown path or method, no or
stale joint state, a start the path cannot be run from, a missing, locked or corrupt database)
is answered on ``~/result`` with ``ok: false`` and a one-line error; nothing is published on
``~/trajectory`` then. The database is opened lazily and re-checked every ``poll_period``, so
the server comes up before the first build and republishes the catalog when a build adds to it.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.qos_overriding_options import QoSOverridingOptions
from rclpy.time import Time
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from hydro_ros.bags.cdr import encode_joint_trajectory
from hydro_ros.contract import topics
from hydro_ros.contract.errors import InputError
from hydro_ros.nodes.common import LATCHED_QOS, SENSOR_QOS, relative, run_node
from hydro_ros.nodes.parameters import declare, parameter, specs_of
from hydro_ros.planning.database import DatabaseError, TrajectoryDatabase
from hydro_ros.planning.problem import METHODS
from hydro_ros.planning.serving import JointStateSample, Served, ServeError, TrajectoryService

_MAX_REQUEST_CHARS = 256
REQUEST_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000, reliability=ReliabilityPolicy.RELIABLE)
# results of a burst reach a live requester whole (a writer keeping one would overwrite unacknowledged answers);
# a late joiner gets the recent ones
RESULT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)
_REQUEST_ID = re.compile(r"[A-Za-z0-9_.\-]{0,64}")
OUTPUT_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.VOLATILE)


@dataclass
class TrajectoryServerParameters:
    """trajectory_server's parameters, each declared once with its unit, range and description."""

    database: str = parameter("", "SQLite trajectory database (hydro-ros db build); required, may appear after start")
    output_topic: str = parameter("", "also send the served JointTrajectory here (a controller's input); empty: only ~/trajectory")
    config: str = parameter("", "machine config with a planner: section (YAML): serve only its machine's trajectories; empty: any", existing_file=True)
    method: str = parameter("dp_cp", "solution served when a request names none", choices=tuple(METHODS))
    joint_state_timeout: float = parameter(0.5, "[s] a joint state older than this is not fresh enough to re-plan from", 0.01, 60.0,
                                           read_only=False)
    tip_tolerance: float = parameter(0.05, "[m] the measured tip may be this far from a stored start", 0.0, 10.0, read_only=False)
    poll_period: float = parameter(1.0, "[s] period of checking the database for new data", 0.05, 600.0)


PARAMETERS = specs_of(TrajectoryServerParameters)


class TrajectoryServer(Node):
    def __init__(self) -> None:
        super().__init__("trajectory_server")
        self.params = declare(self, TrajectoryServerParameters, self._on_parameter)
        self.database_path = self.params.database
        self.output_topic = self.params.output_topic
        self.config_path = self.params.config
        self.default_method = self.params.method
        self.joint_state_timeout = self.params.joint_state_timeout
        self.tip_tolerance = self.params.tip_tolerance
        if not self.database_path:
            raise InputError("parameter database: not set (path of the SQLite file hydro-ros db build writes)")
        self.machine = self._machine_of_config()

        self.catalog_pub = self.create_publisher(String, "~/catalog", LATCHED_QOS)
        self.result_pub = self.create_publisher(String, "~/result", RESULT_QOS)
        self.trajectory_pub = self.create_publisher(JointTrajectory, "~/trajectory", LATCHED_QOS)
        # volatile, as a ros2_control JointTrajectoryController subscribes: a controller that (re)starts must
        # never receive an old trajectory and move the machine
        self.output_pub = self.create_publisher(JointTrajectory, self.output_topic, OUTPUT_QOS) if self.output_topic else None
        self.served: tuple[str, str, list[str]] | None = None  # (request id, path, joints) of the trajectory last served
        # every request of a burst is kept and answered (rclpy's depth 10 dropped the rest unanswered)
        self.create_subscription(String, "~/request", self._on_request, REQUEST_QOS)
        self.create_subscription(JointState, relative(topics.JOINT_STATES), self._on_joint_state, SENSOR_QOS,
                                 qos_overriding_options=QoSOverridingOptions.with_default_policies())

        self.service: TrajectoryService | None = None
        self.database_error = "not opened yet"
        self.data_version: int | None = None
        self.joint_state: JointStateSample | None = None
        self.joint_state_time: Time | None = None
        self._poll()
        self.create_timer(self.params.poll_period, self._poll)

    def _on_parameter(self, name: str, value: Any) -> None:
        if name == "joint_state_timeout":
            self.joint_state_timeout = value
        elif name == "tip_tolerance":
            self.tip_tolerance = value

    def _machine_of_config(self) -> str | None:
        if not self.config_path:
            return None
        from hydro_ros.models.crane import load_crane

        _, config = load_crane(self.config_path)
        return config.name

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
                began = time.perf_counter()
                prepared = self.service.prepare()
                self.get_logger().info(f"re-planning ready for {', '.join(prepared) or 'no DP solution'} "
                                       f"({time.perf_counter() - began:.1f} s)")
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

    def _parse_request(self, text: str) -> dict[str, str]:
        """``{"path", "method", "id"}`` or ``{"cancel": id}`` from a bare path id or a JSON object."""
        text = text.strip()
        if not text or len(text) > _MAX_REQUEST_CHARS:
            raise ServeError(f"request {text[:40]!r}: expected a path id or JSON {{\"path\": ..., \"method\": ..., \"id\": ...}}")
        if not text.startswith("{"):
            return {"path": text, "method": self.default_method, "id": ""}
        try:
            request = json.loads(text)
        except json.JSONDecodeError:
            raise ServeError(f"request {text[:40]!r}: not JSON") from None
        if not isinstance(request, dict) or not ("path" in request or "cancel" in request):
            raise ServeError(f"request {text[:40]!r}: JSON without a \"path\" (or \"cancel\")")
        for key in ("path", "method", "id", "cancel"):  # a null or a number is not a name: it is refused, never made one
            if key in request and not isinstance(request[key], str):
                raise ServeError(f"request {key} {json.dumps(request[key])[:40]}: expected a string")
        request_id = request.get("id", request.get("cancel", ""))
        if not _REQUEST_ID.fullmatch(request_id):
            raise ServeError(f"request id {request_id[:40]!r}: expected at most 64 of [A-Za-z0-9_.-]")
        if "cancel" in request:
            return {"cancel": request_id}
        if not request["path"].strip():
            raise ServeError("request path \"\": expected a path id")
        return {"path": request["path"], "method": request.get("method", self.default_method), "id": request_id}

    def _current_state(self) -> JointStateSample:
        if self.joint_state is None or self.joint_state_time is None:
            raise ServeError(f"joint state: nothing received on {topics.JOINT_STATES}; the trajectory must start at the actual state")
        age = (self.get_clock().now() - self.joint_state_time).nanoseconds * 1e-9
        if age > self.joint_state_timeout:
            raise ServeError(f"joint state: stale ({age:.2f} s old, limit {self.joint_state_timeout} s on {topics.JOINT_STATES})")
        return self.joint_state

    # -- requests ----------------------------------------------------------------------------
    def _on_request(self, msg: String) -> None:
        path_id, request_id = msg.data.strip()[:_MAX_REQUEST_CHARS], ""
        try:
            request = self._parse_request(msg.data)
            if "cancel" in request:
                self._cancel(request["cancel"])
                return
            path_id, request_id = request["path"], request["id"]
            if self.service is None:
                self._poll()
            if self.service is None:
                raise ServeError(self.database_error)
            state = self._current_state()
            if self.output_pub is not None and self.output_pub.get_subscription_count() == 0:
                # volatile output: sent now or never, so never into the void
                raise ServeError(f"output {self.output_pub.topic_name}: no subscriber yet (controller not running or not "
                                 f"discovered); nothing sent")
            served = self.service.serve(path_id, request["method"], state)
        except ServeError as exc:
            self._answer({"path": path_id, "id": request_id, "ok": False, "error": str(exc)})
            return
        except DatabaseError as exc:  # damaged, replaced or locked under us: answer, reopen later
            self._drop_database(str(exc))
            self._answer({"path": path_id, "id": request_id, "ok": False, "error": str(exc)})
            return
        self._publish_trajectory(served)
        self.served = (request_id, path_id, list(served.trajectory.joint_names))
        self._answer({**served.result(), "id": request_id})

    def _cancel(self, request_id: str) -> None:
        """Stop the trajectory served for ``request_id``: an empty JointTrajectory, which a ros2_control
        JointTrajectoryController (and crane_sim) take as "stop the current one"."""
        if self.served is None or self.served[0] != request_id or not request_id:
            self._answer({"path": "", "id": request_id, "ok": False, "cancelled": False,
                          "error": f"cancel {request_id!r}: not the trajectory being served (that is "
                                   f"{self.served[0] if self.served else 'none'!r})"})
            return
        _, path_id, joint_names = self.served
        stop = JointTrajectory(joint_names=joint_names)
        stop.header.stamp = self.get_clock().now().to_msg()
        self.trajectory_pub.publish(stop)
        if self.output_pub is not None:
            self.output_pub.publish(stop)
        self.served = None
        self._answer({"path": path_id, "id": request_id, "ok": True, "cancelled": True, "error": ""})

    def _answer(self, result: dict[str, Any]) -> None:
        if not result["ok"]:
            self.get_logger().warning(f"request {result['path']!r} (id {result.get('id', '')!r}): {result['error']}")
        self.result_pub.publish(String(data=json.dumps(result)))

    def _publish_trajectory(self, served: Served) -> None:
        """The trajectory as CDR bytes, encoded once for both topics (rclpy's own conversion costs ~5 ms each)."""
        data = served.trajectory
        raw = encode_joint_trajectory(self.get_clock().now().nanoseconds, "", list(data.joint_names),
                                      np.round(np.asarray(data.time) * 1e9).astype(np.int64), data.positions, data.velocities,
                                      data.accelerations)
        self.trajectory_pub.publish(raw)
        if self.output_pub is not None:
            self.output_pub.publish(raw)


def main(args: list[str] | None = None) -> None:
    run_node(TrajectoryServer, args)


if __name__ == "__main__":
    main()
