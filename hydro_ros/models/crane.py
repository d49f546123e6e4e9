"""Kinematics and cylinder forces of a crane redundant in its telescope (P-V section 2, P-VI section 2).

One model serves both cranes of the papers: a planar lift-tilt-extension chain (P-V eqs. 1-8,
P-VI eqs. 2-7 with the tilt offset L2), optionally turned about the vertical axis by a base joint
(P-VI q1). The extension is the redundant joint: given the tip path and the extension cylinder's
position, velocity and acceleration, the other joints follow from the closed-form inverse
kinematics (P-V eq. 22-26, P-VI eqs. 33-35; the closed form of h2, h3 is INFERRED, dp.md 4.2).

Every function works elementwise, so the same code evaluates one state, a grid of states
(NumPy broadcasting) or symbolic nodes of a direct-collocation problem (CasADi): the math
functions come from a namespace, ``NUMPY`` by default.
"""

from __future__ import annotations

import contextlib
from dataclasses import dataclass, fields, replace
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from hydro_ros.contract.config import ConfigError, read_config
from hydro_ros.contract.crane import CraneConfig, CraneJoint, parse_crane
from hydro_ros.contract.machine import Arm, ArmLink, LinkMass
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

    def joint(self, c: Any) -> Any:
        """Inverse of ``stroke`` (NumPy)."""
        if self.mapping == "linear":
            return self.q_min + c / self.ratio
        length = c + self.stroke_offset
        cos_theta = (self.la**2 + self.lb**2 - length**2) / (2.0 * self.la * self.lb)
        theta = np.arccos(np.clip(cos_theta, -1.0, 1.0))
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
    """A crane of ``config/crane3dof.yaml`` or ``config/k70m.yaml``: its planar joints a :class:`SerialArm` (lift, tilt and a
    telescope sliding on the tilt link), the planner's closed-form inverse kinematics on top."""

    def __init__(self, config: CraneConfig, payload: float = 0.0) -> None:
        """``payload`` [kg] hangs at the tip."""
        self.config = config
        self.name = config.name
        self.base_rotation = config.base_rotation
        self.cylinders = [_cylinder(joint) for joint in config.joints]
        self.arm = SerialArm(replace(crane_arm(config), payload=payload), config.gravity)
        self.hydraulics = dict(config.hydraulics)
        self.names = [cylinder.name for cylinder in self.cylinders]
        self.extension = self.cylinders[-1]
        self.task_dim = 3 if self.base_rotation else 2

    # -- kinematics ------------------------------------------------------------------------
    def forward(self, q: np.ndarray) -> np.ndarray:
        """Tip [x, y, z] of joint vectors q (..., n) (P-V eqs. 5-6, P-VI eqs. 4-6)."""
        q = np.asarray(q, dtype=float)
        rho, height = self.arm.tip([q[..., -3], q[..., -2], q[..., -1]])
        if self.base_rotation:
            return np.stack([np.cos(q[..., 0]) * rho, height, np.sin(q[..., 0]) * rho], axis=-1)
        return np.stack([rho, height, np.zeros_like(rho)], axis=-1)

    def jacobian(self, q: np.ndarray) -> np.ndarray:
        """d tip / d q, shape (..., task_dim, n) (P-V eq. 8, P-VI eq. 7)."""
        q = np.asarray(q, dtype=float)
        planar_q = [q[..., -3], q[..., -2], q[..., -1]]
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
        """All joints and cylinders from the tip path sample and the extension cylinder's state.

        Position: P-V eq. 22 / P-VI eq. 33; velocity: eqs. 23-25 / 34; acceleration: eq. 26 / 35.
        Unreachable states come out singular (NaN rates) with ``reachable`` False.
        """
        # unreachable states carry NaN (masked by the callers), so NumPy need not warn about them
        with np.errstate(invalid="ignore", divide="ignore") if xp is NUMPY else contextlib.nullcontext():
            return self._motion(tip, tip_vel, tip_acc, c_ext, v_ext, a_ext, xp, forces)

    def _motion(self, tip: tuple, tip_vel: tuple, tip_acc: tuple, c_ext: Any, v_ext: Any, a_ext: Any, xp: SimpleNamespace, forces: bool) -> Motion:
        ext = self.extension
        q_e, qd_e, qdd_e = ext.q_min + c_ext / ext.ratio, v_ext / ext.ratio, a_ext / ext.ratio
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

        # position: triangle lift joint - tilt joint - tip with the extension's reach
        links = self.config.links
        reach = links.extension_base + q_e
        rel_rho, rel_h = rho - links.lift_joint[0], y - links.lift_joint[1]
        arm_length = xp.sqrt(reach * reach + links.tilt_offset**2)
        offset_angle = xp.atan2(links.tilt_offset + 0.0 * reach, reach)
        cos_elbow = (rel_rho * rel_rho + rel_h * rel_h - links.lift_length**2 - arm_length * arm_length) / (
            2.0 * links.lift_length * arm_length
        )
        tilt = -xp.acos(xp.clip_unit(cos_elbow)) - offset_angle  # the elbow-down branch of both papers
        lift = xp.atan2(rel_h, rel_rho) - xp.atan2(
            arm_length * xp.sin(tilt + offset_angle), links.lift_length + arm_length * xp.cos(tilt + offset_angle)
        )

        # velocity: [J_lift J_tilt]^-1 (tip rate - J_ext ext rate)
        (ja_r, ja_h), (jb_r, jb_h), (je_r, je_h) = self.arm.tip_columns([lift, tilt, q_e], xp)
        det = ja_r * jb_h - jb_r * ja_h
        rhs_r, rhs_h = rho_d - je_r * qd_e, yd - je_h * qd_e
        lift_d = (jb_h * rhs_r - jb_r * rhs_h) / det
        tilt_d = (-ja_h * rhs_r + ja_r * rhs_h) / det

        # acceleration: the same matrix; the velocity-product terms are J-dot q-dot (P-VI eq. 9)
        phi_d = lift_d + tilt_d
        phi = lift + tilt
        cp, sp = xp.cos(phi), xp.sin(phi)
        cl, sl = xp.cos(lift), xp.sin(lift)
        centripetal = reach * phi_d * phi_d
        coriolis = 2.0 * qd_e * phi_d
        offset_term = links.tilt_offset * phi_d * phi_d
        bias_r = -links.lift_length * lift_d * lift_d * cl - centripetal * cp - coriolis * sp + offset_term * sp
        bias_h = -links.lift_length * lift_d * lift_d * sl - centripetal * sp + coriolis * cp - offset_term * cp
        rhs_r, rhs_h = rho_dd - je_r * qdd_e - bias_r, ydd - je_h * qdd_e - bias_h
        lift_dd = (jb_h * rhs_r - jb_r * rhs_h) / det
        tilt_dd = (-ja_h * rhs_r + ja_r * rhs_h) / det

        if self.base_rotation:
            spread = 0.0 * c_ext  # the base follows the tip alone: give it the states' shape
            q = [q1 + spread, lift, tilt, q_e]
            qd, qdd = [q1_d + spread, lift_d, tilt_d, qd_e], [q1_dd + spread, lift_dd, tilt_dd, qdd_e]
        else:
            q, qd, qdd = [lift, tilt, q_e], [lift_d, tilt_d, qd_e], [lift_dd, tilt_dd, qdd_e]
        c, v, a = [], [], []
        for cylinder, qi, qdi, qddi in zip(self.cylinders, q, qd, qdd):
            arm, arm_rate = cylinder.arm(qi, xp)
            c.append(cylinder.stroke(qi, xp))
            v.append(arm * qdi)
            a.append(arm_rate * qdi * qdi + arm * qddi)
        reachable = np.abs(cos_elbow) <= 1.0 if xp is NUMPY else None
        motion = Motion(q=q, qd=qd, qdd=qdd, c=c, v=v, a=a, force=None, reachable=reachable)
        if forces:
            motion.force = self.cylinder_forces(motion)
        return motion

    # -- dynamics --------------------------------------------------------------------------
    def cylinder_forces(self, motion: Motion) -> list[Any]:
        """Cylinder forces F = R^-1 (M(q) q'' + G(q) + F_f) of point masses (P-VI eq. 16; Coriolis omitted).

        The masses sum into M (3 x 3) and G on the joint positions' shape; only M q'' is evaluated on the
        states' shape (the DP evaluates a grid of velocities and two controls per position).
        """
        lift, tilt, q_e = motion.q[-3], motion.q[-2], motion.q[-1]
        qdd = motion.qdd[-3:]
        inertia, gravity = self.planar_inertia_gravity(lift, tilt, q_e)
        torque = [gravity[j] + inertia[j][0] * qdd[0] + inertia[j][1] * qdd[1] + inertia[j][2] * qdd[2] for j in range(3)]
        torque[2] = torque[2] + self.extension_friction(q_e, motion.qd[-1])
        forces = []
        planar = self.cylinders[-3:]
        for cylinder, qi, tau in zip(planar, motion.q[-3:], torque):
            arm, _ = cylinder.arm(qi)
            forces.append(tau / arm)  # F v = tau qdot for either sign of the arm
        if self.base_rotation:
            base = self.cylinders[0]
            forces.insert(0, np.zeros_like(np.asarray(qdd[0])) + (base.constant_force or 0.0))
        return forces

    def planar_inertia_gravity(self, lift: Any, tilt: Any, q_e: Any, payload: float | None = None) -> tuple[list[list[Any]], list[Any]]:
        """M (3 x 3) and G (3) of the point masses in the lift, tilt and extension joints (P-VI eq. 16), ``payload`` [kg] at the
        tip (None: the crane's)."""
        return self.arm.inertia_gravity([lift, tilt, q_e], payload)

    def extension_friction(self, q_e: Any, qd_e: Any) -> Any:
        """P-VI eqs. A3-A4: tanh(K qdot4) times a level that ramps by one coulomb per metre over each step."""
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


