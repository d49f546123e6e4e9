"""Commissioning memory (make bench): peak resident memory of `hydro-ros commission` against the length of the recording.

Fault-free SAM recordings of 5 min, 20 min and 2 h (`hydro-ros sim`, cached under out/bench/) are each commissioned by
the installed CLI in a fresh process; its peak resident set (ru_maxrss) is compared with the 5 min run's in the same
run, and with the floor of holding the recording's samples (float64 per column and sample). Writes --out
(bench/results/commissioning_memory.json) and a PNG beside it. The target: 2 h of recording under 2 GB.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from tqdm import tqdm

from hydro_ros.bags.reader import bag_info
from hydro_ros.tooling.benchresults import commit, write_result

REPO = Path(__file__).resolve().parent.parent
DURATIONS_S = (300, 1200, 7200)
TARGET_MB = 2000.0
SAMPLE_COLUMNS = 7  # times, joint position and velocity, p_A, p_B, valve command, supply
# the CLI in a process of its own, reporting its own peak (ru_maxrss of a parent would be the largest child's so far)
MEASURE = ("import resource, sys\nfrom hydro_ros.cli import main\ncode = main(sys.argv[1:])\n"
           "print('MAXRSS_KB', resource.getrusage(resource.RUSAGE_SELF).ru_maxrss)\nsys.exit(code)")


def recording(config: Path, duration_s: int, cache: Path) -> Path:
    bag = cache / f"sam_fault_free_{duration_s}s"
    if not bag.exists():
        subprocess.run([sys.executable, "-m", "hydro_ros.cli", "sim", "--config", str(config), "--duration", str(duration_s),
                        "--seed", "1", "--out", str(bag), "--quiet"], check=True, stdout=subprocess.DEVNULL)
    return bag


def commission_peak_mb(config: Path, bag: Path, out: Path) -> tuple[float, float]:
    start = time.perf_counter()
    done = subprocess.run([sys.executable, "-c", MEASURE, "commission", "--bag", str(bag), "--config", str(config), "--out",
                           str(out), "--quiet", "--force"], check=True, capture_output=True, text=True)
    kilobytes = next(int(line.split()[1]) for line in done.stdout.splitlines() if line.startswith("MAXRSS_KB"))
    return kilobytes / 1024.0, time.perf_counter() - start


def plot(summary: dict, png: Path) -> None:
    runs = summary["runs"]
    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    minutes = [r["recording_s"] / 60.0 for r in runs]
    ax.plot(minutes, [r["peak_mb"] for r in runs], "o-", label="hydro-ros commission, peak RSS")
    ax.plot(minutes, [r["samples_mb"] for r in runs], "s--", label="the recording's samples (float64)")
    ax.axhline(TARGET_MB, color="k", lw=0.8, ls=":", label=f"target {TARGET_MB:.0f} MB")
    ax.set_xlabel("recording [min]")
    ax.set_ylabel("memory [MB]")
    ax.set_title(f"Commissioning memory ({summary['commit']})")
    ax.legend()
    fig.tight_layout()
    fig.savefig(png, dpi=110)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(REPO / "config" / "sam.yaml"))
    parser.add_argument("--out", default="bench/results/commissioning_memory.json")
    parser.add_argument("--cache", default=str(REPO / "out" / "bench"), help="where the simulated recordings are kept")
    args = parser.parse_args()
    config, cache, out = Path(args.config), Path(args.cache), Path(args.out)
    cache.mkdir(parents=True, exist_ok=True)
    runs = []
    for duration_s in tqdm(DURATIONS_S, unit="recording", desc="commissioning memory"):
        bag = recording(config, duration_s, cache)
        samples = bag_info(bag)["topics"]["/joint_states"]["messages"]
        peak_mb, wall_s = commission_peak_mb(config, bag, cache / f"commissioned_{duration_s}s.yaml")
        runs.append({"recording_s": duration_s, "samples": samples, "samples_mb": samples * SAMPLE_COLUMNS * 8 / 2**20,
                     "peak_mb": round(peak_mb, 1), "wall_s": round(wall_s, 1)})
    reference = runs[0]
    for run in runs:
        run["peak_vs_shortest"] = round(run["peak_mb"] / reference["peak_mb"], 2)
        run["peak_vs_samples"] = round(run["peak_mb"] / run["samples_mb"], 2)
    longest = runs[-1]
    growth = (longest["peak_mb"] - reference["peak_mb"]) / ((longest["recording_s"] - reference["recording_s"]) / 3600.0)
    shown = config.resolve().relative_to(REPO) if config.resolve().is_relative_to(REPO) else config
    summary = {"commit": commit(), "config": str(shown), "target_mb": TARGET_MB, "runs": runs,
               "growth_mb_per_recorded_hour": round(growth, 1), "within_target": longest["peak_mb"] < TARGET_MB}
    plot(summary, out.with_suffix(".png"))
    write_result(out, summary)  # last: a stamped file stands for a finished step
    print(json.dumps(summary, indent=2))
    return 0 if summary["within_target"] else 1


if __name__ == "__main__":
    sys.exit(main())
