"""Load-independent unscented Kalman filter of P-II (Sections 3.2-3.3), batched over actuators.

State x = [p_A, p_B, x_s, x_s'] with pressures carried in MPa inside the filter: the covariance
then spans ~1e0..1e-10 instead of 1e12..1e-10, which keeps the 4x4 Cholesky well conditioned
with the alpha = 0.001 weights (|W| ~ 1e6). Inputs u = [x, x', u_c, p_S] (piston position and
velocity from the joint sensor, valve command, supply pressure [Pa]); measurement y = [p_A, p_B].

Numerical guards (INFERRED, not in P-II): the sigma-point mean is formed as
chi_0 + sum W_i (chi_i - chi_0), which is exact because the weights sum to one but avoids adding
two 1e6-weighted numbers of size ~10 MPa; the covariance is symmetrised after every update and a
failed Cholesky is repaired by re-seeding the covariance with its clipped diagonal (counted).

The measurement update is P-II's linear form (eqs. 14-15, P_yy = H P^- H^T + R, P_xy = P^- H^T),
which equals the general sigma-point form when the sigma points are redrawn from P^-.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numba import njit

from hydro_ros.contract.errors import InputError
from hydro_ros.models.sam import Param, SamModel, chambers
from hydro_ros.models.valve import chamber_valve_flows, spool_acceleration

N_X = 4
N_Y = 2
N_SIGMA = 2 * N_X + 1
PRESSURE_UNIT = 1.0e6  # [Pa] per filter pressure unit (MPa, the papers' residual unit)


@njit(cache=True)
def reduced_model_step(x: np.ndarray, u: np.ndarray, p: np.ndarray, poly: np.ndarray, centre: np.ndarray, dt: float, out: np.ndarray) -> None:
    """P-II eq. (18), Euler step of the reduced model; x and out in filter units (MPa)."""
    p_a = x[0] * PRESSURE_UNIT
    p_b = x[1] * PRESSURE_UNIT
    piston = u[0]
    velocity = u[1]
    q_a, q_b = chamber_valve_flows(x[2], x[2], p_a, p_b, u[3], p[Param.TANK], poly, centre, p[Param.LAMINAR_BAND], 1.0)  # no overlap: one opening
    volume_a, volume_b, bulk_a, bulk_b = chambers(p, piston, p_a, p_b, 0.0)  # P-II eq. (19): no entrained air in the monitor's model
    out[0] = x[0] + dt * bulk_a / volume_a * (q_a - velocity * p[Param.AREA_A]) / PRESSURE_UNIT
    out[1] = x[1] + dt * bulk_b / volume_b * (q_b + velocity * p[Param.AREA_B]) / PRESSURE_UNIT
    out[2] = x[2] + dt * x[3]
    out[3] = x[3] + dt * spool_acceleration(x[2], x[3], u[2], p[Param.SPOOL_OMEGA], p[Param.SPOOL_DAMPING])


@njit(cache=True)
def _cholesky(a: np.ndarray, out: np.ndarray) -> bool:
    """Lower Cholesky factor of a small SPD matrix; False when a pivot is not positive."""
    n = a.shape[0]
    for j in range(n):
        s = a[j, j]
        for k in range(j):
            s -= out[j, k] * out[j, k]
        if not s > 0.0:
            return False
        d = math.sqrt(s)
        out[j, j] = d
        for i in range(j + 1, n):
            t = a[i, j]
            for k in range(j):
                t -= out[i, k] * out[j, k]
            out[i, j] = t / d
        for i in range(j):
            out[i, j] = 0.0
    return True


@njit(cache=True)
def _propagate(x: np.ndarray, cov: np.ndarray, u: np.ndarray, p: np.ndarray, poly: np.ndarray, centre: np.ndarray,
               spread: float, dt: float, sigmas: np.ndarray, propagated: np.ndarray, root: np.ndarray) -> bool:
    """Draw the 2L+1 sigma points of (x, cov) and push the whole batch through the model."""
    scaled = cov * spread
    ok = _cholesky(scaled, root)
    if not ok:
        for i in range(N_X):
            for j in range(N_X):
                cov[i, j] = max(cov[i, i], 1e-12) if i == j else 0.0
        _cholesky(cov * spread, root)
    for j in range(N_X):
        sigmas[0, j] = x[j]
    for i in range(N_X):
        for j in range(N_X):
            sigmas[1 + i, j] = x[j] + root[j, i]
            sigmas[1 + N_X + i, j] = x[j] - root[j, i]
    for s in range(N_SIGMA):
        reduced_model_step(sigmas[s], u, p, poly, centre, dt, propagated[s])
    return ok


@njit(cache=True)
def ukf_run(
    x: np.ndarray,
    cov: np.ndarray,
    inputs: np.ndarray,
    measurements: np.ndarray,
    valid: np.ndarray,
    params: np.ndarray,
    poly: np.ndarray,
    centre: np.ndarray,
    process_noise: np.ndarray,
    measurement_noise: np.ndarray,
    weights: np.ndarray,
    dt: float,
    prior_out: np.ndarray,
    posterior_out: np.ndarray,
) -> int:
    """Filter ``n`` samples for ``A`` actuators at once; returns the number of Cholesky repairs.

    Shapes: x (A, 4), cov (A, 4, 4), inputs (n, A, 4), measurements (n, A, 2) [Pa],
    valid (n, A), params (A, N_PARAMS), poly (A, 4, 4), centre (A, 4), process_noise (A, 4),
    measurement_noise (A, 2) in filter units, weights = [Wm0, Wc0, Wi, L + lambda];
    prior_out / posterior_out (n, A, 2) [Pa]. An invalid sample leaves the filter untouched and
    writes NaN estimates.
    """
    n_actuators = x.shape[0]
    sigmas = np.empty((N_SIGMA, N_X))
    propagated = np.empty((N_SIGMA, N_X))
    root = np.zeros((N_X, N_X))
    mean = np.empty(N_X)
    delta = np.empty(N_X)
    dev = np.empty((N_SIGMA, N_X))
    gain = np.empty((N_X, N_Y))
    update = np.empty((N_X, N_X))
    wc0 = weights[1]
    wi = weights[2]
    spread = weights[3]
    repairs = 0
    for k in range(inputs.shape[0]):
        for a in range(n_actuators):
            if not valid[k, a]:
                prior_out[k, a, 0] = np.nan
                prior_out[k, a, 1] = np.nan
                posterior_out[k, a, 0] = np.nan
                posterior_out[k, a, 1] = np.nan
                continue
            P = cov[a]
            xa = x[a]
            if not _propagate(xa, P, inputs[k, a], params[a], poly[a], centre[a], spread, dt, sigmas, propagated, root):
                repairs += 1
            # a-priori mean (eq. 7) as chi_0 + sum W_i (chi_i - chi_0)
            for j in range(N_X):
                acc = 0.0
                for s in range(1, N_SIGMA):
                    acc += propagated[s, j] - propagated[0, j]
                delta[j] = wi * acc
                mean[j] = propagated[0, j] + delta[j]
            for s in range(N_SIGMA):
                for j in range(N_X):
                    dev[s, j] = propagated[s, j] - mean[j]
            # a-priori covariance (eq. 8)
            for i in range(N_X):
                for j in range(i, N_X):
                    acc = wc0 * dev[0, i] * dev[0, j]
                    for s in range(1, N_SIGMA):
                        acc += wi * dev[s, i] * dev[s, j]
                    acc += process_noise[a, i] if i == j else 0.0
                    P[i, j] = acc
                    P[j, i] = acc
            prior_out[k, a, 0] = mean[0] * PRESSURE_UNIT
            prior_out[k, a, 1] = mean[1] * PRESSURE_UNIT
            # measurement update, linear H = [I2 0] (eqs. 11-15)
            s00 = P[0, 0] + measurement_noise[a, 0]
            s11 = P[1, 1] + measurement_noise[a, 1]
            s01 = P[0, 1]
            det = s00 * s11 - s01 * s01
            i00 = s11 / det
            i11 = s00 / det
            i01 = -s01 / det
            e0 = measurements[k, a, 0] / PRESSURE_UNIT - mean[0]
            e1 = measurements[k, a, 1] / PRESSURE_UNIT - mean[1]
            for i in range(N_X):
                gain[i, 0] = P[i, 0] * i00 + P[i, 1] * i01
                gain[i, 1] = P[i, 0] * i01 + P[i, 1] * i11
            for i in range(N_X):
                xa[i] = mean[i] + gain[i, 0] * e0 + gain[i, 1] * e1
            # P = P^- - K P_yy K^T = P^- - K P_xy^T, symmetrised
            for i in range(N_X):
                for j in range(N_X):
                    update[i, j] = gain[i, 0] * P[j, 0] + gain[i, 1] * P[j, 1]
            for i in range(N_X):
                for j in range(i, N_X):
                    value = 0.5 * ((P[i, j] - update[i, j]) + (P[j, i] - update[j, i]))
                    P[i, j] = value
                    P[j, i] = value
            posterior_out[k, a, 0] = xa[0] * PRESSURE_UNIT
            posterior_out[k, a, 1] = xa[1] * PRESSURE_UNIT
    return repairs


def unscented_weights(alpha: float, beta: float, kappa: float, n: int = N_X) -> np.ndarray:
    """[Wm0, Wc0, Wi, L + lambda] of the scaled unscented transform (P-II eq. 21 settings)."""
    lam = alpha * alpha * (n + kappa) - n
    spread = n + lam
    return np.array([lam / spread, lam / spread + (1.0 - alpha * alpha + beta), 0.5 / spread, spread])


@dataclass
class UkfSettings:
    """Tuning of P-II eq. (21) in SI units (Pa^2 for pressures), as in the paper's tables."""

    alpha: float = 1.0e-3
    beta: float = 2.0
    kappa: float = 0.0
    initial_state: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # [Pa, Pa, -, 1/s]
    initial_covariance: tuple[float, float, float, float] = (1.0e12, 1.0e12, 1.0e-3, 1.0e-3)
    process_noise: tuple[float, float, float, float] = (1.0e8, 1.0e8, 1.0e-10, 1.0e-10)
    measurement_noise: tuple[float, float] = (1.0e10, 1.0e10)
    laminar_band: float | None = None  # [Pa] orifice linearisation of the filter's model; None = the machine's

    @classmethod
    def from_config(cls, section: dict[str, Any] | None) -> UkfSettings:
        section = dict(section or {})
        known = {name: section.pop(name) for name in list(section) if name in cls.__dataclass_fields__}
        if section:
            raise InputError(f"fdi.ukf: unknown key(s) {', '.join(sorted(section))}")
        for name in ("initial_state", "initial_covariance", "process_noise", "measurement_noise"):
            if name in known:
                known[name] = tuple(float(v) for v in known[name])
        return cls(**known)


