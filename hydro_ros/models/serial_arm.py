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

from types import SimpleNamespace
from typing import Any, Sequence

import numpy as np

from hydro_ros.contract.machine import Arm

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
