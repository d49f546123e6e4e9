"""Condition monitoring of a crane's cylinders: its parity thresholds, fitted on the crane at work, and their evaluation.

The monitor (:class:`hydro_ros.fdi.monitor.FdiMonitor`) runs the parity method on every cylinder at
once, load independent: the crane's dynamics are not in its model, the motion of the other joints
reaches a cylinder only through its own measured motion and pressures. What differs from the SAM is
the work: every joint moves, the loads change with the pose and the payload, and 5 s windows in
which a joint moved for a second and held for four are the rule. So the thresholds are binned on each
chamber's 5 s mean modelled valve flow (``bins: flow``) and carry a flow-proportional allowance for
the notch coefficients (``flow_fraction``, :class:`hydro_ros.fdi.parity.ParityThresholds`):

- mu and sigma per flow bin from the nominal crane (the config's own model as the plant) at work;
- c per bin = ``MARGIN`` x the largest factor reached in that bin on held-out plants that differ from
  the model (every notch, the bulk moduli, friction and sensor noise drawn per plant,
  ``fdi_evaluation.MISMATCH``), carrying payload steps, working the config's paths and the random
  operator; at least ``MARGIN`` x ``FACTOR_FLOOR``. One c for all bins would be set by the moving
  bins, where the mismatched notches reach 4-7 sigma, and blunt the bins at rest (1-3 sigma), where
  a leak shows best: a held cylinder's chamber has only its leak to explain.

The evaluation (``make bench``, ``bench/results/crane_monitoring.json``) uses further plants drawn the same
way and the crane working the three P-VI paths (their DP-CP trajectories) with a leak in one named
cylinder: detection, isolation to the cylinder and the fault, delay, and false alarms per hour.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.fdi.monitor import FdiMonitor, crossing_episodes
from hydro_ros.fdi.parity import FLOW_EDGES, POINT_CHANNELS, ParityThresholds
from hydro_ros.models.serial_arm import SerialArm
from hydro_ros.sim.arm_cylinders import ArmCylinders, ArmRun, simulate_arm
from hydro_ros.studies.fdi_evaluation import mismatched_config, parallel_map
from hydro_ros.studies.independent_arm import ArmWork
from hydro_ros.workflows.commissioning import FaultFreeRecording

FLOW_FRACTION = 0.1  # k: the notch coefficients' tolerance the allowance covers: twice MISMATCH's +-5 % (INFERRED; see docs/crane_monitoring.md)
MARGIN = 1.5  # c = margin x the largest held-out factor of the bin (the evaluation's plants are others again)
FACTOR_FLOOR = 3.0  # [sigma] no bin's c below margin x this, however quiet its held-out data
PAYLOAD_KG = 300.0  # a log in the grapple (INFERRED, as the SAM's payload steps)
CRANE_LEAKS = ("external_leakage_a", "external_leakage_b", "internal_leakage")


@dataclass(frozen=True)
class CraneCase:
    """One run of the crane: which plant, what work, which fault where."""

    seed: int
    duration_s: float
    path: str | None = None  # a path id worked as a cycle, or None: the random operator
    mismatch: float = 1.0  # 0: the config's own model is the plant
    payload: bool = True  # a payload gripped at 1/3 and released at 2/3 of the run
    actuator: str | None = None
    fault: str | None = None
    value: float = 0.0
    onset_s: float = 20.0


@dataclass
class CraneOutcome:
    case: CraneCase
    alarms: list[dict[str, Any]] = field(default_factory=list)  # every alarm: actuator, fault, time_s
    crossing_episodes: dict[str, int] = field(default_factory=dict)
    monitored_s: float = 0.0
    residual: np.ndarray | None = None  # armed (n, A, 2) 5 s mean residuals, kept when asked
    operating_point: np.ndarray | None = None  # armed (n, A, 5)

    @property
    def false_alarms(self) -> list[dict[str, Any]]:
        c = self.case
        return [a for a in self.alarms if c.fault is None or a["actuator"] != c.actuator or a["time_s"] < c.onset_s]

    @property
    def named(self) -> str | None:
        """The faulty cylinder's name for its fault at the end of the run (its last alarm)."""
        own = [a["fault"] for a in self.alarms if a["actuator"] == self.case.actuator]
        return own[-1] if own else None

    @property
    def detection(self) -> dict[str, Any] | None:
        """The first alarm on the faulty cylinder after onset."""
        c = self.case
        hits = [a for a in self.alarms if c.fault is not None and a["actuator"] == c.actuator and a["time_s"] >= c.onset_s]
        return hits[0] if hits else None


def crane_run(case: CraneCase, trajectories: dict[str, Any]) -> ArmRun:
    payload = [Injection("payload_mass", PAYLOAD_KG, case.duration_s / 3.0),
               Injection("payload_mass", -PAYLOAD_KG, 2.0 * case.duration_s / 3.0)] if case.payload else []
    faults = {case.actuator: [Injection(case.fault, case.value, case.onset_s)]} if case.fault else {}
    return ArmRun(case.duration_s, case.seed, faults, payload, trajectories.get(case.path) if case.path else None)


