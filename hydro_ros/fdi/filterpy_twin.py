"""filterpy's UnscentedKalmanFilter on the same model and tuning: the reference of tests and bench.

filterpy forms P_yy and P_xy from the propagated sigma points, which lack Q; redrawing them
from P^- before the update gives P-II's linear update (eqs. 14-15), the form UkfBank uses.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from hydro_ros.fdi.ukf import PRESSURE_UNIT, UkfBank, reduced_model_step

_SCALE = np.array([PRESSURE_UNIT, PRESSURE_UNIT, 1.0, 1.0])


def filterpy_twin(bank: UkfBank, actuator: int = 0) -> tuple[object, Callable[[np.ndarray, np.ndarray], np.ndarray]]:
    """(filter, step): step(inputs (4,), measurement (2,) [Pa]) -> a-posteriori state in SI."""
    from filterpy.kalman import MerweScaledSigmaPoints, UnscentedKalmanFilter

    settings = bank.settings
    params, poly, centre = bank.params[actuator], bank.poly[actuator], bank.centre[actuator]

    def fx(state: np.ndarray, dt: float, u: np.ndarray) -> np.ndarray:
        out = np.empty(4)
        reduced_model_step(state / _SCALE, u, params, poly, centre, dt, out)
        return out * _SCALE

    points = MerweScaledSigmaPoints(4, settings.alpha, settings.beta, settings.kappa)
    ukf = UnscentedKalmanFilter(4, 2, bank.dt, hx=lambda state: state[:2], fx=fx, points=points)
    ukf.x = np.array(settings.initial_state, dtype=float)
    ukf.P = np.diag(settings.initial_covariance)
    ukf.Q = np.diag(settings.process_noise)
    ukf.R = np.diag(settings.measurement_noise)

    def step(inputs: np.ndarray, measurement: np.ndarray) -> np.ndarray:
        ukf.predict(u=inputs)
        ukf.sigmas_f = points.sigma_points(ukf.x, ukf.P)
        ukf.update(measurement)
        return ukf.x

    return ukf, step
