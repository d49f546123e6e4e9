"""Sequential MCAP scanning with compiled record and CDR decoding (no per-message Python).

The offline tools read a 1 kHz bag at hundreds of times real time: Python walks the top-level
records and decompresses each chunk (C code), a numba kernel lists the chunk's records, and the
messages of one channel are decoded together by a numba CDR kernel. Layouts follow the MCAP spec
(https://mcap.dev/spec) and XCDR1 little-endian as written by ROS 2 (alignment relative to the
byte after the 4-byte encapsulation header), the same as hydro_ros.bags.cdr.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import BinaryIO

import numpy as np
from numba import njit

try:
    from compression import zstd  # Python >= 3.14
except ImportError:
    from backports import zstd  # before 3.14: a dependency of rosbags

MAGIC = b"\x89MCAP0\r\n"
OP_SCHEMA, OP_CHANNEL, OP_MESSAGE, OP_CHUNK, OP_FOOTER, OP_STATISTICS = 0x03, 0x04, 0x05, 0x06, 0x02, 0x0B
RECORD_OPS = frozenset(range(0x01, 0x10))  # header ... data end: the record types of the MCAP spec


class McapDamage(Exception):
    """The stream is damaged from here on; everything before it was delivered."""


@dataclass
class Channel:
    topic: str
    schema: str


@dataclass
class MessageBatch:
    """Messages of one channel from one chunk: views into ``buffer``."""

    channel_id: int
    buffer: np.ndarray  # uint8
    starts: np.ndarray  # data start offsets
    ends: np.ndarray


@njit(cache=True)
def _u16(buf, i):
    return buf[i] | (buf[i + 1] << 8)


@njit(cache=True)
def _u32(buf, i):
    return np.uint32(buf[i]) | (np.uint32(buf[i + 1]) << 8) | (np.uint32(buf[i + 2]) << 16) | (np.uint32(buf[i + 3]) << 24)


@njit(cache=True)
def _u64(buf, i):
    return np.uint64(_u32(buf, i)) | (np.uint64(_u32(buf, i + 4)) << np.uint64(32))


@njit(cache=True)
def scan_records(buf: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int]:
    """(opcodes, content starts, content ends, message channel ids, bytes consumed) of a record run."""
    n = buf.shape[0]
    capacity = 1024
    ops = np.empty(capacity, np.uint8)
    starts = np.empty(capacity, np.int64)
    ends = np.empty(capacity, np.int64)
    channels = np.empty(capacity, np.int32)
    count = 0
    i = 0
    while i + 9 <= n:
        op = buf[i]
        length = np.int64(_u64(buf, i + 1))
        if length < 0 or i + 9 + length > n:
            break
        if count == capacity:
            capacity *= 2
            ops = np.concatenate((ops, np.empty(capacity - count, np.uint8)))
            starts = np.concatenate((starts, np.empty(capacity - count, np.int64)))
            ends = np.concatenate((ends, np.empty(capacity - count, np.int64)))
            channels = np.concatenate((channels, np.empty(capacity - count, np.int32)))
        ops[count] = op
        starts[count] = i + 9
        ends[count] = i + 9 + length
        channels[count] = _u16(buf, i + 9) if (op == OP_MESSAGE and length >= 22) else -1
        count += 1
        i += 9 + length
    return ops[:count], starts[:count], ends[:count], channels[:count], i


@njit(cache=True)
def _align(offset, s, alignment):
    rel = offset - s - 4
    return offset + ((-rel) % alignment)


@njit(cache=True)
def _body(buf, s, e, alignment, need):
    """(stamp_ns, offset of the first field after std_msgs/Header aligned to ``alignment``),
    or (0, -1) when the message is malformed or has fewer than ``need`` bytes left there."""
    if e - s < 16 or buf[s] != 0 or buf[s + 1] != 1:
        return np.int64(0), np.int64(-1)
    sec = np.int64(np.int32(_u32(buf, s + 4)))
    nsec = np.int64(_u32(buf, s + 8))
    offset = _align(s + 16 + np.int64(_u32(buf, s + 12)), s, alignment)
    if offset + need > e:
        return np.int64(0), np.int64(-1)
    return sec * 1_000_000_000 + nsec, offset


@njit(cache=True)
def _f64(buf, i):
    return buf[i:i + 8].copy().view(np.float64)[0]


@njit(cache=True)
def decode_fluid_pressures(buf, starts, ends):
    """sensor_msgs/FluidPressure batch -> (stamps, pressures, ok)."""
    m = starts.shape[0]
    stamps = np.zeros(m, np.int64)
    values = np.full(m, np.nan)
    ok = np.zeros(m, np.bool_)
    for k in range(m):
        stamp, offset = _body(buf, starts[k], ends[k], 8, 16)
        if offset < 0:
            continue
        stamps[k] = stamp
        values[k] = _f64(buf, offset)
        ok[k] = True
    return stamps, values, ok


@njit(cache=True)
def decode_joint_states(buf, starts, ends, width):
    """sensor_msgs/JointState batch -> (stamps, names byte ranges, positions, velocities, ok).

    Names are returned as byte ranges so the caller compares them without building strings.
    """
    m = starts.shape[0]
    stamps = np.zeros(m, np.int64)
    name_ranges = np.zeros((m, 2), np.int64)
    position = np.full((m, width), np.nan)
    velocity = np.full((m, width), np.nan)
    ok = np.zeros(m, np.bool_)
    for k in range(m):
        s, e = starts[k], ends[k]
        stamp, offset = _body(buf, s, e, 4, 4)
        if offset < 0:
            continue
        count = np.int64(_u32(buf, offset))
        name_ranges[k, 0] = offset
        offset += 4
        bad = False
        for _ in range(count):
            offset = _align(offset, s, 4)
            if offset + 4 > e:
                bad = True
                break
            offset += 4 + np.int64(_u32(buf, offset))
            if offset > e:
                bad = True
                break
        if bad:
            continue
        name_ranges[k, 1] = offset
        for array in range(2):
            offset = _align(offset, s, 4)
            if offset + 4 > e:
                bad = True
                break
            n = np.int64(_u32(buf, offset))
            offset += 4
            if n:
                offset = _align(offset, s, 8)
            if offset + 8 * n > e:
                bad = True
                break
            for j in range(min(n, width)):
                value = _f64(buf, offset + 8 * j)
                if array == 0:
                    position[k, j] = value
                else:
                    velocity[k, j] = value
            offset += 8 * n
        if bad:
            continue
        stamps[k] = stamp
        ok[k] = True
    return stamps, name_ranges, position, velocity, ok


@njit(cache=True)
def same_bytes(buf, ranges, reference):
    """Per row of ``ranges``: do its bytes equal ``reference``?"""
    out = np.zeros(ranges.shape[0], np.bool_)
    size = reference.shape[0]
    for k in range(ranges.shape[0]):
        a, b = ranges[k, 0], ranges[k, 1]
        if b - a != size:
            continue
        equal = True
        for j in range(size):
            if buf[a + j] != reference[j]:
                equal = False
                break
        out[k] = equal
    return out


def _string(data: bytes, offset: int) -> tuple[str, int]:
    (n,) = struct.unpack_from("<I", data, offset)
    return data[offset + 4 : offset + 4 + n].decode(), offset + 4 + n


def _decompress(compression: str, payload: bytes, size: int) -> bytes:
    if compression == "":
        return payload
    if compression == "zstd":
        return zstd.decompress(payload)
    if compression == "lz4":
        import lz4.frame

        return lz4.frame.decompress(payload)
    raise McapDamage(f"unsupported chunk compression {compression!r}")


def _chunk_records(content: bytes) -> bytes | None:
    """A chunk record's decompressed records, or None where the chunk is damaged."""
    try:
        _, _, size, crc = struct.unpack_from("<QQQI", content, 0)
        compression, offset = _string(content, 28)
        (records_len,) = struct.unpack_from("<Q", content, offset)
        if offset + 8 + records_len > len(content) or (records_len == 0 and len(content) > offset + 8):
            return None  # records beyond the chunk, or none in a chunk with bytes left (a zeroed header reads as empty)
        records = _decompress(compression, content[offset + 8 : offset + 8 + records_len], size)
    except Exception:  # struct, UnicodeDecodeError, zstd or lz4 errors all mean a damaged chunk
        return None
    if len(records) != size or (crc and zlib.crc32(records) != crc):
        return None
    return records


