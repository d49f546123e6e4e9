"""plant_sim and bag_player on a real DDS graph (separate processes, private localhost domain)."""

from __future__ import annotations

import time

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
from test.ros_graph import answered, node_process, probe_node, spin_until


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
        assert answered(node, lambda: client.set_parameters([Parameter("fault.external_leakage_a", value=20.0)])).results[0].successful
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
        result = answered(node, lambda: client.set_parameters([Parameter("fault.internal_leakage", value=float("nan"))])).results[0]
        assert not result.successful and "finite" in result.reason


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory, sam_config):
    path = tmp_path_factory.mktemp("replay") / "bag"
    with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
        for _, _, block in run_blocks(sam_config, Scenario(2.0, (), seed=2)):
            writer.write_block("boom", block)
    return path


def test_bag_player_replays_contract_types_with_clock(ros_domain, short_bag):
    got: dict[str, list] = {"pa": [], "cmd": [], "clock": []}
    with probe_node("probe") as node:
        node.create_subscription(FluidPressure, topics.pressure_a("boom"), lambda m: got["pa"].append(m), SENSOR_QOS)
        node.create_subscription(JointState, topics.VALVE_COMMANDS, lambda m: got["cmd"].append(m), SENSOR_QOS)
        node.create_subscription(Clock, topics.CLOCK, lambda m: got["clock"].append(m), CLOCK_QOS)
        # every one of the 2000 messages is counted: on a loaded machine discovery can outlast the default 1 s delay
        with node_process("hydro_ros.nodes.bag_player", "-p", f"bag:={short_bag}", "-p", "rate:=1.0", "-p", "start_delay:=5.0",
                          "-p", "publish_clock:=true"):
            assert spin_until(node, lambda: len(got["pa"]) >= 2000 and len(got["cmd"]) >= 2000, 45)
        assert got["cmd"][0].name == ["boom"] and -1.0 <= got["cmd"][0].position[0] <= 1.0
        assert got["clock"] and got["clock"][-1].clock.sec * 1e9 + got["clock"][-1].clock.nanosec <= 2.0e9
        stamps = [m.header.stamp.nanosec + m.header.stamp.sec * 10**9 for m in got["pa"]]
        assert stamps == sorted(stamps) and len(set(stamps)) == 2000


def test_record_of_a_live_plant_is_a_split_contract_bag_the_monitor_reads(ros_domain, tmp_path):
    """hydro-ros bag record on a live plant_sim (best-effort sensor publishers, as many drivers offer), split every 2 s;
    then hydro-ros bag info and hydro-ros fdi run over the recording."""
    import json
    import subprocess
    import sys

    import yaml

    bag = tmp_path / "recorded"
    cli = [sys.executable, "-m", "hydro_ros.cli"]
    best_effort = [arg for topic in topics.sensor_topics(["boom"])
                   for arg in ("-p", f"qos_overrides.{topic}.publisher.reliability:=best_effort")]
    # the plant at half real time; publishers discovered after the recorder's first look are still recorded with their QoS
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}", "-p", "real_time_factor:=0.5", "-p", "seed:=2",
                      *best_effort) as plant:
        recorded = subprocess.run([*cli, "bag", "record", "--config", str(SAM_CONFIG), "--out", str(bag), "--duration", "9",
                                   "--split-duration", "2", "--quiet"], capture_output=True, text=True, timeout=120)
        assert plant.poll() is None
    assert recorded.returncode == 0, recorded.stderr
    summary = json.loads(recorded.stdout)
    assert len(summary["files"]) >= 3
    assert min(summary["topics"].values()) > 2000  # ~3.5 s of 1 kHz samples at half real time

    info = subprocess.run([*cli, "bag", "info", str(bag), "--json"], capture_output=True, text=True, timeout=120)
    assert info.returncode == 0, info.stdout
    report = json.loads(info.stdout)
    assert report["errors"] == [] and report["messages"] == summary["messages"]
    assert {topic: row["messages"] for topic, row in report["topics"].items()} == summary["topics"]
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    assert meta["relative_file_paths"] == summary["files"]
    offered = {entry["topic_metadata"]["name"]: entry["topic_metadata"]["offered_qos_profiles"] for entry in meta["topics_with_message_count"]}
    assert offered[topics.JOINT_STATES][0]["reliability"] == "best_effort"

    out = tmp_path / "fdi.json"
    monitored = subprocess.run([*cli, "fdi", "run", "--bag", str(bag), "--config", str(SAM_CONFIG), "--out", str(out), "--quiet"],
                               capture_output=True, text=True, timeout=300)
    assert monitored.returncode == 0, monitored.stderr
    result = json.loads(out.read_text())
    assert result["errors"] == [] and result["partial"] is False
    assert result["actuators"]["boom"]["fault"] == "none" and result["alarms"] == []


