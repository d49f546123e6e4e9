"""Energy-optimal motion for an arm the crane model was not written for: config/excavator.yaml's boom, arm and bucket,
redundant in the bucket along a planar tip path, read from the monitor's description (arm:, actuators:) and a planner:
section; planned, stored, served and executed as the K70M is."""

from __future__ import annotations

import json

import numpy as np
import pytest
import yaml

from hydro_ros.cli import main as cli_main
from hydro_ros.contract.config import ConfigError, default_config_path
from hydro_ros.contract.errors import InputError
from hydro_ros.models.crane import STRETCHED_ELBOW, Crane, Motion, load_crane
from hydro_ros.planning.catalog import build, plan_units
from hydro_ros.planning.database import TrajectoryDatabase
from hydro_ros.planning.problem import Problem, method_record, run_method
from hydro_ros.planning.serving import JointStateSample, TrajectoryService, path_start_state
from hydro_ros.planning.trajectory import crane_motion, evaluate

EXCAVATOR = default_config_path("excavator")
GRID = (60, 41, 61)


@pytest.fixture(scope="module")
def excavator():
    return load_crane(EXCAVATOR)


def _elbow(crane, q: np.ndarray, solved: tuple[str, ...] = ("boom_joint", "arm_joint")) -> np.ndarray:
    """The sine of the angle between the vector from the first solved joint to the second and the one from the second to
    the tip (the solved pair's elbow)."""
    frames = crane.arm.frames(list(q.T))
    (xa, ya), _ = frames[crane.names.index(solved[0])]
    (xb, yb), _ = frames[crane.names.index(solved[1])]
    xt, yt = crane.arm.tip(list(q.T))
    return ((xb - xa) * (yt - yb) - (yb - ya) * (xt - xb)) / np.hypot(xb - xa, yb - ya) / np.hypot(xt - xb, yt - yb)


@pytest.mark.parametrize("redundant", ["bucket", "arm", "boom"])
def test_the_excavator_is_read_from_the_monitors_description_and_its_inverse_kinematics_inverts_its_forward(excavator,
                                                                                                            redundant) -> None:
    """Whichever joint is redundant: the last, one between the two solved, or the first (each solved angle within half a
    turn of its range's middle: the sums of atan2 come out a turn away for some poses)."""
    crane = Crane(excavator[1].with_overrides({"planner": {"redundant": redundant}}))
    assert crane.names == ["boom_joint", "arm_joint", "bucket_joint"] and crane.extension.name == f"{redundant}_joint"
    assert crane.solved_names == [name for name in crane.names if name != f"{redundant}_joint"]
    # the cylinders are the actuators' own: the bore's area, and the mount's stroke over the joint's range
    assert crane.cylinders[0].area_a == pytest.approx(np.pi * 0.140**2 / 4)
    assert crane.cylinders[2].stroke_max == pytest.approx(0.703, abs=1e-3)  # the bucket's mount over its range, in its 0.75 m
    rng = np.random.default_rng(3)
    low, high = (np.array([getattr(c, end) for c in crane.cylinders]) for end in ("q_min", "q_max"))
    q = low + (high - low) * rng.random((5000, 3))
    qd, qdd = 0.1 * rng.normal(size=q.shape), 0.1 * rng.normal(size=q.shape)
    step = 1e-6
    jac = crane.jacobian(q)
    jac_rate = (crane.jacobian(q + step * qd) - crane.jacobian(q - step * qd)) / (2 * step)
    tip_vel = np.einsum("kij,kj->ki", jac, qd)
    tip_acc = np.einsum("kij,kj->ki", jac_rate, qd) + np.einsum("kij,kj->ki", jac, qdd)
    zero = np.zeros(len(q))
    r = crane.redundant
    arm, arm_rate = crane.extension.arm(q[:, r])
    motion = crane.motion(tuple(crane.forward(q).T), (*tip_vel.T, zero), (*tip_acc.T, zero), crane.extension.stroke(q[:, r]),
                          arm * qd[:, r], arm_rate * qd[:, r] ** 2 + arm * qdd[:, r])
    # the poses in the ranges on the elbow branch the planner keeps (for the bucket: all of them) come back
    elbow = _elbow(crane, q, crane.solved_names)
    kept = (np.sign(elbow) == crane._branch) & (np.abs(elbow) > np.sin(STRETCHED_ELBOW))  # a stretched elbow is out of reach
    assert kept.mean() > (0.999 if redundant == "bucket" else 0.5) and motion.reachable[kept].all()
    q, qd, qdd = q[kept], qd[kept], qdd[kept]
    motion = Motion(*(list(np.stack(values, axis=-1)[kept].T) for values in (motion.q, motion.qd, motion.qdd, motion.c, motion.v,
                                                                             motion.a)), None, None)
    assert np.abs(np.stack(motion.q, axis=-1) - q).max() < 1e-9
    assert np.abs(np.stack(motion.qd, axis=-1) - qd).max() < 1e-8
    assert np.abs(np.stack(motion.qdd, axis=-1) - qdd).max() < 1e-5  # J-dot by finite differences