def crane_arm(config: CraneConfig) -> Arm:
    """The crane's planar joints as a serial arm: the lift link, the tilt link (its masses on the extension's axis, L2 from
    the tilt joint) and the telescope sliding on it from ``extension_base``; the masses that ride on the telescope slide
    with it."""
    lift, tilt, extension = config.joints[-3:]
    links = config.links
    on: dict[str, list[LinkMass]] = {"lift": [], "tilt": [], "telescope": []}
    for mass in config.masses:
        link = "lift" if mass.link == "lift" else "telescope" if mass.moves_with_extension else "tilt"
        on[link].append(LinkMass(mass.name, mass.mass, mass.s, 0.0 if link == "lift" else links.tilt_offset))
    return Arm(links=(ArmLink(lift.name, "revolute", links.lift_length, (lift.q_min, lift.q_max), 0.0, tuple(on["lift"])),
                      ArmLink(tilt.name, "revolute", 0.0, (tilt.q_min, tilt.q_max), 0.0, tuple(on["tilt"])),
                      ArmLink(extension.name, "prismatic", links.extension_base, (extension.q_min, extension.q_max), links.tilt_offset,
                              tuple(on["telescope"]))),
               origin=links.lift_joint)


def _cylinder(joint: CraneJoint) -> CraneCylinder:
    cylinder = CraneCylinder(**{f.name: getattr(joint, f.name) for f in fields(joint)})
    if cylinder.mapping == "triangle":
        ends = cylinder.length(np.array([cylinder.q_min, cylinder.q_max]))
        cylinder = replace(cylinder, stroke_offset=float(ends.min()))
    return cylinder


def load_crane(path: str | Path) -> tuple[Crane, CraneConfig]:
    """The crane of a machine config and its typed config (one-line ConfigError on bad input)."""
    config = read_config(path, required=("machine",), nonempty="machine")
    if config.get("kind") != "crane":
        joints = len(config.get("actuators") or {})
        why = ("a planar tip path fixes two joints, so it has nothing to optimise" if joints <= 2 else
               f"its {joints} joints may be redundant along a tip path, but the planner's inverse kinematics is the lift-tilt-"
               "telescope crane's (kind: crane, with links, joints and paths as in k70m.yaml); other chains are not planned yet")
        raise ConfigError(f"config {path}: not a crane config (kind: crane): the planner needs one redundant degree of freedom "
                          f"along a planar tip path; {why}")
    crane_config = parse_crane(config, Path(path).resolve())
    return Crane(crane_config), crane_config
