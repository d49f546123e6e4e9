"""Complementary filter of P-III (Section II, Fig. 3): MEMS inclinometer + gyro -> angle and rate.

    dz/dt = y_g - b + K_P (y_a - z),    db/dt = -K_I (y_a - z)

z is the angle estimate, y_a the accelerometer inclination, y_g the gyro rate and b the gyro
bias estimate. The low frequencies come from the inclinometer, the high ones from the gyro; K_I
removes a constant gyro bias. The rate handed on is the bias-corrected gyro rate. K_P and K_I
are not given in P-III (INFERRED defaults in config/sam_mems.yaml).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from hydro_ros.contract.errors import InputError


@njit(cache=True)
def _filter(inclination, gyro, dt, k_p, k_i, state, angle_out, rate_out):
    z = state[0]
    b = state[1]
    for k in range(inclination.shape[0]):
        error = inclination[k] - z
        rate = gyro[k] - b
        z += dt * (rate + k_p * error)
        b -= dt * k_i * error
        angle_out[k] = z
        rate_out[k] = rate
    state[0] = z
    state[1] = b


class ComplementaryFilter:
    def __init__(self, k_p: float, k_i: float, sample_rate: float, initial_angle: float | None = None) -> None:
        if k_p <= 0.0 or k_i < 0.0:
            raise InputError(f"complementary filter gains k_p={k_p}, k_i={k_i}: need k_p > 0 and k_i >= 0")
        self.k_p, self.k_i, self.dt = k_p, k_i, 1.0 / sample_rate
        self.state = np.array([np.nan if initial_angle is None else initial_angle, 0.0])

    def __call__(self, inclination: np.ndarray, gyro: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Angle [rad] and rate [rad/s] per sample of a block."""
        if np.isnan(self.state[0]):
            self.state[0] = inclination[0]
        angle = np.empty(len(inclination))
        rate = np.empty(len(inclination))
        _filter(np.asarray(inclination, float), np.asarray(gyro, float), self.dt, self.k_p, self.k_i, self.state, angle, rate)
        return angle, rate
