"""CDR (little-endian, XCDR1) encoding of the two fixed-layout contract types and of JointTrajectory.

The writer, plant_sim and the reader handle hundreds of thousands of 1 kHz samples without
building message objects; bag_player and plant_sim publish these bytes raw, and trajectory_server
its served trajectories. Every layout is cross-checked byte for byte against rosbags' typestore
in test_bags.py.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence

import numpy as np

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
    chunk, offset = _strings(names, offset)
    parts.append(chunk)
    for values in (position, velocity, effort):
        chunk, offset = _doubles(values, offset)
        parts.append(chunk)
    return _HEADER + b"".join(parts)


def encode_joint_trajectory(
    stamp_ns: int, frame_id: str, names: list[str], times_ns: Sequence[int], positions: np.ndarray, velocities: np.ndarray,
    accelerations: np.ndarray,
) -> bytes:
    """trajectory_msgs/JointTrajectory, one point per row (no efforts): what rclpy's Python-to-C conversion
    does in ~5 ms for 200 points, done once, so a served trajectory goes to several topics as these bytes."""
    body, offset = _header(stamp_ns, frame_id)
    parts = [body]
    chunk, offset = _strings(names, offset)
    parts.append(chunk)
    pad = _pad(offset, 4)
    parts.append(b"\x00" * pad + _U32.pack(len(times_ns)))
    offset += pad + 4
    for position, velocity, acceleration, t_ns in zip(positions, velocities, accelerations, times_ns):
        for values in (position, velocity, acceleration, ()):
            chunk, offset = _doubles(values, offset)
            parts.append(chunk)
        pad = _pad(offset, 4)
        parts.append(b"\x00" * pad + _STAMP.pack(*divmod(int(t_ns), 1_000_000_000)))
        offset += pad + 8
    return _HEADER + b"".join(parts)


def _strings(texts: list[str], offset: int) -> tuple[bytes, int]:
    pad = _pad(offset, 4)
    parts = [b"\x00" * pad + _U32.pack(len(texts))]
    offset += pad + 4
    for text in texts:
        chunk, offset = _string(text, offset)
        parts.append(chunk)
    return b"".join(parts), offset


def _doubles(values: Sequence[float], offset: int) -> tuple[bytes, int]:
    """A sequence<double>: its length, then the values aligned to 8."""
    pad = _pad(offset, 4)
    chunk = b"\x00" * pad + _U32.pack(len(values))
    offset += pad + 4
    if len(values):
        pad = _pad(offset, 8)
        chunk += b"\x00" * pad + struct.pack(f"<{len(values)}d", *values)
        offset += pad + 8 * len(values)
    return chunk, offset


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


def header_stamp_ns(data: bytes) -> int:
    """std_msgs/Header.stamp [ns] of a CDR message whose first field is the header; CdrError if it cannot be one."""
    return _read_header(data)[0]


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
        names, offset = _read_strings(data, offset, "JointState")
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


def _read_strings(data: bytes, offset: int, what: str) -> tuple[list[str], int]:
    """A sequence<string> at ``offset``: (the strings, the offset after it)."""
    offset = _align(offset, 4)
    (count,) = _U32.unpack_from(data, offset)
    offset += 4
    if count > len(data):
        raise CdrError(f"{what} claims {count} names")
    names = []
    for _ in range(count):
        offset = _align(offset, 4)
        (n,) = _U32.unpack_from(data, offset)
        if offset + 4 + n > len(data):
            raise CdrError(f"{what} name runs past the message")
        names.append(data[offset + 4 : offset + 3 + n].decode())
        offset += 4 + n
    return names, offset


def _read_doubles(data: bytes, offset: int) -> tuple[tuple[float, ...], int]:
    offset = _align(offset, 4)
    (count,) = _U32.unpack_from(data, offset)
    offset += 4
    if not count:
        return (), offset
    offset = _align(offset, 8)
    if offset + 8 * count > len(data):
        raise CdrError("a sequence runs past the message")
    return struct.unpack_from(f"<{count}d", data, offset), offset + 8 * count


def decode_joint_trajectory(data: bytes) -> tuple[list[str], np.ndarray, np.ndarray, np.ndarray]:
    """(joint_names, times [s], positions (n, joints), velocities (n, joints), zero where a point gives none) of a
    trajectory_msgs/JointTrajectory. Plain Python on purpose: a thread decoding a large message lets the others run
    (rclpy's own conversion holds the interpreter for the whole message)."""
    _, offset = _read_header(data)
    try:
        names, offset = _read_strings(data, offset, "JointTrajectory")
        offset = _align(offset, 4)
        (count,) = _U32.unpack_from(data, offset)
        offset += 4
        joints = len(names)
        times = np.empty(count)
        positions = np.empty((count, joints))
        velocities = np.zeros((count, joints))
        for k in range(count):
            position, offset = _read_doubles(data, offset)
            velocity, offset = _read_doubles(data, offset)
            for _ in range(2):  # accelerations, effort
                _, offset = _read_doubles(data, offset)
            offset = _align(offset, 4)
            sec, nanosec = struct.unpack_from("<iI", data, offset)
            offset += 8
            if len(position) != joints or len(velocity) not in (0, joints):
                raise CdrError(f"JointTrajectory point {k}: {len(position)} positions and {len(velocity)} velocities for "
                               f"{joints} joint names")
            times[k] = sec + nanosec * 1e-9
            positions[k] = position
            if velocity:
                velocities[k] = velocity
    except (struct.error, UnicodeDecodeError) as exc:
        raise CdrError(f"JointTrajectory malformed ({exc})") from None
    return names, times, positions, velocities


def joint_trajectory_size(data: bytes) -> tuple[list[str], int]:
    """(joint_names, number of points) of a trajectory_msgs/JointTrajectory, read without decoding the points."""
    _, offset = _read_header(data)
    try:
        names, offset = _read_strings(data, offset, "JointTrajectory")
        (points,) = _U32.unpack_from(data, _align(offset, 4))
    except (struct.error, UnicodeDecodeError) as exc:
        raise CdrError(f"JointTrajectory malformed ({exc})") from None
    return names, points


_POINT_FIELD_FLOAT64 = 8  # sensor_msgs/PointField.FLOAT64
SAMPLE_TIME_FIELD = "t"  # [s] after header.stamp: the first field of a sample block


def encode_sample_block(stamp_ns: int, frame_id: str, names: Sequence[str], stamps_ns: np.ndarray, rows: np.ndarray) -> bytes:
    """sensor_msgs/PointCloud2 as a table of samples: one point per sample, its fields the time after header.stamp
    (``t`` [s], header.stamp = the first sample's stamp) and then ``names``, all FLOAT64 little-endian."""
    stamps_ns = np.asarray(stamps_ns, dtype=np.int64)
    rows = np.asarray(rows, dtype=float).reshape(len(stamps_ns), len(names))
    body, offset = _header(stamp_ns, frame_id)
    parts = [body]
    pad = _pad(offset, 4)
    parts.append(b"\x00" * pad + struct.pack("<II", 1, len(stamps_ns)))
    offset += pad + 8
    fields = [SAMPLE_TIME_FIELD, *names]
    parts.append(_U32.pack(len(fields)))
    offset += 4
    for k, name in enumerate(fields):
        chunk, offset = _string(name, offset)
        pad = _pad(offset, 4)
        parts.append(chunk + b"\x00" * pad + _U32.pack(8 * k) + bytes([_POINT_FIELD_FLOAT64]))
        offset += pad + 5
        pad = _pad(offset, 4)
        parts.append(b"\x00" * pad + _U32.pack(1))
        offset += pad + 4
    table = np.column_stack([(stamps_ns - stamp_ns) * 1e-9, rows]).astype("<f8").tobytes()
    point_step = 8 * len(fields)
    pad = _pad(offset + 1, 4)  # is_bigendian, then point_step aligned
    parts.append(b"\x00" + b"\x00" * pad + struct.pack("<III", point_step, point_step * len(stamps_ns), len(table)))
    parts.append(table + bytes([bool(np.isfinite(rows).all())]))
    return _HEADER + b"".join(parts)


def decode_sample_block(data: bytes) -> tuple[list[str], np.ndarray, np.ndarray]:
    """(field names after ``t``, stamps_ns (n,), rows (n, fields)) of a PointCloud2 written by :func:`encode_sample_block`
    (or any other whose fields are all FLOAT64 and begin with ``t``)."""
    stamp, offset = _read_header(data)
    try:
        offset = _align(offset, 4)
        height, width, count = struct.unpack_from("<III", data, offset)
        offset += 12
        names, offsets = [], []
        for _ in range(count):
            offset = _align(offset, 4)
            (n,) = _U32.unpack_from(data, offset)
            name = data[offset + 4 : offset + 3 + n].decode()
            offset = _align(offset + 4 + n, 4)
            (field_offset,) = _U32.unpack_from(data, offset)
            datatype = data[offset + 4]
            offset = _align(offset + 5, 4)
            (field_count,) = _U32.unpack_from(data, offset)
            offset += 4
            if datatype != _POINT_FIELD_FLOAT64 or field_count != 1:
                raise CdrError(f"sample block field {name!r}: datatype {datatype} x {field_count}, expected one FLOAT64")
            names.append(name)
            offsets.append(field_offset)
        big_endian = data[offset]
        offset = _align(offset + 1, 4)
        point_step, _, size = struct.unpack_from("<III", data, offset)
        offset += 12
    except (struct.error, IndexError, UnicodeDecodeError) as exc:
        raise CdrError(f"sample block malformed ({exc})") from None
    if big_endian or not names or names[0] != SAMPLE_TIME_FIELD or offsets != [8 * k for k in range(len(names))]:
        raise CdrError(f"sample block: fields {names} are not little-endian FLOAT64 {SAMPLE_TIME_FIELD!r}, ... in order")
    points = height * width
    if point_step != 8 * len(names) or size != points * point_step or offset + size > len(data):
        raise CdrError(f"sample block: {points} points of {point_step} bytes do not fill its {size} data bytes")
    table = np.frombuffer(data, dtype="<f8", count=points * len(names), offset=offset).reshape(points, len(names))
    return names[1:], stamp + np.round(table[:, 0] * 1e9).astype(np.int64), table[:, 1:]
