"""Commissioning a machine built apart from the model (make bench): what 2, 4 and 8 minutes of its work buy.

Each rig is one build of the config (config/boom_arm.yaml; config/sam.yaml as the one link its load describes) by
hydro_ros.studies.independent_arm (its own chain dynamics, tabulated
notches each drawn off, lines, Stribeck friction, warming oil, a drooping supply, its own operator and sensors). It is
commissioned (`commission`, as `hydro-ros commission` on its bags) from its fault-free work of 2 minutes (2 x 60 s), 4
minutes (2 x 120 s, the documented minimum) and 8 minutes (4 x 120 s), payload picked up and set down in every
other recording. Then, on runs of that rig no fit has seen (other moves, speeds, payloads and oil temperatures):
- fault-free work: false alarms per hour with the upper end of their 95 % exact Poisson interval (two-sided), and the share of the time each
  actuator is held outside the commissioned valve commands; the same for the config as shipped, not commissioned;
- a leak from 20 s of each kind on each cylinder (external A, external B, internal; 0.25, 0.5, 1, 2 L/min at 10 MPa):
  the smallest size named on its cylinder with its name, nothing on the other cylinder, nothing before onset; and the
  smallest detected there (any alarm on its cylinder after onset, ``unisolated`` included).
Writes --out (bench/results/arm_commissioning.json; sam_commissioning_apart.json for the SAM) and a PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.errors import InputError  # noqa: E402
from hydro_ros.contract.machine import Machine, load_machine_config  # noqa: E402
from hydro_ros.fdi.monitor import FdiMonitor  # noqa: E402
from hydro_ros.fdi.offline import run_monitor  # noqa: E402
from hydro_ros.fdi.rates import CONFIDENCE, false_alarm_rate  # noqa: E402
from hydro_ros.studies import independent_arm as plant  # noqa: E402
from hydro_ros.studies.fdi_evaluation import parallel_map, smallest_leaks  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402
from hydro_ros.workflows.commissioning import FaultFreeRecording, commission  # noqa: E402

TRAINING = {"2 min": (2, 60.0), "4 min": (2, 120.0), "8 min": (4, 120.0)}  # recordings x seconds
SHIPPED = "shipped"  # the config as it comes, not commissioned
SIZES = (0.25, 0.5, 1.0, 2.0)  # [L/min at 10 MPa]
ONSET_S, RUN_S = 20.0, 60.0


def _commission(job: tuple[Machine, int, str]) -> tuple[str, dict | str]:
    machine, rig, level = job
    count, seconds = TRAINING[level]
    recordings = [FaultFreeRecording(f"rig{rig}/{level}/{w.seed}", plant.recording(machine, rig, w))
                  for w in plant.work_day(machine, range(101, 101 + count), seconds)]
    try:
        block, _ = commission(machine, recordings)
    except InputError as refused:  # a refusal is a result: the rig stays on its shipped threshold
        return level, str(refused)
    return level, block


def _evaluate(job: tuple[Machine, int, plant.ArmWork, dict[str, Machine]]) -> dict:
    """One run of the rig, simulated once and monitored with each level's commissioned config."""
    machine, rig, work, configs = job
    samples = plant.recording(machine, rig, work)
    out = {"seed": work.seed, "faults": [list(f) for f in work.faults], "levels": {}}
    for level, config in configs.items():
        monitor = FdiMonitor(config)
        run = run_monitor(monitor, samples)
        out["levels"][level] = {"alarms": [a.to_json() for a in run.alarms], "held": monitor.outside_held_samples.tolist(),
                                "evaluated": int(monitor.evaluated_samples)}
    return out


