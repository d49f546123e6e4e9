"""Condition monitor of a machine: residual generation, evaluation and isolation per actuator.

Per sample block: the residual generator of the configured method (:mod:`hydro_ros.fdi.residuals`;
P-II's UKF: r = p - p_hat) gives two residuals per actuator; they are masked, averaged over a 5 s
window (eq. 24), compared with the generator's thresholds (UKF: +-(c0 + c2 mu_p^2), eq. 25, per
chamber, mu_p the 5 s mean measured pressure) and the crossing pattern is fed to the isolator
with the generator's signature table (UKF: P-II Table 3). Everything is vectorised over the block;
only changes of the evidence reach the (Python) isolation logic.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Fault
from hydro_ros.contract.samples import Samples
from hydro_ros.fdi.health import CHANNELS, SensorHealth
from hydro_ros.fdi.isolation import NO_CLOSED_CODE, Alarm, Isolator, code_string, crossing_code
from hydro_ros.fdi.residuals import BlockInput, MovingAverage, generator_for
from hydro_ros.fdi.settings import FdiSettings
from hydro_ros.fdi.ukf import PRESSURE_UNIT
from hydro_ros.models.sam import SamModel
from hydro_ros.safety.supervisor import ERROR, OK, STALE, WARN  # noqa: F401 - the levels, named once

SUPPLY = CHANNELS.index("supply_pressure")


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
    operating_point: np.ndarray | None = None  # (n, A, 5) parity: 5 s means of the opening, |Q_A|, |Q_B| and the roots' noise bias in A, B [L/min]
    closed_mean: np.ndarray | None = None  # (n, A, 2) mean residual over the last closed-valve samples (NaN: not judged)
    closed_code: np.ndarray | None = None  # (n, A) its crossing code, NO_CLOSED_CODE: not known
    held_outside: np.ndarray | None = None  # (n, A) detection held: the window left the commissioned region (fdi.coverage)


@dataclass
class ActuatorStatus:
    level: int
    message: str
    fault: Fault | None
    detected_at: float | None
    code: str


class FdiMonitor:
    """Runs the configured residual generator on every actuator of a machine, then evaluates and isolates."""

    def __init__(self, machine: Machine, method: str | None = None) -> None:
        self.machine = machine
        self.settings = FdiSettings.from_machine(machine)
        self.actuators = machine.actuator_names
        self.joints = [actuator.joint for actuator in machine.actuators]
        self.models = [SamModel(machine, a) for a in self.actuators]
        self.sample_rate = self.models[0].sample_rate
        self.window = int(round(self.settings.window_s * self.sample_rate))
        self.generator = generator_for(method or self.settings.method, self.models, self.settings, self.window)
        n = len(self.actuators)
        self._residual_mean = MovingAverage(self.window, 2 * n)
        self._pressure_mean = MovingAverage(self.window, 2 * n)
        self._command_mean = MovingAverage(self.window, n)
        self._mask_pressure_mean = MovingAverage(max(int(round(self.settings.mask_average_s * self.sample_rate)), 1), 2 * n)
        self.startup = int(round(self.settings.startup_s * self.sample_rate))
        self.isolators = [Isolator(a, table=self.generator.table, settle_s=self.settings.settle_s) for a in self.actuators]
        self.samples_seen = 0
        self._last_key = [None] * n
        self._last_valid = np.zeros((n, 5))
        self.last_mean_residual = np.zeros((n, 2))
        self.last_threshold = np.zeros((n, 2))
        self.last_mean_pressure = np.zeros((n, 2))
        self.last_closed_mean = np.full((n, 2), np.nan)
        self.invalid_samples = 0
        self.supply_substituted = 0
        self.nominal_supply = machine.supply_pressure
        self.health = SensorHealth(machine, 9 if self.generator.needs_mobile_pressures else 6, self.sample_rate)
        # outside what commissioning saw (fdi.coverage): samples since the last such sample, and why it was outside
        self._since_outside = np.full(n, np.iinfo(np.int64).max // 2, dtype=np.int64)
        self._outside_reason = [""] * n
        self.outside_held_samples = np.zeros(n, dtype=np.int64)  # evaluated samples held for it, per actuator
        self.evaluated_samples = 0

    @property
    def method(self) -> str:
        return self.generator.method

    @property
    def armed(self) -> bool:
        """Whether a full window of data has been evaluated after the start-up since the start, a reset or a time jump."""
        return self.samples_seen >= self.startup + self.window

    @property
    def confirmed(self) -> bool:
        """Armed, and every actuator's evidence explained: an alarm latched, or no threshold crossing at the last sample.

        Until then "no severe fault" is assumed, not known (a restarted monitor before it re-isolates a fault).
        """
        return all(self.explained(i) for i in range(len(self.actuators)))

    def explained(self, index: int) -> bool:
        """Armed, and this actuator's evidence explained: an alarm latched, or no threshold crossing at the last sample."""
        key = self._last_key[index]
        return self.armed and (self.isolators[index].fault is not None or (key is not None and key // 32 % 16 == 0))

    def sensor_problems(self, index: int) -> dict[str, str]:
        """The actuator's readings that were invalid within the last second: sensor -> nonfinite / out_of_range / frozen."""
        return self.health.problems(index)

    def restart(self) -> None:
        """Restart filters and averages, keeping the latched alarms: detection re-arms after a window of data."""
        self.generator.reset()
        self._residual_mean.reset()
        self._pressure_mean.reset()
        self._command_mean.reset()
        self._mask_pressure_mean.reset()
        self.samples_seen = 0

    def reset(self) -> None:
        """Restart filters and averages (the ``~/reset`` service); also clears the latches."""
        self.restart()
        for isolator in self.isolators:
            isolator.acknowledge()
        self._last_key = [None] * len(self.actuators)

    def piston_motion(self, joint_position: np.ndarray, joint_velocity: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Eqs. (3)-(4): measured joint positions and rates (n, A) -> piston positions and velocities, each by its mount."""
        x = np.empty_like(joint_position)
        v = np.empty_like(joint_position)
        for a, model in enumerate(self.models):
            x[:, a] = model.piston_from_joint(joint_position[:, a])
            v[:, a] = model.piston_velocity(joint_position[:, a], joint_velocity[:, a])
        return x, v

    def process(self, block: Samples, *, hold: bool = False) -> BlockResult:
        """One block of samples. ``hold``: the input is known to be incomplete (overload); the filters and
        means run on, but no crossing is taken as evidence, so no alarm is raised from such data."""
        n = len(block)
        n_act = len(self.actuators)
        supply = np.broadcast_to(np.asarray(block.supply_pressure, dtype=float).reshape(n, -1), (n, n_act))
        raw = np.stack([block.joint_position, block.joint_velocity, block.valve_command, supply,
                        block.pressure_a, block.pressure_b], axis=2).reshape(n, n_act, 6)
        mobile = None
        if self.generator.needs_mobile_pressures and block.mobile:
            mobile = np.stack([np.broadcast_to(np.asarray(getattr(block, name), dtype=float).reshape(n, -1), (n, n_act))
                               for name in ("pilot_pressure_1", "pilot_pressure_2", "compensator_pressure")], axis=2)
        readings = raw[:, :, [0, 1, 4, 5, 2, 3]]  # health.CHANNELS order
        if self.generator.needs_mobile_pressures:
            readings = np.concatenate([readings, mobile if mobile is not None else np.full((n, n_act, 3), np.nan)], axis=2)
        good = self.health.check(readings)
        # a bad supply reading is replaced by the nominal supply pressure (the pump's relief setting), so the
        # cylinders stay monitored; every other bad reading makes the actuator's sample a gap
        supply_bad = ~good[:, :, SUPPLY]
        raw[:, :, 3] = np.where(supply_bad, self.nominal_supply, raw[:, :, 3])
        self.supply_substituted += int(np.count_nonzero(supply_bad))
        good[:, :, SUPPLY] = True
        valid = good.all(axis=2)
        self.invalid_samples += int(np.count_nonzero(~valid))
        x, v = self.piston_motion(raw[:, :, 0], raw[:, :, 1])
        measured = raw[:, :, 4:6]
        # means of the measured pressures and the command hold their last valid value across gaps
        held = self._hold_last(np.concatenate([measured, raw[:, :, 2:3]], axis=2), valid)
        seen = self.samples_seen + np.arange(1, n + 1)
        cavitating = self._mask_pressure_mean(held[:, :, :2].reshape(n, -1)).reshape(n, n_act, 2) < self.settings.mask_pressure
        if not self.generator.chambers_independent:
            cavitating = np.repeat(cavitating.any(axis=2, keepdims=True), 2, axis=2)
        mask = cavitating | (~valid | (x < self.settings.mask_retracted) | (seen <= self.startup)[:, None])[:, :, None]
        mean_pressure = self._pressure_mean(held[:, :, :2].reshape(n, -1) / PRESSURE_UNIT).reshape(n, n_act, 2)
        mean_command = self._command_mean(held[:, :, 2])
        residual, operating_point = self.generator.residuals(
            BlockInput(piston=x, velocity=v, command=raw[:, :, 2], supply=raw[:, :, 3], pressure=measured, valid=valid, mobile=mobile))
        residual[mask] = 0.0
        mean_residual = self._residual_mean(residual.reshape(n, -1)).reshape(n, n_act, 2)
        threshold = self.generator.thresholds(mean_pressure, operating_point)
        code = crossing_code(mean_residual, threshold)
        closed_mean = self.generator.closed_mean(residual, mask)
        closed_code = self.generator.closed_code(closed_mean)
        armed = seen >= self.startup + self.window
        code[~armed] = 0
        if hold:
            code[:] = 0
        outside = None
        if self.settings.coverage is not None:
            outside = self._outside_window(raw, valid)
            code[outside] = 0
            self.outside_held_samples += np.count_nonzero(outside & armed[:, None], axis=0)
        self.evaluated_samples += int(np.count_nonzero(armed))
        pa_gt_pb = mean_pressure[:, :, 0] > mean_pressure[:, :, 1]
        large = self.generator.large(mean_residual, operating_point)
        s = self.settings
        direction = np.where(np.abs(mean_command) < s.command_deadband, 0, np.sign(mean_command)).astype(np.int8)
        alarms = self._isolate(block.times, code, pa_gt_pb, large, direction, closed_code)
        self.samples_seen += n
        self.last_mean_residual = mean_residual[-1]
        self.last_threshold = threshold[-1]
        self.last_mean_pressure = mean_pressure[-1]
        self.last_closed_mean = closed_mean[-1]
        return BlockResult(block.times, residual, mean_residual, threshold, code, valid, alarms, mean_command, operating_point, closed_mean,
                           closed_code, outside)

    def _outside_window(self, raw: np.ndarray, valid: np.ndarray) -> np.ndarray:
        """(n, A): whether the window ending at each sample holds a valid sample outside the commissioned region."""
        n = len(raw)
        held = np.zeros((n, len(self.actuators)), dtype=bool)
        index = np.arange(n)
        for a, actuator in enumerate(self.actuators):
            beyond, reason = self.settings.coverage.outside(actuator, raw[:, a, 2])
            beyond &= valid[:, a]
            if beyond.any():
                self._outside_reason[a] = reason
            last = np.maximum.accumulate(np.where(beyond, index, -1))
            since = np.where(last >= 0, index - last, self._since_outside[a] + index + 1)
            held[:, a] = since < self.window
            self._since_outside[a] = since[-1]
        return held

    def outside(self, index: int) -> str:
        """Why detection holds for the actuator: its window holds a sample outside what commissioning saw ("" if not)."""
        return self._outside_reason[index] if self._since_outside[index] < self.window else ""

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

    def _isolate(self, times: np.ndarray, code: np.ndarray, pa_gt_pb: np.ndarray, large: np.ndarray, direction: np.ndarray,
                 closed_code: np.ndarray) -> list[Alarm]:
        alarms: list[Alarm] = []
        key = ((closed_code.astype(np.int32) + 1) * 16 + code) * 32 + pa_gt_pb * 16 + large * 8 + (direction + 1).astype(np.int32)
        for a, isolator in enumerate(self.isolators):
            column = key[:, a]
            changes = np.flatnonzero(np.diff(column)) + 1
            if self._last_key[a] != column[0]:
                changes = np.concatenate(([0], changes))
            for k in changes:
                closed = int(closed_code[k, a])
                alarms += isolator.observe(float(times[k]), int(code[k, a]), bool(pa_gt_pb[k, a]), bool(large[k, a]), int(direction[k, a]),
                                           None if closed == NO_CLOSED_CODE else closed)
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


def crossing_episodes(code: np.ndarray, *, previous: bool = False) -> tuple[int, bool]:
    """Threshold-crossing episodes (rising edges of code != 0) in a block, counting on from the last block's state."""
    crossing = (np.asarray(code) != 0).astype(np.int8)
    if crossing.size == 0:
        return 0, previous
    rising = np.count_nonzero(np.diff(np.concatenate(([int(previous)], crossing))) == 1)
    return int(rising), bool(crossing[-1])
