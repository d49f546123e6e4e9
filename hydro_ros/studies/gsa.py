"""Global sensitivity analysis of P-I: Sobol' indices of the SAM model.

Set-up as P-I: a 25 % valve step that extends the cylinder from retracted, outputs p_A, p_B and
the piston velocity at transient instants and at 4 s (P-I's steady state, though the boom still moves
and its load with it), parameters uniform over
P-I Table 1 (k = 7) or the leak coefficients of Table 5 (k = 3). The model is the package's SAM
plant with the GSA's simplifications: constant flow coefficients K_v = Q_N / sqrt(dp_N) per notch
(eq. 12, in place of P-II's polynomials) and a single effective bulk modulus (no hose term).
Sampling and indices are SALib's (Saltelli/Sobol' sequence, Jansen/Saltelli estimators, bootstrap
confidence intervals); the runs are spread over processes.

Convergence: the Saltelli sample at N is the first N (k + 2) rows of the sample at any larger N of the
same seed (the Sobol' points are nested), so one set of runs at the largest N gives the indices at
every smaller N. The true steady state (eqs. 39-40 with the leaks of eqs. 41-43, the load held) is
solved without simulation: what P-I's steady-state argument predicts, free of what still moves at 4 s.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NotRequired, TypedDict

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.extras import optional_module
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.models.chamber import leak_coefficient
from hydro_ros.models.kinematics import piston_position
from hydro_ros.models.sam import Param, SamModel, SamPlant

# P-I Table 1; SI units
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
LEAK_FAULTS = {"k_int": "internal_leakage", "k_ext_a": "external_leakage_a", "k_ext_b": "external_leakage_b"}
SPACES = {"parameters": PARAMETERS, "leakages": LEAKS}
TIMES = (0.05, 0.10, 0.20, 0.30, 0.50, 0.75, 1.0, 2.0, 3.0, 4.0)
OUTPUTS = ("p_a", "p_b", "velocity")
STEP = 0.25
SETTLE_S = 0.5  # at rest before the step, so the start is the centre-leakage equilibrium
RETRACTED_THETA = 0.728 + 0.005  # P-I's triangle angle with the cylinder retracted (P-I App. 2), just off the end stop (INFERRED)
STEADY = "steady"  # the instant of the steady-state indices
# P-I's total-order indices of p_A at 4 s: Table 4 (parameters) and Table 8 (leaks)
P_I_P_A_TOTAL_4S = {
    "parameters": {"offset": 0.006, "q_n_pa": 0.164, "dp_n_pa": 0.263, "q_n_bt": 0.313, "dp_n_bt": 0.326, "bulk_modulus": 0.0,
                   "viscous": 0.0},
    "leakages": {"k_int": 0.3674, "k_ext_a": 0.3385, "k_ext_b": 0.3568},
}
NEGLIGIBLE = 0.01  # an index below this share of the variance is not ranked: its order is the estimator's noise


def start_joint(model: SamModel) -> float:
    """The joint position at P-I's retracted triangle angle, whatever the mount's angle offset."""
    _, l1, l2, l3, *_ = model.mount
    return float(model.joint_from_piston(piston_position(RETRACTED_THETA, l1, l2, l3))[0])


def run_once(machine: Machine, values: dict[str, float], initial_p_b: float | None = None) -> np.ndarray:
    """Outputs (p_A, p_B, v) at TIMES after the step, flattened output-major, for one parameter set.

    The step comes after SETTLE_S at rest at the centre-leakage equilibrium, or, given ``initial_p_b``,
    at once from rest with that p_B and the p_A that holds the load.
    """
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
    settle_s = SETTLE_S if initial_p_b is None else 0.0
    injections = []
    if values.get("offset"):
        injections.append(Injection("spool_offset", values["offset"], 0.0))
    for name, fault in LEAK_FAULTS.items():
        if values.get(name):
            injections.append(Injection(fault, values[name] / leak_coefficient(1.0), settle_s))
    joint = start_joint(model)
    plant = SamPlant(model, injections=injections, initial_joint=joint)
    rate = model.sample_rate
    if initial_p_b is None:
        settle = int(round(settle_s * rate))
        plant.advance(settle, commands=np.zeros(settle))
    else:
        plant.state = model.resting_state(joint, p_b=initial_p_b)
    n = int(round(TIMES[-1] * rate))
    _, states, _ = plant.advance(n, commands=np.full(n, STEP))
    index = np.round(np.asarray(TIMES) * rate).astype(int) - 1
    return np.concatenate([states[index, 0], states[index, 1], states[index, 5]])


def _run_rows(args: tuple[Machine, list[str], np.ndarray, float | None]) -> np.ndarray:
    machine, names, rows, initial_p_b = args
    return np.array([run_once(machine, dict(zip(names, row)), initial_p_b) for row in rows])


def problem(space: dict[str, tuple[float, float]]) -> dict[str, Any]:
    return {"num_vars": len(space), "names": list(space), "bounds": [list(b) for b in space.values()]}


def saltelli_sample(space: dict[str, tuple[float, float]], samples: int, seed: int = 0) -> np.ndarray:
    """The N (k + 2) parameter rows of Saltelli's scheme (no second-order indices)."""
    if samples < 2 or samples & (samples - 1):
        raise InputError(f"{samples} samples: must be a power of two >= 2 (Sobol' sequence)")
    return optional_module("SALib.sample.sobol").sample(problem(space), samples, calc_second_order=False, seed=seed)


