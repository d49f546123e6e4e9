"""The K70M's lift and tilt mounts that the thesis does not give, swept: every triangle mount that spans its cylinder's
whole stroke over its joint's whole range (P-VI Tables 1 and 3), and what the DP saves over the pseudo-inverses on each.

A triangle mount (``models.kinematics``: cylinder length c = sqrt(l1^2 + l2^2 - 2 l1 l2 cos theta), theta = sign q +
theta_offset, piston x = c - l3) has four constants. Two conditions fix two of them: the cylinder is closed at one end of
the joint's range and fully out at the other (the stroke spans the range: a longer stroke would not be all usable, a
shorter one could not reach it). What is left is swept: the triangle's angle at the closed end, ``theta_closed``, and the
ratio of its sides, ``l2 / l1``; l1 then follows from the stroke and l3 is the closed length. Kept are mounts a cylinder
could be built for (INFERRED bounds, a mount the paper's Fig. 9 drawing does not contradict): the triangle inside
(0, pi) over the whole range (no toggle), a closed length at least the stroke plus MIN_DEAD_LENGTH (the cylinder's head,
piston and gland), sides at most the lift link's length, and a torque arm of at least MIN_ARM over the range; the force
the cylinder must give is not checked (MIN_ARM). The config's own placeholders satisfy these rules (a test rebuilds them);
a sweep's grid of angles and ratios need not pass through them.

P-VI's tilt is a four-bar (its eq. 14), not a triangle: the tilt's 2.5 rad of range on a 0.725 m stroke is what a
triangle reaches only with a small arm near its ends; the sweep says what the triangle family gives, not the four-bar.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from hydro_ros.contract.crane import CraneConfig
from hydro_ros.models.crane import Crane, load_crane
from hydro_ros.models.kinematics import cylinder_length, torque_arm
from hydro_ros.studies.savings_map import savings

MIN_DEAD_LENGTH = 0.15  # [m] closed length beyond the stroke: head, piston and gland (INFERRED, lenient: the config's own tilt
# placeholder has 0.175 m)
MIN_ARM = 0.05  # [m] the smallest torque arm over the range (INFERRED): a floor against triangles near their toggle.
# Whether the cylinder can hold the boom at the supply pressure everywhere in its range is not checked: the sweep asks what
# the mounts do to the energy of a motion, and the boom's weight at the range's ends depends on the other joints
MAX_SIDE = 3.5  # [m] the lift link's length (P-VI Table 2): no mount side longer than the boom it sits on


@dataclass(frozen=True)
class TriangleMount:
    """One mount of the family, in the config's terms (``actuators.<name>.mount``)."""

    l1: float
    l2: float
    l3: float  # the closed length
    theta_offset: float
    sign: int
    theta_closed: float  # [rad] the triangle's angle with the cylinder closed
    side_ratio: float  # l2 / l1

    def config(self) -> dict[str, float]:
        return {"l1": self.l1, "l2": self.l2, "l3": self.l3, "theta_offset": self.theta_offset, "sign": self.sign}

    def arm_range(self, joint_range: tuple[float, float]) -> tuple[float, float]:
        """The least and the greatest torque arm [m] over the joint's range."""
        theta = self.sign * np.linspace(*joint_range, 201) + self.theta_offset
        arm = torque_arm(theta, self.l1, self.l2)
        return float(arm.min()), float(arm.max())


def spanning_mount(joint_range: tuple[float, float], stroke: float, sign: int, theta_closed: float, side_ratio: float) -> TriangleMount:
    """The triangle mount with angle ``theta_closed`` at the closed end and sides l2 = ``side_ratio`` l1 whose cylinder
    travels exactly ``stroke`` over ``joint_range`` (closed at its low end for sign +1, at its high end for sign -1)."""
    low, high = joint_range
    theta_open = theta_closed + (high - low)

    closed, opened = (float(cylinder_length(theta, 1.0, side_ratio)) for theta in (theta_closed, theta_open))  # per metre of l1
    l1 = stroke / (opened - closed)
    closed_joint = low if sign > 0 else high
    return TriangleMount(l1, side_ratio * l1, l1 * closed, theta_closed - sign * closed_joint, sign, theta_closed, side_ratio)


def why_not_buildable(mount: TriangleMount, joint_range: tuple[float, float], stroke: float) -> str:
    """Why a cylinder could not be built for ``mount`` (empty when it could)."""
    theta_open = mount.theta_closed + (joint_range[1] - joint_range[0])
    if not (mount.theta_closed > 0.0 and theta_open < math.pi):
        return "the triangle toggles within the range"
    if mount.l3 < stroke + MIN_DEAD_LENGTH:
        return f"closed length {mount.l3:.3f} m < stroke + {MIN_DEAD_LENGTH} m"
    if max(mount.l1, mount.l2) > MAX_SIDE:
        return f"a side of {max(mount.l1, mount.l2):.2f} m > {MAX_SIDE} m"
    if mount.arm_range(joint_range)[0] < MIN_ARM:
        return f"torque arm below {MIN_ARM} m"
    return ""


def mount_family(joint_range: tuple[float, float], stroke: float, sign: int, closed_angles: Iterable[float],
                 side_ratios: Iterable[float]) -> list[TriangleMount]:
    """Every buildable spanning mount on the grid of closed-end angles and side ratios."""
    candidates = (spanning_mount(joint_range, stroke, sign, theta, ratio) for theta in closed_angles for ratio in side_ratios)
    return [m for m in candidates if not why_not_buildable(m, joint_range, stroke)]


def crane_with_mounts(config_path: str | Path, mounts: dict[str, TriangleMount]) -> tuple[Crane, CraneConfig]:
    """The planner's crane of ``config_path`` with these actuators' mounts replaced."""
    return load_crane(config_path, {name: {"mount": mount.config()} for name, mount in mounts.items()})


def sweep(config_path: str | Path, geometries: Iterable[dict[str, TriangleMount]], paths: dict[str, dict[str, Any]], *,
          grid: tuple[int, int, int] | None = None, progress: Callable[[str], None] | None = None) -> list[dict[str, Any]]:
    """The savings (``studies.savings_map.savings``) on ``paths`` (config ``paths:`` entries) for each geometry (the mounts
    it replaces): one entry per geometry, its mounts and its rows."""
    out = []
    for mounts in geometries:
        crane, config = crane_with_mounts(config_path, mounts)
        out.append({"mounts": {name: asdict(m) for name, m in mounts.items()}, "rows": savings(crane, config, paths, grid=grid)})
        if progress:
            progress(", ".join(f"{name} {m.theta_closed:.2f} rad/{m.side_ratio:.2f}" for name, m in mounts.items()))
    return out


def one_at_a_time(families: dict[str, list[TriangleMount]]) -> list[dict[str, TriangleMount]]:
    """Each family's mounts alone (the others as the config has them), then every combination of each family's two
    extremes of the closed-end angle."""
    alone = [{name: mount} for name, family in families.items() for mount in family]
    extremes = [[min(f, key=lambda m: m.theta_closed), max(f, key=lambda m: m.theta_closed)] for f in families.values()]
    return alone + [dict(zip(families, choice, strict=True)) for choice in itertools.product(*extremes)]
