"""Offline FDI over a contract bag (``hydro-ros fdi``): the same monitor the node runs, fed from MCAP."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.reader import BagData, BagError, read_bag
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.samples import Samples
from hydro_ros.fdi.isolation import Alarm
from hydro_ros.fdi.monitor import BlockResult, FdiMonitor

BLOCK = 5000  # samples per call of the monitor: long enough to amortise, short enough for progress


@dataclass
class FdiRun:
    """Everything one analysis produced (arrays for plots, alarms for JSON)."""

    monitor: FdiMonitor
    times: np.ndarray
    residual_mean: np.ndarray  # (n, A, 2) MPa
    threshold: np.ndarray  # (n, A, 2) MPa
    code: np.ndarray  # (n, A)
    alarms: list[Alarm]
    operating_point: np.ndarray | None = None  # (n, A, 5) parity: 5 s means of the opening, |Q_A|, |Q_B| and the roots' noise bias in A, B [L/min]
    data: BagData | None = None

    def to_json(self) -> dict[str, Any]:
        """docs/interface.md section 5 layout, plus the bag's read errors and the latched patterns."""
        actuators = {}
        for i, name in enumerate(self.monitor.actuators):
            status = self.monitor.status(i)
            actuators[name] = {
                "fault": status.fault.value if status.fault is not None else "none",
                "first_detection_s": None if status.detected_at is None else round(status.detected_at, 4),
                "level": ["ok", "warn", "error"][status.level],
                "code": status.code,
                # detection held outside what commissioning saw (fdi.coverage), as a share of the evaluated samples
                "held_outside_commissioned_share": round(float(self.monitor.outside_held_samples[i]) / max(self.monitor.evaluated_samples, 1), 4),
            }
        out: dict[str, Any] = {"actuators": actuators, "alarms": [alarm.to_json() for alarm in self.alarms]}
        if self.data is not None:
            out["bag"] = str(self.data.path)
            out["errors"] = list(self.data.errors)
            out["partial"] = not self.data.complete  # computed on what could be read, not on the whole recording
        out["invalid_samples"] = self.monitor.invalid_samples
        return out


def blocks_from_bag(data: BagData, monitor: FdiMonitor) -> Samples:
    """The bag's samples for the monitor's actuators; a clear error names a missing topic."""
    return data.samples(SampleLayout(monitor.actuators, monitor.joints, mobile=monitor.generator.needs_mobile_pressures))


def monitor_blocks(monitor: FdiMonitor, samples: Samples, progress: Callable[[int], None] | None = None
                   ) -> Iterator[tuple[int, BlockResult]]:
    """The monitor over ``samples`` a block at a time, each with the index of its first sample (a long recording need not
    be held as results)."""
    for start in range(0, len(samples), BLOCK):
        block = samples.slice(slice(start, start + BLOCK))
        yield start, monitor.process(block)
        if progress is not None:
            progress(len(block))


def run_monitor(monitor: FdiMonitor, samples: Samples, progress: Callable[[int], None] | None = None) -> FdiRun:
    results = [result for _, result in monitor_blocks(monitor, samples, progress)]
    if not results:
        raise BagError("no samples to analyse")
    return FdiRun(
        monitor=monitor,
        times=np.concatenate([r.times for r in results]),
        residual_mean=np.concatenate([r.mean_residual for r in results]),
        threshold=np.concatenate([r.threshold for r in results]),
        code=np.concatenate([r.code for r in results]),
        alarms=[alarm for r in results for alarm in r.alarms],
        operating_point=None if results[0].operating_point is None else np.concatenate([r.operating_point for r in results]),
    )


def prepare(bag: str | Path, machine: Machine, method: str | None = None) -> tuple[BagData, FdiMonitor, Samples]:
    """Everything that can fail on bad input (bag, config, method, missing topics), before any work."""
    data = read_bag(bag)
    monitor = FdiMonitor(machine, method)
    return data, monitor, blocks_from_bag(data, monitor)


def analyse_bag(bag: str | Path, machine: Machine, method: str | None = None,
                progress: Callable[[int], None] | None = None) -> FdiRun:
    data, monitor, samples = prepare(bag, machine, method)
    run = run_monitor(monitor, samples, progress)
    run.data = data
    return run
