"""bench/results/: what a benchmark writes there (its JSON stamped with the commit it ran on), and docs/benchmarks.md's
table written from those files (no figure typed by hand).

Each row reads one measurement and the reference it is compared with in the same run; a file or a key a run did not
write shows as "not in bench/results". Each file's commit is the one its run recorded (older runs recorded none), and
its ``code`` the hash of the code that ran (:func:`code_hash`), which ``make bench`` (:mod:`hydro_ros.tooling.benchrun`) compares to resume a run.
"""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[2]  # the checkout
RESULTS = ROOT / "bench" / "results"
MISSING = "not in bench/results"
# what is written from the results, so not what ran: regenerating the docs after a run leaves its results current
NOT_CODE = ("bench/results", "docs", "README.md")
CODE_ENV = "HYDRO_ROS_BENCH_CODE"  # set by make bench: the code hash taken when the run started, which its results carry


def _git(*args: str, root: Path = ROOT, env: dict[str, str] | None = None) -> str:
    return subprocess.run(["git", *args], cwd=root, capture_output=True, text=True, env=env).stdout.strip()


def code_hash(root: Path = ROOT, paths: tuple[str, ...] = (".",), excluding: tuple[str, ...] = ()) -> str:
    """The git tree hash of the working tree as it is (uncommitted and new files included, ignored ones not) without
    bench/results, docs/ and README.md: the code a result ran on, equal for equal code whatever the commit. ``paths``
    and ``excluding`` narrow it to the code one computation reads."""
    with tempfile.TemporaryDirectory() as tmp:
        env = {**os.environ, "GIT_INDEX_FILE": str(Path(tmp) / "index")}
        named = [path for path in paths if (root / path).exists()]
        if len(named) < len(paths):  # git would refuse the whole list and hash an empty tree
            raise ValueError(f"code_hash: {', '.join(sorted(set(paths) - set(named)))} not in {root}")
        _git("add", "--all", "--", *named, *(f":(exclude){path}" for path in (*NOT_CODE, *excluding)), root=root, env=env)
        return _git("write-tree", root=root, env=env) or "unknown"


def imported_by(script: str, root: Path = ROOT, leaving: tuple[str, ...] = ()) -> tuple[str, ...]:
    """``script`` and every file of the package it imports, directly or through others (imports inside functions too,
    and each package's ``__init__`` on the way), as paths under ``root``, less those under ``leaving``: the code a
    computation reads, for :func:`code_hash`, so that a commit elsewhere in the package keeps its cache."""

    def module_file(name: str) -> Path | None:
        base = root.joinpath(*name.split("."))
        return next((path for path in (base.with_suffix(".py"), base / "__init__.py") if path.is_file()), None)

    def named(path: Path) -> set[str]:
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ImportFrom) and node.level:
                raise ValueError(f"imported_by: {path.relative_to(root)}:{node.lineno}: a relative import; the package writes them absolute")
            if isinstance(node, ast.ImportFrom) and node.module:
                found |= {node.module, *(f"{node.module}.{alias.name}" for alias in node.names)}
            elif isinstance(node, ast.Import):
                found |= {alias.name for alias in node.names}
        return {name for name in found if name.split(".")[0] == "hydro_ros"}

    seen: set[Path] = set()
    todo = [root / script]
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for name in named(path):
            parts = name.split(".")
            todo += [f for f in (module_file(".".join(parts[:i])) for i in range(1, len(parts) + 1)) if f is not None]
    files = sorted(str(path.relative_to(root)) for path in seen)
    return tuple(f for f in files if not any(f == place or f.startswith(place.rstrip("/") + "/") for place in leaving))


def commit() -> str:
    """The checked-out commit, ``+changes`` when the code differs from it, a new file not yet committed included (results
    and the docs written from them do not count): what a result ran on."""
    head = _git("rev-parse", "--short", "HEAD")
    changed = _git("status", "--porcelain", "--untracked-files=normal", "--", ".", *(f":(exclude){path}" for path in NOT_CODE))
    return (head + ("+changes" if changed else "")) if head else "unknown"


def write_result(path: str | Path, result: dict[str, Any]) -> Path:
    """``result`` as JSON at ``path``, with the commit and the code it ran on first."""
    path = Path(path)
    stamps = {"commit": commit(), "code": os.environ.get(CODE_ENV) or code_hash()}
    path.write_text(json.dumps({**stamps, **{k: v for k, v in result.items() if k not in stamps}}, indent=2) + "\n")
    return path


