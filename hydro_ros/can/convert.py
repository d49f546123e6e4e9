"""`hydro-ros bag convert`: a machine's CAN log (candump .log, Vector .asc, .blf) -> contract bag.

Every frame goes through the same checks as on the live bus (MachineBus.decode through the machine's
signal map, counters and checksums where the map names them, cycle grouping, the machine's clock:
hydro_ros.can.clock); only complete cycles become samples, so a converted log and a recording of the
bridge's output carry the same stamps.
Bad frames are counted by kind and reported, never written.
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import numpy as np

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.can.codec import MachineBus, cycle_row
from hydro_ros.can.stream import FrameStream
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine

LOG_SUFFIXES = (".log", ".asc", ".blf")
FORWARD_JUMP_S = 1.0


@dataclass
class ConversionReport:
    frames: int = 0
    cycles: int = 0
    incomplete_cycles: int = 0
    rejected: Counter = field(default_factory=Counter)
    counter_gaps: dict[str, int] = field(default_factory=dict)
    error_frames: int = 0
    out_of_order_cycles: int = 0  # cycles stamped before an earlier one: put back in time order
    rejected_samples: Counter = field(default_factory=Counter)  # complete cycles not written, by reason
    forward_time_jumps: int = 0  # gaps of more than FORWARD_JUMP_S between two cycles (a clock step, a log spliced)

    def to_json(self) -> dict[str, Any]:
        return {"frames": self.frames, "samples": self.cycles, "incomplete_cycles": self.incomplete_cycles,
                "rejected_frames": dict(self.rejected), "counter_gaps": self.counter_gaps, "error_frames": self.error_frames,
                "out_of_order_cycles": self.out_of_order_cycles, "forward_time_jumps": self.forward_time_jumps,
                "rejected_samples": dict(self.rejected_samples)}


def _kept_in_time_order(stamps: np.ndarray, rows: list[dict[str, Any]], slots: list[Any], machine: Machine,
                        report: ConversionReport) -> np.ndarray:
    """Indices of the cycles to write, in time order: a second cycle at one stamp and a physically
    impossible reading (a garbage frame whose CRC-8 matched by chance: a value outside the sensors' range, or a
    change from the last kept sample faster than the machine can move) are rejected and counted."""
    report.out_of_order_cycles = int(np.count_nonzero(np.diff(stamps) < 0))
    report.forward_time_jumps = int(np.count_nonzero(np.diff(stamps) > FORWARD_JUMP_S * 1e9))
    order = np.argsort(stamps, kind="stable")
    duplicate = np.concatenate([[False], np.diff(stamps[order]) == 0])
    report.rejected_samples["duplicate_stamp"] = int(np.count_nonzero(duplicate))
    sensors = machine.sensors
    low, high = sensors.pressure_range
    keep: list[int] = []
    last: tuple[int, list[float], list[float]] | None = None  # the last kept sample: stamp, positions, pressures
    for i in order[~duplicate]:
        row = rows[i]
        positions = [row["joint_position"][slot.joint] for slot in slots]
        velocities = [row["joint_velocity"][slot.joint] for slot in slots]
        pressures = [row["supply_pressure"], *(row[side][slot.actuator] for slot in slots for side in ("pressure_a", "pressure_b"))]
        if not np.all(np.isfinite([*positions, *velocities, *pressures])):
            report.rejected_samples["nonfinite"] += 1
        elif (not all(sensors.joint_range[0] <= q <= sensors.joint_range[1] for q in positions)
              or any(abs(v) > sensors.joint_velocity_max for v in velocities)
              or not all(low <= p <= high for p in pressures)):
            report.rejected_samples["implausible"] += 1
        elif last is not None and _too_fast(last, stamps[i], positions, pressures, sensors):
            report.rejected_samples["implausible_change"] += 1
        else:
            keep.append(i)
            last = (int(stamps[i]), positions, pressures)
    return np.asarray(keep, dtype=np.int64)


def _too_fast(last: tuple[int, list[float], list[float]], stamp: int, positions: list[float], pressures: list[float],
              sensors: Any) -> bool:
    """Whether a sample moved from the last kept one faster than the sensors' limits allow."""
    dt = max((int(stamp) - last[0]) * 1e-9, 1e-6)
    return (any(abs(p - q) > sensors.pressure_rate_max * dt for p, q in zip(pressures, last[2]))
            or any(abs(p - q) > sensors.joint_velocity_max * dt + 2.0 * sensors.encoder_resolution for p, q in zip(positions, last[1])))


def convert_log(log: str | Path, machine: Machine, out: str | Path, progress: Callable[[int], None] | None = None,
                dbc: str | Path | None = None) -> ConversionReport:
    """Every frame of ``log`` checked and decoded through the machine's signal map (``dbc``: another file for its DBC)."""
    log = Path(log)
    if not log.is_file():
        raise InputError(f"log {log}: no such file")
    if log.suffix.lower() not in LOG_SUFFIXES:
        raise InputError(f"log {log}: unsupported format {log.suffix!r}; expected candump .log, .asc or .blf")
    bus = MachineBus(machine, dbc)
    slots = bus.slots
    mobile = machine.mobile
    stream = FrameStream(bus)
    report = ConversionReport()
    rows: list[dict[str, Any]] = []
    stamps: list[int] = []

    def keep(cycles: list) -> None:
        for stamp, values in stream.complete(cycles):
            rows.append(values)
            stamps.append(stamp)

    try:
        reader = can.LogReader(str(log))
        for message in reader:
            report.frames += 1
            if progress is not None and report.frames % 10000 == 0:
                progress(10000)
            if message.is_error_frame:
                report.error_frames += 1
                continue
            keep(stream.add(message.arbitration_id, bytes(message.data), message.timestamp)[1])
    except (ValueError, OSError, EOFError) as exc:
        if report.frames == 0:
            raise InputError(f"log {log}: unreadable ({exc})") from None
        report.rejected["log_damaged_after"] = report.frames
    keep(stream.flush())
    report.rejected.update(stream.rejected)
    report.incomplete_cycles = stream.incomplete
    report.counter_gaps = dict(stream.counters.gaps)
    if not rows:
        raise InputError(f"log {log}: no complete sensor cycle of machine {machine.name!r} ({dict(report.rejected)})")
    order = _kept_in_time_order(np.asarray(stamps), rows, slots, machine, report)
    report.cycles = len(order)
    if not len(order):
        raise InputError(f"log {log}: no plausible sensor cycle of machine {machine.name!r} ({dict(report.rejected_samples)})")

    layout = SampleLayout([slot.actuator for slot in slots], [slot.joint for slot in slots], mobile=mobile)
    samples = layout.samples(np.asarray(stamps)[order] * 1e-9, np.array([cycle_row(rows[i], layout.columns) for i in order]))
    if mobile:  # the load-sensing line is a bag topic, not a column the monitor reads
        samples.ls_pressure = np.array([rows[i]["ls_pressure"] for i in order])
    variance = machine.sensors.pressure_noise_std ** 2
    with ContractBagWriter(out, actuators={slot.actuator: slot.joint for slot in slots}, pressure_variance=variance, mobile=mobile) as writer:
        writer.custom_data["hydro_ros.source"] = str(log.name)
        writer.write_machine_block(samples)
    return report