def test_dp_plans_the_excavators_paths_within_its_limits_on_one_branch_and_beats_the_pseudo_inverses_in_ls(excavator) -> None:
    crane, config = excavator
    for path_id in config.paths:
        problem = Problem.build(crane, config, path_id, grid=GRID)
        plans = {method: run_method(problem, method) for method in ("dp_ls", "pinv_actuator", "pinv_joint")}
        records = {method: method_record(plan) for method, plan in plans.items()}
        assert all(record["limits_ok"] for record in records.values()), {m: r["limits"] for m, r in records.items()}
        motion = crane_motion(crane, problem.samples, plans["dp_ls"].trajectory, forces=False)
        q = np.stack(motion.q, axis=-1)
        assert np.abs(crane.forward(q) - problem.samples.position).max() < 1e-9
        assert (_elbow(crane, q) < 0).all()  # no elbow flip along the path
        # the bucket does work for the energy: the DP's LS energy below both pseudo-inverses' (>= 0 % on lift_out, 36 % on
        # the level cut at this grid)
        assert records["dp_ls"]["ls_energy_J"] <= min(records["pinv_actuator"]["ls_energy_J"], records["pinv_joint"]["ls_energy_J"])
    # the low-pass filter keeps the bucket's accelerations (it averages them) but not always the solved joints': raising
    # the bucket out of the trench on the actuator-energy cost, the arm's would end 0.8 % past its limit, so the DP's own
    # reference is served
    problem = Problem.build(crane, config, "lift_out", grid=GRID)
    plan = run_method(problem, "dp_actuator_energy")
    assert method_record(plan)["limits_ok"] and plan.info["filtered"] is False
    filtered = evaluate(crane, problem.samples, plan.trajectory.filtered(problem.filter_cutoff))
    assert not filtered["limits"]["acceleration"]


def test_a_path_out_of_reach_or_through_a_stretched_elbow_and_chains_without_one_redundancy_are_refused_in_one_line(
        excavator, tmp_path) -> None:
    crane, config = excavator
    stretched = config.with_paths({"reach": {"start": [7.0, 0.0, 0.0], "segments": [{"type": "quintic", "to": [9.0, 2.0, 0.0],
                                                                                     "duration": 6.0}]}})
    with pytest.raises(InputError, match=r"path 'reach': tip path at t = 3\.\d\d s: the tip .* is out of reach of excavator: no "
                                         r"bucket_joint stroke .* boom_joint and arm_joint bent more than 0.02 rad") as refused:
        Problem.build(crane, stretched, "reach", grid=GRID)
    assert "\n" not in str(refused.value)
    mapping = yaml.safe_load(EXCAVATOR.read_text())

    def refusal(change) -> str:
        variant = json.loads(json.dumps(mapping))
        change(variant)
        path = tmp_path / "variant.yaml"
        path.write_text(yaml.safe_dump(variant))
        with pytest.raises(ConfigError) as refused:
            load_crane(path)
        assert "\n" not in str(refused.value)
        return str(refused.value)

    def two_links(variant) -> None:
        variant["arm"]["links"].pop()
        del variant["actuators"]["bucket"], variant["planner"]["actuators"]["bucket"]
        variant["planner"]["redundant"] = "arm"

    assert "2 links: a planar tip path (x, y) fixes two joints" in refusal(two_links)
    assert "planner.redundant: 'stick'" in refusal(lambda v: v["planner"].update(redundant="stick"))
    assert "planner.actuators.arm.velocity_max: missing" in refusal(lambda v: v["planner"]["actuators"]["arm"].pop("velocity_max"))
    assert "planner.hydraulics.ls_margin: missing" in refusal(lambda v: v["planner"]["hydraulics"].pop("ls_margin"))

    def prismatic_arm(variant) -> None:
        variant["arm"]["links"][1].update(kind="prismatic", range=[0.0, 1.0])
        variant["actuators"]["arm"]["mount"] = {"kind": "linear", "ratio": 0.5, "theta_offset": 0.0}

    assert "make a prismatic joint the redundant one" in refusal(prismatic_arm)
    assert "planner.controller.position_gian: unknown key (did you mean position_gain?)" in refusal(
        lambda v: v["planner"].update(controller={"position_gian": 3.0}))
    assert "planner.friction: the redundant joint bucket_joint turns" in refusal(lambda v: v["planner"].update(friction={"coulomb": 10.0}))
    with pytest.raises(ConfigError, match=r"nothing to plan .* no redundancy to optimise"):
        load_crane(default_config_path("boom_arm"))


