"""Reproducibly regenerate the simulated sample bags shipped in bags/ (`make bags`)."""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from hydro_ros.cli import main as cli
from hydro_ros.contract.config import default_config_path

DURATION_S = 25.0  # keeps each compressed bag under 5 MB at 1 kHz
# valve faults are told from an internal leak only after the valve command reverses (P-II 4.9):
# their bags run long enough for one reversal after the onset
LONG_S = 40.0
LONG = {"spool_too_small_opening", "spool_too_large_opening", "spool_stuck_closed"}
SAMPLES = {
    "fault_free": [],
    "external_leakage_a": ["--fault", "external_leakage_a=1.0@10"],
    "external_leakage_b": ["--fault", "external_leakage_b=1.0@10"],
    "internal_leakage": ["--fault", "internal_leakage=1.0@10"],
    "spool_offset": ["--fault", "spool_offset=0.03@10"],
    # the rest of P-II Table 3 (seeds continue, so the bags above stay byte-identical)
    "external_leakage_ab": ["--fault", "external_leakage_ab=1.0@10"],
    "spool_too_small_opening": ["--fault", "spool_too_small_opening=0.4@10"],
    "spool_too_large_opening": ["--fault", "spool_too_large_opening=0.4@10"],
    "spool_stuck_closed": ["--fault", "spool_stuck_closed=1@10"],
}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", default="bags")
    args = parser.parse_args()
    out = Path(args.out)
    out.mkdir(exist_ok=True)
    for seed, (name, fault) in enumerate(SAMPLES.items(), start=100):
        bag = out / name
        shutil.rmtree(bag, ignore_errors=True)
        status = cli(["sim", "--config", str(default_config_path("sam")), "--duration", str(LONG_S if name in LONG else DURATION_S),
                      "--seed", str(seed), *fault, "--out", str(bag), "--quiet"])
        if status:
            return status
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
