"""Trajectory database and serving benchmarks (make bench): catalog build throughput on 1 local
process (the reference), on all local cores and on a Dask LocalCluster, in the same run; request ->
trajectory latency of trajectory_server on a live DDS graph (stored start and re-planned start);
and the closed-loop execution of every stored solution on the simulated crane (P-VI Table 4 style).
Writes bench/results/trajectories.json, bench/results/execution.md and bench/results/execution.png.
"""

from __future__ import annotations

import argparse
import os
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.contract.config import default_config_path  # noqa: E402
from hydro_ros.models.crane import load_crane  # noqa: E402
from hydro_ros.planning.catalog import build, plan_units  # noqa: E402
from hydro_ros.planning.database import TrajectoryDatabase  # noqa: E402
from hydro_ros.planning.problem import CONTRACT_METHODS  # noqa: E402
from hydro_ros.planning.serving import path_start_state  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402
from hydro_ros.workflows.execution import execute  # noqa: E402

METHODS = ("dp_cp", "dp_ls", "pinv_actuator", "pinv_joint")  # of the throughput builds
THROUGHPUT_GRID = (179, 51, 75)  # about half the P-VI grid per axis (odd counts: DpGrid), so three builds stay within minutes


def throughput(config: dict, workdir: Path) -> dict:
    from distributed import LocalCluster

    units = plan_units(config, methods=METHODS, grid=THROUGHPUT_GRID)
    results = {"units": len(units), "grid": list(THROUGHPUT_GRID)}
    for label in ("1 process", "local processes", "Dask LocalCluster"):
        path = workdir / f"throughput_{label.replace(' ', '_')}.db"
        with TrajectoryDatabase(path, writable=True) as db:
            if label == "Dask LocalCluster":
                with LocalCluster(n_workers=os.cpu_count(), threads_per_worker=1, dashboard_address=None) as cluster:
                    report = build(db, units, scheduler=cluster.scheduler_address)
            else:
                report = build(db, units, workers=1 if label == "1 process" else None)
        results[label] = {"seconds": report.seconds, "units_per_s": len(report.computed) / report.seconds, "scheduler": report.scheduler}
        print(f"build on {label}: {report.summary()}", flush=True)
    reference = results["1 process"]["seconds"]
    for label in ("local processes", "Dask LocalCluster"):
        results[label]["speedup_vs_1_process"] = reference / results[label]["seconds"]
    return results


def full_catalog(config: dict, path: Path) -> dict:
    units = plan_units(config, methods=CONTRACT_METHODS)  # every method, so all are executed in closed loop
    with TrajectoryDatabase(path, writable=True) as db:
        report = build(db, units)
    began = time.perf_counter()
    TrajectoryDatabase(path).close()
    check_s = time.perf_counter() - began
    size = path.stat().st_size / 1e6
    print(f"full-grid catalog: {report.summary()}; {size:.0f} MB, open + quick_check {check_s:.2f} s", flush=True)
    return {"seconds": report.seconds, "units": len(units), "grid": list(config.dp.grid), "size_MB": size, "open_check_s": check_s}


def latency(config: dict, db_path: Path, requests: int = 200, replans: int = 200) -> dict:
    """Request -> JointTrajectory received, measured by a client node on a private localhost domain."""
    os.environ.update(ROS_DOMAIN_ID="97", ROS_AUTOMATIC_DISCOVERY_RANGE="LOCALHOST")
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String
    from trajectory_msgs.msg import JointTrajectory

    from hydro_ros.nodes.common import LATCHED_QOS
    from hydro_ros.processes import node_process, spin_until

    with TrajectoryDatabase(db_path) as db:
        stored = db.solution("horizontal", "dp_cp")
    names = stored.trajectory.joint_names
    at_start = stored.trajectory.positions[0]
    # re-planned from a different extension each time (0.05-0.6 m beyond the stored start): nothing is reused
    moved = [path_start_state(config, "horizontal", stored.start_position + d) for d in np.linspace(0.05, 0.6, 12)]
    results = {}
    with node_process("hydro_ros.nodes.trajectory_server", "-p", f"database:={db_path}"):
        rclpy.init()
        node = rclpy.create_node("latency_client")
        received: list[float] = []
        node.create_subscription(JointTrajectory, "/trajectory_server/trajectory", lambda m: received.append(time.perf_counter()), LATCHED_QOS)
        answers: list[str] = []
        node.create_subscription(String, "/trajectory_server/result", lambda m: answers.append(m.data), LATCHED_QOS)
        pub = node.create_publisher(String, "/trajectory_server/request", 10)
        joints = node.create_publisher(JointState, "/joint_states", 10)
        catalog: list[str] = []
        node.create_subscription(String, "/trajectory_server/catalog", lambda m: catalog.append(m.data), LATCHED_QOS)
        opened = time.perf_counter()
        assert spin_until(node, lambda: catalog and catalog[-1] != "[]" and joints.get_subscription_count() > 0, 120), "server not up"
        results["server_ready_s"] = time.perf_counter() - opened  # process start, integrity check, catalog
        current = {"state": moved[0]}
        node.create_timer(0.1, lambda: joints.publish(JointState(name=names, position=current["state"].tolist(), velocity=[0.0] * 4)))
        # the re-planned phase first: its first request is the server's first
        for label, states, count in (("re-planned start", moved, replans), ("stored start", [at_start], requests)):
            current["state"] = states[0]
            spin_until(node, lambda: False, 0.5)
            samples = []
            for n in range(count):
                if len(states) > 1:  # a new actual state, published and received before the request
                    current["state"] = states[n % len(states)]
                    joints.publish(JointState(name=names, position=current["state"].tolist(), velocity=[0.0] * 4))
                    spin_until(node, lambda: False, 0.02)
                received.clear()
                sent = time.perf_counter()
                pub.publish(String(data="horizontal"))
                if not spin_until(node, lambda: received, 10):
                    raise RuntimeError(f"{label}: no trajectory within 10 s (last result: {answers[-1] if answers else 'none'})")
                samples.append(received[0] - sent)
            ms = 1e3 * np.array(samples)  # the first request included: the server prepares before it publishes its catalog
            results[label] = {"requests": count, "first_ms": float(ms[0]), "p50_ms": float(np.percentile(ms, 50)),
                              "p99_ms": float(np.percentile(ms, 99)), "max_ms": float(ms.max())}
            print(f"latency {label}: p50 {results[label]['p50_ms']:.1f} ms, p99 {results[label]['p99_ms']:.1f} ms", flush=True)
        node.destroy_node()
        rclpy.shutdown()
    return results