def test_machine_check_samples_every_path_and_says_what_the_monitor_would_need(tmp_path, capsys) -> None:
    """A file for the planner only passes, saying what the monitor lacks; a path out of reach, one without segments and
    one of an unknown segment type are each named with their id (the planner would refuse them later, one by one)."""
    assert cli_main(["machine", "check", str(EXCAVATOR), "--quiet"]) == 0
    said = capsys.readouterr().out
    assert "planned along level_cut, lift_out (each within reach), redundant joint bucket_joint" in said
    assert "not monitored: the monitor would need sample_rate_hz: missing" in said and "actuators.boom.valve: missing" in said
    mapping = yaml.safe_load(EXCAVATOR.read_text())
    mapping["planner"]["paths"].update({
        "far": {"start": [20.0, 0.0, 0.0], "segments": [{"type": "quintic", "to": [4.5, 0.0, 0.0], "duration": 4.0}]},
        "bare": {"start": [7.0, 0.0, 0.0]},
        "line": {"start": [7.0, 0.0, 0.0], "segments": [{"type": "line", "to": [4.5, 0.0, 0.0], "duration": 4.0}]}})
    broken = tmp_path / "paths.yaml"
    broken.write_text(yaml.safe_dump(mapping))
    assert cli_main(["machine", "check", str(broken), "--quiet"]) == 1
    lines = capsys.readouterr().out.splitlines()
    assert any("path 'far': tip path at t = 0.00 s: the tip [20.0, 0.0, 0.0] m is out of reach of excavator" in line for line in lines)
    assert any("path bare: missing 'segments'" in line for line in lines)
    assert any("path line: segment type 'line' (quintic or spline)" in line for line in lines)


def test_the_excavators_plans_are_stored_served_from_the_measured_state_and_executed_on_the_simulated_arm(excavator, tmp_path,
                                                                                                          capsys) -> None:
    crane, config = excavator
    db_path = tmp_path / "catalog.db"
    with TrajectoryDatabase(db_path, writable=True) as db:
        build(db, plan_units(config, methods=("dp_ls", "pinv_joint"), grid=GRID, paths=("level_cut",)), workers=1)
        service = TrajectoryService(db)
        stored = db.solution("level_cut", "dp_ls")
        assert stored.trajectory.joint_names == crane.names
        # from a bucket 0.1 m further out than planned: replanned from there, the path still kept
        q0 = path_start_state(config, "level_cut", stored.start_position + 0.1)
        served = service.serve("level_cut", "dp_ls", JointStateSample(list(crane.names), q0.tolist(), [0.0] * 3))
        assert served.replanned and all(served.record["limits"].values())
        np.testing.assert_allclose(served.trajectory.positions[0], q0, atol=1e-3)
        assert np.abs(crane.forward(served.trajectory.positions) - crane.forward(stored.trajectory.positions)).max() < 1e-6
    summary = tmp_path / "run.json"
    assert cli_main(["dp", "execute", "--config", str(EXCAVATOR), "--path", "level_cut", "--method", "dp_ls", "--db", str(db_path),
                     "--out", str(tmp_path / "run"), "--summary", str(summary)]) == 0, capsys.readouterr().err
    run = json.loads(summary.read_text())
    # the closed-loop arm (valve dead zone and delay, payload, friction) follows the bucket-tip line at the K70M's scale
    assert run["path_accuracy_iso9283_m"] < 0.2 and run["planned"]["limits_ok"]
    assert run["energy_J"] == pytest.approx(run["planned"]["cp_energy_J"], rel=0.15)