def simulate(machine: Machine, space: dict[str, tuple[float, float]], matrix: np.ndarray, *, workers: int = 2,
             initial_p_b: float | None = None, progress: Callable[[int], None] | None = None) -> np.ndarray:
    """run_once per row of ``matrix`` (columns in the order of ``space``), spread over processes."""
    names = list(space)
    chunks = np.array_split(matrix, max(1, min(len(matrix), 8 * workers)))
    results = []
    with ProcessPoolExecutor(workers) as pool:
        for block in pool.map(_run_rows, [(machine, names, c, initial_p_b) for c in chunks]):
            results.append(block)
            if progress is not None:
                progress(len(block))
    return np.concatenate(results)


class SobolIndex(TypedDict):
    S1: float
    S1_conf: float  # 95 % bootstrap half-width
    ST: float
    ST_conf: float


class SobolResult(TypedDict):
    """Indices per output, per instant (seconds as text), per parameter; what ``hydro-ros gsa`` writes per analysis."""
    parameters: list[str]
    bounds: list[list[float]]
    samples: int
    runs: int
    indices: dict[str, dict[str, dict[str, SobolIndex]]]
    times_s: NotRequired[list[float]]
    held_force_n: NotRequired[float]
    ranking_4s: NotRequired[dict[str, list[str]]]
    interaction_4s: NotRequired[dict[str, float]]


def analyse(space: dict[str, tuple[float, float]], outputs: np.ndarray, samples: int, *, instants: Sequence[str],
            seed: int = 0, resamples: int = 200) -> SobolResult:
    """Indices from the first ``samples`` (k + 2) rows of ``outputs``, whose columns are OUTPUTS x ``instants``,
    output-major: per output and instant, S1 and ST with their 95 % bootstrap half-widths."""
    analyze = optional_module("SALib.analyze.sobol")
    spec = problem(space)
    rows = samples * (len(space) + 2)
    if rows > len(outputs):
        raise InputError(f"{samples} samples need {rows} runs; {len(outputs)} given")
    indices: dict[str, dict[str, dict[str, SobolIndex]]] = {}
    for o, output in enumerate(OUTPUTS):
        per_time = {}
        for t, instant in enumerate(instants):
            y = outputs[:rows, o * len(instants) + t]
            if np.ptp(y) == 0.0:
                continue  # no variance at this instant (e.g. every run still at rest)
            # seed + 1: SALib (1.6) takes a seed of 0 for none (`if seed:`) and bootstraps from numpy's global state
            result = analyze.analyze(spec, y, calc_second_order=False, num_resamples=resamples, conf_level=0.95, seed=seed + 1)
            per_time[instant] = {
                name: {"S1": float(result["S1"][i]), "S1_conf": float(result["S1_conf"][i]),
                       "ST": float(result["ST"][i]), "ST_conf": float(result["ST_conf"][i])}
                for i, name in enumerate(spec["names"])
            }
        indices[output] = per_time
    return {"parameters": spec["names"], "bounds": spec["bounds"], "samples": samples, "runs": rows, "indices": indices}


