"""Soak of the live safety chain, checked from the outside against the injected ground truth (not /fdi/halt).

The graph: plant_sim (the K70M's cylinders, valves from /hydraulics/valve_commands, sample blocks) -> fdi_node and
trajectory_executor, the executor driven by this script's node (its trajectory source), which sends a new motion of
the telescope whenever the executor is not moving. Impairments are injected at random, one at a time:

- ``monitor_freeze``: fdi_node stopped (SIGSTOP) for 1-4 s, then continued: a hung monitor;
- ``monitor_kill``: fdi_node killed (SIGKILL) and restarted 1-3 s later;
- ``plant_gap``: plant_sim stopped (SIGSTOP) for 1-4 s: every input of the monitor stops (a gap);
- ``executor_kill``: the executor killed (SIGKILL) and restarted 1-3 s later: the plant's deadman;
- ``severe_fault``: the telescope's spool stuck closed for 25 s (``fault.extension.spool_stuck_closed``), then repaired
  and, once the reset interval allows, the monitor reset.

The observer records every valve command (stamped by the executor's clock, the system clock here) and the joint
states, and counts a violation for each non-neutral command stamped later than the documented bound after the monitor
lost sight (a freeze, kill or gap began: ``HEARTBEAT_TIMEOUT_S`` + one control period + ``stale_timeout`` for a gap),
until the impairment ended; and for a killed executor, a non-neutral command the plant still applied (its sample
blocks carry what its valves got) later than ``VALVE_COMMAND_TIMEOUT_S`` + one control period + one plant tick after
the kill (the plant's deadman). What the telescope does on neutral valves is the plant's, not the deadman's: its speed
then is measured and listed (``telescope_creep_m_s``: the valves' centre leakage under load). A severe fault is not a
loss of sight: whether the monitor named it and stopped the machine within ``DETECTION_BUDGET_S`` is measured and
listed (``severe_faults_still_moving_after_budget``), a statement about detection on this machine, not about the
safety core. The machine must move at least half of the fault-free time (outside impairments and the re-arming after
them), or the soak proves nothing.

    python bench/safety_soak.py --duration 1800 --out bench/results/safety_soak.json
"""

from __future__ import annotations

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
from tqdm import tqdm

from hydro_ros.tooling.benchresults import write_result

REPO = Path(__file__).resolve().parent.parent

CONFIG = REPO / "config" / "k70m.yaml"
CONTROL_PERIOD_S = 0.01
STALE_TIMEOUT_S = 0.5  # fdi_node's default
DETECTION_BUDGET_S = 20.0  # a severe fault named and the machine stopped within this of its onset (window 5 s + isolation)
PLANT_TICK_S = 0.01  # plant_sim's default tick_period: its deadman is read once a tick, for the samples due then
REARM_ALLOWANCE_S = 8.0  # after an impairment, time for the monitor to re-arm before "fault-free" time counts again
KINDS = ("monitor_freeze", "monitor_kill", "plant_gap", "executor_kill", "severe_fault")


def _start(module: str, *args: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, "--ros-args", *args], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)


def _executor_args(names: list[str]) -> list[str]:
    return ["-p", f"config:={CONFIG}", "-p", "joint_state_source:=plant_sim", "-p", "trajectory_source:=/soak",
            "-p", "monitor:=fdi_node", "-p", "joint_state_timeout:=0.3"]