@dataclass
class McapScanner:
    """Walks an MCAP stream: ``channels`` fills as records appear; ``batches()`` yields messages."""

    stream: BinaryIO
    channels: dict[int, Channel] = field(default_factory=dict)
    schemas: dict[int, str] = field(default_factory=dict)
    messages: int = 0
    skipped: list[str] = field(default_factory=list)  # damaged stretches read past, each said once
    counted: int | None = None  # the messages the file's summary (its statistics record) says it holds

    def _records(self, buf: np.ndarray, raw: bytes) -> Iterator[MessageBatch]:
        ops, starts, ends, channel_ids, consumed = scan_records(buf)
        if consumed != len(buf):
            self.skipped.append(f"a damaged record in a chunk: its last {len(buf) - consumed} bytes skipped")
        for k in np.flatnonzero(ops != OP_MESSAGE):
            self._metadata(int(ops[k]), raw[starts[k] : ends[k]], in_chunk=True)
        messages = ops == OP_MESSAGE
        ids = channel_ids[messages]
        self.messages += int(messages.sum())
        for channel_id in np.unique(ids):
            pick = ids == channel_id
            yield MessageBatch(int(channel_id), buf, starts[messages][pick] + 22, ends[messages][pick])

    def _resync(self, position: int, reason: str) -> bool:
        """Move to the next intact chunk after a damaged record header; False if there is none."""
        self.stream.seek(position + 1)
        rest = self.stream.read()
        start = 0
        while True:
            k = rest.find(bytes([OP_CHUNK]), start)
            if k < 0 or k + 9 > len(rest):
                self.skipped.append(f"{reason} at byte {position}: no intact chunk after it")
                return False
            (length,) = struct.unpack_from("<Q", rest, k + 1)
            if k + 9 + length <= len(rest) and _chunk_records(rest[k + 9 : k + 9 + length]) is not None:
                self.skipped.append(f"{reason} at byte {position}: {k + 1} bytes skipped to the next intact chunk")
                self.stream.seek(position + 1 + k)
                return True
            start = k + 1

    def _metadata(self, op: int, content: bytes, *, in_chunk: bool = False) -> None:
        """A schema or channel record. One inside a chunk (rosbags writes them there, and the summary again) never
        replaces what the summary said, and one that cannot be decoded costs only itself: the summary's stands."""
        try:
            if op == OP_SCHEMA:
                (schema_id,) = struct.unpack_from("<H", content, 0)
                if not (in_chunk and schema_id in self.schemas):
                    self.schemas[schema_id], _ = _string(content, 2)
            elif op == OP_CHANNEL:
                channel_id, schema_id = struct.unpack_from("<HH", content, 0)
                if not (in_chunk and channel_id in self.channels):
                    topic, _ = _string(content, 4)
                    self.channels[channel_id] = Channel(topic, self.schemas.get(schema_id, ""))
        except (struct.error, UnicodeDecodeError) as exc:
            if not in_chunk:
                raise
            self.skipped.append(f"a damaged {'schema' if op == OP_SCHEMA else 'channel'} record in a chunk ({type(exc).__name__}): "
                                "the summary's is used")

    def _summary_channels(self, size: int) -> None:
        """The schemas and channels the file's summary section repeats, read first: a damaged chunk that defined them
        then costs only its own messages, not every later message of its channels."""
        footer = size - len(MAGIC) - 29  # the footer record: opcode, length 20, summary start, summary offset start, CRC
        if footer <= len(MAGIC):
            return
        self.stream.seek(footer)
        head = self.stream.read(29)
        if len(head) < 29 or head[0] != OP_FOOTER:
            return
        (summary_start,) = struct.unpack_from("<Q", head, 9)
        (summary_crc,) = struct.unpack_from("<I", head, 25)
        if not len(MAGIC) < summary_start < footer:
            return
        self.stream.seek(summary_start)
        summary = self.stream.read(footer - summary_start)
        # the footer's CRC covers the summary and the footer up to itself; a summary that fails it says nothing
        intact = summary_crc == 0 or zlib.crc32(head[:25], zlib.crc32(summary)) == summary_crc
        position = 0
        while position + 9 <= len(summary):
            op = summary[position]
            (length,) = struct.unpack_from("<Q", summary, position + 1)
            content = summary[position + 9 : position + 9 + length]
            if len(content) < length:
                return
            if op in (OP_SCHEMA, OP_CHANNEL):
                try:
                    self._metadata(op, content)
                except (struct.error, UnicodeDecodeError):
                    return
            elif op == OP_STATISTICS and len(content) >= 8 and intact:
                (self.counted,) = struct.unpack_from("<Q", content, 0)
            position += 9 + length

    def batches(self) -> Iterator[MessageBatch]:
        """Message batches in file order; raises McapDamage where the stream stops making sense.

        A damaged chunk is skipped and noted in ``skipped``; where a record header itself is damaged,
        reading resumes at the next intact chunk, so the chunks after a damaged one are still read.
        """
        size = self.stream.seek(0, 2)
        self.stream.seek(0)
        if self.stream.read(8) != MAGIC:
            raise McapDamage("not an MCAP file (bad magic)")
        self._summary_channels(size)
        self.stream.seek(8)
        while True:
            position = self.stream.tell()
            head = self.stream.read(9)
            if not head:
                raise McapDamage("file ends without a footer (truncated)")
            if len(head) < 9:
                raise McapDamage("truncated record header")
            op = head[0]
            (length,) = struct.unpack_from("<Q", head, 1)
            if op not in RECORD_OPS:
                if not self._resync(position, f"unknown record opcode 0x{op:02x}"):
                    return
                continue
            remaining = size - position - 9
            if length > remaining:
                if not self._resync(position, f"record of {length} bytes in the {remaining} bytes left"):
                    raise McapDamage(f"record of {length} bytes truncated to {remaining}")
                continue
            content = self.stream.read(length)
            if op == OP_FOOTER:
                return
            if op == OP_CHUNK:
                records = _chunk_records(content)
                if records is None:
                    self.skipped.append(f"damaged chunk at byte {position} skipped (CRC, size or compression)")
                    continue
                yield from self._records(np.frombuffer(records, np.uint8), records)
            elif op == OP_MESSAGE:
                record = head + content
                yield from self._records(np.frombuffer(record, np.uint8), record)
            else:
                self._metadata(op, content)

    def iter_messages(self) -> Iterator[tuple[str, str, int, bytes]]:
        """(topic, schema name, log time, CDR bytes) of every message: chunk after chunk, by log time within one."""
        pending: list[MessageBatch] = []
        for batch in self.batches():
            if pending and batch.buffer is not pending[0].buffer:
                yield from self._by_log_time(pending)
                pending = []
            pending.append(batch)
        yield from self._by_log_time(pending)

    def _by_log_time(self, batches: list[MessageBatch]) -> Iterator[tuple[str, str, int, bytes]]:
        rows = []
        for batch in batches:
            channel = self.channels.get(batch.channel_id, Channel("", ""))
            # a message record's log time sits 16 bytes before its data (publish time between)
            log_times = batch.buffer[(batch.starts - 16)[:, None] + np.arange(8)].copy().view("<u8")[:, 0]
            rows += [(int(t), channel, batch.buffer, int(a), int(b)) for t, a, b in zip(log_times, batch.starts, batch.ends)]
        rows.sort(key=lambda row: row[0])
        for log_time, channel, buffer, start, end in rows:
            yield channel.topic, channel.schema, log_time, buffer[start:end].tobytes()
