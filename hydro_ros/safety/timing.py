"""Whether the monitor's samples are regularly timed, so that rates and filters can trust their stamps.

The monitor's equations assume the machine's sample period between samples; a rate differentiated from stamps that
jitter (arrival times of a loaded host, a bridge whose bus clock cannot lock) is off by the jitter, the size of what
commissioning corrects. A sample interval is regular when it is a whole number of periods (a lost sample is a gap,
not a timing fault) within ``TOLERANCE`` of a period. :class:`SampleTiming` reports a problem once more than
``HOLD_SHARE`` of the intervals over the last window are irregular, and clears it only after a whole window with
fewer than ``RELEASE_SHARE`` (hysteresis: no chatter between holding and monitoring).
"""

from __future__ import annotations

from collections import deque

import numpy as np

TOLERANCE = 0.2  # of a period
HOLD_SHARE = 0.02
RELEASE_SHARE = 0.005


class SampleTiming:
    """The regularity of a stream's sample stamps over a window of ``window`` intervals (see the module)."""

    def __init__(self, period_s: float, window: int) -> None:
        self.period_ns = period_s * 1e9
        self.window = max(int(window), 1)
        self._blocks: deque[tuple[int, int]] = deque()  # (intervals, irregular) per observed block, within the window
        self._intervals = self._irregular = 0
        self._last: int | None = None
        self.problem = ""

    def restart(self) -> None:
        """A time jump of the input: the next sample has no interval to the last one."""
        self._last = None

    def observe(self, stamps_ns: np.ndarray) -> str:
        """The problem after these samples ("" while the timing is regular)."""
        if not len(stamps_ns):
            return self.problem
        stamps = np.asarray(stamps_ns, dtype=np.int64)
        intervals = np.diff(stamps if self._last is None else np.concatenate([[self._last], stamps])) / self.period_ns
        self._last = int(stamps[-1])
        irregular = int(np.count_nonzero((intervals < 1.0 - TOLERANCE) | (np.abs(intervals - np.round(intervals)) > TOLERANCE)))
        self._blocks.append((len(intervals), irregular))
        self._intervals += len(intervals)
        self._irregular += irregular
        while self._blocks and self._intervals - self._blocks[0][0] >= self.window:
            n, k = self._blocks.popleft()
            self._intervals -= n
            self._irregular -= k
        share = self._irregular / self._intervals if self._intervals else 0.0
        if share > HOLD_SHARE:
            self.problem = f"{share:.0%} of the sample intervals off the {self.period_ns * 1e-6:g} ms period"
        elif self.problem and share < RELEASE_SHARE and self._intervals >= self.window:
            self.problem = ""
        return self.problem
