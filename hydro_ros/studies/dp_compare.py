"""`hydro-ros dp solve` / `dp compare`: one path, one or all methods, scored by one evaluation.

The problem and its methods are :mod:`hydro_ros.planning.problem`; this module runs them side by
side and reports energies relative to the best (P-V Tables 2-3 style).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import NotRequired, TypedDict

from hydro_ros.planning.problem import CONTRACT_METHODS, MethodRecord, Plan, Problem, method_record, run_method


class Comparison(TypedDict):
    """Every method on one path (``dp compare``'s JSON)."""
    machine: str
    path: str
    start_position_m: float
    grid: list[int]
    stages: int
    sample_time_s: float
    methods: dict[str, MethodRecord]
    plot: NotRequired[str]


def compare(
    problem: Problem,
    methods: tuple[str, ...] = CONTRACT_METHODS,
    *,
    progress: Callable[[str], None] | None = None,
) -> Comparison:
    """All methods on one path; energies also relative to the best of each (P-V Tables 2-3 style)."""
    plans: dict[str, Plan] = {}
    for method in methods:
        seed = plans["pinv_joint"].trajectory if method == "direct_cp" and "pinv_joint" in plans else None
        plans[method] = run_method(problem, method, seed=seed)
        if progress:
            progress(method)
    records = {method: method_record(plan) for method, plan in plans.items()}
    best_cp = min(record["cp_energy_J"] for record in records.values())
    best_ls = min(record["ls_energy_J"] for record in records.values())
    for record in records.values():
        record["relative_cp"] = record["cp_energy_J"] / best_cp
        record["relative_ls"] = record["ls_energy_J"] / best_ls
    return {
        "machine": problem.crane.name,
        "path": problem.path.path_id,
        "start_position_m": problem.start,
        "grid": list(problem.grid.shape),
        "stages": problem.samples.stages,
        "sample_time_s": float(problem.samples.time[1]),
        "methods": records,
    }


def markdown_table(result: Comparison) -> str:
    lines = [
        f"{result['machine']} / {result['path']} (start c = {result['start_position_m']:.3f} m, grid {result['grid']})",
        "",
        "| method | CP energy kJ | rel. CP | LS energy kJ | rel. LS | peak LS pressure MPa | limits claimed | limits ok |",
        "|---|---|---|---|---|---|---|---|",
    ]
    ordered = sorted(result["methods"].items(), key=lambda item: item[1]["cp_energy_J"])
    for method, record in ordered:
        lines.append(
            f"| {method} | {record['cp_energy_J'] / 1e3:.1f} | {record['relative_cp']:.3f} | {record['ls_energy_J'] / 1e3:.1f} | "
            f"{record['relative_ls']:.3f} | {record['ls_supply_pressure_peak_Pa'] / 1e6:.1f} | "
            f"{', '.join(record['limits_claimed'])} | {'yes' if record['limits_ok'] else 'NO'} |"
        )
    return "\n".join(lines)


def plot_comparison(result: Comparison, out: str | Path) -> Path:
    """Bar chart of CP and LS energy per method, like P-VI Figs. 10-12 (a)."""
    import numpy as np

    from hydro_ros.workflows.plots import plt

    methods = sorted(result["methods"], key=lambda name: result["methods"][name]["cp_energy_J"])
    cp = [result["methods"][name]["cp_energy_J"] / 1e3 for name in methods]
    ls = [result["methods"][name]["ls_energy_J"] / 1e3 for name in methods]
    x = np.arange(len(methods))
    fig, ax = plt.subplots(figsize=(1.1 * len(methods) + 3, 4))
    ax.bar(x - 0.2, cp, 0.4, label="CP system")
    ax.bar(x + 0.2, ls, 0.4, label="LS system")
    for xi, name in zip(x, methods, strict=True):
        if not result["methods"][name]["limits_ok"]:
            ax.annotate("limits!", (xi, max(cp[xi], ls[xi])), ha="center", va="bottom", color="red")
    ax.set_xticks(x, methods, rotation=30, ha="right")
    ax.set_ylabel("hydraulic energy [kJ]")
    ax.set_title(f"{result['machine']} / {result['path']}: energy per method")
    ax.legend()
    ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    out = Path(out)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
