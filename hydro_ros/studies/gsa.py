"""Global sensitivity analysis of P-I (digest section 3): Sobol' indices of the SAM model.

Set-up as P-I: a 25 % valve step that extends the cylinder from retracted, outputs p_A, p_B and
the piston velocity at transient instants and at 4 s (steady state), parameters uniform over
P-I Table 1 (k = 7) or the leak coefficients of Table 5 (k = 3). The model is the package's SAM
plant with the GSA's simplifications: constant flow coefficients K_v = Q_N / sqrt(dp_N) per notch
(eq. 12, in place of P-II's polynomials) and a single effective bulk modulus (no hose term).
Sampling and indices are SALib's (Saltelli/Sobol' sequence, Jansen/Saltelli estimators, bootstrap
confidence intervals); the runs are spread over processes.
"""

from __future__ import annotations

import math
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable

import numpy as np

from hydro_ros.contract.extras import optional_module
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.models.chamber import leak_coefficient
from hydro_ros.models.sam import SamModel, SamPlant

# P-I Table 1 (L3749-L3830); SI units
PARAMETERS = {
    "offset": (-0.05, 0.05),
    "q_n_pa": (15.0 / 60000.0, 35.0 / 60000.0),
    "dp_n_pa": (0.5e6, 4.0e6),
    "q_n_bt": (15.0 / 60000.0, 35.0 / 60000.0),
    "dp_n_bt": (0.5e6, 4.0e6),
    "bulk_modulus": (300e6, 1200e6),
    "viscous": (2000.0, 5000.0),
}
# P-I Table 5: each leak coefficient in [0, 5.27e-9] m^3/(s Pa^0.5) (1 L/min at 10 MPa)
LEAKS = {"k_int": (0.0, 5.27e-9), "k_ext_a": (0.0, 5.27e-9), "k_ext_b": (0.0, 5.27e-9)}
TIMES = (0.05, 0.10, 0.20, 0.30, 0.50, 0.75, 1.0, 2.0, 3.0, 4.0)
OUTPUTS = ("p_a", "p_b", "velocity")
STEP = 0.25
SETTLE_S = 0.5  # at rest before the step, so the start is the centre-leakage equilibrium
RETRACTED_JOINT = 0.728 - 1.6 + 0.005  # P-I's initial angle (L4842), just off the end stop (INFERRED)


def run_once(machine: Machine, values: dict[str, float]) -> np.ndarray:
    """Outputs (p_A, p_B, v) at TIMES after the step, flattened output-major, for one parameter set."""
    actuator = machine.first
    kv = actuator.valve.nominal_flow / math.sqrt(actuator.valve.nominal_pressure_drop)
    kv_pa = values["q_n_pa"] / math.sqrt(values["dp_n_pa"]) if "q_n_pa" in values else kv
    kv_bt = values["q_n_bt"] / math.sqrt(values["dp_n_bt"]) if "q_n_bt" in values else kv
    overrides: dict[str, Any] = {"valve": {"kv_poly": {"PA": [0, 0, 0, kv_pa], "BT": [0, 0, 0, kv_bt],
                                                       "PB": [0, 0, 0, kv], "AT": [0, 0, 0, kv]}}}
    if "bulk_modulus" in values:
        overrides["fluid"] = {"oil_bulk_modulus": values["bulk_modulus"], "hose_volume": 0.0}
    if "viscous" in values:
        overrides["friction"] = {"viscous": values["viscous"]}
    model = SamModel(machine.with_overrides({"actuators": {actuator.name: overrides}}), actuator.name)
    injections = []
    if values.get("offset"):
        injections.append(Injection("spool_offset", values["offset"], 0.0))
    for name, fault in (("k_int", "internal_leakage"), ("k_ext_a", "external_leakage_a"), ("k_ext_b", "external_leakage_b")):
        if values.get(name):
            injections.append(Injection(fault, values[name] / leak_coefficient(1.0), SETTLE_S))
    plant = SamPlant(model, injections=injections, initial_joint=RETRACTED_JOINT)
    rate = model.sample_rate
    settle = int(round(SETTLE_S * rate))
    plant.advance(settle, commands=np.zeros(settle))
    n = int(round(TIMES[-1] * rate))
    _, states, _ = plant.advance(n, commands=np.full(n, STEP))
    index = np.round(np.asarray(TIMES) * rate).astype(int) - 1
    return np.concatenate([states[index, 0], states[index, 1], states[index, 5]])


def _run_rows(args: tuple[dict[str, Any], list[str], np.ndarray]) -> np.ndarray:
    machine, names, rows = args
    return np.array([run_once(machine, dict(zip(names, row))) for row in rows])


def problem(space: dict[str, tuple[float, float]]) -> dict[str, Any]:
    return {"num_vars": len(space), "names": list(space), "bounds": [list(b) for b in space.values()]}


def sobol_indices(machine: Machine, space: dict[str, tuple[float, float]], samples: int, *, workers: int = 2,
                  seed: int = 0, resamples: int = 200, progress: Callable[[int], None] | None = None) -> dict[str, Any]:
    """First- and total-order indices with 95 % bootstrap intervals, per output and instant."""
    analyze = optional_module("SALib.analyze.sobol")
    sample = optional_module("SALib.sample.sobol")

    spec = problem(space)
    matrix = sample.sample(spec, samples, calc_second_order=False, seed=seed)
    chunks = np.array_split(matrix, max(1, min(len(matrix), 8 * workers)))
    results = []
    with ProcessPoolExecutor(workers) as pool:
        for block in pool.map(_run_rows, [(machine, spec["names"], c) for c in chunks]):
            results.append(block)
            if progress is not None:
                progress(len(block))
    outputs = np.concatenate(results)
    indices: dict[str, Any] = {}
    for o, output in enumerate(OUTPUTS):
        per_time = {}
        for t, instant in enumerate(TIMES):
            y = outputs[:, o * len(TIMES) + t]
            if np.ptp(y) == 0.0:
                continue  # no variance at this instant (e.g. every run still at rest)
            result = analyze.analyze(spec, y, calc_second_order=False, num_resamples=resamples, conf_level=0.95, seed=seed)
            per_time[f"{instant:g}"] = {
                name: {"S1": float(result["S1"][i]), "S1_conf": float(result["S1_conf"][i]),
                       "ST": float(result["ST"][i]), "ST_conf": float(result["ST_conf"][i])}
                for i, name in enumerate(spec["names"])
            }
        indices[output] = per_time
    return {"parameters": spec["names"], "bounds": spec["bounds"], "samples": samples, "runs": len(matrix),
            "times_s": list(TIMES), "indices": indices}


def ranking(result: dict[str, Any], output: str, instant: str = "4", order: str = "S1") -> list[str]:
    """Parameter names by decreasing index at one instant (P-I Tables 2 and 6 use 4 s)."""
    table = result["indices"][output][instant]
    return sorted(table, key=lambda name: -table[name][order])


def interaction(result: dict[str, Any], output: str, instant: str = "4") -> float:
    """1 - sum S_i (P-I Table 3)."""
    return 1.0 - sum(v["S1"] for v in result["indices"][output][instant].values())
