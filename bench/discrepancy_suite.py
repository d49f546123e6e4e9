"""Hidden-effect suite of the discrepancy workflow (part of `make bench`): every vocabulary effect at a
realistic magnitude in its own form, every other physical form of a family (names.EFFECT_FORMS),
pairs of simultaneous effects, and clean data, on plants with 40 % of fdi-eval's mismatch and
sensor noise.

Each row also gives the floor: the validation gap of the plant's own model (its mismatch drawn, the
effect at its true value), the best any fitted model can do on that bag. The valve delay and the
entrained air also run at a second, larger size: at the first, little more than the plant's
mismatch, half the gap before lies near that floor.

Writes bench/results/discrepancy_suite.json, its table and what it shows (.md beside it, which docs/discrepancy.md
shows) and bench/results/discrepancy_example.html (the report of EXAMPLE); ``--table`` writes the .md files from the
.json files and runs nothing.

Then the same workflow on data it was not written with: plain overlaps of 4, 6 and 8 % on the independent plant
(studies/independent_plant: its own forms, integrator and numbers), each with the fit gap along the overlap on the
screened segments and on all of them (bench/results/discrepancy_independent.json and .png; ``--independent`` runs only
these), and their table (.md). Its floor is the model with the rig's numbers (``nearest_model``).
"""

from __future__ import annotations

import argparse
import json
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hydro_ros.bags.reader import BagData, read_bag
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import Machine, load_machine_config
from hydro_ros.contract.names import first_form
from hydro_ros.studies.hidden_effects import hidden_effect_bag, hidden_effect_plant
from hydro_ros.studies.independent_plant import independent_plant_bag, nearest_model
from hydro_ros.tooling.benchresults import write_result
from hydro_ros.workflows.discrepancy import FIT_SHARE, SCREEN_EVERY, DiscrepancyReport, Recording, gap, run, simulate_recording
from hydro_ros.workflows.plots import plot_gap_profiles

RESULTS = Path(__file__).resolve().parent / "results"
OWN_FORM = [(None, 0.0), ("internal_leakage", 1.5), ("external_leakage_a", 2.0), ("external_leakage_b", 2.0),
            ("valve_deadzone", 0.08), ("spool_offset", 0.04), ("valve_delay", 0.05), ("valve_delay", 0.1), ("valve_flow_gain", 0.25),
            ("entrained_air", 0.03), ("entrained_air", 0.045), ("coulomb_friction", 3000.0), ("viscous_friction", 1.5e5),
            ("payload_mass", 150.0), ("pressure_sensor_bias_a", 5e5), ("pressure_sensor_bias_b", 5e5)]
# (hidden effects, their forms): every effect in its own form, each other form of a family, and pairs
SUITE: list[tuple[dict[str, float], dict[str, str]]] = [({name: value} if name else {}, {}) for name, value in OWN_FORM] + [
    ({"valve_deadzone": 0.08}, {"valve_deadzone": "overlap"}),
    ({"internal_leakage": 1.5}, {"internal_leakage": "laminar"}),
    ({"external_leakage_a": 2.0}, {"external_leakage_a": "laminar"}),
    ({"external_leakage_b": 2.0}, {"external_leakage_b": "laminar"}),
    ({"valve_delay": 0.05}, {"valve_delay": "lag"}),
    ({"coulomb_friction": 3000.0}, {"coulomb_friction": "stribeck"}),
    ({"external_leakage_a": 2.0, "coulomb_friction": 3000.0}, {}),
    ({"internal_leakage": 1.5, "viscous_friction": 1.5e5}, {"internal_leakage": "laminar"}),
    ({"valve_delay": 0.1, "valve_deadzone": 0.08}, {}),
]


def split(config: Machine, data: BagData) -> tuple[Recording, Recording]:
    """The fit and validation parts run() uses."""
    rec = Recording.from_bag(data, config)
    return rec.part(slice(0, int(FIT_SHARE * len(rec.times)))), rec.part(slice(int(FIT_SHARE * len(rec.times)), None))


def floor(plant_model: Machine, config: Machine, data: BagData) -> float:
    """Validation gap of the plant's own model on the validation part run() uses."""
    return gap(simulate_recording(plant_model, split(config, data)[1]))


def _form(name: str, forms: dict[str, str]) -> str | None:
    return forms.get(name, first_form(name))


EXAMPLE = ({"valve_delay": 0.1, "valve_deadzone": 0.08}, {})  # its report.html is kept as bench/results/discrepancy_example.html


def run_row(config: Machine, effects: dict[str, float], forms: dict[str, str], out_dir: Path) -> dict:
    """One row: the bag, the workflow on it, and the plant's own floor."""
    with tempfile.TemporaryDirectory() as tmp:
        data = read_bag(hidden_effect_bag(config, Path(tmp) / "bag", duration=60.0, forms=forms, also=effects))
        start = time.perf_counter()
        report = run(data, config, Path(tmp) / "out")
        wall = time.perf_counter() - start
        best = floor(hidden_effect_plant(config, forms=forms, also=effects), config, data)
        if (effects, forms) == EXAMPLE:
            shutil.copy(Path(tmp) / "out" / "report.html", out_dir / "discrepancy_example.html")
    return row(report, effects, forms, best, wall)


