"""Commissioning the K70M's cylinders (make bench): what the crane's own fault-free work buys its monitor.

Each plant is a crane that differs from config/k70m.yaml by fdi_evaluation's mismatch (every notch
+-5 %, bulk moduli +-25 %, centre leakage, friction and noise +-30 %, drawn per plant). It is
commissioned (`hydro_ros.workflows.commissioning.commission`, as `hydro-ros commission` on its bags) on
its own fault-free work: the operator twice for 2 min and each P-VI path's cycle for 1 min, 300 kg
gripped and released in each (`crane_monitoring.commissioning_recordings`). Then, on runs no fit has
seen, of the same plant:
- fault-free work (the operator and the three paths, 90 s each, payload steps), monitored with the
  shipped config (thresholds for a crane never seen) and with the commissioned one: false alarms;
- a leak in one cylinder from 20 s while the crane works a path (each plant its own path), 0.25 and
  0.5 L/min at 10 MPa (the shipped thresholds name none below 1 L/min, bench/results/crane_monitoring.json):
  detected on that cylinder, named, delay, any alarm on another cylinder or before onset.
Writes --out (bench/results/crane_commissioning.json) and a PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.errors import InputError  # noqa: E402
from hydro_ros.contract.machine import load_machine_config  # noqa: E402
from hydro_ros.fdi.parity import FLOW_EDGES, POINT_CHANNELS  # noqa: E402
from hydro_ros.fdi.settings import FdiSettings  # noqa: E402
from hydro_ros.models.crane import load_crane  # noqa: E402
from hydro_ros.studies.crane_monitoring import (  # noqa: E402
    commissioning_recordings,
    fault_cases,
    path_trajectories,
    run_crane_cases,
    summarise_crane,
    summarise_fault_free,
    work_cases,
)
from hydro_ros.studies.fdi_evaluation import mismatched_config  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402
from hydro_ros.workflows.commissioning import commission  # noqa: E402

SIZES = (0.25, 0.5)
BIN_FLOWS = (0.5, 1.5, 3.0, 6.0, 12.0, 30.0)  # [L/min] one operating point inside each of FLOW_EDGES' bins


def thresholds_at_bins(machine) -> list[list[float]]:
    """[L/min] the (A, B) threshold at a mean valve flow inside each bin."""
    point = np.zeros((len(BIN_FLOWS), POINT_CHANNELS))
    point[:, 1] = point[:, 2] = BIN_FLOWS
    return np.round(FdiSettings.from_machine(machine).parity_thresholds(point), 3).tolist()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "k70m.yaml"))
    parser.add_argument("--out", default="bench/results/crane_commissioning.json")
    parser.add_argument("--plants", type=int, default=4)
    parser.add_argument("--fault-free-seeds", type=int, default=2, help="per plant: the operator and each path, 90 s each")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    assert len(BIN_FLOWS) == len(FLOW_EDGES) - 1
    nominal = load_machine_config(args.config)
    _, crane = load_crane(args.config)
    trajectories = path_trajectories(crane)
    paths = list(trajectories)
    actuators = nominal.actuator_names
    start = time.perf_counter()
    plants, faults, fault_free = [], [], {"shipped": [], "commissioned": []}
    per_plant_runs = 2 * args.fault_free_seeds * (1 + len(paths)) + len(actuators) * 3 * len(SIZES)
    bar = tqdm(total=args.plants * per_plant_runs, unit="run", desc="crane commissioning")
    for k, plant_seed in enumerate(range(700, 700 + args.plants)):
        plant = mismatched_config(nominal, plant_seed)
        began = time.perf_counter()
        recordings = commissioning_recordings(plant, trajectories, 1)
        try:
            block, report = commission(nominal, recordings)
        except InputError as refused:  # a refusal is a result: the plant stays on the shipped thresholds
            plants.append({"plant_seed": plant_seed, "refused": str(refused)})
            bar.update(per_plant_runs)
            continue
        commission_s = time.perf_counter() - began
        commissioned = nominal.with_overrides(block["model"])
        free = work_cases(range(50, 50 + args.fault_free_seeds), paths, 90.0, 1.0)
        alarms = {}
        for name, machine in (("shipped", nominal), ("commissioned", commissioned)):
            outcomes = run_crane_cases(machine, trajectories, free, plant=plant, workers=args.workers, progress=bar.update)
            fault_free[name] += outcomes
            alarms[name] = [{"run": f"{o.case.seed}/{o.case.path or 'operator'}", **a} for o in outcomes for a in o.alarms]
        leaks = fault_cases([60], actuators, [paths[k % len(paths)]], SIZES, 60.0, 20.0)
        faults += run_crane_cases(commissioned, trajectories, leaks, plant=plant, workers=args.workers, progress=bar.update)
        plants.append({"plant_seed": plant_seed, "path": paths[k % len(paths)], "commission_s": round(commission_s, 1),
                       "recorded_s": round(sum(float(r.samples.times[-1] - r.samples.times[0]) for r in recordings), 1),
                       "fit": block["fit"], "threshold": {key: report["threshold"][key] for key in ("form", "reached", "value")},
                       "thresholds_l_min": {"shipped": thresholds_at_bins(nominal), "commissioned": thresholds_at_bins(commissioned)},
                       "fault_free_alarms": alarms})
    bar.close()
    plants, refused = [p for p in plants if "refused" not in p], [p for p in plants if "refused" in p]
    summary = {
        "refused": refused,
        "config": str(Path(args.config).resolve().relative_to(REPO)) if Path(args.config).resolve().is_relative_to(REPO) else args.config,
        "plants": len(plants), "sizes_l_min": list(SIZES), "bin_flows_l_min": list(BIN_FLOWS), "flow_edges_l_min": list(FLOW_EDGES),
        "fault_free": {name: summarise_fault_free(outcomes) for name, outcomes in fault_free.items()},
        "thresholds_median_l_min": {name: np.median([p["thresholds_l_min"][name] for p in plants], axis=0).round(3).tolist()
                                    for name in ("shipped", "commissioned")},
        "faults": summarise_crane(faults, [])["faults"],
        "commission_s_per_plant": float(np.mean([p["commission_s"] for p in plants])),
        "wall_s": round(time.perf_counter() - start, 1), "per_plant": plants,
    }
    out = Path(args.out)
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps({k: v for k, v in summary.items() if k != "per_plant"}, indent=2))
    return 0


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    bins = np.arange(len(summary["bin_flows_l_min"]))
    for offset, name, color in ((-0.2, "shipped", "0.6"), (0.2, "commissioned", "tab:blue")):
        values = np.asarray(summary["thresholds_median_l_min"][name])
        axes[0].bar(bins + offset - 0.1, values[:, 0], width=0.2, color=color, label=f"{name} A")
        axes[0].bar(bins + offset + 0.1, values[:, 1], width=0.2, color=color, alpha=0.6, label=f"{name} B")
    axes[0].set_xticks(bins, [f"{q:g}" for q in summary["bin_flows_l_min"]])
    axes[0].set_xlabel("chamber's 5 s mean valve flow [L/min]")
    axes[0].set_ylabel(f"threshold [L/min], median of {summary['plants']} plants")
    axes[0].legend(fontsize=7)
    axes[0].grid(alpha=0.3, axis="y")
    rows = summary["faults"]
    labels = [f"{r['actuator']} {r['fault'].replace('external_leakage_', 'ext ').replace('internal_leakage', 'int')} {r['value_l_min']:g}"
              for r in rows]
    axes[1].barh(labels, [r["isolated"] / r["runs"] for r in rows], color="tab:blue", label="named on its cylinder")
    axes[1].barh(labels, [r["other_cylinder_alarms"] / r["runs"] for r in rows], color="tab:red", label="alarm on another cylinder")
    axes[1].set_xlabel(f"share of {summary['plants']} commissioned plants")
    axes[1].tick_params(axis="y", labelsize=7)
    ff = summary["fault_free"]
    axes[1].set_title(f"fault-free: shipped {ff['shipped']['alarms']} / commissioned {ff['commissioned']['alarms']} alarms "
                      f"in {ff['commissioned']['hours']:.2f} h each", fontsize=9)
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    sys.exit(main())
