"""Condition monitor of a machine: residual generation, evaluation and isolation per actuator.

Per sample block: the residual generator (P-II UKF) gives chamber-pressure estimates; the
residual r = p - p_hat is masked, averaged over a 5 s window (eq. 24), compared with the adaptive
threshold +-(c0 + c2 mu_p^2) (eq. 25, per chamber, mu_p the 5 s mean measured pressure) and the
crossing pattern is fed to the isolator (P-II Table 3). Everything is vectorised over the block;
only changes of the evidence reach the (Python) isolation logic.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.isolation import (
    A_DOWN,
    A_UP,
    B_DOWN,
    B_UP,
    UKF_TABLE,
    Alarm,
    Isolator,
    PatternRow,
    code_string,
    signature_rows,
)
from hydro_ros.fdi.parity import ParityGenerator, ParityThresholds
from hydro_ros.fdi.ukf import PRESSURE_UNIT, UkfBank, UkfSettings
from hydro_ros.models.kinematics import piston_position, torque_arm
from hydro_ros.models.sam import MOUNT_L1, MOUNT_L2, MOUNT_L3, THETA_OFFSET, SamModel
from hydro_ros.contract.names import Fault
from hydro_ros.contract.samples import Samples

OK, WARN, ERROR, STALE = 0, 1, 2, 3  # diagnostic_msgs/DiagnosticStatus levels

DEFAULT_SEVERE = (
    Fault.SPOOL_TOO_SMALL_OPENING,
    Fault.SPOOL_TOO_LARGE_OPENING,
    Fault.SPOOL_STUCK_CLOSED,
    Fault.MAIN_SPOOL_LOCKING,
    Fault.COMPENSATOR_SPOOL_LOCKING,
)


@dataclass
class FdiSettings:
    """The ``fdi:`` section of a machine config (defaults = P-II; see config/sam.yaml)."""

    method: str = "ukf"
    window_s: float = 5.0
    threshold_constant: float = 0.012  # [MPa] c0 of eq. (25); P-III: 0.015 encoder, 0.023 MEMS
    threshold_quadratic: float = 4.0e-4  # [1/MPa] c2 of eq. (25)
    residual: str = "posterior"  # which estimate p_hat is: a-posteriori (default) or a-priori
    mask_pressure_b: float = 2.0e5  # [Pa] residuals zeroed while p_B is below this (P-II "close to zero")
    mask_retracted: float = 2.0e-3  # [m] ... or while the piston is within this of full retraction (P-III)
    large_residual: float = 1.0  # [MPa] "Large" of Table 3: both |mean residuals| above this (INFERRED, tuned in
    # simulation: a spool stuck closed gives 1.5-1.8 MPa, a 40 % too small opening < 0.8 MPa, leaks < 0.2 MPa)
    settle_s: float = 1.0  # [s] a crossing pattern must hold this long before it narrows the cause
    command_deadband: float = 0.005  # |5 s mean valve command| below this leaves the command sign unknown
    stale_timeout_s: float = 0.2  # [s] a sensor silent this long makes the actuator STALE
    severe_faults: tuple[Fault, ...] = DEFAULT_SEVERE
    ukf: UkfSettings = field(default_factory=UkfSettings)
    parity_thresholds: ParityThresholds | None = None  # fitted by fdi-fit on fault-free data
    parity_signatures: tuple[PatternRow, ...] = ()  # built by simulation (fdi-fit)

    @classmethod
    def from_config(cls, config: dict[str, Any]) -> "FdiSettings":
        section = dict(config.get("fdi") or {})
        ukf = UkfSettings.from_config(section.pop("ukf", None))
        severe = section.pop("severe_faults", None)
        thresholds = ParityThresholds.from_config(section.pop("parity_thresholds", None))
        signatures = signature_rows(section.pop("parity_signatures", None) or [])
        unknown = [name for name in section if name not in cls.__dataclass_fields__]
        if unknown:
            raise InputError(f"fdi: unknown key(s) {', '.join(sorted(unknown))}")
        settings = cls(ukf=ukf, parity_thresholds=thresholds, parity_signatures=signatures, **section)
        if severe is not None:
            try:
                settings.severe_faults = tuple(Fault(name) for name in severe)
            except ValueError as exc:
                raise InputError(f"fdi.severe_faults: {exc}") from None
        if settings.method not in ("ukf", "parity"):
            raise InputError(f"fdi.method {settings.method!r}: expected ukf or parity")
        if settings.residual not in ("posterior", "prior"):
            raise InputError(f"fdi.residual {settings.residual!r}: expected posterior or prior")
        return settings


class MovingAverage:
    """Eq. (24): mean of the last N samples per channel, zero-initialised like the paper's buffer."""

    def __init__(self, window: int, channels: int) -> None:
        self.window = window
        self.history = np.zeros((window, channels))

    def reset(self) -> None:
        self.history[:] = 0.0

    def __call__(self, block: np.ndarray) -> np.ndarray:
        m = block.shape[0]
        extended = np.concatenate((self.history, block))
        sums = np.cumsum(extended, axis=0)
        # mean of the N samples ending at each block sample; cumsum differences stay exact enough
        # because the whole history is re-summed every block (no recursive drift)
        out = (sums[self.window :] - sums[:m]) / self.window
        self.history = extended[m:].copy()
        return out


