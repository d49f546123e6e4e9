"""The machine's CAN bus (config/machine_bus.dbc) <-> contract samples, with every frame checked.

Bus layout: per sensor cycle one frame per joint (JOINTn_STATE), per cylinder (CYLn_PRESSURE),
per valve (VALVEn_STATE) and one SUPPLY_STATE; slot n of a machine-config actuator is its
`can_slot` (default: its position, 1-based). Every frame carries a 4-bit rolling counter shared by
the frames of one cycle (byte 6 low nibble) and a CRC-8/SAE-J1850 in byte 7 computed over the
11-bit ID (2 bytes, little endian) and bytes 0-6, AUTOSAR-E2E style. Signals are encoded and
decoded with cantools; the framing checks are ours.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools
import numpy as np

from hydro_ros.contract.config import config_dir
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine

DLC = 8
COUNTER_MODULO = 16


def _crc_table() -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x1D) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return table


_CRC = _crc_table()


def crc8(frame_id: int, payload: bytes) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init and xorout 0xFF) over the ID and the first 7 data bytes."""
    crc = 0xFF
    for byte in (frame_id & 0xFF, (frame_id >> 8) & 0xFF, *payload[:7]):
        crc = _CRC[crc ^ byte]
    return crc ^ 0xFF


class FrameError(InputError):
    """A frame that must not reach ROS; ``kind`` names the counter it is reported under."""

    def __init__(self, kind: str, message: str) -> None:
        super().__init__(message)
        self.kind = kind


@dataclass(frozen=True)
class Slot:
    actuator: str
    joint: str
    number: int
    mobile: bool


@dataclass
class Cycle:
    """The frames of one sensor cycle, decoded; ``stamp_ns`` = timestamp of its first frame."""

    counter: int
    stamp_ns: int
    values: dict[str, dict[str, float]] = field(default_factory=dict)  # message name -> signals

    def complete(self, expected: frozenset[str]) -> bool:
        return expected <= self.values.keys()