def sobol_indices(machine: Machine, space: dict[str, tuple[float, float]], samples: int, *, workers: int = 2,
                  seed: int = 0, resamples: int = 200, initial_p_b: float | None = None,
                  progress: Callable[[int], None] | None = None) -> SobolResult:
    """First- and total-order indices with 95 % bootstrap intervals, per output and instant."""
    matrix = saltelli_sample(space, samples, seed)
    outputs = simulate(machine, space, matrix, workers=workers, initial_p_b=initial_p_b, progress=progress)
    return {**analyse(space, outputs, samples, instants=[f"{t:g}" for t in TIMES], seed=seed, resamples=resamples),
            "times_s": list(TIMES)}


def indices_at_sizes(space: dict[str, tuple[float, float]], outputs: np.ndarray, sizes: Sequence[int], *,
                     instants: Sequence[str], seed: int = 0, resamples: int = 200) -> dict[int, SobolResult]:
    """analyse at each N of ``sizes`` from the outputs of the sample at the largest (its first N (k + 2) rows are the
    sample at N)."""
    return {n: analyse(space, outputs, n, instants=instants, seed=seed, resamples=resamples) for n in sorted(sizes)}


def convergence(machine: Machine, space: dict[str, tuple[float, float]], sizes: Sequence[int], *, workers: int = 2,
                seed: int = 0, resamples: int = 200, progress: Callable[[int], None] | None = None) -> dict[int, SobolResult]:
    """sobol_indices at each N of ``sizes``, from one set of runs at the largest."""
    matrix = saltelli_sample(space, max(sizes), seed)
    outputs = simulate(machine, space, matrix, workers=workers, progress=progress)
    return indices_at_sizes(space, outputs, sizes, instants=[f"{t:g}" for t in TIMES], seed=seed, resamples=resamples)


def ranking(result: SobolResult, output: str, instant: str = "4", order: str = "S1") -> list[str]:
    """Parameter names by decreasing index at one instant (P-I Tables 2 and 6 use 4 s)."""
    table = result["indices"][output][instant]
    return sorted(table, key=lambda name: -table[name][order])


def ranking_convergence(results: dict[int, SobolResult], output: str, instant: str = "4",
                        order: str = "S1") -> dict[str, Any]:
    """How the ranking at one instant settles with N: at each N the order of the parameters that carry at least
    NEGLIGIBLE of the variance at the largest N, the leader, and the smallest N from which every larger N ranks
    as the largest does (``stable_from``; the largest N itself when no smaller one does)."""
    sizes = sorted(results)
    largest = results[sizes[-1]]["indices"][output][instant]
    ranked = [name for name in ranking(results[sizes[-1]], output, instant, order) if largest[name][order] >= NEGLIGIBLE]
    rankings = {n: [name for name in ranking(results[n], output, instant, order) if name in ranked] for n in sizes}

    def stable_from(same: Callable[[list[str]], bool]) -> int:
        first = sizes[-1]
        for n in reversed(sizes):
            if not same(rankings[n]):
                break
            first = n
        return first

    return {"rankings": {str(n): r for n, r in rankings.items()}, "stable_from": stable_from(lambda r: r == ranked),
            "leader_stable_from": stable_from(lambda r: r[:1] == ranked[:1]),
            "widest_interval": {str(n): max(v[f"{order}_conf"] for v in results[n]["indices"][output][instant].values())
                                for n in sizes}}


def interaction(result: SobolResult, output: str, instant: str = "4") -> float:
    """1 - sum S_i (P-I Table 3)."""
    return 1.0 - sum(v["S1"] for v in result["indices"][output][instant].values())


def held_force(machine: Machine) -> float:
    """[N] the force the chambers carry at 4 s in the nominal run (load and friction): the load a steady state holds."""
    p_a, p_b = run_once(machine, {}).reshape(len(OUTPUTS), len(TIMES))[:2, -1]
    base = SamModel(machine).base
    return float(p_a * base[Param.AREA_A] - p_b * base[Param.AREA_B])


