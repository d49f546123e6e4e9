"""make bench's stamps and its resuming: the code hash follows the code and nothing written from the results, a step
runs again exactly when one of its files does not hold the code as it is, and --dask runs the untimed steps on a
cluster after the timed ones ran here alone."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest

from hydro_ros.tooling import benchrun
from hydro_ros.tooling.benchresults import code_hash, imported_by, moved, write_result
from test.conftest import REPO


def _git(root: Path, *args: str) -> None:
    subprocess.run(["git", "-c", "user.name=t", "-c", "user.email=t@t", *args], cwd=root, check=True, capture_output=True)


@pytest.fixture()
def checkout(tmp_path) -> Path:
    for name, text in {"hydro_ros/model.py": "K = 1\n", "docs/model.md": "K is 1\n", "README.md": "read me\n",
                       "bench/results/r.json": "{}\n", ".gitignore": "out/\n"}.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    _git(tmp_path, "init", "-q")
    _git(tmp_path, "add", "-A")
    _git(tmp_path, "commit", "-qm", "c")
    return tmp_path


def test_a_narrowed_code_hash_follows_only_the_code_it_names(checkout):
    """A hash narrowed to some paths, less some of them, moves only with the code it names (make bench narrows each
    step to its imports with ``paths``)."""
    def run_code() -> str:
        return code_hash(checkout, paths=("hydro_ros",), excluding=("hydro_ros/nodes",))

    before = run_code()
    (checkout / "hydro_ros" / "nodes").mkdir()
    (checkout / "hydro_ros" / "nodes" / "node.py").write_text("RATE = 10\n")
    (checkout / "test_other.py").write_text("x = 1\n")
    assert run_code() == before != code_hash(checkout)
    (checkout / "hydro_ros" / "model.py").write_text("K = 3\n")
    assert run_code() != before
    with pytest.raises(ValueError, match=r"requirements\.txt not in"):  # never the empty tree's hash for a path that is not there
        code_hash(checkout, paths=("hydro_ros", "requirements.txt"))


def test_the_code_a_script_reads_is_what_it_imports_through_the_package_and_nothing_else(tmp_path):
    files = {
        "bench/job.py": "import numpy\nfrom hydro_ros.lower import kernel\n",
        "hydro_ros/__init__.py": "",
        "hydro_ros/lower/__init__.py": "",
        "hydro_ros/lower/kernel.py": "def f():\n    from hydro_ros import helper  # lazily\n",
        "hydro_ros/helper.py": "import hydro_ros.stamps.write\n",
        "hydro_ros/stamps/__init__.py": "",
        "hydro_ros/stamps/write.py": "",
        "hydro_ros/planner.py": "from hydro_ros.lower import kernel\n",  # imports the job's code, is not imported by it
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert imported_by("bench/job.py", tmp_path, leaving=("hydro_ros/stamps",)) == (
        "bench/job.py", "hydro_ros/__init__.py", "hydro_ros/helper.py", "hydro_ros/lower/__init__.py", "hydro_ros/lower/kernel.py")
    (tmp_path / "hydro_ros/helper.py").write_text("from .kernel import g\n")
    with pytest.raises(ValueError, match=r"helper\.py:1: a relative import"):
        imported_by("bench/job.py", tmp_path)
    # the fault-free hours' key: the monitor and the plants, not the planner, the nodes or the tooling
    hours = imported_by("bench/fault_free_hours.py", leaving=("hydro_ros/tooling",))
    assert {"hydro_ros/fdi/ukf.py", "hydro_ros/studies/independent_arm.py", "hydro_ros/models/chamber.py"} <= set(hours)
    assert not [f for f in hours if f.startswith(("hydro_ros/planning", "hydro_ros/nodes", "hydro_ros/cli", "hydro_ros/tooling"))]


def test_fault_free_hours_adopt_another_codes_runs_only_where_this_code_computes_them_again_bit_for_bit(tmp_path):
    import importlib.util

    spec = importlib.util.spec_from_file_location("fault_free_hours", REPO / "bench" / "fault_free_hours.py")
    hours = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hours)
    models = {"1": {"fdi": {"threshold_constant": 0.05}}}
    runs = [{"rig": 1, "seed": 1000 + k, "seconds": 120.0, "alarms": [{"time_s": 30.0}] if k == 3 else []} for k in range(5)]
    by_seed = {r["seed"]: r for r in runs}

    def same(seeds):  # this code computes the runs as they were
        return [by_seed[seed] for seed in seeds]

    def cache(key: str, models: dict, runs: list[dict]) -> Path:
        folder = tmp_path / key / "sam"
        folder.mkdir(parents=True)
        (folder / "models.json").write_text(json.dumps(models))
        (folder / "runs.jsonl").write_text("".join(json.dumps(r) + "\n" for r in runs))
        return folder

    cache("short", models, runs[:3])
    cache("other_models", {"1": {"fdi": {"threshold_constant": 0.06}}}, runs)
    (cache("torn", models, runs) / "runs.jsonl").write_text('{"rig": 1, "se')  # a killed writer's: skipped, not fatal
    mine = (tmp_path / "now" / "sam")
    mine.mkdir(parents=True)
    first = runs[:2]
    assert hours._adopted(mine, models, first, same) == ("short", runs[:3])  # the longest whose models are this code's
    cache("long", models, runs)
    assert hours._adopted(mine, models, first, same) == ("long", runs)
    quiet = lambda seeds: [dict(by_seed[seed], alarms=[]) for seed in seeds]  # noqa: E731  this code no longer alarms at 1003
    assert hours._adopted(mine, models, first, quiet) == ("short", runs[:3])
    moved = [dict(runs[0], alarms=[{"time_s": 12.0}]), runs[1]]  # this code alarms where the cached did not
    assert hours._adopted(mine, models, moved, same) == (None, moved)


def test_the_code_hash_follows_the_code_committed_or_not_and_nothing_written_from_the_results(checkout):
    committed = code_hash(checkout)
    assert len(committed) == 40
    (checkout / "docs" / "model.md").write_text("K is 2\n")
    (checkout / "README.md").write_text("new figures\n")
    (checkout / "bench" / "results" / "r.json").write_text('{"x": 1}\n')
    (checkout / "out").mkdir()
    (checkout / "out" / "scratch.txt").write_text("ignored\n")
    assert code_hash(checkout) == committed
    (checkout / "hydro_ros" / "model.py").write_text("K = 2\n")
    changed = code_hash(checkout)
    assert changed != committed
    (checkout / "hydro_ros" / "new.py").write_text("")  # a file not yet added counts: it ran
    assert code_hash(checkout) not in (committed, changed)
    (checkout / "hydro_ros" / "new.py").unlink()
    (checkout / "hydro_ros" / "model.py").write_text("K = 1\n")
    assert code_hash(checkout) == committed


def test_a_step_is_pending_until_every_file_it_writes_holds_the_code(tmp_path):
    steps = (benchrun.Step("a", "a"), benchrun.Step("b", "b", also=("b_more",)), benchrun.Step("c", "c"))
    (tmp_path / "a.json").write_text(json.dumps({"commit": "x", "code": "new"}))
    (tmp_path / "b.json").write_text(json.dumps({"commit": "x", "code": "new"}))
    (tmp_path / "b_more.json").write_text(json.dumps({"commit": "x", "code": "old"}))  # half of b from an older run
    (tmp_path / "c.json").write_text("{not json")  # an interrupted write
    new, old = dict.fromkeys("abc", "new"), dict.fromkeys("abc", "old")
    assert [s.name for s in benchrun.pending(steps, new, tmp_path)] == ["b", "c"]
    assert [s.name for s in benchrun.pending(steps, old, tmp_path)] == ["a", "b", "c"]
    assert [s.name for s in benchrun.pending(steps, {**new, "a": "old"}, tmp_path)] == ["a", "b", "c"]  # a's own code changed
    (tmp_path / "b_more.json").write_text(json.dumps({"commit": "x"}))  # written before files recorded their code
    assert [s.name for s in benchrun.pending(steps, new, tmp_path)] == ["b", "c"]
    (tmp_path / "b_more.json").write_text(json.dumps({"code": "new"}))
    (tmp_path / "a.json").write_text(json.dumps({"code": "new", "complete": False}))  # stopped by its own budget: goes on
    assert [s.name for s in benchrun.pending(steps, new, tmp_path)] == ["a", "c"]


def test_a_steps_code_is_what_its_script_and_the_processes_it_names_import_or_else_the_whole_tree(tmp_path):
    files = {
        "bench/quiet.py": "from hydro_ros.model import f\n",
        "bench/spawning.py": "from hydro_ros.runner import go\n",
        "hydro_ros/__init__.py": "",
        "hydro_ros/model.py": "def f():\n    return 1\n",
        "hydro_ros/runner.py": "import subprocess\n\ndef go():\n    subprocess.run(['python', '-m', 'hydro_ros.nodes.x'])\n",
        "hydro_ros/tooling/benchresults.py": "import subprocess  # git, to stamp\n",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    (tmp_path / "bench/quiet.py").write_text("from hydro_ros.model import f\nfrom hydro_ros.tooling.benchresults import x\n")
    assert benchrun.Step("quiet", "quiet").reads(tmp_path) == (
        "bench/quiet.py", "hydro_ros/__init__.py", "hydro_ros/model.py", "hydro_ros/tooling/benchresults.py", *benchrun.DATA)
    assert benchrun.Step("spawning", "spawning").reads(tmp_path) is None
    # named, what the processes run is read as the script is, and nothing of the package beyond it
    (tmp_path / "hydro_ros/nodes").mkdir()
    (tmp_path / "hydro_ros/nodes/__init__.py").write_text("")
    (tmp_path / "hydro_ros/nodes/x.py").write_text("from hydro_ros.model import f\n")
    (tmp_path / "hydro_ros/unused.py").write_text("")
    assert benchrun.Step("spawning", "spawning", starts=("hydro_ros.nodes.x",)).reads(tmp_path) == (
        "bench/spawning.py", "hydro_ros/__init__.py", "hydro_ros/runner.py", "hydro_ros/model.py", "hydro_ros/nodes/__init__.py",
        "hydro_ros/nodes/x.py", *benchrun.DATA)
    with pytest.raises(ValueError, match=r"hydro_ros\.nodes\.gone is not a module"):
        benchrun.Step("spawning", "spawning", starts=("hydro_ros.nodes.gone",)).reads(tmp_path)
    # the shipped steps: the long evaluations follow their own code, what runs nodes or the CLI theirs too, mutants the whole tree
    shipped = {step.name: step.reads() for step in benchrun.STEPS}
    assert shipped["fault_free_hours"] and shipped["gsa_convergence"] and shipped["savings_map"] and shipped["mutants"] is None
    assert "hydro_ros/nodes/hmi.py" in shipped["hmi"] and not [f for f in shipped["hmi"] if f.startswith("test/")]
    assert not [f for f in shipped["savings_map"] if f.startswith(("hydro_ros/fdi", "hydro_ros/nodes", "hydro_ros/cli"))]


def test_a_result_file_records_the_code_that_wrote_it(tmp_path, monkeypatch):
    monkeypatch.delenv(benchrun.CODE_ENV, raising=False)  # as outside make bench (bench/mutants.py runs this test inside it)
    written = json.loads(write_result(tmp_path / "r.json", {"code": "forged", "value": 1}).read_text())
    assert written["code"] == code_hash() and written["value"] == 1 and list(written)[:2] == ["commit", "code"]
    monkeypatch.setenv(benchrun.CODE_ENV, "started-on")  # make bench's run: the code it started on, not the tree at the end
    assert json.loads(write_result(tmp_path / "r.json", {}).read_text())["code"] == "started-on"


def test_every_result_file_is_written_by_one_step_and_what_the_benchmark_page_times_runs_alone():
    from hydro_ros.tooling.benchresults import RESULTS, ROWS

    written = {name for step in benchrun.STEPS for name in step.writes}
    assert {path.stem for path in RESULTS.glob("*.json")} == written
    assert len(written) == sum(len(step.writes) for step in benchrun.STEPS)  # no file written by two steps
    for step in benchrun.STEPS:
        assert (benchrun.ROOT / "bench" / f"{step.script}.py").is_file(), step.script
    # the page reads a speed, a latency or a memory from each of its files but the mutation run's: those run alone
    assert {name for name, _, _ in ROWS} - {s.name for s in benchrun.STEPS if s.timed} == {"mutants"}


def test_resuming_runs_only_the_pending_steps_timed_ones_here_first_the_rest_on_dask(tmp_path, monkeypatch):
    from dask.distributed import LocalCluster

    steps = (benchrun.Step("speed", "s", timed=True), benchrun.Step("eval", "e"), benchrun.Step("done", "d"),
             benchrun.Step("eval2", "e2"))
    (tmp_path / "done.json").write_text(json.dumps({"code": "now-done"}))
    log = tmp_path / "ran.log"  # a file, not a list: dask hands its workers a copy of the function

    def run_step(step: benchrun.Step, code: str) -> tuple[str, int, float]:
        import threading

        with log.open("a") as f:
            f.write(f"{step.name} {threading.current_thread().name} {code}\n")
        return step.name, 1 if step.name == "eval2" else 0, 0.0

    monkeypatch.setattr(benchrun, "STEPS", steps)
    monkeypatch.setattr(benchrun, "RESULTS", tmp_path)
    monkeypatch.setattr(benchrun, "code_hash", lambda: "now")
    monkeypatch.setattr(benchrun, "step_code", lambda step: f"now-{step.name}")
    monkeypatch.setattr(benchrun, "run_step", run_step)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        status = benchrun.main(["--allow-dirty", "--dask", cluster.scheduler_address])
    assert status == 1  # eval2 failed
    ran = [line.split() for line in log.read_text().splitlines()]
    assert len(ran) == 3 and ran[0] == ["speed", "MainThread", "now-speed"]  # "done" not rerun; the timed step first, and here
    assert sorted(name for name, thread, _ in ran[1:] if thread != "MainThread") == ["eval", "eval2"]
    assert all(code == f"now-{name}" for name, _, code in ran)  # each step told its own code as the run started, on a worker too


def test_a_steps_code_includes_its_arguments_and_a_run_stops_when_a_steps_code_changes_before_or_while_it_runs(tmp_path, monkeypatch):
    plain, mobile = benchrun.Step("c", "commissioning"), benchrun.Step("c", "commissioning", ("--config", "config/sam_mobile.yaml"))
    assert benchrun.step_code(plain) != benchrun.step_code(mobile) and benchrun.step_code(plain) == benchrun.step_code(plain)
    steps = (benchrun.Step("first", "f"), benchrun.Step("second", "s"))
    edits = {"first": 0, "second": 0}  # how many times each step's code was read: "second" is edited while "first" runs

    def step_code(step: benchrun.Step) -> str:
        edits[step.name] += 1
        return f"{step.name}-{'edited' if step.name == 'second' and edits['second'] > 1 else 'as started'}"

    ran = []
    monkeypatch.setattr(benchrun, "STEPS", steps)
    monkeypatch.setattr(benchrun, "RESULTS", tmp_path)
    monkeypatch.setattr(benchrun, "step_code", step_code)
    monkeypatch.setattr(benchrun, "run_step", lambda step, code: ran.append(step.name) or (step.name, 0, 0.0))
    with pytest.raises(SystemExit, match="the code second runs changed before it ran"):
        benchrun.main(["--allow-dirty"])
    assert ran == ["first"]


def test_a_rerun_names_the_figures_it_moved_and_not_the_machine_bound_ones(tmp_path, capsys):
    before = {"commit": "a", "code": "x", "wall_s": 10.0, "rows": [{"gap": 0.781, "named": "leak", "delays_s": [3.0]}],
              "runs_per_s": 50.0, "hours": 7.2}
    after = {"commit": "b", "code": "y", "wall_s": 14.0, "rows": [{"gap": 0.7835, "named": "leak", "delays_s": [3.1]}],
             "runs_per_s": 30.0, "hours": 7.2, "extra": 1}
    assert moved(before, after) == ["rows[0].delays_s[0]: 3 -> 3.1", "extra: added"]  # 0.781 -> 0.7835 is within 0.5 %
    assert moved(before, {**after, "rows": []}) == ["rows: 1 -> 0 entries", "extra: added"]
    (tmp_path / "mems.json").write_text(json.dumps(after))
    step = benchrun.Step("mems", "mems")
    assert benchrun.report_moves(step, {"mems": before}, 0, tmp_path, tmp_path / "moved") == ["mems: rows[0].delays_s[0]: 3 -> 3.1",
                                                                                              "mems: extra: added"]
    assert json.loads((tmp_path / "moved" / "mems.json").read_text())["moved"][0] == "mems: rows[0].delays_s[0]: 3 -> 3.1"
    assert "2 figures moved by more than 0.5 %" in capsys.readouterr().out
    assert benchrun.report_moves(step, {"mems": before}, 1, tmp_path, tmp_path / "moved") == []
    assert "failed (status 1): its files are not compared" in capsys.readouterr().out


def test_same_outputs_names_each_output_that_differs_and_nothing_else(tmp_path, monkeypatch):
    """hydro_ros.tooling.same_outputs compares two commits' outputs exactly, places and times left out."""
    from hydro_ros.tooling import same_outputs

    for run, (delay, wall, threshold) in {"a": (12.0, 3.1, 0.063), "b": (12.0, 9.9, 0.064)}.items():
        (tmp_path / run / "discrepancy").mkdir(parents=True)
        for name in ("leak_fdi.json", "mobile_fdi.json", "discrepancy/report.json"):
            (tmp_path / run / name).write_text(json.dumps({"bag": f"/{run}/bag", "wall_s": wall, "first_alarm_s": delay}))
        (tmp_path / run / "commissioned.yaml").write_text(f"extends: /{run}/sam.yaml\nfdi:\n  threshold_constant: {threshold}\n")
    monkeypatch.setattr(same_outputs, "BAGS", ())
    assert same_outputs.differences(tmp_path / "a", tmp_path / "b") == ["commissioned.yaml: fdi.threshold_constant: 0.063 -> 0.064"]
    shipped = REPO / "bags"
    assert same_outputs.bag_digest(shipped / "fault_free") == same_outputs.bag_digest(shipped / "fault_free")
    assert same_outputs.bag_digest(shipped / "fault_free") != same_outputs.bag_digest(shipped / "external_leakage_a")


