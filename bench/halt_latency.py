"""How fast trajectory_executor goes neutral: after a ``true`` on /fdi/halt, and after its joint states stop.

docs/motion.md promises every command neutral within 0.1 s of a halt. The live tests check the order of events (no
motion after the stop, under whatever load runs beside them); this bench measures the time, on a quiet machine:

- ``halt``: the executor moving the K70M's telescope on the probe's trajectory and heartbeats; the probe publishes
  ``true`` at t0 (system clock) and the latency is the executor's stamp of its first neutral command after t0 (the
  executor stamps with the system clock). The next heartbeat clears the halt; the next trial sends a new trajectory.
- ``joint_states_stale``: the probe, also the crane's sensor bridge, stops its joint states; the latency is the
  first neutral command's stamp after the last joint state was sent, less ``joint_state_timeout`` (what the executor
  adds beyond the timeout it was told).

    python bench/halt_latency.py --trials 40 --out bench/results/halt_latency.json
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hydro_ros.processes import node_process, spin_until
from hydro_ros.tooling.benchresults import write_result

REPO = Path(__file__).resolve().parent.parent
CONFIG = REPO / "config" / "k70m.yaml"
EXECUTOR = "/crane/trajectory_executor"
JOINT_STATE_TIMEOUT_S = 0.2
PROMISE_S = 0.1  # docs/motion.md: neutral within this of a halt


def _trajectory(pose: np.ndarray, names: list[str], step: float, duration: float):
    from builtin_interfaces.msg import Duration
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    msg = JointTrajectory(joint_names=names)
    for t in np.linspace(0.0, duration, 21):
        point = JointTrajectoryPoint(positions=(pose + np.array([0.0, 0.0, 0.0, step * t / duration])).tolist(),
                                     velocities=[0.0, 0.0, 0.0, step / duration])
        point.time_from_start = Duration(sec=int(t), nanosec=int(round((t % 1.0) * 1e9)))
        msg.points.append(point)
    return msg


def run(trials: int) -> dict:
    import rclpy
    from sensor_msgs.msg import JointState
    from std_msgs.msg import Bool, String
    from trajectory_msgs.msg import JointTrajectory

    from hydro_ros.contract import topics
    from hydro_ros.models.crane import load_crane
    from hydro_ros.nodes.common import HALT_QOS, LATCHED_QOS, SENSOR_QOS
    from hydro_ros.safety.motion import HEARTBEAT_PERIOD_S

    crane, _ = load_crane(CONFIG)
    names = list(crane.names)
    pose = np.array([0.5 * (c.q_min + c.q_max) for c in crane.cylinders])
    commands: list[tuple[float, bool]] = []  # (executor's stamp, any valve open)
    status: list[str] = []
    feeding = {"on": True, "last": 0.0}
    rclpy.init()
    node = rclpy.create_node("client")
    node.create_subscription(JointState, "/crane" + topics.VALVE_COMMANDS, lambda m: commands.append(
        (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, bool(np.any(np.asarray(m.position))))), 2000)
    node.create_subscription(String, f"{EXECUTOR}/status", lambda m: status.append(json.loads(m.data)["state"]), LATCHED_QOS)
    trajectories = node.create_publisher(JointTrajectory, f"{EXECUTOR}/joint_trajectory", 10)
    halt = node.create_publisher(Bool, "/crane" + topics.FDI_HALT, HALT_QOS)
    joints = node.create_publisher(JointState, "/crane" + topics.JOINT_STATES, SENSOR_QOS)

    def publish_joints() -> None:
        if feeding["on"]:
            joints.publish(JointState(name=names, position=pose.tolist()))
            feeding["last"] = time.time()

    node.create_timer(0.01, publish_joints)
    node.create_timer(HEARTBEAT_PERIOD_S, lambda: halt.publish(Bool(data=False)))

    def spin(seconds: float, until=lambda: False) -> bool:
        return spin_until(node, until, seconds)

    def moving() -> bool:
        """A new trajectory taken and a valve open; False when none was taken in 10 s."""
        for _ in range(20):
            count = len(status)
            trajectories.publish(_trajectory(pose, names, 0.3 if len(commands) % 2 else -0.3, 6.0))
            if spin(0.5, lambda: "executing" in status[count:]):
                return spin(2.0, lambda: bool(commands) and commands[-1][1])
        return False

    def first_neutral_after(t0: float) -> float | None:
        spin(1.0)
        later = [stamp for stamp, open_ in commands if stamp >= t0 and not open_]
        return later[0] if later else None

    latencies: dict[str, list[float]] = {"halt": [], "joint_states_stale": []}
    failed: dict[str, int] = {"halt": 0, "joint_states_stale": 0}
    args = ["-r", "__ns:=/crane", "-p", f"config:={CONFIG}", "-p", "joint_state_source:=/client", "-p", "trajectory_source:=/client",
            "-p", "monitor:=/client", "-p", f"joint_state_timeout:={JOINT_STATE_TIMEOUT_S}"]
    try:
        with node_process("hydro_ros.nodes.trajectory_executor", *args):
            if not spin(30.0, lambda: trajectories.get_subscription_count() > 0 and bool(status)):
                raise SystemExit("halt latency: the executor did not come up in 30 s")
            spin(1.0)
            for trial in tqdm(range(2 * trials), desc="halt latency", unit="trial"):
                kind = "halt" if trial % 2 == 0 else "joint_states_stale"
                if not moving():
                    failed[kind] += 1
                    continue
                if kind == "halt":
                    t0 = time.time()
                    halt.publish(Bool(data=True))
                    neutral = first_neutral_after(t0)
                else:
                    feeding["on"] = False
                    spin(0.02)
                    t0 = feeding["last"] + JOINT_STATE_TIMEOUT_S
                    neutral = first_neutral_after(feeding["last"])
                    feeding["on"] = True
                if neutral is None:
                    failed[kind] += 1
                else:
                    latencies[kind].append(neutral - t0)
                spin(0.5)  # the next heartbeat clears a halt; the joint states come back
    finally:
        node.destroy_node()
        rclpy.shutdown()

    def summary(values: list[float]) -> dict:
        v = np.asarray(values)
        return {"trials": len(v), "median": float(np.median(v)), "p95": float(np.percentile(v, 95)), "max": float(v.max()),
                "within_promise": int(np.sum(v <= PROMISE_S))} if len(v) else {"trials": 0}

    return {"promise_s": PROMISE_S, "joint_state_timeout_s": JOINT_STATE_TIMEOUT_S, "control_period_s": 0.01,
            "cpus": os.cpu_count(), "latency_s": {kind: summary(v) for kind, v in latencies.items()},
            "samples_s": latencies, "not_measured": failed}


def plot(result: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 3.5))
    for kind, values in result["samples_s"].items():
        ax.hist(np.asarray(values) * 1e3, bins=20, alpha=0.6, label=kind.replace("_", " "))
    ax.axvline(result["promise_s"] * 1e3, color="k", linestyle="--", label="documented 0.1 s")
    ax.set_xlabel("to the first neutral command [ms]")
    ax.set_ylabel("trials")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=40, help="trials of each kind")
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "halt_latency.json")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    result = run(args.trials)
    plot(result, args.out.with_suffix(".png"))
    write_result(args.out, result)  # last: a stamped file stands for a finished step
    print(json.dumps(result["latency_s"], indent=2))


if __name__ == "__main__":
    main()
