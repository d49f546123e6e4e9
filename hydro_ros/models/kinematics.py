"""Cylinder mount kinematics: P-I eqs. (3)-(5) of the SAM boom, and the mounts of a crane's cylinders.

Scalar or array arguments (numba compiles each). theta is the triangle angle at the boom joint between the two cylinder mounts; the joint
position reported on /joint_states is theta - theta_offset (INFERRED mapping, config/sam.yaml). A crane's cylinder may open its
triangle as the joint closes (sign -1, P-VI's tilt), or move linearly with the joint (a telescope: x = ratio (joint + offset)).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(cache=True)
def cylinder_length(theta: float, l1: float, l2: float) -> float:
    return np.sqrt(l1 * l1 + l2 * l2 - 2.0 * l1 * l2 * np.cos(theta))


@njit(cache=True)
def piston_position(theta: float, l1: float, l2: float, l3: float) -> float:
    """Eq. (3): x(theta) = sqrt(l1^2 + l2^2 - 2 l1 l2 cos theta) - l3."""
    return cylinder_length(theta, l1, l2) - l3


@njit(cache=True)
def torque_arm(theta: float, l1: float, l2: float) -> float:
    """Eq. (5): r(theta) = dx/dtheta = l1 l2 sin theta / cylinder length."""
    return l1 * l2 * np.sin(theta) / cylinder_length(theta, l1, l2)


@njit(cache=True)
def torque_arm_derivative(theta: float, l1: float, l2: float) -> float:
    """dr/dtheta, the R'(theta) of eq. (7)."""
    length = cylinder_length(theta, l1, l2)
    arm = l1 * l2 * math.sin(theta) / length
    return (l1 * l2 * math.cos(theta) - arm * arm) / length


@njit(cache=True)
def triangle_angle(x: float, l1: float, l2: float, l3: float) -> float:
    """Inverse of eq. (3) on 0 < theta < pi."""
    length = x + l3
    cosine = (l1 * l1 + l2 * l2 - length * length) / (2.0 * l1 * l2)
    return math.acos(min(1.0, max(-1.0, cosine)))


TRIANGLE, LINEAR = 0, 1
MOUNT_KINDS = ("triangle", "linear")


@njit(cache=True)
def mount_piston(joint, kind, l1, l2, l3, offset, sign, ratio):
    """Piston position at a joint position: eq. (3) at theta = sign joint + offset, or ratio (joint + offset) if linear."""
    if kind == LINEAR:
        return ratio * (joint + offset)
    return piston_position(sign * joint + offset, l1, l2, l3)


@njit(cache=True)
def mount_arm(joint, kind, l1, l2, l3, offset, sign, ratio):
    """dx/d(joint) at a joint position: eq. (5) with the mount's sign, or the ratio if linear."""
    if kind == LINEAR:
        return ratio + 0.0 * joint
    return sign * torque_arm(sign * joint + offset, l1, l2)


@njit(cache=True)
def mount_joint(x, kind, l1, l2, l3, offset, sign, ratio):
    """Inverse of mount_piston (a triangle on 0 < theta < pi)."""
    if kind == LINEAR:
        return x / ratio - offset
    return sign * (triangle_angle(x, l1, l2, l3) - offset)


def joint_reach(mount: tuple, low: float, high: float) -> tuple[float, float]:
    """The joint positions at the pistons ``low`` and ``high`` (its end stops), in increasing order; ``mount`` as
    SamModel.mount."""
    ends = sorted((float(mount_joint(low, *mount)), float(mount_joint(high, *mount))))
    return ends[0], ends[1]
