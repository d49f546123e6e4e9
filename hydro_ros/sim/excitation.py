"""The simulated operator: random rest-to-rest moves of the joint, followed in closed loop.

An operator picks a target, moves towards it at a moderate speed, rests, and picks another
(P-II used "fairly random control signals"; amplitude and spectrum are not given, so this
profile is INFERRED). The reference is generated lazily, block by block, so the live node and
the offline simulator share it.
"""

from __future__ import annotations

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.schema import Excitation


class OperatorReference:
    def __init__(self, settings: Excitation, rng: np.random.Generator, start: float, sample_rate: float) -> None:
        self.low, self.high = settings.joint_range
        self.speed_range = settings.move_speed
        self.rest_range = settings.rest_time
        self.rng = rng
        self.dt = 1.0 / sample_rate
        self.position = float(np.clip(start, self.low, self.high))
        self._target = self.position
        self._speed = 0.0
        self._rest_left = float(rng.uniform(*self.rest_range))

    def _new_move(self) -> None:
        self._target = float(self.rng.uniform(self.low, self.high))
        self._speed = float(self.rng.uniform(*self.speed_range))

    def next(self, n: int) -> np.ndarray:
        out = np.empty(n)
        for k in range(n):
            if self._rest_left > 0.0:
                self._rest_left -= self.dt
                if self._rest_left <= 0.0:
                    self._new_move()
            else:
                step = self._speed * self.dt
                error = self._target - self.position
                if abs(error) <= step:
                    self.position = self._target
                    self._rest_left = float(self.rng.uniform(*self.rest_range))
                else:
                    self.position += np.sign(error) * step
            out[k] = self.position
        return out


class WorkCycleReference:
    """A stored joint trajectory as a work cycle: forwards, a hold, backwards to its start, a hold, again.

    A forwarder's crane repeats its path between the load space and the logs; the holds are where a
    grapple would close or open. ``positions`` (k, J) at ``time`` (k,) are resampled to the sample rate
    once; ``next(n)`` gives the following n samples (n, J).
    """

    def __init__(self, time: np.ndarray, positions: np.ndarray, hold_s: float, sample_rate: float) -> None:
        if hold_s < 0.0 or not np.all(np.isfinite(positions)):
            raise InputError(f"work cycle: hold {hold_s} s must be >= 0 and the trajectory's positions finite")
        t = np.arange(0.0, float(time[-1]) + 0.5 / sample_rate, 1.0 / sample_rate)
        forwards = np.stack([np.interp(t, time, column) for column in np.asarray(positions, dtype=float).T], axis=1)
        hold = int(round(hold_s * sample_rate))
        self.cycle = np.concatenate([forwards, np.repeat(forwards[-1:], hold, axis=0), forwards[::-1],
                                     np.repeat(forwards[:1], hold, axis=0)])
        self.index = 0

    @property
    def start(self) -> np.ndarray:
        return self.cycle[0]

    def next(self, n: int) -> np.ndarray:
        rows = self.cycle[(self.index + np.arange(n)) % len(self.cycle)]
        self.index = (self.index + n) % len(self.cycle)
        return rows
