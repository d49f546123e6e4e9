"""The nodes launch/machine.launch.py brings up on a machine, and the params file it reads for each.

``hydro-ros params --config C`` writes that file from the nodes' own parameter tables, so every
parameter appears with its unit, default and range, and the file cannot drift from the code
(test/test_launch.py compares the shipped config/params/*.yaml with it).
"""

from __future__ import annotations

from pathlib import Path

from hydro_ros.contract.config import config_dir
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.nodes import can_bridge, fdi_node, hmi
from hydro_ros.nodes.parameters import PACKAGE_SHARE, Spec, params_yaml

# the bus a bridge opens is machine.launch.py's `interface` and `channel` arguments, so it is said in one place
LAUNCH_ARGUMENTS = {"can_bridge": ("interface", "channel")}
BRINGUP: dict[str, dict[str, Spec]] = {
    "can_bridge": {name: spec for name, spec in can_bridge.PARAMETERS.items() if name not in LAUNCH_ARGUMENTS["can_bridge"]},
    "fdi_node": fdi_node.PARAMETERS,
    "hmi": hmi.PARAMETERS,
}

# a crane's cylinders at 1 kHz are ~19 000 per-sample messages a second, more than rclpy carries: the bridge hands the
# monitor sample blocks and keeps only /joint_states, which the HMI and a trajectory server read
CRANE_VALUES = {"can_bridge": {"sensor_topics": "joint_states", "sample_blocks": True}, "fdi_node": {"input": "sample_block"}}


def machine_params(config: Path) -> str:
    """The params file of the machine whose config is ``config``: a file of the package's config/ is named through the
    package share (the launch file expands it), any other by its absolute path."""
    shipped = config.resolve().parent == config_dir().resolve()
    config_value = f"{PACKAGE_SHARE}/config/{config.name}" if shipped else str(config.resolve())
    header = (
        f"# Parameters of the hydro_ros nodes on the machine of {config.name}, for launch/machine.launch.py\n"
        f"# (written by `hydro-ros params --config {f'config/{config.name}' if shipped else config}`; edit the values, keep the keys).\n"
        "# Each comment: what it is [unit] (default; range; read at start or settable while running).\n"
        f"# {PACKAGE_SHARE} is expanded by the launch file; for `--params-file` write the path out.\n"
        "# /**: the same values for these node names in any namespace (-r __ns:=/machine2).\n"
    )
    crane = load_machine_config(config).planned
    blocks = [params_yaml(name, specs, {"config": config_value, **(CRANE_VALUES.get(name, {}) if crane else {})})
              .replace(f"{name}:\n", f"/**/{name}:\n", 1)
              for name, specs in BRINGUP.items()]
    return header + "\n".join(blocks)


# topics the nodes use by their absolute names in any namespace (/diagnostics, as diagnostic_updater keeps it; /clock;
# rclcpp's /rosout and /parameter_events)
ABSOLUTE_TOPICS = ("diagnostics", "clock", "rosout", "parameter_events")


def sros2_policy(namespace: str) -> str:
    """config/sros2/policy.xml for the machine in ``namespace`` (machine.launch.py's namespace argument): every profile in
    that namespace, the topics used by absolute name made absolute. The shipped file is the root namespace's."""
    import xml.etree.ElementTree as ET

    tree = ET.parse(config_dir() / "sros2" / "policy.xml")
    ns = "/" + namespace.strip("/") if namespace.strip("/") else "/"
    for profile in tree.getroot().iter("profile"):
        profile.set("ns", ns)
    for topic in tree.getroot().iter("topic"):
        if topic.text in ABSOLUTE_TOPICS and ns != "/":
            topic.text = "/" + topic.text
    ET.indent(tree)
    # (no double hyphen in an XML comment: the option is named, not spelled)
    comment = (f"<!-- SROS2 access control for the hydro_ros machine in namespace {ns}, written by hydro-ros sros2 policy from "
               "config/sros2/policy.xml: every enclave and its access as there. -->\n")
    return '<?xml version="1.0" encoding="UTF-8"?>\n' + comment + ET.tostring(tree.getroot(), encoding="unicode") + "\n"


def aggregator_config(namespaces: list[str]) -> str:
    """config/diagnostic_aggregator.yaml for the machines in ``namespaces`` on one graph: a group per machine (its
    namespace; "" the root namespace), in it the shipped file's group per function, each matching only that machine's
    statuses and showing them without the machine's and the function's prefix (m1/hydro_ros/fdi/boom -> m1 > Condition
    monitoring > boom)."""
    import yaml

    shipped = yaml.safe_load((config_dir() / "diagnostic_aggregator.yaml").read_text())["analyzers"]["ros__parameters"]
    functions = {key: value for key, value in shipped.items() if isinstance(value, dict)}
    machines = {}
    for namespace in dict.fromkeys(n.strip("/") for n in namespaces):
        prefix = f"{namespace}/" if namespace else ""
        group = {}
        for key, analyzer in functions.items():
            leaf = {k: v for k, v in analyzer.items() if k not in ("contains", "remove_prefix")}
            leaf["startswith"] = [prefix + text for text in analyzer["contains"]]
            leaf["remove_prefix"] = [prefix + text for text in analyzer.get("remove_prefix", analyzer["contains"])]
            group[key] = leaf
        machines[namespace or "root"] = {"type": "diagnostic_aggregator/AnalyzerGroup", "path": namespace or "root", "analyzers": group}
    header = (f"# diagnostic_aggregator for the hydro_ros machines {', '.join(n or '(root)' for n in machines)}: written by hydro-ros "
              "aggregator config from config/diagnostic_aggregator.yaml, a group per machine, in it a group per function\n")
    return header + yaml.safe_dump({"analyzers": {"ros__parameters": {"path": shipped["path"], **machines}}}, sort_keys=False)
