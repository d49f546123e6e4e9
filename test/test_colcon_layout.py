"""`colcon build` installs every node where `ros2 run hydro_ros <node>` looks for it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from test.conftest import REPO

EXECUTABLES = ("plant_sim", "crane_sim", "bag_player", "fdi_node", "can_bridge", "trajectory_server", "trajectory_executor", "hmi")


def test_colcon_build_installs_executables_in_the_ament_index(tmp_path):
    src = tmp_path / "src" / "hydro_ros"
    shutil.copytree(REPO, src, ignore=shutil.ignore_patterns(".venv", ".git", "build", "install", "log", "out", "bags", "*.egg-info", "__pycache__"))
    colcon = Path(sys.executable).parent / "colcon"
    env = dict(os.environ, PATH=f"{Path(sys.executable).parent}:{os.environ['PATH']}")
    # the README's step as written: colcon build --packages-select hydro_ros, in the workspace root
    result = subprocess.run([str(colcon), "build", "--packages-select", "hydro_ros"], cwd=tmp_path, env=env, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    prefix = tmp_path / "install" / "hydro_ros"
    # ros2 run: ament index -> prefix -> lib/<package>/<executable>
    probe = subprocess.run(
        [sys.executable, "-c", "from ament_index_python.packages import get_package_prefix as g; print(g('hydro_ros'))"],
        env=dict(env, AMENT_PREFIX_PATH=str(prefix)), capture_output=True, text=True, check=True)
    assert Path(probe.stdout.strip()) == prefix
    for name in EXECUTABLES:
        exe = prefix / "lib" / "hydro_ros" / name
        assert exe.is_file() and os.access(exe, os.X_OK), f"{exe} missing"
    for name in ("sam.yaml", "foxglove_layout.json", "diagnostic_aggregator.yaml", "params/sam.yaml", "sros2/policy.xml"):
        assert (prefix / "share" / "hydro_ros" / "config" / name).is_file(), name
    assert (prefix / "share" / "hydro_ros" / "launch" / "machine.launch.py").is_file()
    pages = list(prefix.glob("lib/python3*/site-packages/hydro_ros/hmi/static/index.html"))
    assert pages and (pages[0].parent / "hmi.js").is_file()  # the HMI's page travels with the package
    installed = pages[0].parents[2]
    assert (installed / "planning" / "polish.py").is_file() and not (installed / "tooling").exists()  # the docs' tools stay behind
    assert (prefix / "share" / "hydro_ros" / "package.xml").is_file()
    assert (prefix / "share" / "hydro_ros" / "launch" / "crane_motion.launch.py").is_file()

    # the README's ROS-machine steps: the installed command (what `ros2 run hydro_ros hydro-ros` starts) on a user's config
    site = next(prefix.glob("lib/python3*/site-packages"))
    installed = dict(env, AMENT_PREFIX_PATH=str(prefix), PYTHONPATH=str(site))
    cli = [str(prefix / "lib" / "hydro_ros" / "hydro-ros")]
    own = tmp_path / "my_machine.yaml"
    made = subprocess.run([*cli, "machine", "new", "--like", "boom_arm", "--out", str(own)], env=installed, capture_output=True,
                          text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    params = subprocess.run([*cli, "params", "--config", str(own)], env=installed, capture_output=True, text=True, timeout=120)
    assert params.returncode == 0, params.stderr
    values = [line.strip() for line in params.stdout.splitlines() if line.strip().startswith("config:")]
    assert values and all(value == f'config: "{own}"' for value in values), values  # the path it was given, in every node
