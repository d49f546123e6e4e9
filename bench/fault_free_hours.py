"""Hours of fault-free work under the commissioned monitor, per shipped config of the SAM and the arm (the crane's:
bench/crane_apart.py), on machines built apart (make bench):
false alarms per hour with the exact Poisson (Garwood) 95 % interval, toward issue 55's 100 h per config.

Plants: each config built apart from the model (hydro_ros.studies.independent_arm, rigs 1-3: its own chain dynamics,
tabulated notches drawn off, lines, Stribeck friction, warming oil, its own operator and sensors), commissioned on 4
minutes of its own fault-free work (the documented minimum), then monitored on fresh fault-free work (RUN_S runs of the
random operator, every other one picking up a payload), the rigs in turn, until --hours per config or --budget-min of
wall time. Finished runs are kept in out/bench-cache/ under the hash of the code a run reads (RUN_CODE: this script, the
package's files it imports, the configs and the pins), so a run stopped by its budget (or killed) goes on where it stopped when started
again on a commit that changed none of it. A new cache adopts an older one's runs where this code computes its commissioned
models, first batch of runs and every run that alarmed again bit for bit (the result names it: adopted_from_code). Writes --out and a PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hydro_ros.contract.machine import Machine, load_machine_config
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.fdi.rates import CONFIDENCE, false_alarm_rate
from hydro_ros.studies import independent_arm as plant
from hydro_ros.studies.fdi_evaluation import commissioned_apart, parallel_map
from hydro_ros.tooling.benchresults import ROOT, code_hash, imported_by, write_result

CONFIGS = ("config/sam.yaml", "config/sam_mobile.yaml", "config/boom_arm.yaml")
RIGS = (1, 2, 3)
RUN_S = 120.0
BATCH = 8  # runs per batch between cache writes
FIRST_SEED = 1000
# what a run reads: this script, the package's files it imports (the tooling that stamps results computes nothing), the
# configs and the pinned libraries (numpy, scipy and numba compute too); a commit that changes none of them (the planner,
# the nodes, the CLI, the docs) keeps the cached hours
RUN_CODE = (*imported_by("bench/fault_free_hours.py", leaving=("hydro_ros/tooling",)), "config", "requirements.txt")


def _monitored(job: tuple[Machine, Machine, int, plant.ArmWork]) -> dict:
    """One run: the rig built from the shipped config, monitored with its commissioned one."""
    shipped, commissioned, rig, work = job
    samples = plant.recording(shipped, rig, work)
    alarms = run_monitor(FdiMonitor(commissioned), samples).alarms
    return {"rig": rig, "seed": work.seed, "seconds": float(samples.times[-1] - samples.times[0]),
            "alarms": [a.to_json() for a in alarms]}


def _cached(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def _adopted(cache: Path, models: dict, first: list[dict], computed: Callable[[list[int]], list[dict]]) -> tuple[str | None, list[dict]]:
    """(the key, its runs) of the cache of another code, the one with the most runs, whose commissioned models, first
    batch of runs (``first``) and every run that alarmed this code computes again bit for bit (``computed(seeds)``);
    else (None, ``first``). A change to the code a run reads that leaves the runs as they were (a refactor, a type) keeps
    the hours; one that moves an alarm, or the first batch, does not. A run that had no alarm and would now have one is
    seen only in the first batch: the check is the first batch's and the alarms', not every run's."""
    others = []
    for other in cache.parent.parent.glob(f"*/{cache.name}"):
        try:
            if other != cache and json.loads((other / "models.json").read_text()) == models:
                others.append((other, _cached(other / "runs.jsonl")))
        except (OSError, ValueError):  # another code's cache that is not whole: not a candidate
            continue
    for other, runs in sorted(others, key=lambda pair: -len(pair[1])):
        if runs[:len(first)] != first:
            continue
        alarmed = [r for r in runs[len(first):] if r["alarms"]]
        if computed([r["seed"] for r in alarmed]) != alarmed:
            continue
        print(f"{cache.name}: {len(runs)} runs of code {other.parent.name} adopted: its models, first {len(first)} runs and "
              f"{len(alarmed)} alarmed runs are this code's, bit for bit", flush=True)
        return other.parent.name, runs
    return None, first


