"""`hydro-ros dp solve` / `dp compare`: one path, one or all methods, scored by one evaluation.

The problem and its methods are :mod:`hydro_ros.planning.problem`; this module runs them side by
side and reports energies relative to the best (P-V Tables 2-3 style).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hydro_ros.planning.problem import CONTRACT_METHODS, Plan, Problem, method_record, run_method


def compare(
    problem: Problem,
    methods: tuple[str, ...] = CONTRACT_METHODS,
    *,
    progress: Callable[[str], None] | None = None,
) -> dict[str, Any]:
    """All methods on one path; energies also relative to the best of each (P-V Tables 2-3 style)."""
    plans: dict[str, Plan] = {}
    for method in methods:
        seed = plans["pinv_joint"].trajectory if method == "direct_cp" and "pinv_joint" in plans else None
        plans[method] = run_method(problem, method, seed=seed)
        if progress:
            progress(method)
    records = {method: method_record(plan) for method, plan in plans.items()}
    for energy in ("cp_energy_J", "ls_energy_J"):
        best = min(record[energy] for record in records.values())
        for record in records.values():
            record[f"relative_{energy[:2]}"] = record[energy] / best
    return {
        "machine": problem.crane.name,
        "path": problem.path.path_id,
        "start_position_m": problem.start,
        "grid": list(problem.grid.shape),
        "stages": problem.samples.stages,
        "sample_time_s": float(problem.samples.time[1]),
        "methods": records,
    }


def markdown_table(result: dict[str, Any]) -> str:
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
