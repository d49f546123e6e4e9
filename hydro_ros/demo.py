"""`make demo`: the two halves of the thesis on one crane. First the SAM with a developing leak, simulated and
analysed offline (bag, FDI JSON, plot). Then the K70M on a DDS graph: trajectory_server serves the energy-optimal
horizontal path from where the crane stands, plant_sim's crane mode works it with the crane's cylinders and their
valves, fdi_node monitors every cylinder (sample blocks at 1 kHz), and a leak develops in the lift cylinder's
chamber A. The operator view (a line per second) and the HMI, whose URL it prints, show every cylinder's health
and name the leaking one. At the end the path's pump energy against the joint-space pseudo-inverse's.
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
START_EXTENSION = 0.3  # [m] the telescope at the start of the path
# the cylinder, its fault, the size it grows to [L/min at 10 MPa]: the lift's A carries the boom (7-12 MPa), so the leak
# flows near its quoted size; the tilt's chambers sit at 0.5-1.5 MPa at this path's start, where 2 L/min leaks 0.45
LEAK = ("lift", "external_leakage_a", 2.0)
TIP_TOLERANCE = 0.1  # [m] the crane holds its start on closed valves and sags within the loop's dead band (0.05 m at the tip)


def _operator_view(duration_s: float) -> list[str]:
    import json

    import rclpy
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    from hydro_ros.nodes.common import LATCHED_QOS, SENSOR_QOS

    rclpy.init()
    node = rclpy.create_node("operator_view")
    crane: dict = {}
    health: dict[str, str] = {}
    levels = {0: "OK", 1: "WARN", 2: "ERROR", 3: "STALE"}
    node.create_subscription(
        DiagnosticArray, "/diagnostics",
        lambda m: health.update({s.name.removeprefix("hydro_ros/fdi/"): f"{levels.get(s.level[0], s.level)} {s.message}"
                                 for s in m.status if s.name.startswith("hydro_ros/fdi/")}), 10)
    node.create_subscription(JointState, "/joint_states",
                             lambda m: crane.update(t=m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, q=list(m.position)), SENSOR_QOS)
    node.create_subscription(String, "/trajectory_server/result", lambda m: crane.update(result=json.loads(m.data)), LATCHED_QOS)
    requests = node.create_publisher(String, "/trajectory_server/request", 10)
    faults = AsyncParameterClient(node, "plant_sim")
    actuator, fault, size = LEAK
    onset, lines = duration_s / 3.0, []
    first = None
    end = time.monotonic() + duration_s + 30.0
    next_print = time.monotonic() + 1.0
    while time.monotonic() < end:
        rclpy.spin_once(node, timeout_sec=0.05)
        if time.monotonic() < next_print or "t" not in crane:
            continue
        next_print += 1.0
        first = crane["t"] if first is None else first
        t = crane["t"] - first
        result = crane.get("result")
        if result and not result["ok"] and ("nothing received" in result["error"] or "no subscriber" in result["error"]):
            del crane["result"]  # the server has not yet discovered the crane: ask again
        if "result" not in crane and requests.get_subscription_count() > 0 and health and all(h == "OK ok" for h in health.values()):
            requests.publish(String(data=CRANE_PATH))  # once every cylinder is monitored
            crane["result"] = {}
        leaking = min(size, size * (t - onset) / onset) if t > onset else 0.0
        if leaking > 0.0 and faults.services_are_ready():
            faults.set_parameters([Parameter(f"fault.{actuator}.{fault}", value=round(leaking, 2))])  # the leak grows
        line = (f"t={t:6.1f} s  {actuator} {fault} {leaking:4.2f} L/min  crane: {_crane_status(crane)}\n"
                f"          health: {', '.join(f'{name} {state}' for name, state in sorted(health.items())) or 'waiting for /diagnostics'}")
        print(line, flush=True)
        lines.append(line)
        if t >= duration_s and health.get(actuator, "").endswith(fault):
            break
    node.destroy_node()
    rclpy.shutdown()
    return lines


def _crane_status(crane: dict) -> str:
    result = crane.get("result")
    joints = ", ".join(f"{q:+.2f}" for q in crane.get("q", []))
    if result is None:
        return f"joints [{joints}], waiting for every cylinder to be monitored"
    if not result:
        return f"requested {CRANE_PATH!r}"
    if not result["ok"]:
        return f"refused: {result['error']}"
    return f"working {result['method']} {CRANE_PATH} forwards and back, joints [{joints}]"


def _start_hmi(out: Path, port: int, config: str) -> tuple[subprocess.Popen, str, str]:
    """The operator HMI for this graph, with a fresh token so acknowledge and request can be tried."""
    import secrets

    from hydro_ros.nodes.hmi import TOKEN_ENV

    token = secrets.token_urlsafe(12)
    log = out / "hmi.log"
    process = subprocess.Popen(
        [sys.executable, "-m", "hydro_ros.nodes.hmi", "--ros-args", "-p", f"port:={port}", "-p", f"config:={config}"],
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


def run_demo(out: Path, *, config_path: str | None = None, duration: float = 60.0, hmi_port: int = 8080, linger: float = 0.0) -> int:
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
    status = cli(["fdi", "run", "--bag", str(bag), "--config", config, "--out", str(out / "fdi.json"), "--quiet"])
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
    actuator, fault, size = LEAK
    print(f"4/4 the K70M at work on a DDS graph (ROS_DOMAIN_ID={os.environ.get('ROS_DOMAIN_ID', '0')}): trajectory_server -> "
          f"plant_sim (the crane's cylinders) -> fdi_node; {actuator} {fault} growing from {onset:.0f} s to {size:g} L/min. "
          f"Operator view:")
    nodes = [
        ("plant_sim", "-p", f"config:={crane_config}", "-p", "excitation:=trajectory", "-p", f"initial_path:={CRANE_PATH}",
         "-p", f"initial_extension:={START_EXTENSION}", "-p", "seed:=7", "-p", "sensor_topics:=joint_states", "-p", "sample_blocks:=true"),
        ("trajectory_server", "-p", f"database:={database}", "-p", "output_topic:=joint_trajectory", "-p", f"tip_tolerance:={TIP_TOLERANCE}"),
        ("fdi_node", "-p", f"config:={crane_config}", "-p", "input:=sample_block"),
    ]
    hmi, url, token = _start_hmi(out, hmi_port, crane_config)
    print(f"    operator HMI: {url}  (operator token for acknowledge / request: {token})" if url else f"    {token}", flush=True)
    processes = [subprocess.Popen([sys.executable, "-m", f"hydro_ros.nodes.{name}", "--ros-args", *args], stderr=subprocess.DEVNULL)
                 for name, *args in nodes] + [hmi]
    try:
        _operator_view(duration)
        if linger > 0 and url:
            print(f"    the graph stays up {linger:g} s more: {url}", flush=True)
            time.sleep(linger)
    finally:
        for process in processes:
            process.terminate()
            process.wait(timeout=10)
    _energy_against_pseudo_inverse(crane_config, database)
    print(f"bag:  {bag}\nplot: {bag}.png\nFDI:  {out / 'fdi.json'} and {out / 'fdi.png'}\ncatalog: hydro-ros db list --db {database}\n"
          f"HMI log (operator actions): {out / 'hmi.log'}")
    return 0


def _energy_against_pseudo_inverse(crane_config: str, database: Path) -> None:
    """The served DP-CP trajectory and the joint pseudo-inverse from the same start, each in closed loop on P-VI's
    simulated crane (``workflows.execution``: the controller of Appendix A, the CP pump)."""
    from hydro_ros.models.crane import load_crane
    from hydro_ros.planning.serving import executable_trajectory
    from hydro_ros.workflows.execution import execute

    _, config = load_crane(crane_config)
    runs = {method: execute(config, executable_trajectory(config, CRANE_PATH, method, database=str(database),
                                                          start_extension=START_EXTENSION)[0], "cp").summary
            for method in ("dp_cp", "pinv_joint")}
    optimal, baseline = runs["dp_cp"], runs["pinv_joint"]
    saving = 1.0 - optimal["energy_J"] / baseline["energy_J"]
    print(f"crane {CRANE_PATH}: energy-optimal (DP-CP) {optimal['energy_J'] / 1e3:.1f} kJ, joint pseudo-inverse "
          f"{baseline['energy_J'] / 1e3:.1f} kJ on the same crane: {100 * saving:.0f} % saved; "
          f"path accuracy {optimal['path_accuracy_iso9283_m']:.3f} m vs {baseline['path_accuracy_iso9283_m']:.3f} m")
