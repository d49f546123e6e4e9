"""Operator HMI benchmark (make bench): is the page responsive at the SAM's rates?

plant_sim (1 kHz sensor topics) -> fdi_node -> hmi, with 0, 1 and 4 headless Chromium pages open.
Per phase: CPU share of the hmi process, against fdi_node's in the same run (the reference: the
work the HMI watches), latency from a /diagnostics stamp to the tile in the page's DOM, the
websocket bytes per page and the page's own time per update. fdi_node publishes its diagnostics
at 5 Hz here (diagnostics_period 0.2 s) so each phase has enough latency samples.
Writes bench/results/hmi.json and bench/results/hmi.png.
"""

from __future__ import annotations

import argparse
import os
import time
from contextlib import ExitStack
from pathlib import Path

import numpy as np
import psutil

REPO = Path(__file__).resolve().parent.parent

from hydro_ros.hmi.headless import CHROMIUM, CHROMIUM_ARGS  # noqa: E402
from hydro_ros.processes import cpu_seconds, free_port, node_process  # noqa: E402
from hydro_ros.tooling.benchresults import write_result  # noqa: E402

SAM = str(REPO / "config" / "sam.yaml")


def _percentiles(samples: list[float], scale: float = 1.0) -> dict:
    if not samples:
        return {"n": 0}
    values = np.asarray(samples) * scale
    return {"n": int(values.size), "p50": float(np.percentile(values, 50)), "p95": float(np.percentile(values, 95)),
            "max": float(values.max())}


def measure(phase_s: float, clients: tuple[int, ...]) -> dict:
    from playwright.sync_api import sync_playwright
    from tqdm import tqdm

    os.environ.setdefault("ROS_DOMAIN_ID", "91")
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    os.environ.setdefault("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    port = free_port()
    phases = []
    with ExitStack() as stack:
        nodes = {
            "plant_sim": stack.enter_context(node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={SAM}", "-p", "seed:=3")),
            "fdi_node": stack.enter_context(node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={SAM}",
                                                         "-p", "diagnostics_period:=0.2")),
            "hmi": stack.enter_context(node_process("hydro_ros.nodes.hmi", "-p", f"port:={port}")),
        }
        processes = {name: psutil.Process(proc.pid) for name, proc in nodes.items()}
        playwright = stack.enter_context(sync_playwright())
        browser = playwright.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        stack.callback(browser.close)
        time.sleep(10.0)  # discovery, and the FDI's first window
        with tqdm(total=len(clients), desc="HMI phases (clients)", unit="phase") as bar:
            for count in clients:
                pages = [browser.new_page() for _ in range(count)]
                for page in pages:
                    page.goto(f"http://127.0.0.1:{port}/")
                    page.wait_for_selector("[data-actuator=boom]", timeout=30_000)
                time.sleep(2.0)
                for page in pages:  # count from here
                    page.evaluate("() => { window.hmiLatencies = []; window.hmiBytes = 0; window.hmiRenderMs = []; window.hmiDrawMs = []; }")
                start_cpu = {name: cpu_seconds(p) for name, p in processes.items()}
                start = time.monotonic()
                time.sleep(phase_s)
                wall = time.monotonic() - start
                share = {name: (cpu_seconds(p) - start_cpu[name]) / wall for name, p in processes.items()}
                latencies, render, draw, rates = [], [], [], []
                for page in pages:
                    sample = page.evaluate("() => [window.hmiLatencies, window.hmiBytes, window.hmiRenderMs, window.hmiDrawMs]")
                    latencies += sample[0]
                    rates.append(sample[1] / wall)
                    render += sample[2]
                    draw += sample[3]
                    page.close()
                phases.append({
                    "clients": count,
                    "seconds": wall,
                    "cpu_share_of_one_core": share,
                    "hmi_cpu_vs_fdi_node": share["hmi"] / share["fdi_node"],
                    "diagnostics_to_dom_latency_ms": _percentiles(latencies, 1e3),
                    "websocket_bytes_per_s_per_page": float(np.mean(rates)) if rates else 0.0,
                    "page_update_ms": _percentiles(render),
                    "page_plot_draw_ms": _percentiles(draw),
                })
                bar.update(1)
    return {"setup": {"plant": "SAM, 1 kHz sensor topics", "fdi_diagnostics_hz": 5, "hmi_update_rate_hz": 5,
                      "hmi_plot_rate_hz": 10, "phase_s": phase_s, "cores": os.cpu_count()},
            "phases": phases}


def _plot(result: dict, target: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    phases = result["phases"]
    labels = [str(p["clients"]) for p in phases]
    fig, (cpu, lat) = plt.subplots(1, 2, figsize=(10, 3.8))
    x = np.arange(len(phases))
    for k, name in enumerate(("hmi", "fdi_node", "plant_sim")):
        cpu.bar(x + (k - 1) * 0.27, [100 * p["cpu_share_of_one_core"][name] for p in phases], 0.27, label=name)
    cpu.set_xticks(x, labels)
    cpu.set_xlabel("browser pages open")
    cpu.set_ylabel("CPU [% of one core]")
    cpu.legend()
    cpu.set_title("CPU share at the SAM's rates")
    measured = [p for p in phases if p["diagnostics_to_dom_latency_ms"]["n"]]
    lat.bar([str(p["clients"]) for p in measured], [p["diagnostics_to_dom_latency_ms"]["p50"] for p in measured], label="p50")
    lat.scatter([str(p["clients"]) for p in measured], [p["diagnostics_to_dom_latency_ms"]["p95"] for p in measured],
                color="k", zorder=3, label="p95")
    lat.set_xlabel("browser pages open")
    lat.set_ylabel("/diagnostics stamp -> DOM [ms]")
    lat.set_title("Update latency (5 Hz websocket)")
    lat.legend()
    fig.tight_layout()
    fig.savefig(target, dpi=120)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "bench" / "results" / "hmi.json"))
    parser.add_argument("--phase", type=float, default=30.0, help="seconds per phase")
    args = parser.parse_args()
    result = measure(args.phase, (0, 1, 4))
    out = Path(args.out)
    _plot(result, out.with_suffix(".png"))
    write_result(out, result)  # last: a stamped file stands for a finished step
    for phase in result["phases"]:
        latency = phase["diagnostics_to_dom_latency_ms"]
        print(f"{phase['clients']} page(s): hmi {100 * phase['cpu_share_of_one_core']['hmi']:.1f} % of a core "
              f"({phase['hmi_cpu_vs_fdi_node']:.2f}x fdi_node), latency p50 {latency.get('p50', float('nan')):.0f} ms "
              f"p95 {latency.get('p95', float('nan')):.0f} ms, {phase['websocket_bytes_per_s_per_page'] / 1e3:.1f} kB/s per page")
    print(f"wrote {out} and {out.with_suffix('.png')}")


if __name__ == "__main__":
    main()
