"""package.xml as rosdep sees it, and the import face a machine without the optional extras has."""

from __future__ import annotations

import ast
import subprocess
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

from hydro_ros.contract.extras import OPTIONAL

ROOT = Path(__file__).resolve().parents[1]
ROSDEP = Path(__file__).with_name("rosdep")  # ros/rosdistro at 8468e88: rosdep keys and Kilted packages
# import name -> package.xml key, for the libraries whose key is not the import name
KEY_OF_IMPORT = {
    "numpy": "python3-numpy", "scipy": "python3-scipy", "yaml": "python3-yaml", "matplotlib": "python3-matplotlib",
    "tqdm": "python3-tqdm", "numba": "python3-numba", "rosbags": "python3-rosbags-pip", "aiohttp": "python3-aiohttp",
    "can": "python3-can", "cantools": "python3-cantools-pip", "filterpy": "python3-filterpy-pip", "psutil": "python3-psutil",
    # dependencies of rosbags, used through it: its zstd and lz4 chunk codecs
    "backports": "python3-rosbags-pip", "compression": "python3-rosbags-pip", "lz4": "python3-rosbags-pip",
}


def _depends() -> dict[str, set[str]]:
    root = ET.parse(ROOT / "package.xml").getroot()
    kinds = ("depend", "exec_depend", "build_depend", "test_depend", "buildtool_depend", "build_export_depend")
    return {kind: {element.text.strip() for element in root.iter(kind)} for kind in kinds}


def test_every_package_xml_key_resolves_with_rosdep():
    known = set((ROSDEP / "rosdep_keys.txt").read_text().split()) | set((ROSDEP / "kilted_packages.txt").read_text().split())
    keys = set().union(*_depends().values())
    assert keys, "package.xml lists no dependencies"
    assert sorted(keys - known) == []


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            names |= {alias.name.split(".")[0] for alias in node.names}
        elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
            names.add(node.module.split(".")[0])
    return names


def test_every_third_party_import_is_declared_or_an_optional_extra():
    depends = _depends()
    declared = depends["exec_depend"] | depends["depend"]
    testing = declared | depends["test_depend"]
    stdlib = set(sys.stdlib_module_names) | {"hydro_ros", "__future__"}
    undeclared = []
    for path in sorted((ROOT / "hydro_ros").rglob("*.py")):
        for name in sorted(_imports(path) - stdlib - set(OPTIONAL)):
            key = KEY_OF_IMPORT.get(name, name)  # a ROS package imports as its own name (sensor_msgs, rclpy)
            # the filterpy twin serves only the tests and the benchmarks (it is imported by nothing that ships)
            allowed = testing if path.name == "filterpy_twin.py" else declared
            if key not in allowed:
                undeclared.append(f"{path.relative_to(ROOT)}: {name} ({key})")
    assert undeclared == []


def test_nodes_and_cli_import_without_the_optional_extras():
    blocked = [*sorted(OPTIONAL), "dask", "zstandard"]
    script = f"""
import importlib, importlib.abc, pkgutil, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name.split('.')[0] in {blocked!r}:
            raise ImportError('blocked: ' + name)
sys.meta_path.insert(0, Block())
import hydro_ros.nodes
for module in pkgutil.iter_modules(hydro_ros.nodes.__path__):
    importlib.import_module('hydro_ros.nodes.' + module.name)
import hydro_ros.cli, hydro_ros.demo
from hydro_ros.contract.extras import optional_module
try:
    optional_module('SALib.sample.sobol')
except ValueError as exc:
    print(exc)
"""
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == "hydro-ros gsa (Sobol indices) needs the optional Python package SALib: pip install SALib"
