"""Frames in, complete sensor cycles out: the one path from a machine's CAN frames to its samples, shared by the live
bridge (``nodes/can_bridge``) and the log converter (``can/convert``), so a frame is judged the same way in both."""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Iterator
from typing import Any

from hydro_ros.can.clock import CycleClock
from hydro_ros.can.codec import CounterCheck, Cycle, CycleAssembler, FrameError, MachineBus, cycle_values


class FrameStream:
    """Each frame decoded and checked through the machine's bus (a refused frame counted by its kind, counter gaps
    per message), grouped into cycles on the bus's clock."""

    def __init__(self, bus: MachineBus) -> None:
        self.bus = bus
        self.assembler = CycleAssembler(bus.expected, bus.clock(), by_counter=bus.by_counter)
        self.counters = CounterCheck()
        self.rejected: Counter[str] = Counter()
        self.frames_per_message: Counter[str] = Counter()

    def add(self, arbitration_id: int, data: bytes, timestamp_s: float) -> tuple[str | None, list[Cycle]]:
        """One frame: its message's name (None: refused) and the cycles it releases."""
        try:
            name, counter, values = self.bus.decode(arbitration_id, data)
        except FrameError as exc:
            self.rejected[exc.kind] += 1
            return None, []
        self.frames_per_message[name] += 1
        self.counters(name, counter)
        return name, self.assembler.add(name, counter, values, int(round(timestamp_s * 1e9)))

    def complete(self, cycles: Iterable[Cycle]) -> Iterator[tuple[int, dict[str, Any]]]:
        """(stamp [ns], decoded values) of each complete cycle: one missing a frame is dropped whole (``incomplete``), so
        the monitor sees a gap, never a part-sample."""
        for cycle in cycles:
            if cycle.complete(self.bus.expected):
                yield cycle.stamp_ns, cycle_values(self.bus, cycle)

    def flush(self) -> list[Cycle]:
        """The cycles still held, at the end of a log."""
        return self.assembler.flush()

    @property
    def incomplete(self) -> int:
        return self.assembler.incomplete

    @property
    def clock(self) -> CycleClock:
        return self.assembler.clock
