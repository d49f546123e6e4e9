"""The launch files and params files, checked without `launch` (not installable here): a stand-in
records what each launch file asks for, and the test checks that every executable, parameter and file
it names exists; the shipped params files are what `hydro-ros params` writes; a node reads one."""

from __future__ import annotations

import importlib.util
import re
import sys
import types
from pathlib import Path

import pytest
import yaml
from rclpy.parameter_client import AsyncParameterClient

from hydro_ros.nodes.bringup import BRINGUP, machine_params
from hydro_ros.nodes.parameters import PACKAGE_SHARE
from test.conftest import REPO
from test.ros_graph import node_process, probe_node, spin_until

ENTRY_POINTS = set(re.findall(r'"(\w+) = hydro_ros\.nodes\.', (REPO / "setup.py").read_text()))
KILTED = set((REPO / "test" / "rosdep" / "kilted_packages.txt").read_text().split())


class _Recorded:
    def __init__(self, *args, **kwargs):
        self.args, self.kwargs = args, kwargs


class _Share(_Recorded):  # FindPackageShare("hydro_ros") -> the repository
    pass


def _fake_launch(monkeypatch) -> None:
    names = {"launch": ["LaunchDescription"], "launch.actions": ["DeclareLaunchArgument", "EmitEvent", "RegisterEventHandler"],
             "launch.conditions": ["IfCondition"], "launch.events": [], "launch.substitutions": ["LaunchConfiguration", "PathJoinSubstitution"],
             "launch_ros.actions": ["Node", "LifecycleNode"], "launch_ros.event_handlers": ["OnStateTransition"],
             "launch_ros.events": [], "launch_ros.events.lifecycle": ["ChangeState"],
             "launch_ros.parameter_descriptions": ["ParameterFile"], "launch_ros.substitutions": []}
    for module_name, classes in names.items():
        module = types.ModuleType(module_name)
        for cls in classes:
            setattr(module, cls, type(cls, (_Recorded,), {}))
        monkeypatch.setitem(sys.modules, module_name, module)
    sys.modules["launch_ros.substitutions"].FindPackageShare = _Share
    sys.modules["launch.events"].matches_action = lambda action: ("matches", action)


def _resolve(value, arguments: dict[str, object]) -> object:
    """A recorded substitution as a value: repository paths for the package share, argument defaults."""
    kind = type(value).__name__
    if kind == "_Share":
        return REPO if value.args[0] == "hydro_ros" else Path("/opt/ros/kilted/share") / value.args[0]
    if kind == "PathJoinSubstitution":
        return Path(*(str(_resolve(part, arguments)) for part in value.args[0]))
    if kind == "LaunchConfiguration":
        return _resolve(arguments[value.args[0]], arguments)
    if kind == "ParameterFile":
        return _resolve(value.args[0], arguments)
    return value


def _launch(path: Path, monkeypatch):
    _fake_launch(monkeypatch)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    entities = module.generate_launch_description().args[0]
    arguments = {e.args[0]: e.kwargs.get("default_value") for e in entities if type(e).__name__ == "DeclareLaunchArgument"}
    nodes = [e for e in entities if type(e).__name__ in ("Node", "LifecycleNode")]
    return arguments, nodes


