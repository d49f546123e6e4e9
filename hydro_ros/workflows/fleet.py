"""A fleet's recordings: per recording and cylinder the monitor's verdict and the leak flows the recording holds, per
machine and cylinder the trend of each leak and the date it reaches the service limit (``hydro-ros fleet analyse``).

Layout: ``DIR/<machine id>/machine.yaml`` (its config, commissioned or not) and its recordings (bag folders or .mcap
files) anywhere below. Each recording is one unit of work, on local processes or on the workers of a Dask cluster
(``distributed``'s executor, as ``db build``); a worker reads one recording, never the fleet. Results go into a SQLite
store in OUT keyed by the recording's content hash, one row per recording and actuator, committed as each unit ends:
a rerun analyses only new recordings, a killed run loses nothing finished.

The leak flows come from the identification core of commissioning (``models.identification``): the load-independent
continuity rows of the recording, with the valve and fluid of the machine's config (its commissioned model where it
has one), leave unexplained flow; the three leak terms are fitted to it, in L/min at 10 MPa (the quoting of every leak
here), with a standard error from the fit's residual over the recording's effective number of independent rows
(one per `identification.CORRELATION_S` of motion, INFERRED from the 8 Hz low-pass of the rows). A notch is covered when the recording
held it open long enough to separate the leaks from the valve (commissioning's MIN_OPEN_S).
"""

from __future__ import annotations

import base64
import datetime
import hashlib
import io
import json
import math
import sqlite3
from collections.abc import Callable
from concurrent.futures import Future, as_completed
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.reader import read_bag
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.models.identification import LeakFit, flow_regression, leak_fit, nominal_coefficients
from hydro_ros.models.sam import SamModel
from hydro_ros.planning.catalog import work_executor
from hydro_ros.workflows.commissioning import MIN_OPEN_S

SHORT = {"external_leakage_a": "a", "external_leakage_b": "b", "internal_leakage": "internal"}
SERVICE_LIMIT_L_MIN = 0.5  # [L/min at 10 MPa] default: the smallest leak P-II names on its test bed is 0.17-0.4
MIN_TREND_POINTS = 3
MIN_TREND_SPAN_S = 86400.0  # [s] a trend needs its recordings' start times spread over a day at least: recordings 1 ms apart
# gave slopes of 2.5e8 L/min/day
GROWTH_MIN_L_MIN = 0.1  # [L/min at 10 MPa] growth over the recordings' span below this is not flagged: below the smallest leak
# P-II names (0.17), and within what a changing payload and temperature move an estimate (INFERRED)


@dataclass
class Unit:
    machine: str
    config: str
    bag: str
    content_hash: str


def content_hash(path: Path) -> str:
    """SHA-256 of a recording's data files (a bag folder's .mcap files in order, or the .mcap file itself)."""
    digest = hashlib.sha256()
    files = sorted(path.glob("*.mcap")) if path.is_dir() else [path]
    for file in files:
        with file.open("rb") as stream:
            for chunk in iter(lambda: stream.read(1 << 20), b""):
                digest.update(chunk)
    return digest.hexdigest()


def discover(root: Path) -> list[Unit]:
    """Every recording of every machine folder (one with a machine.yaml) under ``root``."""
    if not root.is_dir():
        raise InputError(f"fleet {root}: not a directory")
    units = []
    machines = sorted(p for p in root.iterdir() if p.is_dir() and (p / "machine.yaml").is_file())
    if not machines:
        raise InputError(f"fleet {root}: no machine folders (each <machine id>/machine.yaml with its recordings below it)")
    for folder in machines:
        bags = sorted({p.parent for p in folder.rglob("metadata.yaml")})
        loose = sorted(p for p in folder.rglob("*.mcap") if not any(bag in p.parents for bag in bags))
        for recording in [*bags, *loose]:
            units.append(Unit(folder.name, str(folder / "machine.yaml"), str(recording), content_hash(recording)))
    return units


def leak_estimate(model: SamModel, samples: Any, column: int) -> tuple[LeakFit, dict[str, float]]:
    """(the leaks and their standard errors [L/min at 10 MPa], seconds each notch was open) of one actuator of a recording."""
    regression = flow_regression(model, samples, column)
    return leak_fit(regression, nominal_coefficients(model)), dict(regression.open_s)