def row(report: DiscrepancyReport, effects: dict[str, float], forms: dict[str, str], plant_model_gap: float, wall: float) -> dict:
    """What a run on a bag with ``effects`` (in ``forms``) found, against the plant model's floor."""
    named = {e.name: e.to_json()["parameters"] for e in report.effects}
    return {"hidden": effects, "forms": {name: _form(name, forms) for name in effects if _form(name, forms)},
            "named": named, "right": set(named) == set(effects),
            "form_right": all(named[n].get("form") == _form(n, forms) for n in effects if n in named),
            "steps": [step.added for step in report.selection.steps if step.kept],
            "validation_gap_before": report.validation_gap.before, "validation_gap_after": report.validation_gap.after,
            "plant_model_gap": plant_model_gap, "wall_s": wall}


INDEPENDENT_OVERLAPS = (0.04, 0.06, 0.08)  # plain overlaps of the independent plant (an outside tester's 6 % and either side)
PROFILE_VALUES = np.linspace(0.0, 0.1, 11)


def independent_row(config: Machine, overlap: float) -> dict:
    """A 60 s bag of the independent plant with a plain ``overlap``: the workflow on it, the model with the rig's numbers
    as its floor, the dead zone's screened and refitted values and calibrations, and the fit gap along the overlap (the
    fitted model otherwise) on the screened segments and on all of them."""
    effects, forms = {"valve_deadzone": overlap}, {"valve_deadzone": "overlap"}
    with tempfile.TemporaryDirectory() as tmp:
        data = read_bag(independent_plant_bag(config, Path(tmp) / "bag", effects))
        start = time.perf_counter()
        report = run(data, config, Path(tmp) / "out")
        wall = time.perf_counter() - start
        fitted = load_machine_config(Path(tmp) / "out" / "model.yaml")
    fit = split(config, data)[0]

    def fit_gap(value: float, every: int) -> float:
        model = fitted.with_overrides({"effects": {**fitted.effects, "valve_deadzone": float(value)}, "effect_forms": forms})
        return gap(simulate_recording(model, fit, every))

    first = report.selection.steps[0]
    return row(report, effects, forms, floor(nearest_model(config, effects), config, data), wall) | {
        "screened": [r for r in first.screened if r["name"] == "valve_deadzone"],
        "refitted": [{"form": c.form, "value": c.value, "bic_gain": c.bic_gain} for c in first.candidates if c.name == "valve_deadzone"],
        "calibration": report.calibration, "joint_calibration": report.selection.calibration,
        "profile": {"values": PROFILE_VALUES.tolist(), "screened": [fit_gap(v, SCREEN_EVERY) for v in PROFILE_VALUES],
                    "all": [fit_gap(v, 1) for v in PROFILE_VALUES]}}


def independent(config: Machine, out_dir: Path) -> list[dict]:
    rows = [independent_row(config, overlap) for overlap in tqdm(INDEPENDENT_OVERLAPS, desc="independent plant", unit="bag")]
    plot_gap_profiles([r["profile"] | {"title": f"plain overlap {r['hidden']['valve_deadzone']:g}", "truth": r["hidden"]["valve_deadzone"],
                                       "named": r["named"].get("valve_deadzone", {}).get("value")} for r in rows],
                      out_dir / "discrepancy_independent.png")
    write_result(out_dir / "discrepancy_independent.json", {"plant": "hydro_ros.studies.independent_plant", "rows": rows})  # last
    return rows


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--out", type=Path, default=RESULTS / "discrepancy_suite.json",
                        help="the suite's file; discrepancy_independent.{json,png} and discrepancy_example.html are written beside it")
    parser.add_argument("--table", action="store_true", help="write the .md files from the .json files, run nothing")
    parser.add_argument("--independent", action="store_true", help="the independent plant's rows only")
    args = parser.parse_args()
    out_dir = args.out.parent
    if not args.table:
        config = load_machine_config(default_config_path("sam"))
        if not args.independent:
            rows = []
            for effects, forms in tqdm(SUITE, desc="discrepancy suite", unit="bag"):
                rows.append(run_row(config, effects, forms, out_dir))
                tqdm.write(json.dumps(rows[-1]))
            write_result(args.out, {"rows": rows})
        independent(config, out_dir)
    for path, markdown in ((args.out, suite_markdown), (out_dir / "discrepancy_independent.json", independent_markdown)):
        if path.is_file():
            path.with_suffix(".md").write_text(markdown(json.loads(path.read_text())["rows"]) + "\n")
            print(path.with_suffix(".md").read_text())
    return 0