class MachineBus:
    """Encoding and checked decoding of one machine's frames."""

    def __init__(self, machine: Machine, dbc: str | Path | None = None) -> None:
        path = Path(dbc) if dbc else config_dir() / machine.dbc
        try:
            self.db = cantools.database.load_file(str(path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError) as exc:
            raise InputError(f"dbc {path}: cannot load ({exc})") from None
        self.dbc_path = path
        self.slots = []
        for actuator in machine.actuators:
            self.slots.append(Slot(actuator.name, actuator.joint, actuator.can_slot, actuator.valve.mobile))
        self.by_id = {m.frame_id: m for m in self.db.messages}
        # every frame's counter and checksum signals, by message name
        self.framing = {m.name: (next(g.name for g in m.signals if g.name.endswith("_COUNTER")),
                                 next(g.name for g in m.signals if g.name.endswith("_CHECKSUM"))) for m in self.db.messages}
        names = ["SUPPLY_STATE"]
        for slot in self.slots:
            names += [f"JOINT{slot.number}_STATE", f"CYL{slot.number}_PRESSURE", f"VALVE{slot.number}_STATE"]
        missing = [n for n in names if n not in {m.name for m in self.db.messages}]
        if missing:
            raise InputError(f"dbc {path}: no message(s) {', '.join(missing)} for this machine's slots")
        self.expected = frozenset(names)
        self.cycle_ms = {name: self.db.get_message_by_name(name).cycle_time or 0 for name in names}

    # encoding ----------------------------------------------------------------------------------
    def _frame(self, name: str, signals: dict[str, float], counter: int) -> tuple[int, bytes]:
        message = self.db.get_message_by_name(name)
        counter_signal, checksum_signal = self.framing[name]
        values = dict(signals)
        values[counter_signal] = counter
        values[checksum_signal] = 0
        data = bytearray(message.encode(values, strict=True))
        data[7] = crc8(message.frame_id, bytes(data))
        return message.frame_id, bytes(data)

    def encode_cycle(self, sample: dict[str, Any], counter: int) -> list[tuple[int, bytes]]:
        """Frames of one cycle from {'joint_position': {joint: v}, 'pressure_a': {act: v}, ...}."""
        frames = [self._frame("SUPPLY_STATE", {"SUPPLY_P_S": _clip(sample["supply_pressure"], 0, 32767500),
                                               "SUPPLY_P_LS": _clip(sample.get("ls_pressure") or 0.0, 0, 32767500)}, counter)]
        for slot in self.slots:
            n = slot.number
            frames.append(self._frame(f"JOINT{n}_STATE", {f"JOINT{n}_ANGLE": sample["joint_position"][slot.joint],
                                                          f"JOINT{n}_RATE": _clip(sample["joint_velocity"][slot.joint], -3.2767, 3.2767)}, counter))
            frames.append(self._frame(f"CYL{n}_PRESSURE", {
                f"CYL{n}_P_A": _clip(sample["pressure_a"][slot.actuator], 0, 32767500),
                f"CYL{n}_P_B": _clip(sample["pressure_b"][slot.actuator], 0, 32767500),
                f"CYL{n}_P_COMP": _clip((sample.get("compensator_pressure") or {}).get(slot.actuator, 0.0), 0, 32767500)}, counter))
            frames.append(self._frame(f"VALVE{n}_STATE", {
                f"VALVE{n}_COMMAND": _clip(sample["valve_command"][slot.actuator], -1.09, 1.09),
                f"VALVE{n}_PILOT_1": _clip((sample.get("pilot_pressure_1") or {}).get(slot.actuator, 0.0), 0, 6553500),
                f"VALVE{n}_PILOT_2": _clip((sample.get("pilot_pressure_2") or {}).get(slot.actuator, 0.0), 0, 6553500)}, counter))
        return frames

    def encode_request(self, slot_number: int, command: float, counter: int) -> tuple[int, bytes]:
        return self._frame(f"VALVE{slot_number}_REQUEST", {f"REQ{slot_number}_COMMAND": _clip(command, -1.0, 1.0)}, counter)

    # decoding ----------------------------------------------------------------------------------
    def decode(self, frame_id: int, data: bytes) -> tuple[str, int, dict[str, float]]:
        """(message name, counter, physical signals) of a valid frame; FrameError otherwise."""
        message = self.by_id.get(frame_id)
        if message is None:
            raise FrameError("unknown_id", f"unknown frame id 0x{frame_id:X}")
        if len(data) != message.length:
            raise FrameError("wrong_dlc", f"{message.name}: {len(data)} data bytes, expected {message.length}")
        if data[7] != crc8(frame_id, data):
            raise FrameError("bad_checksum", f"{message.name}: checksum mismatch")
        try:
            values = message.decode(bytes(data), decode_choices=False)
        except Exception as exc:  # noqa: BLE001 - cantools raises several types on bad payloads
            raise FrameError("undecodable", f"{message.name}: {exc}") from None
        counter_signal, checksum_signal = self.framing[message.name]
        counter = int(values.pop(counter_signal))
        values.pop(checksum_signal)
        if not all(math.isfinite(float(v)) for v in values.values()):
            raise FrameError("undecodable", f"{message.name}: non-finite value")
        return message.name, counter, {k: float(v) for k, v in values.items()}


def _clip(value: float, low: float, high: float) -> float:
    return min(max(float(value), low), high)


@dataclass
class CounterCheck:
    """Per message: the rolling counter must advance by one from frame to frame."""

    last: dict[str, int] = field(default_factory=dict)
    gaps: dict[str, int] = field(default_factory=dict)

    def __call__(self, name: str, counter: int) -> None:
        previous = self.last.get(name)
        if previous is not None and counter != (previous + 1) % COUNTER_MODULO:
            self.gaps[name] = self.gaps.get(name, 0) + 1
        self.last[name] = counter


class CycleAssembler:
    """Groups valid frames into cycles by their shared counter; a cycle is released complete, or
    incomplete once ``horizon`` newer cycles have started (its missing frames are counted)."""

    def __init__(self, expected: frozenset[str], horizon: int = 4) -> None:
        self.expected = expected
        self.horizon = horizon
        self.open: list[Cycle] = []
        self.incomplete = 0

    def add(self, name: str, counter: int, values: dict[str, float], stamp_ns: int) -> list[Cycle]:
        cycle = next((c for c in self.open if c.counter == counter and name not in c.values), None)
        if cycle is None:
            cycle = Cycle(counter, stamp_ns)
            self.open.append(cycle)
        cycle.values[name] = values
        released = []
        while self.open and (self.open[0].complete(self.expected) or len(self.open) > self.horizon):
            first = self.open.pop(0)
            if not first.complete(self.expected):
                self.incomplete += 1
            released.append(first)
        return released

    def flush(self) -> list[Cycle]:
        out, self.open = self.open, []
        self.incomplete += sum(not c.complete(self.expected) for c in out)
        return out


def cycle_values(bus: MachineBus, cycle: Cycle) -> dict[str, Any]:
    """Contract quantities of a cycle, only from frames that arrived (the rest stays absent)."""
    out: dict[str, Any] = {"joint_position": {}, "joint_velocity": {}, "pressure_a": {}, "pressure_b": {}, "valve_command": {},
                           "pilot_pressure_1": {}, "pilot_pressure_2": {}, "compensator_pressure": {}}
    supply = cycle.values.get("SUPPLY_STATE")
    if supply is not None:
        out["supply_pressure"] = supply["SUPPLY_P_S"]
        out["ls_pressure"] = supply["SUPPLY_P_LS"]
    for slot in bus.slots:
        n = slot.number
        joint = cycle.values.get(f"JOINT{n}_STATE")
        if joint is not None:
            out["joint_position"][slot.joint] = joint[f"JOINT{n}_ANGLE"]
            out["joint_velocity"][slot.joint] = joint[f"JOINT{n}_RATE"]
        cylinder = cycle.values.get(f"CYL{n}_PRESSURE")
        if cylinder is not None:
            out["pressure_a"][slot.actuator] = cylinder[f"CYL{n}_P_A"]
            out["pressure_b"][slot.actuator] = cylinder[f"CYL{n}_P_B"]
            if slot.mobile:
                out["compensator_pressure"][slot.actuator] = cylinder[f"CYL{n}_P_COMP"]
        valve = cycle.values.get(f"VALVE{n}_STATE")
        if valve is not None:
            out["valve_command"][slot.actuator] = valve[f"VALVE{n}_COMMAND"]
            if slot.mobile:
                out["pilot_pressure_1"][slot.actuator] = valve[f"VALVE{n}_PILOT_1"]
                out["pilot_pressure_2"][slot.actuator] = valve[f"VALVE{n}_PILOT_2"]
    return out


def cycle_row(values: dict[str, Any], columns: list[tuple[str, str]]) -> list[float]:
    """A complete cycle's :func:`cycle_values` in a sample layout's columns, (quantity, joint or actuator; "" machine-wide)."""
    return [values[quantity][name] if name else values[quantity] for quantity, name in columns]


def sample_values(samples: Any, k: int, actuators: dict[str, str]) -> dict[str, Any]:
    """Sample ``k`` of a Samples block in the shape encode_cycle takes; ``actuators``: actuator -> joint, in the block's
    column order ((n,) columns for one actuator, (n, A) for several)."""
    names = list(actuators)

    def row(name: str) -> list[float] | None:
        series = getattr(samples, name)
        return None if series is None else [float(v) for v in np.asarray(series[k]).reshape(-1)]

    def by_actuator(name: str) -> dict[str, float] | None:
        values = row(name)
        return None if values is None else dict(zip(names, values))

    positions, velocities = row("joint_position"), row("joint_velocity")
    return {
        "joint_position": dict(zip(actuators.values(), positions)), "joint_velocity": dict(zip(actuators.values(), velocities)),
        "pressure_a": by_actuator("pressure_a"), "pressure_b": by_actuator("pressure_b"), "valve_command": by_actuator("valve_command"),
        "supply_pressure": float(samples.supply_pressure[k]),
        "ls_pressure": None if samples.ls_pressure is None else float(samples.ls_pressure[k]),
        "pilot_pressure_1": by_actuator("pilot_pressure_1"), "pilot_pressure_2": by_actuator("pilot_pressure_2"),
        "compensator_pressure": by_actuator("compensator_pressure"),
    }