def analyse_recording(unit: Unit) -> dict[str, Any]:
    """One recording: per actuator the first alarm and the leak estimates; or the reason it could not be read."""
    try:
        machine = load_machine_config(unit.config)
        data = read_bag(unit.bag)
        layout = SampleLayout(machine.actuator_names, [a.joint for a in machine.actuators], mobile=machine.mobile)
        samples = data.samples(layout)
        if len(samples) == 0:
            raise InputError(f"{unit.bag}: no samples")
        recorded_on = (data.truth or {}).get("machine")
        if recorded_on not in (None, machine.name):  # a recording of another machine placed in this machine's folder
            return {"unit": unit.__dict__, "error": f"foreign: recorded on machine {recorded_on!r} (its metadata), this folder's "
                                                    f"config is {machine.name!r}: not analysed as this machine"}
        run = run_monitor(FdiMonitor(machine), samples)
    except (InputError, OSError, ValueError) as exc:
        return {"unit": unit.__dict__, "error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
    rows = []
    start = float(data.stamps_ns[0]) * 1e-9
    for column, actuator in enumerate(machine.actuator_names):
        first = next((a for a in run.alarms if a.actuator == actuator), None)
        named = next((a for a in run.alarms if a.actuator == actuator and a.fault.value != "unisolated"), first)
        fit, open_s = leak_estimate(SamModel(machine, actuator), samples, column)
        rows.append({"actuator": actuator, "start_unix_s": start, "duration_s": float(data.times[-1]) if len(data.times) else 0.0,
                     "alarm": None if first is None else {"fault": named.fault.value, "first_s": first.time_s},
                     "leak_l_min": {SHORT[k]: v for k, v in fit.leaks.items()}, "leak_sigma_l_min": {SHORT[k]: v for k, v in fit.errors.items()},
                     "coverage": {n: s >= MIN_OPEN_S for n, s in open_s.items()}, "errors": data.errors[:3]})
    return {"unit": unit.__dict__, "rows": rows}


class Store:
    """OUT/fleet.sqlite: one row per recording x actuator, keyed by the recording's content hash; failures apart."""

    def __init__(self, path: Path) -> None:
        self.db = sqlite3.connect(path)
        self.db.executescript("""
            CREATE TABLE IF NOT EXISTS results (hash TEXT, actuator TEXT, machine TEXT, bag TEXT, row TEXT, PRIMARY KEY (hash, actuator));
            CREATE TABLE IF NOT EXISTS failures (hash TEXT PRIMARY KEY, machine TEXT, bag TEXT, error TEXT);
        """)

    def done(self) -> set[str]:
        return {h for (h,) in self.db.execute("SELECT hash FROM results UNION SELECT hash FROM failures")}

    def put(self, result: dict[str, Any]) -> None:
        unit = result["unit"]
        with self.db:
            if "error" in result:
                self.db.execute("INSERT OR REPLACE INTO failures VALUES (?, ?, ?, ?)", (unit["content_hash"], unit["machine"], unit["bag"],
                                                                                       result["error"]))
            for row in result.get("rows", []):
                self.db.execute("INSERT OR REPLACE INTO results VALUES (?, ?, ?, ?, ?)",
                                (unit["content_hash"], row["actuator"], unit["machine"], unit["bag"], json.dumps(row)))

    def rows(self) -> list[dict[str, Any]]:
        return [{"machine": m, "bag": b, "hash": h, **json.loads(r)} for h, m, b, r in
                self.db.execute("SELECT hash, machine, bag, row FROM results ORDER BY machine, actuator")]

    def failures(self) -> list[dict[str, str]]:
        return [{"machine": m, "bag": b, "error": e} for m, b, e in self.db.execute("SELECT machine, bag, error FROM failures ORDER BY bag")]

    def close(self) -> None:
        self.db.close()


def trend(points: list[tuple[float, float]], limit: float) -> dict[str, Any]:
    """Theil-Sen slope of one leak over time (robust to an outlying recording) with its 95 % interval, whether it grows
    significantly or exceeds ``limit``, and when its line reaches ``limit``."""
    from scipy.stats import theilslopes

    points = sorted((t, v) for t, v in points if math.isfinite(v))
    latest = points[-1][1] if points else math.nan
    span = points[-1][0] - points[0][0] if points else 0.0
    out: dict[str, Any] = {"points": len(points), "latest_l_min": latest, "slope_l_min_per_day": None, "slope_95": None,
                           "growing": False, "above_limit": bool(latest > limit), "projected_unix_s": None, "too_short": ""}
    if len(points) < MIN_TREND_POINTS or span < MIN_TREND_SPAN_S:
        out["too_short"] = (f"too short to trend: {len(points)} recording(s) over {span / 3600.0:.3g} h (needs {MIN_TREND_POINTS} "
                            f"over {MIN_TREND_SPAN_S / 3600.0:g} h)")
    else:
        t = np.array([p[0] for p in points]) / 86400.0
        v = np.array([p[1] for p in points])
        slope, intercept, low, high = theilslopes(v, t)
        # significant (the slope's interval above zero) and worth a visit (it grew by more than GROWTH_MIN over the span)
        growing = low > 0.0 and slope * (t[-1] - t[0]) > GROWTH_MIN_L_MIN
        out.update(slope_l_min_per_day=float(slope), slope_95=[float(low), float(high)], growing=bool(growing))
        if slope > 0.0:
            reach = (limit - intercept) / slope
            out["projected_unix_s"] = float(max(reach, t[-1]) * 86400.0)
    return out


def summarise(rows: list[dict[str, Any]], failures: list[dict[str, str]], limit: float) -> dict[str, Any]:
    machines: dict[str, Any] = {}
    for row in rows:
        entry = machines.setdefault(row["machine"], {"actuators": {}})["actuators"].setdefault(row["actuator"], {"recordings": []})
        entry["recordings"].append({k: row[k] for k in ("bag", "start_unix_s", "duration_s", "alarm", "leak_l_min", "leak_sigma_l_min",
                                                        "coverage", "errors")})
    for machine in machines.values():
        for entry in machine["actuators"].values():
            entry["recordings"].sort(key=lambda r: r["start_unix_s"])
            # a recording read with errors is listed, and kept out of the trend: part of it is missing
            whole = [r for r in entry["recordings"] if not r["errors"]]
            entry["trend"] = {leak: trend([(r["start_unix_s"], r["leak_l_min"][leak]) for r in whole], limit)
                              for leak in SHORT.values()}
            entry["flagged"] = sorted(leak for leak, t in entry["trend"].items() if t["growing"] or t["above_limit"])
            dates = [t["projected_unix_s"] for leak, t in entry["trend"].items() if leak in entry["flagged"] and t["projected_unix_s"]]
            entry["service_by_unix_s"] = min(dates) if dates else None
        machine["flagged"] = sorted(a for a, e in machine["actuators"].items() if e["flagged"])
    return {"service_limit_l_min": limit, "machines": machines, "unreadable": [f for f in failures if not f["error"].startswith("foreign:")],
            "foreign": [f for f in failures if f["error"].startswith("foreign:")]}


def analyse(root: Path, out: Path, *, scheduler: str | None = None, workers: int | None = None, limit: float = SERVICE_LIMIT_L_MIN,
            progress: Callable[[str], None] | None = None) -> dict[str, Any]:
    """Analyse the recordings not yet in OUT's store, then write fleet.json, fleet.csv and fleet.html from all of it."""
    out.mkdir(parents=True, exist_ok=True)
    units = discover(root)
    store = Store(out / "fleet.sqlite")
    try:
        done = store.done()
        # one analysis per recording: a copy of a recording (the same content) is listed, not analysed twice
        unique = {u.content_hash: u for u in reversed(units)}
        duplicates = [u.bag for u in units if unique[u.content_hash] is not u]
        todo = [u for h, u in unique.items() if h not in done]
        with ExitStack() as stack:
            executor, where = work_executor(stack, scheduler, workers, len(todo))
            results = (analyse_recording(u) for u in todo) if executor is None else _as_completed(executor, todo)
            for result in results:
                store.put(result)
                if progress:
                    progress(result["unit"]["bag"])
        report = summarise(store.rows(), store.failures(), limit)
    finally:
        store.close()
    report.update(recordings=len(unique), analysed=len(todo), already_analysed=len(unique) - len(todo), duplicates=duplicates, ran_on=where)
    (out / "fleet.json").write_text(json.dumps(report, indent=2) + "\n")
    _write_csv(report, out / "fleet.csv")
    (out / "fleet.html").write_text(fleet_page(report))
    return report


def _as_completed(executor: Any, todo: list[Unit]):
    futures: list[Future] = [executor.submit(analyse_recording, unit) for unit in todo]
    for future in as_completed(futures):
        yield future.result()


def _write_csv(report: dict[str, Any], path: Path) -> None:
    import csv

    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["machine", "actuator", "bag", "start_unix_s", "alarm", *(f"leak_{k}_l_min" for k in SHORT.values()),
                         *(f"leak_{k}_sigma" for k in SHORT.values())])
        for name, machine in report["machines"].items():
            for actuator, entry in machine["actuators"].items():
                for r in entry["recordings"]:
                    writer.writerow([name, actuator, r["bag"], f"{r['start_unix_s']:.3f}", (r["alarm"] or {}).get("fault", ""),
                                     *(f"{r['leak_l_min'][k]:.4f}" for k in SHORT.values()),
                                     *(f"{r['leak_sigma_l_min'][k]:.4f}" for k in SHORT.values())])


