"""DP benchmarks (make bench): fast solver against the NumPy reference in the same run, grid convergence,
`dp compare` on every placeholder path, and the direct method from many seeds against the DP (``multistart``: does the
problem have the local minima P-V's case for a global method rests on?). Writes bench/results/dp.json,
bench/results/dp_convergence.png, bench/results/dp_multistart.png and bench/results/dp_compare_<machine>_<path>.{json,md,png}.

Time and peak memory are measured in a fresh process per solver (ru_maxrss of that child), so one
solver's allocations do not hide the other's; the time after one solve on a tiny grid, which loads
the compiled kernels from numba's cache, and for the fast solvers the best of FAST_REPEATS (all in
``runs_s``).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

from hydro_ros.tooling.benchresults import commit, write_result

_CHILD = """
import json, resource, sys, time
from hydro_ros.contract.config import default_config_path
from hydro_ros.planning.problem import Problem
from hydro_ros.planning.costs import Cost
from hydro_ros.models.crane import load_crane
from hydro_ros.planning.dp import DpGrid, solve
from hydro_ros.planning.reference import solve_reference
solver, cost, repeats = sys.argv[1], Cost(sys.argv[2]), int(sys.argv[3])
crane, config = load_crane(default_config_path("k70m"))
problem = Problem.build(crane, config, "horizontal")
run = solve if solver == "fast" else solve_reference
run(crane, problem.samples, cost, DpGrid.for_path(crane, problem.samples, (8, 9, 9)))  # loads the compiled kernels
times = []
for _ in range(repeats):
    began = time.perf_counter()
    solution = run(crane, problem.samples, cost, problem.grid, progress=True)
    times.append(time.perf_counter() - began)
