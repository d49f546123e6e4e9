"""Kinematics and rigid-body dynamics of a planar serial arm (:class:`hydro_ros.contract.machine.Arm`).

One model for every machine the config schema describes: the SAM's boom (one revolute link), a
boom and arm (two), the K70M's lift, tilt and telescope (two revolute links and a prismatic one,
P-V eqs. 1-8, P-VI eqs. 2-7 and 16). Link i turns by its revolute joint's angle relative to the
link before it, or slides along that link's direction by its prismatic joint's extension, and
carries point masses (with their inertia about their own centre of gravity) fixed in its frame;
the payload hangs at the tip.

    M(q) = sum_k m_k J_k^T J_k + I_k w_k^T w_k,      G(q) = g sum_k m_k dy_k/dq

with J_k the Jacobian of mass k's position and w_k which revolute joints turn it. The
velocity-product (Coriolis and centripetal) terms are omitted, as in P-VI eq. (16): a hydraulic
boom turning at 0.3 rad/s feels m L w^2 = 0.09 m L against g m L of gravity, under 1 %.

Every function works elementwise over joint positions given as a list (one entry per joint), so
one state, a NumPy grid of states or CasADi symbols go through the same code; the math comes
from a namespace with ``cos`` and ``sin`` (NumPy's by default).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from types import SimpleNamespace
from typing import Any

import numpy as np

from hydro_ros.contract.machine import Machine
from hydro_ros.contract.schema import Arm, ArmLink, Load
from hydro_ros.models.kinematics import MOUNT_KINDS, mount_arm

NUMPY = SimpleNamespace(cos=np.cos, sin=np.sin)
MIN_COS = 0.1  # below this cos(q) of a middle pose, a one-cylinder model of the joint cannot carry the arm's torque

Point = tuple[Any, Any]


class SerialArm:
    def __init__(self, arm: Arm, gravity: float) -> None:
        self.arm = arm
        self.gravity = gravity
        self.links = arm.links
        self.joint_names = [link.joint for link in arm.links]
        self.payload = arm.payload

    @classmethod
    def of(cls, machine: Machine) -> SerialArm:
        """The arm of a machine config's ``arm:`` under its simulation's gravity."""
        if machine.arm is None:
            raise ValueError(f"config {machine.source}: no arm: section")
        return cls(machine.arm, machine.simulation.gravity)

    def frames(self, q: Sequence[Any], xp: SimpleNamespace = NUMPY) -> list[tuple[Point, Point]]:
        """Each link's joint position and direction (cos, sin) in the plane."""
        x, y = self.arm.origin
        angle: Any = 0.0
        frames = []
        for link, qi in zip(self.links, q):
            if link.kind == "revolute":
                angle = angle + qi
            frames.append(((x, y), (xp.cos(angle), xp.sin(angle))))
            x, y = self._on_link(frames[-1], link.length + self._slide(link, qi), link.offset)
        return frames

    @staticmethod
    def _slide(link: ArmLink, q: Any) -> Any:
        """How far along itself a link has slid: a prismatic link by its joint, a revolute one not at all."""
        return q if link.kind == "prismatic" else 0.0

    @staticmethod
    def _on_link(frame: tuple[Point, Point], along: Any, across: float) -> Point:
        (x, y), (c, s) = frame
        return x + along * c - across * s, y + along * s + across * c

    def tip(self, q: Sequence[Any], xp: SimpleNamespace = NUMPY) -> Point:
        """The end of the last link."""
        frames = self.frames(q, xp)
        last = self.links[-1]
        return self._on_link(frames[-1], last.length + self._slide(last, q[-1]), last.offset)

    def columns(self, point: Point, link: int, frames: list[tuple[Point, Point]]) -> list[Point]:
        """d point / d q_j of a point fixed on link ``link``, for every joint j."""
        out: list[Point] = []
        for j, ((x, y), direction) in enumerate(frames):
            if j > link:
                out.append((0.0, 0.0))
            elif self.links[j].kind == "revolute":
                out.append((y - point[1], point[0] - x))  # e_z x (point - joint)
            else:
                out.append(direction)
        return out

    def tip_columns(self, q: Sequence[Any], xp: SimpleNamespace = NUMPY) -> list[Point]:
        """The tip's Jacobian, one (dx, dy) column per joint."""
        frames = self.frames(q, xp)
        return self.columns(self.tip(q, xp), len(self.links) - 1, frames)

    def inertia_gravity(self, q: Sequence[Any], payload: float | None = None) -> tuple[list[list[Any]], list[Any]]:
        """M (n x n) and G (n) at joint positions q; ``payload`` [kg] at the tip (None: the arm's)."""
        n = len(self.links)
        frames = self.frames(q)
        inertia: list[list[Any]] = [[0.0] * n for _ in range(n)]
        gravity: list[Any] = [0.0] * n
        carried = [(i, mass.mass, self._on_link(frames[i], mass.along + self._slide(link, q[i]), mass.across),
                    mass.inertia)
                   for i, link in enumerate(self.links) for mass in link.masses]
        tip_mass = self.payload if payload is None else payload
        if tip_mass:
            carried.append((n - 1, tip_mass, self.tip(q), 0.0))
        for link, mass, point, rotational in carried:
            columns = self.columns(point, link, frames)[:link + 1]  # the joints beyond its link do not move it
            turned = [self.links[j].kind == "revolute" for j in range(link + 1)]
            for j, (d_x, d_y) in enumerate(columns):
                gravity[j] = gravity[j] + mass * self.gravity * d_y
                for k, (e_x, e_y) in enumerate(columns):
                    inertia[j][k] = inertia[j][k] + mass * (d_x * e_x + d_y * e_y) + (rotational if turned[j] and turned[k] else 0.0)
        return inertia, gravity


