"""A machine's CAN bus <-> contract samples, with every frame checked, through a map of DBC signals.

The machine config's ``can:`` section names the DBC (``dbc``) and, in ``map``, which DBC signal carries
each quantity: ``supply_pressure`` (and ``ls_pressure`` on mobile valves) machine-wide, and per actuator
``joint_position``, ``joint_velocity`` (optional: derived from the angle and low-pass filtered at
``sensors.velocity_filter_hz`` when the bus has none), ``pressure_a``, ``pressure_b``, ``valve_command``,
mobile valves' ``pilot_pressure_1``, ``pilot_pressure_2``, ``compensator_pressure``, and ``valve_request``
(where can_bridge sends commands), each as ``MESSAGE.SIGNAL``. Units are converted from the DBC's (bar,
kPa, MPa, psi, deg, deg/s, mm, %...). ``counters`` ({MESSAGE: SIGNAL}) names the rolling counters (4 bit) and
``checksums`` each message's checksum where the bus has them, and only there are they checked: ``{MESSAGE: SIGNAL}``
is hydro_ros's own CRC-8/SAE-J1850 over the ID's two low bytes and the other data bytes; ``{MESSAGE: {signal,
algorithm, data_id}}`` names another of ``CHECKSUM_ALGORITHMS`` (CRC-8/SAE-J1850 without the id, J1939-71's 4-bit
message checksum, a byte sum, AUTOSAR E2E profile 2). Without counters the frames of a
cycle are grouped by time (a message seen again starts the next cycle). 11- and 29-bit ids (J1939: the DBC's
extended ids) and either byte order, as cantools reads them.

Without ``map`` the bus is hydro_ros's own layout (config/machine_bus.dbc): per cycle JOINTn_STATE,
CYLn_PRESSURE, VALVEn_STATE per actuator slot n (its ``can_slot``) and SUPPLY_STATE, every frame with a
counter and a checksum in byte 7.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cantools
import numpy as np

from hydro_ros.can.clock import COUNTER_MODULO, CycleClock
from hydro_ros.contract.config import config_dir
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine

PRESSURE_UNITS = {"Pa": 1.0, "kPa": 1e3, "MPa": 1e6, "bar": 1e5, "mbar": 1e2, "psi": 6894.757}
UNITS = {  # quantity -> DBC unit -> factor to SI
    "joint_position": {"rad": 1.0, "deg": math.pi / 180.0, "m": 1.0, "mm": 1e-3},
    "joint_velocity": {"rad/s": 1.0, "deg/s": math.pi / 180.0, "m/s": 1.0, "mm/s": 1e-3},
    "valve_command": {"": 1.0, "-": 1.0, "1": 1.0, "%": 0.01},
    "valve_request": {"": 1.0, "-": 1.0, "1": 1.0, "%": 0.01},
    **{q: PRESSURE_UNITS for q in ("supply_pressure", "ls_pressure", "pressure_a", "pressure_b", "pilot_pressure_1",
                                   "pilot_pressure_2", "compensator_pressure")},
}
MACHINE_WIDE = ("supply_pressure", "ls_pressure")
PER_ACTUATOR = ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command", "pilot_pressure_1",
                "pilot_pressure_2", "compensator_pressure", "valve_request")
MOBILE_ONLY = ("ls_pressure", "pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")
OPTIONAL = ("joint_velocity", "valve_request")


def _crc_table(polynomial: int) -> list[int]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ polynomial) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return table


_CRC = {0x1D: _crc_table(0x1D), 0x2F: _crc_table(0x2F)}  # SAE J1850; AUTOSAR's CRC-8H2F (E2E profile 2)


def _crc8(polynomial: int, data: bytes | list[int]) -> int:
    """CRC-8 with init and xorout 0xFF over ``data`` (SAE J1850 with 0x1D, AUTOSAR CRC-8H2F with 0x2F)."""
    table, crc = _CRC[polynomial], 0xFF
    for byte in data:
        crc = table[crc ^ byte]
    return crc ^ 0xFF


def crc8(frame_id: int, payload: bytes, at: int = 7) -> int:
    """CRC-8/SAE-J1850 (poly 0x1D, init and xorout 0xFF) over the ID's two low bytes and every data byte but byte ``at``."""
    return _crc8(0x1D, [frame_id & 0xFF, (frame_id >> 8) & 0xFF, *payload[:at], *payload[at + 1:]])


