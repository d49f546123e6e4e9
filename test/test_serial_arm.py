"""One rigid-body model for every serial arm a config describes (models/serial_arm.py): the K70M's lift, tilt and
telescope, and config/boom_arm.yaml's boom and arm, checked against the energies of their masses and moved as one arm."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hydro_ros.cli.machine import reach_warnings
from hydro_ros.contract.check import config_problems
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config, parse_machine
from hydro_ros.contract.names import Injection
from hydro_ros.models.crane import load_crane
from hydro_ros.models.sam import Param, SamModel
from hydro_ros.models.serial_arm import SerialArm, arm_problems, equivalent_load, holding
from hydro_ros.sim.scenario import MachineRun

REPO = Path(__file__).resolve().parents[1]
STEP = 1e-6


def _arms() -> dict[str, SerialArm]:
    boom_arm = load_machine_config(REPO / "config" / "boom_arm.yaml")
    return {"boom_arm": SerialArm(boom_arm.arm, 9.81), "k70m": load_crane(REPO / "config" / "k70m.yaml")[0].arm}


def _energies(arm: SerialArm, q: np.ndarray, qd: np.ndarray) -> tuple[float, float]:
    """Potential and kinetic energy of every mass, from positions alone (the kinetic by differencing them along qd)."""
    def points(at: np.ndarray) -> list[tuple[float, float, float, float]]:  # (mass, x, y, link angle) of each mass
        frames = arm.frames(list(at))
        out = []
        for i, link in enumerate(arm.links):
            (x, y), (c, s) = frames[i]
            slide = at[i] if link.kind == "prismatic" else 0.0
            for m in link.masses:
                along = m.along + slide
                out.append((m.mass, x + along * c - m.across * s, y + along * s + m.across * c, np.arctan2(s, c), m.inertia))
        tip = arm.tip(list(at))
        out.append((arm.payload, tip[0], tip[1], 0.0, 0.0))
        return out

    now, later = points(q), points(q + STEP * qd)
    potential = sum(m * arm.gravity * y for m, _, y, _, _ in now)
    kinetic = sum(0.5 * m * ((x1 - x0) ** 2 + (y1 - y0) ** 2) / STEP**2 + 0.5 * inertia * ((a1 - a0) / STEP) ** 2
                  for (m, x0, y0, a0, inertia), (_, x1, y1, a1, _) in zip(now, later))
    return potential, kinetic


@pytest.mark.parametrize("name", ["boom_arm", "k70m"])
def test_inertia_and_gravity_are_those_of_the_masses_energies(name):
    """G = dV/dq and q'^T M q' / 2 = T at random poses and rates: the Jacobians, prismatic links and rotational inertia."""
    arm = _arms()[name]
    rng = np.random.default_rng(3)
    arm.payload = 120.0
    for _ in range(5):
        q = np.array([rng.uniform(*link.joint_range) for link in arm.links])
        qd = rng.normal(size=len(q))
        inertia, gravity = arm.inertia_gravity(list(q))
        potential, kinetic = _energies(arm, q, qd)
        for j in range(len(q)):
            nudged = q.copy()
            nudged[j] += STEP
            assert gravity[j] == pytest.approx((_energies(arm, nudged, qd)[0] - potential) / STEP, rel=1e-4, abs=1e-2)
        assert 0.5 * qd @ np.asarray(inertia, dtype=float) @ qd == pytest.approx(kinetic, rel=1e-4)


def test_the_boom_cylinder_carries_the_arm_as_it_moves():
    """config/boom_arm.yaml as one arm: with the boom's valve closed, its cylinder's force follows the static load of the arm's
    pose as the arm swings out and back (each actuator a boom of its own, as before the arm: section, it stayed constant)."""
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    run = MachineRun(machine, {})
    commands = np.zeros((4000, 2))
    commands[500:2000, 1], commands[2000:3500, 1] = 0.5, -0.5  # the boom's valve stays closed
    states, samples = run.advance(4000, commands)
    boom = SamModel(machine, "boom")
    force = states[0][:, 0] * boom.base[Param.AREA_A] - states[0][:, 1] * boom.base[Param.AREA_B]
    pose = samples.joint_position
    static = np.array([run.arm.arm.inertia_gravity(list(q))[1][0] / float(boom.piston_velocity(q[0], 1.0)) for q in pose])
    # 0.2 s means while the arm swings at a steady rate, once the oil column's ringing after the valve's switching has died
    steady = np.r_[1000:2000, 2600:3500].reshape(-1, 100)
    assert np.ptp(pose[:, 1]) > 0.5 and np.ptp(pose[:, 0]) < 0.02
    swing = np.ptp(static[steady].mean(axis=1))
    assert swing > 2000.0  # [N] the arm's swing moves the boom's load by this much
    assert np.max(np.abs(force[steady].mean(axis=1) - static[steady].mean(axis=1))) < 0.25 * swing


@pytest.mark.parametrize("actuator", ["boom", "arm"])
def test_a_cylinder_studied_alone_carries_the_arms_load_at_the_middle_of_its_ranges(actuator):
    """discrepancy and gsa look at one cylinder: its load (``equivalent_load``) gives the arm's gravity force and inertia about
    its joint with every joint at the middle of its range."""
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    arm = SerialArm.of(machine)
    joint = machine.actuator(actuator).joint
    alone = SamModel(machine.only(actuator, equivalent_load(arm, joint)))
    middle = [0.5 * (low + high) for low, high in (link.joint_range for link in arm.links)]
    index = arm.joint_names.index(joint)
    inertia, gravity = arm.inertia_gravity(middle)
    x = float(alone.piston_from_joint(middle[index]))
    assert alone.load_force(x) == pytest.approx(gravity[index] / float(alone.piston_velocity(middle[index], 1.0)), rel=1e-9)
    assert alone.inertia() == pytest.approx(inertia[index][index], rel=1e-9)
    assert SamModel(machine, actuator).base == pytest.approx(alone.base)  # the machine's own one-cylinder model is the same


def test_the_sams_load_is_a_one_link_arm():
    """config/sam.yaml's ``load`` (P-I eqs. 20-21: a boom of mass m_B and length L_B, m_L and m_R at +-L) said as an ``arm:`` of
    one link gives its one-cylinder model the same inertia and the same load on the piston over the stroke."""
    sam = load_machine_config(REPO / "config" / "sam.yaml")
    load = sam.first.load
    mapping = sam.to_yaml_mapping()
    del mapping["actuators"]["boom"]["load"]
    mapping["arm"] = {"links": [{"joint": sam.first.joint, "length": load.load_distance, "range": [-0.5, 0.5], "masses": [
        {"name": "boom", "mass": load.boom_mass, "along": load.boom_cog_distance, "inertia": load.boom_mass * load.boom_length**2 / 12},
        {"name": "left", "mass": load.left_mass, "along": load.load_distance},
        {"name": "right", "mass": 1.0, "along": -load.load_distance}]}]}
    one_link = SamModel(parse_machine(mapping, sam.source))
    shipped = SamModel(sam.with_overrides({"actuators": {"boom": {"load": {"right_mass": 1.0}}}}))
    assert one_link.inertia() == pytest.approx(shipped.inertia(), rel=1e-12)
    for x in np.linspace(0.05, 0.45, 9):
        assert one_link.load_force(x) == pytest.approx(shipped.load_force(x), rel=1e-12)


def test_a_bent_arms_cylinder_alone_gets_the_arms_torque_and_inertia_or_a_reason():
    """Ranges centred off zero (the arm folded under the boom): the one-cylinder model's torque g cos(q) (m_B d + (m_L - m_R) L)
    and inertia at the middle pose are the arm's, signs included; a joint centred where cos(q) vanishes is refused."""
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    boom, arm_link = machine.arm.links
    bent = SerialArm(replace(machine.arm, links=(replace(boom, joint_range=(0.2, 1.0)), replace(arm_link, joint_range=(-2.5, -1.0)))),
                     9.81)
    middle = [0.6, -1.75]
    inertia, gravity = bent.inertia_gravity(middle)
    for index, joint in enumerate(bent.joint_names):
        load = equivalent_load(bent, joint)
        torque = 9.81 * np.cos(middle[index]) * (load.boom_mass * load.boom_cog_distance
                                                 + (load.left_mass - load.right_mass) * load.load_distance)
        assert torque == pytest.approx(gravity[index], rel=1e-9)
        assert (load.boom_mass * (load.boom_length**2 / 12 + load.boom_cog_distance**2)
                + (load.left_mass + load.right_mass) * load.load_distance**2) == pytest.approx(inertia[index][index], rel=1e-9)
    # the arm folded back past the vertical of its own joint angle: cos(q) < 0 while its weight still opens it, a right-hand mass
    assert np.cos(middle[1]) < 0 < gravity[1] and equivalent_load(bent, "arm_joint").right_mass > 0
    upright = SerialArm(replace(machine.arm, links=(replace(boom, joint_range=(1.4, 1.7)), arm_link)), 9.81)
    with pytest.raises(ValueError, match=r"boom_joint's range \[1.4, 1.7\] is centred at 1.55 rad"):
        equivalent_load(upright, "boom_joint")


