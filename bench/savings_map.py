"""Where the K70M's telescope redundancy saves energy (make bench): DP against the better pseudo-inverse on P-VI's
vertical and horizontal lines moved across the workspace, CP and LS. Writes --out (bench/results/savings_map.json), a table
(.md) and the map (.png: each line drawn where it lies, coloured by the DP's CP saving)."""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
from tqdm import tqdm

from hydro_ros.contract.config import default_config_path
from hydro_ros.models.crane import load_crane
from hydro_ros.studies.savings_map import line_paths, savings
from hydro_ros.tooling.benchresults import write_result

VERTICAL_X = (3.5, 4.5, 5.5, 6.5, 7.5)
VERTICAL_Y0 = (-1.5, -0.5, 0.5)
HORIZONTAL_Y = (-1.5, -0.5, 0.5, 1.5, 2.5)
HORIZONTAL_X0 = (2.0, 3.0, 4.0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/savings_map.json")
    args = parser.parse_args()
    crane, config = load_crane(default_config_path("k70m"))
    paths = line_paths(VERTICAL_X, VERTICAL_Y0, HORIZONTAL_Y, HORIZONTAL_X0)
    with tqdm(total=len(paths), unit="line", desc="savings map") as bar:
        rows = savings(crane, config, paths, progress=lambda _: bar.update())
    out = Path(args.out)
    lines = ["| line | from | to | DP saving CP | DP saving LS | pseudo-inverses within limits |", "|---|---|---|---|---|---|"]
    for row in rows:
        if row["feasible"]:
            lines.append(f"| {row['path']} | {row['start'][:2]} | {row['end'][:2]} | {row['saving_cp']:+.1%} | {row['saving_ls']:+.1%} "
                         f"| {', '.join(row['pinv_within_limits']) or 'neither'} |")
        else:
            lines.append(f"| {row['path']} | {row['start'][:2]} | {row['end'][:2]} | not followed | {row['reason'][:60]} | |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharey=True)
    for ax, cost in zip(axes, ("cp", "ls")):
        colour = plt.get_cmap("viridis")
        for row in rows:
            (x0, y0), (x1, y1) = row["start"][:2], row["end"][:2]
            if x0 == x1:  # the vertical lines of one x from different heights overlap: drawn side by side
                x0 = x1 = x0 + 0.12 * VERTICAL_Y0.index(y0)
            else:  # ... as the horizontal ones of one height from different starts
                y0 = y1 = y0 + 0.12 * HORIZONTAL_X0.index(row["start"][0])
            if row["feasible"]:
                ax.plot([x0, x1], [y0, y1], color=colour(min(max(row[f"saving_{cost}"] / 0.4, 0.0), 1.0)), lw=4)
            else:
                ax.plot([x0, x1], [y0, y1], color="lightgrey", lw=1, ls=":")
        ax.set_title(f"{cost.upper()} energy: DP saving over the better pseudo-inverse", fontsize=9)
        ax.set_xlabel("x [m]")
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("y, up [m]")
    fig.colorbar(plt.cm.ScalarMappable(cmap="viridis", norm=plt.Normalize(0, 40)), ax=axes, label="saving [%] (grey dotted: not followed)")
    fig.savefig(out.with_suffix(".png"), dpi=100)
    write_result(out, {"machine": "k70m", "rows": rows})  # last: a stamped file stands for a finished step
    print(out.with_suffix(".md").read_text())


if __name__ == "__main__":
    main()
