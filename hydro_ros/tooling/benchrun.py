"""`make bench` (``python -m hydro_ros.tooling.benchrun``): every benchmark, each skipped when its result files already hold the code as it is (resumable).

A step is done when every file it writes in bench/results carries ``code`` equal to the hash of the code the step reads
now and its arguments (:func:`step_code`: its script, the package's files it imports followed through the package, the
configs, the bags and the pins; for a script that runs other processes, whose imports no walk sees, the same of every
module it names as what they run (``Step.starts``), or the whole tree, less bench/results and the docs written from
them, where it names none) and none says ``"complete": false`` (a step stopped by its own budget, which goes on when run
again). An interrupted ``make bench`` therefore goes on where it stopped, and a commit reruns only the steps whose code it
changed: the full run can be gathered over several sittings, each file backed by the code as it is. Results carry the
hash taken when the step started (``CODE_ENV``); a run whose code changes under a step stops. ``--force`` reruns every
step; ``--only NAME`` picks steps.

``--dask ADDRESS`` (a ``dask.distributed`` scheduler, ``local`` for a cluster of this machine's cores) runs the
evaluations on its workers, which must share this checkout (the same path); the steps whose speeds or latencies the
benchmark page reads run here, one at a time, before them, so no other work skews what they time.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.extras import optional_module
from hydro_ros.tooling.benchresults import CODE_ENV, RESULTS, ROOT, code_hash, imported_by, moved, require_clean_tree

MOVES = ROOT / "out" / "bench-moved"  # per step, what its rerun moved against the files it replaced


@dataclass(frozen=True)
class Step:
    name: str  # its main file, bench/results/<name>.json
    script: str  # bench/<script>.py
    args: tuple[str, ...] = ()
    also: tuple[str, ...] = ()  # the other stamped files it writes in bench/results
    timed: bool = False  # the benchmark page reads a speed or a latency from it: run alone
    # the package's modules any process the step starts runs (``python -m``, ``-c``), each read as its script is; None:
    # not named, so a step whose code starts processes reads the whole tree. () for processes of its own code only (a
    # multiprocessing pool). test_benchrun holds each name to the modules its scripts start.
    starts: tuple[str, ...] | None = None

    @property
    def writes(self) -> tuple[str, ...]:
        return (self.name, *self.also)

    def command(self) -> list[str]:
        return [sys.executable, str(ROOT / "bench" / f"{self.script}.py"), *self.args, "--out", f"bench/results/{self.name}.json"]

    def reads(self, root: Path = ROOT) -> tuple[str, ...] | None:
        """The paths whose code the step runs (see the module's docstring); None for the whole tree: its script, or a
        package file it imports, starts other processes (the CLI, the nodes) and the step does not name what they run
        (``starts``), git's calls that stamp the results aside."""
        files = imported_by(f"bench/{self.script}.py", root)
        if any(SPAWNS.search((root / f).read_text()) for f in files if f not in STAMPING):
            if self.starts is None:
                return None
            started = {f for module in self.starts for entry in module_entries(module, root) for f in imported_by(entry, root)}
            files = (*files, *sorted(started - set(files)))
        return (*files, *DATA)


def module_entries(module: str, root: Path = ROOT) -> tuple[str, ...]:
    """The files ``python -m module`` runs first: the module's file, or its package's ``__init__`` and ``__main__``, after
    the ``__init__`` of every package above it."""
    parts = module.split(".")
    base = root.joinpath(*parts)
    entries = [path for path in (base.with_suffix(".py"), base / "__init__.py", base / "__main__.py") if path.is_file()]
    if not entries:
        raise ValueError(f"Step.starts: {module} is not a module under {root}")
    above = (root.joinpath(*parts[:i], "__init__.py") for i in range(1, len(parts)))
    return tuple(str(path.relative_to(root)) for path in (*(path for path in above if path.is_file()), *entries))


SPAWNS = re.compile(r"\bsubprocess\b|\bPopen\b|\bos\.system\b|\bexecv|\bspawn|\bcreate_subprocess")
STAMPING = ("hydro_ros/tooling/benchresults.py",)  # runs git to stamp what ran, computes nothing
DATA = ("config", "bags", "requirements.txt")  # what every step may read beside code: the configs, the bags, the pins


def step_code(step: Step) -> str:
    """The hash of the code ``step`` runs now and of its arguments, which its result files must carry to be current."""
    reads = step.reads()
    tree = code_hash() if reads is None else code_hash(paths=reads)
    return hashlib.sha1(f"{tree} {step.script} {step.args!r}".encode()).hexdigest()


def _step(name: str, *args: str, script: str | None = None, also: tuple[str, ...] = (), timed: bool = False,
          starts: tuple[str, ...] | None = None) -> Step:
    return Step(name, script or name, args, also, timed, starts)


STEPS = (
    _step("results", script="run", also=("fdi_eval", "fdi_parity_eval", "gsa"), timed=True,
          starts=("hydro_ros.nodes.plant_sim", "hydro_ros.nodes.fdi_node", "hydro_ros.nodes.can_bridge", "hydro_ros.cli")),
    _step("discrepancy_suite", also=("discrepancy_independent",), timed=True),  # reproduction.md quotes its time per bag
    _step("dp", timed=True, starts=("hydro_ros.cli", "hydro_ros.planning.reference"), also=tuple(f"dp_compare_{case}" for case in (  # bench/dp.py's comparisons
        "k70m_horizontal", "k70m_vertical", "k70m_half_cycle", "k70m_horizontal_middle", "k70m_vertical_middle",
        "k70m_half_cycle_middle", "crane3dof_triangle", "excavator_level_cut", "excavator_lift_out"))),
    _step("trajectories", timed=True, starts=("hydro_ros.nodes.trajectory_server",)),
    _step("hmi", timed=True, starts=("hydro_ros.nodes.plant_sim", "hydro_ros.nodes.fdi_node", "hydro_ros.nodes.hmi")),
    _step("commissioning"),
    _step("commissioning_mobile", "--config", "config/sam_mobile.yaml", script="commissioning"),
    _step("commissioning_memory", timed=True, starts=("hydro_ros.cli",)),
    _step("arm_commissioning"),
    _step("sam_commissioning_apart", "--config", "config/sam.yaml", script="arm_commissioning"),
    _step("roc"),
    _step("fault_free_hours", "--budget-min", "600"),
    _step("crane_monitoring"),
    _step("crane_cpu", timed=True, starts=("hydro_ros.nodes.plant_sim", "hydro_ros.nodes.fdi_node")),
    _step("crane_commissioning"),
    _step("crane_apart"),
    _step("fleet", timed=True, starts=()),
    _step("mems"),
    _step("savings_map"),
    _step("mount_sweep"),
    _step("gsa_convergence"),
    _step("safety_soak", "--duration", "1800", timed=True,
          starts=("hydro_ros.nodes.plant_sim", "hydro_ros.nodes.fdi_node", "hydro_ros.nodes.trajectory_executor")),
    _step("halt_latency", "--trials", "40", timed=True, starts=("hydro_ros.nodes.trajectory_executor",)),
    _step("mutants"),
)


def _read(name: str, results: Path = RESULTS) -> object:
    """A result file's content; None where there is no file or it cannot be read."""
    try:
        return json.loads((results / f"{name}.json").read_text())
    except (OSError, ValueError):
        return None


def current(name: str, code: str, results: Path = RESULTS) -> bool:
    """Whether a result file holds ``code`` and is complete (no file, an unreadable one or one written before files
    recorded their code is not)."""
    data = _read(name, results)
    return isinstance(data, dict) and data.get("code") == code and data.get("complete", True) is not False


def pending(steps: tuple[Step, ...], codes: dict[str, str], results: Path = RESULTS) -> list[Step]:
    """The steps some of whose files do not hold their step's code (``codes``: per step name) or are not complete."""
    return [step for step in steps if not all(current(name, codes[step.name], results) for name in step.writes)]


def run_step(step: Step, code: str) -> tuple[str, int, float]:
    """Runs one step from the checkout's root, its results stamped with ``code`` (on a Dask worker too, whose
    environment is not this process's): (name, exit status, seconds)."""
    start = time.monotonic()
    status = subprocess.run(step.command(), cwd=ROOT, check=False, env={**os.environ, CODE_ENV: code}).returncode
    return step.name, status, time.monotonic() - start


def _previous(step: Step, results: Path = RESULTS) -> dict[str, object]:
    return {name: data for name in step.writes if (data := _read(name, results)) is not None}


def report_moves(step: Step, previous: dict[str, object], status: int = 0, results: Path = RESULTS, out: Path = MOVES) -> list[str]:
    """What the step's rerun moved by more than 0.5 % against the files it replaced (issue 56: refactors leave the published
    numbers as they were), printed and kept in out/bench-moved/<step>.json; nothing for a step that failed."""
    if status != 0:
        print(f"bench: {step.name} failed (status {status}): its files are not compared", flush=True)
        return []
    lines = [f"{name}: {line}" for name, before in previous.items() if (after := _read(name, results)) is not None
             for line in moved(before, after)]
    out.mkdir(parents=True, exist_ok=True)
    (out / f"{step.name}.json").write_text(json.dumps({"compared": list(previous), "moved": lines}, indent=1) + "\n")
    shown = "; ".join(lines[:6]) + (f"; ... ({len(lines)} in {out / step.name}.json)" if len(lines) > 6 else "")
    print(f"bench: {step.name}: " + (f"{len(lines)} figures moved by more than 0.5 % from the files it replaced: {shown}" if lines
                                     else f"every figure within 0.5 % of the files it replaced ({', '.join(previous) or 'none'})"), flush=True)
    return lines


def _on_dask(steps: list[Step], address: str, codes: dict[str, str]) -> list[tuple[str, int, float]]:
    try:
        distributed = optional_module("distributed")
    except InputError as exc:
        raise SystemExit(f"make bench --dask: {exc}") from None
    cluster = distributed.LocalCluster(threads_per_worker=1) if address == "local" else None
    with distributed.Client(cluster or address) as client:
        futures = {client.submit(run_step, step, codes[step.name], key=f"bench-{step.name}", pure=False): step.name for step in steps}
        done = []
        for future in distributed.as_completed(list(futures)):
            try:
                done.append(future.result())
            except Exception as exc:  # a worker lost or a step that raised: the others' results stand
                done.append((futures[future], 1, 0.0))
                print(f"bench: {futures[future]} failed on dask: {exc}", file=sys.stderr, flush=True)
                continue
            print(f"bench: {done[-1][0]} finished on dask (status {done[-1][1]}, {done[-1][2] / 60:.1f} min)", flush=True)
    if cluster is not None:
        cluster.close()
    return done


def _unchanged(step: Step, codes: dict[str, str], when: str) -> None:
    """Stops the run where ``step``'s code is no longer what the run started on: its results would carry the wrong code."""
    if step_code(step) != codes[step.name]:
        raise SystemExit(f"make bench: the code {step.name} runs changed {when} it ran: its results carry the code the run "
                         "started on; commit, then run make bench again")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--force", action="store_true", help="rerun every step, current or not")
    parser.add_argument("--only", action="append", choices=[s.name for s in STEPS], help="these steps only (repeatable)")
    parser.add_argument("--dask", metavar="ADDRESS", help="run the untimed steps on this dask.distributed scheduler ('local': here)")
    parser.add_argument("--allow-dirty", action="store_true", help="run on uncommitted code (its results say +changes)")
    parser.add_argument("--list", action="store_true", help="print each step and whether it is current, run nothing")
    args = parser.parse_args(argv)
    if not (args.allow_dirty or args.list):
        require_clean_tree()
    if code_hash() == "unknown":
        raise SystemExit(f"make bench: {ROOT} is not a git checkout: a result could not say which code ran (clone the repository)")
    chosen = tuple(s for s in STEPS if not args.only or s.name in args.only)
    codes = {step.name: step_code(step) for step in chosen}
    todo = list(chosen) if args.force else pending(chosen, codes, RESULTS)
    if args.list:
        for step in chosen:
            print(f"{step.name:28s} {'to run' if step in todo else 'current'}  ({', '.join(step.writes)})")
        return 0
    print(f"bench: {len(todo)} of {len(chosen)} steps to run"
          + (f"; current, skipped: {', '.join(s.name for s in chosen if s not in todo)}" if len(todo) < len(chosen) else ""), flush=True)
    alone = [s for s in todo if s.timed or not args.dask]
    results = []
    for step in alone:
        _unchanged(step, codes, "before")
        print(f"bench: {step.name}: {' '.join(step.command()[1:])}", flush=True)
        previous = _previous(step)
        results.append(run_step(step, codes[step.name]))
        report_moves(step, previous, results[-1][1])
        _unchanged(step, codes, "while")
    if args.dask and len(alone) < len(todo):
        remote = [s for s in todo if s not in alone]
        previous = {s.name: _previous(s) for s in remote}
        for step in remote:
            _unchanged(step, codes, "before")
        finished = _on_dask(remote, args.dask, codes)
        exit_status = {name: status for name, status, _ in finished}
        for step in remote:
            report_moves(step, previous[step.name], exit_status.get(step.name, 1))
            _unchanged(step, codes, "while")
        results += finished
    failed = [name for name, status, _ in results if status != 0]
    if failed:
        print(f"bench: failed: {', '.join(failed)} (their files are not current; make bench reruns only what is not)", file=sys.stderr)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