def _date(unix_s: float | None) -> str:
    return "" if unix_s is None else datetime.datetime.fromtimestamp(unix_s, datetime.UTC).strftime("%Y-%m-%d")


def fleet_page(report: dict[str, Any]) -> str:
    """One page a fleet manager reads: machines ranked by urgency, each flagged cylinder's leaks over time with the
    projection to the service limit, plots inline."""
    import html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    limit = report["service_limit_l_min"]
    ranked = sorted(report["machines"].items(), key=lambda item: (
        min([e["service_by_unix_s"] or math.inf for e in item[1]["actuators"].values()] + [math.inf]), -len(item[1]["flagged"])))
    parts = [f"<!doctype html><meta charset='utf-8'><title>hydro_ros fleet</title><h1>Fleet: {len(ranked)} machines</h1>",
             f"<p>Leaks in L/min at 10 MPa; service limit {limit:g} L/min. Flagged: a leak that grows significantly (Theil-Sen "
             "slope, its 95 % interval above zero) or is above the limit.</p><table border=1 cellpadding=4>"
             "<tr><th>machine</th><th>flagged cylinders</th><th>service by</th></tr>"]
    for name, machine in ranked:
        dates = [e["service_by_unix_s"] for e in machine["actuators"].values() if e["service_by_unix_s"]]
        parts.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(', '.join(machine['flagged']) or 'none')}</td>"
                     f"<td>{_date(min(dates)) if dates else ''}</td></tr>")
    parts.append("</table>")
    for name, machine in ranked:
        for actuator in machine["flagged"]:
            entry = machine["actuators"][actuator]
            fig, ax = plt.subplots(figsize=(7, 3))
            for leak in entry["flagged"]:
                t = [datetime.datetime.fromtimestamp(r["start_unix_s"], datetime.UTC) for r in entry["recordings"]]
                v = [r["leak_l_min"][leak] for r in entry["recordings"]]
                e = [r["leak_sigma_l_min"][leak] for r in entry["recordings"]]
                ax.errorbar(t, v, yerr=e, marker="o", capsize=3, label=f"{leak} leak")
                projected = entry["trend"][leak]["projected_unix_s"]
                if projected:
                    ax.plot([t[-1], datetime.datetime.fromtimestamp(projected, datetime.UTC)], [v[-1], limit], "--", color="grey")
            ax.axhline(limit, color="red", lw=1, label="service limit")
            ax.set_ylabel("L/min at 10 MPa")
            ax.legend(fontsize=8)
            fig.autofmt_xdate()
            fig.tight_layout()
            png = io.BytesIO()
            fig.savefig(png, format="png", dpi=90)
            plt.close(fig)
            parts.append(f"<h2>{html.escape(name)}: {html.escape(actuator)} (service by {_date(entry['service_by_unix_s']) or 'not projected'})"
                         f"</h2><img src='data:image/png;base64,{base64.b64encode(png.getvalue()).decode()}'>")
    if report["unreadable"]:
        parts.append("<h2>Recordings that could not be read</h2><ul>" + "".join(
            f"<li>{html.escape(f['machine'])}: {html.escape(f['bag'])}: {html.escape(f['error'])}</li>" for f in report["unreadable"]) + "</ul>")
    return "\n".join(parts) + "\n"