def equivalent_load(arm: SerialArm, joint: str) -> Load:
    """The load a one-cylinder model of revolute ``joint`` (the SAM's boom, P-I eqs. 20-21: torque g cos(q) (m_B d + m_L L),
    inertia m_B (L_B^2 / 12 + d^2) + m_L L^2) carries: its link's own masses as the boom, and what the arm adds beyond
    them as one mass whose moment and inertia give the arm's gravity torque and inertia about the joint with every joint
    at the middle of its range. Exact there; elsewhere the torque's phase and the inertia move with the other joints,
    which only the arm's model follows. ValueError where the model cannot carry it: a prismatic joint, or a middle pose
    where cos(q) vanishes but the arm's torque does not."""
    index = arm.joint_names.index(joint)
    link = arm.links[index]
    if link.kind != "revolute":
        raise ValueError(f"joint {joint} is prismatic: the one-cylinder boom model turns its joint")
    q = [0.5 * (low + high) for low, high in (each.joint_range for each in arm.links)]
    inertia, gravity = arm.inertia_gravity(q)
    mass = sum(m.mass for m in link.masses)
    cog = sum(m.mass * m.along for m in link.masses) / mass if mass else 0.0
    about_cog = sum(m.inertia + m.mass * ((m.along - cog) ** 2 + m.across ** 2) for m in link.masses)
    # a slender boom of that inertia about its centre of gravity: I = m L^2 / 12
    length = math.sqrt(12.0 * about_cog / mass) if mass and about_cog > 0.0 else link.length
    cos_q = math.cos(q[index])
    if abs(cos_q) < MIN_COS:
        raise ValueError(f"joint {joint}'s range {list(link.joint_range)} is centred at {q[index]:.2f} rad, where the one-cylinder "
                         "model's gravity torque g cos(q) (...) vanishes")
    moment = float(gravity[index]) / (arm.gravity * cos_q) - mass * cog if arm.gravity else 0.0  # [kg m] m_L L
    added = float(inertia[index][index]) - mass * (length**2 / 12.0 + cog**2)  # [kg m^2] m_L L^2
    if added <= 1e-12:
        return Load(mass, length, cog, 0.0, 0.0, link.length)
    if abs(moment) < 1e-9:  # no moment to carry (or no gravity): the inertia as two equal masses either side of the joint
        reach = link.length or 1.0
        return Load(mass, length, cog, added / (2.0 * reach**2), added / (2.0 * reach**2), reach)
    # one mass m_L at L with m_L L = moment and m_L L^2 = added; a negative moment is the right-hand mass
    distance, carried = added / abs(moment), moment * moment / added
    return Load(mass, length, cog, carried if moment > 0 else 0.0, carried if moment < 0 else 0.0, distance)


