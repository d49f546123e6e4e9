"""trajectory_server on a real DDS graph: a client at some joint state requests paths."""

from __future__ import annotations

import json

import numpy as np
import pytest
from sensor_msgs.msg import JointState
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory

from hydro_ros.contract import topics
from hydro_ros.models.crane import Crane
from hydro_ros.nodes.common import LATCHED_QOS
from hydro_ros.planning.catalog import build, plan_units
from hydro_ros.planning.database import TrajectoryDatabase
from hydro_ros.planning.serving import path_start_state
from hydro_ros.planning.trajectory import LIMIT_TOLERANCE
from test.conftest import K70M
from test.ros_graph import node_process, probe_node, spin_until


@pytest.fixture(scope="module")
def catalog_db(tmp_path_factory, k70m):
    config = k70m
    path = tmp_path_factory.mktemp("server") / "catalog.db"
    with TrajectoryDatabase(path, writable=True) as db:
        build(db, plan_units(config, methods=("dp_cp", "pinv_actuator"), grid=(80, 31, 31), paths=("horizontal",)), workers=1)
    return path, config


def _limits_hold(config: dict, msg: JointTrajectory) -> None:
    crane = Crane(config)
    q = np.array([p.positions for p in msg.points])
    qd = np.array([p.velocities for p in msg.points])
    for i, cylinder in enumerate(crane.cylinders):
        span = (cylinder.q_max - cylinder.q_min) * LIMIT_TOLERANCE
        assert cylinder.q_min - span <= q[:, i].min() and q[:, i].max() <= cylinder.q_max + span, cylinder.name
        arm, _ = cylinder.arm(q[:, i])
        assert np.abs(arm * qd[:, i]).max() <= cylinder.velocity_max * (1 + LIMIT_TOLERANCE), cylinder.name


def test_server_serves_from_the_clients_joint_state_and_refuses_unknown_paths(ros_domain, catalog_db):
    db_path, config = catalog_db
    with TrajectoryDatabase(db_path) as db:
        stored_start = db.solution("horizontal", "dp_cp").start_position
    q0 = path_start_state(config, "horizontal", stored_start + 0.3)
    received: dict[str, list] = {"catalog": [], "result": [], "trajectory": [], "output": []}
    with node_process("hydro_ros.nodes.trajectory_server", "-p", f"database:={db_path}", "-p", f"config:={K70M}",
                      "-p", "output_topic:=/crane/joint_trajectory") as proc, probe_node("client") as node:
        node.create_subscription(String, "/trajectory_server/catalog", lambda m: received["catalog"].append(m), LATCHED_QOS)
        node.create_subscription(String, "/trajectory_server/result", lambda m: received["result"].append(json.loads(m.data)), LATCHED_QOS)
        node.create_subscription(JointTrajectory, "/trajectory_server/trajectory", lambda m: received["trajectory"].append(m), LATCHED_QOS)
        # volatile, as a ros2_control controller subscribes (a latched subscription would not match)
        node.create_subscription(JointTrajectory, "/crane/joint_trajectory", lambda m: received["output"].append(m), 10)
        requests = node.create_publisher(String, "/trajectory_server/request", 10)
        joints = node.create_publisher(JointState, topics.JOINT_STATES, 10)
        assert spin_until(node, lambda: received["catalog"], 30), proc.stdout.read() if proc.poll() is not None else "no catalog"
        catalog = json.loads(received["catalog"][-1].data)
        assert [entry["path"] for entry in catalog if entry["solutions"]] == ["horizontal"]

        # no joint state yet: a clear error, no trajectory
        assert spin_until(node, lambda: requests.get_subscription_count() > 0, 10)
        requests.publish(String(data="horizontal"))
        assert spin_until(node, lambda: received["result"], 10)
        assert not received["result"][-1]["ok"] and "nothing received" in received["result"][-1]["error"]

        def publish_state() -> None:
            joints.publish(JointState(name=config_joint_names(config), position=q0.tolist(), velocity=[0.0] * 4))

        node.create_timer(0.05, publish_state)
        assert spin_until(node, lambda: joints.get_subscription_count() > 0 and node.count_publishers("/crane/joint_trajectory") > 0, 10)
        for method in ("dp_cp", "pinv_actuator"):
            count = len(received["result"])
            spin_until(node, lambda: False, 0.3)  # a fresh joint state has arrived
            requests.publish(String(data=json.dumps({"path": "horizontal", "method": method})))
            assert spin_until(node, lambda: len(received["result"]) > count and len(received["trajectory"]) >= 1, 20)
            result = received["result"][-1]
            assert result["ok"], result
            assert result["replanned"] and result["method"] == method
            msg = received["trajectory"][-1]
            assert msg.joint_names == ["base", "lift", "tilt", "extension"]
            np.testing.assert_allclose(msg.points[0].positions, q0, atol=1e-3)  # starts where the client is
            _limits_hold(config, msg)
            assert len(msg.points) == result["points"]
        assert spin_until(node, lambda: received["output"], 5)

        # a request with an id, echoed; cancelling it sends the empty trajectory that stops a controller
        count, outputs = len(received["result"]), len(received["output"])
        requests.publish(String(data=json.dumps({"path": "horizontal", "id": "run-7"})))
        assert spin_until(node, lambda: len(received["result"]) > count and len(received["output"]) > outputs, 20)
        assert received["result"][-1]["ok"] and received["result"][-1]["id"] == "run-7"
        for wrong in ("run-6", "run 7!"):
            count = len(received["result"])
            requests.publish(String(data=json.dumps({"cancel": wrong})))
            assert spin_until(node, lambda: len(received["result"]) > count, 10)
            assert not received["result"][-1]["ok"], wrong
        count, outputs = len(received["result"]), len(received["output"])
        requests.publish(String(data=json.dumps({"cancel": "run-7"})))
        assert spin_until(node, lambda: len(received["result"]) > count and len(received["output"]) > outputs, 10)
        assert received["result"][-1] == {"path": "horizontal", "id": "run-7", "ok": True, "cancelled": True, "error": ""}
        stop = received["output"][-1]
        assert stop.points == [] and list(stop.joint_names) == ["base", "lift", "tilt", "extension"]

        count = len(received["result"])
        requests.publish(String(data="nowhere"))
        assert spin_until(node, lambda: len(received["result"]) > count, 10)
        assert received["result"][-1] == {"path": "nowhere", "id": "", "ok": False, "error": received["result"][-1]["error"]}
        assert "not in the database" in received["result"][-1]["error"]


