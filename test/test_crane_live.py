"""The K70M on a real DDS graph: trajectory_server serves the energy-optimal horizontal path, plant_sim's crane mode
works it with the crane's cylinders, fdi_node monitors every cylinder; a leak set on one cylinder shows at WARN on it.

plant_sim runs the crane at 0.3 x real time: its 19 sensor topics at 1 kHz are ~19 000 messages a second, which
neither plant_sim nor fdi_node can carry in rclpy on this 2-core machine (docs/crane_monitoring.md).
"""

from __future__ import annotations

import json

import pytest
from builtin_interfaces.msg import Duration
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String
from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

from hydro_ros.hmi.state import HEALTHY_MESSAGES
from hydro_ros.nodes.common import LATCHED_QOS
from hydro_ros.planning.catalog import build, plan_units
from hydro_ros.planning.database import TrajectoryDatabase
from test.conftest import K70M
from test.ros_graph import node_process, probe_node, spin_until


@pytest.fixture(scope="module")
def horizontal_db(tmp_path_factory, k70m):
    path = tmp_path_factory.mktemp("crane_live") / "catalog.db"
    with TrajectoryDatabase(path, writable=True) as db:
        build(db, plan_units(k70m, methods=("dp_cp",), grid=(80, 31, 31), paths=("horizontal",)), workers=1)
    return path


CYLINDERS = ("lift", "tilt", "extension")


def _statuses(messages: list[DiagnosticArray], actuator: str) -> list:
    return [s for m in messages for s in m.status if s.name == f"hydro_ros/fdi/{actuator}"]


def _plant_status(messages: list[DiagnosticArray]) -> str:
    plant = [s for m in messages for s in m.status if s.name == "hydro_ros/plant_sim"]
    return plant[-1].message if plant else "none yet"


def _armed(node, diags: list[DiagnosticArray], timeout: float) -> None:
    assert spin_until(node, lambda: all(_statuses(diags, a) and _statuses(diags, a)[-1].message == "ok" for a in CYLINDERS), timeout), \
        {a: [s.message for s in _statuses(diags, a)[-3:]] for a in CYLINDERS}


def _leak_named_on_its_cylinder_only(node, diags: list[DiagnosticArray], actuator: str, fault: str, timeout: float):
    """Set the leak through plant_sim's parameter; its cylinder turns WARN with the fault's name, the others name no fault.
    Returns the parameter client and the cylinder's last status."""
    client = AsyncParameterClient(node, "plant_sim")
    assert client.wait_for_services(10.0)
    future = client.set_parameters([Parameter(f"fault.{actuator}.{fault}", value=3.0)])
    assert spin_until(node, future.done, 10) and future.result().results[0].successful
    assert spin_until(node, lambda: _statuses(diags, actuator)[-1].message == fault, timeout), \
        [s.message for s in _statuses(diags, actuator)[-5:]]
    status = _statuses(diags, actuator)[-1]
    assert status.level == bytes([1])  # WARN: a leak is a minor fault
    for other in CYLINDERS:
        if other != actuator:
            # no fault named on it; "overloaded" (the node behind its input under a full test run's load) names none
            assert {s.message for s in _statuses(diags, other)} <= set(HEALTHY_MESSAGES), other
    return client, status


def test_a_leak_in_one_cylinder_of_the_working_crane_shows_at_warn_on_that_cylinder(ros_domain, horizontal_db):
    diags: list[DiagnosticArray] = []
    results: list[dict] = []
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={K70M}", "-p", "excitation:=trajectory", "-p", "seed:=5",
                      "-p", "initial_path:=horizontal", "-p", "real_time_factor:=0.3"), \
            node_process("hydro_ros.nodes.trajectory_server", "-p", f"database:={horizontal_db}", "-p", "output_topic:=joint_trajectory",
                         "-p", "tip_tolerance:=0.1"), \
            node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={K70M}"), probe_node("probe") as node:
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        node.create_subscription(String, "/trajectory_server/result", lambda m: results.append(json.loads(m.data)), LATCHED_QOS)
        requests = node.create_publisher(String, "/trajectory_server/request", 10)
        _armed(node, diags, 90)  # every cylinder monitored before the trajectory is asked for
        for _ in range(20):  # until discovery connects the joint states and the output (the answers say what is missing)
            count = len(results)
            requests.publish(String(data="horizontal"))
            assert spin_until(node, lambda: len(results) > count, 20)
            if results[-1]["ok"]:
                break
            spin_until(node, lambda: False, 0.5)
        assert results[-1]["ok"], results[-1]
        spin_until(node, lambda: False, 6.0)  # ~2 s of the crane working its path
        assert "refused" not in _plant_status(diags), _plant_status(diags)
        client, _ = _leak_named_on_its_cylinder_only(node, diags, "lift", "external_leakage_a", 120)
        refused = client.set_parameters([Parameter("fault.external_leakage_a", value=1.0)])
        assert spin_until(node, refused.done, 10)
        assert not refused.result().results[0].successful and "names its cylinder" in refused.result().results[0].reason
        # a trajectory that starts away from the joints would be a jump: refused, said on /diagnostics, the cycle goes on
        jump = JointTrajectory(joint_names=["lift", "tilt", "extension"],
                               points=[JointTrajectoryPoint(positions=[1.0, -1.0, 0.5], time_from_start=Duration(sec=t)) for t in (0, 1)])
        node.create_publisher(JointTrajectory, "/joint_trajectory", 10).publish(jump)
        assert spin_until(node, lambda: "trajectory refused: starts" in _plant_status(diags), 20), _plant_status(diags)


def test_fdi_node_takes_the_crane_in_sample_blocks_at_full_rate(ros_domain):
    """Every cylinder at 1 kHz in real time through /hydraulics/sample_block (the per-sample topics are off): armed,
    nothing lost, and a leak set on one cylinder is named on it."""
    diags: list[DiagnosticArray] = []
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={K70M}", "-p", "seed:=6", "-p", "sensor_topics:=none",
                      "-p", "sample_blocks:=true"), \
            node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={K70M}", "-p", "input:=sample_block"), probe_node("probe") as node:
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        _armed(node, diags, 60)
        _, tilt = _leak_named_on_its_cylinder_only(node, diags, "tilt", "external_leakage_b", 60)
        values = {v.key: v.value for v in tilt.values}
        assert int(values["samples"]) > 10_000 and int(values["undecodable_messages"]) == 0, values
        assert int(values["incomplete_samples"]) == 0 and int(values["out_of_order_dropped"]) == 0, values
