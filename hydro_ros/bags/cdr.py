"""CDR (little-endian, XCDR1) encoding of the two fixed-layout contract types.

The writer, plant_sim and the reader handle hundreds of thousands of 1 kHz samples without
building message objects; bag_player and plant_sim publish these bytes raw. Both layouts are
cross-checked byte for byte against rosbags' typestore in test_bags.py.
"""

from __future__ import annotations

import struct

from hydro_ros.contract.errors import InputError

_HEADER = b"\x00\x01\x00\x00"  # CDR_LE encapsulation
_STAMP = struct.Struct("<iI")
_U32 = struct.Struct("<I")
_TWO_F64 = struct.Struct("<dd")


class CdrError(InputError):
    """A message's bytes do not match its declared type."""


def _pad(offset: int, alignment: int) -> int:
    return (-offset) % alignment


def _string(text: str, offset: int) -> tuple[bytes, int]:
    data = text.encode() + b"\x00"
    pad = b"\x00" * _pad(offset, 4)
    return pad + _U32.pack(len(data)) + data, offset + len(pad) + 4 + len(data)


def _header(stamp_ns: int, frame_id: str) -> tuple[bytes, int]:
    sec, nsec = divmod(stamp_ns, 1_000_000_000)
    if not -(1 << 31) <= sec < (1 << 31):
        raise CdrError(f"stamp {stamp_ns * 1e-9:.3f} s: outside builtin_interfaces/Time's int32 seconds (1901-2038)")
    head = _STAMP.pack(sec, nsec)
    frame, offset = _string(frame_id, 8)
    return head + frame, offset


def encode_fluid_pressure(stamp_ns: int, frame_id: str, pressure: float, variance: float) -> bytes:
    head, offset = _header(stamp_ns, frame_id)
    return _HEADER + head + b"\x00" * _pad(offset, 8) + _TWO_F64.pack(pressure, variance)


def encode_joint_state(
    stamp_ns: int, frame_id: str, names: list[str], position: list[float], velocity: list[float], effort: list[float]
) -> bytes:
    body, offset = _header(stamp_ns, frame_id)
    parts = [body]
    pad = _pad(offset, 4)
    parts.append(b"\x00" * pad + _U32.pack(len(names)))
    offset += pad + 4
    for name in names:
        chunk, offset = _string(name, offset)
        parts.append(chunk)
    for values in (position, velocity, effort):
        pad = _pad(offset, 4)
        parts.append(b"\x00" * pad + _U32.pack(len(values)))
        offset += pad + 4
        if values:
            pad = _pad(offset, 8)
            parts.append(b"\x00" * pad + struct.pack(f"<{len(values)}d", *values))
            offset += pad + 8 * len(values)
    return _HEADER + b"".join(parts)


def _read_header(data: bytes) -> tuple[int, int]:
    """(stamp_ns, absolute offset just after header.frame_id); alignment is relative to byte 4."""
    if len(data) < 16 or data[:2] != b"\x00\x01":
        raise CdrError("not a little-endian CDR message")
    sec, nsec = _STAMP.unpack_from(data, 4)
    (length,) = _U32.unpack_from(data, 12)
    end = 16 + length
    if end > len(data):
        raise CdrError("frame_id runs past the message")
    return sec * 1_000_000_000 + nsec, end


def _align(offset: int, alignment: int) -> int:
    return offset + _pad(offset - 4, alignment)


def decode_fluid_pressure(data: bytes) -> tuple[int, float, float]:
    """(stamp_ns, fluid_pressure, variance)."""
    stamp, offset = _read_header(data)
    offset = _align(offset, 8)
    if offset + 16 > len(data):
        raise CdrError("FluidPressure truncated")
    pressure, variance = _TWO_F64.unpack_from(data, offset)
    return stamp, pressure, variance


def decode_joint_state(data: bytes) -> tuple[int, list[str], tuple[float, ...], tuple[float, ...]]:
    """(stamp_ns, names, positions, velocities)."""
    stamp, offset = _read_header(data)
    try:
        offset = _align(offset, 4)
        (count,) = _U32.unpack_from(data, offset)
        offset += 4
        names = []
        for _ in range(count):
            offset = _align(offset, 4)
            (n,) = _U32.unpack_from(data, offset)
            if offset + 4 + n > len(data):
                raise CdrError("JointState name runs past the message")
            names.append(data[offset + 4 : offset + 3 + n].decode())
            offset += 4 + n
        arrays = []
        for _ in range(2):
            offset = _align(offset, 4)
            (m,) = _U32.unpack_from(data, offset)
            offset += 4
            if m:
                offset = _align(offset, 8)
            arrays.append(struct.unpack_from(f"<{m}d", data, offset))
            offset += 8 * m
    except (struct.error, UnicodeDecodeError) as exc:
        raise CdrError(f"JointState malformed ({exc})") from None
    return stamp, names, arrays[0], arrays[1]
