"""docs/reproduction.md's table: each claim of the thesis's papers against ours.

A paper's figure is a published fact and stays in the claim's text; a figure of ours is read from bench/results/ (no
figure of ours typed by hand) or, where a test is the evidence, the test is named. A file or a key a run did not write
shows as "not in bench/results"; a figure no result file holds says so in its row ("typed by hand: ...").
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass
from itertools import takewhile
from statistics import mean
from typing import Any

import numpy as np

from hydro_ros.contract.names import first_form
from hydro_ros.fdi.rates import INTERVAL, false_alarm_text
from hydro_ros.planning.certify import CERTIFIED
from hydro_ros.tooling.benchresults import MISSING, commit_of, read_results, span

LEAK = {"external_leakage_a": "A", "external_leakage_b": "B", "internal_leakage": "internal"}
P_I_NATURAL_FREQUENCY_HZ = 4.5  # P-I Fig. 4's maximum
P_VI_TRACKING_M = (0.041, 0.346)  # P-VI Table 4's smallest and largest tracking error
P_I_RANKING = {  # P-I Table 2 (parameters, first order) and Table 6 (leaks), most influential first, by gsa.json's names
    "parameters": {"p_a": ("dp_n_bt", "q_n_bt", "dp_n_pa", "q_n_pa", "offset", "bulk_modulus", "viscous"),
                   "p_b": ("dp_n_pa", "q_n_pa", "dp_n_bt", "q_n_bt", "offset", "bulk_modulus", "viscous"),
                   "velocity": ("dp_n_pa", "q_n_pa", "offset", "dp_n_bt", "q_n_bt", "bulk_modulus", "viscous")},
    "leakages": {"p_a": ("k_int", "k_ext_b", "k_ext_a"), "p_b": ("k_ext_a", "k_ext_b", "k_int"),
                 "velocity": ("k_int", "k_ext_a", "k_ext_b")},
}
DP_SMALLEST_START = ("dp_compare_k70m_horizontal", "dp_compare_k70m_half_cycle", "dp_compare_k70m_vertical",
                     "dp_compare_crane3dof_triangle")
DP_MIDDLE_START = ("dp_compare_k70m_horizontal_middle", "dp_compare_k70m_half_cycle_middle", "dp_compare_k70m_vertical_middle")


# what a row's status starts with: the paper's claim reproduced, in part, not, contradicted, not attempted; OURS: a claim
# of the package's own that no paper makes (the thesis asks for it or it is the package's workflow)
VERDICTS = ("REPRODUCED", "PARTLY", "NOT ATTEMPTED", "NOT", "CONTRADICTED", "OURS")


@dataclass(frozen=True)
class Claim:
    claim: str  # the paper's claim with its figures
    status: str  # a verdict, then why: "PARTLY: in kind, not in time"
    ours: str | Callable[..., str]  # text where tests are the evidence, else a reader of ``files`` in their order
    files: tuple[str, ...] = ()  # bench/results/<name>.json
    tests: tuple[str, ...] = ()  # <file in test/>::<function>
    by_hand: str = ""  # where a figure of ours comes from that no result file holds
    part: str | None = None  # the part of a file whose parts run apart (bench/dp.py --parts) the row reads: its commit is shown

    def __post_init__(self) -> None:
        if not re.match(rf"({'|'.join(VERDICTS)})\b", self.status):
            raise ValueError(f"claim {self.claim!r}: status {self.status!r} starts with none of {', '.join(VERDICTS)}")

    @property
    def verdict(self) -> str:
        return next(verdict for verdict in VERDICTS if re.match(rf"{verdict}\b", self.status))


def _count(share: float, runs: int) -> str:
    return f"{round(share * runs)}/{runs}"


def _pct(values: list[float], fmt: str = ".0f", sep: str = "-") -> str:
    return span([100.0 * v for v in values], fmt, sep)


def _signed(values: list[float], fmt: str = "+.0f") -> str:
    return _pct(values, fmt, " to ") + " %"


def _above(energy: float, reference: float) -> float:
    return energy / reference - 1.0


def _threshold(commissioning: dict) -> str:
    t = commissioning["threshold"]
    return (f"`{commissioning['config']}` ships c0 = {t['shipped']:g} MPa, safe on the model's own equations with their numbers "
            "drawn off (a machine built apart needs `hydro-ros machine threshold`'s); `hydro-ros "
            f"commission` fits c0 to the identified machine (median {t['median']:.4f} MPa on {commissioning['plants']} plants)")


def _valve_faults(evaluation: dict) -> str:
    rows = [r for r in evaluation["rows"] if r["fault"].startswith("spool_")]
    if not rows:
        raise KeyError("spool_* rows")
    isolated = ", ".join(f"{r['fault'].removeprefix('spool_').replace('_', ' ')} {_count(r['isolation_accuracy'], r['runs'])}"
                         for r in rows)
    return f"the shipped bags and Table 3's procedure; `fdi eval` isolates {isolated}"


def _smallest_leaks(evaluation: dict, commissioning: dict) -> str:
    def sizes(table: dict[str, Any]) -> str:
        return ", ".join(f"{LEAK[n]} {'none' if table[n] is None else f'{table[n]:g}'}"
                         for n in ("external_leakage_b", "external_leakage_a", "internal_leakage"))

    uncommissioned = {n: v and v["value_l_min_at_10mpa"] for n, v in evaluation["smallest_detectable"].items()}
    plants = commissioning["plants"]
    free = evaluation["fault_free"]
    commissioned_alarms = sum(p["false_alarms"]["commissioned"] for p in commissioning["per_plant"])
    return (f"uncommissioned, flow coefficients ±{100 * evaluation['mismatch']['flow_coefficient']:g} % off: "
            f"{sizes(uncommissioned)} L/min (isolated in ≥ 80 % of runs) at "
            f"{false_alarm_text(free['crossing_episodes'], free['hours'], 'threshold-crossing episode')}; after `hydro-ros "
            f"commission` on the plant's own recordings: {sizes(commissioning['smallest_isolated_in_every_plant_l_min'])} L/min "
            f"isolated in {plants}/{plants} plants at "
            f"{false_alarm_text(commissioned_alarms, commissioning['fault_free_hours_per_config'])}")


def _fault_rows(evaluation: dict) -> dict[str, list[dict]]:
    faults: dict[str, list[dict]] = {}
    for row in evaluation["rows"]:
        faults.setdefault(row["fault"], []).append(row)
    return faults


def _sensor_biases(parity: dict) -> str:
    faults = _fault_rows(parity)
    chambers = []
    for chamber in ("a", "b"):
        sizes = []
        for r in faults[f"pressure_sensor_bias_{chamber}"]:
            detected, isolated = _count(r["detection_rate"], r["runs"]), _count(r["isolation_accuracy"], r["runs"])
            sizes.append(f"{r['value'] / 1e6:g} MPa {isolated}" + ("" if detected == isolated else f" (detected {detected})"))
        chambers.append(f"p_{chamber.upper()} " + ", ".join(sizes))
    return "on the simulated mobile-valve SAM, biases detected and isolated on " + "; ".join(chambers)


def _detectable(parity: dict) -> str:
    faults = _fault_rows(parity)
    never = [f for f, rows in faults.items() if not any(r["detection_rate"] for r in rows)]
    unisolated = [f for f, rows in faults.items() if f not in never and not any(r["isolation_accuracy"] for r in rows)]
    return (f"{len(never)} of {len(faults)} faults never detected: {', '.join(never)}. Isolation is a further limit: "
            f"{', '.join(unisolated)} {'is' if len(unisolated) == 1 else 'are'} detected but never named (the evidence shared "
            "with other faults' rows)")


def _gsa(gsa: dict, convergence: dict) -> str:
    def kept(table: str) -> str:
        ranking = gsa[table]["ranking_4s"]
        return ", ".join(f"{output} {sum(1 for _ in takewhile(lambda pair: pair[0] == pair[1], zip(ranking[output], paper)))}"
                         f"/{len(paper)}" for output, paper in P_I_RANKING[table].items())

    def settled(key: str) -> int:
        return max(n for outputs in convergence[key].values() for n in outputs.values())

    def load(cause: dict) -> str:
        start, further = cause["load_n"]
        return f"load {(further - start) / 1e3:+.1f} kN over the first 0.1 m"

    indices = gsa["parameters"]["indices"]
    first, at_first = next(iter(indices["p_a"].items()))
    friction = max(at["viscous"]["ST"] for output in indices.values() for at in output.values())
    causes = [c for c in convergence["causes"] if "load_n" in c]
    shipped = next(c for c in causes if c["name"] == "as shipped")
    leak_order = [c["name"] for c in causes if c.get("leak_ranking_p_a") == list(P_I_RANKING["leakages"]["p_a"])]
    alike = max((c for c in causes if "leak_spread_p_a" in c), key=lambda c: c["leak_spread_p_a"])
    return (f"leading ranks as P-I's: parameters {kept('parameters')}; leaks {kept('leakages')}; b's total order ≤ "
            f"{friction:.0e}; B_eff's on p_A {at_first['bulk_modulus']['ST']:.2f} at {first} s, "
            f"{indices['p_a']['1']['bulk_modulus']['ST']:.3f} at 1 s; interaction "
            f"{_pct(list(gsa['parameters']['interaction_4s'].values()))} % at 4 s. N = {convergence['sizes']['parameters'][0]}-"
            f"{convergence['sizes']['parameters'][-1]}: each 4 s leader is the largest N's from N = {settled('leader_stable_from_4s')}, "
            f"each full order from N = {settled('stable_from_4s')}. Causes at N = {causes[0]['samples']}: a notch-BT parameter leads "
            f"p_A, as in P-I, for {'; '.join(c['name'] + ', ' + load(c) for c in causes if c.get('bt_leads_p_a')) or 'none'} "
            f"(as shipped: {load(shipped)}); P-I's p_A leak order for {', '.join(leak_order) or 'none'}; the leaks on p_A at best within "
            f"a factor {1.0 / alike['leak_spread_p_a']:.1f} of each other ({alike['name']}), P-I's within 1.1")


def _pinvs_above_dp(*compares: dict, cost: str) -> list[float]:
    """Each pseudo-inverse within limits against the DP of the same cost."""
    key = f"{cost}_energy_J"
    return [_above(r[key], c["methods"][f"dp_{cost}"][key]) for c in compares for name, r in c["methods"].items()
            if name.startswith("pinv_") and r["limits_ok"]]


def _against_direct(compare: dict, *methods: str) -> list[float]:
    return [_above(compare["methods"][m]["cp_energy_J"], compare["methods"]["direct_cp"]["cp_energy_J"]) for m in methods]


def _dp_vs_conventional(horizontal: dict, half_cycle: dict, vertical: dict, triangle: dict, *middle: dict) -> str:
    def pinvs(*compares: dict) -> str:
        return f"{_signed(_pinvs_above_dp(*compares, cost='cp'))} CP, {_signed(_pinvs_above_dp(*compares, cost='ls'))} LS"

    pinv_names = [m for m in vertical["methods"] if m.startswith("pinv_")]
    return (f"the pseudo-inverses within limits against the DP of the same cost: horizontal and half-cycle "
            f"{pinvs(horizontal, half_cycle)}; P-V triangle {pinvs(triangle)}. Vertical placeholder from the smallest start: the "
            f"tilt joint's limit decides the motion, DP (CP) and the pseudo-inverses end within "
            f"{_pct([max(_against_direct(vertical, 'dp_cp', *pinv_names))], '.2f')} % of the direct method, DP (LS) and DP "
            f"(actuator) within {_pct([max(_against_direct(vertical, 'dp_ls', 'dp_actuator_energy'))], '.1f')} % (CP). P-VI's "
            f"second start (middle of the window), all {len(middle)} paths: {pinvs(*middle)}. P-VI's almost 2x LS on its "
            f"vertical path: not reproduced (last row)")


def _table_shape(*compares: dict) -> str:
    excess = []
    for c in compares:
        ls = {m: r["ls_energy_J"] for m, r in c["methods"].items() if m.startswith("dp_")}
        best = min(ls, key=ls.__getitem__)
        if best != "dp_ls":
            excess.append(f"{c['path']} ({_signed([_above(ls['dp_ls'], ls[best])], '+.1f')} against {best})")
    methods = next(c for c in compares if c["path"] == "vertical")["methods"]
    over_pinvs = [_above(methods["dp_cp"]["cp_energy_J"], r["cp_energy_J"]) for m, r in methods.items()
                  if m.startswith("pinv_") and r["limits_ok"]]
    direct = [_against_direct(c, "dp_cp")[0] for c in compares]
    return (f"DP (LS) lowest LS of the DP methods on the full grid, except on {', '.join(excess) or 'no path'}; on the vertical "
            f"path not at a 2x velocity and control grid either (motion.md: DP (LS) 35.55 kJ, DP (CP) 35.48 kJ; no result file). "
            f"DP (CP) {_signed(direct, '+.2f')} against the direct method"
            + (", which is lower on every path" if min(direct) > 0 else "")
            + f"; on the vertical path {_signed(over_pinvs, '+.2f')} against the pseudo-inverses (grid resolution)")


def best_feasible_baseline(methods: dict[str, dict], cost: str) -> float | None:
    """[J] the least energy in ``cost`` of a baseline (a pseudo-inverse or the direct method) that keeps every limit,
    acceleration included; None where none does."""
    feasible = [r[f"{cost}_energy_J"] for name, r in methods.items()
                if not name.startswith("dp_") and r.get("limits") and all(r["limits"].values())]
    return min(feasible) if feasible else None


def _dp_excess(methods: dict[str, dict], cost: str) -> float | None:
    """DP(cost)'s realised energy in its own cost over the best feasible baseline; None where no baseline is feasible."""
    best = best_feasible_baseline(methods, cost)
    return methods[f"dp_{cost}"][f"{cost}_energy_J"] / best - 1.0 if best is not None else None


