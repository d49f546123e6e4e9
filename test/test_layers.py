"""The package's layering holds: every import points down, no science imports ROS, no import cycle.

Imports are read from the source (module level and inside functions alike), so a lazy import that
would close a cycle or reach up a layer fails here too.
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "hydro_ros"

# each folder (or top-level module) and its layer; an import may reach its own folder or a lower layer
LAYER = {
    "contract": 0,
    "bags": 1,
    "safety": 1,  # the safety core: pure state machines, no ROS
    "can": 2,
    "models": 3,
    "sim": 4, "fdi": 4, "planning": 4,
    "workflows": 5, "hmi": 5,  # what ships: commissioning, the fleet view, the discrepancy workflow, execution, plots
    "studies": 6,  # the thesis's studies, which use the workflows
    "nodes": 7,
    "demo": 8,
    "processes": 8,  # node processes as the tests, benches and demo start them
    "cli": 9,
    "tooling": 10,  # not installed: the result files' writer, the papers' claims against them, the generated docs
}
SCIENCE = {"contract", "safety", "bags", "can", "models", "sim", "fdi", "planning", "workflows", "studies", "hmi"}
ROS_MODULES = ("rclpy", "rosidl", "rmw", "std_msgs", "sensor_msgs", "diagnostic_msgs", "trajectory_msgs", "std_srvs",
               "geometry_msgs", "rosgraph_msgs", "builtin_interfaces", "control_msgs")


def module_name(path: Path, package: Path = PACKAGE) -> str:
    parts = path.relative_to(package.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def imports(path: Path, package: Path = PACKAGE) -> set[str]:
    """Every module the file imports, absolute, whether at module level or inside a function."""
    name = module_name(path, package)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")[: len(package.split(".")) - node.level + 1]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.add(module)
            found.update(f"{module}.{alias.name}" for alias in node.names)
    return found


def graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    modules = {module_name(p, package): p for p in package.rglob("*.py")}
    return {name: {m for m in imports(path, package) if m in modules and m != name} for name, path in modules.items()}


def folder(module: str) -> str | None:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def test_every_module_belongs_to_a_layer() -> None:
    unplaced = sorted({folder(m) for m in graph()} - set(LAYER) - {None})
    assert not unplaced, f"folders or top-level modules without a layer: {unplaced}"


def upward_imports(package: Path = PACKAGE) -> list[str]:
    upward = []
    for module, deps in graph(package).items():
        here = folder(module)
        for dep in deps:
            there = folder(dep)
            if here is None or there is None or here == there:
                continue
            if LAYER[there] >= LAYER[here]:
                upward.append(f"{module} -> {dep}")
    return sorted(upward)


def ros_in_science(package: Path = PACKAGE) -> list[str]:
    offenders = []
    for path in package.rglob("*.py"):
        if folder(module_name(path, package)) in SCIENCE:
            ros = sorted(m for m in imports(path, package) if m.split(".")[0] in ROS_MODULES)
            if ros:
                offenders.append(f"{module_name(path, package)}: {', '.join(ros)}")
    return offenders


def cycles(package: Path = PACKAGE) -> list[list[str]]:
    edges = graph(package)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:  # Tarjan's strongly connected components
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for dep in edges[node]:
            if dep not in index:
                visit(dep)
                low[node] = min(low[node], low[dep])
            elif dep in on_stack:
                low[node] = min(low[node], index[dep])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(edges):
        if node not in index:
            visit(node)
    return found


def test_imports_point_down() -> None:
    assert not upward_imports(), "imports that do not point to a lower layer:\n" + "\n".join(upward_imports())


def test_science_never_imports_ros() -> None:
    assert not ros_in_science(), "science modules importing ROS:\n" + "\n".join(ros_in_science())


def test_no_import_cycle() -> None:
    assert not cycles(), f"import cycles: {cycles()}"


def test_the_checks_catch_violations(tmp_path: Path) -> None:
    """A planted package with an upward import, an rclpy import in science and a cycle fails each check."""
    package = tmp_path / "hydro_ros"
    for folder_name, source in (("fdi", "from hydro_ros.nodes.common import run_node\nimport rclpy\n"),
                                ("nodes", "from hydro_ros.nodes import other\n")):
        (package / folder_name).mkdir(parents=True)
        (package / folder_name / "__init__.py").write_text("")
        (package / folder_name / ("monitor.py" if folder_name == "fdi" else "common.py")).write_text(source)
    (package / "nodes" / "other.py").write_text("from hydro_ros.nodes.common import run_node\n")
    assert upward_imports(package) == ["hydro_ros.fdi.monitor -> hydro_ros.nodes.common"]
    assert ros_in_science(package) == ["hydro_ros.fdi.monitor: rclpy"]
    assert cycles(package) == [["hydro_ros.nodes.common", "hydro_ros.nodes.other"]]


def test_the_benchmarks_import_only_the_package_and_libraries():
    """bench/ scripts take what they share from hydro_ros, never from test/ or from each other, and need no sys.path edits."""
    bench = PACKAGE.parent / "bench"
    scripts = {path.stem for path in bench.glob("*.py")}
    for path in bench.glob("*.py"):
        text = path.read_text()
        assert "sys.path" not in text, path.name
        for node in ast.walk(ast.parse(text, str(path))):
            names = ([alias.name for alias in node.names] if isinstance(node, ast.Import)
                     else [node.module or ""] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                assert name.split(".")[0] not in {"test", *scripts}, f"{path.name} imports {name}"
