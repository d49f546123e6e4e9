"""Where in the K70M's workspace the telescope's redundancy pays: the energy-optimal DP against the pseudo-inverses on
straight tip lines placed across the workspace (P-VI's vertical and horizontal paths moved), CP and LS.

Each line keeps its P-VI duration and length (a vertical line of 3.04 m in 6 s, a horizontal one of 3.2 m in 10 s);
only its position changes. Per position: DP (CP) and DP (LS) against the better of the joint and actuator
pseudo-inverses that stay within the joint and cylinder limits (both, where neither does), each from the smallest
feasible telescope start, as the config's paths are planned. A position the crane cannot follow (unreachable, or no
feasible telescope along it) is reported as such.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import Crane
from hydro_ros.planning.problem import Problem, method_record, run_method

METHODS = ("dp_cp", "dp_ls", "pinv_joint", "pinv_actuator", "pinv_actuator_weighted")
SAVING_BASELINES = ("pinv_joint", "pinv_actuator")  # the saving is over P-VI's pseudo-inverses; the weighted one (P-V's) is recorded
VERTICAL = {"length": 3.04, "duration": 6.0}  # P-VI's vertical path (config/k70m.yaml)
HORIZONTAL = {"length": 3.2, "duration": 10.0}  # P-VI's horizontal path


def line_paths(vertical_x: Iterable[float], vertical_y0: Iterable[float], horizontal_y: Iterable[float],
               horizontal_x0: Iterable[float]) -> dict[str, dict[str, Any]]:
    """Path entries (config ``paths:`` form) of vertical lines from (x, y0) and horizontal lines from (x0, y)."""
    paths = {}
    for x in vertical_x:
        for y0 in vertical_y0:
            paths[f"vertical_x{x:g}_y{y0:g}"] = {"start": [x, y0, 0.0], "segments": [
                {"type": "quintic", "to": [x, y0 + VERTICAL["length"], 0.0], "duration": VERTICAL["duration"]}]}
    for y in horizontal_y:
        for x0 in horizontal_x0:
            paths[f"horizontal_x{x0:g}_y{y:g}"] = {"start": [x0, y, 0.0], "segments": [
                {"type": "quintic", "to": [x0 + HORIZONTAL["length"], y, 0.0], "duration": HORIZONTAL["duration"]}]}
    return paths


def savings(crane: Crane, config: CraneConfig, paths: dict[str, dict[str, Any]], *, grid: tuple[int, int, int] | None = None,
            progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """One row per line position: the methods' energies and the DP's saving over the better pseudo-inverse."""
    rows = []
    for path_id, entry in paths.items():
        variant = config.with_paths({path_id: entry})
        row: dict[str, Any] = {"path": path_id, "start": entry["start"], "end": entry["segments"][-1]["to"]}
        try:
            problem = Problem.build(crane, variant, path_id, grid=grid)
            records = {method: method_record(run_method(problem, method)) for method in METHODS}
        except (InputError, ValueError) as exc:
            row["feasible"], row["reason"] = False, str(exc).splitlines()[0]
            rows.append(row)
            continue
        row["feasible"] = True
        # limits_ok: the limits a method claims to keep (a pseudo-inverse: position and velocity); limits: each kind,
        # acceleration included, as the DP keeps them (the certificate of docs/reproduction.md compares those)
        row["energy_J"] = {m: {"cp": r["cp_energy_J"], "ls": r["ls_energy_J"], "limits_ok": r["limits_ok"], "limits": r["limits"]}
                           for m, r in records.items()}
        # a pseudo-inverse that breaks a joint or cylinder limit is no alternative the machine could run
        within = [m for m in SAVING_BASELINES if records[m]["limits_ok"]]
        row["pinv_within_limits"] = within
        for cost in ("cp", "ls"):
            best_pinv = min(records[m][f"{cost}_energy_J"] for m in within or SAVING_BASELINES)
            row[f"saving_{cost}"] = 1.0 - records[f"dp_{cost}"][f"{cost}_energy_J"] / best_pinv
        rows.append(row)
        if progress:
            progress(path_id)
    return rows