def hours_of(config: str, target_h: float, deadline: float, workers: int, cache: Path) -> dict:
    """One config's fault-free hours, resumed from ``cache``, until ``target_h`` or the wall-clock ``deadline``."""
    base = load_machine_config(ROOT / config)
    models_file = cache / "models.json"
    models = json.loads(models_file.read_text()) if models_file.is_file() else {}
    todo = [rig for rig in RIGS if str(rig) not in models]
    for rig, model in zip(todo, parallel_map(commissioned_apart, [(base, rig) for rig in todo], workers=workers), strict=True):
        models[str(rig)] = model
    models_file.write_text(json.dumps(models))
    machines = {rig: base.with_overrides(models[str(rig)]) for rig in RIGS}
    runs_file = cache / "runs.jsonl"
    runs = _cached(runs_file)

    def computed(seeds: list[int]) -> list[dict]:
        jobs = [(base, machines[RIGS[seed % len(RIGS)]], RIGS[seed % len(RIGS)], plant.work_day(base, [seed], RUN_S)[0])
                for seed in seeds]
        return json.loads(json.dumps(parallel_map(_monitored, jobs, workers=workers)))  # as the cache holds them

    def batch_from(seed: int) -> list[dict]:
        return computed(list(range(seed, seed + BATCH)))

    adopted_file = cache / "adopted_from"
    if not runs and time.monotonic() < deadline:
        adopted_file.unlink(missing_ok=True)
        adopted, runs = _adopted(cache, models, batch_from(FIRST_SEED), computed)
        aside = runs_file.with_suffix(".writing")
        aside.write_text("".join(json.dumps(r) + "\n" for r in runs))
        aside.replace(runs_file)
        if adopted:
            adopted_file.write_text(adopted)
    adopted = adopted_file.read_text() if adopted_file.is_file() else None
    done = sum(r["seconds"] for r in runs) / 3600.0
    seed = FIRST_SEED + len(runs)
    with tqdm(total=target_h, initial=done, desc=Path(config).stem,
              bar_format="{l_bar}{bar}| {n:.1f}/{total:g} h [{elapsed}<{remaining}]") as bar:
        while done < target_h and time.monotonic() < deadline:
            batch = batch_from(seed)
            with runs_file.open("a") as stream:
                stream.writelines(json.dumps(r) + "\n" for r in batch)
            runs += batch
            seed += BATCH
            added = sum(r["seconds"] for r in batch) / 3600.0
            done += added
            bar.update(added)
    hours = sum(r["seconds"] for r in runs) / 3600.0
    alarms = [dict(a, rig=r["rig"], seed=r["seed"]) for r in runs for a in r["alarms"]]
    rate, low, high = false_alarm_rate(len(alarms), hours) if hours else (None, None, None)
    per_rig = {}
    for rig in RIGS:
        mine = [r for r in runs if r["rig"] == rig]
        rig_hours = sum(r["seconds"] for r in mine) / 3600.0
        count = sum(len(r["alarms"]) for r in mine)
        per_rig[str(rig)] = {"hours": round(rig_hours, 3), "false_alarms": count,
                             "per_hour_upper": round(false_alarm_rate(count, rig_hours)[2], 3) if rig_hours else None,
                             "c0_mpa": models[str(rig)].get("fdi", {}).get("threshold_constant")}  # None: parity thresholds
    return {"config": config, "target_hours": target_h, "hours": round(hours, 3), "runs": len(runs), "false_alarms": len(alarms),
            "per_hour": rate, "per_hour_interval": [low, high], "reached_target": hours >= target_h, "per_rig": per_rig,
            "alarmed_runs": len({(a["rig"], a["seed"]) for a in alarms}), "alarms": alarms,
            "adopted_from_code": adopted}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--config", action="append", help="a shipped config (repeatable); default: " + ", ".join(CONFIGS))
    parser.add_argument("--hours", type=float, default=100.0, help="fault-free hours per config (issue 55: 100)")
    parser.add_argument("--budget-min", type=float, default=60.0, help="wall-clock minutes for all configs together; what is "
                        "done by then is written, and the next run on the same code goes on from it")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", default="bench/results/fault_free_hours.json")
    args = parser.parse_args()
    if not args.hours > 0 or not args.budget_min > 0:
        parser.error(f"--hours {args.hours} and --budget-min {args.budget_min}: both must be > 0")
    configs = args.config or list(CONFIGS)
    cache_root = ROOT / "out" / "bench-cache" / "fault_free_hours" / code_hash(paths=RUN_CODE)[:16]
    start = time.monotonic()
    results = {}
    for index, config in enumerate(configs):
        # each config gets its share of what is left of the budget
        deadline = start + 60.0 * args.budget_min * (index + 1) / len(configs)
        cache = cache_root / Path(config).stem
        cache.mkdir(parents=True, exist_ok=True)
        results[Path(config).stem] = hours_of(config, args.hours, deadline, args.workers, cache)
    summary = {"complete": all(r["reached_target"] for r in results.values()),  # false: make bench goes on from the cache
               "plant": plant.__name__, "rigs": list(RIGS), "run_s": RUN_S, "confidence": CONFIDENCE,
               "commissioned_on": "4 min of each rig's own fault-free work (2 x 120 s)", "configs": results,
               "wall_s": round(time.monotonic() - start, 1)}
    out = Path(args.out)
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps({name: {k: r[k] for k in ("hours", "false_alarms", "per_hour_interval")} for name, r in results.items()}, indent=2))
    return 0


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(summary["configs"])
    rows = [summary["configs"][n] for n in names]
    fig, ax = plt.subplots(figsize=(8, 3.5))
    x = np.arange(len(names))
    upper = [r["per_hour_interval"][1] or 0.0 for r in rows]
    ax.bar(x, upper, color="tab:red", alpha=0.7, label=f"upper end of the {summary['confidence']:.0%} Garwood interval [1/h]")
    ax.scatter(x, [r["per_hour"] or 0.0 for r in rows], color="k", zorder=3, label="measured rate [1/h]")
    ax.set_xticks(x, [f"{n}\n{r['false_alarms']} in {r['hours']:.1f} h (target {r['target_hours']:g} h)" for n, r in zip(names, rows, strict=True)],
                  fontsize=8)
    ax.set_ylabel("false alarms per hour")
    ax.set_title("fault-free work of machines built apart, each commissioned on 4 min of its own work", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