def _certificate(*files: dict) -> str:
    """The DP against every feasible baseline in its own cost, on each comparison and each line of the savings map."""
    *compares, savings, dp = files
    parts = []
    for cost in ("cp", "ls"):
        cases = {f"{c['machine']}/{c['path']}" + ("" if abs(c["start_position_m"] - min(x["start_position_m"] for x in compares
                 if x["path"] == c["path"] and x["machine"] == c["machine"])) < 1e-9 else " (middle)"): _dp_excess(c["methods"], cost)
                 for c in compares}
        lines = {row["path"]: _dp_excess({name: {f"{k}_energy_J": v for k, v in e.items() if k in ("cp", "ls")}
                                          | {"limits": e.get("limits")} for name, e in row["energy_J"].items()}, cost)
                 for row in savings["rows"] if row["feasible"]}
        measured = {name: x for name, x in {**cases, **lines}.items() if x is not None}
        above = sorted(name for name, x in measured.items() if x > CERTIFIED)
        parts.append(f"DP ({cost.upper()}) against the best feasible baseline in {cost.upper()}: {_signed(list(measured.values()), '+.1f')} "
                     f"over {len(cases)} comparisons and {len(lines)} savings-map lines; above {CERTIFIED:.1%} on {len(above)}"
                     + (f" ({', '.join(above[:4])}{', ...' if len(above) > 4 else ''})" if above else ""))
    text = "; ".join(parts) + " (baselines: the pseudo-inverses, weighted too, and the direct method where run)"
    polished = dp.get("polish")
    if polished:
        found = []
        for cost in ("cp", "ls"):
            rows = [r for r in polished["cases"].values() if r["cost"] == cost and r["polished_over_baseline"] is not None]
            still = sorted(r["case"] for r in rows if r["polished_over_baseline"] > CERTIFIED)
            if rows:
                found.append(f"the {len(rows)} {cost.upper()} cases above it: {_signed([r['polished_over_baseline'] for r in rows], '+.1f')}, "
                             + (f"still above on {len(still)} ({', '.join(still)})" if still else "none above"))
        text += ". Polished (`planning.polish`: the DP's own trajectory to a local minimum of its realised cost): " + "; ".join(found)
        rows = [r for r in polished["cases"].values() if "certified_over_baseline" in r]
        if rows:
            tube = polished["tube"]
            still = sorted(f"{r['case']} {r['cost'].upper()}" for r in rows if r["certified_over_baseline"] > CERTIFIED)
            text += (f". Planned again on a grid narrowed to a tube around that baseline (`DpGrid.around`: +-{tube['half_width_m']:g} m, "
                     f"its speeds +-{tube['velocity_pad_m_s']:g} m/s, the same node counts): the DP's answer "
                     f"{_signed([r['refined_over_baseline'] for r in rows], '+.1f')} (within {CERTIFIED:.1%} on "
                     f"{sum(r['refined_over_baseline'] <= CERTIFIED for r in rows)} of {len(rows)}), polished "
                     f"{_signed([r['refined_polished_over_baseline'] for r in rows], '+.1f')}; the better of the two polished DP answers "
                     + (f"still above on {len(still)} ({', '.join(still)})" if still else f"within {CERTIFIED:.1%} on all {len(rows)}"))
    return text


