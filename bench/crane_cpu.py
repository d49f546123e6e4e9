"""fdi_node on the K70M at 1 kHz (make bench): CPU share of one core with every cylinder batched, against the contract's
per-sample topics in the same run.

Both are real processes on a private localhost domain: plant_sim's crane mode -> fdi_node.
- sample blocks: plant_sim publishes each tick's samples (10 ms, every column) as one PointCloud2 on
  /hydraulics/sample_block and no per-sample topics; fdi_node ``input:=sample_block``; real time.
- per-sample topics (the reference): the contract's 19 topics of the crane (joint states, valve commands,
  supply, LS, five pressures per cylinder); fdi_node ``input:=topics``. At 1 kHz these are ~19 000
  messages a second, more than either process carries on this machine, so plant_sim runs at 0.25 x real
  time and the CPU share is scaled to 1 kHz (x 4; rclpy's cost is per message).
Writes --out (bench/results/crane_cpu.json).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.processes import live_cpu_share  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402

K70M = REPO / "config" / "k70m.yaml"
TOPICS_REAL_TIME_FACTOR = 0.25
GOAL = 0.5  # of one core, the target for every cylinder at 1 kHz


def measure(domain: int, plant_args: list[str], fdi_input: str, measure_s: float) -> dict:
    commands = [["hydro_ros.nodes.plant_sim", "-p", f"config:={K70M}", *plant_args],
                ["hydro_ros.nodes.fdi_node", "-p", f"config:={K70M}", "-p", f"input:={fdi_input}"]]
    cpu, wall, v0, v1 = live_cpu_share(domain, commands, "hydro_ros/fdi/lift", "samples", measure_s)
    processed = int(v1["samples"]) - int(v0["samples"])
    return {"cpu_share_of_one_core": cpu, "samples_processed_per_s": processed / wall, "wall_s": wall,
            "gap_samples": int(v1["gap_samples"]), "incomplete_samples": int(v1["incomplete_samples"]),
            "out_of_order_dropped": int(v1["out_of_order_dropped"]), "undecodable_messages": int(v1["undecodable_messages"])}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/crane_cpu.json")
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    blocks = measure(153, ["-p", "sensor_topics:=none", "-p", "sample_blocks:=true"], "sample_block", args.seconds)
    per_sample = measure(154, ["-p", f"real_time_factor:={TOPICS_REAL_TIME_FACTOR}"], "topics", args.seconds)
    per_sample["cpu_share_at_1khz"] = per_sample["cpu_share_of_one_core"] / TOPICS_REAL_TIME_FACTOR
    result = {"cylinders": 3, "sample_rate_hz": 1000.0, "goal_share_of_one_core": GOAL, "sample_blocks": blocks,
              "per_sample_topics": per_sample,
              "ratio_blocks_to_topics": blocks["cpu_share_of_one_core"] / per_sample["cpu_share_at_1khz"]}
    write_result(Path(args.out), result)
    print(json.dumps(result, indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
