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
from collections.abc import Callable, Iterator
from concurrent.futures import Future, as_completed
from contextlib import ExitStack
from dataclasses import asdict, dataclass, field
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


@dataclass(frozen=True)
class Unit:
    machine: str
    config: str
    bag: str
    content_hash: str


@dataclass(frozen=True)
class FirstAlarm:
    fault: str  # the first isolated fault, else the first alarm's (unisolated)
    first_s: float  # [s from the recording's start] the first alarm


@dataclass(frozen=True)
class Verdict:
    """One recording of one actuator: the monitor's first alarm and the leaks [L/min at 10 MPa] the recording holds."""

    bag: str
    actuator: str
    start_unix_s: float
    duration_s: float
    alarm: FirstAlarm | None
    leak_l_min: dict[str, float]  # by SHORT name
    leak_sigma_l_min: dict[str, float]
    coverage: dict[str, bool]  # per notch: open long enough to tell the leaks from the valve
    errors: list[str]  # what the reader reported (a recording with errors is kept out of the trend)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> Verdict:
        alarm = data["alarm"]
        return cls(**{**data, "alarm": None if alarm is None else FirstAlarm(**alarm)})


@dataclass(frozen=True)
class Analysis:
    """What one unit of work returns: its verdicts, or why the recording was not analysed."""

    unit: Unit
    verdicts: list[Verdict] = field(default_factory=list)
    error: str | None = None


@dataclass(frozen=True)
class Failure:
    machine: str
    bag: str
    error: str


@dataclass(frozen=True)
class Trend:
    """One leak of one cylinder over the recordings (:func:`trend`)."""

    points: int
    latest_l_min: float
    slope_l_min_per_day: float | None = None
    slope_95: list[float] | None = None
    growing: bool = False
    above_limit: bool = False
    projected_unix_s: float | None = None  # where the line reaches the service limit (not before the latest recording)
    too_short: str = ""  # why there is no slope


@dataclass
class CylinderHistory:
    recordings: list[Verdict]  # by start time
    trend: dict[str, Trend]  # by SHORT leak name
    flagged: list[str]  # leaks growing or above the limit
    service_by_unix_s: float | None


@dataclass
class MachineHistory:
    actuators: dict[str, CylinderHistory]
    flagged: list[str]  # its cylinders with a flagged leak


@dataclass
class FleetReport:
    """What ``fleet analyse`` found (written as OUT/fleet.json, docs/fleet.md)."""

    service_limit_l_min: float
    machines: dict[str, MachineHistory]
    unreadable: list[Failure]
    foreign: list[Failure]  # recordings of another machine in a machine's folder
    recordings: int = 0  # unique ones
    analysed: int = 0  # this run
    already_analysed: int = 0
    duplicates: list[str] = field(default_factory=list)  # copies of a recording, listed not analysed
    ran_on: str = ""

    def to_json(self) -> dict[str, Any]:
        return asdict(self)


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


def analyse_recording(unit: Unit) -> Analysis:
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
            return Analysis(unit, error=f"foreign: recorded on machine {recorded_on!r} (its metadata), this folder's config is "
                                        f"{machine.name!r}: not analysed as this machine")
        run = run_monitor(FdiMonitor(machine), samples)
    except (InputError, OSError, ValueError) as exc:
        return Analysis(unit, error=f"{type(exc).__name__}: {exc}".splitlines()[0])
    verdicts = []
    start = float(data.stamps_ns[0]) * 1e-9
    for column, actuator in enumerate(machine.actuator_names):
        first = next((a for a in run.alarms if a.actuator == actuator), None)
        named = next((a for a in run.alarms if a.actuator == actuator and a.fault.value != "unisolated"), first)
        fit, open_s = leak_estimate(SamModel(machine, actuator), samples, column)
        verdicts.append(Verdict(
            unit.bag, actuator, start, float(data.times[-1]) if len(data.times) else 0.0,
            None if first is None else FirstAlarm(named.fault.value, first.time_s),
            {SHORT[k]: v for k, v in fit.leaks.items()}, {SHORT[k]: v for k, v in fit.errors.items()},
            {n: s >= MIN_OPEN_S for n, s in open_s.items()}, data.errors[:3]))
    return Analysis(unit, verdicts)


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

    def put(self, result: Analysis) -> None:
        unit = result.unit
        with self.db:
            if result.error is not None:
                self.db.execute("INSERT OR REPLACE INTO failures VALUES (?, ?, ?, ?)", (unit.content_hash, unit.machine, unit.bag, result.error))
            for verdict in result.verdicts:
                self.db.execute("INSERT OR REPLACE INTO results VALUES (?, ?, ?, ?, ?)",
                                (unit.content_hash, verdict.actuator, unit.machine, unit.bag, json.dumps(asdict(verdict))))

    def verdicts(self) -> list[tuple[str, Verdict]]:
        """(machine, verdict) of every recording and actuator, by machine and actuator."""
        return [(m, Verdict.from_json({"bag": b, **json.loads(r)})) for m, b, r in  # a store's older rows kept the bag apart
                self.db.execute("SELECT machine, bag, row FROM results ORDER BY machine, actuator")]

    def failures(self) -> list[Failure]:
        return [Failure(m, b, e) for m, b, e in self.db.execute("SELECT machine, bag, error FROM failures ORDER BY bag")]

    def close(self) -> None:
        self.db.close()


