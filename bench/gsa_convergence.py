"""P-I GSA: does N suffice, and what sets p_A's ranking (make bench)? Sobol' indices of the SAM model at N = 256 ... 4096
(the leaks, k = 3, to 2048: their indices are far apart and the runs stay within ~25 min of CPU) from one set of runs
at the largest N, then candidate causes of the differences from P-I at a small N each: the initial pressures, the load,
the leak law, the load's course along the stroke, and the true steady state (solved, N = 16384).

Writes --out (bench/results/gsa_convergence.json), the indices and rankings against N (.png beside it) and each cause's
p_A indices at 4 s against P-I's Tables 4 and 8 (_causes.png). P-I's own N = 10 000 costs N (k + 2) = 140 000 runs (the
JSON estimates their CPU time from this run's).
"""

from __future__ import annotations

import argparse
import json
import resource
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
from tqdm import tqdm

from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.studies.gsa import (
    CAUSES,
    OUTPUTS,
    P_I_P_A_TOTAL_4S,
    SPACES,
    STEADY,
    cause_summary,
    convergence,
    load_change,
    ranking_convergence,
    sobol_indices,
    steady_state_indices,
)
from hydro_ros.tooling.benchresults import commit, write_result

REPO = Path(__file__).resolve().parent.parent
P_I_SAMPLES = 10000
SIZES = (256, 512, 1024, 2048, 4096)
COLOURS = {"offset": "C7", "q_n_pa": "C0", "dp_n_pa": "C9", "q_n_bt": "C3", "dp_n_bt": "C1", "bulk_modulus": "C2",
           "viscous": "C5", "k_int": "C4", "k_ext_a": "C0", "k_ext_b": "C3"}


def cpu_s() -> float:
    """CPU seconds of this process and its finished children (the worker processes)."""
    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + children.ru_utime + children.ru_stime


def plot_convergence(summary: dict, png: Path) -> None:
    fig, axes = plt.subplots(2, 4, figsize=(17, 7.5))
    for row, space in enumerate(SPACES):
        results = summary["convergence"][space]
        sizes = [int(n) for n in results]
        for col, output in enumerate(OUTPUTS):
            ax = axes[row, col]
            for k, name in enumerate(results[str(sizes[0])]["parameters"]):
                at = [results[str(n)]["indices"][output]["4"][name] for n in sizes]
                shifted = [n * 1.03 ** (k - 3) for n in sizes]  # side by side, so the intervals do not hide each other
                ax.errorbar(shifted, [a["S1"] for a in at], yerr=[a["S1_conf"] for a in at], marker="o", ms=3, capsize=2,
                            color=COLOURS[name], label=name)
            ax.set_xscale("log", base=2)
            ax.set_title(f"{space}: {output} at 4 s, first order ± 95 %", fontsize=9)
            ax.grid(alpha=0.3)
        axes[row, 0].legend(fontsize=7)
        axes[row, 0].set_ylabel("first-order index")
        ax = axes[row, 3]
        for output in OUTPUTS:
            widest = summary["rankings"][space][output]["4"]["widest_interval"]
            ax.plot(sizes, [widest[str(n)] for n in sizes], marker="o", label=output)
        reference = widest[str(sizes[0])] * np.sqrt(sizes[0] / np.array(sizes, dtype=float))
        ax.plot(sizes, reference, "k:", label="∝ N^-1/2")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_title(f"{space}: widest first-order interval at 4 s", fontsize=9)
        ax.legend(fontsize=7)
        ax.grid(alpha=0.3)
    for ax in axes[-1]:
        ax.set_xlabel("N (runs = N (k + 2))")
    fig.suptitle(f"P-I GSA against N ({summary['commit']})")
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)


