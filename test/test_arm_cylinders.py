"""The K70M's cylinders as the monitor sees them: one config for planner, plant and monitor; a leak shows in its own cylinder."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from hydro_ros.bags.align import SampleLayout
from hydro_ros.bags.reader import read_bag
from hydro_ros.contract.crane import parse_planning
from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.contract.names import Injection
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.fdi.parity import ParityThresholds
from hydro_ros.models.crane import Crane, load_crane
from hydro_ros.models.sam import Param, SamModel, simulate_segments
from hydro_ros.models.serial_arm import SerialArm
from hydro_ros.planning.serving import executable_trajectory
from hydro_ros.sim.arm_cylinders import ArmCylinders, ArmRun
from hydro_ros.studies import independent_arm
from hydro_ros.studies.crane_monitoring import CraneCase, apart_commissioning_work, path_trajectories, run_crane_cases
from hydro_ros.workflows.commissioning import LEAK_LIMIT, FaultFreeRecording, above_shipped, commission
from test.conftest import K70M

CRANE_RIG = 2  # one built crane; its overlaps 0.14-0.18 against the sheet's 0.15

# studies of minutes of simulated data each: make test runs them, make test-fast does not
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def crane_machine():
    _, config = load_crane(K70M)
    return load_machine_config(K70M), config


def test_one_k70m_config_gives_the_planner_and_the_monitor_the_same_cylinders(crane_machine):
    machine, _ = crane_machine
    crane, _ = load_crane(K70M)
    assert machine.planned and machine.actuator_names == ["lift", "tilt", "extension"]
    for cylinder in crane.cylinders[1:]:  # the base rotation has no actuator (non-differential plungers, no load model)
        model = SamModel(machine, cylinder.name)
        q = np.linspace(cylinder.q_min, cylinder.q_max, 40)
        assert np.allclose(model.piston_from_joint(q), cylinder.stroke(q), atol=1e-5), cylinder.name
        assert np.allclose(model.piston_velocity(q, 0.1), cylinder.arm(q)[0] * 0.1, rtol=1e-6), cylinder.name
        assert np.allclose(model.joint_from_piston(cylinder.stroke(q)), q, atol=1e-6), cylinder.name
        assert model.base[[Param.AREA_A, Param.AREA_B]] == pytest.approx([cylinder.area_a, cylinder.area_b], rel=1e-4), cylinder.name
    # one cylinder, one description: a mount changed for the monitor is the planner's mount too (its rod-end pin 4 cm
    # further out, the retracted length where the range starts)
    mount = machine.actuator("tilt").mount
    low, high = machine.arm.links[1].joint_range
    l1 = mount.l1 + 0.04
    l3 = min(np.sqrt(l1**2 + mount.l2**2 - 2 * l1 * mount.l2 * np.cos(mount.sign * np.linspace(low, high, 201) + mount.theta_offset)))
    shifted = machine.with_overrides({"actuators": {"tilt": {"mount": {"l1": l1, "l3": float(l3)}}}})
    replanned = Crane(parse_planning(shifted.mapping, shifted.source)).cylinders[2]
    q = np.linspace(replanned.q_min, replanned.q_max, 40)
    moved = SamModel(shifted, "tilt").piston_from_joint(q)
    assert np.allclose(moved - moved[0], replanned.stroke(q) - replanned.stroke(q[0]), atol=1e-6)
    assert not np.allclose(replanned.stroke(q), crane.cylinders[2].stroke(q), atol=1e-3)
    arm = SerialArm.of(machine)
    with pytest.raises(InputError, match="lift:payload_mass: an arm's payload hangs at its tip"):
        ArmCylinders(machine, arm, ArmRun(1.0, faults={"lift": [Injection("payload_mass", 300.0)]}))
    with pytest.raises(InputError, match="fault on base: no such actuator"):  # the slew is described, not monitored or simulated
        ArmCylinders(machine, arm, ArmRun(1.0, faults={"base": [Injection("external_leakage_a", 1.0)]}))
    # the one-cylinder boom model takes the lift with its share of the chain (as a boom and arm's), not the sliding telescope
    with pytest.raises(InputError, match="joint extension is prismatic"):
        simulate_segments(SamModel(machine, "extension"), np.zeros((1, 7)), np.zeros(10), np.array([0]), np.array([10]),
                          np.zeros((1, 4096)))


def test_a_leak_shows_in_the_residual_of_its_own_cylinder_while_the_others_move(crane_machine, tmp_path):
    """`hydro-ros sim` of the crane at work (every joint moved by the simulated operator, the loads the crane's own
    masses) into contract bags: the monitor's parity residuals, load-independent, move by the leak's flow in the
    leaking chamber only."""
    machine, _ = crane_machine
    probe = machine.with_overrides({"fdi": {"parity_thresholds": ParityThresholds.probe()}})
    layout = SampleLayout(machine.actuator_names, [a.joint for a in machine.actuators], mobile=True)
    runs = {}
    for name, faults in (("free", []), ("leaking", ["--fault", "lift:external_leakage_a=1.0@20"])):
        bag = tmp_path / name
        done = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "sim", "--config", str(K70M), "--duration", "50", "--seed", "3",
                               *faults, "--out", str(bag), "--quiet"], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        data = read_bag(bag)
        assert data.complete and (data.truth or {}).get("faults") == (
            [] if not faults else [{"actuator": "lift", "name": "external_leakage_a", "value": 1.0, "onset_s": 20.0, "ramp_s": 0.0}])
        runs[name] = data.samples(layout)
    free = runs["free"]
    moved = np.ptp(free.joint_position[:20000], axis=0)
    assert np.all(moved > np.array([0.1, 0.1, 0.1])), moved  # every joint moves, lift and tilt [rad], extension [m]
    at_rest = np.median(free.pressure_a - free.pressure_b, axis=0)
    assert at_rest[0] > 2e6 and at_rest[1] < -2e6, at_rest  # the lift pushes (A carries the load), the tilt pulls (B)
    means = []
    for samples in runs.values():
        run = run_monitor(FdiMonitor(probe), samples)
        means.append(np.nanmean(run.residual_mean[run.times > 26.0], axis=0))  # (A, 2) [L/min], a window after onset
    shift = means[1] - means[0]
    # 1 L/min at 10 MPa leaks ~0.95 L/min at the lift's ~9 MPa; the 5 s means of the other channels stay put
    assert 0.5 < shift[0, 0] < 1.2, shift
    others = np.delete(shift.reshape(-1), 0)
    assert np.all(np.abs(others) < 0.15), shift
    refused = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "sim", "--config", str(K70M), "--duration", "5",
                              "--fault", "external_leakage_a=1.0@2", "--out", str(tmp_path / "refused"), "--quiet"],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 1 and "names its cylinder" in refused.stderr and not (tmp_path / "refused").exists()
    refused = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "sim", "--config", str(K70M), "--duration", "5",
                              "--effect", "coulomb_friction=500", "--out", str(tmp_path / "refused"), "--quiet"],
                             capture_output=True, text=True, timeout=120)
    assert refused.returncode == 1 and "effect names its cylinder" in refused.stderr and not (tmp_path / "refused").exists()


@pytest.fixture(scope="module")
def horizontal():
    _, config = load_crane(K70M)
    return {"horizontal": executable_trajectory(config, "horizontal", "dp_cp")[0]}


def test_the_shipped_crane_thresholds_stay_quiet_on_the_models_own_equations_with_numbers_drawn_off(crane_machine, horizontal):
    """The shipped thresholds on cranes no fit has seen, of the family they were fitted across (the model's own
    equations, every notch, bulk modulus, friction and noise drawn per plant): the random operator moving every joint at
    once, then the energy-optimal horizontal path worked forwards and back at full speed; 300 kg gripped and released
    in both. A claim about that family only: on the crane built apart they alarm within seconds (the test below)."""
    machine, _ = crane_machine
    cases = [CraneCase(901, 90.0), CraneCase(902, 60.0, "horizontal")]
    for outcome in run_crane_cases(machine, horizontal, cases, workers=2):
        assert outcome.alarms == [], (outcome.case, outcome.alarms)


def test_a_leak_is_isolated_to_its_cylinder_while_the_crane_works_its_path(crane_machine, horizontal):
    machine, _ = crane_machine
    cases = [CraneCase(903, 60.0, "horizontal", actuator="lift", fault="external_leakage_a", value=1.0, onset_s=20.0),
             CraneCase(904, 60.0, "horizontal", actuator="tilt", fault="external_leakage_b", value=1.0, onset_s=20.0)]
    for outcome in run_crane_cases(machine, horizontal, cases, workers=2):
        case = outcome.case
        assert outcome.false_alarms == [], (case, outcome.alarms)  # nothing before onset, nothing on another cylinder
        named = [a for a in outcome.alarms if a["fault"] != "unisolated"]
        assert outcome.detection is not None and named and named[0]["fault"] == case.fault, (case, outcome.alarms)


def test_the_crane_built_apart_commissioned_on_its_own_work_is_quiet_and_names_two_litres_but_not_below_the_shipped(crane_machine):
    """The K70M built apart from the model (studies/independent_arm, rig CRANE_RIG: its hoses, tabulated notches, drawn
    overlaps, warming oil) commissioned on its own fault-free work (the operator twice, each path's cycle, a payload
    gripped and released): no leak is read into the healthy crane, each main spool's overlap is found near its build, and
    the commissioned thresholds come out above the shipped ones, which commissioning refuses without --force (the
    model's form errors against this crane: its held-out 5 s means reach ~4 sigma), saying that the shipped ones alarm
    on the same held-out parts. Forced, the monitor stays quiet
    on fresh work of that crane and names a 2 L/min leak on the telescope's B; smaller leaks are not claimed."""
    machine, config = crane_machine
    trajectories = path_trajectories(config)
    rig = independent_arm.build_rig(machine, CRANE_RIG)
    recordings = [FaultFreeRecording(name, independent_arm.measure(rig, independent_arm.simulate(rig, work), work.seed))
                  for name, work in apart_commissioning_work(trajectories)]
    block, report = commission(machine, recordings, force=True)
    for ident in report["identification"]:
        assert max(ident["leaks_l_min"].values()) < LEAK_LIMIT, ident["actuator"]
    built = rig.cylinder[:, independent_arm._C_OVERLAP]
    for index, name in enumerate(machine.actuator_names):
        assert block["model"]["actuators"][name]["valve"]["deadzone"] == pytest.approx(built[index], abs=0.015), name
    assert block["threshold"]["forced"] and above_shipped(report["threshold"]), report["threshold"]["mean_threshold_l_min"]
    # the refusal says why: the config's own thresholds alarm on the same held-out parts of this healthy crane
    assert block["threshold"]["config_alarms_on_held_out"]["count"] > 0
    commissioned = machine.with_overrides(block["model"])
    work = [independent_arm.ArmWork(60.0, 50, payload_steps=((20.0, 300.0), (40.0, 0.0)), lever_limit=0.5),
            independent_arm.ArmWork(60.0, 51, payload_steps=((20.0, 300.0),), path=trajectories["horizontal"]),
            independent_arm.ArmWork(60.0, 52, path=trajectories["half_cycle"]),
            independent_arm.ArmWork(45.0, 53, path=trajectories["half_cycle"], faults=(("extension", "external_leakage_b", 2.0, 20.0),))]
    for run in work:
        alarms = run_monitor(FdiMonitor(commissioned), independent_arm.measure(rig, independent_arm.simulate(rig, run), run.seed)).alarms
        if not run.faults:
            assert alarms == [], (run.seed, alarms)
        else:
            assert alarms and all(a.actuator == "extension" and a.time_s > 20.0 for a in alarms), alarms
            assert alarms[-1].fault.value == "external_leakage_b", alarms