@dataclass
class BlockResult:
    """Residual evaluation of one block: MPa for the UKF method, L/min for the parity method."""

    times: np.ndarray
    residual: np.ndarray  # (n, A, 2) raw masked residual
    mean_residual: np.ndarray  # (n, A, 2) 5 s mean
    threshold: np.ndarray  # (n, A, 2) positive threshold (negative is its mirror)
    code: np.ndarray  # (n, A) crossing pattern bits
    valid: np.ndarray  # (n, A)
    alarms: list[Alarm]
    mean_command: np.ndarray  # (n, A) 5 s mean valve command
    operating_point: np.ndarray | None = None  # (n, A) parity: 5 s mean pilot-measured opening


@dataclass
class ActuatorStatus:
    level: int
    message: str
    fault: Fault | None
    detected_at: float | None
    code: str


class FdiMonitor:
    """Runs the configured FDI method on every actuator of a machine config."""

    def __init__(self, config: dict[str, Any], method: str | None = None) -> None:
        self.config = config
        self.settings = FdiSettings.from_config(config)
        self.method = method or self.settings.method
        if self.method not in ("ukf", "parity"):
            raise InputError(f"fdi method {self.method!r}: expected ukf or parity")
        self.actuators = list(config["actuators"])
        self.joints = [str(config["actuators"][a]["joint"]) for a in self.actuators]
        self.models = [SamModel(config, a) for a in self.actuators]
        self.sample_rate = self.models[0].sample_rate
        self.window = int(round(self.settings.window_s * self.sample_rate))
        self.bank = UkfBank(self.models, self.settings.ukf) if self.method == "ukf" else None
        self.parity = ParityGenerator(self.models) if self.method == "parity" else None
        if self.parity is not None and self.settings.parity_thresholds is None:
            raise InputError("fdi method parity: the config has no fdi.parity_thresholds (fit them with hydro-ros fdi-fit --write)")
        table = UKF_TABLE if self.method == "ukf" else self.settings.parity_signatures
        n = len(self.actuators)
        self._residual_mean = MovingAverage(self.window, 2 * n)
        self._pressure_mean = MovingAverage(self.window, 2 * n)
        self._command_mean = MovingAverage(self.window, n)
        self._opening_mean = MovingAverage(self.window, n)
        self.isolators = [Isolator(a, table=table, settle_s=self.settings.settle_s) for a in self.actuators]
        self.samples_seen = 0
        self._last_key = [None] * n
        self._last_valid = np.zeros((n, 5))
        self.last_mean_residual = np.zeros((n, 2))
        self.last_threshold = np.zeros((n, 2))
        self.last_mean_pressure = np.zeros((n, 2))
        self.invalid_samples = 0
        geometry = np.stack([m.base[[MOUNT_L1, MOUNT_L2, MOUNT_L3, THETA_OFFSET]] for m in self.models])
        self._l1, self._l2, self._l3, self._offset = geometry.T

    def reset(self) -> None:
        """Restart filters and averages (the ``~/reset`` service); also clears the latches."""
        if self.bank is not None:
            self.bank.reset()
        if self.parity is not None:
            self.parity.reset()
        self._opening_mean.reset()
        self._residual_mean.reset()
        self._pressure_mean.reset()
        self._command_mean.reset()
        for isolator in self.isolators:
            isolator.acknowledge()
        self.samples_seen = 0
        self._last_key = [None] * len(self.actuators)

    def acknowledge(self) -> None:
        """Clear the latched alarms; a fault still present is detected again at once."""
        for i, isolator in enumerate(self.isolators):
            isolator.acknowledge()
            self._last_key[i] = None

    def piston_motion(self, joint_position: np.ndarray, joint_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (3)-(4): measured joint angle and rate -> piston position and velocity."""
        theta = joint_position + self._offset
        x = piston_position(theta, self._l1, self._l2, self._l3)
        return x, torque_arm(theta, self._l1, self._l2) * joint_velocity

    def process(self, block: Samples) -> BlockResult:
        n = len(block)
        n_act = len(self.actuators)
        supply = np.broadcast_to(np.asarray(block.supply_pressure, dtype=float).reshape(n, -1), (n, n_act))
        raw = np.stack([block.joint_position, block.joint_velocity, block.valve_command, supply,
                        block.pressure_a, block.pressure_b], axis=2).reshape(n, n_act, 6)
        mobile = None
        operating_point = None
        if self.parity is not None:
            if not block.mobile:
                raise InputError("fdi method parity: no pilot/compensator pressures in the samples")
            mobile = np.stack([np.broadcast_to(np.asarray(getattr(block, name), dtype=float).reshape(n, -1), (n, n_act))
                               for name in ("pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")], axis=2)
        valid = np.all(np.isfinite(raw), axis=2) & (np.all(np.isfinite(mobile), axis=2) if mobile is not None else True)
        self.invalid_samples += int(np.count_nonzero(~valid))
        x, v = self.piston_motion(raw[:, :, 0], raw[:, :, 1])
        measured = raw[:, :, 4:6]
        mask = ~valid | (measured[:, :, 1] < self.settings.mask_pressure_b) | (x < self.settings.mask_retracted)
        # means of the measured pressures and the command hold their last valid value across gaps
        held = self._hold_last(np.concatenate([measured, raw[:, :, 2:3]], axis=2), valid)
        mean_pressure = self._pressure_mean(held[:, :, :2].reshape(n, -1) / PRESSURE_UNIT).reshape(n, n_act, 2)
        mean_command = self._command_mean(held[:, :, 2])
        s = self.settings
        if self.bank is not None:
            inputs = np.stack([x, v, raw[:, :, 2], raw[:, :, 3]], axis=2)
            prior, posterior = self.bank.run(inputs, measured, valid)
            estimate = posterior if s.residual == "posterior" else prior
            residual = (measured - estimate) / PRESSURE_UNIT
            residual[mask] = 0.0
            mean_residual = self._residual_mean(residual.reshape(n, -1)).reshape(n, n_act, 2)
            threshold = s.threshold_constant + s.threshold_quadratic * mean_pressure**2
        else:
            residual, opening = self.parity.run(x, v, measured[:, :, 0], measured[:, :, 1], mobile[:, :, 0], mobile[:, :, 1],
                                                mobile[:, :, 2], valid)
            residual[mask] = 0.0
            mean_residual = self._residual_mean(residual.reshape(n, -1)).reshape(n, n_act, 2)
            operating_point = self._opening_mean(opening)
            threshold = s.parity_thresholds(operating_point)
        code = (
            A_UP * (mean_residual[:, :, 0] > threshold[:, :, 0])
            + A_DOWN * (mean_residual[:, :, 0] < -threshold[:, :, 0])
            + B_UP * (mean_residual[:, :, 1] > threshold[:, :, 1])
            + B_DOWN * (mean_residual[:, :, 1] < -threshold[:, :, 1])
        ).astype(np.int8)
        armed = (self.samples_seen + np.arange(1, n + 1)) >= self.window
        code[~armed] = 0
        pa_gt_pb = mean_pressure[:, :, 0] > mean_pressure[:, :, 1]
        large = np.all(np.abs(mean_residual) > s.large_residual, axis=2) if self.bank is not None else np.zeros_like(pa_gt_pb)
        direction = np.where(np.abs(mean_command) < s.command_deadband, 0, np.sign(mean_command)).astype(np.int8)
        alarms = self._isolate(block.times, code, pa_gt_pb, large, direction)
        self.samples_seen += n
        self.last_mean_residual = mean_residual[-1]
        self.last_threshold = threshold[-1]
        self.last_mean_pressure = mean_pressure[-1]
        return BlockResult(block.times, residual, mean_residual, threshold, code, valid, alarms, mean_command, operating_point)

    def _hold_last(self, values: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """Forward-fill invalid samples per actuator with the last valid one (kept across blocks)."""
        out = values.copy()
        for a in range(values.shape[1]):
            good = valid[:, a]
            if good.all():
                continue
            index = np.where(good, np.arange(len(good)), -1)
            np.maximum.accumulate(index, out=index)
            carry = self._last_valid[a, : values.shape[2]]
            out[:, a] = np.where((index >= 0)[:, None], values[np.maximum(index, 0), a], carry)
        last_good = [np.flatnonzero(valid[:, a]) for a in range(values.shape[1])]
        for a, where in enumerate(last_good):
            if len(where):
                self._last_valid[a, : values.shape[2]] = values[where[-1], a]
        return out

    def _isolate(self, times: np.ndarray, code: np.ndarray, pa_gt_pb: np.ndarray, large: np.ndarray, direction: np.ndarray) -> list[Alarm]:
        alarms: list[Alarm] = []
        key = code.astype(np.int32) * 32 + pa_gt_pb * 16 + large * 8 + (direction + 1).astype(np.int32)
        for a, isolator in enumerate(self.isolators):
            column = key[:, a]
            changes = np.flatnonzero(np.diff(column)) + 1
            if self._last_key[a] != column[0]:
                changes = np.concatenate(([0], changes))
            for k in changes:
                alarms += isolator.observe(float(times[k]), int(code[k, a]), bool(pa_gt_pb[k, a]), bool(large[k, a]), int(direction[k, a]))
            alarms += isolator.advance(float(times[-1]))
            self._last_key[a] = column[-1]
        return alarms

    def status(self, index: int) -> ActuatorStatus:
        isolator = self.isolators[index]
        fault = isolator.fault
        if fault is None:
            return ActuatorStatus(OK, "ok", None, None, "0000")
        level = ERROR if fault in self.settings.severe_faults else WARN
        return ActuatorStatus(level, fault.value, fault, isolator.detected_at, code_string(isolator.latched_code))

    @property
    def halt(self) -> bool:
        return any(self.status(i).level == ERROR for i in range(len(self.actuators)))