def run(duration: float, seed: int) -> dict:
    import rclpy
    from builtin_interfaces.msg import Duration
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from sensor_msgs.msg import JointState, PointCloud2
    from std_msgs.msg import String
    from std_srvs.srv import Trigger
    from trajectory_msgs.msg import JointTrajectory, JointTrajectoryPoint

    from hydro_ros.bags.cdr import decode_sample_block
    from hydro_ros.contract import topics
    from hydro_ros.nodes.common import LATCHED_QOS
    from hydro_ros.safety.motion import HEARTBEAT_TIMEOUT_S, VALVE_COMMAND_TIMEOUT_S

    rng = random.Random(seed)
    commands: list[tuple[float, float]] = []  # (executor's stamp, largest |command|)
    joints: list[tuple[float, float]] = []  # (plant's stamp, telescope extension)
    applied: list[tuple[np.ndarray, np.ndarray]] = []  # per sample block: (plant's stamps, largest |command| its valves got)
    status: list[dict] = []
    rclpy.init()
    node = rclpy.create_node("soak")
    node.create_subscription(JointState, topics.VALVE_COMMANDS, lambda m: commands.append(
        (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, max((abs(p) for p in m.position), default=0.0))), 5000)
    node.create_subscription(JointState, topics.JOINT_STATES, lambda m: joints.append(
        (m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, m.position[list(m.name).index("extension")] if "extension" in m.name else np.nan)),
        5000)

    def on_block(data: bytes) -> None:
        fields, stamps, rows = decode_sample_block(data)
        valves = [k for k, name in enumerate(fields) if name.endswith("/valve_command")]
        applied.append((stamps * 1e-9, np.abs(rows[:, valves]).max(axis=1)))

    node.create_subscription(PointCloud2, topics.SAMPLE_BLOCK, on_block, 1000, raw=True)
    node.create_subscription(String, "/trajectory_executor/status", lambda m: status.append(json.loads(m.data)), LATCHED_QOS)
    trajectories = node.create_publisher(JointTrajectory, "/trajectory_executor/joint_trajectory", 10)

    def spin(seconds: float) -> None:
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.01)
            drive()

    last_sent = {"t": 0.0}
    names = ["base", "lift", "tilt", "extension"]

    def drive() -> None:
        """A new telescope motion (out or in by 0.25 m over 5 s) whenever the executor is idle, stopped or refused."""
        if not status or status[-1]["state"] == "executing" or time.monotonic() - last_sent["t"] < 0.5 or not latest["q"]:
            return
        q = np.array(latest["q"][-1])
        step = 0.25 if q[3] < 1.2 else -0.25
        msg = JointTrajectory(joint_names=names)
        for k, t in enumerate(np.linspace(0.0, 5.0, 11)):
            point = JointTrajectoryPoint(positions=(q + np.array([0, 0, 0, step * k / 10])).tolist(), velocities=[0.0, 0.0, 0.0, step / 5.0])
            point.time_from_start = Duration(sec=int(t), nanosec=int(round((t % 1.0) * 1e9)))
            msg.points.append(point)
        trajectories.publish(msg)
        last_sent["t"] = time.monotonic()

    latest: dict[str, list] = {"q": []}
    node.create_subscription(JointState, topics.JOINT_STATES, lambda m: latest["q"].append(list(m.position)) or
                             (len(latest["q"]) > 10 and latest["q"].pop(0)), 10)

    plant = _start("hydro_ros.nodes.plant_sim", "-p", f"config:={CONFIG}", "-p", "excitation:=topic", "-p", "seed:=11",
                         "-p", "sensor_topics:=joint_states", "-p", "sample_blocks:=true", "-p", "initial_path:=horizontal",
                         "-p", "initial_extension:=0.8")
    monitor_args = ["-p", f"config:={CONFIG}", "-p", "input:=sample_block"]
    processes = {"plant": plant, "monitor": _start("hydro_ros.nodes.fdi_node", *monitor_args),
                 "executor": _start("hydro_ros.nodes.trajectory_executor", *_executor_args(names))}
    events: list[dict] = []
    reset = node.create_client(Trigger, "/fdi_node/reset")
    plant_params = AsyncParameterClient(node, "plant_sim")

    def restart(role: str) -> None:
        module, args = {"monitor": ("hydro_ros.nodes.fdi_node", monitor_args), "executor": ("hydro_ros.nodes.trajectory_executor", _executor_args(names))}[role]
        processes[role] = _start(module, *args)

    def set_fault(value: float) -> None:
        future = plant_params.set_parameters([Parameter("fault.extension.spool_stuck_closed", value=value)])
        spin(0.0)
        end = time.monotonic() + 10
        while not future.done() and time.monotonic() < end:
            spin(0.05)

    try:
        spin(25.0)  # start-up and the first arming
        started = time.time()
        progress = tqdm(total=int(duration), unit="s", desc="soak")
        while time.time() - started < duration:
            spin(rng.uniform(15.0, 30.0))  # fault-free work
            kind = rng.choice(KINDS)
            begin = time.time()
            if kind in ("monitor_freeze", "plant_gap"):
                process = processes["monitor" if kind == "monitor_freeze" else "plant"]
                process.send_signal(signal.SIGSTOP)
                spin(rng.uniform(1.0, 4.0))
                process.send_signal(signal.SIGCONT)
            elif kind in ("monitor_kill", "executor_kill"):
                role = "monitor" if kind == "monitor_kill" else "executor"
                processes[role].send_signal(signal.SIGKILL)
                processes[role].wait(timeout=10)
                spin(rng.uniform(1.0, 3.0) if role == "monitor" else 1.5)
                restart(role)
            else:
                set_fault(1.0)
                spin(25.0)
                set_fault(0.0)
                spin(6.0)
                future = reset.call_async(Trigger.Request())
                end = time.monotonic() + 10
                while not future.done() and time.monotonic() < end:
                    spin(0.05)
            events.append({"kind": kind, "begin": begin, "end": time.time()})
            progress.update(int(min(time.time() - started, duration) - progress.n))
        progress.close()
        spin(2.0)
    finally:
        for process in processes.values():
            process.send_signal(signal.SIGCONT)
            process.terminate()
        for process in processes.values():
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
        node.destroy_node()
        rclpy.shutdown()
    applied_at, applied_command = (np.concatenate(part) for part in zip(*applied)) if applied else (np.zeros(0), np.zeros(0))
    return judge(commands, joints, (applied_at, applied_command), events, started, HEARTBEAT_TIMEOUT_S, VALVE_COMMAND_TIMEOUT_S)