# keys whose numbers are wall-clock times, speeds, speed-ups or memory: they move with the machine and its load, not with the
# code (checked against every key of bench/results: a physical peak, ratio or speed, e.g. pump_flow_peak_m3s, side_ratio,
# telescope_speed_m_s, is compared)
MACHINE_BOUND = re.compile(r"(^|_)(wall|seconds|cpu|cores|rss|mb|memory|latency|elapsed|runtime|speedup|ms)($|_)|per_s($|_)|per_core"
                           r"|real_time|peak_(rss|mb|vs)|ratio_(to|blocks)|^(commission|open_check|samples|measured|duration|server_ready)_s",
                           re.I)


def moved(before: Any, after: Any, tolerance: float = 0.005, where: str = "") -> list[str]:
    """The figures of a result that a rerun moved by more than ``tolerance`` of their size, and what it added or dropped
    ("rows[3].gap: 0.781 -> 0.79"), leaving out the stamps and the machine-bound figures (MACHINE_BOUND)."""
    if isinstance(before, dict) and isinstance(after, dict):
        out = []
        for key in dict.fromkeys([*before, *after]):
            if key in ("commit", "code", "part_commits") or MACHINE_BOUND.search(str(key)):
                continue
            if key not in after or key not in before:
                out.append(f"{where}{key}: {'dropped' if key not in after else 'added'}")
            else:
                out += moved(before[key], after[key], tolerance, f"{where}{key}.")
        return out
    if isinstance(before, list) and isinstance(after, list):
        if len(before) != len(after):
            return [f"{where.rstrip('.')}: {len(before)} -> {len(after)} entries"]
        return [line for k, (b, a) in enumerate(zip(before, after)) for line in moved(b, a, tolerance, f"{where.rstrip('.')}[{k}].")]
    numbers = (int, float)
    if isinstance(before, numbers) and isinstance(after, numbers) and not isinstance(before, bool) and not isinstance(after, bool):
        same = before == after or abs(after - before) <= tolerance * max(abs(before), abs(after))
        return [] if same else [f"{where.rstrip('.')}: {before:.6g} -> {after:.6g}"]
    return [] if before == after else [f"{where.rstrip('.')}: {str(before)[:40]} -> {str(after)[:40]}"]


def read_results() -> dict[str, Any]:
    """Every result file, by name without ``.json``, each read once."""
    return {path.stem: json.loads(path.read_text()) for path in RESULTS.glob("*.json")}


def commit_of(data: Any, part: str | None = None) -> str:
    """The commit a result file's run recorded ("-" for a file not written); for a file some of whose parts were rerun
    (bench/dp.py --parts), the commit ``part`` ran on."""
    if data is None:
        return "-"
    if not isinstance(data, dict):
        return "commit not recorded"
    return data.get("part_commits", {}).get(part, data.get("commit", "commit not recorded"))


def span(values: list[float], fmt: str, sep: str = "-") -> str:
    """The least and the greatest of ``values``, one number where they print alike."""
    low, high = format(min(values), fmt), format(max(values), fmt)
    return low if low == high else f"{low}{sep}{high}"


def _model(r: dict) -> tuple[str, str, str]:
    m = r["sam_model_1khz"]
    return ("SAM model at 1 kHz, one core", f"{m['real_time_factor']:.0f}x real time ({m['simulated_s']:.0f} simulated s in "
            f"{m['wall_s']:.2f} s)", f"target >= {m['target_real_time_factor']:.0f}x")


def _bag(r: dict) -> tuple[str, str, str]:
    b = r["bag_read"]
    return ("bag read into aligned arrays", f"{b['hydro_ros_msgs_per_s'] / 1e6:.2f} M msg/s",
            f"rosbags `AnyReader` deserialising only: {b['rosbags_anyreader_msgs_per_s']:,.0f} msg/s "
            f"(**{b['speedup_vs_rosbags']:.1f}x**)")


