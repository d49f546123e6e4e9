"""Whether two commits compute the same: the contract's commands run at each (a SAM leak and a mobile-valve leak
simulated and monitored, three fault-free recordings simulated and commissioned, a hidden dead zone simulated and named
by the discrepancy workflow), their outputs compared exactly. A refactor that says it changes no behaviour shows it
here (issue 56), where ``make bench``'s reruns only hold the published figures to 0.5 %.

``python -m hydro_ros.tooling.same_outputs A B [--work DIR]``: each commit is checked out into its own worktree under
DIR and run with this checkout's environment; exits 1 naming each output that differs (file paths, plots and times
left out). About 2 minutes per commit.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from hydro_ros.bags.reader import read_bag
from hydro_ros.tooling.benchresults import ROOT, moved

# each a command line of ``hydro-ros`` with {out} for the commit's output folder
COMMANDS = (
    "sim --config config/sam.yaml --duration 40 --fault external_leakage_a=1@15 --seed 3 --out {out}/leak",
    "fdi run --config config/sam.yaml --bag {out}/leak --out {out}/leak_fdi.json",
    "sim --config config/sam_mobile.yaml --duration 40 --fault internal_leakage=1@15 --seed 4 --out {out}/mobile",
    "fdi run --config config/sam_mobile.yaml --bag {out}/mobile --out {out}/mobile_fdi.json",
    *(f"sim --config config/sam.yaml --duration 120 --seed {seed} --out {{out}}/free{seed}" for seed in (11, 12, 13)),
    "commission --config config/sam.yaml --bag {out}/free11 --bag {out}/free12 --bag {out}/free13 --out {out}/commissioned.yaml",
    "sim --config config/sam.yaml --duration 40 --effect valve_deadzone=0.06 --seed 5 --out {out}/hidden",
    "discrepancy --config config/sam.yaml --bag {out}/hidden --out {out}/discrepancy",
)
JSON_OUTPUTS = ("leak_fdi.json", "mobile_fdi.json", "discrepancy/report.json")
YAML_OUTPUTS = ("commissioned.yaml",)
BAGS = ("leak", "mobile", "free11", "free12", "free13", "hidden")
WHERE_NOT_WHAT = ("bag", "plot", "plots", "html", "path", "out", "config", "extends", "recordings", "wall_s", "seconds")


def without_places(value: Any) -> Any:
    """An output less what says where it was written or how long it took."""
    if isinstance(value, dict):
        return {k: without_places(v) for k, v in value.items() if k not in WHERE_NOT_WHAT}
    if isinstance(value, list):
        return [without_places(v) for v in value]
    return value


def bag_digest(path: Path) -> str:
    """A hash of every sample array of a contract bag (its file's own metadata, e.g. the writer's version, left out)."""
    data = read_bag(path)
    if not data.message_count:
        raise SystemExit(f"same_outputs: {path} holds no message")
    digest = hashlib.sha256()
    for name, value in sorted(vars(data).items()):
        arrays = [value] if isinstance(value, np.ndarray) else (
            [value[key] for key in sorted(value)] if isinstance(value, dict) and all(isinstance(v, np.ndarray) for v in value.values()) else [])
        for array in arrays:
            digest.update(name.encode())
            digest.update(np.ascontiguousarray(array).tobytes())
    return digest.hexdigest()


def differences(a: Path, b: Path) -> list[str]:
    """Every output of two runs (output folders of :func:`run`) that differs, exactly."""
    lines = []
    for name in JSON_OUTPUTS:
        lines += [f"{name}: {line}" for line in moved(*(without_places(json.loads((d / name).read_text())) for d in (a, b)), tolerance=0.0)]
    for name in YAML_OUTPUTS:
        lines += [f"{name}: {line}" for line in moved(*(without_places(yaml.safe_load((d / name).read_text())) for d in (a, b)), tolerance=0.0)]
    lines += [f"{bag}: its samples differ" for bag in BAGS if bag_digest(a / bag) != bag_digest(b / bag)]
    return lines


def run(commit: str, work: Path) -> Path:
    """The commands at ``commit`` (a worktree of this checkout under ``work``); their output folder."""
    tree, out = work / f"tree-{commit}", work / f"out-{commit}"
    if not tree.exists():
        added = subprocess.run(["git", "-C", str(ROOT), "worktree", "add", "-q", "--detach", str(tree), commit], capture_output=True, text=True)
        if added.returncode != 0:
            raise SystemExit(f"same_outputs: {commit}: {(added.stderr.strip().splitlines() or ['not a commit of this checkout'])[-1]}")
    out.mkdir(parents=True, exist_ok=True)
    env = {**os.environ, "PYTHONPATH": str(tree)}
    for command in COMMANDS:
        args = command.format(out=out).split()
        status = subprocess.run([sys.executable, "-m", "hydro_ros.cli", *args, "--quiet"], cwd=tree, env=env, check=False).returncode
        if status != 0:
            raise SystemExit(f"same_outputs: at {commit}, `hydro-ros {' '.join(args)}` exited {status}")
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hydro_ros.tooling.same_outputs", description=__doc__.splitlines()[0])
    parser.add_argument("before", help="a commit")
    parser.add_argument("after", help="another commit")
    parser.add_argument("--work", type=Path, default=ROOT / "out" / "same-outputs", help="where the worktrees and outputs go")
    args = parser.parse_args(argv)
    found = differences(run(args.before, args.work), run(args.after, args.work))
    print("\n".join(found) if found else f"{args.before} and {args.after}: every output the same, bit for bit")
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
