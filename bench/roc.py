"""The SAM's monitor swept over its threshold (make bench): ROC curves and detection delay against leak size, with intervals.

Plants: config/sam.yaml built apart from the model (hydro_ros.studies.independent_arm, rigs 1-3: its own chain dynamics,
tabulated notches drawn off, lines, Stribeck friction, warming oil, its own operator and sensors), each commissioned on
4 minutes of its fault-free work (the documented minimum). Each run is simulated once and monitored at every threshold
scale: the commissioned c0 times 0.5 ... 2 (the UKF's threshold, P-II's c0 + c1 x^2 with c1 as commissioned).
- false alarms per hour with the two-sided 95 % exact Poisson (Garwood) interval, over fault-free work of each rig
  (60 s runs, every other one picking up 150 kg) and the 20 s before onset of every leak run;
- leaks from 20 s (external A, external B, internal; 0.25, 0.5, 1, 2 L/min at 10 MPa), several operator seeds per rig,
  over the runs quiet before onset: the share detected (Clopper-Pearson 95 %) and named right (``leak_run_verdict``),
  the median delay with a bootstrap 95 % band (rigs resampled, then runs within them; none below MIN_BAND delays), and
  the leak's flow at detection (the plant's laminar leak at the chamber pressure then, P-II's way of quoting a leak)
  beside its size at 10 MPa.
Writes --out (bench/results/roc.json) and a PNG beside it.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
from scipy.stats import beta
from tqdm import tqdm

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.machine import Machine, load_machine_config  # noqa: E402
from hydro_ros.fdi.monitor import FdiMonitor  # noqa: E402
from hydro_ros.fdi.offline import run_monitor  # noqa: E402
from hydro_ros.fdi.rates import CONFIDENCE, false_alarm_rate  # noqa: E402
from hydro_ros.studies import independent_arm as plant  # noqa: E402
from hydro_ros.studies.fdi_evaluation import commissioned_apart, leak_run_verdict, parallel_map  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402

SCALES = (0.5, 0.7, 0.85, 1.0, 1.25, 1.5, 2.0)  # x the commissioned c0
SIZES = (0.25, 0.5, 1.0, 2.0)  # [L/min at 10 MPa]
ONSET_S, RUN_S = 20.0, 60.0
BOOTSTRAP = 2000
MIN_BAND = 5  # delays below this many get no band


def _evaluate(job: tuple[Machine, int, plant.ArmWork, dict, list[float]]) -> dict:
    """One run, simulated once, monitored at each threshold scale; for a leak, the chamber pressures to price it."""
    machine, rig, work, model, scales = job
    samples = plant.recording(machine, rig, work)
    c0 = model["fdi"]["threshold_constant"]
    out = {"rig": rig, "seed": work.seed, "faults": [list(f) for f in work.faults], "alarms": {}}
    for scale in scales:
        config = machine.with_overrides({**model, "fdi": {**model["fdi"], "threshold_constant": c0 * scale}})
        out["alarms"][f"{scale:g}"] = [a.to_json() for a in run_monitor(FdiMonitor(config), samples).alarms]
    if work.faults:
        out["times"] = samples.times[::100].tolist()
        out["pressure_a"], out["pressure_b"] = samples.pressure_a[::100, 0].tolist(), samples.pressure_b[::100, 0].tolist()
        out["tank_pa"] = machine.tank_pressure
    return out


def _clopper_pearson(k: int, n: int) -> list[float]:
    alpha = 1.0 - CONFIDENCE
    low = beta.ppf(alpha / 2, k, n - k + 1) if k else 0.0
    high = beta.ppf(1 - alpha / 2, k + 1, n - k) if k < n else 1.0
    return [round(float(low), 3), round(float(high), 3)]


def _leak_flow_at(run: dict, time_s: float) -> float:
    """[L/min] the plant's laminar leak at the detection: its size at 10 MPa scaled by the chamber's pressure then (across
    the piston for an internal leak), at the oil's viscosity at onset (the oil warms by under 1 K in a run: 2 % at most)."""
    _, fault, size, _ = run["faults"][0]
    i = int(np.searchsorted(run["times"], time_s))
    i = min(i, len(run["times"]) - 1)
    pa, pb, tank = run["pressure_a"][i], run["pressure_b"][i], run["tank_pa"]
    drop = {"external_leakage_a": pa - tank, "external_leakage_b": pb - tank, "internal_leakage": abs(pa - pb)}[fault]
    return size * drop / plant.LEAK_DROP