def _ukf(r: dict) -> tuple[str, str, str]:
    u = r["ukf"]
    return ("UKF steps (P-II filter, one actuator)", f"{u['hydro_ros_steps_per_s'] / 1e6:.2f} M steps/s; "
            f"{u['hydro_ros_4_actuator_batch_steps_per_s_per_actuator'] / 1e6:.2f} M/s per actuator in a 4-actuator batch",
            f"filterpy `UnscentedKalmanFilter`, same model: {u['filterpy_steps_per_s']:,.0f} steps/s "
            f"(**{u['speedup_vs_filterpy']:.0f}x**, target >= {u['target_speedup']:.0f}x); {u['agreement']}")


def _fdi_offline(r: dict) -> tuple[str, str, str]:
    f = r["fdi_offline"]
    return (f"offline `hydro-ros fdi` on a {f['bag_s']:.0f} s SAM bag", f"**{f['real_time_factor']:.0f}x real time** "
            f"(read {f['read_real_time_factor']:.0f}x, monitor {f['monitor_real_time_factor']:.0f}x)",
            f"target >= {f['target_real_time_factor']:.0f}x")


def _live(row: dict, what: str, rate: str, progress: str, counts: tuple[str, ...]) -> tuple[str, str, str]:
    faults = ", ".join(f"{row[key]} {key.replace('_', ' ')}" for key in counts)
    return (what, f"{row['cpu_share_of_one_core']:.0%} of one core; {row[progress]:.0f}/s processed; {faults}",
            f"the {row['sample_rate_hz']:.0f} Hz {rate}")


def _fdi_live(r: dict) -> tuple[str, str, str]:
    row = r["fdi_node_live"]
    return _live(row, f"live fdi_node fed by plant_sim ({row['messages_per_s']:.0f} msg/s)", "sample rate", "samples_processed_per_s",
                 ("gap_samples", "incomplete_samples", "out_of_order_dropped"))


def _can(r: dict) -> tuple[str, str, str]:
    c = r["can_decode"]
    return ("CAN frames decoded with every check (DLC, CRC, counter, cycle grouping)", f"{c['checked_frames_per_s']:,.0f} frames/s",
            f"bare `cantools` decode of the same frames: {c['bare_cantools_frames_per_s']:,.0f}/s (ratio "
            f"{c['ratio_to_bare_cantools']:.2f}); the SAM needs {c['sam_frames_per_s_needed']:,}/s")


def _can_live(r: dict) -> tuple[str, str, str]:
    row = r["can_bridge_live"]
    return _live(row, f"live can_bridge, plant_sim on udp_multicast CAN ({row['frames_per_s']:.0f} frames/s)", "cycle",
                 "cycles_published_per_s", ("incomplete_cycles",))


def _dp(d: dict) -> tuple[str, str, str]:
    s = d["solver"]
    grid = " x ".join(str(n) for n in s["grid"])
    cp, ls, ref = s["fast_cp"], s["fast_ls"], s["reference_cp"]
    return (f"DP backward pass, grid {grid}, N = {s['stages']}",
            f"CP cost **{cp['seconds']:.2f} s** (best of {len(cp['runs_s'])}: {span(cp['runs_s'], '.2f')} s), "
            f"{cp['peak_rss_MB']:.0f} MB peak RSS; LS cost **{ls['seconds']:.2f} s** (best of {len(ls['runs_s'])}: "
            f"{span(ls['runs_s'], '.2f')} s)",
            f"the straightforward NumPy DP (`planning/reference.py`): {ref['seconds']:.0f} s, {ref['peak_rss_MB']:.0f} MB "
            f"(**{s['speedup_cp']:.0f}x** time, {s['memory_ratio_cp']:.2f}x memory); same cost-to-go: {s['same_cost_to_go']}")


def _db(t: dict) -> tuple[str, str, str]:
    runs = t["throughput"]
    grid = " x ".join(str(n) for n in runs["grid"])
    others = [f"{name}: {run['seconds']:.1f} s ({run['units_per_s']:.2f}/s, **{run['speedup_vs_1_process']:.2f}x**)"
              for name, run in runs.items() if isinstance(run, dict) and "speedup_vs_1_process" in run]
    return (f"`db build`, {runs['units']} solutions, grid {grid}", "; ".join(others),
            f"1 process: {runs['1 process']['seconds']:.1f} s ({runs['1 process']['units_per_s']:.2f}/s)")


