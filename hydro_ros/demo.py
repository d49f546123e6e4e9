"""`make demo`: simulate the SAM with a developing leak, analyse it offline, then play it through
bag_player -> fdi_node on a DDS graph, with the operator HMI (hydro_ros.nodes.hmi) serving the page whose
URL it prints: the actuator's health turning from ok to the isolated fault name. Beside it, the K70M crane
(crane_sim) asks trajectory_server for the energy-optimal horizontal path from where it
stands and executes it; the operator sees its pump energy against the joint-space pseudo-inverse's.
"""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

from hydro_ros.contract.config import default_config_path

CRANE_PATH = "horizontal"
CRANE_GRID = ("120", "41", "41")  # a catalog in seconds; make bench runs the full P-VI grid


def _operator_view(duration_s: float, rate: float) -> tuple[list[str], dict | None]:
    import json

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from sensor_msgs.msg import FluidPressure, JointState
    from std_msgs.msg import String

    from hydro_ros.nodes.common import LATCHED_QOS, SENSOR_QOS

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
    crane: dict = {}
    node.create_subscription(JointState, "/crane/joint_states", lambda m: crane.update(q=list(m.position)), SENSOR_QOS)
    node.create_subscription(FluidPressure, "/crane/hydraulics/supply_pressure", lambda m: crane.update(p_s=m.fluid_pressure), SENSOR_QOS)
    node.create_subscription(String, "/crane/trajectory_server/result", lambda m: crane.update(result=json.loads(m.data)), LATCHED_QOS)
    node.create_subscription(String, "/crane/crane_sim/execution", lambda m: crane.update(execution=json.loads(m.data)), LATCHED_QOS)
    requests = node.create_publisher(String, "/crane/trajectory_server/request", 10)
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
            result = crane.get("result")
            if result and not result["ok"] and ("nothing received" in result["error"] or "no subscriber" in result["error"]):
                del crane["result"]  # the server has not yet discovered the crane: ask again
            if "result" not in crane and "q" in crane and requests.get_subscription_count() > 0:
                requests.publish(String(data=CRANE_PATH))
                crane["result"] = {}
            print(f"          crane: {_crane_status(crane)}", flush=True)
            if latest["t"] >= duration_s - 0.5 and "execution" in crane:
                break
    node.destroy_node()
    rclpy.shutdown()
    return lines, crane.get("execution")


def _crane_status(crane: dict) -> str:
    if "execution" in crane:
        run = crane["execution"]
        return f"done: {run['energy_J'] / 1e3:.1f} kJ pump energy, ISO 9283 path accuracy {run['path_accuracy_iso9283_m']:.3f} m" if run["ok"] else run["error"]
    result = crane.get("result")
    if result is None:
        return "waiting for crane_sim and trajectory_server"
    if not result:
        return f"requested {CRANE_PATH!r}"
    if not result["ok"]:
        return f"refused: {result['error']}"
    joints = ", ".join(f"{q:+.2f}" for q in crane.get("q", []))
    return (f"executing {result['method']} ({'re-planned from here' if result['replanned'] else 'as stored'}), joints [{joints}], "
            f"supply {crane.get('p_s', float('nan')) / 1e6:.1f} MPa")


def _start_hmi(out: Path, port: int) -> tuple[subprocess.Popen, str, str]:
    """The operator HMI for this graph, with a fresh token so acknowledge and request can be tried."""
    import secrets

    from hydro_ros.nodes.hmi import TOKEN_ENV

    token = secrets.token_urlsafe(12)
    log = out / "hmi.log"
    process = subprocess.Popen(
        [sys.executable, "-m", "hydro_ros.nodes.hmi", "--ros-args", "-p", f"port:={port}", "-p", "trajectory_server:=/crane/trajectory_server"],
        env=dict(os.environ, **{TOKEN_ENV: token}), stdout=log.open("w"), stderr=subprocess.STDOUT)
    deadline = time.monotonic() + 15.0
    while time.monotonic() < deadline:
        text = log.read_text()
        if "HMI on " in text:
            return process, text.split("HMI on ", 1)[1].split()[0], token
        if process.poll() is not None:
            break
        time.sleep(0.2)
    reason = (log.read_text().strip().splitlines() or ["no output"])[-1]
    return process, "", f"the HMI did not start ({reason}); the rest of the demo goes on without it"


def cli(arguments: list[str]) -> int:
    """Run one ``hydro-ros`` command as its own process, as an operator would type it."""
    return subprocess.run([sys.executable, "-m", "hydro_ros.cli", *arguments], check=False).returncode


