"""The mount family of the K70M's sweep: the config's own placeholders pass its rules, every member spans its stroke over
its joint's range in the model's own kinematics, and what cannot be built is refused with its reason."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hydro_ros.contract.config import default_config_path, read_config
from hydro_ros.models.kinematics import TRIANGLE, mount_piston
from hydro_ros.studies.mount_sweep import crane_with_mounts, mount_family, one_at_a_time, spanning_mount, why_not_buildable

LIFT, TILT = (-0.425, 1.097), (-2.75, -0.25)  # P-VI Table 3, config/k70m.yaml
LIFT_STROKE, TILT_STROKE = 0.610, 0.725
K70M = read_config(default_config_path("k70m"), required=("machine",), nonempty="machine")


@pytest.mark.parametrize(("name", "joint_range", "stroke"), [("lift", LIFT, LIFT_STROKE), ("tilt", TILT, TILT_STROKE)])
def test_the_configs_own_placeholder_mount_is_a_member_of_the_family(name, joint_range, stroke):
    mount = K70M["actuators"][name]["mount"]
    sign = mount.get("sign", 1)
    theta_closed = mount["theta_offset"] + sign * (joint_range[0] if sign > 0 else joint_range[1])
    rebuilt = spanning_mount(joint_range, stroke, sign, theta_closed, mount["l2"] / mount["l1"])
    assert (rebuilt.l1, rebuilt.l2, rebuilt.l3, rebuilt.theta_offset) == pytest.approx(
        (mount["l1"], mount["l2"], mount["l3"], mount["theta_offset"]), abs=2e-4)
    assert why_not_buildable(rebuilt, joint_range, stroke) == ""


@pytest.mark.parametrize(("joint_range", "stroke", "sign"), [(LIFT, LIFT_STROKE, 1), (TILT, TILT_STROKE, -1)])
def test_every_member_spans_its_whole_stroke_monotonically_over_the_whole_range(joint_range, stroke, sign):
    family = mount_family(joint_range, stroke, sign, np.linspace(0.05, math.pi - (joint_range[1] - joint_range[0]) - 0.02, 8),
                          (0.2, 0.35, 0.5, 0.7, 0.9))
    assert len(family) >= 4
    q = np.linspace(*joint_range, 301)
    for m in family:
        x = np.array([mount_piston(v, TRIANGLE, m.l1, m.l2, m.l3, m.theta_offset, m.sign, 1.0) for v in q])
        closed, opened = (x[0], x[-1]) if sign > 0 else (x[-1], x[0])
        assert closed == pytest.approx(0.0, abs=1e-9) and opened == pytest.approx(stroke, abs=1e-9)
        assert np.all(np.diff(x) * sign > 0)  # no toggle: the cylinder moves one way over the range
        assert m.arm_range(joint_range)[0] > 0.0


def test_what_cannot_be_built_is_refused_with_its_reason():
    assert "toggles" in why_not_buildable(spanning_mount(LIFT, LIFT_STROKE, 1, 1.8, 0.5), LIFT, LIFT_STROKE)
    assert "closed length" in why_not_buildable(spanning_mount(LIFT, LIFT_STROKE, 1, 0.3, 0.5), LIFT, LIFT_STROKE)
    assert "a side of" in why_not_buildable(spanning_mount(LIFT, LIFT_STROKE, 1, 0.6, 0.1), LIFT, LIFT_STROKE)
    assert "torque arm" in why_not_buildable(spanning_mount(TILT, TILT_STROKE, -1, 0.02, 0.2), TILT, TILT_STROKE)


def test_a_geometry_replaces_only_its_mounts_and_the_sweep_covers_each_family_and_their_extremes():
    lift = spanning_mount(LIFT, LIFT_STROKE, 1, 0.5, 0.35)
    _, config = crane_with_mounts(default_config_path("k70m"), {"lift": lift})
    joint = next(j for j in config.joints if j.name == "lift")
    assert (joint.la, joint.lb, joint.theta_at_min) == pytest.approx((lift.l1, lift.l2, lift.theta_closed))
    assert config.mapping["actuators"]["tilt"]["mount"] == K70M["actuators"]["tilt"]["mount"]
    lifts = [spanning_mount(LIFT, LIFT_STROKE, 1, t, 0.35) for t in (0.3, 0.5, 0.9)]
    tilts = [spanning_mount(TILT, TILT_STROKE, -1, t, 0.2) for t in (0.2, 0.3)]
    geometries = one_at_a_time({"lift": lifts, "tilt": tilts})
    assert len(geometries) == 3 + 2 + 4
    assert {(g["lift"].theta_closed, g["tilt"].theta_closed) for g in geometries if len(g) == 2} == {(0.3, 0.2), (0.3, 0.3), (0.9, 0.2), (0.9, 0.3)}