def _grid_convergence(dp: dict) -> str:
    """The full grid against a finer one on every K70M path and start (bench/dp.py ``convergence``)."""
    study = dp["convergence"]
    cases = study["cases"]
    # a finer grid whose realised energy is higher (a trajectory riding a moving limit edge) is no convergence either
    converged = {cost: [name for name, case in cases.items() if abs(case[f"{cost}_full_grid_excess"]) <= study["converged_share"]]
                 for cost in ("cp", "ls")}
    at_full = [row for case in cases.values() for cost in ("cp", "ls") for row in case[cost] if row["scale"] == 1.0]
    coarsest = [case[cost][0]["relative"] - 1.0 for case in cases.values() for cost in ("cp", "ls")]
    ratio = [row["predicted_over_realised"] for row in at_full]
    return (f"the full grid's energy against a {study['scales'][-1]:g}x finer grid's on {len(cases)} cases (3 K70M paths x 2 starts): "
            f"CP {_signed([case['cp_full_grid_excess'] for case in cases.values()], '+.2f')}, "
            f"LS {_signed([case['ls_full_grid_excess'] for case in cases.values()], '+.2f')}; within "
            f"{study['converged_share']:.1%}: CP {len(converged['cp'])} of {len(cases)}, LS {len(converged['ls'])} of {len(cases)}"
            + "".join(f" (not: {', '.join(sorted(set(cases) - set(converged[c])))} {c.upper()})" for c in ("cp", "ls")
                      if len(converged[c]) < len(cases))
            + f". The coarsest grid ({study['scales'][0]:g}x) {_signed(coarsest, '+.1f')}. On the full grid the DP's "
            f"predicted cost is {_pct(ratio, '.1f')} % of its own trajectory's realised energy")


def _multistart(dp: dict) -> str:
    """The direct method from many seeds against DP (CP) on every K70M path and start (bench/dp.py ``multistart``)."""
    study = dp["multistart"]
    cases, share, variants = study["cases"], study["distinct_share"], study["variants"]
    several = [f"{name} ({variant.replace('_', ' ')})" for name, case in cases.items() for variant in variants
               if case[variant].get("distinct_optima", 0) > 1]
    beaten = sorted({name for name, case in cases.items() for variant in variants if case[variant].get("dp_beats_median")})
    over_best = [case[variant]["dp_over_best"] for case in cases.values() for variant in variants if case[variant]["local_optima"]]

    def no_optimum(variant: str) -> str:
        rows = [r for case in cases.values() for r in case[variant]["seeds"].values()
                if r["finest_status"] != "Solve_Succeeded" or not all(r["limits"].values()) or r["tip_error_max_m"] >= 1e-6]
        statuses = sorted({r["finest_status"] for r in rows})
        return f"{len(rows)} {variant.replace('_', ' ')}" + (f" ({', '.join(statuses)})" if statuses else "")

    return (f"the direct method (IPOPT) from {span(list(study['seeds_per_case'].values()), 'd')} seeds per case (the joint-space "
            f"pseudo-inverse, the DP (CP)'s trajectory, blends to and via shares of the extension window) on {len(cases)} cases "
            f"(3 K70M paths x 2 starts), bootstrapped over node counts and at the finest alone: "
            + (f"more than one optimum ({share:.1%} apart) on {', '.join(several)}" if several
               else f"one optimum per case (every local optimum within {share:.1%} of the best)")
            + f"; DP (CP) {_signed(over_best, '+.2f')} against the best local optimum, "
            + (f"below the median by more than {share:.1%} on {', '.join(beaten)}" if beaten
               else f"never below the median or the worst by more than {share:.1%}")
            + f". Seeds that ended in no local optimum within limits: {no_optimum('bootstrapped')}; {no_optimum('finest_only')}")


