"""Condition monitoring of the K70M's cylinders (make bench): per cylinder and leak, detection, isolation and delay while
the crane works the three P-VI paths; false alarms per hour of fault-free work.

The monitor is config/k70m.yaml's (parity method, its fitted thresholds: ``hydro-ros fdi-fit --config
config/k70m.yaml``). Every run is on a plant that differs from that config by fdi_evaluation's mismatch
(each notch +-5 %, bulk moduli +-25 %, centre leakage and friction +-30 %, noise level +-30 %), drawn per
seed from seeds no fit has seen, with 300 kg gripped at 1/3 and released at 2/3 of the run:
- leaks (external A, external B, internal; sizes in L/min at 10 MPa) in one named cylinder from 20 s of
  a 60 s run, the crane working a path's DP-CP trajectory forwards and back with 4 s holds: the first
  alarm on that cylinder after onset (detected), the right cylinder and fault named (isolated), alarms
  on any other cylinder, alarms before onset;
- fault-free: per seed, 120 s each of the random operator and of each path's work cycle; and again on
  plants drawn with twice the mismatch (each notch +-10 %, bulk moduli +-50 %, centre leakage and
  friction +-60 %), beyond anything the thresholds were fitted on.
Writes --out (bench/results/crane_monitoring.json), a Markdown table and a PNG beside it.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.machine import load_machine_config  # noqa: E402
from hydro_ros.fdi.rates import false_alarm_text  # noqa: E402
from hydro_ros.models.crane import load_crane  # noqa: E402
from hydro_ros.studies.crane_monitoring import (  # noqa: E402
    fault_cases,
    path_trajectories,
    run_crane_cases,
    summarise_crane,
    summarise_fault_free,
    work_cases,
)
from hydro_ros.tooling.benchresults import write_result  # noqa: E402

SIZES = (0.5, 1.0, 2.0)


def markdown(summary: dict) -> str:
    free = summary["fault_free"]
    doubled = summary["fault_free_doubled_mismatch"]
    lines = [f"Fault-free: {false_alarm_text(free['alarms'], free['hours'], 'alarm')} of work; with twice the mismatch "
             f"{false_alarm_text(doubled['alarms'], doubled['hours'], 'alarm')}.", "",
             "| cylinder | fault | L/min at 10 MPa | detected | isolated (cylinder and fault) | other cylinder alarmed | median delay [s] | "
             "named at the end |",
             "|---|---|---|---|---|---|---|---|"]
    for row in summary["faults"]:
        delay = "-" if row["median_delay_s"] is None else f"{row['median_delay_s']:.1f}"
        lines.append(f"| {row['actuator']} | {row['fault']} | {row['value_l_min']:g} | {row['detected']}/{row['runs']} | "
                     f"{row['isolated']}/{row['runs']} | {row['other_cylinder_alarms']}/{row['runs']} | {delay} | "
                     f"{', '.join(f'{name} {n}' for name, n in sorted(row['named'].items())) or '-'} |")
    return "\n".join(lines) + "\n"


def plot(summary: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = summary["faults"]
    actuators = sorted({r["actuator"] for r in rows})
    faults = sorted({r["fault"] for r in rows})
    fig, axes = plt.subplots(1, len(actuators), figsize=(4.2 * len(actuators), 3.6), sharey=True)
    for ax, actuator in zip(axes, actuators):
        for fault in faults:
            chosen = [r for r in rows if r["actuator"] == actuator and r["fault"] == fault]
            ax.plot([r["value_l_min"] for r in chosen], [r["isolated"] / r["runs"] for r in chosen], "o-", label=fault)
        ax.set_title(actuator)
        ax.set_xlabel("leak [L/min at 10 MPa]")
        ax.set_ylim(-0.05, 1.05)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("isolated share (right cylinder and fault)")
    axes[-1].legend(fontsize=8)
    free = summary["fault_free"]
    fig.suptitle(f"K70M cylinders working the P-VI paths on mismatched plants; fault-free: {free['false_alarms_per_hour']:.2f} false alarms/h")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "k70m.yaml"))
    parser.add_argument("--out", default="bench/results/crane_monitoring.json")
    parser.add_argument("--seeds", type=int, default=2, help="mismatched plants per cylinder, leak, size and path")
    parser.add_argument("--fault-free-seeds", type=int, default=4, help="plants of fault-free work (operator and every path)")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    machine = load_machine_config(args.config)
    _, crane_config = load_crane(args.config)
    trajectories = path_trajectories(crane_config)
    paths = list(trajectories)
    faulty = fault_cases(range(700, 700 + args.seeds), machine.actuator_names, paths, SIZES, 60.0, 20.0)
    free = work_cases(range(800, 800 + args.fault_free_seeds), paths, 120.0, 1.0)
    doubled = work_cases(range(850, 850 + args.fault_free_seeds // 2), paths, 120.0, 2.0)
    start = time.perf_counter()
    with tqdm(total=len(faulty) + len(free) + len(doubled), unit="run", desc="crane monitoring") as bar:
        free_outcomes = run_crane_cases(machine, trajectories, free, workers=args.workers, progress=bar.update)
        doubled_outcomes = run_crane_cases(machine, trajectories, doubled, workers=args.workers, progress=bar.update)
        fault_outcomes = run_crane_cases(machine, trajectories, faulty, workers=args.workers, progress=bar.update)
    summary = summarise_crane(fault_outcomes, free_outcomes)
    summary["fault_free_doubled_mismatch"] = summarise_fault_free(doubled_outcomes)
    summary["setup"] = {"config": Path(args.config).name, "paths": paths, "trajectory_method": "dp_cp", "sizes_l_min": list(SIZES),
                        "fault_seeds": args.seeds, "fault_free_seeds": args.fault_free_seeds, "fault_run_s": 60.0, "onset_s": 20.0,
                        "fault_free_run_s": 120.0, "payload_kg": 300.0, "runtime_s": time.perf_counter() - start}
    summary["false_alarm_runs"] = [{"seed": o.case.seed, "mismatch": o.case.mismatch, "path": o.case.path or "operator", "alarms": o.alarms}
                                   for o in free_outcomes + doubled_outcomes if o.alarms]
    out = Path(args.out)
    out.with_suffix(".md").write_text(markdown(summary))
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(markdown(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