def machine_load(machine: Machine, actuator: str) -> Load:
    """What ``actuator``'s one-cylinder model carries: its own ``load``, or its share of the machine's arm (ValueError why not)."""
    own = machine.actuator(actuator)
    if own.load is not None:
        return own.load
    return equivalent_load(SerialArm.of(machine), own.joint)


def arm_problems(machine: Machine, payload: float | None = None, points: int = 7) -> list[str]:
    """What keeps the machine's arm from being simulated (``holding``'s first list)."""
    return holding(machine, payload, points)[0]


def holding(machine: Machine, payload: float | None = None, points: int = 7) -> tuple[list[str], list[str]]:
    """The arm over a grid of ``points`` poses per joint inside the ranges, ``payload`` [kg] in place of the arm's.

    Problems, one line each, that keep it from being simulated: a joint that moves no mass (its inertia zero: nothing to
    integrate), or a cylinder that cannot hold the arm and its payload still with the supply pressure on its pushing or
    pulling side with every joint at the middle of its range, named with its worst pose (a mass in grams or a payload in
    the wrong unit shows here before it makes the simulator flail). Warnings: cylinders that hold it at the middle but not
    at some pose within the ranges, a load chart's limit (the K70M's tilt, its placeholder triangle, with the telescope
    out and the tilt folded down), not a wrong unit."""
    if machine.arm is None:
        return [], []
    arm = SerialArm.of(machine)
    payload = arm.payload if payload is None else payload
    grid = np.meshgrid(*[np.linspace(low, high, points) for low, high in (link.joint_range for link in arm.links)], indexing="ij")
    q = [g.ravel() for g in grid]
    inertia, gravity = arm.inertia_gravity(q, payload)
    matrices = np.stack([np.stack([np.broadcast_to(np.asarray(m, dtype=float), q[0].shape) for m in row], axis=-1) for row in inertia],
                        axis=-2)
    singular = np.linalg.cond(matrices) > 1e12

    def pose(index: int) -> str:
        return ", ".join(f"{name} = {qi[index]:.2f}" for name, qi in zip(arm.joint_names, q))

    if singular.any():
        return [f"arm: its links' masses leave a joint with no inertia at {pose(int(np.argmax(singular)))} (M(q) singular): every "
                "joint must move a mass off its axis (its link's, one beyond, or the payload)"], []
    by_joint = {a.joint: a for a in machine.actuators}
    middle = (points ** len(q) - 1) // 2  # the grid's middle point: every joint at the middle of its range (points is odd)
    out: list[str] = []
    corners: list[str] = []
    for index, joint in enumerate(arm.joint_names):
        actuator = by_joint[joint]
        cylinder, mount = actuator.cylinder, actuator.mount
        lever = mount_arm(q[index], MOUNT_KINDS.index(mount.kind), mount.l1, mount.l2, mount.l3, mount.theta_offset, mount.sign,
                          mount.ratio)
        force = np.broadcast_to(np.asarray(gravity[index], dtype=float), lever.shape) / lever  # [N] the piston holds, + pushes
        area_a = math.pi * cylinder.piston_diameter**2 / 4.0
        capacity = np.where(force > 0.0, machine.supply_pressure * area_a,
                            machine.supply_pressure * (area_a - math.pi * cylinder.rod_diameter**2 / 4.0))
        worst = int(np.argmax(np.abs(force) / capacity))
        if abs(force[worst]) > capacity[worst]:
            held_in_middle = abs(force[middle]) <= capacity[middle]
            (corners if held_in_middle else out).append(
                f"arm: actuator {actuator.name}'s cylinder cannot hold the arm and its {payload:g} kg payload: it must "
                f"{'push' if force[worst] > 0 else 'pull'} {abs(force[worst]) / 1e3:.1f} kN at {pose(worst)}, its "
                f"{'piston' if force[worst] > 0 else 'rod'} side gives {capacity[worst] / 1e3:.1f} kN at supply pressure "
                + ("(it holds at the middle of the ranges: keep the machine away from there with this payload)" if held_in_middle
                   else "(a mass in grams? masses are kg)"))
    return out, corners