def test_the_soak_judges_the_plants_deadman_by_what_its_valves_got_and_lists_creep_on_neutral_valves_apart():
    """A killed executor: a command the plant applied after the deadman's bound is a violation, whatever the telescope
    did; a telescope creeping on neutral valves is the plant's leakage, measured and listed, not a violation."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("safety_soak", REPO / "bench" / "safety_soak.py")
    soak = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(soak)
    kill = {"kind": "executor_kill", "begin": 100.0, "end": 101.6}
    commands = [(t, 0.3) for t in np.arange(90.0, 100.0, 0.01)]  # the executor moved until killed
    t = np.arange(90.0, 101.6, 0.001)
    creeping = [(s, 0.004 * (s - 100.0)) for s in t]  # 4 mm/s on neutral valves

    def judged(neutral_after_s: float) -> dict:
        return soak.judge(commands, creeping, (t, np.where(t < 100.0 + neutral_after_s, 0.3, 0.0)), [kill], 90.0, 0.5, 0.5)

    kept = judged(0.505)
    assert kept["violations"] == [] and kept["measured_s"]["executor_kill"]["max"] == pytest.approx(0.505, abs=2e-3)
    assert kept["telescope_creep_m_s"]["max"] == pytest.approx(0.004, rel=1e-6)
    late = judged(0.6)
    assert [v["last_applied_command_after_s"] for v in late["violations"]] == [pytest.approx(0.6, abs=2e-3)]
    assert late["telescope_creep_m_s"] is None  # valves open past the bound: no creep on neutral valves to measure
    blind = soak.judge(commands, creeping, (np.zeros(0), np.zeros(0)), [kill], 90.0, 0.5, 0.5)
    assert blind["violations"] == [{**kill, "no_plant_samples": True}]  # a deadman never seen is not passed


def test_a_step_that_names_what_its_processes_run_names_every_module_its_script_starts():
    """Each module a bench script names as a string (``python -m hydro_ros...``) or imports in code it hands a process
    (``python -c``) is among what its step reads; a module named by an f-string cannot be checked, so none is."""
    import ast
    import re

    for step in (step for step in benchrun.STEPS if step.starts is not None):
        reads = set(step.reads())
        script = REPO / "bench" / f"{step.script}.py"
        named: set[str] = set()
        for node in ast.walk(ast.parse(script.read_text())):
            if isinstance(node, ast.JoinedStr):
                text = "".join(part.value for part in node.values if isinstance(part, ast.Constant))
                assert not re.match(r"hydro_ros\.\w*\.?$", text), f"{script.name}: a module named by an f-string ({text}...)"
            elif isinstance(node, ast.Constant) and isinstance(node.value, str):
                if re.fullmatch(r"hydro_ros(\.\w+)+", node.value):
                    named.add(node.value)
                elif "import" in node.value:
                    try:
                        code = ast.parse(node.value)
                    except SyntaxError:
                        continue
                    named |= {name for inner in ast.walk(code) for name in (
                        [inner.module] if isinstance(inner, ast.ImportFrom) and inner.module else
                        [alias.name for alias in inner.names] if isinstance(inner, ast.Import) else []) if name.startswith("hydro_ros")}
        missing = [module for module in named if not set(benchrun.module_entries(module)) <= reads]
        assert not missing, f"{step.name}: starts {missing} but does not read them"
