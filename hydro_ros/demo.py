"""`make demo`: simulate the SAM with a developing leak, analyse it offline, then play it through
bag_player -> fdi_node on a DDS graph and show what the operator's HMI would: the actuator's
health turning from ok to the isolated fault name on /diagnostics.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from hydro_ros.config import default_config_path


def _operator_view(duration_s: float, rate: float) -> list[str]:
    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import FluidPressure, JointState

    from hydro_ros.nodes.common import SENSOR_QOS

    rclpy.init()
    node = rclpy.create_node("operator_view")
    latest: dict[str, float] = {}
    health: dict[str, str] = {}
    node.create_subscription(FluidPressure, "/hydraulics/boom/pressure_a", lambda m: latest.__setitem__("p_a", m.fluid_pressure), SENSOR_QOS)
    node.create_subscription(FluidPressure, "/hydraulics/boom/pressure_b", lambda m: latest.__setitem__("p_b", m.fluid_pressure), SENSOR_QOS)
    node.create_subscription(JointState, "/joint_states", lambda m: latest.update(t=m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, joint=m.position[0]), SENSOR_QOS)
    levels = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
    node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: health.update({s.name.removeprefix("hydro_ros/"): f"{levels.get(s.level[0], s.level)} {s.message}"
                                 for s in m.status if s.name.startswith("hydro_ros/fdi/")}), 10)
    lines = []
    end = time.monotonic() + duration_s / rate + 5.0
    next_print = time.monotonic() + 1.0
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        if time.monotonic() >= next_print and "t" in latest:
            next_print += 1.0
            line = (f"t={latest['t']:6.1f} s  boom joint {latest['joint']:+.3f} rad  p_A {latest.get('p_a', float('nan')) / 1e6:5.2f} MPa"
                    f"  p_B {latest.get('p_b', float('nan')) / 1e6:5.2f} MPa  health: {health or 'waiting for /diagnostics'}")
            print(line, flush=True)
            lines.append(line)
            if latest["t"] >= duration_s - 0.5:
                break
    node.destroy_node()
    rclpy.shutdown()
    return lines


def run_demo(out: Path, *, config_path: str | None = None, duration: float = 60.0, rate: float = 2.0) -> int:
    from hydro_ros.cli import main as cli

    out.mkdir(parents=True, exist_ok=True)
    config = config_path or str(default_config_path("sam"))
    bag = out / "developing_leak"
    if bag.exists():
        import shutil

        shutil.rmtree(bag)
    onset = duration / 3
    print(f"1/3 simulating {duration:.0f} s of the SAM, external leak A developing from {onset:.0f} s to 1.5 L/min")
    status = cli(["sim", "--config", config, "--duration", str(duration), "--seed", "7",
                  "--fault", f"external_leakage_a=1.5@{onset:g}:{onset:g}", "--out", str(bag), "--quiet"])
    if status:
        return status
    print("2/3 offline FDI over the bag (hydro-ros fdi):")
    status = cli(["fdi", "--bag", str(bag), "--config", config, "--json", str(out / "fdi.json"), "--quiet"])
    if status:
        return status
    print(f"3/3 replaying it x{rate:g}: bag_player -> fdi_node on a DDS graph "
          f"(ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}), operator view:")
    fdi = subprocess.Popen([sys.executable, "-m", "hydro_ros.nodes.fdi_node", "--ros-args", "-p", f"config:={config}",
                            "-p", "use_sim_time:=true"], stderr=subprocess.DEVNULL)
    player = subprocess.Popen([sys.executable, "-m", "hydro_ros.nodes.bag_player", "--ros-args",
                               "-p", f"bag:={bag}", "-p", f"rate:={rate}", "-p", "start_delay:=3.0"], stderr=subprocess.DEVNULL)
    try:
        _operator_view(duration, rate)
    finally:
        for process in (player, fdi):
            process.terminate()
            process.wait(timeout=10)
    print(f"bag:  {bag}\nplot: {bag}.png\nFDI:  {out / 'fdi.json'} and {out / 'fdi.png'}")
    return 0
