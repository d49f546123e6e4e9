"""The cylinders of a serial arm with their valves and chambers, moving its links together: the plant the per-cylinder
monitor is tested on, for the K70M crane and for a machine with an ``arm:`` (the boom and arm of ``config/boom_arm.yaml``).

Each cylinder has the SAM model's valve and chambers (``models.sam.hydraulic_rates``: the pressure-compensated
mobile valve, leaks, effective bulk modulus), and the pistons move the joints through the arm's rigid-body
dynamics (``models.serial_arm``),

    M(q) q'' = R(q) (F_hydraulic - F_friction + F_stop) - G(q) - tau_joint_friction,

with R the mounts' torque arms. M and G are evaluated once per sensor sample and held over its RK4 substeps
(they change little in 1 ms). A cylinder's friction is viscous plus a smoothed Coulomb force; the crane's
extension adds its own (P-VI eqs. A3-A4).

A crane's base rotation is held still and not monitored: its rack-and-pinion plungers are non-differential,
and P-VI replaced their force by an identified constant, so the thesis gives no load or valve model for it.

The operator moves each joint to random targets in closed loop (``OperatorReference`` per joint, within 80 % of
its range); the moves overlap, so one joint moves fast while another holds. Or the arm works a stored joint
trajectory (``ArmRun.trajectory``, e.g. a P-VI path from the trajectory database) as a work cycle, forwards and
back with holds between (``WorkCycleReference``), the same proportional loop following it; the base column is
not followed (see above), so a path that turns the base is worked in the plane of its start. The sensors are the
SAM's (``SensorModel`` per cylinder). Measurements and states come in the machine config's actuator order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field, fields, replace
from typing import Protocol

import numpy as np
from numba import njit

from hydro_ros.contract.crane import parse_planning
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.contract.samples import PER_ACTUATOR, Samples
from hydro_ros.models.crane import Crane
from hydro_ros.models.kinematics import mount_arm, mount_piston
from hydro_ros.models.sam import N_STATES, Param, SamModel, end_stop_force, hydraulic_rates, injection_levels
from hydro_ros.models.serial_arm import SerialArm, arm_problems
from hydro_ros.sim.blocks import in_blocks, replace_injection
from hydro_ros.sim.excitation import OperatorReference, WorkCycleReference
from hydro_ros.sim.sensors import SensorModel

FRICTION_VELOCITY = 0.005  # [m/s] tanh smoothing of the Coulomb force's sign (as the closed-loop crane plant)
OPERATOR_SHARE = 0.8  # the operator's targets lie within this share of each joint's range, about its middle
NOT_PER_CYLINDER = {  # injections the SAM's model takes that this plant does not, refused rather than ignored
    "payload_mass": "an arm's payload hangs at its tip, not on one cylinder (ArmRun.payload)",
    "valve_delay": "not simulated on an arm's coupled cylinders",
}
JointFriction = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (q, q') -> joint torques [N m] or forces [N]


@njit(cache=True)
def _mount(p: np.ndarray) -> tuple:
    return int(p[Param.MOUNT_KIND]), p[Param.MOUNT_L1], p[Param.MOUNT_L2], p[Param.MOUNT_L3], p[Param.THETA_OFFSET], p[Param.MOUNT_SIGN], p[Param.MOUNT_RATIO]


@njit(cache=True)
def _rates(state, commands, params, poly, centre, inverse_mass, bias, rates, y, dy):
    """state = [4 hydraulic states per cylinder..., q..., q'...]; rates the same layout."""
    n = commands.shape[0]
    torque = np.empty(n)
    for i in range(n):
        p = params[i]
        q, qd = state[4 * n + i], state[5 * n + i]
        kind, l1, l2, l3, offset, sign, ratio = _mount(p)
        x = mount_piston(q, kind, l1, l2, l3, offset, sign, ratio)
        arm = mount_arm(q, kind, l1, l2, l3, offset, sign, ratio)
        v = arm * qd
        for j in range(4):
            y[j] = state[4 * i + j]
        y[4], y[5], y[6] = x, v, 0.0
        hydraulic_rates(y, commands[i], p, poly[i], centre[i], dy)
        for j in range(4):
            rates[4 * i + j] = dy[j]
        force = (y[0] * p[Param.AREA_A] - y[1] * p[Param.AREA_B] - p[Param.VISCOUS] * v - p[Param.COULOMB] * math.tanh(v / FRICTION_VELOCITY)
                 + end_stop_force(x, v, p))
        torque[i] = arm * force
    for i in range(n):
        rates[4 * n + i] = state[5 * n + i]
        acceleration = 0.0
        for j in range(n):
            acceleration += inverse_mass[i, j] * (torque[j] - bias[j])
        rates[5 * n + i] = acceleration


@njit(cache=True)
def _sample(state, commands, params, poly, centre, inverse_mass, bias, h, substeps):
    """RK4 over one sensor sample with M and G held."""
    size = state.shape[0]
    n = commands.shape[0]
    k = np.empty((4, size))
    trial = np.empty(size)
    y = np.empty(N_STATES)
    dy = np.empty(N_STATES)
    for _ in range(substeps):
        _rates(state, commands, params, poly, centre, inverse_mass, bias, k[0], y, dy)
        for stage, weight in ((1, 0.5), (2, 0.5), (3, 1.0)):
            for j in range(size):
                trial[j] = state[j] + weight * h * k[stage - 1, j]
            _rates(trial, commands, params, poly, centre, inverse_mass, bias, k[stage], y, dy)
        for j in range(size):
            state[j] += h / 6.0 * (k[0, j] + 2.0 * k[1, j] + 2.0 * k[2, j] + k[3, j])
        for i in range(n):
            floor = params[i, Param.CAVITATION]
            for j in (4 * i, 4 * i + 1):
                if state[j] < floor:
                    state[j] = floor


class JointPath(Protocol):
    """What the plant takes of a stored trajectory (``planning.trajectory.JointTrajectoryData`` is one)."""

    joint_names: list[str]
    time: np.ndarray  # (k,) [s]
    positions: np.ndarray  # (k, joints)


@dataclass
class ArmRun:
    """What one run asks of the plant: its length, the operator's seed, faults per cylinder, payload steps."""

    duration_s: float
    seed: int = 0
    faults: dict[str, list[Injection]] = field(default_factory=dict)  # actuator -> its injections
    payload: list[Injection] = field(default_factory=list)  # payload_mass steps at the tip [kg]
    trajectory: JointPath | None = None  # worked as a cycle in place of the random operator
    hold_s: float = 4.0  # [s] the work cycle's holds at either end of the trajectory


def redundant_friction(machine: Machine) -> JointFriction | None:
    """The friction a planned machine's ``planner.friction`` puts on its redundant joint (the K70M telescope's pads, P-VI
    eqs. A3-A4), in the same chain dynamics the planner uses; None for a machine without a planner: section."""
    if not machine.planned:
        return None
    crane = Crane(parse_planning(machine.mapping, machine.source))
    redundant = crane.redundant - (1 if crane.base_rotation else 0)

    def friction(q: np.ndarray, qd: np.ndarray) -> np.ndarray:
        out = np.zeros(len(q))
        out[redundant] = float(crane.extension_friction(q[redundant], qd[redundant]))
        return out

    return friction


class ArmCylinders:
    """The cylinders of ``machine`` moving the links of ``arm``, one actuator per link (by its joint)."""

    def __init__(self, machine: Machine, arm: SerialArm, run: ArmRun, start: Sequence[float] | None = None,
                 joint_friction: JointFriction | None = None) -> None:
        self.machine = machine
        self.arm = arm
        by_joint = {a.joint: a for a in machine.actuators}
        missing = [name for name in arm.joint_names if name not in by_joint]
        if missing or len(machine.actuators) != len(arm.joint_names):
            raise InputError(f"config {machine.source}: the arm's joints {', '.join(arm.joint_names)} need one actuator "
                             f"each (missing: {', '.join(missing) or 'none'}; actuators: {', '.join(machine.actuator_names)})")
        unknown = [name for name in run.faults if name not in machine.actuator_names]
        if unknown:
            raise InputError(f"fault on {', '.join(unknown)}: no such actuator (actuators: {', '.join(machine.actuator_names)})")
        for actuator, injections in run.faults.items():
            for injection in injections:
                if injection.name in NOT_PER_CYLINDER:
                    raise InputError(f"fault {actuator}:{injection.name}: {NOT_PER_CYLINDER[injection.name]}")
        steps = sorted(run.payload, key=lambda step: step.onset_s)
        tip = arm.payload + np.cumsum([0.0] + [step.value for step in steps])
        for payload in sorted({float(tip.min()), float(tip.max())}):  # the lightest may leave a joint no inertia, the heaviest unheld
            problem = self.tip_problem(payload)
            if problem:
                given = f"config {machine.source}" if payload == arm.payload else f"payload_mass steps to {payload:g} kg at the tip"
                raise InputError(f"{given}: {problem}")
        self.models = [SamModel(machine, by_joint[name].name) for name in arm.joint_names]  # link order, as the state
        # the machine config's actuator i is link order[i]
        self.order = [arm.joint_names.index(a.joint) for a in machine.actuators]
        self.joint_friction = joint_friction if joint_friction is not None else redundant_friction(machine)
        self.run = run
        self.dt = 1.0 / machine.sample_rate_hz
        self.substeps = self.models[0].substeps
        rng = np.random.default_rng(run.seed)
        ranges = [link.joint_range for link in arm.links]
        middle = [0.5 * (low + high) for low, high in ranges]
        self.work_cycle = None
        if run.trajectory is not None:
            self.work_cycle = self._work_cycle(run.trajectory)
            start = self.work_cycle.start
        start = middle if start is None else list(start)
        excitation = machine.excitation
        self.operators = [
            OperatorReference(replace(excitation, joint_range=(m - 0.5 * OPERATOR_SHARE * (high - low), m + 0.5 * OPERATOR_SHARE * (high - low))),
                              rng, q0, machine.sample_rate_hz)
            for (low, high), m, q0 in zip(ranges, middle, start)]
        self.sensors = [SensorModel(self.models[i], rng, run.faults.get(self.models[i].actuator, ())) for i in self.order]
        # extending the cylinder closes the tilt joint: the operator's lever follows the joint, not the cylinder
        self.direction = np.sign([float(m.piston_velocity(q0, 1.0)) for m, q0 in zip(self.models, start)])
        self.sample_index = 0
        n = len(self.models)
        self.state = np.zeros(6 * n)
        self.state[4 * n:5 * n] = start
        self.state[:4 * n].reshape(n, 4)[:, :2] = self._holding_pressures()
        self.poly = np.stack([m.poly for m in self.models])
        self.centre = np.stack([m.centre_leakage for m in self.models])

    def _holding_pressures(self) -> np.ndarray:
        """Chamber pressures that hold the arm at rest in its start pose (the loaded side carries the load)."""
        n = len(self.models)
        q = self.state[4 * n:5 * n]
        _, gravity = self.arm.inertia_gravity(list(q))
        out = np.zeros((n, 2))
        for i, (model, qi, tau) in enumerate(zip(self.models, q, gravity)):
            force = tau / float(model.piston_velocity(qi, 1.0))
            p = model.base
            out[i] = (max(force, 0.0) / p[Param.AREA_A] + 1e5, max(-force, 0.0) / p[Param.AREA_B] + 1e5)
        return out

    def _dynamics(self, q: np.ndarray, qd: np.ndarray, payload: float) -> tuple[np.ndarray, np.ndarray]:
        inertia, gravity = self.arm.inertia_gravity(list(q), payload)
        bias = np.asarray(gravity, dtype=float)
        if self.joint_friction is not None:
            bias = bias + self.joint_friction(q, qd)
        return np.linalg.inv(np.asarray(inertia, dtype=float)), bias

    def set_fault(self, actuator: str, name: str, value: float, now_s: float) -> None:
        """``name`` of size ``value`` (0: none) in ``actuator``'s cylinder from ``now_s`` on, replacing its previous size; a
        ``payload_mass`` hangs at the tip whichever actuator names it. InputError for a fault this plant does not simulate."""
        if name == "payload_mass":
            problem = self.payload_problem(value)
            if problem:
                raise InputError(f"fault payload_mass={value:g}: {problem}")
            replace_injection(self.run.payload, name, value, now_s)
            return
        if name in NOT_PER_CYLINDER:
            raise InputError(f"fault {actuator}:{name}: {NOT_PER_CYLINDER[name]}")
        index = self.machine.actuator_names.index(actuator)
        replace_injection(self.run.faults.setdefault(actuator, []), name, value, now_s)
        replace_injection(self.sensors[index].injections, name, value, now_s)

    def payload_problem(self, value: float) -> str:
        """Why a ``payload_mass`` of ``value`` [kg], added to the arm's payload, cannot be set ("" if it can)."""
        return self.tip_problem(self.arm.payload + value)

    def tip_problem(self, tip_mass: float) -> str:
        """Why the arm cannot carry ``tip_mass`` [kg] at its tip ("" if it can): a negative mass, or ``arm_problems``."""
        if tip_mass < 0.0:
            return (f"the tip would carry {tip_mass:g} kg (the arm's payload {self.arm.payload:g} kg plus the steps; a payload change "
                    "is added to it)")
        problems = arm_problems(self.machine, tip_mass) if self.machine.arm is not None else []
        return problems[0] if problems else ""

    def active_faults(self) -> list[str]:
        """``actuator:name=value`` of every fault set, and ``payload_mass=value`` at the tip."""
        return sorted({f"{actuator}:{i.name}={i.value:g}" for actuator, injections in self.run.faults.items() for i in injections}
                      | {f"{i.name}={i.value:g}" for i in self.run.payload})

    def blocks(self) -> Iterator[tuple[np.ndarray, Samples]]:
        """(true states (n, A, 7), measured samples (n, A)) block by block over the run's duration."""
        yield from in_blocks(int(round(self.run.duration_s * self.machine.sample_rate_hz)) - self.sample_index, self.step)

    def follow(self, trajectory: JointPath) -> None:
        """Work ``trajectory`` as a cycle from its first point on; the caller checks that it starts where the joints are."""
        self.work_cycle = self._work_cycle(trajectory)

    def hold(self) -> None:
        """Hold the joints where they are (the operator's loop on a constant reference)."""
        here = self.joints()
        self.work_cycle = WorkCycleReference(np.array([0.0, 1.0]), np.stack([here, here]), 0.0, self.machine.sample_rate_hz)

    def joints(self) -> np.ndarray:
        """The arm's true joint positions now, base to tip."""
        n = len(self.models)
        return self.state[4 * n:5 * n].copy()

    def _work_cycle(self, trajectory: JointPath) -> WorkCycleReference:
        names = self.arm.joint_names
        columns = [trajectory.joint_names.index(name) if name in trajectory.joint_names else -1 for name in names]
        if min(columns) < 0:
            raise InputError(f"trajectory: joints {', '.join(trajectory.joint_names)} lack "
                             f"{', '.join(name for name, i in zip(names, columns) if i < 0)}")
        return WorkCycleReference(trajectory.time, np.asarray(trajectory.positions)[:, columns], self.run.hold_s,
                                  self.machine.sample_rate_hz)

    def step(self, n: int, commands: np.ndarray | None = None) -> tuple[np.ndarray, Samples]:
        """The next n samples: (true states (n, A, 7), measured samples (n, A)), in the machine config's actuator order.
        ``commands`` (n, A) are valve commands from outside (a controller), in that order; without them the operator or
        the work cycle closes the loop."""
        n_act = len(self.models)
        if commands is not None:
            commands = np.asarray(commands, dtype=float)[:, np.argsort(self.order)]
        times = (self.sample_index + np.arange(n)) * self.dt
        references = None
        if commands is None:
            references = (self.work_cycle.next(n) if self.work_cycle is not None
                          else np.stack([op.next(n) for op in self.operators], axis=1))
        params = np.stack([m.parameter_matrix(times, self.run.faults.get(m.actuator, ())) for m in self.models], axis=1)
        payload = self.arm.payload + sum((injection_levels(step, times) for step in self.run.payload), np.zeros(n))
        trajectory = np.empty((n, self.state.size))  # the plant's state after each sample
        applied = np.empty((n, n_act))
        gain, ceiling = self.machine.excitation.gain, self.machine.excitation.max_command
        h = self.dt / self.substeps
        for k in range(n):
            q, qd = self.state[4 * n_act:5 * n_act], self.state[5 * n_act:]
            applied[k] = (np.clip(commands[k], -1.0, 1.0) if references is None
                          else np.clip(gain * self.direction * (references[k] - q), -ceiling, ceiling))
            inverse_mass, bias = self._dynamics(q, qd, float(payload[k]))
            _sample(self.state, applied[k], np.ascontiguousarray(params[k]), self.poly, self.centre, inverse_mass, bias, h,
                    self.substeps)
            trajectory[k] = self.state
        states = self._cylinder_states(trajectory)[:, self.order]
        if not np.all(np.isfinite(states)):
            raise InputError(f"arm simulation diverged at t = {times[0]:.2f} s (check the valve sizes and end stops of {self.machine.source})")
        self.sample_index += n
        applied = applied[:, self.order]
        measured = [sensor.measure(times, states[:, i], applied[:, i]) for i, sensor in enumerate(self.sensors)]
        return states, combine(measured)

    def _cylinder_states(self, trajectory: np.ndarray) -> np.ndarray:
        """The SAM model's state layout (n, A, 7) of each cylinder in link order, its piston from its joint (bristle state 0)."""
        n = len(self.models)
        out = np.zeros((len(trajectory), n, N_STATES))
        for i, model in enumerate(self.models):
            q, qd = trajectory[:, 4 * n + i], trajectory[:, 5 * n + i]
            out[:, i, :4] = trajectory[:, 4 * i:4 * i + 4]
            out[:, i, 4] = model.piston_from_joint(q)
            out[:, i, 5] = model.piston_velocity(q, qd)
        return out


def combine(per_actuator: Sequence[Samples]) -> Samples:
    """One actuator's samples each -> (n, A) columns; the supply from the first, the load-sensing line the highest."""
    first = per_actuator[0]
    out = {}
    for f in fields(Samples):
        values = getattr(first, f.name)
        if f.name == "ls_pressure" and values is not None:
            out[f.name] = np.max([s.ls_pressure for s in per_actuator], axis=0)
        elif values is None or f.name not in PER_ACTUATOR:
            out[f.name] = values
        else:
            out[f.name] = np.stack([np.asarray(getattr(s, f.name)).reshape(len(first)) for s in per_actuator], axis=1)
    return Samples(**out)


def simulate_arm(machine: Machine, run: ArmRun) -> Samples:
    """The whole run's measurements, (n, A)."""
    parts = [measured for _, measured in ArmCylinders(machine, SerialArm.of(machine), run).blocks()]
    return Samples(**{f.name: None if getattr(parts[0], f.name) is None else np.concatenate([getattr(p, f.name) for p in parts])
                      for f in fields(Samples)})