print(json.dumps({"seconds": min(times), "runs_s": times, "peak_rss_MB": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                  "cost_to_go": float(solution.cost_to_go[0][solution.cost_to_go[0] < 1e12].sum())}))
"""


FAST_REPEATS = 5  # the fast solvers' time is the best of five solves: this host's speed varies by +-20 % from minute to minute


def _child(solver: str, cost: str, repeats: int = 1) -> dict:
    done = subprocess.run([sys.executable, "-c", _CHILD, solver, cost, str(repeats)], capture_output=True, text=True, check=True)
    return json.loads(done.stdout.strip().splitlines()[-1])


def solver_speed() -> dict:
    _child("fast", "cp")  # numba compiles into its cache once, outside the measurement
    fast_cp, fast_ls, reference = _child("fast", "cp", FAST_REPEATS), _child("fast", "ls", FAST_REPEATS), _child("reference", "cp")
    return {
        "grid": [356, 101, 151],
        "stages": 200,
        "fast_cp": fast_cp,
        "fast_ls": fast_ls,
        "reference_cp": reference,
        "speedup_cp": reference["seconds"] / fast_cp["seconds"],
        "memory_ratio_cp": fast_cp["peak_rss_MB"] / reference["peak_rss_MB"],
        "same_cost_to_go": abs(fast_cp["cost_to_go"] - reference["cost_to_go"]) <= 1e-9 * abs(reference["cost_to_go"]),
    }


CONVERGENCE_SCALES = (0.25, 0.35, 0.5, 0.7, 1.0, 1.4)  # of the K70M's grid (356 x 101 x 151); 1.4: a finer grid to judge 1.0 by
CONVERGED = 0.005  # the full grid's energy within this share of the finer grid's: converged (issue 55)


def convergence(out_dir: Path) -> dict:
    """P-V Figs. 8/10 on every K70M path and both starts (P-VI's smallest feasible extension and the middle of the window):
    the energy of each grid against the finest, CP and LS. Each grid starts from the full grid's start state (a coarse grid's
    own smallest node lies up to a cell further out), so the grids solve one problem. Per grid: the realised energy of the
    reference it serves (filtered) and of the DP's own trajectory, and the cost the DP predicted for it (its cost-to-go at
    the start node)."""
    from dataclasses import replace

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hydro_ros.contract.config import default_config_path
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.costs import Cost
    from hydro_ros.planning.problem import Problem, plan_dp

    crane, config = load_crane(default_config_path("k70m"))
    full = config.dp.grid
    cases: dict[str, dict] = {}
    for path in ("horizontal", "vertical", "half_cycle"):
        for start in ("smallest", "middle"):
            start_position = Problem.build(crane, config, path, start=start).start
            case = cases[f"{path}/{start}"] = {"start_position_m": start_position}
            for cost in (Cost.CP, Cost.LS):
                rows = case[cost.value] = []
                for scale in CONVERGENCE_SCALES:
                    grid = (int((full[0] - 1) * scale) + 1, 2 * int((full[1] - 1) / 2 * scale) + 1, 2 * int((full[2] - 1) / 2 * scale) + 1)
                    problem = replace(Problem.build(crane, config, path, grid=grid), start=start_position)
                    plan = plan_dp(problem, cost)
                    key = f"{cost.value}_energy_J"
                    rows.append({"scale": scale, "grid": list(grid), "energy_J": plan.evaluation[key],
                                 "unfiltered_energy_J": plan.info["unfiltered"][key], "predicted_J": plan.info["predicted_cost"],
                                 "limits_ok": all(plan.evaluation["limits"].values()), "seconds": round(plan.seconds, 3)})
                    print(f"convergence {path}/{start} {cost.value} {grid}: {plan.evaluation[key] / 1e3:.3f} kJ "
                          f"in {plan.seconds:.1f} s", flush=True)
                finest = rows[-1]["energy_J"]
                for row in rows:
                    row["relative"] = row["energy_J"] / finest
                    row["predicted_over_realised"] = row["predicted_J"] / row["unfiltered_energy_J"]
                at_full = next(row for row in rows if row["scale"] == 1.0)
                case[f"{cost.value}_full_grid_excess"] = at_full["relative"] - 1.0
    summary = {"scales": list(CONVERGENCE_SCALES), "converged_share": CONVERGED, "cases": cases,
               "full_grid_excess_max": {cost: max(case[f"{cost}_full_grid_excess"] for case in cases.values()) for cost in ("cp", "ls")},
               "full_grid_excess_min": {cost: min(case[f"{cost}_full_grid_excess"] for case in cases.values()) for cost in ("cp", "ls")}}
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.6), sharey=True)
    for ax, path in zip(axes, ("horizontal", "vertical", "half_cycle")):
        for start, style in (("smallest", "-"), ("middle", "--")):
            for cost, colour in (("cp", "C0"), ("ls", "C1")):
                rows = cases[f"{path}/{start}"][cost]
                ax.plot([r["grid"][0] * r["grid"][1] * r["grid"][2] for r in rows], [r["relative"] for r in rows], colour + style, marker="o",
                        label=f"{cost.upper()}, {start} start")
        ax.axhline(1.0 + CONVERGED, color="k", lw=0.8, ls=":")
        ax.set_xscale("log")
        ax.set_xlabel("grid points N_c N_v N_u")
    _finish_paths_figure(fig, axes, ("horizontal", "vertical", "half_cycle"), "energy / finest grid's",
                         f"DP grid convergence (full grid {full[0]} x {full[1]} x {full[2]} at scale 1; dotted: +{CONVERGED:.1%})",
                         out_dir / "dp_convergence.png")
    return summary


def _finish_paths_figure(fig, axes, paths, ylabel: str, title: str, out: Path) -> None:
    """One panel per K70M path: titled and gridded, the first labelled, the figure titled and written."""
    import matplotlib.pyplot as plt

    for ax, path in zip(axes, paths):
        ax.set_title(f"k70m {path}")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel(ylabel)
    axes[0].legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)


def comparisons(out_dir: Path, machines: set[str], earlier: dict) -> dict:
    """``dp compare`` of every method on each case of ``machines``; the other machines' cases kept from ``earlier``."""
    # P-VI's second initial configuration (App. D, Figs. A4-A6): the middle of the feasible extension window
    cases = [("k70m", path, start) for start in ("smallest", "middle") for path in ("horizontal", "vertical", "half_cycle")]
    cases.append(("crane3dof", "triangle", "smallest"))
    # an arm the crane model was not written for: redundant in its bucket, described in the monitor's terms
    cases += [("excavator", path, "smallest") for path in ("level_cut", "lift_out")]
    summary = {key: value for key, value in earlier.items() if key.split("/")[0] not in machines}
    for machine, path, start in (case for case in cases if case[0] in machines):
        suffix = "" if start == "smallest" else f"_{start}"
        target = out_dir / f"dp_compare_{machine}_{path}{suffix}.json"
        began = time.perf_counter()
        subprocess.run(
            [sys.executable, "-m", "hydro_ros.cli", "dp", "compare", "--config", f"config/{machine}.yaml", "--path", path,
             "--out", str(target), "--all-methods", "--quiet", "--start", start],
            check=True,
        )
        result = json.loads(target.read_text())
        write_result(target, result)  # the commit it ran on, as every file of bench/results
        summary[f"{machine}/{path}{suffix}"] = {
            "seconds": time.perf_counter() - began,
            "start_position_m": result["start_position_m"],
            "relative_cp": {m: round(r["relative_cp"], 4) for m, r in result["methods"].items()},
            "relative_ls": {m: round(r["relative_ls"], 4) for m, r in result["methods"].items()},
            "limits_ok": {m: r["limits_ok"] for m, r in result["methods"].items()},
        }
    return summary