_PRESSURE_SCALE = np.array([PRESSURE_UNIT, PRESSURE_UNIT, 1.0, 1.0])


class UkfBank:
    """One P-II UKF per actuator, all advanced together by :func:`ukf_run`."""

    def __init__(self, models: list[SamModel], settings: UkfSettings) -> None:
        self.models = models
        self.settings = settings
        self.dt = 1.0 / models[0].sample_rate
        self.params = np.stack([m.base.copy() for m in models])
        if settings.laminar_band is not None:
            self.params[:, Param.LAMINAR_BAND] = settings.laminar_band
        self.poly = np.stack([m.poly for m in models])
        self.centre = np.stack([m.centre_leakage for m in models])
        n = len(models)
        self.process_noise = np.tile(np.asarray(settings.process_noise) / _PRESSURE_SCALE**2, (n, 1))
        self.measurement_noise = np.tile(np.asarray(settings.measurement_noise) / PRESSURE_UNIT**2, (n, 1))
        self.weights = unscented_weights(settings.alpha, settings.beta, settings.kappa)
        self.repairs = 0
        self.reset()

    def reset(self) -> None:
        n = len(self.models)
        self.x = np.tile(np.asarray(self.settings.initial_state) / _PRESSURE_SCALE, (n, 1))
        self.cov = np.tile(np.diag(np.asarray(self.settings.initial_covariance) / _PRESSURE_SCALE**2), (n, 1, 1))

    def run(self, inputs: np.ndarray, measurements: np.ndarray, valid: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Filter a block: inputs (n, A, 4), measurements (n, A, 2) [Pa] -> (prior, posterior) [Pa]."""
        n = inputs.shape[0]
        prior = np.empty((n, len(self.models), N_Y))
        posterior = np.empty_like(prior)
        self.repairs += ukf_run(
            self.x, self.cov, np.ascontiguousarray(inputs, dtype=float), np.ascontiguousarray(measurements, dtype=float),
            np.ascontiguousarray(valid, dtype=np.bool_), self.params, self.poly, self.centre,
            self.process_noise, self.measurement_noise, self.weights, self.dt, prior, posterior,
        )
        return prior, posterior

    def state_si(self) -> np.ndarray:
        """Current estimates in SI (Pa, Pa, -, 1/s), shape (A, 4)."""
        return self.x * _PRESSURE_SCALE