def _catalog(t: dict) -> tuple[str, str, str]:
    c = t["full_catalog"]
    grid = " x ".join(str(n) for n in c["grid"])
    return (f"full-grid catalog ({grid}, {c['units']} solutions)", f"{c['seconds']:.0f} s; {c['size_MB']:.0f} MB file; open + "
            f"quick_check {c['open_check_s']:.2f} s", "-")


def _server(t: dict) -> tuple[str, str, str]:
    lat = t["latency"]
    moved, stored = lat["re-planned start"], lat["stored start"]
    return ("trajectory_server request -> JointTrajectory received (live DDS graph, full-grid catalog)",
            f"re-planned from a moved start: **p50 {moved['p50_ms']:.1f} ms, p99 {moved['p99_ms']:.1f} ms**, max "
            f"{moved['max_ms']:.0f} ms ({moved['requests']} requests); stored start: p50 {stored['p50_ms']:.1f} ms, p99 "
            f"{stored['p99_ms']:.1f} ms; ready {lat['server_ready_s']:.1f} s after its process starts", "target p99 <= 20 ms")


def _hmi(h: dict) -> tuple[str, str, str]:
    phases = h["phases"]
    clients = " / ".join(str(p["clients"]) for p in phases)
    shares = " / ".join(f"{p['cpu_share_of_one_core']['hmi']:.1%}" for p in phases)
    latency = [p["diagnostics_to_dom_latency_ms"] for p in phases if p["diagnostics_to_dom_latency_ms"]["n"]]
    fdi = [p["cpu_share_of_one_core"]["fdi_node"] for p in phases]
    ratios = [p["hmi_cpu_vs_fdi_node"] for p in phases]
    return (f"operator HMI at the SAM's rates, {clients} headless Chromium pages", f"**{shares} of one core**; /diagnostics -> DOM "
            f"p50 {span([x['p50'] for x in latency], '.0f')} ms, p95 {span([x['p95'] for x in latency], '.0f')} ms",
            f"fdi_node in the same run: {span(fdi, '.0%')} (HMI {span(ratios, '.2f')}x)")


def _crane_cpu(c: dict) -> tuple[str, str, str]:
    blocks, topics = c["sample_blocks"], c["per_sample_topics"]
    return (f"live fdi_node on the K70M's {c['cylinders']} cylinders at {c['sample_rate_hz']:.0f} Hz, `input:=sample_block`",
            f"**{blocks['cpu_share_of_one_core']:.0%} of one core** (target under {c['goal_share_of_one_core']:.0%}); "
            f"{blocks['samples_processed_per_s']:.0f} samples/s, {blocks['gap_samples']} gaps",
            f"the contract's per-sample topics, `input:=topics`: {topics['cpu_share_at_1khz']:.2f} cores scaled to 1 kHz "
            f"(**blocks {c['ratio_blocks_to_topics']:.2f}x**)")


def _fleet(f: dict) -> tuple[str, str, str]:
    runs = f["runs"]
    best = max(runs, key=lambda name: runs[name]["one_hour_recordings_per_core_hour"])
    fleet = f["fleet"]
    return (f"fleet analysis, {f['recordings']} recordings of {f['recording_s']:.0f} s",
            "; ".join(f"{name}: {run['one_hour_recordings_per_core_hour']:.0f} recorded hours per core-hour" for name, run in runs.items()),
            f"a fleet of {fleet['machines']} machines recording {fleet['hours_per_day']:.0f} h a day needs "
            f"{fleet['cores_for_a_day_in_a_day']:.2f} cores (at the best, {best})")


def _memory(m: dict) -> tuple[str, str, str]:
    runs = m["runs"]
    return ("`hydro-ros commission`, peak resident memory", "; ".join(f"{run['recording_s'] / 60:.0f} min: {run['peak_mb']:.0f} MB"
                                                                      for run in runs),
            f"target {m['target_mb']:.0f} MB for 2 h; the samples themselves: {runs[-1]['samples_mb']:.0f} MB "
            f"({runs[-1]['peak_vs_samples']:.1f}x); growth {m['growth_mb_per_recorded_hour']:.0f} MB per recorded hour")