def _raw_range(signal: Any) -> tuple[float, float]:
    """The physical values a signal's bits can carry (scale and offset applied), in DBC units."""
    top = (1 << (signal.length - 1)) - 1 if signal.is_signed else (1 << signal.length) - 1
    bottom = -(1 << (signal.length - 1)) if signal.is_signed else 0
    ends = (bottom * signal.scale + signal.offset, top * signal.scale + signal.offset)
    return min(ends), max(ends)


# the checksums a map can name per message (``checksums: {MESSAGE: {signal, algorithm, data_id}}``), each computed over the
# frame with the checksum's own bits zeroed (``masked``); the bytes the checksum occupies are left out of the CRCs and sums
CHECKSUM_ALGORITHMS = {
    "crc8_sae_j1850_id": "CRC-8/SAE-J1850 over the id's two low bytes and the other data bytes (hydro_ros's own bus)",
    "crc8_sae_j1850": "CRC-8/SAE-J1850 over the other data bytes",
    "j1939_4bit": "J1939-71's 4-bit message checksum (TSC1): the data bytes and the id's four bytes summed, folded to 4 bits",
    "byte_sum": "the other data bytes summed, modulo 256",
    "autosar_e2e_p2": "AUTOSAR E2E profile 2: CRC-8H2F over data bytes 1.. and the data id (per counter: data_ids), in byte 0",
}


@dataclass(frozen=True)
class Checksum:
    signal: str
    algorithm: str = "crc8_sae_j1850_id"
    data_ids: tuple[int, ...] = ()  # autosar_e2e_p2: one data id, or 16 (one per counter value, the counter in byte 1's low nibble)


def checksum_value(checksum: Checksum, frame_id: int, masked: bytes, covered: frozenset[int]) -> int:
    """The checksum of a frame whose checksum bits are zeroed (``masked``); ``covered``: the bytes the checksum occupies."""
    other = [b for k, b in enumerate(masked) if k not in covered]
    algorithm = checksum.algorithm
    if algorithm == "crc8_sae_j1850_id":
        return _crc8(0x1D, [frame_id & 0xFF, (frame_id >> 8) & 0xFF, *other])
    if algorithm == "crc8_sae_j1850":
        return _crc8(0x1D, other)
    if algorithm == "j1939_4bit":
        total = sum(masked) + sum((frame_id >> shift) & 0xFF for shift in (0, 8, 16, 24))
        return ((total >> 4) + total) & 0x0F
    if algorithm == "byte_sum":
        return sum(other) & 0xFF
    ids = checksum.data_ids
    data_id = ids[masked[1] & 0x0F] if len(ids) == 16 else ids[0]
    return _crc8(0x2F, [*masked[1:], data_id])


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


@dataclass(frozen=True)
class MappedSignal:
    message: str
    signal: str
    scale: float
    """SI per DBC unit"""


@dataclass
class Cycle:
    """The frames of one sensor cycle, decoded; ``stamp_ns``: its first frame's arrival, once released its stamp on the
    machine's clock (:class:`CycleAssembler`)."""

    counter: int | None
    stamp_ns: int
    values: dict[str, dict[str, float]] = field(default_factory=dict)  # message name -> signals

    def complete(self, expected: frozenset[str]) -> bool:
        return expected <= self.values.keys()