def _tracking_errors(trajectories: dict) -> list[float]:
    return [run[s]["path_accuracy_m"] for methods in trajectories["execution"].values() for run in methods.values()
            for s in ("cp", "ls")]


def _tracking(trajectories: dict) -> str:
    means = "; ".join(f"{path} {mean(r['cp']['path_accuracy_m'] for r in methods.values()):.3f} / "
                      f"{mean(r['ls']['path_accuracy_m'] for r in methods.values()):.3f}"
                      for path, methods in trajectories["execution"].items())
    return (f"{span(_tracking_errors(trajectories), '.3f')} m on the simulated crane; mean CP / LS: {means} m. The field "
            f"energies need the real machine")


def _closed_loop(trajectories: dict) -> str:
    runs = trajectories["execution"]
    saved = []
    for path, methods in runs.items():
        pinvs = [r for m, r in methods.items() if m.startswith("pinv_")]
        saved.append(f"{path} " + " / ".join(_signed([_above(methods["dp_cp"][s]["executed_J"], min(p[s]["executed_J"] for p in pinvs))],
                                                     "+.1f") for s in ("cp", "ls")))
    vertical = [[r[s]["executed_J"] for m, r in runs["vertical"].items() if m != "dp_extension"] for s in ("cp", "ls")]
    spread = max(_above(max(energies), min(energies)) for energies in vertical)
    return (f"on the simulated crane with payload, friction and valve mismatch, DP-CP executed against the better pseudo-inverse "
            f"(CP / LS): {'; '.join(saved)}. On our vertical placeholder all methods but dp_extension ride one joint limit and "
            f"execute within {_pct([spread], '.1f')} % of each other (as planned); all {len(runs['vertical'])} contract methods executed")


def _multi_actuator(monitoring: dict, commissioning: dict) -> str:
    def isolated_in_every_run(faults: list[dict]) -> str:
        for size in sorted({f["value_l_min"] for f in faults}):
            chambers = [f for f in faults if f["value_l_min"] == size and f["isolated"] == f["runs"]]
            if chambers:
                return (f"{size:g} L/min isolated in every run ({span([f['runs'] for f in chambers], 'd')} each) in "
                        + ", ".join(f"{f['actuator']} {LEAK[f['fault']]}" for f in chambers))
        return "no leak isolated in every run"

    free, faults = monitoring["fault_free"], monitoring["faults"]
    elsewhere = sum(f["other_cylinder_alarms"] for f in faults)
    plants, refused = commissioning["plants"], len(commissioning["refused"])
    commissioned_free = commissioning["fault_free"]["commissioned"]
    return (f"the simulated K70M's {len({f['actuator'] for f in faults})} cylinders at work, mismatched cranes with "
            f"{monitoring['setup']['payload_kg']:g} kg payload: {false_alarm_text(free['alarms'], free['hours'])}; "
            + ("every leak run alarmed only its own cylinder" if not elsewhere else f"{elsewhere} alarms on another cylinder")
            + f"; {isolated_in_every_run(faults)}. Commissioned on the crane's own work ({plants} of {plants + refused} plants; "
            f"the others' recordings refused): {isolated_in_every_run(commissioning['faults'])}, at "
            f"{false_alarm_text(commissioned_free['alarms'], commissioned_free['hours'])} of their fault-free work. No field data")


def _arm_commissioning(arm: dict) -> str:
    pooled = arm["pooled"]
    levels = [level for level in pooled if pooled[level]["rigs"]]

    def smallest(level: str, key: str) -> str:
        """The size named (detected) on every rig, per chamber."""
        out = []
        for chamber, sizes in pooled[level][key].items():
            out.append(f"{chamber.replace('/', ' ').replace('external_leakage_', '').replace('internal_leakage', 'internal')} "
                       + (f"{max(sizes):g}" if sizes and None not in sizes else f"> {max(arm['sizes_l_min']):g}"))
        return ", ".join(out)

    documented = "4 min" if "4 min" in levels else levels[-1]
    refused = [f"{level} on {pooled[level]['refused']} of {pooled[level]['rigs'] + pooled[level]['refused']} rigs"
               for level in pooled if pooled[level]["refused"]]
    def label(level: str) -> str:
        if level == "shipped":
            return f"as shipped (c0 {pooled[level]['threshold_c0_mpa']:g} MPa)"
        return f"commissioned from {level}"

    return (f"`{arm['config']}` built apart from the model (`{arm['plant']}`), {max(pooled[level]['rigs'] for level in pooled)} "
            "rigs; "
            + "; ".join(f"{label(level)}: {false_alarm_text(pooled[level]['false_alarms'], pooled[level]['fault_free_hours'])}"
                        + ("" if level == "shipped" else ", held outside the commissioned commands "
                           + ", ".join(f"{a} {100 * v:.1f} %" for a, v in pooled[level]["held_share_by_actuator"].items())
                           + f" of the time ({100 * pooled[level]['held_share_max']:.1f} % on the worst rig)") for level in levels)
            + (f"; commissioning refused from {', '.join(refused)} (each reason in the file)" if refused else "")
            + f". From {documented}, named on every rig [L/min at 10 MPa]: {smallest(documented, 'smallest_named_l_min')}; "
            f"detected: {smallest(documented, 'smallest_detected_l_min')}")


def _roc(roc: dict) -> str:
    """The SAM built apart swept over its threshold (bench/roc.py)."""
    by_scale, sizes = roc["by_scale"], roc["sizes_l_min"]
    kinds = ("external_leakage_a", "external_leakage_b", "internal_leakage")

    def pooled(scale: str, size: float) -> tuple[int, int]:
        rows = [by_scale[scale]["leaks"][f"{kind}/{size:g}"] for kind in kinds]
        return sum(r["detected"] for r in rows), sum(r["quiet_before_onset"] for r in rows)

    nominal = by_scale["1"]
    curve = "; ".join(f"x{scale}: {by_scale[scale]['false_alarms']} false alarm{'' if by_scale[scale]['false_alarms'] == 1 else 's'}, "
                      + ", ".join(f"{size:g} L/min {pooled(scale, size)[0]}/{pooled(scale, size)[1]}" for size in sizes)
                      for scale in by_scale)
    def delay(r: dict) -> str:
        band = f" [{r['delay_band_s'][0]:.1f}-{r['delay_band_s'][1]:.1f}]" if r["delay_band_s"] else f" (n = {r['detected']}, no band)"
        return f"{r['delay_median_s']:.1f} s{band} at {r['flow_at_detection_l_min']:.2f} L/min"

    delays = "; ".join(f"{LEAK[kind]} " + ", ".join(f"{size:g}: {delay(r)}" for size in sizes
                                                    if (r := nominal["leaks"][f"{kind}/{size:g}"])["delay_median_s"] is not None)
                       for kind in kinds)
    return (f"`{roc['config']}` built apart (`{roc['plant']}`), {roc['rigs']} rigs commissioned on 4 min (c0 "
            f"{span(list(roc['commissioned_c0_mpa'].values()), '.3f')} MPa), each run monitored at {len(by_scale)} threshold scales. "
            f"At the commissioned c0: {false_alarm_text(nominal['false_alarms'], nominal['hours'])} (fault-free runs and the leak runs "
            f"before onset). Detected after onset, of the leak runs quiet before it (all kinds) per scale: {curve}. Median delay at "
            "the commissioned c0 [bootstrap 95 % band] and the leak's flow at detection "
            f"(P-II's way of quoting a leak; the size is at 10 MPa): {delays}. {nominal['hours']:g} h fault-free per scale, not "
            "the 100 h issue 55 asks for")