def steady_state(machine: Machine, values: Mapping[str, np.ndarray], force: float) -> np.ndarray:
    """(p_A, p_B, v) per row of ``values`` (arrays by parameter name; nominal where absent) in steady extension under
    the step with ``force`` held (friction lumped in, as P-I's eqs. 39-40; the viscous term b v is < 0.5 % of it).

    The flows balance through both chambers, valve notches and the leaks of eqs. (41)-(43): one equation in p_A with
    p_B from the force, decreasing in p_A, solved by bisection. Without leaks its root is eqs. (39)-(40)."""
    actuator = machine.first
    base = SamModel(machine).base
    a, b, p_s, p_t = base[Param.AREA_A], base[Param.AREA_B], base[Param.SUPPLY], base[Param.TANK]
    size = len(next(iter(values.values())))
    q_n, dp_n = actuator.valve.nominal_flow, actuator.valve.nominal_pressure_drop

    def given(name: str, nominal: float) -> np.ndarray:
        return np.asarray(values[name], dtype=float) if name in values else np.full(size, nominal)

    opening = STEP + given("offset", 0.0)
    k_pa = given("q_n_pa", q_n) / np.sqrt(given("dp_n_pa", dp_n))
    k_bt = given("q_n_bt", q_n) / np.sqrt(given("dp_n_bt", dp_n))
    k_int, k_ext_a, k_ext_b = given("k_int", 0.0), given("k_ext_a", 0.0), given("k_ext_b", 0.0)

    def signed_root(dp: np.ndarray) -> np.ndarray:
        return np.sign(dp) * np.sqrt(np.abs(dp))

    def velocities(p_a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        p_b = (a * p_a - force) / b
        q_int = k_int * signed_root(p_a - p_b)
        from_a = (k_pa * opening * signed_root(p_s - p_a) - q_int - k_ext_a * signed_root(p_a - p_t)) / a
        from_b = (k_bt * opening * signed_root(p_b - p_t) - q_int + k_ext_b * signed_root(p_b - p_t)) / b
        return from_a, from_b

    low = np.full(size, (force + b * p_t) / a)  # p_B at tank: the B side passes no flow
    high = np.full(size, p_s)
    for _ in range(60):
        middle = 0.5 * (low + high)
        from_a, from_b = velocities(middle)
        above = from_a > from_b
        low = np.where(above, middle, low)
        high = np.where(above, high, middle)
    p_a = 0.5 * (low + high)
    return np.column_stack([p_a, (a * p_a - force) / b, velocities(p_a)[0]])


def steady_state_indices(machine: Machine, space: dict[str, tuple[float, float]], samples: int, *, seed: int = 0,
                         resamples: int = 200) -> SobolResult:
    """Indices of the true steady state (instant STEADY) with the nominal run's 4 s force held."""
    force = held_force(machine)
    matrix = saltelli_sample(space, samples, seed)
    outputs = steady_state(machine, dict(zip(space, matrix.T)), force)
    return {**analyse(space, outputs, samples, instants=[STEADY], seed=seed, resamples=resamples), "held_force_n": force}


@dataclass(frozen=True)
class Cause:
    """A candidate cause of a difference from P-I: what differs from the study's set-up."""

    name: str
    change: str
    actuator: Mapping[str, Any] = field(default_factory=dict)  # patch of the actuator's config section
    machine: Mapping[str, Any] = field(default_factory=dict)  # patch of the config's top level
    initial_p_b: float | None = None
    spaces: tuple[str, ...] = ("parameters", "leakages")

    def applied(self, machine: Machine) -> Machine:
        if not (self.actuator or self.machine):
            return machine
        return machine.with_overrides({**self.machine, "actuators": {machine.first.name: dict(self.actuator)}})


MOUNT_OFFSET_P_I = 0.415  # P-I's alpha1 + alpha2 (P-I App. 2, Fig. 3), read as boom angle = theta - (alpha1 + alpha2) (INFERRED)
CAUSES = (
    Cause("step from p_B = 0", "the step at once from rest with p_B at tank pressure (p_A holding the load), not after "
          "0.5 s at the centre-leakage equilibrium (P-I gives no initial pressures)", initial_p_b=0.0),
    Cause("step from p_B = 6 MPa", "the step at once from rest with p_B = 6 MPa (p_A holding the load)", initial_p_b=6.0e6),
    Cause("no payload", "left load mass 0 kg instead of P-I's 494 kg: the boom's own weight only",
          actuator={"load": {"left_mass": 0.0}}),
    Cause("laminar leaks", "leak flow in proportion to the pressure drop (1 L/min at 10 MPa, as Table 5's bound), not to "
          "its square root (eqs. 41-43)", machine={"effects": {name: 0.0 for name in LEAK_FAULTS.values()},
                                                   "effect_forms": {name: "laminar" for name in LEAK_FAULTS.values()}},
          spaces=("leakages",)),
    *(Cause(f"mount offset {offset:g} rad", f"boom angle = theta - {offset:g} rad instead of theta - 1.6 rad (the relation "
            "is not given; INFERRED): the load " + how, actuator={"mount": {"theta_offset": offset}})
      for offset, how in ((1.4, "nearly flat along the first 0.1 m"), (1.3, "falling slightly along the stroke"),
                          (1.2, "falling along the stroke"),
                          (MOUNT_OFFSET_P_I, "falling steeply (P-I's alpha1 + alpha2 as the offset)"))),
)


def load_change(machine: Machine, stroke: float = 0.1) -> tuple[float, float]:
    """[N] the load on the piston at the retracted start and ``stroke`` further out: which way it goes as the step extends."""
    model = SamModel(machine)
    _, l1, l2, l3, *_ = model.mount
    start = piston_position(RETRACTED_THETA, l1, l2, l3)
    return model.load_force(start), model.load_force(start + stroke)


def cause_summary(results: Mapping[str, dict[str, Any]], instant: str = "4") -> dict[str, Any]:
    """What a set-up gives against P-I at one instant: the p_A and p_B parameter rankings (first and total order), the
    p_A leak indices and ranking, whether a notch-BT parameter leads p_A (P-I Table 2) and how alike the leaks are on
    p_A (the smallest total-order index over the largest; P-I Table 8: 0.92)."""
    summary: dict[str, Any] = {}
    if "parameters" in results:
        parameters = results["parameters"]
        summary["parameter_rankings"] = {output: {order: ranking(parameters, output, instant, order) for order in ("S1", "ST")}
                                         for output in ("p_a", "p_b")}
        summary["p_a_parameters"] = parameters["indices"]["p_a"][instant]
        summary["bt_leads_p_a"] = summary["parameter_rankings"]["p_a"]["S1"][0] in ("dp_n_bt", "q_n_bt")
    if "leakages" in results:
        leaks = results["leakages"]["indices"]["p_a"][instant]
        totals = [v["ST"] for v in leaks.values()]
        summary["p_a_leaks"] = leaks
        summary["leak_ranking_p_a"] = ranking(results["leakages"], "p_a", instant, "ST")
        summary["leak_spread_p_a"] = max(min(totals), 0.0) / max(totals)
    return summary


def plot_indices(results: dict[str, SobolResult], out: str | Path) -> Path:
    """Total-order Sobol' indices against time per output (P-I Table 4 / Table 8 as curves), 95 % bands."""
    from hydro_ros.workflows.plots import plt

    out = Path(out)
    analyses = [name for name in ("parameters", "leakages") if name in results]
    outputs = ("p_a", "p_b", "velocity")
    fig, axes = plt.subplots(len(analyses), 3, figsize=(14, 3.6 * len(analyses)), squeeze=False, sharex=True)
    for row, name in enumerate(analyses):
        result = results[name]
        for col, output in enumerate(outputs):
            ax = axes[row, col]
            instants = sorted(result["indices"][output], key=float)
            times = [float(t) for t in instants]
            for parameter in result["parameters"]:
                st = np.array([result["indices"][output][t][parameter]["ST"] for t in instants])
                conf = np.array([result["indices"][output][t][parameter]["ST_conf"] for t in instants])
                ax.plot(times, st, marker="o", ms=3, label=parameter)
                ax.fill_between(times, st - conf, st + conf, alpha=0.15)
            ax.set_xscale("log")
            ax.set_title(f"{name}: {output}")
            ax.set_ylabel("total-order index")
            ax.grid(alpha=0.3)
        axes[row, 0].legend(fontsize=7)
    for ax in axes[-1]:
        ax.set_xlabel("time after the 25 % step [s]")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out
