"""The operator tool configs match what the nodes publish: the aggregator groups every status once,
and the Foxglove layout's plots index /fdi/residuals the way fdi_node lays it out."""

from __future__ import annotations

import json
import re

import yaml

from hydro_ros.can.codec import MachineBus
from hydro_ros.contract import topics
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.nodes.fdi_node import ALARM_LOG_STATUS
from hydro_ros.nodes.hmi import HMI_STATUS
from test.conftest import REPO, SAM_CONFIG

AGGREGATOR = REPO / "config" / "diagnostic_aggregator.yaml"
LAYOUT = REPO / "config" / "foxglove_layout.json"


def _published_status_names() -> list[str]:
    names = ["hydro_ros/plant_sim", "hydro_ros/can_bridge/bus", HMI_STATUS, ALARM_LOG_STATUS, topics.FDI_HALT_STATUS]
    for machine in ("sam", "sam_mobile", "sam_mems"):
        config = load_machine_config(REPO / "config" / f"{machine}.yaml")
        names += [f"{prefix}{actuator}" for actuator in config.actuator_names
                  for prefix in (topics.FDI_STATUS_PREFIX, topics.SENSOR_STATUS_PREFIX)]
    names += [f"hydro_ros/can_bridge/{message}" for message in MachineBus(load_machine_config(SAM_CONFIG)).expected]
    names.append("hydro_ros/trajectory_executor")
    return names + [f"machine1/{name}" for name in names]  # a machine in a namespace (nodes.common.namespaced_statuses)


def _matches(analyzer: dict, name: str) -> bool:
    """diagnostic_aggregator's GenericAnalyzer: any of name / startswith / contains / regex."""
    return (name in analyzer.get("name", []) or any(name.startswith(p) for p in analyzer.get("startswith", []))
            or any(c in name for c in analyzer.get("contains", [])) or any(re.search(r, name) for r in analyzer.get("regex", [])))


def test_the_aggregator_groups_every_published_status_exactly_once():
    parameters = yaml.safe_load(AGGREGATOR.read_text())["analyzers"]["ros__parameters"]
    analyzers = {key: value for key, value in parameters.items() if isinstance(value, dict)}
    assert all(a["type"] == "diagnostic_aggregator/GenericAnalyzer" and a["timeout"] > 1.0 for a in analyzers.values())
    for name in _published_status_names():
        groups = [key for key, analyzer in analyzers.items() if _matches(analyzer, name)]
        assert len(groups) == 1, f"{name}: grouped under {groups}"
    fdi = next(a for a in analyzers.values() if _matches(a, f"{topics.FDI_STATUS_PREFIX}boom"))
    assert fdi["remove_prefix"] == [topics.FDI_STATUS_PREFIX]


def test_an_aggregator_for_several_machines_groups_by_machine_then_function(capsys):
    from hydro_ros.cli import main as cli

    assert cli(["aggregator", "config", "--namespace", "m1", "--namespace", "/m2", "--namespace", ""]) == 0
    machines = yaml.safe_load(capsys.readouterr().out)["analyzers"]["ros__parameters"]
    groups = {key: value for key, value in machines.items() if isinstance(value, dict)}
    assert set(groups) == {"m1", "m2", "root"} and all(g["type"] == "diagnostic_aggregator/AnalyzerGroup" for g in groups.values())
    root_names = [name for name in _published_status_names() if not name.startswith("machine1/")]
    for machine, prefix in (("m1", "m1/"), ("m2", "m2/"), ("root", "")):
        for name in root_names:
            where = [(g, key, analyzer) for g, group in groups.items() for key, analyzer in group["analyzers"].items()
                     if _matches(analyzer, prefix + name)]
            assert len(where) == 1 and where[0][0] == machine, (prefix + name, [(g, k) for g, k, _ in where])
            shown = prefix + name
            for removed in where[0][2]["remove_prefix"]:
                shown = shown.removeprefix(removed)
            assert not shown.startswith(("m1/", "m2/")) and "hydro_ros/fdi/" not in shown, shown  # the leaf: boom, bus, ...


def _leaves(node) -> set[str]:
    return {node} if isinstance(node, str) else _leaves(node["first"]) | _leaves(node["second"])


def test_the_foxglove_layout_plots_the_residual_channels_it_names():
    layout = json.loads(LAYOUT.read_text())
    panels = layout["configById"]
    assert _leaves(layout["layout"]) == set(panels)  # every panel is placed, every placed panel configured
    channels = topics.fdi_residual_channels(load_machine_config(SAM_CONFIG).actuator_names)
    plotted = set()
    for panel_id, panel in panels.items():
        if panel_id.startswith("Plot!"):
            for series in panel["paths"]:
                match = re.fullmatch(re.escape(topics.FDI_RESIDUALS) + r"\.position\[(\d+)\](\.@negative)?", series["value"])
                assert match, series["value"]
                assert series["label"].split(" ")[0] == channels[int(match.group(1))], series
                plotted.add(channels[int(match.group(1))])
        elif panel_id.startswith(("DiagnosticSummary!", "DiagnosticStatusPanel!")):
            assert panel["topicToRender"] == topics.DIAGNOSTICS
    assert plotted == set(channels)  # both chambers' residuals and thresholds
    halt = next(p for k, p in panels.items() if k.startswith("Indicator!"))
    assert halt["path"] == f"{topics.FDI_HALT}.data" and halt["rules"][0]["rawValue"] == "true"
    transitions = next(p for k, p in panels.items() if k.startswith("StateTransitions!"))
    assert f'name=="{topics.FDI_STATUS_PREFIX}boom"' in transitions["paths"][0]["value"]


def test_the_shipped_layout_is_the_generated_one_and_follows_the_config():
    from hydro_ros.hmi.foxglove_layout import foxglove_layout

    assert json.loads(LAYOUT.read_text()) == foxglove_layout(load_machine_config(SAM_CONFIG)), \
        "regenerate: hydro-ros foxglove-layout --config config/sam.yaml --out config/foxglove_layout.json"
    mobile = foxglove_layout(load_machine_config(REPO / "config" / "sam_mobile.yaml"))
    labels = [series["label"] for panel in mobile["configById"].values() for series in panel.get("paths", []) if "position" in series["value"]]
    assert labels and all("[L/min]" in label for label in labels)  # parity residuals are flows


def test_a_layout_for_a_machine_in_a_namespace_reads_its_topics_and_its_namespaced_statuses():
    from hydro_ros.hmi.foxglove_layout import foxglove_layout

    layout = json.dumps(foxglove_layout(load_machine_config(SAM_CONFIG), "/machine1"))
    assert '"/machine1/fdi/halt.data"' in layout and '/machine1/fdi/residuals.position[' in layout
    assert f'"machine1/{topics.FDI_STATUS_PREFIX}boom"' in layout
    assert f'"topicToRender": "{topics.DIAGNOSTICS}"' in layout  # /diagnostics stays absolute