def _fault_free_hours(hours: dict) -> str:
    """Long fault-free work of the shipped configs built apart (bench/fault_free_hours.py)."""
    per_config = "; ".join(
        f"`{name}`: " + (f"{false_alarm_text(r['false_alarms'], r['hours'])}, {r['hours']:.1f}" if r["hours"] else "none yet")
        + f" of the {r['target_hours']:g} h asked"
        + (f" ({len({(a['rig'], a['seed']) for a in r['alarms']})} of {r['runs']} runs alarmed; by rig "
           + ", ".join(f"{rig}: {n['false_alarms']}" for rig, n in r["per_rig"].items())
           + "; named: " + (", ".join(sorted({a["fault"] for a in r["alarms"]} - {"unisolated"})) or "none") + ")"
           if r["alarms"] else "")
        for name, r in hours["configs"].items())
    short = [name for name, r in hours["configs"].items() if not r["reached_target"]]
    return (f"each shipped config built apart (`{hours['plant']}`, rigs {span(hours['rigs'], 'd')}), the rigs commissioned on "
            f"{hours['commissioned_on']}, then monitored on fresh fault-free work in {hours['run_s']:g} s runs: {per_config}"
            + (f". Short of 100 h: {', '.join(short)} (the bench's wall-clock budget; a rerun on the same code goes on)" if short else ""))


def _crane_apart(apart: dict) -> str:
    """The K70M built apart, commissioned on its own day (bench/crane_apart.py)."""
    pooled, rigs = apart["pooled"], apart["per_rig"]
    shipped, commissioned = pooled["shipped"], pooled["commissioned"]
    firsts = [t for r in rigs for t in (r["fault_free"]["shipped"]["first_alarm_s"] or [])]

    def chambers(key: str) -> list[str]:
        return [f"{k.split('/')[0]} {LEAK[k.split('/')[1]]}" for k, sizes in commissioned[key].items() if any(s is not None for s in sizes)]

    named, detected = chambers("named_l_min"), chambers("detected_l_min")
    effects, largest = apart["effects"], max(apart["sizes_l_min"])
    return (f"`{apart['config']}` built apart (`{apart['plant']}`), {len(rigs)} rigs, each commissioned on its own day: thresholds at rest "
            f"{span([r['mean_threshold_at_rest_l_min']['value'] for r in rigs], '.1f')} L/min against the shipped "
            f"{span([r['mean_threshold_at_rest_l_min']['before'] for r in rigs], '.2f')} ("
            f"{'refused without --force' if all(r['refused_unforced'] for r in rigs) else 'not all refused without --force'}; the shipped ones "
            f"alarmed {span([r['shipped_alarms_on_held_out'] for r in rigs], 'd')} times on the held-out parts). Fresh fault-free work "
            f"({apart['run_s']:g} s runs, {apart['payload_kg']:g} kg gripped and released): shipped "
            f"{false_alarm_text(shipped['false_alarms'], shipped['hours'])}, {shipped['runs_alarmed']} of {shipped['runs']} runs alarmed"
            + (f" within {span(firsts, '.0f')} s" if firsts else "")
            + f"; commissioned {false_alarm_text(commissioned['false_alarms'], commissioned['hours'])}. Leaks of "
            f"{span(apart['sizes_l_min'], 'g')} L/min on its {apart['leak_path']}: named on some rig in {len(named)} of {len(commissioned['named_l_min'])} "
            f"chambers ({', '.join(named) or 'none'}), detected in {len(detected)}; below {largest:g} L/min "
            + ("none named" if all(s in (None, largest) for v in commissioned["named_l_min"].values() for s in v)
               else "some named") + ". The shipped model's 95th percentile of 5 s mean residuals with the plant's effects switched "
            f"(rig {apart['effects_rig']}): " + ", ".join(f"{name} {e['residual_p95_l_min']:.1f}" for name, e in effects.items()) + " L/min")


def _discrepancy(suite: dict) -> str:
    rows = suite["rows"]
    single = [r for r in rows if len(r["hidden"]) == 1]
    own = [r for r in single if all(r["forms"].get(n) == first_form(n) for n in r["hidden"])]
    clean = [r for r in rows if not r["hidden"]]
    closed = [(r["validation_gap_before"] - r["validation_gap_after"]) / (r["validation_gap_before"] - r["plant_model_gap"])
              for r in rows if r["hidden"] and r["validation_gap_before"] > r["plant_model_gap"]]
    with_forms = [r for r in rows if r["forms"]]
    return (f"the right families in {sum(r['right'] for r in rows)}/{len(rows)} rows ({len({n for r in own for n in r['hidden']})} "
            f"effects in their own form, {len(single) - len(own)} other forms, {len(rows) - len(single) - len(clean)} pairs, "
            f"clean data: {'none named' if not any(r['named'] for r in clean) else 'effects named'}), the right form in "
            f"{sum(r['form_right'] for r in with_forms)}/{len(with_forms)} rows whose effects have forms, removable gap closed "
            f"{_pct(closed)} % in every row with an effect, "
            f"{span([r['wall_s'] for r in rows], '.0f')} s per 60 s bag")


def _mems(mems: dict) -> str:
    ours, paper, delays = mems["table_1"], mems["paper"]["table_1"], mems["delays_s"]
    above = ", ".join(f"{_signed([_above(ours['mems'][c], ours['encoder'][c])])} p_{c[1]}" for c in ("pA", "pB"))
    later = ", ".join(f"{delays[f]['mems_minus_encoder']:.1f} s on the {what} (MEMS detected "
                      f"{delays[f]['mems']['detected']}/{delays[f]['mems']['runs']})"
                      for f, what in (("external_leakage_b", "B leak"), ("internal_leakage", "internal leak")))
    return (f"simulated plants close to the model, P-III's thresholds and the complementary filter in the loop: fault-free "
            f"MEMS residuals above the encoder's by {above}; ours {_pct([ours[s][c] / paper[s][c] for s in ours for c in ours[s]])} "
            f"% of P-III's size (our plant is nearer its model than P-III's rig was); MEMS later by {later}")


def _half_cycle(trajectories: dict) -> str:
    methods = trajectories["execution"]["half_cycle"]

    def above(key: str) -> str:
        return _pct([_above(r["ls"][key], methods["dp_ls"]["ls"][key]) for m, r in methods.items() if m.startswith("pinv_")])

    return f"on our placeholder geometry the pseudo-inverses are {above('planned_J')} % above DP (LS) planned and {above('executed_J')} % executed"