def test_record_in_a_namespace_takes_the_sample_blocks_and_the_bag_reads_whole(ros_domain, tmp_path):
    """A machine in namespace /machine1 whose simulator sends sample blocks and only /joint_states per sample (the crane's
    bring-up), started after the recorder: hydro-ros bag record with --ros-args -r __ns:=/machine1 records the blocks once they
    appear; a SIGTERM ends the recording (no --duration) with the open part closed, and the bag reads as every column."""
    import json
    import signal
    import subprocess
    import sys

    import yaml

    from hydro_ros.bags.reader import read_bag

    bag = tmp_path / "recorded"
    # the recorder first, the machine after it (a recorder started before the bring-up must still take the blocks)
    recorder = subprocess.Popen([sys.executable, "-m", "hydro_ros.cli", "bag", "record", "--config", str(SAM_CONFIG), "--out", str(bag),
                                 "--quiet", "--ros-args", "-r", "__ns:=/machine1"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(6.0)  # past the recorder's start and its first look at the graph
    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM_CONFIG}", "-p", "real_time_factor:=1.0", "-p", "seed:=2",
                      "-p", "sample_blocks:=true", "-p", "sensor_topics:=joint_states", "-r", "__ns:=/machine1"):
        time.sleep(6.0)
        recorder.send_signal(signal.SIGTERM)
        out, err = recorder.communicate(timeout=60)
    assert recorder.returncode == 0, err
    summary = json.loads(out)
    assert summary["topics"][topics.SAMPLE_BLOCK] > 10 and summary["topics"][topics.pressure_a("boom")] == 0
    listed = yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]["topics_with_message_count"]
    assert {entry["topic_metadata"]["name"]: entry["message_count"] for entry in listed}[topics.pressure_a("boom")] == 0
    data = read_bag(bag)
    assert len(data.stamps_ns) > 1000 and not data.errors
    assert np.all(np.isfinite(data.pressure_a["boom"])) and np.all(np.isfinite(data.valve_command["boom"]))


def test_a_second_node_of_a_process_keeps_the_remaps_but_not_the_node_name():
    from hydro_ros.nodes.common import without_node_name

    argv = ["hmi", "--ros-args", "-r", "__node:=hmi", "-r", "__ns:=/m1", "--remap", "hmi:__name:=x", "-r", "/joint_states:=/a",
            "-p", "port:=0", "--", "other"]
    assert without_node_name(argv) == ["--ros-args", "-r", "__ns:=/m1", "-r", "/joint_states:=/a", "-p", "port:=0"]
    assert without_node_name(["hmi"]) == []


def test_the_hmi_started_as_launch_names_it_is_one_node_of_that_name(ros_domain):
    """launch's ``name="hmi"`` and ``namespace="m1"`` as the remaps it passes: one /m1/hmi on the graph, its joint-state
    sampler beside it in the namespace."""
    with node_process("hydro_ros.nodes.hmi", "-r", "__node:=hmi", "-r", "__ns:=/m1", "-p", f"config:={SAM_CONFIG}", "-p", "port:=0",
                      "-p", "foxglove_port:=-1"), probe_node("probe") as node:
        names = lambda: node.get_node_names_and_namespaces()  # noqa: E731
        assert spin_until(node, lambda: ("hmi_joint_state_sampler", "/m1") in names(), 30), names()
        spin_until(node, lambda: False, 1.0)
        listed = names()
    assert listed.count(("hmi", "/m1")) == 1 and ("hmi_joint_state_sampler", "/m1") in listed, listed


def test_can_bridge_says_its_state_on_diagnostics_in_every_lifecycle_state(ros_domain):
    """autostart off (launch drives it): unconfigured, a configure that fails (no such bus) with its error, asked twice and
    logged twice, then configured on another interface: inactive. Each said on /diagnostics by the periodic status."""
    from lifecycle_msgs.msg import Transition

    from test.ros_graph import change_state, node_output

    statuses: list = []
    with node_process("hydro_ros.nodes.can_bridge", "-p", f"config:={SAM_CONFIG}", "-p", "autostart:=false", "-p", "interface:=socketcan",
                      "-p", "channel:=hydro_ros_no_such_bus", "-p", "diagnostics_period:=0.2") as bridge, probe_node("operator") as node:
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, lambda m: statuses.extend(
            {v.key: v.value for v in s.values} | {"message": s.message, "level": s.level[0]}
            for s in m.status if s.name == "hydro_ros/can_bridge/bus"), 50)
        assert spin_until(node, lambda: any(s["lifecycle_state"] == "unconfigured" for s in statuses), 30)
        for _ in range(2):  # a person asks twice: refused twice, said twice
            assert not change_state(node, "/can_bridge", Transition.TRANSITION_CONFIGURE)
        count = len(statuses)
        assert spin_until(node, lambda: len(statuses) > count + 2, 5)
        assert statuses[-1]["lifecycle_state"] == "unconfigured" and "hydro_ros_no_such_bus" in statuses[-1]["message"]
        assert statuses[-1]["level"] == 2 and statuses[-1]["reconnects"] == "2"
        assert node_output(bridge).count("bus socketcan:hydro_ros_no_such_bus cannot be opened") >= 2
        parameters = AsyncParameterClient(node, "can_bridge")
        assert parameters.wait_for_services(10.0)
        future = parameters.set_parameters([Parameter("interface", value="virtual")])
        assert spin_until(node, future.done, 10)
        assert change_state(node, "/can_bridge", Transition.TRANSITION_CONFIGURE)
        assert spin_until(node, lambda: statuses[-1]["lifecycle_state"] == "inactive", 5), statuses[-1]
        assert statuses[-1]["level"] == 1 and "nothing published" in statuses[-1]["message"]