def executions(config: dict, db_path: Path, out_dir: Path) -> dict:
    """Every stored solution on the CP and the LS crane (P-VI Table 4: energy and ISO 9283 path accuracy)."""
    from tqdm import tqdm

    rows = {}
    with TrajectoryDatabase(db_path) as db:
        jobs = [(p, m, s) for p in config.paths for m in CONTRACT_METHODS for s in ("cp", "ls")]
        for path_id, method, supply in tqdm(jobs, desc="closed-loop runs", unit="run"):
            stored = db.solution(path_id, method)
            summary = execute(config, stored.trajectory, supply, seed=1).summary
            planned = stored.record["cp_energy_J" if supply == "cp" else "ls_energy_J"]
            rows.setdefault(path_id, {}).setdefault(method, {})[supply] = {
                "planned_J": planned, "executed_J": summary["energy_J"], "path_accuracy_m": summary["path_accuracy_iso9283_m"],
                "final_tip_error_m": summary["final_tip_error_m"],
            }
    lines = ["| path | method | CP planned kJ | CP executed kJ | CP AT_p m | LS planned kJ | LS executed kJ | LS AT_p m |", "|---|---|---|---|---|---|---|---|"]
    for path_id, methods in rows.items():
        for method, run in methods.items():
            cp, ls = run["cp"], run["ls"]
            lines.append(f"| {path_id} | {method} | {cp['planned_J'] / 1e3:.1f} | {cp['executed_J'] / 1e3:.1f} | {cp['path_accuracy_m']:.3f} | "
                         f"{ls['planned_J'] / 1e3:.1f} | {ls['executed_J'] / 1e3:.1f} | {ls['path_accuracy_m']:.3f} |")
    (out_dir / "execution.md").write_text("\n".join(lines) + "\n")
    _plot(rows, out_dir / "execution.png")
    return rows


def _plot(rows: dict, target: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 4.5), sharey=False)
    width = 0.8 / len(CONTRACT_METHODS)
    for ax, supply in zip(axes, ("cp", "ls")):
        for j, method in enumerate(CONTRACT_METHODS):
            values = [rows[p][method][supply]["executed_J"] / 1e3 for p in rows]
            ax.bar(np.arange(len(rows)) + j * width, values, width, label=method)
        ax.set_xticks(np.arange(len(rows)) + 0.4 - width / 2, list(rows))
        ax.set_ylabel("executed pump energy, kJ")
        ax.set_title(f"{supply.upper()} crane (closed loop, App. A controller)")
    axes[0].legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(target, dpi=110)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/trajectories.json")
    args = parser.parse_args()
    out = Path(args.out)
    _, config = load_crane(default_config_path("k70m"))
    workdir = Path(tempfile.mkdtemp(prefix="hydro_ros_bench_"))
    try:
        results = {"throughput": throughput(config, workdir)}
        catalog = workdir / "catalog.db"
        results["full_catalog"] = full_catalog(config, catalog)
        results["latency"] = latency(config, catalog)
        results["execution"] = executions(config, catalog, out.parent)
    finally:
        shutil.rmtree(workdir, ignore_errors=True)
    write_result(out, results)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