def plot_causes(summary: dict, png: Path) -> None:
    fig, axes = plt.subplots(1, 2, figsize=(17, 7))
    for ax, space, key in zip(axes, SPACES, ("p_a_parameters", "p_a_leaks")):
        rows = [("P-I Tables 4 / 8", P_I_P_A_TOTAL_4S[space], "")]
        for cause in (c for c in summary["causes"] if key in c):
            note = (f"first-order leader: {'BT' if cause['bt_leads_p_a'] else 'PA'}" if space == "parameters"
                    else f"smallest/largest {cause['leak_spread_p_a']:.2f}")
            load = cause.get("load_n")
            label = f"{cause['name']} (N = {cause['samples']}" + (f"; load {(load[1] - load[0]) / 1e3:+.1f} kN over 0.1 m)" if load else ")")
            rows.append((label, {name: v["ST"] for name, v in cause[key].items()}, note))
        left = np.zeros(len(rows))
        for name in rows[0][1]:
            widths = np.array([max(values[name], 0.0) for _, values, _ in rows])
            ax.barh(range(len(rows)), widths, left=left, color=COLOURS[name], label=name)
            left += widths
        for y, (_, _, note) in enumerate(rows):
            ax.text(left[y] + 0.02, y, note, va="center", fontsize=7)
        ax.set_yticks(range(len(rows)), [label for label, _, _ in rows], fontsize=8)
        ax.invert_yaxis()
        ax.set_xlim(0.0, left.max() + 0.45)
        ax.set_xlabel("total-order index of p_A at 4 s (stacked)")
        ax.set_title(f"{space}: which set-up gives P-I's p_A order?", fontsize=10)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.09), ncol=4)
        ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    fig.savefig(png, dpi=100)
    plt.close(fig)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default=str(default_config_path("sam")))
    parser.add_argument("--out", default="bench/results/gsa_convergence.json")
    parser.add_argument("--sizes", type=int, nargs="+", default=list(SIZES), help="Sobol' base samples N (powers of two)")
    parser.add_argument("--leak-largest", type=int, default=2048, help="the largest N of --sizes the leaks run at")
    parser.add_argument("--cause-samples", type=int, default=SIZES[0], help="N of each cause's runs; one of --sizes")
    parser.add_argument("--steady-samples", type=int, default=16384, help="N of the solved steady state")
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--resamples", type=int, default=200, help="bootstrap resamples for the 95 %% intervals")
    args = parser.parse_args()
    sizes = {"parameters": sorted(args.sizes), "leakages": sorted(n for n in args.sizes if n <= args.leak_largest)}
    if not all(args.cause_samples in space_sizes for space_sizes in sizes.values()):
        parser.error("--cause-samples must be one of --sizes, at most --leak-largest: the shipped set-up's indices at that N come "
                     "from the convergence runs")
    machine = load_machine_config(args.config)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    convergence_runs = sum(sizes[space][-1] * (len(values) + 2) for space, values in SPACES.items())
    cause_runs = sum(args.cause_samples * (len(SPACES[space]) + 2) for cause in CAUSES for space in cause.spaces)
    with tqdm(total=convergence_runs + cause_runs, unit="run", desc="gsa convergence") as bar:
        start, cpu = time.perf_counter(), cpu_s()
        results = {space: convergence(machine, values, sizes[space], workers=args.workers, resamples=args.resamples,
                                      progress=bar.update) for space, values in SPACES.items()}
        convergence_wall, convergence_cpu = time.perf_counter() - start, cpu_s() - cpu
        shipped = {space: results[space][args.cause_samples] for space in SPACES}
        causes = [{"name": "true steady state", "change": "eqs. (39)-(40) with the leaks, solved with the nominal run's 4 s "
                   "force held: nothing moves", "samples": args.steady_samples,
                   **cause_summary({space: steady_state_indices(machine, values, args.steady_samples, resamples=args.resamples)
                                    for space, values in SPACES.items()}, STEADY)},
                  {"name": "as shipped", "change": "the study's set-up (mount offset 1.6 rad: the load rising along the stroke)",
                   "samples": args.cause_samples, "load_n": load_change(machine), **cause_summary(shipped)}]
        for cause in CAUSES:
            applied = cause.applied(machine)
            runs = {space: sobol_indices(applied, SPACES[space], args.cause_samples, workers=args.workers,
                                         resamples=args.resamples, initial_p_b=cause.initial_p_b, progress=bar.update)
                    for space in cause.spaces}
            causes.append({"name": cause.name, "change": cause.change, "samples": args.cause_samples,
                           "load_n": load_change(applied), **cause_summary(runs)})
    wall, cpu = time.perf_counter() - start, cpu_s() - cpu
    per_run_cpu = convergence_cpu / convergence_runs
    rankings = {space: {output: {instant: ranking_convergence(results[space], output, instant)
                                 for instant in results[space][sizes[space][-1]]["indices"][output]}
                        for output in OUTPUTS} for space in SPACES}
    shown = Path(args.config).resolve()
    summary = {
        "config": str(shown.relative_to(REPO) if shown.is_relative_to(REPO) else shown), "sizes": sizes, "workers": args.workers,
        "resamples": args.resamples, "runs": {"convergence": convergence_runs, "causes": cause_runs},
        "wall_s": {"convergence": round(convergence_wall, 1), "total": round(wall, 1)},
        "cpu_s": {"convergence": round(convergence_cpu, 1), "total": round(cpu, 1)},
        "p_i_samples": P_I_SAMPLES,
        "p_i_samples_cpu_s_estimate": round(per_run_cpu * sum(P_I_SAMPLES * (len(space) + 2) for space in SPACES.values())),
        "stable_from_4s": {space: {output: rankings[space][output]["4"]["stable_from"] for output in OUTPUTS} for space in SPACES},
        "leader_stable_from_4s": {space: {output: rankings[space][output]["4"]["leader_stable_from"] for output in OUTPUTS}
                                  for space in SPACES},
        "rankings": rankings,
        "causes": causes,
        "p_i_p_a_total_4s": P_I_P_A_TOTAL_4S,
        "convergence": {space: {str(n): result for n, result in results[space].items()} for space in SPACES},
    }
    plot_convergence({**summary, "commit": commit()}, out.with_suffix(".png"))
    plot_causes(summary, out.with_name(out.stem + "_causes.png"))
    written = json.loads(write_result(out, summary).read_text())  # last: a stamped file stands for a finished step
    print(json.dumps({key: written[key] for key in ("commit", "runs", "wall_s", "cpu_s", "p_i_samples_cpu_s_estimate",
                                                    "stable_from_4s", "leader_stable_from_4s")}, indent=2))
    for cause in written["causes"]:
        order = cause.get("parameter_rankings", {}).get("p_a", {}).get("S1", [])
        print(f"{cause['name']}: p_A {' > '.join(order[:4]) or '-'}; leaks on p_A {' > '.join(cause.get('leak_ranking_p_a', [])) or '-'}"
              f" (spread {cause.get('leak_spread_p_a', float('nan')):.2f})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
