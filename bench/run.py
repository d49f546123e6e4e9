"""`make bench`: speed of the model, the bag reader, the UKF and the FDI (offline and live), each
against a reference or target measured in the same run, and the FDI evaluation with model mismatch.

Writes bench/results/results.json and bench/results/results.png, and bench/results/fdi_eval.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hydro_ros.bags.reader import mcap_files, read_bag
from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import Machine, load_machine_config
from hydro_ros.models.sam import SamModel, SamPlant
from hydro_ros.processes import live_cpu_share
from hydro_ros.sim.scenario import Scenario, run_blocks
from hydro_ros.tooling.benchresults import write_result


def model_speed(config: Machine, seconds: float = 60.0) -> dict:
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


def bag_read(config: Machine, seconds: float = 30.0) -> dict:
    from rosbags.highlevel import AnyReader

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench"
        with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
            for _, _, block in run_blocks(config, Scenario(seconds, (), seed=1)):
                writer.write_block("boom", block)
        start = time.perf_counter()
        data = read_bag(path)
        ours = time.perf_counter() - start
        start = time.perf_counter()
        with AnyReader([path]) as reader:
            count = sum(1 for c, _, raw in reader.messages() if reader.deserialize(raw, c.msgtype) is not None)
        reference = time.perf_counter() - start
        size = mcap_files(path)[0].stat().st_size
    assert count == data.message_count
    return {"messages": data.message_count, "hydro_ros_msgs_per_s": data.message_count / ours,
            "rosbags_anyreader_msgs_per_s": count / reference, "speedup_vs_rosbags": reference / ours,
            "bag_bytes_per_simulated_s": size / seconds}


def ukf_speed(config: Machine, steps: int = 20000, reference_steps: int = 1500) -> dict:
    from hydro_ros.fdi.filterpy_twin import filterpy_twin
    from hydro_ros.fdi.ukf import UkfBank, UkfSettings

    model = SamModel(config)
    rng = np.random.default_rng(0)
    t = np.arange(steps) / model.sample_rate
    inputs = np.stack([0.2 + 0.05 * np.sin(t), 0.05 * np.cos(t), 0.3 * np.sin(3 * t), np.full(steps, 1e7)], axis=1)
    measured = np.stack([6e6 + 1e5 * rng.normal(size=steps), 3e6 + 1e5 * rng.normal(size=steps)], axis=1)

    def per_step(actuators: int, n: int) -> float:
        bank = UkfBank([model] * actuators, UkfSettings())
        batch_in = np.repeat(inputs[:n, None, :], actuators, axis=1)
        batch_y = np.repeat(measured[:n, None, :], actuators, axis=1)
        valid = np.ones((n, actuators), dtype=bool)
        bank.run(batch_in[:10], batch_y[:10], valid[:10])  # JIT warm-up
        start = time.perf_counter()
        bank.run(batch_in, batch_y, valid)
        return (time.perf_counter() - start) / (n * actuators)

    ours = per_step(1, steps)
    batched = per_step(4, steps)
    _, step = filterpy_twin(UkfBank([model], UkfSettings()))
    start = time.perf_counter()
    for k in range(reference_steps):
        step(inputs[k], measured[k])
    theirs = (time.perf_counter() - start) / reference_steps
    return {"hydro_ros_steps_per_s": 1.0 / ours, "hydro_ros_4_actuator_batch_steps_per_s_per_actuator": 1.0 / batched,
            "filterpy_steps_per_s": 1.0 / theirs, "speedup_vs_filterpy": theirs / ours, "target_speedup": 10.0,
            "agreement": "max |p_hat difference| < 1 Pa over 2000 recorded samples (test_fdi.py)"}


def fdi_offline(config: Machine, seconds: float = 60.0) -> dict:
    from hydro_ros.fdi.monitor import FdiMonitor
    from hydro_ros.fdi.offline import analyse_bag, blocks_from_bag, run_monitor

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "bench"
        with ContractBagWriter(path, actuators={"boom": "boom_joint"}, pressure_variance=1e10) as writer:
            for _, _, block in run_blocks(config, Scenario(seconds, (), seed=3)):
                writer.write_block("boom", block)
        analyse_bag(path, config)  # JIT warm-up
        start = time.perf_counter()
        analyse_bag(path, config)
        total = time.perf_counter() - start
        start = time.perf_counter()
        data = read_bag(path)
        reading = time.perf_counter() - start
        monitor = FdiMonitor(config)
        samples = blocks_from_bag(data, monitor)
        start = time.perf_counter()
        run_monitor(monitor, samples)
        monitoring = time.perf_counter() - start
    return {"bag_s": seconds, "real_time_factor": seconds / total, "read_real_time_factor": seconds / reading,
            "monitor_real_time_factor": seconds / monitoring, "target_real_time_factor": 200.0}


def fdi_node_live(config_path: Path, measure_s: float = 20.0) -> dict:
    """plant_sim at 1 kHz -> fdi_node, both real processes on a private localhost domain."""
    commands = [[module, "-p", f"config:={config_path}"] for module in ("hydro_ros.nodes.plant_sim", "hydro_ros.nodes.fdi_node")]
    cpu, wall, v0, v1 = live_cpu_share(151, commands, "hydro_ros/fdi/boom", "samples", measure_s)
    processed = int(v1["samples"]) - int(v0["samples"])
    return {"cpu_share_of_one_core": cpu, "samples_processed_per_s": processed / wall,
            "gap_samples": int(v1["gap_samples"]), "incomplete_samples": int(v1["incomplete_samples"]),
            "out_of_order_dropped": int(v1["out_of_order_dropped"]), "sample_rate_hz": 1000.0,
            "messages_per_s": 5 * processed / wall}


def can_decode(config: Machine, cycles: int = 5000) -> dict:
    """Checked decoding (DLC, CRC, counter, cycle grouping) against bare cantools decoding, same frames."""
    from hydro_ros.can.codec import CounterCheck, CycleAssembler, MachineBus

    bus = MachineBus(config)
    sample = {"joint_position": {"boom_joint": 0.1}, "joint_velocity": {"boom_joint": 0.01}, "pressure_a": {"boom": 6e6},
              "pressure_b": {"boom": 2e6}, "valve_command": {"boom": 0.2}, "supply_pressure": 1e7}
    frames = [f for c in range(cycles) for f in bus.encode_cycle(sample, c % 16)]
    start = time.perf_counter()
    assembler, counters = CycleAssembler(bus.expected, bus.clock()), CounterCheck()
    for frame_id, data in frames:
        name, counter, values = bus.decode(frame_id, data)
        counters(name, counter)
        assembler.add(name, counter, values, 0)
    ours = time.perf_counter() - start
    start = time.perf_counter()
    for frame_id, data in frames:
        bus.db.decode_message(frame_id, data)
    bare = time.perf_counter() - start
    return {"frames": len(frames), "checked_frames_per_s": len(frames) / ours, "bare_cantools_frames_per_s": len(frames) / bare,
            "ratio_to_bare_cantools": bare / ours, "sam_frames_per_s_needed": 4000}


def can_bridge_live(config_path: Path, measure_s: float = 15.0) -> dict:
    """plant_sim emitting its sensors on a udp_multicast CAN bus at 1 kHz -> can_bridge: CPU share and rate."""
    group = "239.74.152.1"
    aside = [a for t in ("/joint_states", "/hydraulics/boom/pressure_a", "/hydraulics/boom/pressure_b", "/hydraulics/supply_pressure",
                         "/hydraulics/valve_commands") for a in ("-r", f"{t}:=/sim{t}")]
    commands = [["hydro_ros.nodes.plant_sim", "-p", f"config:={config_path}", "-p", "can_interface:=udp_multicast", "-p", f"can_channel:={group}", *aside],
                ["hydro_ros.nodes.can_bridge", "-p", f"config:={config_path}", "-p", "interface:=udp_multicast", "-p", f"channel:={group}"]]
    cpu, wall, v0, v1 = live_cpu_share(152, commands, "hydro_ros/can_bridge/bus", "published_cycles", measure_s)
    return {"cpu_share_of_one_core": cpu,
            "cycles_published_per_s": (int(v1["published_cycles"]) - int(v0["published_cycles"])) / wall,
            "frames_per_s": (int(v1["frames_received"]) - int(v0["frames_received"])) / wall,
            "incomplete_cycles": int(v1["incomplete_cycles"]), "sample_rate_hz": 1000.0}


def fdi_evaluation(config: Machine, out_dir: Path, name: str = "fdi_eval") -> dict:
    from tqdm import tqdm

    from hydro_ros.studies.fdi_evaluation import evaluate, markdown_table, plot_summary

    with tqdm(unit="run", desc="fdi-eval") as bar:
        summary = evaluate(config, progress=bar.update)
    (out_dir / f"{name}.md").write_text(markdown_table(summary))
    plot_summary(summary, out_dir / f"{name}.png")
    record = summary.to_json()
    write_result(out_dir / f"{name}.json", record)  # last: a stamped file stands for a finished step
    return {"threshold": record["threshold"], "false_alarms_per_hour": summary.fault_free.false_alarms_per_hour,
            "smallest_detectable": record["smallest_detectable"], "table": f"bench/{name}.md"}


def gsa(config_path: Path, out_dir: Path, samples: int = 1024) -> dict:
    """P-I GSA at N = 1024 (runs N (k + 2) over two processes); indices in bench/results/gsa.json."""
    start = time.perf_counter()
    status = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "gsa", "--config", str(config_path), "--samples", str(samples),
                             "--out", str(out_dir / "gsa.json"), "--quiet"], check=False).returncode
    wall = time.perf_counter() - start
    report = json.loads((out_dir / "gsa.json").read_text())
    write_result(out_dir / "gsa.json", report)  # the command writes a user's file; the bench's records its commit
    runs = report["parameters"]["runs"] + report["leakages"]["runs"]
    return {"status": status, "samples": samples, "runs": runs, "wall_s": wall, "runs_per_s": runs / wall,
            "ranking_4s": {name: report[name]["ranking_4s"] for name in ("parameters", "leakages")}}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="bench/results/results.json")
    args = parser.parse_args()
    config = load_machine_config(default_config_path("sam"))
    out = Path(args.out)
    results = {"sam_model_1khz": model_speed(config), "bag_read": bag_read(config), "ukf": ukf_speed(config),
               "fdi_offline": fdi_offline(config), "fdi_node_live": fdi_node_live(default_config_path("sam")),
               "can_decode": can_decode(config), "can_bridge_live": can_bridge_live(default_config_path("sam")),
               "gsa": gsa(default_config_path("sam"), out.parent),
               "fdi_evaluation": fdi_evaluation(config, out.parent),
               "fdi_parity_evaluation": fdi_evaluation(load_machine_config(default_config_path("sam_mobile")), out.parent,
                                                       "fdi_parity_eval")}
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b, c, d) = plt.subplots(1, 4, figsize=(16, 3.5))
    a.bar(["SAM model", "target"], [results["sam_model_1khz"]["real_time_factor"], 50.0], color=["C0", "grey"])
    a.set_ylabel("simulated s per wall s")
    b.bar(["hydro_ros reader", "rosbags AnyReader"],
          [results["bag_read"]["hydro_ros_msgs_per_s"], results["bag_read"]["rosbags_anyreader_msgs_per_s"]], color=["C0", "grey"])
    b.set_ylabel("messages per s")
    c.bar(["hydro_ros UKF", "filterpy UKF"], [results["ukf"]["hydro_ros_steps_per_s"], results["ukf"]["filterpy_steps_per_s"]],
          color=["C0", "grey"])
    c.set_yscale("log")
    c.set_ylabel("filter steps per s")
    d.bar(["offline fdi", "read only", "monitor only", "target"],
          [results["fdi_offline"]["real_time_factor"], results["fdi_offline"]["read_real_time_factor"],
           results["fdi_offline"]["monitor_real_time_factor"], 200.0], color=["C0", "C1", "C2", "grey"])
    d.set_yscale("log")
    d.set_ylabel("x real time (SAM, 1 kHz)")
    fig.tight_layout()
    fig.savefig(out.with_suffix(".png"), dpi=100)
    write_result(out, results)  # last: a stamped file stands for a finished step
    print(json.dumps(results, indent=2))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