def window_study() -> dict:
    """Why the vertical path's saving vanishes on our geometry: what bounds the feasible extension window along
    each K70M path, and the energy of following its lower edge, its middle and its upper edge (filtered at 5 Hz)."""
    import numpy as np

    from hydro_ros.contract.config import default_config_path
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.dp import extension_windows
    from hydro_ros.planning.paths import path_from_config
    from hydro_ros.planning.trajectory import ExtensionTrajectory, evaluate

    crane, config = load_crane(default_config_path("k70m"))
    study = {}
    for path in ("horizontal", "vertical", "half_cycle"):
        samples = path_from_config(config, path).sample(config.dp.sample_time)
        window = extension_windows(crane, samples)
        tips, rest = tuple(samples.position[:, i] for i in range(3)), (0.0,) * 3
        row: dict = {"window_width_m": {"min": float(np.min(window[:, 1] - window[:, 0])),
                                        "max": float(np.max(window[:, 1] - window[:, 0]))}}
        for end, label in ((0, "lower"), (1, "upper")):
            motion = crane.motion(tips, rest, rest, window[:, end], 0.0 * window[:, end], 0.0 * window[:, end], forces=False)
            row[f"{label}_edge_set_by"] = {c.name: int(np.sum((np.abs(q - c.q_min) < 1e-3) | (np.abs(q - c.q_max) < 1e-3)))
                                          for c, q in zip(crane.cylinders, motion.q)}
        for label, profile in (("lower", window[:, 0]), ("middle", window.mean(axis=1)), ("upper", window[:, 1])):
            trajectory = ExtensionTrajectory.from_positions(profile, float(samples.time[1])).filtered(config.dp.filter_cutoff)
            result = evaluate(crane, samples, trajectory)
            row[f"follow_{label}_edge"] = {"cp_energy_J": result["cp_energy_J"], "ls_energy_J": result["ls_energy_J"],
                                           "limits": result["limits"]}
        row["samples"] = int(samples.stages + 1)
        study[path] = row
        print(f"window {path}: {json.dumps(row)}", flush=True)
    return study