def _default_map(machine: Machine, db: Any) -> dict[str, Any]:
    """hydro_ros's own bus layout (config/machine_bus.dbc) as a map."""
    actuators = {}
    for actuator in machine.actuators:
        n = actuator.can_slot
        entry = {"joint_position": f"JOINT{n}_STATE.JOINT{n}_ANGLE", "joint_velocity": f"JOINT{n}_STATE.JOINT{n}_RATE",
                 "pressure_a": f"CYL{n}_PRESSURE.CYL{n}_P_A", "pressure_b": f"CYL{n}_PRESSURE.CYL{n}_P_B",
                 "valve_command": f"VALVE{n}_STATE.VALVE{n}_COMMAND", "valve_request": f"VALVE{n}_REQUEST.REQ{n}_COMMAND"}
        if actuator.valve.mobile:
            entry.update({"compensator_pressure": f"CYL{n}_PRESSURE.CYL{n}_P_COMP", "pilot_pressure_1": f"VALVE{n}_STATE.VALVE{n}_PILOT_1",
                          "pilot_pressure_2": f"VALVE{n}_STATE.VALVE{n}_PILOT_2"})
        actuators[actuator.name] = entry
    framing = {kind: {m.name: s.name for m in db.messages for s in m.signals if s.name.endswith(suffix)}
               for kind, suffix in (("counters", "_COUNTER"), ("checksums", "_CHECKSUM"))}
    return {"supply_pressure": "SUPPLY_STATE.SUPPLY_P_S", "ls_pressure": "SUPPLY_STATE.SUPPLY_P_LS", "actuators": actuators, **framing}


class BusMapError(InputError):
    """Every problem of a machine's bus map against its DBC (``problems``), said as one line."""

    def __init__(self, problems: list[str]) -> None:
        super().__init__("; ".join(problems))
        self.problems = problems