def _median_band(delays: list[tuple[int, float]], rng: np.random.Generator) -> list[float] | None:
    """Bootstrap 95 % band of the median delay, resampling the rigs and then the runs within each drawn rig (the runs of
    one rig share its build); None for fewer than MIN_BAND delays."""
    if len(delays) < MIN_BAND:
        return None
    by_rig = [np.array([d for r, d in delays if r == rig]) for rig in sorted({r for r, _ in delays})]
    medians = np.empty(BOOTSTRAP)
    for k in range(BOOTSTRAP):
        drawn = [by_rig[i] for i in rng.integers(len(by_rig), size=len(by_rig))]
        medians[k] = np.median(np.concatenate([rig[rng.integers(len(rig), size=len(rig))] for rig in drawn]))
    return [round(float(np.percentile(medians, 2.5)), 2), round(float(np.percentile(medians, 97.5)), 2)]


def summarise(runs: list[dict], actuator: str, scales: list[float], sizes: list[float], seed: int = 0) -> dict:
    """Per threshold scale: false alarms in the fault-free runs and the leak runs before onset; per leak kind and size,
    over the leak runs quiet before onset, the share detected and named (``leak_run_verdict``), the median delay with its
    band and the flow at detection."""
    rng = np.random.default_rng(seed)
    free = [r for r in runs if not r["faults"]]
    leaking = [r for r in runs if r["faults"]]
    hours = (len(free) * RUN_S + len(leaking) * ONSET_S) / 3600.0
    out = {}
    for scale in (f"{s:g}" for s in scales):
        alarms = sum(len(r["alarms"][scale]) for r in free) + sum(any(a["time_s"] <= ONSET_S for a in r["alarms"][scale]) for r in leaking)
        rate, low, high = false_alarm_rate(alarms, hours)
        row = {"false_alarms": alarms, "hours": round(hours, 3), "per_hour": rate, "per_hour_interval": [low, high], "leaks": {}}
        for fault in plant.LEAKS:
            for size in sizes:
                cases = [r for r in leaking if r["faults"][0][1] == fault and r["faults"][0][2] == size]
                quiet = [r for r in cases if not any(a["time_s"] <= ONSET_S for a in r["alarms"][scale])]
                delays, named, flows = [], 0, []
                for r in quiet:
                    detected, named_after = leak_run_verdict(r["alarms"][scale], actuator, fault, ONSET_S)
                    if detected is not None:
                        delays.append((r["rig"], detected))
                        flows.append(_leak_flow_at(r, ONSET_S + detected))
                    named += named_after is not None
                row["leaks"][f"{fault}/{size:g}"] = {
                    "runs": len(cases), "quiet_before_onset": len(quiet), "detected": len(delays),
                    "detected_interval": _clopper_pearson(len(delays), len(quiet)), "named": named,
                    "delay_median_s": round(float(np.median([d for _, d in delays])), 2) if delays else None,
                    "delay_band_s": _median_band(delays, rng),
                    "flow_at_detection_l_min": round(float(np.median(flows)), 3) if flows else None}
        out[scale] = row
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "sam.yaml"))
    parser.add_argument("--out", default="bench/results/roc.json")
    parser.add_argument("--rigs", type=int, default=3)
    parser.add_argument("--fault-free", type=int, default=40, help="fault-free runs of 60 s per rig")
    parser.add_argument("--leak-seeds", type=int, default=3, help="operator seeds per rig, leak kind and size")
    parser.add_argument("--workers", type=int, default=2)
    args = parser.parse_args()
    machine = load_machine_config(args.config)
    actuator = machine.actuator_names[0]
    start = time.perf_counter()
    rigs = list(range(1, 1 + args.rigs))
    models = dict(zip(rigs, parallel_map(commissioned_apart, [(machine, rig) for rig in rigs], workers=args.workers)))
    jobs = []
    for rig in rigs:
        work = plant.work_day(machine, range(201, 201 + args.fault_free), RUN_S)
        work += [plant.ArmWork(RUN_S, 301 + k, faults=((actuator, fault, size, ONSET_S),))
                 for k, (fault, size, _) in enumerate((f, s, n) for f in plant.LEAKS for s in SIZES for n in range(args.leak_seeds))]
        jobs += [(machine, rig, w, models[rig], list(SCALES)) for w in work]
    bar = tqdm(total=len(jobs), unit="run", desc="roc")
    runs = parallel_map(_evaluate, jobs, workers=args.workers, progress=bar.update)
    bar.close()
    summary = {"plant": plant.__name__, "config": str(Path(args.config).resolve().relative_to(REPO)), "rigs": args.rigs,
               "commissioned_c0_mpa": {str(rig): round(m["fdi"]["threshold_constant"], 4) for rig, m in models.items()},
               "scales": list(SCALES), "sizes_l_min": list(SIZES), "run_s": RUN_S, "onset_s": ONSET_S, "confidence": CONFIDENCE,
               "bootstrap": BOOTSTRAP, "by_scale": summarise(runs, actuator, list(SCALES), list(SIZES)),
               "wall_s": round(time.perf_counter() - start, 1)}
    out = Path(args.out)
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps({k: v for k, v in summary.items() if k != "by_scale"}, indent=2))
    return 0