def run_demo(out: Path, *, config_path: str | None = None, duration: float = 60.0, rate: float = 2.0, hmi_port: int = 8080,
             linger: float = 0.0) -> int:
    out.mkdir(parents=True, exist_ok=True)
    config = config_path or str(default_config_path("sam"))
    bag = out / "developing_leak"
    if bag.exists():
        import shutil

        shutil.rmtree(bag)
    onset = duration / 3
    print(f"1/4 simulating {duration:.0f} s of the SAM, external leak A developing from {onset:.0f} s to 1.5 L/min")
    status = cli(["sim", "--config", config, "--duration", str(duration), "--seed", "7",
                  "--fault", f"external_leakage_a=1.5@{onset:g}:{onset:g}", "--out", str(bag), "--quiet"])
    if status:
        return status
    print("2/4 offline FDI over the bag (hydro-ros fdi):")
    status = cli(["fdi", "--bag", str(bag), "--config", config, "--json", str(out / "fdi.json"), "--quiet"])
    if status:
        return status
    crane_config = str(default_config_path("k70m"))
    database = out / "trajectories.db"
    for stale in (database, database.with_name(database.name + "-wal"), database.with_name(database.name + "-shm")):
        stale.unlink(missing_ok=True)  # a catalog of an earlier run (or release) is rebuilt, as the bag is
    print(f"3/4 trajectory catalog of the K70M crane ({CRANE_PATH}: DP-CP and the joint pseudo-inverse) -> {database}")
    status = cli(["db", "build", "--config", crane_config, "--db", str(database), "--paths", CRANE_PATH,
                  "--methods", "dp_cp", "pinv_joint", "--grid", *CRANE_GRID, "--quiet"])
    if status:
        return status
    print(f"4/4 replaying the SAM x{rate:g}: bag_player -> fdi_node; beside it crane_sim (K70M crane, CP pump) <- "
          f"trajectory_server on a DDS graph (ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}), operator view:")
    nodes = [
        ("fdi_node", "-p", f"config:={config}", "-p", "use_sim_time:=true"),
        ("bag_player", "-p", f"bag:={bag}", "-p", f"rate:={rate}", "-p", "start_delay:=3.0"),
        # the crane is a second machine on the graph: its contract topics live in the namespace /crane
        ("crane_sim", "-r", "__ns:=/crane", "-p", f"config:={crane_config}", "-p", f"initial_path:={CRANE_PATH}",
         "-p", "initial_extension:=0.3"),
        ("trajectory_server", "-r", "__ns:=/crane", "-p", f"database:={database}", "-p", "output_topic:=joint_trajectory"),
    ]
    hmi, url, token = _start_hmi(out, hmi_port)
    print(f"    operator HMI: {url}  (operator token for acknowledge / request: {token})" if url else f"    {token}", flush=True)
    processes = [subprocess.Popen([sys.executable, "-m", f"hydro_ros.nodes.{name}", "--ros-args", *args], stderr=subprocess.DEVNULL)
                 for name, *args in nodes] + [hmi]
    try:
        _, executed = _operator_view(duration, rate)
        if linger > 0 and url:
            print(f"    the graph stays up {linger:g} s more: {url}", flush=True)
            time.sleep(linger)
    finally:
        for process in processes:
            process.terminate()
            process.wait(timeout=10)
    if executed and executed.get("ok"):
        _energy_against_pseudo_inverse(crane_config, database, executed)
    print(f"bag:  {bag}\nplot: {bag}.png\nFDI:  {out / 'fdi.json'} and {out / 'fdi.png'}\ncatalog: hydro-ros db list --db {database}\n"
          f"HMI log (operator actions): {out / 'hmi.log'}")
    return 0


def _energy_against_pseudo_inverse(crane_config: str, database: Path, executed: dict) -> None:
    """The pseudo-inverse from the same start on the same simulated crane (offline: the live crane has moved on)."""
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.serving import executable_trajectory
    from hydro_ros.studies.execution import execute

    _, config = load_crane(crane_config)
    trajectory, _ = executable_trajectory(config, CRANE_PATH, "pinv_joint", database=str(database), start_extension=0.3)
    baseline = execute(config, trajectory, "cp").summary
    saving = 1.0 - executed["energy_J"] / baseline["energy_J"]
    print(f"crane {CRANE_PATH}: energy-optimal (DP-CP) {executed['energy_J'] / 1e3:.1f} kJ, joint pseudo-inverse "
          f"{baseline['energy_J'] / 1e3:.1f} kJ on the same crane: {100 * saving:.0f} % saved; "
          f"path accuracy {executed['path_accuracy_iso9283_m']:.3f} m vs {baseline['path_accuracy_iso9283_m']:.3f} m")