def run_crane_case(machine: Machine, trajectories: dict[str, Any], case: CraneCase, *,
                   keep_residuals: bool = False, plant: Machine | None = None) -> CraneOutcome:
    """The monitor of ``machine`` on ``plant``, else on the crane plant of the case (``machine`` mismatched per its seed)."""
    if plant is None:
        plant = mismatched_config(machine, case.seed, case.mismatch) if case.mismatch else machine
    monitor = FdiMonitor(machine)
    outcome = CraneOutcome(case)
    crossing = dict.fromkeys(monitor.actuators, False)
    outcome.crossing_episodes = dict.fromkeys(monitor.actuators, 0)
    kept: list[tuple[np.ndarray, np.ndarray]] = []
    armed_from = monitor.startup + monitor.window
    seen = 0
    for _, block in ArmCylinders(plant, SerialArm.of(plant), crane_run(case, trajectories)).blocks():
        result = monitor.process(block)
        for i, name in enumerate(monitor.actuators):
            new, crossing[name] = crossing_episodes(result.code[:, i], previous=crossing[name])
            outcome.crossing_episodes[name] += new
        outcome.alarms += [{"actuator": a.actuator, "fault": a.fault.value if a.fault else None, "time_s": a.time_s}
                           for a in result.alarms]
        if keep_residuals:
            armed = seen + np.arange(len(block)) >= armed_from
            kept.append((result.mean_residual[armed], result.operating_point[armed]))
        seen += len(block)
    outcome.monitored_s = max(case.duration_s - armed_from / monitor.sample_rate, 0.0)
    if keep_residuals:
        outcome.residual = np.concatenate([r for r, _ in kept])
        outcome.operating_point = np.concatenate([p for _, p in kept])
    return outcome


def _run(arguments: tuple) -> CraneOutcome:
    machine, trajectories, case, keep, plant = arguments
    return run_crane_case(machine, trajectories, case, keep_residuals=keep, plant=plant)


def run_crane_cases(machine: Machine, trajectories: dict[str, Any], cases: Sequence[CraneCase], *,
                    keep_residuals: bool = False, workers: int = 2, progress: Callable[[int], None] | None = None,
                    plant: Machine | None = None) -> list[CraneOutcome]:
    return parallel_map(_run, [(machine, trajectories, case, keep_residuals, plant) for case in cases], workers=workers,
                        progress=progress)


def path_trajectories(crane_config: CraneConfig, method: str = "dp_cp", database: str | None = None) -> dict[str, Any]:
    """Every path of the crane config as its ``method`` joint trajectory (served from ``database`` or planned now)."""
    from hydro_ros.planning.serving import executable_trajectory

    return {path: executable_trajectory(crane_config, path, method, database=database)[0] for path in crane_config.paths}


def commissioning_recordings(plant: Machine, trajectories: dict[str, Any], seed: int, *,
                             operator_s: float = 120.0, path_s: float = 60.0) -> list[FaultFreeRecording]:
    """A crane's fault-free work to commission it on: the operator twice, each path's cycle once, a payload gripped and
    released in each (a forestry crane's day; recorded into the bags ``hydro-ros commission`` reads)."""
    runs = [(f"operator{seed + k}", CraneCase(seed + k, operator_s)) for k in range(2)]
    runs += [(path, CraneCase(seed, path_s, path)) for path in trajectories]
    return [FaultFreeRecording(f"{name} (seed {case.seed})", simulate_arm(plant, crane_run(case, trajectories)))
            for name, case in runs]


def apart_commissioning_work(trajectories: dict[str, Any], payload_kg: float = 300.0) -> list[tuple[str, ArmWork]]:
    """The fault-free day the crane built apart (``independent_arm``) is commissioned on: the operator twice for 2 min at
    half lever, each path's cycle for 1 min, ``payload_kg`` gripped and released in each."""
    day = [(f"operator{k}", ArmWork(120.0, 10 + k, payload_steps=((30.0, payload_kg), (80.0, 0.0)), lever_limit=0.5)) for k in range(2)]
    day += [(path, ArmWork(60.0, 20, payload_steps=((20.0, payload_kg), (45.0, 0.0)), path=trajectory))
            for path, trajectory in trajectories.items()]
    return day


def work_cases(seeds: Iterable[int], paths: Iterable[str], duration_s: float, mismatch: float) -> list[CraneCase]:
    """Fault-free work: per seed, the random operator and each path's work cycle, a payload gripped and released."""
    return [CraneCase(seed, duration_s, path, mismatch) for seed in seeds for path in (None, *paths)]


def _flatten(outcomes: Sequence[CraneOutcome]) -> tuple[np.ndarray, np.ndarray]:
    residual = np.concatenate([o.residual.reshape(-1, 2) for o in outcomes])
    point = np.concatenate([o.operating_point.reshape(-1, POINT_CHANNELS) for o in outcomes])
    keep = np.all(np.isfinite(residual), axis=1) & np.all(np.isfinite(point), axis=1)
    return residual[keep], point[keep]


