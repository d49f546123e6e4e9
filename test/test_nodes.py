"""plant_sim and bag_player on a real DDS graph (separate processes, private localhost domain)."""

from __future__ import annotations

import numpy as np
import pytest
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import FluidPressure, JointState

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract import topics
from hydro_ros.nodes.common import CLOCK_QOS, SENSOR_QOS
from hydro_ros.sim.scenario import Scenario, run_blocks
from test.conftest import SAM_CONFIG
from test.ros_graph import node_process, probe_node, spin_until


def test_plant_sim_publishes_contract_topics_and_takes_faults(ros_domain):
    samples: dict[str, list] = {"pa": [], "js": [], "diag": []}
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}", "-p", "real_time_factor:=1.0", "-p", "seed:=5"), \
            probe_node("probe") as node:
        node.create_subscription(FluidPressure, topics.pressure_a("boom"), lambda m: samples["pa"].append(m), SENSOR_QOS)
        node.create_subscription(JointState, topics.JOINT_STATES, lambda m: samples["js"].append(m), SENSOR_QOS)
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, lambda m: samples["diag"].append(m), 10)
        assert spin_until(node, lambda: len(samples["pa"]) > 3000, 40), "no pressure stream from plant_sim"
        assert samples["js"][0].name == ["boom_joint"]
        stamps = np.array([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 for m in samples["pa"]])
        assert np.allclose(np.diff(stamps), 1e-3, atol=1e-6)  # every 1 kHz sample, none dropped
        # inject a large external leak A through the ROS parameter and watch p_A fall
        before = np.mean([m.fluid_pressure for m in samples["pa"][-500:]])
        client = AsyncParameterClient(node, "plant_sim")
        assert client.wait_for_services(10.0)
        future = client.set_parameters([Parameter("fault.external_leakage_a", value=20.0)])
        assert spin_until(node, future.done, 10)
        assert future.result().results[0].successful
        count = len(samples["pa"])
        assert spin_until(node, lambda: len(samples["pa"]) > count + 6000, 40)
        after = np.mean([m.fluid_pressure for m in samples["pa"][-500:]])
        assert after < before - 1e6
        assert spin_until(node, lambda: any("external_leakage_a=20" in v.value for m in samples["diag"] for v in m.status[0].values), 10)
        assert samples["diag"][-1].status[0].name == "hydro_ros/plant_sim"


def test_plant_sim_rejects_bad_fault_values(ros_domain):
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}"), probe_node("probe") as node:
        client = AsyncParameterClient(node, "plant_sim")
        assert client.wait_for_services(20.0)
        future = client.set_parameters([Parameter("fault.internal_leakage", value=float("nan"))])
        assert spin_until(node, future.done, 10)
        result = future.result().results[0]
        assert not result.successful and "finite" in result.reason


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory, sam_config):
    path = tmp_path_factory.mktemp("replay") / "bag"
    with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
        for _, _, block in run_blocks(sam_config, Scenario(2.0, (), seed=2)):
            writer.write("boom", block)
    return path


def test_bag_player_replays_contract_types_with_clock(ros_domain, short_bag):
    got: dict[str, list] = {"pa": [], "cmd": [], "clock": []}
    with probe_node("probe") as node:
        node.create_subscription(FluidPressure, topics.pressure_a("boom"), lambda m: got["pa"].append(m), SENSOR_QOS)
        node.create_subscription(JointState, topics.VALVE_COMMANDS, lambda m: got["cmd"].append(m), SENSOR_QOS)
        node.create_subscription(Clock, topics.CLOCK, lambda m: got["clock"].append(m), CLOCK_QOS)
        with node_process("hydro_ros.nodes.bag_player", "-p", f"bag:={short_bag}", "-p", "rate:=0.5"):
            assert spin_until(node, lambda: len(got["pa"]) >= 2000 and len(got["cmd"]) >= 2000, 40)
        assert got["cmd"][0].name == ["boom"] and -1.0 <= got["cmd"][0].position[0] <= 1.0
        assert got["clock"] and got["clock"][-1].clock.sec * 1e9 + got["clock"][-1].clock.nanosec <= 2.0e9
        stamps = [m.header.stamp.nanosec + m.header.stamp.sec * 10**9 for m in got["pa"]]
        assert stamps == sorted(stamps) and len(set(stamps)) == 2000
