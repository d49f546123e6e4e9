"""A listed mutation run (part of `make bench`): each mutant of the plant's fault injections and of the monitor's
isolation table (a flipped sign, a zeroed term, a swapped chamber or row) is applied to a clean copy of the committed
tree, and the tests that guard it must fail. A mutant they let pass is a hole in the suite.

Results: bench/results/mutants.json, one row per mutant (killed or survived, by which test, in how long).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from tqdm import tqdm

from hydro_ros.tooling.benchresults import write_result

REPO = Path(__file__).resolve().parents[1]
SAM = "hydro_ros/models/sam.py"
ISOLATION = "hydro_ros/fdi/isolation.py"
INJECTION_TESTS = ["test/test_injections.py"]
ISOLATION_TESTS = ["test/test_fdi.py"]

# (name, file, text, mutated text, the tests that must catch it)
MUTANTS = [
    ("B leak flows into the chamber", SAM, "q_ext_b = leak_flow(", "q_ext_b = -leak_flow(", INJECTION_TESTS),
    ("internal leak flows B to A", SAM, "q_int = leak_flow(", "q_int = -leak_flow(", INJECTION_TESTS),
    ("A leak zeroed", SAM, "q_ext_a = leak_flow(", "q_ext_a = 0.0 * leak_flow(", INJECTION_TESTS),
    ("A leak driven by B's pressure", SAM, "leak_flow(p[Param.K_EXTERNAL_A], p_a - p[Param.TANK]", "leak_flow(p[Param.K_EXTERNAL_A], p_b - p[Param.TANK]",
     INJECTION_TESTS),
    ("B leak taken from A", SAM, "dy[0] = bulk_a / volume_a * (q_a - q_int - q_ext_a", "dy[0] = bulk_a / volume_a * (q_a - q_int - q_ext_b",
     INJECTION_TESTS),
    ("air left out of chamber B", SAM,
     "effective_bulk_modulus(p_b, volume_b, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], air_fraction)",
     "effective_bulk_modulus(p_b, volume_b, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], 0.0)", INJECTION_TESTS),
    ("A and B leak rows swapped", ISOLATION,
     "PatternRow(Fault.EXTERNAL_LEAKAGE_A, A_DOWN, large=False),\n    PatternRow(Fault.EXTERNAL_LEAKAGE_B, B_DOWN, large=False),",
     "PatternRow(Fault.EXTERNAL_LEAKAGE_A, B_DOWN, large=False),\n    PatternRow(Fault.EXTERNAL_LEAKAGE_B, A_DOWN, large=False),",
     ISOLATION_TESTS),
    ("internal leak row's pressure condition flipped", ISOLATION, "PatternRow(Fault.INTERNAL_LEAKAGE, A_DOWN | B_UP, pa_gt_pb=True, large=False),",
     "PatternRow(Fault.INTERNAL_LEAKAGE, A_DOWN | B_UP, pa_gt_pb=False, large=False),", ISOLATION_TESTS),
    ("stuck spool row not large", ISOLATION, "PatternRow(Fault.SPOOL_STUCK_CLOSED, A_DOWN | B_UP, large=True, command_positive=True),",
     "PatternRow(Fault.SPOOL_STUCK_CLOSED, A_DOWN | B_UP, large=False, command_positive=True),", ISOLATION_TESTS),
    ("too large opening read as too small", ISOLATION, "PatternRow(Fault.SPOOL_TOO_LARGE_OPENING, A_UP | B_DOWN, large=False, command_positive=True),",
     "PatternRow(Fault.SPOOL_TOO_SMALL_OPENING, A_UP | B_DOWN, large=False, command_positive=True),", ISOLATION_TESTS),
]


def committed_tree(into: Path) -> None:
    archive = subprocess.run(["git", "-C", str(REPO), "archive", "HEAD"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)


def run_mutant(name: str, file: str, text: str, mutated: str, tests: list[str]) -> dict:
    with tempfile.TemporaryDirectory(prefix="mutant-") as folder:
        tree = Path(folder)
        committed_tree(tree)
        source = tree / file
        original = source.read_text()
        if original.count(text) != 1:
            raise SystemExit(f"mutant {name!r}: {text!r} is not once in {file}: the list is out of date")
        source.write_text(original.replace(text, mutated))
        start = time.perf_counter()
        env = {**os.environ, "PYTHONPATH": str(tree), "NUMBA_CACHE_DIR": str(tree / ".numba")}
        done = subprocess.run([sys.executable, "-m", "pytest", "-q", "-x", "-p", "no:cacheprovider", "-m", "not ros_graph", *tests],
                              cwd=tree, env=env, capture_output=True, text=True, timeout=3600)
        failed = [line.split(" ")[1] for line in done.stdout.splitlines() if line.startswith("FAILED ")]
        return {"mutant": name, "file": file, "killed": done.returncode != 0, "by": failed[:1], "seconds": round(time.perf_counter() - start, 1),
                "exit_code": done.returncode}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "bench" / "results" / "mutants.json"))
    args = parser.parse_args()
    rows = [run_mutant(*mutant) for mutant in tqdm(MUTANTS, desc="mutants", unit="mutant")]
    result = {"mutants": rows, "killed": sum(r["killed"] for r in rows), "total": len(rows),
              "survivors": [r["mutant"] for r in rows if not r["killed"]]}
    write_result(args.out, result)
    print(json.dumps({k: v for k, v in result.items() if k != "mutants"}))
    if result["survivors"]:
        raise SystemExit(f"mutants not killed by the suite: {', '.join(result['survivors'])}")


if __name__ == "__main__":
    main()