def _tracking_span(trajectories: dict) -> str:
    errors = _tracking_errors(trajectories)
    below = sum(e < P_VI_TRACKING_M[0] for e in errors)
    return f"ours {span(errors, '.3f')} m on the simulated crane; {below} of {len(errors)} runs below P-VI's smallest"


def _natural_frequency() -> str:
    """Computed from the shipped SAM config at docs time: a model figure, not a benchmark's."""
    from hydro_ros.contract.config import default_config_path
    from hydro_ros.contract.machine import load_machine_config
    from hydro_ros.models.sam import SamModel
    from hydro_ros.models.steady_state import hydraulic_natural_frequency

    machine = load_machine_config(default_config_path("sam"))
    model = SamModel(machine)
    positions = np.linspace(0.0, machine.first.cylinder.stroke, 401)
    frequencies = np.array([hydraulic_natural_frequency(model, x) for x in positions])
    above = positions[frequencies > P_I_NATURAL_FREQUENCY_HZ]
    return (f"with the INFERRED hose values the two-chamber formula gives ≤ {P_I_NATURAL_FREQUENCY_HZ:g} Hz only for x ≥ "
            f"{above.max():.2f} m; towards full retraction the small chamber-A volume gives up to {frequencies.max():.1f} Hz. "
            f"The values are kept because the contract fixes them")


def _savings_map(savings: dict, mounts: dict) -> str:
    rows = [r for r in savings["rows"] if r["feasible"]]

    def saved(lines: str) -> list[float]:
        return [r[f"saving_{cost}"] for r in rows if r["path"].startswith(lines) for cost in ("cp", "ls")]

    def ratios(lines: str) -> list[float]:
        return [value for key, row in mounts["summary"].items() if key.startswith(lines) for value in (row["least"], row["greatest"])]

    reached = mounts["geometries_almost_twice"]
    geometries = len(mounts["geometries"])
    return (f"on our placeholder geometry, P-VI's lines moved across the workspace, DP against the better pseudo-inverse within "
            f"limits: horizontal lines save {_pct(saved('horizontal'))} %, vertical lines {_signed(saved('vertical'))} (below "
            f"zero where the tilt limit binds: the DP's grid). At most {_pct([max(saved(''))])} % anywhere, where P-VI's factor "
            f"of two would be 50 %. The missing mounts are not the cause: over {geometries} geometries (the lift's "
            f"{mounts['family_sizes']['lift']} buildable triangle mounts and the tilt's {mounts['family_sizes']['tilt']}, each "
            "spanning its stroke over its joint's range, alone and with their extremes combined), the better pseudo-inverse needs "
            f"{span(ratios('vertical'), '.2f')}x the DP's energy on vertical lines at x 4.5, 6 and 7.5 m and "
            f"{span(ratios('horizontal'), '.2f')}x on the horizontal path; {reached} of them reach {mounts['almost_twice_at']:g}x. "
            "From the smallest start the vertical lines ride the tilt's joint limit, which no mount moves; P-VI's tilt four-bar, "
            "its start and its path positions remain unknown")


