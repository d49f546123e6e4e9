"""Sensor models of the SAM: pressure transmitters, joint encoder, supply transducer.

Pressures: additive Gaussian noise (P-II: R = 1e10 Pa^2), fault biases, saturation to the
transmitter range. Joint motion from `sensors.motion_sensor`:
* `encoder` (P-II): incremental encoder quantised to its resolution; velocity = backward
  difference of the quantised angle through a first-order low-pass (filter INFERRED);
* `mems` (P-III): accelerometer inclination (noise, quantised to 0.032 deg) and gyro rate (noise,
  constant bias, quantised to 0.02 deg/s) fused by the complementary filter of P-III.
The sample rate is the config's.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.names import Injection
from hydro_ros.contract.samples import Samples
from hydro_ros.models.complementary import ComplementaryFilter
from hydro_ros.models.sam import Param, SamModel, compensator_pressures, injection_levels


class SensorModel:
    """Stateful (velocity filter, encoder history) so blocks can be measured one after another."""

    def __init__(self, model: SamModel, rng: np.random.Generator, injections: Sequence[Injection] = ()) -> None:
        sensors = model.machine.sensors
        self.model = model
        self.rng = rng
        self.injections = list(injections)
        self.noise_std = sensors.pressure_noise_std
        self.pilot_noise_std = sensors.pilot_pressure_noise_std
        self.range = sensors.pressure_range
        self.resolution = sensors.encoder_resolution
        cutoff = sensors.velocity_filter_hz
        dt = 1.0 / model.sample_rate
        self._alpha = dt / (dt + 1.0 / (2.0 * math.pi * cutoff))
        self._previous_angle: float | None = None
        self._velocity = 0.0
        self.motion_sensor = sensors.motion_sensor
        self.mems = sensors.mems
        if self.mems is not None:
            self.complementary = ComplementaryFilter(self.mems.k_p, self.mems.k_i, model.sample_rate)

    def _bias(self, name: str, times: np.ndarray) -> np.ndarray | float:
        total: np.ndarray | float = self.model.effects.get(name, 0.0)
        for injection in self.injections:
            if injection.name == name:
                total = total + injection_levels(injection, times)
        return total

    def _pressure(self, true: np.ndarray, bias: np.ndarray | float, noise_std: float | None = None) -> np.ndarray:
        std = self.noise_std if noise_std is None else noise_std
        noisy = true + bias + self.rng.normal(0.0, std, size=true.shape)
        return np.clip(noisy, *self.range)

    def _mems(self, angle: np.ndarray, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        m = self.mems
        rate = states[:, 5] / np.array([self.model.torque_arm_at(x) for x in states[:, 4]])  # eq. (4) inverted
        inclination = angle + self.rng.normal(0.0, m.inclination_noise_std, size=angle.shape)
        inclination = np.round(inclination / m.inclination_resolution) * m.inclination_resolution
        gyro = rate + m.gyro_bias + self.rng.normal(0.0, m.gyro_noise_std, size=rate.shape)
        gyro = np.round(gyro / m.gyro_resolution) * m.gyro_resolution
        return self.complementary(inclination, gyro)

    def measure(self, times: np.ndarray, states: np.ndarray, commands: np.ndarray) -> Samples:
        angle = self.model.joint_from_piston(states[:, 4])
        if self.motion_sensor == "mems":
            joint, velocity = self._mems(angle, states)
            return self._measurements(times, states, commands, joint, velocity)
        counts = np.round(angle / self.resolution)
        quantised = counts * self.resolution
        previous = quantised[0] if self._previous_angle is None else self._previous_angle
        raw_rate = np.diff(np.concatenate(([previous], quantised))) * self.model.sample_rate
        velocity = np.empty_like(raw_rate)
        filtered = self._velocity
        for k, rate in enumerate(raw_rate):
            filtered += self._alpha * (rate - filtered)
            velocity[k] = filtered
        self._velocity = filtered
        self._previous_angle = float(quantised[-1])
        return self._measurements(times, states, commands, quantised, velocity)

    def _mobile_valve(self, times: np.ndarray, states: np.ndarray, commands: np.ndarray) -> dict[str, np.ndarray]:
        """Pilot pressures (the pilot stage follows the command) and the compensator pressure."""
        params = self.model.parameter_matrix(times, self.injections)
        pilot_max = self.model.base[Param.PILOT_MAX]
        compensator = compensator_pressures(states, params)
        if self.pilot_noise_std is None:
            raise ConfigError(f"config {self.model.machine.source}: missing key sensors.pilot_pressure_noise_std (mobile valves)")
        pilot_noise = self.pilot_noise_std
        return {
            "pilot_pressure_1": self._pressure(pilot_max * np.clip(commands, 0.0, 1.0), self._bias("pilot_pressure_sensor_bias", times), pilot_noise),
            "pilot_pressure_2": self._pressure(pilot_max * np.clip(-commands, 0.0, 1.0), 0.0, pilot_noise),
            "compensator_pressure": self._pressure(compensator, self._bias("compensator_pressure_sensor_bias", times)),
            "ls_pressure": self._pressure(np.maximum(compensator - params[:, Param.COMP_DROP], 0.0), 0.0),
        }

    def _measurements(self, times, states, commands, joint: np.ndarray, velocity: np.ndarray) -> Samples:
        supply = np.full(len(times), self.model.machine.supply_pressure, dtype=float)
        extra = self._mobile_valve(times, states, commands) if self.model.mobile_valve else {}
        return Samples(
            times=times,
            joint_position=joint,
            joint_velocity=velocity + self._bias("velocity_sensor_bias", times),
            pressure_a=self._pressure(states[:, 0], self._bias("pressure_sensor_bias_a", times)),
            pressure_b=self._pressure(states[:, 1], self._bias("pressure_sensor_bias_b", times)),
            supply_pressure=self._pressure(supply, self._bias("supply_pressure_sensor_bias", times)),
            valve_command=commands.copy(),
            **extra,
        )
