"""The simulated operator: random rest-to-rest moves of the joint, followed in closed loop.

An operator picks a target, moves towards it at a moderate speed, rests, and picks another
(P-II used "fairly random control signals"; amplitude and spectrum are not given, so this
profile is INFERRED). The reference is generated lazily, block by block, so the live node and
the offline simulator share it.
"""

from __future__ import annotations

import numpy as np

from hydro_ros.contract.machine import Excitation


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