def test_faults_set_while_an_arm_runs_act_or_are_refused():
    """plant_sim sets faults while running (``MachineRun.set_fault``): a payload named on any actuator hangs at the tip and
    loads the boom's cylinder; a fault the arm's plant does not simulate is refused, not listed and ignored."""
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    run = MachineRun(machine, {})
    boom = SamModel(machine, "boom")

    def boom_force() -> float:
        states, _ = run.advance(1000, np.zeros((1000, 2)))
        return float(np.mean(states[0][-200:, 0] * boom.base[Param.AREA_A] - states[0][-200:, 1] * boom.base[Param.AREA_B]))

    before = boom_force()
    run.set_fault("arm", "payload_mass", 300.0, run.time)
    after = boom_force()
    q = list(run.arm.joints())
    moment = run.arm.arm.inertia_gravity(q, 300.0 + machine.arm.payload)[1][0] - run.arm.arm.inertia_gravity(q)[1][0]
    assert after - before == pytest.approx(moment / float(boom.piston_velocity(q[0], 1.0)), rel=0.05)
    assert run.active_faults() == ["payload_mass=300"]
    with pytest.raises(InputError, match="fault boom:valve_delay: not simulated on an arm's coupled cylinders"):
        run.set_fault("boom", "valve_delay", 0.05, run.time)
    run.set_fault("arm", "external_leakage_b", 1.0, run.time)
    assert run.active_faults() == ["arm:external_leakage_b=1", "payload_mass=300"]