def replanning() -> dict:
    """trajectory_server's re-planning pass (the compiled policy, ``follow``) against the step-by-step search (``forward``)
    from the middle of each K70M path's start window, the fastest of 5 runs each."""
    from hydro_ros.contract.config import default_config_path
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.costs import Cost
    from hydro_ros.planning.dp import DpGrid, solve, start_position
    from hydro_ros.planning.paths import path_from_config

    crane, config = load_crane(default_config_path("k70m"))
    out = {}
    for path in ("horizontal", "vertical", "half_cycle"):
        samples = path_from_config(config, path).sample(config.dp.sample_time)
        grid = DpGrid.for_path(crane, samples, (80, 41, 61))
        solution = solve(crane, samples, Cost.CP, grid)
        start = start_position(crane, samples, grid, "middle")
        solution.follow(start)  # compiled once
        timed = {}
        for name, run in (("search_s", solution.forward), ("policy_s", solution.follow)):
            runs = []
            for _ in range(5):
                began = time.perf_counter()
                run(start)
                runs.append(time.perf_counter() - began)
            timed[name] = min(runs)
        out[path] = {**timed, "policy_over_search": timed["policy_s"] / timed["search_s"]}
    return out


MULTISTART_SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)  # of the extension window: where the blended seeds take the extension
DISTINCT = 0.005  # two local optima whose energies differ by more than this share are distinct (issue 55)


def _distinct(energies: list[float]) -> int:
    """How many optima ``energies`` hold: sorted, a new one wherever an energy exceeds the last new one's by over DISTINCT."""
    count, first = 0, -float("inf")
    for energy in sorted(energies):
        if energy > first * (1.0 + DISTINCT):
            count, first = count + 1, energy
    return count