def _transitions(path: Path, monkeypatch) -> dict[str, set[int]]:
    """Which transitions the launch file emits for each lifecycle node (by executable), directly or once it is inactive."""
    _fake_launch(monkeypatch)
    spec = importlib.util.spec_from_file_location(path.stem.replace(".", "_"), path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out: dict[str, set[int]] = {}
    for entity in module.generate_launch_description().args[0]:
        events = [entity] if type(entity).__name__ == "EmitEvent" else []
        if type(entity).__name__ == "RegisterEventHandler":
            handler = entity.args[0]
            # after launch's own configure only, once: a deactivate (active -> deactivating -> inactive) or an operator's
            # cleanup -> configure must not re-activate (launch_ros matches every given field; test_safety_live.py)
            assert (handler.kwargs["start_state"], handler.kwargs["goal_state"], handler.kwargs["handle_once"]) == ("configuring", "inactive", True)
            events = handler.kwargs["entities"]
        for event in events:
            change = event.kwargs["event"]
            target = change.kwargs["lifecycle_node_matcher"][1]
            out.setdefault(target.kwargs["executable"], set()).add(change.kwargs["transition_id"])
    return out


@pytest.mark.parametrize("launch_file", sorted((REPO / "launch").glob("*.launch.py")), ids=lambda p: p.name)
def test_launch_files_name_what_exists(launch_file, monkeypatch):
    arguments, nodes = _launch(launch_file, monkeypatch)
    assert nodes
    for node in nodes:
        package, executable = node.kwargs["package"], node.kwargs["executable"]
        if package == "hydro_ros":
            assert executable in ENTRY_POINTS
        else:
            assert package in KILTED
        for parameters in node.kwargs.get("parameters", []):
            if isinstance(parameters, dict):
                continue
            file = _resolve(parameters, arguments)
            assert Path(file).is_file(), file
            if package == "hydro_ros":
                blocks = yaml.safe_load(Path(file).read_text())
                block = blocks.get(f"/**/{node.kwargs['name']}") or blocks.get(node.kwargs["name"])
                assert set(block["ros__parameters"]) == set(BRINGUP[node.kwargs["name"]]), file


def test_machine_launch_takes_namespace_params_file_sim_time_and_node_choices(monkeypatch):
    arguments, nodes = _launch(REPO / "launch" / "machine.launch.py", monkeypatch)
    assert {"namespace", "params_file", "use_sim_time", "start_can_bridge", "start_fdi_node", "start_hmi",
            "start_diagnostic_aggregator"} <= set(arguments)
    assert {node.kwargs["executable"] for node in nodes} == {"can_bridge", "fdi_node", "hmi", "aggregator_node"}
    # the aggregator reads the absolute /diagnostics; the machine's nodes live in its namespace
    assert all(type(node.kwargs["namespace"]).__name__ == "LaunchConfiguration" for node in nodes if node.kwargs["name"] != "analyzers")
    assert {"interface", "channel", "log_level", "auto_configure", "auto_activate"} <= set(arguments)


def test_lifecycle_nodes_are_driven_by_launch_not_by_their_own_autostart(monkeypatch):
    from lifecycle_msgs.msg import Transition

    for launch_file, lifecycle in (("machine.launch.py", "can_bridge"), ("crane_motion.launch.py", "trajectory_executor")):
        arguments, nodes = _launch(REPO / "launch" / launch_file, monkeypatch)
        node = next(n for n in nodes if n.kwargs["executable"] == lifecycle)
        assert type(node).__name__ == "LifecycleNode"
        assert any(isinstance(p, dict) and p.get("autostart") is False for p in node.kwargs["parameters"])
        assert _transitions(REPO / "launch" / launch_file, monkeypatch)[lifecycle] == {Transition.TRANSITION_CONFIGURE,
                                                                                       Transition.TRANSITION_ACTIVATE}
        assert {"auto_configure", "auto_activate", "log_level"} <= set(arguments)
    arguments, nodes = _launch(REPO / "launch" / "crane_motion.launch.py", monkeypatch)
    server = next(n for n in nodes if n.kwargs["executable"] == "trajectory_server")
    executor = next(n for n in nodes if n.kwargs["executable"] == "trajectory_executor")
    assert server.kwargs["parameters"][0]["output_topic"] == "trajectory_executor/joint_trajectory"  # the executor's input
    assert executor.kwargs["parameters"][0]["require_monitor"] is True


@pytest.mark.parametrize("machine", ["sam", "sam_mobile", "sam_mems", "k70m"])
def test_shipped_params_files_are_what_the_nodes_declare(machine):
    shipped = (REPO / "config" / "params" / f"{machine}.yaml").read_text()
    assert shipped == machine_params(REPO / "config" / f"{machine}.yaml"), f"regenerate: hydro-ros params --config config/{machine}.yaml"
    for block in yaml.safe_load(shipped).values():
        for value in block["ros__parameters"].values():
            assert value is not None


def test_a_node_in_a_namespace_takes_its_values_from_the_params_file(ros_domain, tmp_path):
    text = machine_params(REPO / "config" / "sam.yaml").replace(PACKAGE_SHARE, str(REPO))
    text = text.replace("stale_timeout: 0.5", "stale_timeout: 0.75")
    params = tmp_path / "machine.yaml"
    params.write_text(text)
    with node_process("hydro_ros.nodes.fdi_node", "--params-file", str(params), "-r", "__ns:=/machine2"), probe_node("probe") as node:
        client = AsyncParameterClient(node, "/machine2/fdi_node")
        assert client.wait_for_services(20.0)
        future = client.get_parameters(["stale_timeout", "config"])
        assert spin_until(node, future.done, 30)  # 10 s went by unanswered once, the library tier loading both cores
        values = [value.double_value or value.string_value for value in future.result().values]
        assert values == [0.75, str(REPO / "config" / "sam.yaml")]


def test_the_sros2_policy_lets_only_the_hmi_and_maintenance_call_the_monitor():
    import xml.etree.ElementTree as ET

    policy = ET.parse(REPO / "config" / "sros2" / "policy.xml").getroot()
    callers: dict[str, set[str]] = {}
    for enclave in policy.iter("enclave"):
        for services in enclave.iter("services"):
            if services.get("request") == "ALLOW":
                for service in services.iter("service"):
                    callers.setdefault(service.text, set()).add(enclave.get("path"))
    assert callers["fdi_node/acknowledge"] == {"/hydro_ros/hmi", "/hydro_ros/maintenance"}
    assert callers["fdi_node/reset"] == {"/hydro_ros/maintenance"}
    node_source = (REPO / "hydro_ros" / "nodes" / "fdi_node.py").read_text()
    fdi = next(e for e in policy.iter("enclave") if e.get("path") == "/hydro_ros/fdi_node")
    replied = {s.text for services in fdi.iter("services") if services.get("reply") == "ALLOW" for s in services.iter("service")}
    for service in ("~/acknowledge", "~/reset", "~/self_test"):
        assert service in replied and f'"{service}"' in node_source


def test_every_node_has_an_enclave_and_only_its_owner_may_publish_halt_commands_and_trajectories():
    import re
    import xml.etree.ElementTree as ET
    from fnmatch import fnmatch  # DDS partitions and topic names in a policy match as fnmatch does

    policy = ET.parse(REPO / "config" / "sros2" / "policy.xml").getroot()
    profiles = {profile.get("node"): profile for profile in policy.iter("profile")}
    sources = "".join(source.read_text() for source in (REPO / "hydro_ros" / "nodes").glob("*.py"))
    node_names = set(re.findall(r'(?:super\(\).__init__|create_node)\("(\w+)"', sources))
    assert node_names and node_names <= set(profiles), sorted(node_names - set(profiles))

    def publishers(topic: str) -> set[str]:
        return {name for name, profile in profiles.items() for topics in profile.iter("topics")
                if topics.get("publish") == "ALLOW" and any(fnmatch(topic, t.text) for t in topics.iter("topic"))}

    assert publishers("fdi/halt") == {"fdi_node"}
    assert publishers("hydraulics/valve_commands") == {"trajectory_executor", "plant_sim", "crane_sim"}
    assert publishers("trajectory_executor/joint_trajectory") == {"trajectory_server"}
    assert "can_bridge" in publishers("joint_states") and not publishers("joint_states") & {"trajectory_server", "trajectory_executor", "hmi"}


def test_every_launched_node_runs_in_its_own_enclave_of_the_policy(monkeypatch):
    """The launch files' ``enclave`` argument: each of our nodes gets ``--enclave <enclave>/<node>``, an enclave the policy has."""
    import xml.etree.ElementTree as ET

    enclaves = {e.get("path") for e in ET.parse(REPO / "config" / "sros2" / "policy.xml").getroot().iter("enclave")}
    for launch_file in ("machine.launch.py", "crane_motion.launch.py"):
        arguments, nodes = _launch(REPO / "launch" / launch_file, monkeypatch)
        for node in (n for n in nodes if n.kwargs["package"] == "hydro_ros"):
            ros_arguments = node.kwargs["ros_arguments"]
            enclave = str(_resolve(ros_arguments[ros_arguments.index("--enclave") + 1], arguments))
            assert enclave == f"/hydro_ros/{node.kwargs['name']}" and enclave in enclaves, (launch_file, enclave)


def test_the_sros2_policy_of_a_namespaced_machine_is_generated_and_installed(capsys):
    import xml.etree.ElementTree as ET

    from hydro_ros.cli import main as cli
    from hydro_ros.nodes.bringup import ABSOLUTE_TOPICS

    assert cli(["sros2", "policy", "--namespace", "m1"]) == 0
    generated = ET.fromstring(capsys.readouterr().out.split("\n", 1)[1])
    shipped = ET.parse(REPO / "config" / "sros2" / "policy.xml").getroot()
    assert {p.get("ns") for p in generated.iter("profile")} == {"/m1"}
    assert [p.get("node") for p in generated.iter("profile")] == [p.get("node") for p in shipped.iter("profile")]
    for ours, theirs in zip(generated.iter("topic"), shipped.iter("topic")):
        assert ours.text == ("/" + theirs.text if theirs.text in ABSOLUTE_TOPICS else theirs.text)
    assert [s.text for s in generated.iter("service")] == [s.text for s in shipped.iter("service")]
    assert '("share/" + package_name + "/config/sros2", glob("config/sros2/*.xml"))' in (REPO / "setup.py").read_text()
