"""`hydro-ros can convert`: a machine's CAN log (candump .log, Vector .asc, .blf) -> contract bag.

Every frame goes through the same checks as on the live bus (MachineBus.decode, counters,
cycle grouping); only complete cycles become samples, stamped with their first frame's time.
Bad frames are counted by kind and reported, never written.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import can
import numpy as np

from hydro_ros.bags.writer import ContractBagWriter
from hydro_ros.can.codec import CounterCheck, CycleAssembler, FrameError, MachineBus, cycle_values
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.samples import Samples

LOG_SUFFIXES = (".log", ".asc", ".blf")


@dataclass
class ConversionReport:
    frames: int = 0
    cycles: int = 0
    incomplete_cycles: int = 0
    rejected: Counter = field(default_factory=Counter)
    counter_gaps: dict[str, int] = field(default_factory=dict)
    error_frames: int = 0

    def to_json(self) -> dict[str, Any]:
        return {"frames": self.frames, "samples": self.cycles, "incomplete_cycles": self.incomplete_cycles,
                "rejected_frames": dict(self.rejected), "counter_gaps": self.counter_gaps, "error_frames": self.error_frames}


def convert_log(log: str | Path, machine: Machine, out: str | Path, progress: Callable[[int], None] | None = None) -> ConversionReport:
    log = Path(log)
    if not log.is_file():
        raise InputError(f"log {log}: no such file")
    if log.suffix.lower() not in LOG_SUFFIXES:
        raise InputError(f"log {log}: unsupported format {log.suffix!r}; expected candump .log, .asc or .blf")
    bus = MachineBus(machine)
    if len(bus.slots) != 1:
        raise InputError("can convert: only single-actuator machines are written to bags so far")
    slot = bus.slots[0]
    assembler = CycleAssembler(bus.expected)
    counters = CounterCheck()
    report = ConversionReport()
    rows: list[dict[str, Any]] = []
    stamps: list[int] = []

    def keep(cycles: list) -> None:
        for cycle in cycles:
            if cycle.complete(bus.expected):
                rows.append(cycle_values(bus, cycle))
                stamps.append(cycle.stamp_ns)

    try:
        reader = can.LogReader(str(log))
        for message in reader:
            report.frames += 1
            if progress is not None and report.frames % 10000 == 0:
                progress(10000)
            if message.is_error_frame:
                report.error_frames += 1
                continue
            try:
                name, counter, values = bus.decode(message.arbitration_id, bytes(message.data))
            except FrameError as exc:
                report.rejected[exc.kind] += 1
                continue
            counters(name, counter)
            keep(assembler.add(name, counter, values, int(round(message.timestamp * 1e9))))
    except (ValueError, OSError, EOFError) as exc:
        if report.frames == 0:
            raise InputError(f"log {log}: unreadable ({exc})") from None
        report.rejected["log_damaged_after"] = report.frames
    keep(assembler.flush())
    report.incomplete_cycles = assembler.incomplete
    report.counter_gaps = dict(counters.gaps)
    report.cycles = len(rows)
    if not rows:
        raise InputError(f"log {log}: no complete sensor cycle of machine {machine.name!r} ({dict(report.rejected)})")
    order = np.argsort(stamps, kind="stable")

    def series(key: str, name: str) -> np.ndarray:
        return np.array([rows[i][key][name] for i in order])

    samples = Samples(
        times=np.asarray(stamps)[order] * 1e-9,
        joint_position=series("joint_position", slot.joint), joint_velocity=series("joint_velocity", slot.joint),
        pressure_a=series("pressure_a", slot.actuator), pressure_b=series("pressure_b", slot.actuator),
        supply_pressure=np.array([rows[i]["supply_pressure"] for i in order]),
        valve_command=series("valve_command", slot.actuator),
        **({"pilot_pressure_1": series("pilot_pressure_1", slot.actuator), "pilot_pressure_2": series("pilot_pressure_2", slot.actuator),
            "compensator_pressure": series("compensator_pressure", slot.actuator),
            "ls_pressure": np.array([rows[i]["ls_pressure"] for i in order])} if slot.mobile else {}),
    )
    variance = machine.sensors.pressure_noise_std ** 2
    with ContractBagWriter(out, actuators={slot.actuator: slot.joint}, pressure_variance=variance, mobile=slot.mobile) as writer:
        writer.custom_data["hydro_ros.source"] = str(log.name)
        writer.write(slot.actuator, samples)
    return report
