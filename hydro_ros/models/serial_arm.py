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
from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

from hydro_ros.contract.machine import Arm, Load

NUMPY = SimpleNamespace(cos=np.cos, sin=np.sin)

Point = tuple[Any, Any]


class SerialArm:
    def __init__(self, arm: Arm, gravity: float) -> None:
        self.arm = arm
        self.gravity = gravity
        self.links = arm.links
        self.joint_names = [link.joint for link in arm.links]
        self.payload = arm.payload

    def frames(self, q: Sequence[Any], xp: SimpleNamespace = NUMPY) -> list[tuple[Point, Point]]:
        """Each link's joint position and direction (cos, sin) in the plane."""
        x, y = self.arm.origin
        angle: Any = 0.0
        frames = []
        for link, qi in zip(self.links, q):
            if link.kind == "revolute":
                angle = angle + qi
            frames.append(((x, y), (xp.cos(angle), xp.sin(angle))))
            x, y = self._on_link(frames[-1], link.length + (qi if link.kind == "prismatic" else 0.0), link.offset)
        return frames

    @staticmethod
    def _on_link(frame: tuple[Point, Point], along: Any, across: float) -> Point:
        (x, y), (c, s) = frame
        return x + along * c - across * s, y + along * s + across * c

    def tip(self, q: Sequence[Any], xp: SimpleNamespace = NUMPY) -> Point:
        """The end of the last link."""
        frames = self.frames(q, xp)
        last = self.links[-1]
        return self._on_link(frames[-1], last.length + (q[-1] if last.kind == "prismatic" else 0.0), last.offset)

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
        carried = [(i, mass.mass, self._on_link(frames[i], mass.along + (q[i] if link.kind == "prismatic" else 0.0), mass.across),
                    mass.inertia)
                   for i, link in enumerate(self.links) for mass in link.masses]
        tip_mass = self.payload if payload is None else payload
        if tip_mass:
            carried.append((n - 1, tip_mass, self.tip(q), 0.0))
        for link, mass, point, rotational in carried:
            columns = self.columns(point, link, frames)
            turned = [j <= link and self.links[j].kind == "revolute" for j in range(n)]
            for j, (d_x, d_y) in enumerate(columns):
                if j > link:
                    continue
                gravity[j] = gravity[j] + mass * self.gravity * d_y
                for k, (e_x, e_y) in enumerate(columns[:link + 1]):
                    inertia[j][k] = inertia[j][k] + mass * (d_x * e_x + d_y * e_y) + (rotational if turned[j] and turned[k] else 0.0)
        return inertia, gravity


def equivalent_load(arm: SerialArm, joint: str) -> Load:
    """The load a one-cylinder model of ``joint`` (the SAM's boom, P-I eqs. 20-21) carries: its link's own masses, and the
    links and payload beyond it as one mass whose gravity moment and inertia about the joint are theirs with every joint
    at the middle of its range. Exact there for a revolute joint; elsewhere the moment's direction and the beyond's
    inertia move with the other joints, which only the arm's model follows."""
    index = arm.joint_names.index(joint)
    links = arm.links
    q = [0.5 * (low + high) for low, high in (link.joint_range for link in links)]
    frames = arm.frames(q)
    own = links[index].masses
    mass = sum(m.mass for m in own)
    cog = sum(m.mass * m.along for m in own) / mass if mass else 0.0
    about_cog = sum(m.inertia + m.mass * ((m.along - cog) ** 2 + m.across ** 2) for m in own)
    # a slender boom of that inertia about its centre of gravity: I = m L^2 / 12
    length = math.sqrt(12.0 * about_cog / mass) if mass and about_cog > 0.0 else links[index].length
    (x0, y0), (c, s) = frames[index]
    beyond = [(m.mass, arm._on_link(frames[i], m.along + (q[i] if links[i].kind == "prismatic" else 0.0), m.across), m.inertia)
              for i in range(index + 1, len(links)) for m in links[i].masses]
    beyond.append((arm.payload, arm.tip(q), 0.0))
    moment = sum(m * ((x - x0) * c + (y - y0) * s) for m, (x, y), _ in beyond)  # [kg m] along the link
    inertia = sum(m * ((x - x0) ** 2 + (y - y0) ** 2) + rotational for m, (x, y), rotational in beyond)
    if not moment or not inertia:
        return Load(mass, length, cog, 0.0, 0.0, links[index].length)
    # one mass m_L at distance L with m_L L = moment and m_L L^2 = inertia; behind the joint it is the right-hand mass
    distance = float(inertia / abs(moment))
    carried = float(moment * moment / inertia)
    return Load(mass, length, cog, carried if moment > 0 else 0.0, carried if moment < 0 else 0.0, distance)