CLAIMS: list[Claim] = [
    Claim("5.27e-9 m³/(s·Pa^½) = 1 L/min at 10 MPa (P-I)", "REPRODUCED (test)", "the model's leak coefficient",
          tests=("test_sam_model.py::test_leak_coefficient_matches_p1_calibration",)),
    Claim("B_eff inside P-I's 300-1200 MPa", "REPRODUCED (test)",
          "~0.42 GPa retracted, ~1.2 GPa extended with the SAM config's INFERRED hose values",
          tests=("test_sam_model.py::test_bulk_modulus_grows_with_extension",)),
    Claim("steady pressures of eqs. (39)-(40), p_A ~7-8 MPa holding the load (P-I)", "REPRODUCED (test)",
          "the model settles at the equations' p_A and p_B",
          tests=("test_sam_model.py::test_step_extension_reaches_analytic_steady_pressures",)),
    Claim(f"≤ {P_I_NATURAL_FREQUENCY_HZ:g} Hz maximum hydraulic natural frequency (P-I Fig. 4)", "PARTLY", _natural_frequency,
          tests=("test_sam_model.py::test_natural_frequency_within_seed_maximum_over_the_upper_stroke",)),
    Claim("UKF configuration α = 0.001, β = 2, κ = 0: Wm0 ≈ −1e6, Wi = 1.25e5 (P-II eq. 21)", "REPRODUCED (test)",  # noqa: RUF001 (the paper's symbols)
          "the same weights", tests=("test_fdi.py::test_unscented_weights_are_those_of_p2_eq21",)),
    Claim("adaptive threshold ±(0.012 + 4e-4 µ_p²) MPa per chamber (P-II eq. 25); P-III 0.015 / 0.023",
          "REPRODUCED: implemented as configuration", _threshold, files=("commissioning",)),
    Claim("fault-pattern signs of P-II Table 3 (ext A: r_pA↓; ext B: r_pB↓; internal: r_pA↓ r_pB↑; too small with u_c > 0: "
          "r_pA↓ r_pB↑; too large: reversed)", "REPRODUCED", "on simulated data: the shipped bags and Table 3's procedure",
          tests=("test_fdi.py::test_isolation_follows_table_3_and_its_procedure",
                 "test_fdi.py::test_shipped_bags_are_isolated_after_onset_and_silent_before")),
    Claim("r_pB crosses before r_pA for an internal leak (P-II: by ~3 s)", "PARTLY: the order reproduced, the lead shorter",
          "`bags/internal_leakage`, paper c0: r_pB crosses at 11.8 s, r_pA first at 12.5 s and for good at 13.9 s (the "
          "isolation at 14.9 s adds the 1 s settle): a lead of 0.7-2.1 s", by_hand="the crossing times, read from `bags/internal_leakage`"),
    Claim("too-small opening isolated only after a command sign change; too-large at once; stuck closed by magnitude "
          "(P-II §4.2)", "PARTLY: in kind, not in time", _valve_faults, files=("fdi_eval",),
          tests=("test_fdi.py::test_isolation_follows_table_3_and_its_procedure",
                 "test_fdi.py::test_shipped_bags_are_isolated_after_onset_and_silent_before")),
    Claim("smallest detectable leaks 0.17-0.40 L/min external, < 0.5 L/min internal",
          "PARTLY: not uncommissioned; after commissioning", _smallest_leaks, files=("fdi_eval", "commissioning")),
    Claim("MEMS angle within ±0.05° (P-III)", "REPRODUCED (test)", "for the INFERRED noise levels",
          tests=("test_mems.py::test_complementary_filter_removes_gyro_bias_and_follows_motion",)),
    Claim('P-IV: pressure-sensor biases of 0.3-0.5 MPa detectable "in some cases"; positive biases isolated with high accuracy',
          "PARTLY: in kind, not in time", _sensor_biases, files=("fdi_parity_eval",)),
    Claim("P-IV: only a subset of the fault list is detectable (P-IV's claim is about detection)", "REPRODUCED", _detectable,
          files=("fdi_parity_eval",)),
    Claim("P-I GSA rankings and interaction sums", "PARTLY: not the parameter rankings of p_A and p_B", _gsa, files=("gsa", "gsa_convergence")),
    Claim("DP: IK/FK exact, CP optimum load-independent, acceleration limits cost energy, a new start needs only a forward "
          "pass (the planner's claims of P-V and P-VI)", "REPRODUCED (tests)", "one test each",
          tests=("test_planning_models.py::test_inverse_kinematics_inverts_forward_kinematics_at_all_levels",
                 "test_dp.py::test_cp_optimum_is_load_independent_and_ls_optimum_is_not",
                 "test_dp.py::test_acceleration_limits_cost_energy",
                 "test_dp.py::test_policy_runs_forward_from_another_start_without_a_new_backward_pass")),
    Claim("DP vs conventional methods +15-30 % (P-V, P-VI)", "PARTLY: not on the vertical placeholder from the smallest start",
          _dp_vs_conventional, files=DP_SMALLEST_START + DP_MIDDLE_START),
    Claim("P-V Figs. 8/10: the DP's energy converges as its grid is refined", "PARTLY: not where the LS optimum rides the vertical "
          "path's moving limit edge (placeholder geometry)", _grid_convergence, files=("dp",), part="convergence"),
    Claim("P-V, P-VI: the DP's answer is the global optimum of its cost (issue 55's certificate: never above a feasible "
          "baseline in its own cost by more than 0.5 %)", "PARTLY: the DP on its full grid not on vertical lines, where the optimum "
          "rides a moving limit edge or needs a finer velocity grid (a polish alone leaves some in a local minimum above the "
          "pseudo-inverses); planned again on a grid narrowed around the best feasible baseline and polished, on every case "
          "(the row says by how much): a certificate for the refined DP, not for the full grid's; the planner serves the refined "
          "DP (planning.certify, held to the pseudo-inverses only)", _certificate,
          files=(*DP_SMALLEST_START, *DP_MIDDLE_START, "savings_map", "dp"), part="polish"),
    Claim("P-V: a global method beats local optimisation, the problem having local minima (the case for DP)",
          "NOT: on the K70M placeholder paths the CP problem looks unimodal; every seed the direct method converges from ends "
          "on one optimum, which DP (CP) matches but does not beat", _multistart, files=("dp",), part="multistart"),
    Claim("P-V Table 2/3 shape: DP(CP) best CP, DP(LS) best LS, DIDO within 0.3 %", "PARTLY", _table_shape,
          files=DP_SMALLEST_START, by_hand="the 2x-grid vertical run, which writes no result file"),
    Claim(f"P-VI Table 4 tracking errors ({P_VI_TRACKING_M[0]}-{P_VI_TRACKING_M[1]} m, CP better than LS)", "PARTLY: in scale", _tracking,
          files=("trajectories",)),
    Claim("P-VI: the DP's energy saving survives closed-loop execution", "REPRODUCED: on the simulated crane", _closed_loop,
          files=("trajectories",)),
    Claim("RP2: fault detection and isolation on a multi-actuator machine (the papers test it on the 1-DOF SAM)",
          "PARTLY: in simulation, on the model's own equations with its numbers drawn off", _multi_actuator, files=("crane_monitoring", "crane_commissioning")),
    Claim("commissioning makes the monitor quiet on a machine unlike its model (not a paper result: P-II and P-III tune "
          "c0 on their own rig)", "OURS: shown in simulation, on a plant written apart", _arm_commissioning, files=("arm_commissioning",),
          tests=("test_independent_arm.py::test_commissioned_from_the_minimum_the_arm_is_quiet_at_work_it_never_did_and_names_its_leaks",)),
    Claim("the same for the SAM: P-II's rig built apart from its model (its load as one link)", "OURS: shown in simulation, on a "
          "plant written apart", _arm_commissioning, files=("sam_commissioning_apart",),
          tests=("test_commissioning.py::test_after_commissioning_payload_steps_raise_no_alarm_and_each_fault_is_named",)),
    Claim("P-II's leak detection as a curve: false alarms against detection over the threshold, and detection delay against "
          "leak size with intervals (P-II reports single experiments)", "OURS: shown in simulation, on a plant written apart",
          _roc, files=("roc",)),
    Claim("false alarms per hour of fault-free work, per shipped config (not a paper result: P-III's fault-free runs are six "
          "experiments of 20-70 s)", "OURS: shown in simulation, on plants written apart", _fault_free_hours, files=("fault_free_hours",)),
    Claim("the crane built apart: commissioning on its own work makes the monitor quiet (not a paper result; RP2 on a plant "
          "written apart)", "OURS: shown in simulation, on a plant written apart; a gross-leak detector (2 L/min) on this build",
          _crane_apart, files=("crane_apart",),
          tests=("test_arm_cylinders.py::test_the_crane_built_apart_commissioned_on_its_own_work_is_quiet_and_names_two_litres_but_not_below_the_shipped",)),
    Claim("model-discrepancy workflow (not a paper result; thesis §6.4 asks for it)", "OURS: shown in simulation", _discrepancy,
          files=("discrepancy_suite",)),
    Claim("P-III Table I (fault-free residual RMS, MEMS above the encoder: +6 % p_A, +59 % p_B), Table II (the fault "
          "experiments' RMS) and its delays (MEMS 6 s later on the B leak, 0.3 s on the internal leak)", "PARTLY", _mems,
          files=("mems",), tests=("test_mems.py::test_p3_tables_the_mems_residuals_exceed_the_encoders_and_both_find_the_leaks",)),
    Claim("P-VI: on the half cycle the LS methods are similar", "CONTRADICTED", _half_cycle, files=("trajectories",)),
    Claim(f"P-VI Table 4 tracking error span {P_VI_TRACKING_M[0]}-{P_VI_TRACKING_M[1]} m", "PARTLY", _tracking_span,
          files=("trajectories",)),
    Claim('P-VI: "almost twice" the LS energy of the pseudo-inverses on its vertical path; where the telescope\'s redundancy pays',
          "NOT: on none of a grid of buildable triangle mounts of the lift and tilt either", _savings_map, files=("savings_map", "mount_sweep")),
]


@dataclass(frozen=True)
class ResearchProblem:
    """One of the thesis's research problems (its §1.1; answered in its §5) and what hydro_ros does about it."""

    name: str
    thesis: str  # how the thesis answers it, by publication
    package: str  # what of it hydro_ros does, and where
    tests: tuple[str, ...]  # <file in test/>::<function> that show it here
    real_machine: str  # what only a real machine can show


