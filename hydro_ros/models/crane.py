"""Kinematics and cylinder forces of an arm redundant in one joint along a planar tip path (P-V Sections 2, 5.1;
P-VI Section 3).

One model serves every chain the planner reads (``contract.crane``): three planar joints (P-V eqs. 1-8, P-VI eqs. 2-7 with
the tilt offset L2), optionally turned about the vertical axis by a base joint (P-VI q1), one of them redundant. Given
the tip path and the redundant cylinder's position, velocity and acceleration, the other two joints follow from the
inverse kinematics of the two-link chain they leave (P-V eqs. 22-26, P-VI eqs. 33-35 for the telescope; the same closed
form wherever the redundancy sits, on one elbow branch, for any two revolute joints).

Every function works elementwise, so the same code evaluates one state, a grid of states
(NumPy broadcasting) or symbolic nodes of a direct-collocation problem (CasADi): the math
functions come from a namespace, ``NUMPY`` by default.
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass, fields, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from hydro_ros.contract.config import ConfigError, read_config
from hydro_ros.contract.crane import CraneConfig, CraneJoint, parse_planning
from hydro_ros.models.serial_arm import SerialArm

NUMPY = SimpleNamespace(
    cos=np.cos,
    sin=np.sin,
    atan2=np.arctan2,
    acos=np.arccos,
    sqrt=np.sqrt,
    tanh=np.tanh,
    # an unreachable point reads as the nearest reachable one; ``Motion.reachable`` says which
    clip_unit=lambda value: np.clip(value, -1.0, 1.0),
)

_LOWER_FACTOR = 1.0 + 1e-9  # limit checks forgive rounding, nothing more
STRETCHED_ELBOW = 0.02  # [rad] an elbow this close to a line counts as stretched (singular): the planner does not go there
_STRETCHED = math.cos(STRETCHED_ELBOW)


@dataclass(frozen=True)
class CraneCylinder(CraneJoint):
    """A joint of the crane config with the geometry of its cylinder."""

    stroke_offset: float = 0.0
    """[m] |s| at the retracted end of a triangle mapping"""

    def length(self, q: Any, xp: SimpleNamespace = NUMPY) -> Any:
        theta = self.theta_at_min + self.sign * (q - self.q_min)
        return xp.sqrt(self.la**2 + self.lb**2 - 2.0 * self.la * self.lb * xp.cos(theta))

    def stroke(self, q: Any, xp: SimpleNamespace = NUMPY) -> Any:
        if self.mapping == "linear":
            return self.ratio * (q - self.q_min)
        return self.length(q, xp) - self.stroke_offset

    def arm(self, q: Any, xp: SimpleNamespace = NUMPY) -> tuple[Any, Any]:
        """dc/dq (signed torque arm, eq. 30 / P-VI eqs. 10-15) and its derivative d^2c/dq^2."""
        if self.mapping == "linear":
            return self.ratio + 0.0 * q, 0.0 * q
        theta = self.theta_at_min + self.sign * (q - self.q_min)
        length = self.length(q, xp)
        arm = self.sign * self.la * self.lb * xp.sin(theta) / length
        return arm, (self.la * self.lb * xp.cos(theta) - arm * arm) / length

    def joint(self, c: Any, xp: SimpleNamespace = NUMPY) -> Any:
        """Inverse of ``stroke`` (a triangle's angle at the joint between 0 and pi)."""
        if self.mapping == "linear":
            return self.q_min + c / self.ratio
        length = c + self.stroke_offset
        cos_theta = (self.la**2 + self.lb**2 - length**2) / (2.0 * self.la * self.lb)
        theta = xp.acos(xp.clip_unit(cos_theta))
        return self.q_min + (theta - self.theta_at_min) / self.sign

    @property
    def stroke_max(self) -> float:
        return float(abs(self.stroke(self.q_max) - self.stroke(self.q_min)))


@dataclass
class Motion:
    """Joint and cylinder motion of a crane state; lists hold one entry per joint."""

    q: list[Any]
    qd: list[Any]
    qdd: list[Any]
    c: list[Any]
    v: list[Any]
    a: list[Any]
    force: list[Any] | None
    reachable: Any  # IK solvable (NumPy evaluation only; None for symbolic)


class Crane:
    """The planner's machine (``contract.crane.CraneConfig``): its planar joints a :class:`SerialArm`, one of them redundant,
    the two others solved from the tip by the inverse kinematics of the two-link chain they leave."""

    def __init__(self, config: CraneConfig, payload: float = 0.0) -> None:
        """``payload`` [kg] hangs at the tip."""
        self.config = config
        self.name = config.name
        self.base_rotation = config.base_rotation
        self.cylinders = [_cylinder(joint) for joint in config.joints]
        self.arm = SerialArm(replace(config.arm, payload=payload), config.gravity)
        self.hydraulics = dict(config.hydraulics)
        self.names = [cylinder.name for cylinder in self.cylinders]
        self.redundant = config.redundant
        self.extension = self.cylinders[self.redundant]
        self.task_dim = 3 if self.base_rotation else 2
        self._base = 1 if self.base_rotation else 0  # the planar joints follow the base's
        self._planar_redundant = self.redundant - self._base
        self._solved = [i for i in range(len(self.arm.links)) if i != self._planar_redundant]
        prismatic = [self.arm.links[i].joint for i in self._solved if self.arm.links[i].kind != "revolute"]
        if len(self.arm.links) != 3 or not 0 <= self._planar_redundant < 3 or prismatic:
            raise ConfigError(f"config {config.source}: the planner solves two revolute joints for the tip and chooses the third "
                              f"(found {len(self.arm.links)} planar joints, redundant {self.extension.name}"
                              + (f", {' and '.join(prismatic)} prismatic: make a prismatic joint the redundant one" if prismatic else "")
                              + ")")
        self._branch = self._elbow_branch()
        self.solved_names = [self.names[self._base + i] for i in self._solved]

    def _elbow_branch(self) -> float:
        """The elbow the joint ranges lie on: the sign of the two solved links' relative angle at the middle of every range
        (+1 and -1 are the two mirror solutions; both papers' cranes sit on -1, the elbow below the line from the lift
        joint to the tip). The planner keeps that branch along every path, so an elbow never flips."""
        middle = [0.5 * (low + high) for low, high in (link.joint_range for link in self.arm.links)]
        *_, phi_a, phi_b, alpha_a, alpha_b = self._two_links(middle[self._planar_redundant], NUMPY)
        a, b = self._solved
        relative = (alpha_b + middle[a] + middle[b] + phi_b) - (alpha_a + middle[a] + phi_a)
        sine = float(np.sin(relative))
        if abs(sine) < 1e-6:
            raise ConfigError(f"config {self.config.source}: the chain is straight at the middle of its joint ranges, so its elbow "
                              "branch is not defined there: narrow a range to one side of the straight pose")
        return 1.0 if sine > 0.0 else -1.0

    def _two_links(self, q_r: Any, xp: SimpleNamespace) -> tuple[Any, ...]:
        """The chain the redundant joint at ``q_r`` leaves: the first solved joint's position, the lengths and directions of
        the vectors from it to the second and from that to the tip (their angles in the solved joints' frames at zero), and
        those frames' angles."""
        q: list[Any] = [0.0 * q_r, 0.0 * q_r, 0.0 * q_r]
        q[self._planar_redundant] = q_r
        frames = self.arm.frames(q, xp)
        a, b = self._solved
        (xa, ya), (ca, sa) = frames[a]
        (xb, yb), (cb, sb) = frames[b]
        xt, yt = self.arm.tip(q, xp)
        ax, ay = xb - xa, yb - ya
        bx, by = xt - xb, yt - yb
        a_along, a_across = ca * ax + sa * ay, -sa * ax + ca * ay
        b_along, b_across = cb * bx + sb * by, -sb * bx + cb * by
        return ((xa, ya), xp.sqrt(a_along * a_along + a_across * a_across), xp.sqrt(b_along * b_along + b_across * b_across),
                xp.atan2(a_across, a_along), xp.atan2(b_across, b_along), xp.atan2(sa, ca), xp.atan2(sb, cb))

    # -- kinematics ------------------------------------------------------------------------
    def forward(self, q: np.ndarray) -> np.ndarray:
        """Tip [x, y, z] of joint vectors q (..., n) (P-V eqs. 5-6, P-VI eqs. 4-6)."""
        q = np.asarray(q, dtype=float)
        rho, height = self.arm.tip([q[..., self._base + i] for i in range(3)])
        if self.base_rotation:
            return np.stack([np.cos(q[..., 0]) * rho, height, np.sin(q[..., 0]) * rho], axis=-1)
        return np.stack([rho, height, np.zeros_like(rho)], axis=-1)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """d tip / d q, shape (..., task_dim, n) (P-V eq. 8, P-VI eq. 7)."""
        q = np.asarray(q, dtype=float)
        planar_q = [q[..., self._base + i] for i in range(3)]
        columns = [(np.broadcast_to(d_rho, q.shape[:-1]), np.broadcast_to(d_h, q.shape[:-1])) for d_rho, d_h in self.arm.tip_columns(planar_q)]
        if not self.base_rotation:
            return np.stack([np.stack(column, axis=-1) for column in columns], axis=-1)
        rho, _ = self.arm.tip(planar_q)
        c1, s1 = np.cos(q[..., 0]), np.sin(q[..., 0])
        base = np.stack([-s1 * rho, np.zeros_like(rho), c1 * rho], axis=-1)
        planar = [np.stack([c1 * d_rho, d_h, s1 * d_rho], axis=-1) for d_rho, d_h in columns]
        return np.stack([base, *planar], axis=-1)

    def motion(
        self,
        tip: tuple[Any, Any, Any],
        tip_vel: tuple[Any, Any, Any],
        tip_acc: tuple[Any, Any, Any],
        c_ext: Any,
        v_ext: Any,
        a_ext: Any,
        *,
        xp: SimpleNamespace = NUMPY,
        forces: bool = True,
    ) -> Motion:
        """All joints and cylinders from the tip path sample and the redundant cylinder's state.

        Position: P-V eq. 22 / P-VI eq. 33; velocity: eqs. 23-25 / 34; acceleration: eq. 26 / 35.
        Unreachable states come out singular (NaN rates) with ``reachable`` False.
        """
        # unreachable states carry NaN (masked by the callers), so NumPy need not warn about them
        with np.errstate(invalid="ignore", divide="ignore") if xp is NUMPY else contextlib.nullcontext():
            return self._motion(tip, tip_vel, tip_acc, c_ext, v_ext, a_ext, xp, forces)

    def _motion(self, tip: tuple, tip_vel: tuple, tip_acc: tuple, c_ext: Any, v_ext: Any, a_ext: Any, xp: SimpleNamespace, forces: bool) -> Motion:
        redundant = self.extension
        q_r = redundant.joint(c_ext, xp)
        arm_r, arm_rate_r = redundant.arm(q_r, xp)
        qd_r = v_ext / arm_r
        qdd_r = (a_ext - arm_rate_r * qd_r * qd_r) / arm_r
        x, y, z = tip
        xd, yd, zd = tip_vel
        xdd, ydd, zdd = tip_acc
        if self.base_rotation:
            # polar decomposition of the horizontal plane: base angle and horizontal radius
            q1 = xp.atan2(z, x)
            rho = xp.sqrt(x * x + z * z)
            c1, s1 = xp.cos(q1), xp.sin(q1)
            rho_d = c1 * xd + s1 * zd
            q1_d = (-s1 * xd + c1 * zd) / rho
            rho_dd = c1 * xdd + s1 * zdd + rho * q1_d * q1_d
            q1_dd = (-s1 * xdd + c1 * zdd - 2.0 * rho_d * q1_d) / rho
        else:
            rho, rho_d, rho_dd = x, xd, xdd

        # position: the two solved links as a triangle from the first solved joint to the tip
        (xa, ya), length_a, length_b, phi_a, phi_b, alpha_a, alpha_b = self._two_links(q_r, xp)
        rel_rho, rel_h = rho - xa, y - ya
        cos_elbow = (rel_rho * rel_rho + rel_h * rel_h - length_a * length_a - length_b * length_b) / (2.0 * length_a * length_b)
        elbow = self._branch * xp.acos(xp.clip_unit(cos_elbow))
        first = xp.atan2(rel_h, rel_rho) - xp.atan2(length_b * xp.sin(elbow), length_a + length_b * xp.cos(elbow))
        a, b = self._solved
        q_a = self._wrapped(first - alpha_a - phi_a, a, xp)
        q_b = self._wrapped(first + elbow - alpha_b - q_a - phi_b, b, xp)
        planar_q: list[Any] = [q_r, q_r, q_r]
        planar_q[a], planar_q[b] = q_a, q_b

        # velocity: [J_a J_b]^-1 (tip rate - J_r q_r')
        columns = self.arm.tip_columns(planar_q, xp)
        (ja_r, ja_h), (jb_r, jb_h), (jr_r, jr_h) = columns[a], columns[b], columns[self._planar_redundant]
        det = ja_r * jb_h - jb_r * ja_h
        rhs_r, rhs_h = rho_d - jr_r * qd_r, yd - jr_h * qd_r
        qd_a = (jb_h * rhs_r - jb_r * rhs_h) / det
        qd_b = (-ja_h * rhs_r + ja_r * rhs_h) / det
        planar_qd: list[Any] = [qd_r, qd_r, qd_r]
        planar_qd[a], planar_qd[b] = qd_a, qd_b

        # acceleration: the same matrix; the velocity-product terms are J-dot q-dot (P-VI eq. 9)
        bias_r, bias_h = self._velocity_product(planar_q, planar_qd, xp)
        rhs_r, rhs_h = rho_dd - jr_r * qdd_r - bias_r, ydd - jr_h * qdd_r - bias_h
        planar_qdd: list[Any] = [qdd_r, qdd_r, qdd_r]
        planar_qdd[a] = (jb_h * rhs_r - jb_r * rhs_h) / det
        planar_qdd[b] = (-ja_h * rhs_r + ja_r * rhs_h) / det

        if self.base_rotation:
            spread = 0.0 * c_ext  # the base follows the tip alone: give it the states' shape
            q = [q1 + spread, *planar_q]
            qd, qdd = [q1_d + spread, *planar_qd], [q1_dd + spread, *planar_qdd]
        else:
            q, qd, qdd = planar_q, planar_qd, planar_qdd
        c, v, acc = [], [], []
        for cylinder, qi, qdi, qddi in zip(self.cylinders, q, qd, qdd):
            arm, arm_rate = cylinder.arm(qi, xp)
            c.append(cylinder.stroke(qi, xp))
            v.append(arm * qdi)
            acc.append(arm_rate * qdi * qdi + arm * qddi)
        # a stretched elbow is a singular pose: the tip's rates need unbounded joint rates there
        reachable = np.abs(cos_elbow) <= _STRETCHED if xp is NUMPY else None
        motion = Motion(q=q, qd=qd, qdd=qdd, c=c, v=v, a=acc, force=None, reachable=reachable)
        if forces:
            motion.force = self.cylinder_forces(motion)
        return motion

    def _wrapped(self, angle: Any, link: int, xp: SimpleNamespace) -> Any:
        """A solved joint's angle within half a turn of the middle of its range (atan2 sums come out a turn away)."""
        if xp is not NUMPY:  # a collocation's nodes start from a seed inside the ranges and move continuously
            return angle
        low, high = self.arm.links[link].joint_range
        middle = 0.5 * (low + high)
        return middle + np.mod(angle - middle + np.pi, 2.0 * np.pi) - np.pi

    def _velocity_product(self, q: list[Any], qd: list[Any], xp: SimpleNamespace) -> tuple[Any, Any]:
        """The tip's acceleration at zero joint accelerations (J-dot q-dot): each link's vector u turning at w and its slide
        s' give -w^2 u + 2 w s' (the link's direction turned a quarter)."""
        frames = self.arm.frames(q, xp)
        ends = [joint for joint, _ in frames[1:]] + [self.arm.tip(q, xp)]
        turning: Any = 0.0
        bias_r: Any = 0.0
        bias_h: Any = 0.0
        for link, ((x, y), (c, s)), (x_end, y_end), qi_d in zip(self.arm.links, frames, ends, qd):
            if link.kind == "revolute":
                turning = turning + qi_d
                slide: Any = 0.0
            else:
                slide = qi_d
            square = turning * turning
            bias_r = bias_r - square * (x_end - x) - 2.0 * turning * slide * s
            bias_h = bias_h - square * (y_end - y) + 2.0 * turning * slide * c
        return bias_r, bias_h

    # -- dynamics --------------------------------------------------------------------------
    def cylinder_forces(self, motion: Motion) -> list[Any]:
        """Cylinder forces F = R^-1 (M(q) q'' + G(q) + F_f) of point masses (P-VI eq. 16; Coriolis omitted).

        The masses sum into M (3 x 3) and G on the joint positions' shape; only M q'' is evaluated on the
        states' shape (the DP evaluates a grid of velocities and two controls per position).
        """
        planar_q, planar_qd, qdd = motion.q[self._base:], motion.qd[self._base:], motion.qdd[self._base:]
        inertia, gravity = self.arm.inertia_gravity(planar_q)
        torque = [gravity[j] + inertia[j][0] * qdd[0] + inertia[j][1] * qdd[1] + inertia[j][2] * qdd[2] for j in range(3)]
        r = self._planar_redundant
        torque[r] = torque[r] + self.extension_friction(planar_q[r], planar_qd[r])
        forces = []
        for cylinder, qi, tau in zip(self.cylinders[self._base:], planar_q, torque):
            arm, _ = cylinder.arm(qi)
            forces.append(tau / arm)  # F v = tau qdot for either sign of the arm
        if self.base_rotation:
            base = self.cylinders[0]
            forces.insert(0, np.zeros_like(np.asarray(qdd[0])) + (base.constant_force or 0.0))
        return forces

    def extension_friction(self, q_e: Any, qd_e: Any) -> Any:
        """P-VI eqs. A3-A4 on the redundant joint: tanh(K qdot) times a level that ramps by one coulomb per metre over each
        step."""
        friction = self.config.extension_friction
        level = friction.coulomb + 0.0 * q_e
        for low, high in friction.steps:
            level = level + friction.coulomb * np.clip(q_e - low, 0.0, high - low)
        return np.tanh(friction.tanh_gain * qd_e) * level

    # -- limits ----------------------------------------------------------------------------
    def limit_checks(self, motion: Motion, *, tolerance: float = 0.0) -> dict[str, np.ndarray]:
        """Boolean arrays per limit kind: positions (and IK), cylinder velocities, cylinder accelerations."""
        position = np.asarray(motion.reachable, dtype=bool)
        velocity = np.ones_like(position)
        acceleration = np.ones_like(position)
        for cylinder, qi, vi, ai in zip(self.cylinders, motion.q, motion.v, motion.a):
            span = (cylinder.q_max - cylinder.q_min) * (tolerance + 1e-9)
            position = position & (qi >= cylinder.q_min - span) & (qi <= cylinder.q_max + span)
            velocity = velocity & (np.abs(vi) <= cylinder.velocity_max * (_LOWER_FACTOR + tolerance))
            acceleration = acceleration & (np.abs(ai) <= cylinder.acceleration_max * (_LOWER_FACTOR + tolerance))
        return {"position": position, "velocity": velocity, "acceleration": acceleration}


def _cylinder(joint: CraneJoint) -> CraneCylinder:
    cylinder = CraneCylinder(**{f.name: getattr(joint, f.name) for f in fields(joint)})
    if cylinder.mapping == "triangle":
        ends = cylinder.length(np.array([cylinder.q_min, cylinder.q_max]))
        cylinder = replace(cylinder, stroke_offset=float(ends.min()))
    return cylinder


def load_crane(path: str | Path, actuators: dict[str, dict[str, Any]] | None = None) -> tuple[Crane, CraneConfig]:
    """The planner's machine of a config and its typed config (one-line ConfigError on bad input); ``actuators``: sections
    of ``actuators.<name>`` replaced in part (a study's other mount)."""
    config = read_config(path, required=("machine",), nonempty="machine")
    if actuators:
        config["actuators"] = {**config["actuators"], **{name: {**config["actuators"][name], **section} for name, section in actuators.items()}}
    crane_config = parse_planning(config, Path(path).resolve())
    return Crane(crane_config), crane_config