def test_an_arm_is_checked_against_the_end_stops_and_its_links_required():
    boom_arm = load_machine_config(REPO / "config" / "boom_arm.yaml").to_yaml_mapping()
    boom_arm["simulation"]["end_stop_lower"] = 0.2
    problems = config_problems(boom_arm)
    assert any(p.startswith("arm.links[boom_joint].range: -0.5 puts actuator boom's piston at 0.08") and "end stops 0.2 to 0.5 m" in p
               for p in problems), problems
    operated = load_machine_config(REPO / "config" / "boom_arm.yaml").with_overrides({"excitation": {"joint_range": [-0.2, 0.2]}})
    assert reach_warnings(operated) == ["excitation.joint_range: not used on an arm: its simulated operator moves each joint within "
                                        "80 % of its arm.links range, from the middle"]
    k70m = load_machine_config(REPO / "config" / "k70m.yaml").to_yaml_mapping()
    k70m["arm"] = {"payload": 5000.0, "links": []}
    assert "arm.links: must list the links, base to tip" in config_problems(k70m)


def test_an_arm_its_cylinders_cannot_hold_is_refused_naming_the_cylinder_and_pose():
    """A mass typed in grams passes every range (a link may weigh 280 t) but no 80 mm cylinder holds it at 16 MPa: machine check
    and the simulator say so instead of a bag of a flailing arm and a threshold seven times too high."""
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    assert arm_problems(machine) == []
    grams = machine.with_overrides({"arm": {"links": [machine.to_yaml_mapping()["arm"]["links"][0],
                                                      {**machine.to_yaml_mapping()["arm"]["links"][1],
                                                       "masses": [{"name": "arm", "mass": 250000.0, "along": 0.9}]}]}})
    problems = arm_problems(grams)
    assert len(problems) == 2 and all("cannot hold the arm and its 100 kg payload: it must push" in p for p in problems), problems
    assert problems[1].startswith("arm: actuator arm's cylinder") and "piston side gives 80.4 kN at supply pressure" in problems[1]
    with pytest.raises(InputError, match="actuator boom's cylinder cannot hold the arm"):
        MachineRun(grams, {})


def test_a_cylinder_that_holds_the_arm_at_the_middle_but_not_at_a_corner_is_a_warning_not_a_refusal():
    """The K70M's tilt (its placeholder triangle) holds the crane at the middle of the ranges but not folded down with the
    telescope out: a load chart's limit, said as a warning naming the pose; the simulator still runs it."""
    k70m = load_machine_config(REPO / "config" / "k70m.yaml")
    problems, corners = holding(k70m)
    assert problems == [] and len(corners) == 1, (problems, corners)
    assert corners[0].startswith("arm: actuator tilt's cylinder cannot hold") and "tilt = -2.75" in corners[0] and "holds at the middle" in corners[0]
    problems, corners = holding(k70m.with_overrides({"arm": {"payload": 2000.0}}))  # 2 t at the tip: the lift fails at the middle too
    assert [p.split("'")[0] for p in problems] == ["arm: actuator lift"], problems
    assert [p.split("'")[0] for p in corners] == ["arm: actuator tilt", "arm: actuator extension"], corners


