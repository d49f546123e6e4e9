"""Closed-loop crane plant: valve-controlled cylinders, pressure compensators and a CP or LS pump.

What the planner leaves out, this has (P-VI Appendix A; P-V Section 6.3):
- valve input dead zone (~53 %), input delay (> 0.15 s) and spool lag (bandwidth < 10 Hz), each
  cylinder's valve a little different from the table its controller inverts (seeded);
- a payload at the tip and Coulomb friction on the base, lift and tilt cylinders;
- an LS pump whose pressure follows the highest load-sensed chamber pressure plus the margin with a
  first-order lag (0.20 s): while it lags, a compensator without enough pressure drop passes less
  flow, which is where LS tracking loses to CP (P-VI Section 6.3, Table 4);
- the CP pump's supply pressure is constant; both pumps are limited to their maximum flow.

Cylinder motion follows the compensated valve flow through a first-order lag (the mechanics'
dominant mode); chamber pressures are the steady-state ones of the P-VI model (eqs. 20-28) for the
forces of the plant's own point masses, so supply pressure and pump flow are those of the
executed motion, not the plan's. All values are PLACEHOLDERS of ``planner.plant`` in the machine config.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import Crane, Motion
from hydro_ros.models.crane_hydraulics import pump_flow

SUPPLIES = ("cp", "ls")
_FRICTION_VELOCITY = 0.005  # m/s: tanh smoothing of the Coulomb friction sign


def valve_velocity(command: np.ndarray, dead_zone: np.ndarray, full_velocity: np.ndarray) -> np.ndarray:
    """Static valve table: cylinder velocity at a (compensated) spool position in [-1, 1]."""
    opening = np.clip((np.abs(command) - dead_zone) / (1.0 - dead_zone), 0.0, None)
    return np.sign(command) * opening * full_velocity


@dataclass
class CraneState:
    stroke: np.ndarray  # cylinder strokes c_i, m
    velocity: np.ndarray  # m/s
    acceleration: np.ndarray  # m/s^2
    spool: np.ndarray  # spool positions in [-1, 1]
    supply_pressure: float  # Pa
    pump_flow: float  # m^3/s
    pressure_a: np.ndarray  # Pa
    pressure_b: np.ndarray
    energy: float  # J, pump output energy so far


class CranePlant:
    """One crane (``Crane`` of its config plus the plant's payload and friction), stepped at ``time_step``."""

    def __init__(self, config: CraneConfig, supply: str, start: np.ndarray, *, seed: int = 0) -> None:
        if supply not in SUPPLIES:
            raise InputError(f"supply {supply!r}: cp or ls")
        self.settings = settings = dict(config.plant)
        self.supply = supply
        self.crane = Crane(config, payload=settings["payload"])
        self.dt = settings["time_step"]
        rng = np.random.default_rng(seed)
        cylinders = self.crane.cylinders
        n = len(cylinders)
        self.nominal_full_velocity = settings["full_command_velocity_factor"] * np.array([c.velocity_max for c in cylinders])
        self.full_velocity = self.nominal_full_velocity * (1.0 + settings["valve_gain_spread"] * rng.uniform(-1, 1, n))
        self.dead_zone = settings["valve_dead_zone"] + settings["valve_dead_zone_spread"] * rng.uniform(-1, 1, n)
        self.stroke_max = np.array([c.stroke_max for c in cylinders])
        self._retract_pumped = np.array([c.pump_area_retract > 0.0 for c in cylinders])
        self._delay = deque([np.zeros(n)] * max(int(round(settings["valve_delay"] / self.dt)), 1))
        h = self.crane.hydraulics
        self.margin = h["ls_margin"]
        self.compensator_drop = h["compensator_drop"]
        self.flow_max = h.get("pump_flow_max", np.inf)
        self.pressure_max = h.get("supply_pressure_max", np.inf)
        strokes = np.array([c.stroke(q) for c, q in zip(cylinders, start)], dtype=float)
        self.state = CraneState(
            stroke=strokes, velocity=np.zeros(n), acceleration=np.zeros(n), spool=np.zeros(n),
            supply_pressure=h["supply_pressure_cp"] if supply == "cp" else self.margin, pump_flow=0.0,
            pressure_a=np.zeros(n), pressure_b=np.zeros(n), energy=0.0,
        )
        self.forces = self._plant_forces(self.joint_motion())
        self._update_pressures()

    # -- kinematics of the plant's state ---------------------------------------------------
    def joint_motion(self) -> Motion:
        s = self.state
        q, qd, qdd = [], [], []
        for cylinder, c, v, a in zip(self.crane.cylinders, s.stroke, s.velocity, s.acceleration):
            qi = float(cylinder.joint(c))
            arm, darm = cylinder.arm(qi)
            qdi = v / arm
            q.append(qi)
            qd.append(qdi)
            qdd.append((a - darm * qdi * qdi) / arm)
        motion = Motion(q, qd, qdd, list(s.stroke), list(s.velocity), list(s.acceleration), None, True)
        motion.force = self.crane.cylinder_forces(motion)
        return motion

    # -- one step ----------------------------------------------------------------------------
    def step(self, command: np.ndarray) -> None:
        s, p = self.state, self.settings
        self._delay.append(np.clip(np.asarray(command, dtype=float), -1.0, 1.0))
        delayed = self._delay.popleft()
        s.spool += self.dt / p["spool_time_constant"] * (delayed - s.spool)
        target = valve_velocity(s.spool, self.dead_zone, self.full_velocity)
        # a compensator needs its pressure drop: with less, the flow falls as the square root
        driven = s.pressure_a * (target > 0) + s.pressure_b * (target < 0)
        headroom = np.clip((s.supply_pressure - driven) / self.compensator_drop, 0.0, 1.0)
        pumped = (target > 0) | self._retract_pumped
        target = np.where(pumped, target * np.sqrt(headroom), target)
        demand = self._pump_flow(target)
        if demand > self.flow_max:
            target = np.where(pumped, target * self.flow_max / demand, target)
        s.acceleration = (target - s.velocity) / p["motion_time_constant"]
        s.velocity = s.velocity + self.dt * s.acceleration
        stroke = s.stroke + self.dt * s.velocity
        at_stop = (stroke <= 0.0) | (stroke >= self.stroke_max)
        s.stroke = np.clip(stroke, 0.0, self.stroke_max)
        s.velocity = np.where(at_stop, 0.0, s.velocity)
        self.forces = self._plant_forces(self.joint_motion())
        self._update_pressures()
        s.pump_flow = self._pump_flow(s.velocity)
        if self.supply == "ls":
            needed = self._load_sensed_pressure() + self.margin
            s.supply_pressure += self.dt / p["ls_time_constant"] * (min(needed, self.pressure_max) - s.supply_pressure)
        s.energy += self.dt * s.supply_pressure * s.pump_flow

    def _pump_flow(self, velocity: np.ndarray) -> float:
        return float(sum(pump_flow(v, c.pump_area_extend, c.pump_area_retract) for c, v in zip(self.crane.cylinders, velocity)))

    def _plant_forces(self, motion: Motion) -> np.ndarray:
        friction = self.settings["coulomb_friction"] * np.tanh(np.asarray(self.state.velocity) / _FRICTION_VELOCITY)
        friction[self.crane.redundant] = 0.0  # the redundant joint's friction is in the crane model already (P-VI eqs. A3-A4)
        return np.asarray(motion.force, dtype=float) + friction

    def _load_sensed_pressure(self) -> float:
        """The LS line: the highest pressure of a chamber an open valve connects to the pump (stalled or not)."""
        s = self.state
        extending = s.spool > self.dead_zone
        retracting = (s.spool < -self.dead_zone) & self._retract_pumped
        sensed = np.concatenate([s.pressure_a[extending], s.pressure_b[retracting]])
        return float(sensed.max()) if sensed.size else 0.0

    def _update_pressures(self) -> None:
        """Both chambers: the driven one from the force, the other at its back-pressure (or holding)."""
        s = self.state
        drop = self.compensator_drop
        for i, (c, force, v) in enumerate(zip(self.crane.cylinders, self.forces, s.velocity)):
            if v > 1e-4:
                s.pressure_b[i] = (c.area_b / c.area_a) ** 2 * drop if c.area_b > 0 else 0.0
                s.pressure_a[i] = max((force + s.pressure_b[i] * c.area_b) / c.area_a, 0.0)
            elif v < -1e-4 and c.area_b > 0:
                s.pressure_a[i] = (c.area_a / c.area_b) ** 2 * drop
                s.pressure_b[i] = max((s.pressure_a[i] * c.area_a - force) / c.area_b, 0.0)
            else:  # load-holding: the loaded chamber carries the force, the other is at tank
                s.pressure_a[i] = max(force, 0.0) / c.area_a
                s.pressure_b[i] = max(-force, 0.0) / c.area_b if c.area_b > 0 else 0.0