def plot(summary: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    by_scale, sizes = summary["by_scale"], summary["sizes_l_min"]
    scales = list(by_scale)
    fig, axes = plt.subplots(1, 2, figsize=(13, 4.6))
    for size, colour in zip(sizes, ("C0", "C1", "C2", "C3")):
        rate = [by_scale[s]["per_hour"] for s in scales]
        upper = [by_scale[s]["per_hour_interval"][1] for s in scales]
        hit = [sum(by_scale[s]["leaks"][f"{f}/{size:g}"]["detected"] for f in plant.LEAKS)
               / max(sum(by_scale[s]["leaks"][f"{f}/{size:g}"]["quiet_before_onset"] for f in plant.LEAKS), 1) for s in scales]
        axes[0].plot(rate, hit, "o-", color=colour, label=f"{size:g} L/min")
        axes[0].plot(upper, hit, ":", color=colour, lw=0.8)
        for s, x, y in zip(scales, rate, hit):
            axes[0].annotate(f"x{s}", (x, y), fontsize=6, textcoords="offset points", xytext=(3, -8))
    axes[0].set_xscale("symlog", linthresh=1.0)
    axes[0].set_xlabel("false alarms per hour (dotted: upper end of the 95 % exact Poisson interval)")
    axes[0].set_ylabel("share of leak runs quiet before onset detected after it")
    axes[0].set_title(f"ROC over the threshold scale (x the commissioned c0), {summary['rigs']} rigs built apart", fontsize=9)
    axes[0].legend(fontsize=7)
    axes[0].grid(alpha=0.3)
    nominal = by_scale["1"]
    for fault, marker in zip(plant.LEAKS, ("o", "s", "^")):
        rows = [(size, nominal["leaks"][f"{fault}/{size:g}"]) for size in sizes]
        rows = [(size, r) for size, r in rows if r["delay_median_s"] is not None]
        if not rows:
            continue
        x = np.array([size for size, _ in rows])
        median = np.array([r["delay_median_s"] for _, r in rows])
        band = np.array([r["delay_band_s"] or [m, m] for m, (_, r) in zip(median, rows)]).T  # no band: too few delays
        axes[1].errorbar(x, median, yerr=[median - band[0], band[1] - median], marker=marker, capsize=3,
                         label=fault.replace("external_leakage_", "external ").replace("_", " "))
    axes[1].set_xscale("log")
    axes[1].set_xticks(sizes, [f"{s:g}" for s in sizes])
    axes[1].xaxis.set_minor_formatter(matplotlib.ticker.NullFormatter())
    axes[1].set_xlabel("leak size [L/min at 10 MPa]")
    axes[1].set_ylabel(f"detection delay [s], median with bootstrap 95 % band (none below {MIN_BAND} delays)")
    axes[1].set_title("at the commissioned threshold", fontsize=9)
    axes[1].legend(fontsize=7)
    axes[1].grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


if __name__ == "__main__":
    raise SystemExit(main())
