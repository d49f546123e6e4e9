"""The K70M built apart from the model, commissioned on its own work (make bench): what its monitor can and cannot say.

Each rig is one build of config/k70m.yaml by hydro_ros.studies.independent_arm (its own chain dynamics with the
telescope sliding on the tilt link, mobile valves with drawn overlaps, tabulated notches each drawn off, hoses with
their laminar drop, a compensator spring, a lagging pilot stage, warming oil, its own operator and sensors). It is
commissioned (`commission`, as `hydro-ros commission` on its bags) on its fault-free day
(`crane_monitoring.apart_commissioning_work`: the operator 2 x 2 min at half lever, each path's cycle 1 min, 300 kg
gripped and released), with force where commissioning refuses thresholds above the shipped ones. Then, on runs of the
rig no fit has seen:
- fault-free work (per seed the operator and each path, 60 s each, 300 kg gripped and released), monitored with the
  shipped config and with the commissioned one: false alarms with the upper end of their 95 % exact Poisson interval,
  and when the first alarm of a run came;
- a leak from 20 s of each kind on each cylinder (0.5, 1, 2 L/min at 10 MPa) while the crane works its half cycle with
  300 kg gripped at 10 s:
  the smallest size named on its cylinder with its name and nothing elsewhere or before onset, the smallest detected;
- which of the plant's effects the model lacks: the first rig rebuilt with its overlaps, the spread of its notch tables
  (with its compensators' drop and pilot gains, drawn by the same spread) and
  its hoses' line drop off, then each switched on alone (the pilot lag, compensator spring, transmitter zeros and warming
  oil stay on throughout), monitored with the shipped config: the 95th percentile of |5 s mean residual| and the alarms.
Writes --out (bench/results/crane_apart.json) and a PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.machine import Machine, load_machine_config  # noqa: E402
from hydro_ros.fdi.monitor import FdiMonitor  # noqa: E402
from hydro_ros.fdi.offline import run_monitor  # noqa: E402
from hydro_ros.fdi.rates import CONFIDENCE, false_alarm_rate  # noqa: E402
from hydro_ros.models.crane import load_crane  # noqa: E402
from hydro_ros.studies import independent_arm as plant  # noqa: E402
from hydro_ros.studies.crane_monitoring import apart_commissioning_work, path_trajectories  # noqa: E402
from hydro_ros.studies.fdi_evaluation import parallel_map, smallest_leaks  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402
from hydro_ros.workflows.commissioning import FaultFreeRecording, above_shipped, commission  # noqa: E402

SIZES = (0.5, 1.0, 2.0)  # [L/min at 10 MPa]
ONSET_S, RUN_S = 20.0, 60.0
PAYLOAD_KG = 300.0
LEAK_PATH = "half_cycle"
# the effects the study switches: all off, then each alone on (the others of the plant stay on throughout)
OFF = {"overlap_spread": 0.0, "notch_gain": 0.0, "table_point": 0.0, "line_resistance_scale": 0.0}
# notch_gain also draws each compensator's drop and pilot gain off their sheet values: the second effect is all three
EFFECTS = {"none of the three": {}, "built overlaps": {"overlap_spread": plant.RigSpread.overlap_spread},
           "notch, compensator and pilot spread": {"notch_gain": plant.RigSpread.notch_gain, "table_point": plant.RigSpread.table_point},
           "hoses' line drop": {"line_resistance_scale": 1.0}, "all three (the rig)": {k: getattr(plant.RigSpread, k) for k in OFF}}


def _record(job: tuple[Machine, int, plant.RigSpread, plant.ArmWork]) -> plant.Samples:
    machine, rig, spread, work = job
    return plant.recording(machine, rig, work, spread)


def _evaluate(job: tuple[Machine, int, plant.RigSpread, tuple[str, plant.ArmWork], dict[str, Machine]]) -> dict:
    """One run of the rig, simulated once and monitored with each config."""
    machine, rig, spread, (label, work), configs = job
    samples = _record((machine, rig, spread, work))
    out = {"seed": work.seed, "path": label, "faults": [list(f) for f in work.faults],
           "configs": {}}
    for name, config in configs.items():
        run = run_monitor(FdiMonitor(config), samples)
        residual = np.abs(run.residual_mean[np.isfinite(run.residual_mean).all(axis=2).all(axis=1)])
        out["configs"][name] = {"alarms": [a.to_json() for a in run.alarms],
                                "residual_p95_l_min": {a: round(float(np.percentile(residual[:, i], 95)), 3) if len(residual) else None
                                                       for i, a in enumerate(machine.actuator_names)}}
    return out


def _work(trajectories: dict, seed: int, path: str | None, faults: tuple = ()) -> tuple[str, plant.ArmWork]:
    """A run of 60 s, named: the operator at half lever or a path's cycle, the payload gripped at 20 s and released at 40 s,
    or, with a leak from 20 s, gripped at 10 s and held (its step apart from the onset)."""
    steps = ((10.0, PAYLOAD_KG),) if faults else ((20.0, PAYLOAD_KG), (40.0, 0.0))
    return path or "operator", plant.ArmWork(RUN_S, seed, payload_steps=steps, faults=faults, lever_limit=0.5,
                                             path=None if path is None else trajectories[path])


def fault_free_summary(runs: list[dict], config: str) -> dict:
    free = [r for r in runs if not r["faults"]]
    hours = len(free) * RUN_S / 3600.0
    alarms = [dict(a, seed=r["seed"], path=r["path"]) for r in free for a in r["configs"][config]["alarms"]]
    firsts = [r["configs"][config]["alarms"][0]["time_s"] for r in free if r["configs"][config]["alarms"]]
    high = false_alarm_rate(len(alarms), hours)[2]
    return {"runs": len(free), "hours": round(hours, 3), "false_alarms": len(alarms), "runs_alarmed": len(firsts),
            "per_hour_upper": high, "first_alarm_s": [round(min(firsts), 1), round(max(firsts), 1)] if firsts else None,
            "alarms": alarms[:20]}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "k70m.yaml"))
    parser.add_argument("--out", default="bench/results/crane_apart.json")
    parser.add_argument("--rigs", type=int, nargs="+", default=[2, 3], help="rig seeds (2 is the test's)")
    parser.add_argument("--fault-free-seeds", type=int, default=3, help="per rig: the operator and each path, 60 s each")
    parser.add_argument("--sizes", type=float, nargs="+", default=list(SIZES), help="leak sizes [L/min at 10 MPa]")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    machine = load_machine_config(args.config)
    trajectories = path_trajectories(load_crane(args.config)[1])
    day = apart_commissioning_work(trajectories, PAYLOAD_KG)
    leaks = [(a, f, s) for a in machine.actuator_names for f in plant.LEAKS for s in args.sizes]
    free_runs = (1 + len(trajectories)) * args.fault_free_seeds
    start = time.perf_counter()
    bar = tqdm(total=len(args.rigs) * (len(day) + free_runs + len(leaks)) + 2 * len(EFFECTS), unit="run", desc="crane apart")
    rigs = []
    spread = plant.RigSpread()
    for rig in args.rigs:
        began = time.perf_counter()
        samples = parallel_map(_record, [(machine, rig, spread, work) for _, work in day], workers=args.workers, progress=bar.update)
        block, report = commission(machine, [FaultFreeRecording(name, s) for (name, _), s in zip(day, samples)], force=True)
        commission_s = time.perf_counter() - began
        configs = {"shipped": machine, "commissioned": machine.with_overrides(block["model"])}
        built = plant.build_rig(machine, rig).cylinder[:, plant._C_OVERLAP]
        work = [_work(trajectories, 50 + k, path) for k in range(args.fault_free_seeds) for path in (None, *trajectories)]
        work += [_work(trajectories, 60 + k, LEAK_PATH, ((a, f, s, ONSET_S),)) for k, (a, f, s) in enumerate(leaks)]
        runs = parallel_map(_evaluate, [(machine, rig, spread, w, configs) for w in work], workers=args.workers, progress=bar.update)
        threshold = report["threshold"]
        rigs.append({
            "rig": rig, "commission_s": round(commission_s, 1), "refused_unforced": above_shipped(threshold),
            "mean_threshold_at_rest_l_min": threshold["mean_threshold_l_min"],
            "shipped_alarms_on_held_out": threshold["config_alarms_on_held_out"]["count"],
            "leaks_read_l_min": {i["actuator"]: round(max(i["leaks_l_min"].values()), 3) for i in report["identification"]},
            "overlap": {a: {"built": round(float(b), 4), "fitted": round(block["model"]["actuators"][a]["valve"]["deadzone"], 4)}
                        for a, b in zip(machine.actuator_names, built)},
            "fault_free": {name: fault_free_summary(runs, name) for name in configs},
            "leaks": {name: smallest_leaks(runs, machine.actuator_names, plant.LEAKS, ONSET_S,
                                            lambda run, name=name: run["configs"][name]["alarms"]) for name in configs}})
    # which effects the model lacks: the first rig with the three switched, the shipped monitor on its operator and a path
    effects = {}
    for label, on in EFFECTS.items():
        variant = replace(spread, **{**OFF, **on})
        runs = parallel_map(_evaluate, [(machine, args.rigs[0], variant, _work(trajectories, 70, path), {"shipped": machine})
                                        for path in (None, LEAK_PATH)], workers=args.workers, progress=bar.update)
        effects[label] = {"residual_p95_l_min": max(v for r in runs for v in r["configs"]["shipped"]["residual_p95_l_min"].values()),
                          "alarms": sum(len(r["configs"]["shipped"]["alarms"]) for r in runs)}
    bar.close()
    pooled = {}
    for name in ("shipped", "commissioned"):
        hours = sum(r["fault_free"][name]["hours"] for r in rigs)
        alarms = sum(r["fault_free"][name]["false_alarms"] for r in rigs)
        pooled[name] = {"rigs": len(rigs), "hours": round(hours, 3), "false_alarms": alarms,
                        "runs_alarmed": sum(r["fault_free"][name]["runs_alarmed"] for r in rigs),
                        "runs": sum(r["fault_free"][name]["runs"] for r in rigs),
                        "per_hour_upper": false_alarm_rate(alarms, hours)[2],
                        "named_l_min": {key: [r["leaks"][name][key]["named_l_min"] for r in rigs] for key in rigs[0]["leaks"][name]},
                        "detected_l_min": {key: [r["leaks"][name][key]["detected_l_min"] for r in rigs] for key in rigs[0]["leaks"][name]}}
    summary = {"plant": plant.__name__, "config": str(Path(args.config).resolve().relative_to(REPO)), "rigs": args.rigs,
               "sizes_l_min": args.sizes, "run_s": RUN_S, "onset_s": ONSET_S, "leak_path": LEAK_PATH, "payload_kg": PAYLOAD_KG,
               "confidence": CONFIDENCE, "pooled": pooled, "effects_rig": args.rigs[0], "effects": effects,
               "wall_s": round(time.perf_counter() - start, 1), "per_rig": rigs}
    out = Path(args.out)
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps({k: v for k, v in summary.items() if k != "per_rig"}, indent=2))
    return 0


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5))
    pooled = summary["pooled"]
    keys = list(pooled["commissioned"]["named_l_min"])
    width = 0.4
    for k, (name, color) in enumerate((("shipped", "0.6"), ("commissioned", "tab:blue"))):
        named = [pooled[name]["named_l_min"][key] for key in keys]
        sizes = [0.0 if None in sizes else max(sizes) for sizes in named]
        axes[0].barh(np.arange(len(keys)) + k * width, sizes, height=width, color=color,
                     label=f"{name}: {pooled[name]['false_alarms']} false alarms in {pooled[name]['hours']:.2f} h "
                           f"(<= {pooled[name]['per_hour_upper']:.2g}/h)")
    axes[0].set_yticks(np.arange(len(keys)) + width / 2, [k.replace("external_leakage_", "ext ").replace("internal_leakage", "int")
                                                          for k in keys], fontsize=7)
    axes[0].set_xlabel(f"smallest leak named on every rig [L/min at 10 MPa] (0: not named at {max(summary['sizes_l_min']):g})")
    axes[0].legend(fontsize=7)
    effects = summary["effects"]
    axes[1].barh(list(effects), [e["residual_p95_l_min"] for e in effects.values()], color="tab:orange")
    axes[1].set_xlabel("95th percentile of |5 s mean residual|, shipped model, worst cylinder [L/min]")
    axes[1].set_title(f"rig {summary['effects_rig']}: the plant's effects switched (others on throughout)", fontsize=9)
    axes[1].tick_params(axis="y", labelsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
