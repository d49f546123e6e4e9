"""The K70M's missing lift and tilt mounts swept (make bench): what the DP saves over the pseudo-inverses on P-VI's vertical
and horizontal paths (the config's placeholder positions, and the vertical line moved to x = 4.5 and 7.5 m, its position
being a placeholder too) for every buildable triangle mount spanning its stroke over its joint's range
(hydro_ros.studies.mount_sweep), each family alone beside the config's other mount, then the four combinations of the
families' extreme closed-end angles. Asks whether any such geometry gives P-VI's "almost twice" on a vertical path.
Writes --out (bench/results/mount_sweep.json) and a PNG beside it.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib
import numpy as np
from tqdm import tqdm

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from hydro_ros.contract.config import default_config_path
from hydro_ros.models.crane import load_crane
from hydro_ros.studies.mount_sweep import MIN_ARM, MIN_DEAD_LENGTH, mount_family, one_at_a_time, sweep
from hydro_ros.studies.savings_map import line_paths, savings
from hydro_ros.tooling.benchresults import write_result

VERTICAL_X = (4.5, 7.5)  # [m] beside the config's 6.0
RATIOS = (0.2, 0.35, 0.5, 0.7, 0.9)  # l2 / l1
ANGLES = 8  # closed-end angles per family, across what keeps the triangle inside (0, pi)
ALMOST_TWICE = 1.8  # pseudo-inverse / DP energy counted as P-VI's "almost twice"


def families(crane_config) -> dict[str, list]:
    out = {}
    for name in ("lift", "tilt"):
        link = next(link for link in crane_config.mapping["arm"]["links"] if link["joint"] == name)
        joint_range = (float(link["range"][0]), float(link["range"][1]))
        actuator = crane_config.mapping["actuators"][name]
        sign = int(actuator["mount"].get("sign", 1))
        angles = np.linspace(0.05, math.pi - (joint_range[1] - joint_range[0]) - 0.02, ANGLES)
        out[name] = mount_family(joint_range, float(actuator["cylinder"]["stroke"]), sign, angles, RATIOS)
    return out


def ratio(row: dict, cost: str) -> float:
    """The better pseudo-inverse's energy over the DP's (P-VI's "almost twice" is ~2)."""
    return 1.0 / (1.0 - row[f"saving_{cost}"]) if row.get("feasible") else math.nan


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/mount_sweep.json")
    args = parser.parse_args()
    config_path = default_config_path("k70m")
    crane, crane_config = load_crane(config_path)
    paths = {"vertical": crane_config.paths["vertical"], "horizontal": crane_config.paths["horizontal"],
             **line_paths(VERTICAL_X, (0.0,), (), ())}
    configured = savings(crane, crane_config, paths)
    family = families(crane_config)
    geometries = one_at_a_time(family)
    with tqdm(total=len(geometries), unit="geometry", desc="mount sweep") as bar:
        swept = sweep(config_path, geometries, paths, progress=lambda _: bar.update())
    summary = {}
    for path_index, path in enumerate(paths):
        for cost in ("cp", "ls"):
            values = [ratio(entry["rows"][path_index], cost) for entry in swept]
            finite = [v for v in values if math.isfinite(v)]
            summary[f"{path}_{cost}"] = {"configured": ratio(configured[path_index], cost), "least": min(finite), "greatest": max(finite),
                                         "geometries": len(finite), "infeasible": len(values) - len(finite),
                                         "almost_twice": sum(v >= ALMOST_TWICE for v in finite)}
    result = {"machine": "k70m", "paths": {name: [entry["start"], entry["segments"][-1]["to"]] for name, entry in paths.items()},
              "ratio": "better pseudo-inverse energy / DP energy (P-VI: almost 2 on vertical)",
              "almost_twice_at": ALMOST_TWICE, "rules": {"min_dead_length_m": MIN_DEAD_LENGTH, "min_arm_m": MIN_ARM},
              "family_sizes": {name: len(f) for name, f in family.items()}, "summary": summary,
              "geometries_almost_twice": sum(any(ratio(row, cost) >= ALMOST_TWICE for row in entry["rows"] for cost in ("cp", "ls"))
                                             for entry in swept),
              "configured": configured, "geometries": swept}
    out = Path(args.out)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
    for ax, name in zip(axes, family, strict=True):
        alone = [e for e in swept if list(e["mounts"]) == [name]]
        for path_index, path in enumerate(paths):
            for cost, marker in (("cp", "o"), ("ls", "s")):
                ax.scatter([e["mounts"][name]["theta_closed"] for e in alone], [ratio(e["rows"][path_index], cost) for e in alone],
                           marker=marker, label=f"{path} {cost.upper()}", alpha=0.7)
        ax.axhline(ALMOST_TWICE, color="red", lw=1, ls="--")
        ax.set_xlabel(f"{name}: triangle angle with the cylinder closed [rad]")
        ax.set_title(f"{name} mount swept ({len(alone)} buildable), the other as configured", fontsize=9)
    axes[0].set_ylabel("pseudo-inverse / DP energy")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)
    write_result(out, result)  # last: a stamped file stands for a finished step
    for key, row in summary.items():
        print(f"{key}: configured {row['configured']:.3f}, swept {row['least']:.3f}-{row['greatest']:.3f} over {row['geometries']} "
              f"geometries ({row['infeasible']} infeasible), >= {ALMOST_TWICE}: {row['almost_twice']}")


if __name__ == "__main__":
    main()