def fit_crane_thresholds(machine: Machine, trajectories: dict[str, Any], *, train: Iterable[int],
                         held_out: Iterable[int], duration_s: float = 90.0, workers: int = 2,
                         progress: Callable[[int], None] | None = None) -> tuple[ParityThresholds, dict[str, Any]]:
    """Statistics on the nominal crane at work, the factor on held-out mismatched cranes (module docstring)."""
    probe = machine.with_overrides({"fdi": {"parity_thresholds": ParityThresholds.probe()}})
    paths = list(trajectories)
    fitted = run_crane_cases(probe, trajectories, work_cases(train, paths, duration_s, 0.0), keep_residuals=True,
                             workers=workers, progress=progress)
    statistics = ParityThresholds.from_statistics(*_flatten(fitted), FLOW_EDGES, 1.0, FLOW_FRACTION, "flow")
    checked = run_crane_cases(probe, trajectories, work_cases(held_out, paths, duration_s, 1.0), keep_residuals=True,
                              workers=workers, progress=progress)
    reached = {f"{o.case.seed}/{o.case.path or 'operator'}": statistics.factors_reached(*_flatten([o])) for o in checked}
    per_bin = np.max(list(reached.values()), axis=0)
    thresholds = replace(statistics, factor=tuple(float(v) for v in MARGIN * np.maximum(per_bin, FACTOR_FLOOR)))
    hours = sum(o.monitored_s for o in checked) / 3600.0
    return thresholds, {"form": "|mu| + c sigma per bin of the chamber's 5 s mean valve flow + k x that flow, c per bin",
                        "flow_edges_l_min": list(FLOW_EDGES), "flow_fraction": FLOW_FRACTION, "margin": MARGIN, "floor": FACTOR_FLOOR,
                        "reached": float(per_bin.max()), "reached_per_bin": per_bin.tolist(),
                        "reached_per_run": {k: float(v.max()) for k, v in reached.items()}, "factor": list(thresholds.factor),
                        "held_out_hours": hours,
                        "train_seeds": sorted({o.case.seed for o in fitted}), "held_out_seeds": sorted({o.case.seed for o in checked})}


def fault_cases(seeds: Iterable[int], actuators: Iterable[str], paths: Iterable[str], sizes: Iterable[float], duration_s: float,
                onset_s: float) -> list[CraneCase]:
    return [CraneCase(seed, duration_s, path, 1.0, True, actuator, fault, size, onset_s)
            for actuator in actuators for fault in CRANE_LEAKS for size in sizes for path in paths for seed in seeds]


def summarise_crane(outcomes: Sequence[CraneOutcome], fault_free: Sequence[CraneOutcome]) -> dict[str, Any]:
    """Per cylinder, fault and size: detected / isolated (right cylinder and fault) / median delay; false alarms per hour."""
    rows: dict[tuple[str, str, float], list[CraneOutcome]] = {}
    for outcome in outcomes:
        c = outcome.case
        rows.setdefault((c.actuator, c.fault, c.value), []).append(outcome)
    table = []
    for (actuator, fault, value), group in sorted(rows.items()):
        detections = [o.detection for o in group]
        delays = [d["time_s"] - o.case.onset_s for d, o in zip(detections, group) if d is not None]
        table.append({
            "actuator": actuator, "fault": fault, "value_l_min": value, "runs": len(group),
            "detected": sum(d is not None for d in detections),
            "isolated": sum(any(a["actuator"] == actuator and a["fault"] == fault and a["time_s"] >= o.case.onset_s for a in o.alarms)
                            for o in group),
            "other_cylinder_alarms": sum(any(a["actuator"] != actuator for a in o.alarms) for o in group),
            "named": dict(Counter(o.named for o in group if o.named)),
            "early_alarms": sum(any(a["time_s"] < o.case.onset_s for a in o.alarms) for o in group),
            "median_delay_s": float(np.median(delays)) if delays else None,
        })
    return {"faults": table, "fault_free": summarise_fault_free(fault_free)}


def summarise_fault_free(outcomes: Sequence[CraneOutcome]) -> dict[str, Any]:
    """Hours monitored, alarms (all false) and threshold-crossing episodes per hour and cylinder."""
    hours = sum(o.monitored_s for o in outcomes) / 3600.0
    alarms = sum(len(o.alarms) for o in outcomes)
    episodes = {name: sum(o.crossing_episodes.get(name, 0) for o in outcomes) for name in (outcomes[0].crossing_episodes if outcomes else {})}
    return {"hours": hours, "alarms": alarms, "false_alarms_per_hour": alarms / hours if hours else None,
            "crossing_episodes_per_hour": {k: v / hours for k, v in episodes.items()} if hours else {}, "runs": len(outcomes)}