def summarise(machine: Machine, runs: list[dict], levels: list[str]) -> dict:
    actuators = machine.actuator_names
    free = [r for r in runs if not r["faults"]]
    hours = len(free) * RUN_S / 3600.0
    out = {}
    for level in levels:
        alarms = [dict(a, seed=r["seed"]) for r in free for a in r["levels"][level]["alarms"]]
        held = np.sum([r["levels"][level]["held"] for r in free], axis=0)
        evaluated = sum(r["levels"][level]["evaluated"] for r in free)
        smallest = {chamber: {"size_l_min": found["named_l_min"], "delay_s": found["delay_s"], "detected_l_min": found["detected_l_min"]}
                    for chamber, found in smallest_leaks(runs, actuators, plant.LEAKS, ONSET_S,
                                                         lambda run, level=level: run["levels"][level]["alarms"]).items()}
        out[level] = {"fault_free_hours": round(hours, 3), "false_alarms": len(alarms),
                      "per_hour_upper": round(false_alarm_rate(len(alarms), hours)[2], 2), "alarms": alarms,
                      "held_share": {a: round(float(h) / max(evaluated, 1), 4) for a, h in zip(actuators, held)},
                      "smallest_named_l_min": smallest}
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "boom_arm.yaml"))
    parser.add_argument("--out", default="bench/results/arm_commissioning.json")
    parser.add_argument("--rigs", type=int, default=3)
    parser.add_argument("--fault-free", type=int, default=16, help="fault-free runs of 60 s per rig")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    machine = load_machine_config(args.config)
    start = time.perf_counter()
    levels = list(TRAINING)
    leaks = [(a, f, s) for a in machine.actuator_names for f in plant.LEAKS for s in SIZES]
    bar = tqdm(total=args.rigs * (len(levels) + args.fault_free + len(leaks)), unit="job", desc="arm commissioning")
    rigs = []
    for rig in range(1, 1 + args.rigs):
        blocks = dict(parallel_map(_commission, [(machine, rig, level) for level in levels], workers=args.workers, progress=bar.update))
        configs = {SHIPPED: machine, **{level: machine.with_overrides(b["model"]) for level, b in blocks.items() if isinstance(b, dict)}}
        work = plant.work_day(machine, range(201, 201 + args.fault_free), RUN_S) + [
            plant.ArmWork(RUN_S, 301 + k, faults=((a, f, s, ONSET_S),)) for k, (a, f, s) in enumerate(leaks)]
        runs = parallel_map(_evaluate, [(machine, rig, w, configs) for w in work], workers=args.workers, progress=bar.update)
        rigs.append({"rig": rig, "refused": {level: b for level, b in blocks.items() if isinstance(b, str)},
                     "fit": {level: b["fit"] for level, b in blocks.items() if isinstance(b, dict)},
                     "threshold_c0_mpa": {level: round(b["model"]["fdi"]["threshold_constant"], 4)
                                          for level, b in blocks.items() if isinstance(b, dict)},
                     "levels": summarise(machine, runs, list(configs))})
    bar.close()
    pooled = {}
    for level in [SHIPPED, *levels]:
        done = [r["levels"][level] for r in rigs if level in r["levels"]]
        hours = sum(d["fault_free_hours"] for d in done)
        alarms = sum(d["false_alarms"] for d in done)
        pooled[level] = {
            "rigs": len(done), "refused": sum(level in r["refused"] for r in rigs),
            **({"threshold_c0_mpa": machine.fdi.get("threshold_constant")} if level == SHIPPED else {}), "fault_free_hours": round(hours, 3),
            "false_alarms": alarms, "per_hour_upper": round(false_alarm_rate(alarms, hours)[2], 2) if hours else None,
            "held_share_max": max((max(d["held_share"].values()) for d in done), default=None),
            "held_share_mean": round(float(np.mean([v for d in done for v in d["held_share"].values()])), 4) if done else None,
            "held_share_by_actuator": {a: round(float(np.mean([d["held_share"][a] for d in done])), 4)
                                       for a in machine.actuator_names} if done else {},
            "smallest_named_l_min": {key: [d["smallest_named_l_min"][key]["size_l_min"] for d in done]
                                     for key in (done[0]["smallest_named_l_min"] if done else {})},
            "smallest_detected_l_min": {key: [d["smallest_named_l_min"][key]["detected_l_min"] for d in done]
                                        for key in (done[0]["smallest_named_l_min"] if done else {})},
        }
    summary = {"plant": plant.__name__, "config": str(Path(args.config).resolve().relative_to(REPO)), "training": TRAINING,
               "sizes_l_min": list(SIZES), "run_s": RUN_S, "onset_s": ONSET_S, "confidence": CONFIDENCE, "pooled": pooled,
               "wall_s": round(time.perf_counter() - start, 1), "per_rig": rigs}
    out = Path(args.out)
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps(pooled, indent=2))
    return 0


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    pooled = summary["pooled"]
    levels = [level for level in pooled if pooled[level]["rigs"]]
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    x = np.arange(len(levels))
    axes[0].bar(x - 0.2, [pooled[level]["per_hour_upper"] for level in levels], width=0.4, color="tab:red",
                label=f"false alarms per hour, upper end of the {summary['confidence']:.0%} exact Poisson interval")
    twin = axes[0].twinx()
    twin.bar(x + 0.2, [100 * pooled[level]["held_share_max"] for level in levels], width=0.4, color="0.6",
             label="held outside the commissioned commands, worst actuator [%]")
    axes[0].set_xticks(x, [f"{level}\n{pooled[level]['false_alarms']} alarms in {pooled[level]['fault_free_hours']:.1f} h"
                           for level in levels])
    axes[0].set_ylabel("[1/h]")
    twin.set_ylabel("[%]")
    axes[0].set_title(f"fault-free work of {pooled[levels[0]]['rigs']} rigs it never trained on", fontsize=9)
    fig.legend(loc="upper left", fontsize=7)
    keys = list(pooled[levels[0]]["smallest_named_l_min"])
    width = 0.8 / len(levels)
    for k, level in enumerate(levels):
        per_rig = [pooled[level]["smallest_named_l_min"][key] for key in keys]
        sizes = [0.0 if None in sizes or not sizes else max(sizes) for sizes in per_rig]
        axes[1].barh(np.arange(len(keys)) + k * width, sizes, height=width, label=level)
    axes[1].set_yticks(np.arange(len(keys)) + 0.4 - width / 2, keys, fontsize=7)
    axes[1].set_xlabel(f"smallest leak named on every rig [L/min at 10 MPa] (0: not named at {max(summary['sizes_l_min']):g})")
    axes[1].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