def _soak(s: dict) -> tuple[str, str, str]:
    lost_sight = {k: v for k, v in s["measured_s"].items() if k in ("monitor_freeze", "monitor_kill", "plant_gap")}
    return (f"live safety chain soak ({s['duration_s'] / 60:.0f} min; "
            + ", ".join(f"{n} {kind}" for kind, n in s["impairments"].items()) + ")",
            f"**{len(s['violations'])} violations**; last non-neutral command after the monitor lost sight: "
            + ", ".join(f"{kind} {v['max']:.2f} s" for kind, v in lost_sight.items())
            + f"; moving {s['moving_share_of_fault_free']:.0%} of the fault-free time; severe faults still moving after "
            f"{s['bounds_s']['severe_fault']:.0f} s: {len(s['severe_faults_still_moving_after_budget'])}",
            "documented bounds: " + ", ".join(f"{kind} {bound:.2f} s" for kind, bound in s["bounds_s"].items()))


def _halt_latency(h: dict) -> tuple[str, str, str]:
    lat = h["latency_s"]
    return (f"trajectory_executor to neutral ({lat['halt']['trials']} halts, {lat['joint_states_stale']['trials']} joint-state losses, "
            "quiet machine)",
            f"halt: median {lat['halt']['median'] * 1e3:.1f} ms, max **{lat['halt']['max'] * 1e3:.1f} ms** "
            f"({lat['halt']['within_promise']}/{lat['halt']['trials']} within {h['promise_s']:g} s); joint states lost: "
            f"max {lat['joint_states_stale']['max'] * 1e3:.1f} ms beyond joint_state_timeout",
            f"documented: neutral within {h['promise_s']:g} s of a halt; control period {h['control_period_s'] * 1e3:.0f} ms")


def _mutants(m: dict) -> tuple[str, str, str]:
    return (f"listed mutation run ({m['total']} mutants of the plant's injections and the isolation table)",
            f"**{m['killed']} of {m['total']} killed**" + (f"; survived: {', '.join(m['survivors'])}" if m["survivors"] else ""),
            "the unmutated tree passes the same tests")


ROWS: list[tuple[str, str, Callable[[dict], tuple[str, str, str]]]] = [  # (file, the part a row reads, the row)
    ("results", "sam_model_1khz", _model), ("results", "bag_read", _bag), ("results", "ukf", _ukf),
    ("results", "fdi_offline", _fdi_offline), ("results", "fdi_node_live", _fdi_live), ("results", "can_decode", _can),
    ("results", "can_bridge_live", _can_live), ("dp", "solver", _dp), ("trajectories", "throughput", _db),
    ("trajectories", "full_catalog", _catalog), ("trajectories", "latency", _server), ("hmi", "phases", _hmi),
    ("crane_cpu", "sample_blocks", _crane_cpu), ("fleet", "runs", _fleet), ("commissioning_memory", "runs", _memory),
    ("safety_soak", "violations", _soak), ("halt_latency", "latency_s", _halt_latency), ("mutants", "mutants", _mutants)]


def benchmarks_markdown() -> str:
    results = read_results()
    lines = ["| what | measured | reference in the same run | file (commit) |", "|---|---|---|---|"]
    for name, part, row in ROWS:
        data = results.get(name)
        try:
            what, measured, reference = row(data) if data is not None else (name, MISSING, "-")
        except KeyError as missing:
            what, measured, reference = name, f"{MISSING} (no {missing})", "-"
        cells = (cell.replace("|", "\\|") for cell in (what, measured, reference))
        lines.append(f"| {' | '.join(cells)} | `{name}.json` ({commit_of(data, part)}) |")
    lines += ["", "Every file `make bench` writes, with the commit its run recorded:", ""]
    for path in sorted(RESULTS.glob("*")):
        commit = f" ({commit_of(results[path.stem])})" if path.suffix == ".json" else ""
        lines.append(f"- [`{path.name}`](../bench/results/{path.name}){commit}")
    return "\n".join(lines)


def require_clean_tree() -> None:
    """Refuse (SystemExit, one line) a tree whose code differs from its commit: its results would name a commit that is
    not what ran. ``make bench ALLOW_DIRTY=1`` runs anyway, and the results say ``+changes``."""
    ran_on = commit()
    if ran_on.endswith("+changes"):
        raise SystemExit(f"make bench: the tree has uncommitted changes outside bench/results, docs/ and README.md (commit {ran_on}): "
                         "commit them first, "
                         "or run make bench ALLOW_DIRTY=1 (the results will say +changes)")

