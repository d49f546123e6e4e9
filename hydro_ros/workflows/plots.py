"""Plots people would rather look at than JSON (matplotlib, Agg backend, PNG)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib
import numpy as np

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # files, no display: the studies' plots take it from here too

from hydro_ros.bags.reader import BagData
from hydro_ros.contract.machine import Machine
from hydro_ros.models.sam import Param, SamModel
from hydro_ros.workflows.commissioning import CommissioningReport, FaultFreeRecording

if TYPE_CHECKING:
    from hydro_ros.fdi.offline import FdiRun


def plot_bag(data: BagData, out: str | Path) -> Path:
    """Pressures, joint motion and valve command of every actuator, fault onsets marked."""
    out = Path(out)
    t = data.times
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(10, 7))
    for name, values in data.pressure_a.items():
        axes[0].plot(t, values / 1e6, lw=0.6, label=f"{name} p_A")
    for name, values in data.pressure_b.items():
        axes[0].plot(t, values / 1e6, lw=0.6, label=f"{name} p_B")
    if data.supply_pressure is not None:
        axes[0].plot(t, data.supply_pressure / 1e6, lw=0.4, color="grey", label="supply")
    axes[0].set_ylabel("pressure [MPa]")
    for name, values in data.joint_position.items():
        axes[1].plot(t, values, lw=0.8, label=name)
    axes[1].set_ylabel("joint [rad]")
    for name, values in data.valve_command.items():
        axes[2].plot(t, values, lw=0.6, label=name)
    axes[2].set_ylabel("valve command [-]")
    axes[2].set_xlabel("time from first sample [s]")
    for fault in (data.truth or {}).get("faults", []):
        for ax in axes:
            ax.axvline(fault["onset_s"], color="red", ls="--", lw=0.8)
        axes[0].annotate(fault["name"], (fault["onset_s"], axes[0].get_ylim()[1]), color="red", fontsize=8, va="top")
    for ax in axes:
        ax.legend(loc="upper right", fontsize=7)
        ax.grid(alpha=0.3)
    fig.suptitle(str(data.path.name))
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_fdi(run: FdiRun, out: str | Path) -> Path:
    """Per actuator: 5 s mean residuals of both chambers against their adaptive thresholds."""
    out = Path(out)
    actuators = run.monitor.actuators
    fig, axes = plt.subplots(2 * len(actuators), 1, sharex=True, figsize=(10, 3.2 * 2 * len(actuators)), squeeze=False)
    onsets = [(f["name"], f["onset_s"]) for f in ((run.data.truth or {}).get("faults", []) if run.data else [])]
    for i, actuator in enumerate(actuators):
        for c, chamber in enumerate("AB"):
            ax = axes[2 * i + c, 0]
            ax.plot(run.times, run.residual_mean[:, i, c], lw=0.8, label=f"mean r_p{chamber}")
            ax.plot(run.times, run.threshold[:, i, c], color="k", lw=0.6, ls="--", label="threshold")
            ax.plot(run.times, -run.threshold[:, i, c], color="k", lw=0.6, ls="--")
            ax.set_ylabel(f"{actuator} r_p{chamber} [MPa]")
            for alarm in run.alarms:
                if alarm.actuator == actuator:
                    ax.axvline(alarm.time_s, color="orange", lw=0.8)
                    if c == 0:
                        ax.annotate(alarm.fault.value, (alarm.time_s, ax.get_ylim()[1]), fontsize=7, va="top", color="darkorange")
            for _name, onset in onsets:
                ax.axvline(onset, color="red", ls=":", lw=0.8)
            ax.grid(alpha=0.3)
            ax.legend(loc="lower left", fontsize=7)
    axes[-1, 0].set_xlabel("time from first sample [s]  (red dotted: true onset, orange: alarm)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_discrepancy(rec, machine: Machine, *, before: np.ndarray, after: np.ndarray, effects: dict, out: str | Path,
                     scales: np.ndarray) -> Path:
    """Validation data: measured vs simulated p_A, p_B and position, before and after the named effects.

    ``before`` and ``after`` are normalised errors: measured - simulated = error * scales.
    """
    out = Path(out)
    t = rec.times
    labels = ("p_A [MPa]", "p_B [MPa]", "piston [mm]")
    units = (1e6, 1e6, 1e-3)
    fig, axes = plt.subplots(3, 1, sharex=True, figsize=(11, 7.5))
    named = ", ".join(f"{k}={v:.3g}" for k, v in effects.items()) or "no effect named"
    for i, ax in enumerate(axes):
        # errors are normalised: measured - simulated = error * scale
        measured_scaled = None
        if i < 2:
            measured = (rec.pressure_a, rec.pressure_b)[i]
            measured_scaled = measured / units[i]
        else:
            model = SamModel(machine)
            measured_scaled = np.array([model.piston_from_joint(j) for j in rec.joint]) / units[i]
        ax.plot(t, measured_scaled, color="k", lw=0.6, label="measured")
        ax.plot(t, measured_scaled - before[:, i] * scales[i] / units[i], lw=0.6, label="model before")
        ax.plot(t, measured_scaled - after[:, i] * scales[i] / units[i], lw=0.6, label=f"model after ({named})")
        ax.set_ylabel(labels[i])
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7, loc="upper right")
    axes[-1].set_xlabel("time from first sample [s] (validation part, 2 s segments from the measured state)")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_gap_localisation(before: dict, after: dict, out: str | Path) -> Path:
    """Where the validation gap sits before and after the named effects: per 5 s window and per regime
    (``discrepancy.localise`` of each, channels combined as the RMS over them)."""
    out = Path(out)
    fig, (by_time, by_regime) = plt.subplots(1, 2, figsize=(12, 4), gridspec_kw={"width_ratios": [3, 2]})
    for label, local in (("before", before), ("after", after)):
        by_time.step([w["t_s"] for w in local["by_time"]], [w["rms"] for w in local["by_time"]], where="post", label=label)
    by_time.set_xlabel("validation time [s] (5 s windows)")
    by_time.set_ylabel("gap (RMS of the 0.1 s mean error)")
    by_time.legend()
    by_time.grid(alpha=0.3)
    regimes = [name for name, channels in before["by_regime"].items() if all(v is not None for v in channels.values())]

    def combined(local: dict, name: str) -> float:
        return float(np.sqrt(np.mean(np.square(list(local["by_regime"][name].values())))))

    x = np.arange(len(regimes))
    by_regime.bar(x - 0.2, [combined(before, r) for r in regimes], 0.4, label="before")
    by_regime.bar(x + 0.2, [combined(after, r) for r in regimes], 0.4, label="after")
    by_regime.set_xticks(x, [r.replace("_", " ") for r in regimes], rotation=30, ha="right")
    by_regime.grid(alpha=0.3, axis="y")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_gap_profiles(profiles: list[dict], out: str | Path) -> Path:
    """The discrepancy workflow's fit gap along one effect's value, on the segments it screens on and on all of them, one
    panel per case: each ``profile`` has ``title``, ``values``, ``screened`` and ``all`` (gaps), ``truth`` and ``named``."""
    out = Path(out)
    fig, axes = plt.subplots(1, len(profiles), figsize=(4.2 * len(profiles), 3.6), sharey=True, squeeze=False)
    for ax, profile in zip(axes[0], profiles):
        ax.plot(profile["values"], profile["screened"], marker="o", ms=3, label="screened segments (a quarter)")
        ax.plot(profile["values"], profile["all"], marker="o", ms=3, label="all fit segments (refit)")
        ax.axvline(profile["truth"], color="k", ls="--", lw=0.8, label="plant's value")
        if profile["named"] is not None:
            ax.axvline(profile["named"], color="tab:red", ls=":", lw=1.2, label="named (joint fit)")
        ax.set_title(profile["title"], fontsize=9)
        ax.set_xlabel("effect value")
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("fit gap (RMS of the 0.1 s mean error)")
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
    return out


def plot_commissioning(report: CommissioningReport, machine: Machine, out: str | Path) -> Path:
    """Fitted against nominal flow coefficient per notch, and the threshold it gives."""
    out = Path(out)
    fig, axes = plt.subplots(len(report["identification"]), 5, figsize=(16, 3.2 * len(report["identification"])), squeeze=False)
    for row, ident in zip(axes, report["identification"]):
        nominal = machine.actuator(ident["actuator"]).valve.kv_poly
        for ax, notch in zip(row, ("PA", "PB", "AT", "BT")):
            sign = 1.0 if notch in ("PA", "BT") else -1.0
            openings = np.linspace(0.02, 1.0, 100)
            ax.plot(openings, np.polyval(nominal[notch], sign * openings) * 1e7, label="nominal")
            ax.plot(openings, np.polyval(ident["kv_poly"][notch], sign * openings) * 1e7,
                    label=f"commissioned (gain {ident['notch_gain'][notch]:.3f})")
            ax.set_title(f"{ident['actuator']} {notch}")
            ax.set_xlabel("opening |s| [-]")
            ax.set_ylabel("K_v [1e-7 m^3/(s Pa^0.5)]")
            ax.legend(fontsize=7)
            ax.grid(alpha=0.3)
        ax = row[4]
        threshold = report["threshold"]
        name, unit = threshold["parameter"].split(" ", 1)
        if isinstance(threshold["value"], list):  # a c per bin of the operating point
            bins = np.arange(len(threshold["value"]))
            for offset, label, values, color in ((-0.27, f"{name} before", threshold["before"], "0.6"),
                                                 (0.0, "worst held-out", threshold["reached"], "tab:orange"),
                                                 (0.27, f"{name} commissioned", threshold["value"], "tab:blue")):
                ax.bar(bins + offset, np.broadcast_to(np.asarray(values if values is not None else 0.0, dtype=float), bins.shape),
                       width=0.27, label=label, color=color)
            ax.set_xticks(bins, [f"bin {b}" for b in bins])
            ax.legend(fontsize=7)
        else:
            ax.bar([f"{name} before", "worst held-out", f"{name} commissioned"],
                   [threshold["before"] or 0.0, threshold["reached"], threshold["value"]], color=["0.6", "tab:orange", "tab:blue"])
        ax.set_ylabel(unit)
        ax.set_title(f"threshold ({report['held_out_s']:.0f} s held out)")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def plot_coverage(recordings: Sequence[FaultFreeRecording], coverage: dict[str, dict[str, list[float]]],
                  record_next: dict[str, list[str]], machine: Machine, out: str | Path) -> Path:
    """Where commissioning saw each actuator work: the recordings' valve command against each chamber's pressure (time
    density), the commanded openings the monitor trusts (``fdi.coverage`` widened by its margin; beyond them it holds),
    and what to record next."""
    from hydro_ros.fdi.coverage import COMMAND_MARGIN

    out = Path(out)
    fig, axes = plt.subplots(len(machine.actuators), 2, figsize=(12, 3.6 * len(machine.actuators)), squeeze=False)
    for index, (row, actuator) in enumerate(zip(axes, machine.actuator_names)):
        command = np.concatenate([np.asarray(r.samples.valve_command, dtype=float).reshape(len(r.samples), -1)[:, index]
                                  for r in recordings])
        low, high = coverage[actuator]["valve_command"]
        for ax, chamber in zip(row, ("a", "b")):
            pressure = np.concatenate([np.asarray(getattr(r.samples, f"pressure_{chamber}"), dtype=float)
                                       .reshape(len(r.samples), -1)[:, index] for r in recordings]) * 1e-6
            finite = np.isfinite(command) & np.isfinite(pressure)
            ax.hexbin(command[finite], pressure[finite], gridsize=40, bins="log", cmap="Blues", extent=(-1.0, 1.0, 0.0,
                      machine.supply_pressure * 1.1e-6))
            ax.axvspan(-1.05, low - COMMAND_MARGIN, color="tab:red", alpha=0.15)
            ax.axvspan(high + COMMAND_MARGIN, 1.05, color="tab:red", alpha=0.15, label="held: openings not seen")
            ax.set_xlim(-1.05, 1.05)
            ax.set_xlabel("valve command [-]")
            ax.set_ylabel(f"p_{chamber.upper()} [MPa]")
            ax.set_title(f"{actuator}: where the recordings worked", fontsize=9)
            ax.legend(fontsize=7, loc="upper left")
        advice = record_next.get(actuator) or ["nothing: the valve's stroke and the load range were seen"]
        row[1].text(0.02, 0.02, textwrap.fill("record next: " + "; ".join(advice), 70), transform=row[1].transAxes, fontsize=7,
                    va="bottom")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def plot_machine(machine: Machine, out: str | Path) -> Path:
    """Each actuator of a machine as configured: its link at both ends of its reach and in the middle, the cylinder between
    its mounts (a telescope as a bar), and the load it carries in its one-cylinder model; one panel per actuator. A machine
    with an ``arm:`` has a last panel: the arm at the ends and the middle of its joints' ranges and the workspace its tip
    reaches."""
    from hydro_ros.models.kinematics import LINEAR, joint_reach

    out = Path(out)
    panels = len(machine.actuators) + (machine.arm is not None)
    fig, axes = plt.subplots(1, panels, figsize=(4.5 * panels, 4.2), squeeze=False)
    if machine.arm is not None:
        _plot_arm(axes[0][-1], machine)
    for ax, actuator in zip(axes[0], machine.actuators):
        model = SamModel(machine, actuator.name)
        kind, l1, l2, _, offset, sign, _ = model.mount
        low, high = joint_reach(model.mount, *model.end_stops)
        length = model.base[Param.BOOM_LENGTH] if not machine.planned else max(l1, l2) * 2.0
        for joint, style in ((low, ":"), (0.5 * (low + high), "-"), (high, "--")):
            if kind == LINEAR:  # a telescope: the joint is its extension
                ax.plot([0, joint], [0, 0], "k" + style, lw=2, label=f"extended {joint:.2f} m")
                continue
            tip = length * np.array([np.cos(joint), np.sin(joint)])
            upper = l1 * np.array([np.cos(joint), np.sin(joint)])
            lower = l2 * np.array([np.cos(joint - sign * joint - offset), np.sin(joint - sign * joint - offset)])
            ax.plot([0, tip[0]], [0, tip[1]], "k" + style, lw=2, label=f"link at {np.degrees(joint):.0f} deg")
            ax.plot([lower[0], upper[0]], [lower[1], upper[1]], "C1" + style, lw=4, alpha=0.8)
            if not machine.planned:
                load = model.base[Param.LOAD_DISTANCE] * np.array([np.cos(joint), np.sin(joint)])
                ax.plot(*load, "C3o", ms=6)
        ax.plot(0, 0, "ks", ms=7)
        ax.set_aspect("equal")
        ax.grid(alpha=0.3)
        reach = f"{low:.2f} to {high:.2f} m" if kind == LINEAR else f"{np.degrees(low):.0f} to {np.degrees(high):.0f} deg"
        ax.set_title(f"{actuator.name} ({actuator.joint}): reach {reach}", fontsize=9)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(f"{machine.name}: links (black), cylinders (orange), load (red); pivot at the square", fontsize=10)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
    return out


def _plot_arm(ax: plt.Axes, machine: Machine) -> None:
    from hydro_ros.models.serial_arm import SerialArm

    arm = SerialArm.of(machine)
    ranges = [link.joint_range for link in arm.links]
    grid = np.meshgrid(*[np.linspace(low, high, 25) for low, high in ranges], indexing="ij")
    tip_x, tip_y = arm.tip([g.ravel() for g in grid])
    ax.plot(tip_x, tip_y, ".", color="0.75", ms=2, label="tip's workspace")
    for share, style in ((0.0, ":"), (0.5, "-"), (1.0, "--")):
        q = [low + share * (high - low) for low, high in ranges]
        joints = [origin for origin, _ in arm.frames(q)] + [arm.tip(q)]
        ax.plot(*np.array(joints).T, "k" + style, marker="o", ms=4, lw=2, label=f"{share:.0%} of each range")
    ax.plot(*machine.arm.origin, "ks", ms=7)
    ax.set_aspect("equal")
    ax.grid(alpha=0.3)
    ax.set_title(f"arm: {' - '.join(arm.joint_names)}, payload {machine.arm.payload:g} kg", fontsize=9)
    ax.legend(fontsize=7, loc="best")