STOP_ARGS = {  # each executable of setup.py with what it needs to start on its own
    "plant_sim": [], "crane_sim": [], "fdi_node": [], "trajectory_executor": [],
    "bag_player": ["-p", "bag:=" + str(SAM_CONFIG.parent.parent / "bags" / "fault_free"), "-p", "loop:=true"],
    "can_bridge": ["-p", "interface:=virtual", "-p", "channel:=hydro_ros_stop_test"],
    "trajectory_server": ["-p", "database:=/nonexistent/catalog.db"],
    "hmi": ["-p", "port:=0", "-p", "foxglove_port:=-1"],
}


STOP_BOUND_S = 5.0  # [s] from the signal to the exit of one node


@pytest.mark.parametrize("signal_name", ["SIGINT", "SIGTERM"])
def test_every_node_stops_cleanly_and_promptly(ros_domain, signal_name):
    """Every executable of setup.py up at once; then each in turn gets the signal and must exit 0 within STOP_BOUND_S,
    without a traceback (plant_sim's publisher in an invalid context, the HMI's websockets held for a minute were the
    bugs). The bound catches a hang, not a slow machine: alone the slowest (plant_sim) stops in ~0.8 s, beside the library
    tests it once took 2.03 s."""
    import re
    import signal
    from contextlib import ExitStack

    from test.conftest import REPO
    from test.ros_graph import node_output

    entry_points = set(re.findall(r'"(\w+) = hydro_ros\.nodes\.', (REPO / "setup.py").read_text()))
    assert entry_points == set(STOP_ARGS)  # a new executable is covered by this test
    stopped: dict[str, tuple[int, float, str]] = {}
    with ExitStack() as stack, probe_node("probe") as node:
        processes = {name: stack.enter_context(node_process(f"hydro_ros.nodes.{name}", *args)) for name, args in STOP_ARGS.items()}
        assert spin_until(node, lambda: set(STOP_ARGS) <= {name for name, _ in node.get_node_names_and_namespaces()}, 60), \
            node.get_node_names_and_namespaces()
        spin_until(node, lambda: False, 1.0)  # their timers running
        for name, process in processes.items():
            process.send_signal(getattr(signal, signal_name))
            sent = time.monotonic()
            code = process.wait(timeout=10)
            stopped[name] = (code, time.monotonic() - sent, node_output(process))
    for name, (code, after, output) in stopped.items():
        assert "Traceback" not in output, (name, output[-2000:])
        assert code == 0, (name, code, output[-1000:])
        assert after < STOP_BOUND_S, f"{name} took {after:.1f} s"


def test_statuses_name_the_machine_instance_as_their_hardware_id(ros_domain):
    """Two machines of one type on one graph are told apart by hardware_id: the machine_id parameter, else the namespace,
    else the machine's name."""
    from contextlib import ExitStack

    seen: list = []
    machines = {"m1/": ["-r", "__ns:=/m1"], "m2/": ["-r", "__ns:=/m2", "-p", "machine_id:=crane7"], "": []}
    with ExitStack() as stack, probe_node("probe") as node:
        for args in machines.values():
            stack.enter_context(node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={SAM_CONFIG}", *args))
        node.create_subscription(DiagnosticArray, topics.DIAGNOSTICS, lambda m: seen.extend(m.status), 50)
        assert spin_until(node, lambda: {s.name for s in seen} >= {f"{p}hydro_ros/fdi/boom" for p in machines}, 30)
    ids = {prefix: {s.hardware_id for s in seen if s.name == f"{prefix}hydro_ros/fdi/boom"} for prefix in machines}
    assert ids == {"m1/": {"m1"}, "m2/": {"crane7"}, "": {"sam"}}
