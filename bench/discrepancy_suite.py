"""Hidden-effect suite of the discrepancy workflow (part of `make bench`): every vocabulary effect at a
realistic magnitude, and clean data, on plants with 40 % of fdi-eval's mismatch and sensor noise.

Each row also gives the floor: the validation gap of the plant's own model (its mismatch drawn, the
effect at its true value), the best any fitted model can do on that bag. The valve delay and the
entrained air also run at a second, larger size: at the first, little more than the plant's
mismatch, half the gap before lies near that floor.

Writes bench/discrepancy_suite.json and prints a markdown table.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from hydro_ros.bags.reader import BagData, read_bag  # noqa: E402
from hydro_ros.contract.config import default_config_path  # noqa: E402
from hydro_ros.contract.machine import Machine, load_machine_config  # noqa: E402
from hydro_ros.studies.discrepancy import FIT_SHARE, Recording, gap, run, simulate  # noqa: E402
from test.test_discrepancy import hidden_effect_bag, plant_config  # noqa: E402

SUITE = [(None, 0.0), ("internal_leakage", 1.5), ("external_leakage_a", 2.0), ("external_leakage_b", 2.0),
         ("valve_deadzone", 0.08), ("spool_offset", 0.04), ("valve_delay", 0.05), ("valve_delay", 0.1), ("valve_flow_gain", 0.25),
         ("entrained_air", 0.03), ("entrained_air", 0.045), ("coulomb_friction", 3000.0), ("viscous_friction", 1.5e5),
         ("payload_mass", 150.0), ("pressure_sensor_bias_a", 5e5), ("pressure_sensor_bias_b", 5e5)]


def floor(config: Machine, data: BagData, effect: str | None, value: float) -> float:
    """Validation gap of the plant's own model on the validation part run() uses."""
    rec = Recording.from_bag(data, config)
    validation = rec.part(slice(int(FIT_SHARE * len(rec.times)), None))
    return gap(simulate(plant_config(config, effect, value), validation))


def main() -> int:
    config = load_machine_config(default_config_path("sam"))
    rows = []
    for effect, value in SUITE:
        with tempfile.TemporaryDirectory() as tmp:
            data = read_bag(hidden_effect_bag(config, Path(tmp) / "bag", effect, value, duration=60.0))
            start = time.perf_counter()
            report = run(data, config, Path(tmp) / "out")
            wall = time.perf_counter() - start
            best = floor(config, data, effect, value)
        named = [e["name"] for e in report["effects"]]
        rows.append({"hidden": effect, "value": value, "named": named,
                     "named_value": report["effects"][0]["parameters"]["value"] if named else None,
                     "right": (named[:1] == [effect]) if effect else not named,
                     "validation_gap_before": report["validation_gap"]["before"], "validation_gap_after": report["validation_gap"]["after"],
                     "plant_model_gap": best, "wall_s": wall})
        print(rows[-1], flush=True)
    Path(__file__).with_name("discrepancy_suite.json").write_text(json.dumps(rows, indent=2) + "\n")
    print("| hidden effect | size | named | fitted | validation gap before -> after | change | plant's own model | runtime (60 s bag) |")
    print("|---|---|---|---|---|---|---|---|")
    for r in rows:
        fitted = "-" if r["named_value"] is None else f"{r['named_value']:.3g}"
        change = r["validation_gap_after"] / r["validation_gap_before"] - 1.0
        print(f"| {r['hidden'] or 'none'} | {r['value']:g} | {', '.join(r['named']) or 'none'} | {fitted} | "
              f"{r['validation_gap_before']:.2f} -> {r['validation_gap_after']:.2f} | {change:+.0%} | {r['plant_model_gap']:.2f} | "
              f"{r['wall_s']:.0f} s |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
