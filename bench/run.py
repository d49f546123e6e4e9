"""`make bench`: SAM model speed and bag read throughput, each against a reference in the same run.

Writes bench/results.json and bench/results.png.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import time
from pathlib import Path

import numpy as np

from hydro_ros.bags.reader import mcap_file, read_bag
from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.config import default_config_path, load_machine_config
from hydro_ros.models.sam import SamModel, SamPlant
from hydro_ros.sim.scenario import Scenario, run_blocks


def model_speed(config: dict, seconds: float = 60.0) -> dict:
    model = SamModel(config)
    SamPlant(model).advance(10, commands=np.zeros(10))  # JIT warm-up
    plant = SamPlant(model)
    n = int(seconds * model.sample_rate)
    commands = 0.6 * np.sin(np.linspace(0, 40, n))
    start = time.perf_counter()
    plant.advance(n, commands=commands)
    wall = time.perf_counter() - start
    return {"simulated_s": seconds, "wall_s": wall, "real_time_factor": seconds / wall, "substeps": model.substeps,
            "target_real_time_factor": 50.0}


def bag_read(config: dict, seconds: float = 30.0) -> dict:
    from rosbags.highlevel import AnyReader

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench"
        with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
            for _, _, block in run_blocks(config, Scenario(seconds, (), seed=1)):
                writer.write("boom", block)
        start = time.perf_counter()
        data = read_bag(path)
        ours = time.perf_counter() - start
        start = time.perf_counter()
        with AnyReader([path]) as reader:
            count = sum(1 for c, _, raw in reader.messages() if reader.deserialize(raw, c.msgtype) is not None)
        reference = time.perf_counter() - start
        size = mcap_file(path).stat().st_size
    assert count == data.message_count
    return {"messages": data.message_count, "hydro_ros_msgs_per_s": data.message_count / ours,
            "rosbags_anyreader_msgs_per_s": count / reference, "speedup_vs_rosbags": reference / ours,
            "bag_bytes_per_simulated_s": size / seconds}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="bench/results.json")
    args = parser.parse_args()
    config = load_machine_config(default_config_path("sam"))
    results = {"sam_model_1khz": model_speed(config), "bag_read": bag_read(config)}
    out = Path(args.out)
    out.write_text(json.dumps(results, indent=2) + "\n")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.5))
    a.bar(["SAM model", "target"], [results["sam_model_1khz"]["real_time_factor"], 50.0], color=["C0", "grey"])
    a.set_ylabel("simulated s per wall s")
    b.bar(["hydro_ros reader", "rosbags AnyReader"],
          [results["bag_read"]["hydro_ros_msgs_per_s"], results["bag_read"]["rosbags_anyreader_msgs_per_s"]], color=["C0", "grey"])
    b.set_ylabel("messages per s")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
