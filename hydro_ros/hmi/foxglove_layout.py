"""The Foxglove layout of a machine, generated from its config: every actuator's status, fault history
and residual plots, each series labelled with its /fdi/residuals channel name.

/fdi/residuals is a JointState whose ``name`` lists the channels (``topics.fdi_residual_channels``);
Foxglove's message paths index ``position`` by number, so the indices are computed here from the
same layout the node publishes, never written by hand. ``hydro-ros foxglove layout`` writes it;
config/foxglove_layout.json is the SAM's.
"""

from __future__ import annotations

from typing import Any

from hydro_ros.contract import topics
from hydro_ros.contract.machine import Machine

RESIDUAL_COLOR, THRESHOLD_COLOR = "#1565c0", "#c62828"


def _series(residuals: str, index: int, label: str, color: str, negative: bool = False) -> dict[str, Any]:
    return {"value": f"{residuals}.position[{index}]" + (".@negative" if negative else ""),
            "label": label + (" (negative)" if negative else ""), "enabled": True, "timestampMethod": "headerStamp", "color": color}


def _stack(ids: list[Any], direction: str = "column") -> Any:
    """Panels split evenly along ``direction`` (Foxglove's binary mosaic tree)."""
    if len(ids) == 1:
        return ids[0]
    return {"direction": direction, "first": ids[0], "second": _stack(ids[1:], direction), "splitPercentage": round(100 / len(ids))}


def foxglove_layout(machine: Machine, namespace: str = "") -> dict[str, Any]:
    """The layout of ``machine``; in ``namespace`` its topics are there and its statuses on the absolute /diagnostics carry
    the namespace in their names (nodes.common.namespaced_statuses)."""
    ns = namespace.strip("/")
    halt, residuals = (f"/{ns}{topic}" if ns else topic for topic in (topics.FDI_HALT, topics.FDI_RESIDUALS))
    actuators = machine.actuator_names
    channels = topics.fdi_residual_channels(actuators, mobile=machine.mobile)
    unit = "L/min" if machine.mobile else "MPa"
    panels: dict[str, Any] = {
        "Indicator!halt": {"title": f"Halt request ({halt})", "path": f"{halt}.data", "style": "background",
                           "fallbackColor": "#2e7d32", "fallbackLabel": "no halt request",
                           "rules": [{"operator": "=", "rawValue": "true", "color": "#c62828",
                                      "label": "HALT: a severe fault or the monitor not vouching (hydro_ros/fdi_halt says which)"}]},
        "DiagnosticSummary!hydro_ros": {"topicToRender": topics.DIAGNOSTICS, "minLevel": 0, "pinnedIds": [], "hardwareIdFilter": "",
                                        "sortByLevel": True},
    }
    status_column, plots = [], []
    for actuator in actuators:
        name = f"{ns + '/' if ns else ''}{topics.FDI_STATUS_PREFIX}{actuator}"
        panels[f"DiagnosticStatusPanel!{actuator}"] = {"topicToRender": topics.DIAGNOSTICS, "selectedHardwareId": machine.name,
                                                       "selectedName": name}
        panels[f"StateTransitions!{actuator}"] = {
            "paths": [{"value": f'{topics.DIAGNOSTICS}.status[:]{{name=="{name}"}}.message', "label": f"{actuator}: fault name",
                       "timestampMethod": "receiveTime"}], "isSynced": True}
        status_column.append({"direction": "column", "first": f"DiagnosticStatusPanel!{actuator}",
                              "second": f"StateTransitions!{actuator}", "splitPercentage": 65})
        for chamber in "AB":
            residual = channels.index(next(c for c in channels if c.startswith(f"{actuator}/mean_r_") and c.endswith(chamber)))
            threshold = channels.index(next(c for c in channels if c.startswith(f"{actuator}/threshold_") and c.endswith(chamber)))
            panel = f"Plot!{actuator}_{chamber}"
            panels[panel] = {
                "title": f"{actuator} chamber {chamber}: residual against its adaptive threshold",
                "paths": [_series(residuals, residual, f"{channels[residual]} [{unit}]", RESIDUAL_COLOR),
                          _series(residuals, threshold, f"{channels[threshold]} [{unit}]", THRESHOLD_COLOR),
                          _series(residuals, threshold, f"{channels[threshold]} [{unit}]", THRESHOLD_COLOR, negative=True)],
                "showXAxisLabels": True, "showYAxisLabels": True, "showLegend": True, "legendDisplay": "floating", "isSynced": True,
                "xAxisVal": "timestamp", "followingViewWidth": 60}
            plots.append(panel)
    left = {"direction": "column", "first": "Indicator!halt",
            "second": {"direction": "column", "first": "DiagnosticSummary!hydro_ros", "second": _stack(status_column), "splitPercentage": 35},
            "splitPercentage": 12}
    return {"configById": panels, "globalVariables": {}, "userNodes": {}, "playbackConfig": {"speed": 1},
            "layout": {"direction": "row", "first": left, "second": _stack(plots), "splitPercentage": 40}}