class MachineBus:
    """Encoding and checked decoding of one machine's frames through its signal map.

    Building one checks the map against the DBC as the bridge will read it, every problem at once (BusMapError): the
    DBC loads (cantools' strict mode refuses overlapping signals and signals beyond the DLC), no frame id twice, every
    named message and signal exists, one signal per quantity, each in a unit of its quantity and able to carry the
    machine's range (``sensors.pressure_range``, ``joint_range``) without being a hundred times too wide or ten times
    too narrow: an angle in degrees labelled rad, a pressure in bar labelled Pa.
    """

    def __init__(self, machine: Machine, dbc: str | Path | None = None) -> None:
        path = Path(dbc) if dbc else machine.source.parent / machine.dbc
        if not path.is_file() and not dbc and (config_dir() / machine.dbc).is_file():
            path = config_dir() / machine.dbc  # a config outside the package on the shipped bus
        try:
            self.db = cantools.database.load_file(str(path))
        except (OSError, cantools.database.UnsupportedDatabaseFormatError, ValueError) as exc:
            raise BusMapError([f"dbc {path}: cannot load ({exc})"]) from None
        self.dbc_path = path
        self.problems: list[str] = []
        self._machine = machine
        seen: dict[int, str] = {}
        for message in self.db.messages:
            if message.frame_id in seen:
                self.problems.append(f"dbc {path}: frame id 0x{message.frame_id:X} is both {seen[message.frame_id]} and {message.name}")
            seen.setdefault(message.frame_id, message.name)
        self._mapped: dict[tuple[str, str], str] = {}  # (message, signal) -> the key that mapped it
        self.slots = [Slot(a.name, a.joint, a.can_slot, a.valve.mobile) for a in machine.actuators]
        self.by_id = {m.frame_id: m for m in self.db.messages}
        self.by_name = {m.name: m for m in self.db.messages}
        raw = dict(machine.can_map) if machine.can_map else _default_map(machine, self.db)
        where = "can.map" if machine.can_map else "the default bus layout"
        self.machine_wide: dict[str, MappedSignal] = {}
        self.per_actuator: dict[str, dict[str, MappedSignal]] = {}
        for quantity in MACHINE_WIDE:
            if quantity in raw and (machine.mobile or quantity not in MOBILE_ONLY):
                self.machine_wide[quantity] = self._signal(raw[quantity], quantity, f"{where}.{quantity}")
        if "supply_pressure" not in raw:
            self.problems.append(f"dbc {path}: {where} names no supply_pressure signal")
        if machine.mobile and "ls_pressure" not in raw:
            self.problems.append(f"dbc {path}: {where} names no ls_pressure signal (the machine's valves are mobile)")
        table = raw.get("actuators") or {}
        for slot in self.slots:
            entry = table.get(slot.actuator) or {}
            required = [q for q in PER_ACTUATOR if q not in OPTIONAL and (slot.mobile or q not in MOBILE_ONLY)]
            missing = [q for q in required if q not in entry]
            if missing:
                self.problems.append(f"dbc {path}: {where}.actuators.{slot.actuator} names no {', '.join(missing)} signal")
            mapped = {q: self._signal(entry[q], q, f"{where}.actuators.{slot.actuator}.{q}")
                      for q in PER_ACTUATOR if q in entry and (slot.mobile or q not in MOBILE_ONLY)}
            self.per_actuator[slot.actuator] = {q: m for q, m in mapped.items() if m is not None}
        self.machine_wide = {q: m for q, m in self.machine_wide.items() if m is not None}
        self.counters = self._framing(raw.get("counters") or {}, where, "counters")
        self.checksums = self._checksums(raw.get("checksums") or {}, f"{where}.checksums")
        if self.problems:
            raise BusMapError(self.problems)
        sensors = [*self.machine_wide.values(), *(s for m in self.per_actuator.values() for q, s in m.items() if q != "valve_request")]
        self.expected = frozenset(s.message for s in sensors)
        self.by_counter = self.expected <= self.counters.keys()  # else cycles are grouped by time
        period_ms = 1000.0 / machine.sample_rate_hz
        self.cycle_ms = {name: self.by_name[name].cycle_time or period_ms for name in self.expected}
        self._velocity_filter_hz = machine.sensors.velocity_filter_hz
        self._last_position: dict[str, tuple[int, float, float]] = {}  # joint -> (stamp, position, filtered rate)

    def clock(self) -> CycleClock:
        """A clock for this bus's sensor cycles: the machine's sample period, the config's ``can.latency_limit``."""
        return CycleClock(1.0 / self._machine.sample_rate_hz, self._machine.can_latency_limit)

    def _signal(self, text: Any, quantity: str, key: str) -> MappedSignal | None:
        """The mapped signal, or None with the problem recorded."""
        message_name, _, signal_name = str(text).partition(".")
        message = self.by_name.get(message_name)
        if message is None:
            self.problems.append(f"dbc {self.dbc_path}: no message {message_name!r} (named by {key})")
            return None
        signal = next((s for s in message.signals if s.name == signal_name), None)
        if signal is None:
            self.problems.append(f"dbc {self.dbc_path}: message {message_name} has no signal {signal_name!r} (named by {key}; "
                                 f"it has {', '.join(s.name for s in message.signals)})")
            return None
        twice = self._mapped.setdefault((message_name, signal_name), key)
        if twice != key:
            self.problems.append(f"dbc {self.dbc_path}: {message_name}.{signal_name} is named by both {twice} and {key}: one signal "
                                 "carries one quantity")
        unit = (signal.unit or "").strip()
        if unit not in UNITS[quantity]:
            self.problems.append(f"dbc {self.dbc_path}: {message_name}.{signal_name} is in {unit!r}, not a unit of {quantity} "
                                 f"({', '.join(repr(u) for u in UNITS[quantity])}) (named by {key})")
            return None
        implausible = self._implausible(signal, quantity, unit, UNITS[quantity][unit])
        if implausible:
            self.problems.append(f"dbc {self.dbc_path}: {message_name}.{signal_name} in {unit!r} {implausible} (named by {key}): "
                                 "is its unit right?")
        return MappedSignal(message_name, signal_name, UNITS[quantity][unit])

    def _implausible(self, signal: Any, quantity: str, unit: str, scale: float) -> str:
        """Why the signal's range (its DBC minimum and maximum; else what its bits can carry, for "too narrow" only) cannot
        be the quantity's in this unit; "" when it can."""
        sensors = self._machine.sensors
        machine_range = {"joint_position": sensors.joint_range, "joint_velocity": (-sensors.joint_velocity_max, sensors.joint_velocity_max)}
        low, high = machine_range.get(quantity, sensors.pressure_range if quantity in UNITS and UNITS[quantity] is PRESSURE_UNITS else (None, None))
        if high is None:
            return ""
        widest = max(abs(low), abs(high))
        declared = signal.minimum is not None and signal.maximum is not None
        # what the bits can carry says only "too narrow": a wide raw range is how DBCs leave room
        reach = scale * (max(abs(signal.minimum), abs(signal.maximum)) if declared else max(abs(v) for v in _raw_range(signal)))
        if declared and unit in ("rad", "deg") and quantity == "joint_position" and reach > 4 * math.pi:
            return f"reaches {reach:.4g} rad, more than two turns of a joint"
        if declared and reach > 100 * widest:
            return f"reaches {reach:.4g} SI, over 100x the machine's range ({widest:.4g})"
        if reach < 0.1 * widest:
            return f"reaches only {reach:.4g} SI, under a tenth of the machine's range ({widest:.4g})"
        return ""

    def _framing(self, table: Mapping[str, Any], where: str, kind: str) -> dict[str, str]:
        for message_name, signal_name in table.items():
            message = self.by_name.get(message_name)
            if message is None or not any(s.name == signal_name for s in message.signals):
                self.problems.append(f"dbc {self.dbc_path}: no signal {message_name}.{signal_name} (named by {where}.{kind})")
        return {str(k): str(v) for k, v in table.items()}

    def _checksums(self, table: Mapping[str, Any], where: str) -> dict[str, Checksum]:
        """Each message's checksum: ``SIGNAL`` (hydro_ros's own CRC) or ``{signal, algorithm, data_id | data_ids}``; the
        bits it occupies (``_mask``) and its bytes (``_covered``), found by encoding."""
        out: dict[str, Checksum] = {}
        self._mask: dict[str, bytes] = {}
        self._covered: dict[str, frozenset[int]] = {}
        for message_name, entry in table.items():
            key = f"{where}.{message_name}"
            entry = {"signal": entry} if isinstance(entry, str) else entry
            if not isinstance(entry, Mapping) or "signal" not in entry:
                self.problems.append(f"{key}: expected a signal name or {{signal, algorithm}}")
                continue
            algorithm = str(entry.get("algorithm", "crc8_sae_j1850_id"))
            ids = entry.get("data_ids", [entry["data_id"]] if "data_id" in entry else [])
            message = self.by_name.get(message_name)
            signal = next((s for s in message.signals if s.name == entry["signal"]), None) if message else None
            if signal is None:
                self.problems.append(f"dbc {self.dbc_path}: no signal {message_name}.{entry['signal']} (named by {key})")
                continue
            width = 4 if algorithm == "j1939_4bit" else 8
            if algorithm not in CHECKSUM_ALGORITHMS:
                self.problems.append(f"{key}.algorithm: {algorithm!r}: expected one of {', '.join(CHECKSUM_ALGORITHMS)}")
            elif signal.length != width or signal.scale != 1 or signal.offset != 0:
                self.problems.append(f"{key}: {message_name}.{signal.name} must be a raw {width}-bit signal for {algorithm}")
            elif algorithm == "autosar_e2e_p2" and (len(ids) not in (1, 16) or signal.start // 8 != 0):
                self.problems.append(f"{key}: autosar_e2e_p2 needs data_id (or 16 data_ids) and its CRC in byte 0")
            else:
                zero = {s.name: s.offset for s in message.signals}
                base = message.encode(zero, scaling=True, strict=False)
                full = message.encode({**zero, signal.name: (1 << width) - 1}, scaling=True, strict=False)
                self._mask[message_name] = bytes(a ^ b for a, b in zip(base, full))
                self._covered[message_name] = frozenset(k for k, m in enumerate(self._mask[message_name]) if m)
                out[message_name] = Checksum(signal.name, algorithm, tuple(int(i) for i in ids))
        return out

    def _checksum_of(self, name: str, frame_id: int, data: bytes) -> int:
        masked = bytes(d & ~m for d, m in zip(data, self._mask[name]))
        return checksum_value(self.checksums[name], frame_id, masked, self._covered[name])

    def is_extended(self, frame_id: int) -> bool:
        return bool(self.by_id[frame_id].is_extended_frame)

    # encoding ----------------------------------------------------------------------------------
    def _frame(self, name: str, physical: dict[str, float], counter: int) -> tuple[int, bytes]:
        """A frame of message ``name`` from its signals' values in DBC units; unnamed signals 0 (or their minimum)."""
        message = self.by_name[name]
        values = {}
        for signal in message.signals:
            # saturate at what the signal declares and its bits can carry (a DBC may declare more than its bits hold)
            low, high = _raw_range(signal)
            low = max(low, signal.minimum) if signal.minimum is not None else low
            high = min(high, signal.maximum) if signal.maximum is not None else high
            values[signal.name] = _clip(physical.get(signal.name, 0.0), low, high)
        if name in self.counters:
            values[self.counters[name]] = counter % COUNTER_MODULO
        checksum = self.checksums.get(name)
        if checksum is not None:
            values[checksum.signal] = 0
            values[checksum.signal] = self._checksum_of(name, message.frame_id, message.encode(values, strict=True))
        return message.frame_id, bytes(message.encode(values, strict=True))

    def encode_cycle(self, sample: dict[str, Any], counter: int) -> list[tuple[int, bytes]]:
        """Frames of one cycle from {'joint_position': {joint: v}, 'pressure_a': {act: v}, 'supply_pressure': v, ...} [SI]."""
        messages: dict[str, dict[str, float]] = {name: {} for name in sorted(self.expected)}
        for quantity, mapped in self.machine_wide.items():
            messages[mapped.message][mapped.signal] = float(sample.get(quantity) or 0.0) / mapped.scale
        for slot in self.slots:
            for quantity, mapped in self.per_actuator[slot.actuator].items():
                if quantity == "valve_request":
                    continue
                values = sample.get(quantity) or {}
                value = values.get(slot.joint if quantity.startswith("joint_") else slot.actuator, 0.0)
                messages[mapped.message][mapped.signal] = float(value) / mapped.scale
        return [self._frame(name, physical, counter) for name, physical in messages.items()]

    def encode_request(self, actuator: str, command: float, counter: int) -> tuple[int, bytes]:
        mapped = self.per_actuator[actuator].get("valve_request")
        if mapped is None:
            raise InputError(f"dbc {self.dbc_path}: no valve_request signal for {actuator}: valve commands cannot be sent")
        return self._frame(mapped.message, {mapped.signal: _clip(command, -1.0, 1.0) / mapped.scale}, counter)

    def requests_missing(self) -> list[str]:
        """Actuators whose valve commands the map cannot send."""
        return [a for a, signals in self.per_actuator.items() if "valve_request" not in signals]

    # decoding ----------------------------------------------------------------------------------
    def decode(self, frame_id: int, data: bytes) -> tuple[str, int | None, dict[str, float]]:
        """(message name, counter or None, signals in DBC units) of a valid frame; FrameError otherwise."""
        message = self.by_id.get(frame_id)
        if message is None:
            raise FrameError("unknown_id", f"unknown frame id 0x{frame_id:X}")
        if len(data) != message.length:
            raise FrameError("wrong_dlc", f"{message.name}: {len(data)} data bytes, expected {message.length}")
        checksum = self.checksums.get(message.name)
        covered = self._covered.get(message.name, frozenset())
        if checksum is not None and len(covered) == 1 and self._mask[message.name][next(iter(covered))] == 0xFF:
            # a whole byte (the common case): compared before anything is decoded
            if data[next(iter(covered))] != self._checksum_of(message.name, frame_id, data):
                raise FrameError("bad_checksum", f"{message.name}: checksum mismatch")
            checksum = None
        try:
            values = message.decode(bytes(data), decode_choices=False)
        except Exception as exc:  # cantools raises several types on bad payloads
            raise FrameError("undecodable", f"{message.name}: {exc}") from None
        if checksum is not None and int(values[checksum.signal]) != self._checksum_of(message.name, frame_id, data):
            raise FrameError("bad_checksum", f"{message.name}: checksum mismatch")
        checksum = self.checksums.get(message.name)
        counter = int(values.pop(self.counters[message.name])) if message.name in self.counters else None
        if checksum is not None:
            values.pop(checksum.signal)
        if not all(math.isfinite(float(v)) for v in values.values()):
            raise FrameError("undecodable", f"{message.name}: non-finite value")
        return message.name, counter, {k: float(v) for k, v in values.items()}

    def derived_rate(self, joint: str, stamp_ns: int, position: float) -> float:
        """The joint rate a bus without one implies: the angle differentiated and low-pass filtered, as an encoder's."""
        last = self._last_position.get(joint)
        rate = 0.0
        if last is not None and stamp_ns > last[0]:
            dt = (stamp_ns - last[0]) * 1e-9
            alpha = dt / (dt + 1.0 / (2.0 * math.pi * self._velocity_filter_hz))
            rate = last[2] + alpha * ((position - last[1]) / dt - last[2])
        self._last_position[joint] = (stamp_ns, position, rate)
        return rate


def _clip(value: float, low: float, high: float) -> float:
    return min(max(float(value), low), high)


@dataclass
class CounterCheck:
    """Per message: the rolling counter must advance by one from frame to frame."""

    last: dict[str, int] = field(default_factory=dict)
    gaps: dict[str, int] = field(default_factory=dict)

    def __call__(self, name: str, counter: int | None) -> None:
        if counter is None:
            return
        previous = self.last.get(name)
        if previous is not None and counter != (previous + 1) % COUNTER_MODULO:
            self.gaps[name] = self.gaps.get(name, 0) + 1
        self.last[name] = counter


class CycleAssembler:
    """Groups valid frames into cycles by their shared counter, or without counters by time (a message seen again
    starts the next cycle); a cycle is released complete, or incomplete once ``horizon`` newer cycles have started
    (its missing frames are counted). Every released cycle, complete or not, is stamped by ``clock`` in the order the
    cycles began, so lost and incomplete cycles keep their slots."""

    def __init__(self, expected: frozenset[str], clock: CycleClock, horizon: int = 4, *, by_counter: bool = True) -> None:
        self.expected = expected
        self.clock = clock
        self.horizon = horizon if by_counter else 1
        self.by_counter = by_counter
        self.open: list[Cycle] = []
        self.incomplete = 0

    def add(self, name: str, counter: int | None, values: dict[str, float], stamp_ns: int) -> list[Cycle]:
        if self.by_counter:
            cycle = next((c for c in self.open if c.counter == counter and name not in c.values), None)
        else:
            cycle = self.open[-1] if self.open and name not in self.open[-1].values else None
        if cycle is None:
            cycle = Cycle(counter, stamp_ns)
            self.open.append(cycle)
        cycle.values[name] = values
        released = []
        while self.open and (self.open[0].complete(self.expected) or len(self.open) > self.horizon):
            released.append(self._release(self.open.pop(0)))
        return released

    def flush(self) -> list[Cycle]:
        out, self.open = self.open, []
        return [self._release(cycle) for cycle in out]

    def _release(self, cycle: Cycle) -> Cycle:
        if not cycle.complete(self.expected):
            self.incomplete += 1
        cycle.stamp_ns = self.clock.stamp(cycle.stamp_ns, cycle.counter if self.by_counter else None)
        return cycle


def cycle_values(bus: MachineBus, cycle: Cycle) -> dict[str, Any]:
    """Contract quantities of a cycle in SI, only from frames that arrived (the rest stays absent); a joint rate the bus
    does not carry is derived from the angle."""
    out: dict[str, Any] = {q: {} for q in PER_ACTUATOR if q != "valve_request"}
    for quantity, mapped in bus.machine_wide.items():
        frame = cycle.values.get(mapped.message)
        if frame is not None:
            out[quantity] = frame[mapped.signal] * mapped.scale
    for slot in bus.slots:
        signals = bus.per_actuator[slot.actuator]
        for quantity, mapped in signals.items():
            frame = cycle.values.get(mapped.message)
            if frame is not None and quantity != "valve_request":
                out[quantity][slot.joint if quantity.startswith("joint_") else slot.actuator] = frame[mapped.signal] * mapped.scale
        if "joint_velocity" not in signals and slot.joint in out["joint_position"]:
            out["joint_velocity"][slot.joint] = bus.derived_rate(slot.joint, cycle.stamp_ns, out["joint_position"][slot.joint])
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
