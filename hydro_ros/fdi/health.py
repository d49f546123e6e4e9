"""Sensor validity: a reading that is non-finite, outside its plausible range, or frozen is a sensor fault.

Checked per actuator and sensor on every block, before the residual generator sees the data. An
invalid reading never feeds a residual (the sample is a gap for that actuator); the problems are
held for ``hold_s`` after they were last seen, so the operator sees them rather than a flicker.
The limits are the machine config's ``sensors:`` (``pressure_range``, ``joint_range``,
``joint_velocity_max``, ``frozen_s``).
"""

from __future__ import annotations

import numpy as np

from hydro_ros.contract.machine import Machine

# the per-actuator readings the monitor checks, in this order: joint angle and rate, chamber
# pressures, command, supply pressure, then the mobile valve's pilot and compensator pressures
CHANNELS = ("joint_position", "joint_velocity", "pressure_a", "pressure_b", "valve_command", "supply_pressure",
            "pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")
NONFINITE, OUT_OF_RANGE, FROZEN = "nonfinite", "out_of_range", "frozen"
COMMAND_LIMIT = 1.05  # [-] commands are fractions of full opening; a little beyond is rounding, more is garbage


class SensorHealth:
    """Tracks which readings of which actuator are currently invalid, and why."""

    def __init__(self, machine: Machine, channels: int, sample_rate: float, hold_s: float = 1.0) -> None:
        sensors = machine.sensors
        pressure = sensors.pressure_range
        limits = [sensors.joint_range, (-sensors.joint_velocity_max, sensors.joint_velocity_max), pressure, pressure,
                  (-COMMAND_LIMIT, COMMAND_LIMIT), pressure, pressure, pressure, pressure][:channels]
        self.low, self.high = np.array(limits, dtype=float).T
        self.frozen_checked = np.array(["pressure" in name for name in CHANNELS[:channels]])  # noisy analog readings only
        self.frozen_samples = max(int(round(sensors.frozen_s * sample_rate)), 2)
        self.hold_samples = int(round(hold_s * sample_rate))
        self.channels = channels
        self._last: np.ndarray | None = None  # (A, C) last reading
        self._run: np.ndarray | None = None  # (A, C) how many samples the last reading has repeated
        self._since: dict[str, np.ndarray] = {}  # problem -> (A, C) samples since last seen

    def check(self, values: np.ndarray) -> np.ndarray:
        """(n, A, C) readings -> (n, A, C) whether each reading is valid."""
        n, actuators, _ = values.shape
        if self._last is None:
            self._last = np.full((actuators, self.channels), np.nan)
            self._run = np.zeros((actuators, self.channels), dtype=np.int64)
            self._since = {p: np.full((actuators, self.channels), 1 << 40) for p in (NONFINITE, OUT_OF_RANGE, FROZEN)}
        finite = np.isfinite(values)
        out_of_range = finite & ((values < self.low) | (values > self.high))
        frozen = self._frozen(values, finite & ~out_of_range)
        for problem, seen in ((NONFINITE, ~finite), (OUT_OF_RANGE, out_of_range), (FROZEN, frozen)):
            last = np.where(seen.any(axis=0), n - 1 - np.argmax(seen[::-1], axis=0), -1)
            self._since[problem] = np.where(last >= 0, n - 1 - last, self._since[problem] + n)
        return finite & ~out_of_range & ~frozen

    def _frozen(self, values: np.ndarray, usable: np.ndarray) -> np.ndarray:
        """Readings that have repeated one in-range value for frozen_samples or more (checked channels only)."""
        strictly_inside = usable & (values > self.low) & (values < self.high)
        previous = np.concatenate([self._last[None], values[:-1]])
        same = (values == previous) & strictly_inside
        # run[k]: how many readings in a row up to k equal their predecessor (carried over from the last block)
        index = np.arange(len(values)).reshape(-1, 1, 1)
        last_change = np.maximum.accumulate(np.where(same, -1, index), axis=0)
        run = np.where(last_change >= 0, index - last_change, index + 1 + self._run)
        self._run, self._last = run[-1].copy(), values[-1].copy()
        return (run + 1 >= self.frozen_samples) & self.frozen_checked

    def problems(self, actuator: int) -> dict[str, str]:
        """Channel -> problem of the readings invalid within the last hold time (the worst per channel)."""
        out: dict[str, str] = {}
        if self._last is None:
            return out
        for problem in (FROZEN, OUT_OF_RANGE, NONFINITE):  # later ones win: non-finite is the plainest
            for c in np.flatnonzero(self._since[problem][actuator] < self.hold_samples):
                out[CHANNELS[c]] = problem
        return out