def config_joint_names(config: dict) -> list[str]:
    return [joint["name"] for joint in config["joints"]]


def test_server_answers_with_an_error_when_the_database_is_corrupt(ros_domain, tmp_path):
    broken = tmp_path / "broken.db"
    broken.write_bytes(b"\x00garbage" * 512)
    results: list[dict] = []
    with node_process("hydro_ros.nodes.trajectory_server", "-p", f"database:={broken}"), probe_node("client") as node:
        node.create_subscription(String, "/trajectory_server/result", lambda m: results.append(json.loads(m.data)), LATCHED_QOS)
        requests = node.create_publisher(String, "/trajectory_server/request", 10)
        assert spin_until(node, lambda: requests.get_subscription_count() > 0, 20)
        requests.publish(String(data="horizontal"))
        assert spin_until(node, lambda: results, 10)
    assert not results[-1]["ok"] and "corrupt or not an SQLite file" in results[-1]["error"]


def test_served_trajectory_runs_on_the_simulated_crane(ros_domain, catalog_db):
    """Server -> output_topic -> crane_sim, both in a namespace: the run reports its energy and path accuracy."""
    db_path, _ = catalog_db
    executions: list[dict] = []
    results: list[dict] = []
    with node_process("hydro_ros.nodes.crane_sim", "-r", "__ns:=/crane", "-p", f"config:={K70M}", "-p", "real_time_factor:=4.0",
                      "-p", "initial_path:=horizontal", "-p", "initial_extension:=0.3"), \
            node_process("hydro_ros.nodes.trajectory_server", "-r", "__ns:=/crane", "-p", f"database:={db_path}",
                         "-p", "output_topic:=joint_trajectory"), \
            probe_node("client") as node:
        node.create_subscription(String, "/crane/crane_sim/execution", lambda m: executions.append(json.loads(m.data)), LATCHED_QOS)
        node.create_subscription(String, "/crane/trajectory_server/result", lambda m: results.append(json.loads(m.data)), LATCHED_QOS)
        states: list[JointState] = []
        node.create_subscription(JointState, "/crane" + topics.JOINT_STATES, states.append, 10)
        requests = node.create_publisher(String, "/crane/trajectory_server/request", 10)
        assert spin_until(node, lambda: states and requests.get_subscription_count() > 0, 30)
        for _ in range(20):  # until discovery has connected the crane's joint states to the server
            count = len(results)
            requests.publish(String(data="horizontal"))
            assert spin_until(node, lambda: len(results) > count, 20)
            if results[-1]["ok"] or not ("nothing received" in results[-1]["error"] or "no subscriber" in results[-1]["error"]):
                break
            spin_until(node, lambda: False, 0.5)
        assert results[-1]["ok"] and results[-1]["replanned"], results[-1]
        assert spin_until(node, lambda: executions, 30)
    run = executions[-1]
    assert run["ok"] and run["supply"] == "cp"
    assert run["energy_J"] == pytest.approx(results[-1]["cp_energy_J"], rel=0.1)
    assert run["path_accuracy_iso9283_m"] < 0.2