def _boom_arm_with(change) -> dict:
    mapping = load_machine_config(REPO / "config" / "boom_arm.yaml").to_yaml_mapping()
    change(mapping)
    return mapping


@pytest.mark.parametrize("change, problem", [
    (lambda m: m["arm"]["links"][1].update(joint=["arm_joint"]), "arm.links[1].joint: ['arm_joint']: must be the name of an actuator's joint"),
    (lambda m: m["actuators"]["arm"].update(joint=1.0), "actuators.arm.joint: 1.0: must be a name (quote a number: '1.0')"),
    (lambda m: m["arm"]["links"][1].update(range=[-float("inf"), 0.5]), "arm.links[arm_joint].range: [-inf, 0.5]: must be finite"),
    (lambda m: m["arm"]["links"][1].update(range=[-10.0, 10.0]), "arm.links[arm_joint].range: [-10.0, 10.0] rad: must lie within +-7 "
                                                                 "(radians: 90 deg is 1.571)"),
    (lambda m: m["arm"].update(origin=[float("nan"), 0.0]), "arm.origin: [nan, 0.0]: expected [x, y], finite (m)"),
    (lambda m: m["arm"]["links"][1].update(kind="prismatic", range=[0.0, 0.3]),
     "arm.links[arm_joint].kind: prismatic, but actuator arm's mount is a triangle"),
    (lambda m: m["arm"]["links"].append(dict(m["arm"]["links"][0])), "arm.links[boom_joint].joint: 'boom_joint': has an earlier link"),
    (lambda m: m["arm"]["links"][1].update(range=[-0.5, 0.5 + 2 * np.pi]), "arm.links[arm_joint].range: 4.59823 puts actuator arm's piston at -0.098"),
    (lambda m: m["arm"]["links"][1]["masses"][0].update(name={"a": 1}), "arm.links[arm_joint].masses[0].name: {'a': 1}: must be a name"),
])
def test_a_malformed_arm_is_refused_naming_its_key(change, problem):
    """Each found by an attack on the arm: section; before, a traceback or a config accepted and simulated wrongly."""
    problems = config_problems(_boom_arm_with(change))
    assert any(p.startswith(problem) for p in problems), problems


def test_an_arm_that_cannot_be_integrated_or_lifted_is_refused_before_it_runs():
    machine = load_machine_config(REPO / "config" / "boom_arm.yaml")
    massless = parse_machine(_boom_arm_with(lambda m: [link.update(masses=[]) for link in m["arm"]["links"]] and m["arm"].update(payload=0.0)),
                             machine.source)
    assert arm_problems(massless)[0].startswith("arm: its links' masses leave a joint with no inertia at boom_joint = -0.50")
    with pytest.raises(InputError, match="no inertia"):  # was numpy's LinAlgError: Singular matrix
        MachineRun(massless, {})
    with pytest.raises(InputError, match=r"cannot hold the arm and its 1.0001e\+06 kg payload"):  # given on the command line, not in the file
        MachineRun(machine, {"arm": [Injection("payload_mass", 1e6, 1.0)]})
    weightless = machine.with_overrides({"simulation": {"gravity": 0.0}})  # was a ZeroDivisionError in every command
    arm = SerialArm(weightless.arm, 0.0)
    load = equivalent_load(arm, "boom_joint")
    inertia, _ = arm.inertia_gravity([0.0, 0.0])
    assert load.boom_mass * (load.boom_length**2 / 12 + load.boom_cog_distance**2) + (load.left_mass + load.right_mass) * load.load_distance**2 == \
        pytest.approx(inertia[0][0])


def test_review_findings_on_malformed_input_stay_one_line(tmp_path):
    """A key that is a list, a mount that is a word on a prismatic link, an effect a machine cannot have: said, not raised."""
    from hydro_ros.contract.config import ConfigError

    listed = tmp_path / "listed.yaml"
    listed.write_text("machine: x\n? [a, b]\n: 1\n")
    with pytest.raises(ConfigError, match=r"a key that is not a name: \['a', 'b'\] \(line 2\)"):
        load_machine_config(listed)
    worded = _boom_arm_with(lambda m: (m["arm"]["links"][1].update(kind="prismatic", range=[0.0, 0.3]),
                                       m["actuators"]["arm"].update(mount="linear")))
    assert any(p.startswith("actuators.arm.mount") for p in config_problems(worded))
    assert "effects.spool_offset: spool_offset = 2: must be within [-1, 1]" in " ".join(
        config_problems(_boom_arm_with(lambda m: m.update(effects={"spool_offset": 2.0}))))
