"""P-III's comparison of the MEMS motion sensor with the encoder (its Tables I and II and its detection delays), on the
simulated SAM with the MEMS angle estimate (complementary filter) in the loop.

The plants differ from the monitor's model a little (every MISMATCH parameter drawn at MODEL_QUALITY of its spread: a
model identified on its own rig, as P-III's was), and the monitor runs at P-III's thresholds: c0 = 0.015 MPa with
the encoder, 0.023 MPa with the MEMS sensor. Residuals are the 5 s mean residuals the thresholds judge, armed part
only. Table I: their RMS over fault-free runs of 20 to 70 s weighted by duration, as P-III's six experiments. Table
II and the delays: an external leak in chamber B from 26 s (P-III: 0.38 L/min on average) and an internal leak from
30 s (P-III: 0.91 L/min on average); P-III's leaks varied in time, these are constant.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import Machine, load_machine_config
from hydro_ros.contract.names import Injection
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.sim.scenario import Scenario, simulate
from hydro_ros.studies.fdi_evaluation import mismatched_config

MODEL_QUALITY = 0.2  # of MISMATCH's spread: P-III's model was identified on the rig it monitored (INFERRED)
THRESHOLDS = {"encoder": 0.015, "mems": 0.023}  # [MPa] P-III's c0
PAPER = {
    "table_1": {"encoder": {"pA": 0.0141, "pB": 0.0051}, "mems": {"pA": 0.0150, "pB": 0.0081}},
    "table_2": {"external_leakage_b": {"encoder": {"pA": 0.0119, "pB": 0.0388}, "mems": {"pA": 0.0223, "pB": 0.0365}},
                "internal_leakage": {"encoder": {"pA": 0.1392, "pB": 0.0817}, "mems": {"pA": 0.1534, "pB": 0.0868}}},
    "delay_mems_minus_encoder_s": {"external_leakage_b": 6.0, "internal_leakage": 0.3},
}
FAULTS = {"external_leakage_b": (0.38, 26.0), "internal_leakage": (0.91, 30.0)}  # P-III's mean flows [L/min], onsets [s]
FAULT_RUN_S = 70.0


@dataclass
class Sensor:
    name: str
    machine: Machine


def sensors() -> list[Sensor]:
    return [Sensor(name, load_machine_config(default_config_path(config)).with_overrides({"fdi": {"threshold_constant": THRESHOLDS[name]}}))
            for name, config in (("encoder", "sam"), ("mems", "sam_mems"))]


def _run(sensor: Sensor, seed: int, duration_s: float, injections: tuple = ()) -> tuple[np.ndarray, float | None]:
    """(armed 5 s mean residuals (n, 2) [MPa], first alarm time or None) of one run on one mismatched plant."""
    plant = mismatched_config(sensor.machine, seed, MODEL_QUALITY)
    monitor = FdiMonitor(sensor.machine)
    run = run_monitor(monitor, simulate(plant, Scenario(duration_s, injections, seed=seed)))
    armed = np.arange(len(run.times)) >= monitor.startup + monitor.window
    first = min((a.time_s for a in run.alarms), default=None)
    return run.residual_mean[armed, 0, :], first


def _rms(parts: list[np.ndarray]) -> dict[str, float]:
    joined = np.concatenate(parts)
    return {"pA": float(np.sqrt(np.mean(joined[:, 0] ** 2))), "pB": float(np.sqrt(np.mean(joined[:, 1] ** 2)))}


def tables(seeds: int = 6, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """Tables I and II and the detection delays, ours beside P-III's."""
    durations = np.linspace(20.0, 70.0, seeds) + 6.0  # P-III's 20-70 s of armed data: plus the start-up and the first window
    out: dict[str, Any] = {"paper": PAPER, "seeds": seeds, "model_quality": MODEL_QUALITY, "thresholds_mpa": THRESHOLDS,
                           "table_1": {}, "table_2": {}, "delays_s": {}}
    for sensor in sensors():
        # the armed samples of each run: an RMS over all of them is P-III's mean of RMSs weighted by duration
        out["table_1"][sensor.name] = _rms([_run(sensor, 300 + k, float(d))[0] for k, d in enumerate(durations)])
        if progress:
            progress(seeds)
        for fault, (flow, onset) in FAULTS.items():
            runs = [_run(sensor, 400 + k, FAULT_RUN_S, (Injection(fault, flow, onset),)) for k in range(seeds)]
            out["table_2"].setdefault(fault, {})[sensor.name] = _rms([r for r, _ in runs])
            delays = [first - onset for _, first in runs if first is not None and first >= onset]
            out["delays_s"].setdefault(fault, {})[sensor.name] = {"median": float(np.median(delays)) if delays else None,
                                                                   "detected": len(delays), "runs": seeds,
                                                                   "early": sum(first is not None and first < onset for _, first in runs)}
            if progress:
                progress(seeds)
    for fault in FAULTS:
        delay = out["delays_s"][fault]
        out["delays_s"][fault]["mems_minus_encoder"] = (None if delay["mems"]["median"] is None or delay["encoder"]["median"] is None
                                                        else delay["mems"]["median"] - delay["encoder"]["median"])
    return out


def markdown(result: dict[str, Any]) -> str:
    paper = result["paper"]
    lines = ["| table | case | sensor | residual | P-III [MPa] | ours [MPa] |", "|---|---|---|---|---|---|"]
    for sensor, row in result["table_1"].items():
        for residual, value in row.items():
            lines.append(f"| I | fault-free | {sensor} | {residual} | {paper['table_1'][sensor][residual]:.4f} | {value:.4f} |")
    for fault, rows in result["table_2"].items():
        for sensor, row in rows.items():
            for residual, value in row.items():
                lines.append(f"| II | {fault} | {sensor} | {residual} | {paper['table_2'][fault][sensor][residual]:.4f} | {value:.4f} |")
    lines += ["", "| fault | P-III: MEMS later by [s] | ours: encoder median delay [s] | ours: MEMS median delay [s] | ours: MEMS later by [s] |",
              "|---|---|---|---|---|"]
    for fault, delay in result["delays_s"].items():
        def fmt(value: float | None) -> str:
            return "not detected" if value is None else f"{value:.1f}"
        lines.append(f"| {fault} | {paper['delay_mems_minus_encoder_s'][fault]:.1f} | {fmt(delay['encoder']['median'])} "
                     f"({delay['encoder']['detected']}/{delay['encoder']['runs']}) | {fmt(delay['mems']['median'])} "
                     f"({delay['mems']['detected']}/{delay['mems']['runs']}) | {fmt(delay['mems_minus_encoder'])} |")
    return "\n".join(lines) + "\n"