def _hidden(r: dict) -> str:
    return ", ".join(f"{n} ({r['forms'][n]})" if n in r["forms"] else n for n in r["hidden"]) or "none"


def _named(r: dict) -> str:
    return ", ".join(f"{n} ({p['form']})" if "form" in p else n for n, p in r["named"].items()) or "none"


def _fitted(r: dict) -> str:
    return ", ".join(f"{p['value']:.3g}" for p in r["named"].values()) or "-"


def _gap(r: dict) -> str:
    return f"{r['validation_gap_before']:.2f} -> {r['validation_gap_after']:.2f}"


def _change(r: dict) -> float:
    return r["validation_gap_after"] / r["validation_gap_before"] - 1.0


def _size(r: dict) -> str:
    return ", ".join(f"{v:g}" for v in r["hidden"].values()) or "-"


def suite_markdown(rows: list[dict]) -> str:
    """The suite's table, then what it shows: families and forms named, the gap closed against the floor, the runtime."""
    lines = ["| hidden effect(s) (form) | size | named (form) | fitted | validation gap before -> after | change | plant's own model | "
             "runtime (60 s bag) |", "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {_hidden(r)} | {_size(r)} | {_named(r)} | {_fitted(r)} | {_gap(r)} | {_change(r):+.0%} | "
                     f"{r['plant_model_gap']:.2f} | {r['wall_s']:.0f} s |")
    effects = [r for r in rows if r["hidden"]]
    clean = [r for r in rows if not r["hidden"]]
    with_forms = [r for r in rows if r["forms"]]
    wrong_family = [f"{_hidden(r)}: named {_named(r)}" for r in rows if not r["right"]]
    wrong_form = [f"{_hidden(r)} {_size(r)}: named {_named(r)} at {_fitted(r)}, gap {_change(r):+.0%}, "
                  f"{r['validation_gap_after'] - r['plant_model_gap']:+.2f} from the floor" for r in with_forms if not r["form_right"]]
    # the share of the gap above the floor that the fit removed, where there was some to remove
    removable = [r for r in effects if r["validation_gap_before"] > r["plant_model_gap"]]
    closed = [(r["validation_gap_before"] - r["validation_gap_after"]) / (r["validation_gap_before"] - r["plant_model_gap"]) for r in removable]
    not_halved = [f"{_hidden(r)} {_size(r)}: {_gap(r)}, floor {r['plant_model_gap']:.2f}" for r in effects
                  if r["validation_gap_after"] > 0.5 * r["validation_gap_before"]]
    above = [r["validation_gap_after"] - r["plant_model_gap"] for r in effects]
    wall = [r["wall_s"] for r in rows]
    lines += ["", f"- the right family, and nothing else, in **{sum(r['right'] for r in rows)} of {len(rows)}** rows"
              + (f"; not in: {'; '.join(wrong_family)}" if wrong_family else ""),
              f"- the right form in {sum(r['form_right'] for r in with_forms)} of the {len(with_forms)} rows whose effects have forms"
              + (f"; not in: {'; '.join(wrong_form)}" if wrong_form else "")]
    if closed:
        lines.append(f"- the removable gap (before minus the floor) closed by {min(closed):.0%} to {max(closed):.0%} in the {len(removable)} "
                     f"rows with effects that had one (of {len(effects)})")
    lines += [f"- the gap at least halved in {len(effects) - len(not_halved)} of the {len(effects)} rows with effects"
              + (f" (not in: {'; '.join(not_halved)})" if not_halved else ""),
              f"- after the fit the validation gap lies {min(above):+.2f} to {max(above):+.2f} from the floor"
              + f" ({sum(x < 0 for x in above)} below it)"
              + "".join(f"; on clean data {_gap(r)} against {r['plant_model_gap']:.2f}" for r in clean),
              f"- runtime {min(wall):.0f} to {max(wall):.0f} s per 60 s bag"]
    return "\n".join(lines)


def independent_markdown(rows: list[dict]) -> str:
    """The independent plant's table: what was named at each overlap, the held-out gap and its floor."""
    lines = ["| plain overlap | named (form) | fitted | held-out gap before -> after | change | floor | runtime (60 s bag) |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {_size(r)} | {_named(r)} | {_fitted(r)} | {_gap(r)} | {_change(r):+.0%} | {r['plant_model_gap']:.2f} | "
                     f"{r['wall_s']:.0f} s |")
    off = [abs(p["value"] / r["hidden"][n] - 1.0) for r in rows for n, p in r["named"].items() if n in r["hidden"]]
    forms = sorted({form for r in rows for form in r["forms"].values()})
    lines += ["", f"- the right family in {sum(r['right'] for r in rows)} of {len(rows)}, the plant's form ({', '.join(forms)}) in "
              f"{sum(r['form_right'] for r in rows)}" + (f"; the size named within {max(off):.1%} of the truth" if off else "")]
    return "\n".join(lines)


if __name__ == "__main__":
    raise SystemExit(main())