def trend(points: list[tuple[float, float]], limit: float) -> Trend:
    """Theil-Sen slope of one leak over time (robust to an outlying recording) with its 95 % interval, whether it grows
    significantly or exceeds ``limit``, and when its line reaches ``limit``."""
    from scipy.stats import theilslopes

    points = sorted((t, v) for t, v in points if math.isfinite(v))
    latest = points[-1][1] if points else math.nan
    span = points[-1][0] - points[0][0] if points else 0.0
    above = bool(latest > limit)
    if len(points) < MIN_TREND_POINTS or span < MIN_TREND_SPAN_S:
        return Trend(len(points), latest, above_limit=above, too_short=f"too short to trend: {len(points)} recording(s) over "
                     f"{span / 3600.0:.3g} h (needs {MIN_TREND_POINTS} over {MIN_TREND_SPAN_S / 3600.0:g} h)")
    t = np.array([p[0] for p in points]) / 86400.0
    v = np.array([p[1] for p in points])
    slope, intercept, low, high = theilslopes(v, t)
    # significant (the slope's interval above zero) and worth a visit (it grew by more than GROWTH_MIN over the span)
    growing = low > 0.0 and slope * (t[-1] - t[0]) > GROWTH_MIN_L_MIN
    projected = float(max((limit - intercept) / slope, t[-1]) * 86400.0) if slope > 0.0 else None
    return Trend(len(points), latest, float(slope), [float(low), float(high)], bool(growing), above, projected)


def cylinder_history(verdicts: list[Verdict], limit: float) -> CylinderHistory:
    """One cylinder's recordings by start time, each leak's trend, what is flagged and the service date."""
    recordings = sorted(verdicts, key=lambda v: v.start_unix_s)
    # a recording read with errors is listed, and kept out of the trend: part of it is missing
    whole = [r for r in recordings if not r.errors]
    trends = {leak: trend([(r.start_unix_s, r.leak_l_min[leak]) for r in whole], limit) for leak in SHORT.values()}
    flagged = sorted(leak for leak, t in trends.items() if t.growing or t.above_limit)
    dates = [date for leak in flagged if (date := trends[leak].projected_unix_s)]
    return CylinderHistory(recordings, trends, flagged, min(dates) if dates else None)


def summarise(verdicts: list[tuple[str, Verdict]], failures: list[Failure], limit: float) -> FleetReport:
    grouped: dict[str, dict[str, list[Verdict]]] = {}
    for machine, verdict in verdicts:
        grouped.setdefault(machine, {}).setdefault(verdict.actuator, []).append(verdict)
    machines = {}
    for name, actuators in grouped.items():
        histories = {actuator: cylinder_history(rows, limit) for actuator, rows in actuators.items()}
        machines[name] = MachineHistory(histories, sorted(a for a, h in histories.items() if h.flagged))
    foreign = [f for f in failures if f.error.startswith("foreign:")]
    return FleetReport(limit, machines, [f for f in failures if f not in foreign], foreign)