def judge(commands: list[tuple[float, float]], joints: list[tuple[float, float]], applied: tuple[np.ndarray, np.ndarray],
          events: list[dict], started: float, heartbeat_timeout: float, valve_timeout: float) -> dict:
    """Violations, measured latencies, the telescope's creep on neutral valves and the moving share of the fault-free
    time, from the records alone (``applied``: the plant's sample stamps and the largest |command| its valves got)."""
    stamps = np.array([t for t, _ in commands])
    moving = np.array([c > 1e-6 for _, c in commands])
    applied_at, applied_open = applied[0], applied[1] > 1e-6
    t = np.array([s for s, _ in joints])
    x = np.array([q for _, q in joints])
    bounds = {"monitor_freeze": heartbeat_timeout + CONTROL_PERIOD_S, "monitor_kill": heartbeat_timeout + CONTROL_PERIOD_S,
              "plant_gap": STALE_TIMEOUT_S + heartbeat_timeout + CONTROL_PERIOD_S, "severe_fault": DETECTION_BUDGET_S,
              "executor_kill": valve_timeout + CONTROL_PERIOD_S + PLANT_TICK_S}
    violations, undetected, creep, latencies = [], [], [], {kind: [] for kind in KINDS}
    for event in events:
        kind, begin, end = event["kind"], event["begin"], event["end"]
        if kind == "executor_kill":
            after = (applied_at > begin) & (applied_at < end)
            if not after.any():
                violations.append({**event, "no_plant_samples": True})  # the deadman cannot be judged blind
                continue
            still_open = after & applied_open
            latency = float(applied_at[still_open].max() - begin) if still_open.any() else 0.0
            latencies[kind].append(latency)
            if latency > bounds[kind]:
                violations.append({**event, "last_applied_command_after_s": latency})
            # on neutral valves: the least-squares slope of the position (a difference of two noisy samples reads the
            # sensor's noise as motion), until the executor's restart commands again
            window = (t > begin + bounds[kind] + 0.3) & (t < begin + 1.2)
            if window.sum() > 2 and not (applied_open & (applied_at > begin + bounds[kind]) & (applied_at < begin + 1.2)).any():
                creep.append(float(abs(np.polyfit(t[window] - begin, x[window], 1)[0])))
            continue
        inside = (stamps > begin) & (stamps < end)
        moving_inside = inside & moving
        latencies[kind].append(float(stamps[moving_inside].max() - begin) if moving_inside.any() else 0.0)
        if kind == "severe_fault":
            # how the monitor's detection did: measured and reported, not a loss of sight (docs/monitoring.md)
            if (moving_inside & (stamps > begin + bounds[kind])).any():
                undetected.append(event)
            continue
        late = moving_inside & (stamps > begin + bounds[kind])
        if late.any():
            violations.append({**event, "late_commands": int(late.sum()), "last_late_after_s": float(stamps[late].max() - begin)})
    # fault-free time: outside every impairment and the re-arming after it
    blocked = [(e["begin"], e["end"] + REARM_ALLOWANCE_S) for e in events]
    grid = np.arange(started, stamps.max() if len(stamps) else started, 0.05)
    free = np.ones(len(grid), dtype=bool)
    for begin, end in blocked:
        free &= ~((grid >= begin) & (grid < end))
    index = np.searchsorted(stamps, grid) - 1
    fresh = (index >= 0) & (grid - stamps[np.maximum(index, 0)] < 0.05)
    moving_now = fresh & moving[np.maximum(index, 0)]
    return {
        "duration_s": float(grid[-1] - started) if len(grid) else 0.0,
        "impairments": {kind: sum(e["kind"] == kind for e in events) for kind in KINDS},
        "violations": violations,
        "severe_faults_still_moving_after_budget": undetected,
        "bounds_s": {kind: round(bound, 3) for kind, bound in bounds.items()},
        "measured_s": {kind: {"max": max(v), "median": float(np.median(v))} for kind, v in latencies.items() if v},
        "telescope_creep_m_s": {"max": max(creep), "median": float(np.median(creep)), "kills": len(creep)} if creep else None,
        "fault_free_s": float(free.sum() * 0.05),
        "moving_share_of_fault_free": float(moving_now[free].mean()) if free.any() else 0.0,
        "commands": len(commands),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--duration", type=float, default=1800.0, help="seconds of soak after start-up")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=REPO / "bench" / "results" / "safety_soak.json")
    args = parser.parse_args()
    os.environ.setdefault("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    os.environ.setdefault("ROS_DOMAIN_ID", "91")
    result = run(args.duration, args.seed)
    result["ok"] = not result["violations"] and result["moving_share_of_fault_free"] >= 0.5
    args.out.parent.mkdir(parents=True, exist_ok=True)
    write_result(args.out, result)
    print(json.dumps({k: v for k, v in result.items() if k != "violations"} | {"violations": len(result["violations"])}, indent=2))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    raise SystemExit(main())
