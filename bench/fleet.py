"""Fleet analysis at scale (make bench): recordings of 1 kHz SAM data analysed per core-hour, on local processes and on a
Dask LocalCluster with one and two workers, in the same run; and the cores a fleet of 100 machines recording 8 h a
day needs. Each recording is RECORDING_S of the simulated SAM at work (a payload step, sensor noise, a plant that differs
from the config); rates are scaled to recordings of one hour of 1 kHz data (the analysis is linear in the samples).
Writes --out (bench/results/fleet.json) and a bar chart beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.contract.config import default_config_path
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import Injection
from hydro_ros.sim.scenario import MachineRun
from hydro_ros.studies.fdi_evaluation import mismatched_config
from hydro_ros.tooling.benchresults import write_result
from hydro_ros.workflows.fleet import analyse

RECORDING_S = 300.0
RECORDINGS = 4
FLEET_MACHINES, HOURS_PER_DAY = 100, 8.0


def make_fleet(root: Path) -> None:
    config = default_config_path("sam")
    plant = mismatched_config(load_machine_config(config), seed=7)
    folder = root / "sam1"
    folder.mkdir(parents=True)
    (folder / "machine.yaml").write_text(f"extends: {config}\n")
    for k in range(RECORDINGS):
        with ContractBagWriter(folder / f"run{k}", actuators={a.name: a.joint for a in plant.actuators},
                               pressure_variance=plant.sensors.pressure_noise_std ** 2) as writer:
            for _, block in MachineRun(plant, {"boom": [Injection("payload_mass", 150.0, RECORDING_S / 2)]}, seed=k).blocks(RECORDING_S):
                writer.write_machine_block(replace(block, times=block.times + 1.75e9 + k * 86400.0))


def timed(root: Path, out: Path, **where) -> dict:
    shutil.rmtree(out, ignore_errors=True)
    began = time.perf_counter()
    report = analyse(root, out, **where)
    wall = time.perf_counter() - began
    cores = where.get("workers") or 1
    hours = RECORDINGS * RECORDING_S / 3600.0
    return {"ran_on": report.ran_on, "wall_s": wall, "cores": cores, "recording_hours": hours,
            "one_hour_recordings_per_core_hour": hours / (wall * cores / 3600.0)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="bench/results/fleet.json")
    args = parser.parse_args()
    from distributed import LocalCluster

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "fleet"
        make_fleet(root)
        runs = {"local, 1 process": timed(root, Path(tmp) / "a", workers=1),
                "local, 2 processes": timed(root, Path(tmp) / "b", workers=2)}
        for workers in (1, 2):
            with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
                run = timed(root, Path(tmp) / f"d{workers}", scheduler=cluster.scheduler_address)
                run["cores"] = workers
                run["one_hour_recordings_per_core_hour"] = run["recording_hours"] / (run["wall_s"] * workers / 3600.0)
                runs[f"Dask LocalCluster, {workers} worker{'s' if workers > 1 else ''}"] = run
    best = max(r["one_hour_recordings_per_core_hour"] for r in runs.values())
    daily = FLEET_MACHINES * HOURS_PER_DAY
    result = {"recording_s": RECORDING_S, "recordings": RECORDINGS, "cpu_count": os.cpu_count(), "runs": runs,
              "fleet": {"machines": FLEET_MACHINES, "hours_per_day": HOURS_PER_DAY, "recording_hours_per_day": daily,
                        "cores_for_a_day_in_a_day": daily / (best * 24.0)}}
    fig, ax = plt.subplots(figsize=(7, 3))
    ax.barh(list(runs), [r["one_hour_recordings_per_core_hour"] for r in runs.values()])
    ax.set_xlabel("1 h recordings of 1 kHz data analysed per core-hour")
    fig.tight_layout()
    fig.savefig(Path(args.out).with_suffix(".png"), dpi=100)
    write_result(Path(args.out), result)  # last: a stamped file stands for a finished step
    print(json.dumps(result["fleet"]))


if __name__ == "__main__":
    main()