def analyse(root: Path, out: Path, *, scheduler: str | None = None, workers: int | None = None, limit: float = SERVICE_LIMIT_L_MIN,
            progress: Callable[[str], None] | None = None) -> FleetReport:
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
                    progress(result.unit.bag)
        report = summarise(store.verdicts(), store.failures(), limit)
    finally:
        store.close()
    report.recordings, report.analysed, report.already_analysed = len(unique), len(todo), len(unique) - len(todo)
    report.duplicates, report.ran_on = duplicates, where
    (out / "fleet.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
    _write_csv(report, out / "fleet.csv")
    (out / "fleet.html").write_text(fleet_page(report))
    return report


def _as_completed(executor: Any, todo: list[Unit]) -> Iterator[Analysis]:
    futures: list[Future[Analysis]] = [executor.submit(analyse_recording, unit) for unit in todo]
    for future in as_completed(futures):
        yield future.result()


def _write_csv(report: FleetReport, path: Path) -> None:
    import csv

    with path.open("w", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(["machine", "actuator", "bag", "start_unix_s", "alarm", *(f"leak_{k}_l_min" for k in SHORT.values()),
                         *(f"leak_{k}_sigma" for k in SHORT.values())])
        for name, machine in report.machines.items():
            for actuator, history in machine.actuators.items():
                for r in history.recordings:
                    writer.writerow([name, actuator, r.bag, f"{r.start_unix_s:.3f}", r.alarm.fault if r.alarm else "",
                                     *(f"{r.leak_l_min[k]:.4f}" for k in SHORT.values()),
                                     *(f"{r.leak_sigma_l_min[k]:.4f}" for k in SHORT.values())])


def _date(unix_s: float | None) -> str:
    return "" if unix_s is None else datetime.datetime.fromtimestamp(unix_s, datetime.UTC).strftime("%Y-%m-%d")


def fleet_page(report: FleetReport) -> str:
    """One page a fleet manager reads: machines ranked by urgency, each flagged cylinder's leaks over time with the
    projection to the service limit, plots inline."""
    import html

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    limit = report.service_limit_l_min
    ranked = sorted(report.machines.items(), key=lambda item: (
        min([h.service_by_unix_s or math.inf for h in item[1].actuators.values()] + [math.inf]), -len(item[1].flagged)))
    parts = [f"<!doctype html><meta charset='utf-8'><title>hydro_ros fleet</title><h1>Fleet: {len(ranked)} machines</h1>",
             f"<p>Leaks in L/min at 10 MPa; service limit {limit:g} L/min. Flagged: a leak that grows significantly (Theil-Sen "
             "slope, its 95 % interval above zero) or is above the limit.</p><table border=1 cellpadding=4>"
             "<tr><th>machine</th><th>flagged cylinders</th><th>service by</th></tr>"]
    for name, machine in ranked:
        dates = [h.service_by_unix_s for h in machine.actuators.values() if h.service_by_unix_s]
        parts.append(f"<tr><td>{html.escape(name)}</td><td>{html.escape(', '.join(machine.flagged) or 'none')}</td>"
                     f"<td>{_date(min(dates)) if dates else ''}</td></tr>")
    parts.append("</table>")
    for name, machine in ranked:
        for actuator in machine.flagged:
            history = machine.actuators[actuator]
            fig, ax = plt.subplots(figsize=(7, 3))
            for leak in history.flagged:
                t = [datetime.datetime.fromtimestamp(r.start_unix_s, datetime.UTC) for r in history.recordings]
                v = [r.leak_l_min[leak] for r in history.recordings]
                e = [r.leak_sigma_l_min[leak] for r in history.recordings]
                ax.errorbar(t, v, yerr=e, marker="o", capsize=3, label=f"{leak} leak")
                projected = history.trend[leak].projected_unix_s
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
            parts.append(f"<h2>{html.escape(name)}: {html.escape(actuator)} (service by {_date(history.service_by_unix_s) or 'not projected'})"
                         f"</h2><img src='data:image/png;base64,{base64.b64encode(png.getvalue()).decode()}'>")
    if report.unreadable:
        parts.append("<h2>Recordings that could not be read</h2><ul>" + "".join(
            f"<li>{html.escape(f.machine)}: {html.escape(f.bag)}: {html.escape(f.error)}</li>" for f in report.unreadable) + "</ul>")
    return "\n".join(parts) + "\n"
