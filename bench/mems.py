"""P-III's Tables I and II and its detection delays, MEMS motion sensor against the encoder (make bench).
Writes --out (bench/results/mems.json), the table beside it (.md) and a bar chart (.png)."""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from hydro_ros.studies.mems import markdown, tables
from hydro_ros.tooling.benchresults import write_result


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/mems.json")
    parser.add_argument("--seeds", type=int, default=6, help="runs per case (P-III: six fault-free experiments)")
    args = parser.parse_args()
    result = tables(args.seeds)
    out = Path(args.out)
    out.with_suffix(".md").write_text(markdown(result))
    cases = [("I fault-free", result["table_1"], result["paper"]["table_1"])] + [
        (f"II {fault}", rows, result["paper"]["table_2"][fault]) for fault, rows in result["table_2"].items()]
    fig, axes = plt.subplots(1, len(cases), figsize=(4 * len(cases), 3.2))
    for ax, (title, ours, paper) in zip(axes, cases):
        labels = [f"{sensor} {residual}" for sensor in ours for residual in ours[sensor]]
        x = np.arange(len(labels))
        ax.bar(x - 0.2, [paper[s][r] for s in ours for r in ours[s]], 0.4, label="P-III")
        ax.bar(x + 0.2, [ours[s][r] for s in ours for r in ours[s]], 0.4, label="ours")
        ax.set_xticks(x, labels, rotation=30, fontsize=7)
        ax.set_title(f"Table {title}", fontsize=9)
        ax.set_ylabel("residual RMS [MPa]")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)
    write_result(out, result)  # last: a stamped file stands for a finished step
    print(markdown(result))


if __name__ == "__main__":
    main()