def multistart(out_dir: Path) -> dict:
    """P-V's case for a global method: local optimisation ends in local minima. The direct method (IPOPT) on every K70M
    path and both starts, seeded with the joint-space pseudo-inverse, the DP (CP)'s own trajectory and blends to and via
    shares of the extension window (``multistart_seeds``), each scored as ``run_method`` scores it. Twice: bootstrapped over
    node counts as ``direct_cp`` runs (the coarse first solve may smooth a seed's differences away), and at the finest node
    count alone. A local optimum is a seed whose finest solve converged and whose trajectory keeps every limit and the path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from tqdm import tqdm

    from hydro_ros.contract.config import default_config_path
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.baselines import BOOTSTRAP_NODES, direct_collocation, multistart_seeds, pseudo_inverse
    from hydro_ros.planning.problem import Problem, run_method
    from hydro_ros.planning.trajectory import evaluate

    crane, config = load_crane(default_config_path("k70m"))
    variants = {"bootstrapped": BOOTSTRAP_NODES, "finest_only": BOOTSTRAP_NODES[-1:]}
    paths, starts = ("horizontal", "vertical", "half_cycle"), ("smallest", "middle")
    cases: dict[str, dict] = {}
    for path in paths:
        for start in starts:
            problem = Problem.build(crane, config, path, start=start)
            dp = run_method(problem, "dp_cp")
            dp_energy = dp.evaluation["cp_energy_J"]  # [J]
            seeds = {"pinv_joint": pseudo_inverse(crane, problem.samples, problem.start, space="joint")[0], "dp_cp": dp.trajectory,
                     **multistart_seeds(crane, problem.samples, problem.start, MULTISTART_SHARES)}
            case = cases[f"{path}/{start}"] = {"start_position_m": problem.start,
                                               "dp_cp": {"cp_energy_J": dp_energy, "limits": dp.evaluation["limits"]}}
            for variant, nodes in variants.items():
                rows = {}
                for label, seed in tqdm(seeds.items(), desc=f"multistart {path}/{start} {variant}", unit="seed"):
                    began = time.perf_counter()
                    trajectory, info = direct_collocation(crane, problem.path, problem.samples, problem.start, seed, nodes=nodes)
                    evaluation = evaluate(crane, problem.samples, trajectory)
                    rows[label] = {"seed_cp_energy_J": evaluate(crane, problem.samples, seed)["cp_energy_J"],
                                   "converged": info["converged"], "finest_status": info["ipopt"][-1]["status"],
                                   "limits": evaluation["limits"], "tip_error_max_m": evaluation["tip_error_max_m"],
                                   "cp_energy_J": evaluation["cp_energy_J"], "relative_to_dp": evaluation["cp_energy_J"] / dp_energy,
                                   "seconds": round(time.perf_counter() - began, 3)}
                optima = [r["cp_energy_J"] for r in rows.values() if r["finest_status"] == "Solve_Succeeded"
                          and all(r["limits"].values()) and r["tip_error_max_m"] < 1e-6]
                result = case[variant] = {"seeds": rows, "local_optima": len(optima)}
                if optima:
                    best, median, worst = min(optima), float(np.median(optima)), max(optima)
                    result.update({"cp_energy_J": {"min": best, "median": median, "max": worst}, "distinct_optima": _distinct(optima),
                                   "dp_over_best": dp_energy / best - 1.0, "dp_within_best": dp_energy <= best * (1.0 + DISTINCT),
                                   "dp_beats_median": dp_energy < median * (1.0 - DISTINCT),
                                   "dp_beats_worst": dp_energy < worst * (1.0 - DISTINCT)})
                print(f"multistart {path}/{start} {variant}: DP (CP) {dp_energy / 1e3:.2f} kJ, {len(optima)}/{len(rows)} local optima, "
                      f"{result.get('distinct_optima', 0)} distinct", flush=True)
    measured = [case[variant] for case in cases.values() for variant in variants if case[variant]["local_optima"]]
    summary = {"window_shares": list(MULTISTART_SHARES), "distinct_share": DISTINCT,
               "variants": {variant: list(nodes) for variant, nodes in variants.items()}, "cases": cases,
               "seeds_per_case": {name: len(case["bootstrapped"]["seeds"]) for name, case in cases.items()},
               "distinct_optima_max": max((m["distinct_optima"] for m in measured), default=0),
               "dp_over_best": {"min": min(m["dp_over_best"] for m in measured), "max": max(m["dp_over_best"] for m in measured)}
               if measured else None}
    # the starts' seeds differ (no seed via the start's own share), so each seed's column is its label's
    labels = list(dict.fromkeys(label for case in cases.values() for label in case["bootstrapped"]["seeds"]))
    fig, axes = plt.subplots(1, len(paths), figsize=(13, 3.8), sharey=True)
    for ax, path in zip(axes, paths):
        for start, colour in zip(starts, ("C0", "C1")):
            for variant, marker, offset in (("bootstrapped", "o", -0.15), ("finest_only", "s", 0.15)):
                rows = cases[f"{path}/{start}"][variant]["seeds"]
                kept = [r["finest_status"] == "Solve_Succeeded" and all(r["limits"].values()) for r in rows.values()]
                x = np.array([labels.index(label) for label in rows]) + offset + (0.05 if start == "middle" else -0.05)
                y = [100.0 * (r["relative_to_dp"] - 1.0) for r in rows.values()]
                ax.scatter(x, y, marker=marker, edgecolors=colour, facecolors=[colour if k else "none" for k in kept],
                           label=f"{start} start, {variant.replace('_', ' ')}")
        ax.set_xticks(np.arange(len(labels)), labels, rotation=60, fontsize=7)
        ax.axhline(0.0, color="k", lw=0.8)
        for bound in (-100.0 * DISTINCT, 100.0 * DISTINCT):
            ax.axhline(bound, color="k", lw=0.8, ls=":")
    _finish_paths_figure(fig, axes, paths, "direct method's CP energy vs DP (CP) [%]",
                         f"The direct method from each seed (hollow: not a local optimum within limits); dotted: ±{DISTINCT:.1%}",
                         out_dir / "dp_multistart.png")
    return summary


def polish_part() -> dict:
    """The certificate's third and fourth ways (issue 55): every savings-map line and K70M comparison where the DP's realised
    energy is above the best feasible baseline in its own cost by more than CERTIFIED, planned again and its DP trajectory
    polished (``planning.polish``); and the DP planned on a grid narrowed to a tube around that baseline
    (``DpGrid.around``), its answer polished too; against the same baselines the certificate reads (the file's feasible
    pseudo-inverses and, in a comparison, the direct method). The baseline is run again for its trajectory and must give
    the file's energy."""
    from dataclasses import replace

    from tqdm import tqdm

    from hydro_ros.contract.config import default_config_path
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.certify import CERTIFIED
    from hydro_ros.planning.costs import Cost
    from hydro_ros.planning.dp import TUBE_HALF_WIDTH, TUBE_VELOCITY_PAD, DpGrid
    from hydro_ros.planning.polish import polish
    from hydro_ros.planning.problem import Problem, plan_dp, run_method
    from hydro_ros.studies.savings_map import line_paths
    from hydro_ros.tooling.reproduction import DP_MIDDLE_START, DP_SMALLEST_START, best_feasible_baseline

    crane, config = load_crane(default_config_path("k70m"))
    results = Path(__file__).resolve().parent / "results"
    cases = []  # (name, path id, path entry or None for the config's own, start, cost, best feasible baseline [J], its method)
    savings = json.loads((results / "savings_map.json").read_text())
    for row in savings["rows"]:
        if not row["feasible"]:
            continue
        methods = {name: {f"{k}_energy_J": v for k, v in e.items() if k in ("cp", "ls")} | {"limits": e.get("limits")}
                   for name, e in row["energy_J"].items()}
        for cost in ("cp", "ls"):
            best = best_feasible_baseline(methods, cost)
            if best is not None and methods[f"dp_{cost}"][f"{cost}_energy_J"] / best - 1.0 > CERTIFIED:
                x, y = row["start"][:2]
                lines = line_paths([x], [y], [], []) if row["path"].startswith("vertical") else line_paths([], [], [y], [x])
                cases.append((row["path"], row["path"], lines[row["path"]], "smallest", cost, best, baseline_of(methods, best, cost)))
    for name in DP_SMALLEST_START + DP_MIDDLE_START:
        compare = json.loads((results / f"{name}.json").read_text())
        if compare["machine"] != "k70m":
            continue
        for cost in ("cp", "ls"):
            best = best_feasible_baseline(compare["methods"], cost)
            if best is not None and compare["methods"][f"dp_{cost}"][f"{cost}_energy_J"] / best - 1.0 > CERTIFIED:
                start = "middle" if name.endswith("_middle") else "smallest"
                cases.append((f"k70m/{compare['path']} ({start})", compare["path"], None, start, cost, best,
                              baseline_of(compare["methods"], best, cost)))
    rows = {}
    for name, path_id, entry, start, cost, best, method in tqdm(cases, desc="polish", unit="case"):
        variant = config.with_paths({path_id: entry}) if entry is not None else config
        problem = Problem.build(crane, variant, path_id, start=start)
        dp = run_method(problem, f"dp_{cost}")
        began = time.perf_counter()
        _, info = polish(crane, problem.samples, dp.trajectory, Cost(cost))
        polished = info["after_J"] if info["improved"] else info["before_J"]
        seed = run_method(problem, "pinv_joint").trajectory if method == "direct_cp" else None
        baseline = run_method(problem, method, seed=seed)
        if abs(baseline.evaluation[f"{cost}_energy_J"] / best - 1.0) > 1e-6:
            raise RuntimeError(f"{name} {cost}: {method} gives {baseline.evaluation[f'{cost}_energy_J']:.1f} J, the file {best:.1f} J")
        tube = DpGrid.around(crane, problem.samples, baseline.trajectory, problem.grid.shape)
        refined = plan_dp(replace(problem, grid=tube), Cost(cost))
        _, refined_info = polish(crane, problem.samples, refined.trajectory, Cost(cost))
        refined_polished = refined_info["after_J"] if refined_info["improved"] else refined_info["before_J"]
        rows[f"{name} {cost}"] = {
            "case": name, "cost": cost, "baseline": method, "baseline_J": best, "dp_J": info["before_J"], "polished_J": polished,
            "improved": info["improved"], "status": info["status"], "iterations": info["iterations"],
            "dp_over_baseline": info["before_J"] / best - 1.0, "polished_over_baseline": polished / best - 1.0,
            "refined_J": refined_info["before_J"], "refined_limits_ok": all(refined.evaluation["limits"].values()),
            "refined_predicted_J": refined.info["predicted_cost"] if refined.info else None,
            "refined_over_baseline": refined_info["before_J"] / best - 1.0,
            "refined_polished_over_baseline": refined_polished / best - 1.0, "refined_status": refined_info["status"],
            "certified_over_baseline": min(polished, refined_polished) / best - 1.0,
            "seconds": round(time.perf_counter() - began, 1)}
        print(f"polish {name} {cost}: DP {info['before_J'] / best - 1.0:+.2%}, polished {polished / best - 1.0:+.2%}; refined around "
              f"{method} {refined_info['before_J'] / best - 1.0:+.2%}, polished {refined_polished / best - 1.0:+.2%} over it", flush=True)
    return {"certified_share": CERTIFIED, "savings_map_commit": savings.get("commit"), "cases": rows,
            "tube": {"half_width_m": TUBE_HALF_WIDTH, "velocity_pad_m_s": TUBE_VELOCITY_PAD},
            "certified_after": sum(r["polished_over_baseline"] <= CERTIFIED for r in rows.values()),
            "certified_after_refining": sum(r["certified_over_baseline"] <= CERTIFIED for r in rows.values()),
            "cases_above_before": len(rows)}