RESEARCH_PROBLEMS = (
    ResearchProblem("RP1 load-independency: no knowledge of the payload", "P-II-P-IV: the cylinders' motion from joint "
                    "sensors replaces their motion dynamics (§5.1)", "the UKF and the parity equations take piston position and "
                    "velocity from `/joint_states`; no load enters `fdi/` (a machine's `load` and `arm` masses are the "
                    "simulator's and the planner's, never the monitor's)",
                    ("test_commissioning.py::test_after_commissioning_payload_steps_raise_no_alarm_and_each_fault_is_named",),
                    "payloads of real work and the joint sensors' own errors"),
    ResearchProblem("RP2 general applicability of the monitoring: multi-actuator, proportional and mobile valves",
                    "P-II (proportional valves), P-III (a MEMS sensor for the encoder), P-IV (mobile valves) (§5.2)",
                    "any number of cylinders from one machine description; the UKF for proportional valves, the parity equations "
                    "for mobile ones, a MEMS motion sensor; a maker's own machine and bus (DBC)",
                    ("test_arm_cylinders.py::test_a_leak_is_isolated_to_its_cylinder_while_the_crane_works_its_path",
                     "test_commissioning.py::test_mobile_valve_commissioning_fits_the_notches_from_the_pilot_pressures_and_p_iv_thresholds",
                     "test_own_machine.py::test_own_bus_commissioning_and_a_leak_named_on_its_second_cylinder",
                     "test_mems.py::test_p3_tables_the_mems_residuals_exceed_the_encoders_and_both_find_the_leaks"),
                    "a real mobile valve's hydro-mechanics against the reduced model; which pressures a given machine measures"),
    ResearchProblem("RP3 high FDI performance, experimentally evaluated", "P-II-P-IV: leaks down to 0.17 L/min, sensor biases "
                    "below 0.5 MPa, isolation by residual patterns, on the test bench (§5.3)", "detection, the isolation tables "
                    "and adaptive thresholds, commissioning on a machine's own recordings, evaluated in simulation on plants "
                    "written apart from the model (rows above); not experimentally",
                    ("test_fdi.py::test_an_internal_leak_from_b_to_a_is_isolated_by_table_3_row_4",
                     "test_independent_arm.py::test_commissioned_from_the_minimum_the_arm_is_quiet_at_work_it_never_did_and_names_its_leaks"),
                    "the experimental evaluation RP3 asks for: false-alarm rates and detection limits of real machines"),
    ResearchProblem("RP4 energy-optimal redundancy resolution for LS and CP systems", "P-V, P-VI: optimal control problems solved "
                    "globally by DP over the redundant cylinder, CP and LS cost functions (§5.4)", "the DP with the CP, LS and "
                    "actuator-energy costs, checked against the direct method and the pseudo-inverses; its grid convergence "
                    "measured on every K70M path (rows above; the full grid is not certified where the optimum rides a moving "
                    "limit edge or needs finer velocity nodes; planned again around the best feasible baseline and polished, "
                    "within 0.5 % of it on every case); the direct method from many seeds finds one optimum per K70M path, so "
                    "there the global search buys no energy over a local one (`bench/dp.py` multistart)",
                    ("test_dp.py::test_cp_optimum_is_load_independent_and_ls_optimum_is_not",
                     "test_dp.py::test_direct_collocation_converges_near_the_dp_optimum",
                     "test_dp.py::test_on_a_line_where_the_full_grid_dp_is_above_a_pseudo_inverse_the_dp_around_it_is_not"),
                    "nothing for the optimisation itself (a claim about the model); the energies of a real crane's geometry, "
                    "whose mount constants the thesis does not give"),
    ResearchProblem("RP5 general applicability of the redundancy resolution: 3-DOF and 4-DOF (RRP, RRRP)", "P-V (a 3-DOF "
                    "crane), P-VI (the 4-DOF K70M) (§5.5)", "any chain of three planar joints redundant in one of them, a slewing "
                    "base under it: the K70M, crane3dof and an excavator's boom, arm and bucket (RRR)",
                    ("test_redundant_arm.py::test_dp_plans_the_excavators_paths_within_its_limits_on_one_branch_and_beats_the_pseudo_inverses_in_ls",),
                    "nothing for the kinematics; a real machine's geometry"),
    ResearchProblem("RP6 high performance within the actuators' limits, experimentally against conventional methods",
                    "P-V in simulation, P-VI on the K70M: 15-30 % less energy than the pseudo-inverses within every limit (§5.6)",
                    "every method's position, velocity and acceleration limits checked; the trajectories executed on a "
                    "simulated closed loop with the valves' dead zones, delays and a payload, and ranked as planned",
                    ("test_execution.py::test_executed_energies_rank_like_the_planned_ones",
                     "test_dp.py::test_forward_pass_keeps_every_limit_and_the_path_and_matches_the_predicted_cost"),
                    "P-VI's experiment itself: energies measured on a real crane"),
)


def research_problems_markdown() -> str:
    lines = ["| research problem (thesis §1.1) | the thesis's answer | hydro_ros | shown by | needs a real machine for |",
             "|---|---|---|---|---|"]
    for problem in RESEARCH_PROBLEMS:
        cells = (problem.name, problem.thesis, problem.package, "; ".join(f"`{test}`" for test in problem.tests), problem.real_machine)
        escaped = (cell.replace("|", "\\|") for cell in cells)
        lines.append(f"| {' | '.join(escaped)} |")
    return "\n".join(lines)


def _ours(claim: Claim, results: dict[str, Any]) -> str:
    if isinstance(claim.ours, str):
        return claim.ours
    absent = [name for name in claim.files if name not in results]
    if absent:
        return f"{MISSING} (no {', '.join(f'`{name}.json`' for name in absent)})"
    try:
        return claim.ours(*(results[name] for name in claim.files))
    except KeyError as missing:
        return f"{MISSING} (no {missing})"


def reproduction_markdown() -> str:
    results = read_results()
    lines = ["Status: **REPRODUCED**, **PARTLY** (and where not), **NOT**, **CONTRADICTED** or **NOT ATTEMPTED**; **OURS** is a "
             f"claim of the package's own that no paper makes. A false-alarm rate is given with its {INTERVAL} (Garwood, "
             "two-sided), from the count and the monitored hours its result file holds.", "",
             "| claim (the paper's figures) | status | ours | from (commit) |", "|---|---|---|---|"]
    for claim in CLAIMS:
        by_commit: dict[str, list[str]] = {}
        for name in claim.files:
            by_commit.setdefault(commit_of(results.get(name), claim.part), []).append(f"`{name}.json`")
        sources = ([f"{', '.join(names)} ({commit})" for commit, names in by_commit.items()] + [f"`{test}`" for test in claim.tests]
                   + ([f"typed by hand: {claim.by_hand}"] if claim.by_hand else []))
        status = f"**{claim.verdict}**{claim.status[len(claim.verdict):]}"
        cells = (cell.replace("|", "\\|") for cell in (claim.claim, status, _ours(claim, results), "; ".join(sources)))
        lines.append(f"| {' | '.join(cells)} |")
    lines += ["", "The thesis's research problems (RP1-RP6), how it answers each (its §5), and what of each hydro_ros answers "
              "without a real machine:", "", research_problems_markdown()]
    return "\n".join(lines)