def baseline_of(methods: dict[str, dict], best: float, cost: str) -> str:
    """The method whose energy in ``cost`` is ``best`` (the best feasible baseline's)."""
    return next(name for name, r in methods.items() if not name.startswith("dp_") and r[f"{cost}_energy_J"] == best)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="bench/results/dp.json")
    parser.add_argument("--parts", default="solver,convergence,compare,window,replanning,multistart,polish",
                        help="comma-separated parts to run; the others are kept from an existing --out")
    parser.add_argument("--machines", default="k70m,crane3dof,excavator",
                        help="comma-separated machines the compare part runs; the others' comparisons are kept from --out")
    args = parser.parse_args()
    out = Path(args.out)
    known = ("solver", "convergence", "compare", "window", "replanning", "multistart", "polish")
    unknown = set(args.parts.split(",")) - set(known)
    if unknown:
        parser.error(f"--parts: unknown {', '.join(sorted(unknown))} (known: {', '.join(known)})")
    results = json.loads(out.read_text()) if out.exists() else {}
    parts = {"solver": solver_speed, "convergence": lambda: convergence(out.parent),
             "compare": lambda: comparisons(out.parent, set(args.machines.split(",")), results.get("compare", {})),
             "window": window_study, "replanning": replanning, "multistart": lambda: multistart(out.parent),
             "polish": polish_part}
    chosen = args.parts.split(",")
    results.update({name: run() for name, run in parts.items() if name in chosen})
    # a part kept from an earlier run keeps the commit it ran on
    kept = results.get("part_commits", dict.fromkeys(parts, results.get("commit", "not recorded")))
    results["part_commits"] = {name: commit() if name in chosen else kept.get(name, "not recorded") for name in parts}
    results["bench_process_peak_rss_MB"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    write_result(out, results)
    print(json.dumps(results["solver"], indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
