"""A two-joint arm written apart from the monitor's model (studies/independent_arm): its physics checked on its own,
then the claim the commissioning issue makes: commissioned from the documented minimum (2 recordings of 2 minutes)
of its fault-free work, it raises no alarm in fault-free work it did not train on, holds little of that time and
says where, and still names a 1 L/min leak on the right cylinder and chamber."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES, load_machine_config
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.models.crane import load_crane
from hydro_ros.studies import independent_arm as plant
from hydro_ros.workflows.commissioning import FaultFreeRecording, commission
from test.conftest import REPO

RIG = 1  # one built machine
MAX_HELD_SHARE = 0.10  # the commissioning issue's bound on the share of normal work held, per actuator over the runs


K70M = REPO / "config" / "k70m.yaml"


@pytest.fixture(scope="module")
def boom_arm():
    return load_machine_config(REPO / "config" / "boom_arm.yaml")


@pytest.fixture(scope="module")
def k70m():
    """(the crane's machine config, its crane config): the lift, tilt and sliding telescope built apart."""
    return load_machine_config(K70M), load_crane(K70M)[1]


@pytest.mark.parametrize("machine", ["boom_arm", "k70m"])
def test_the_chain_dynamics_follow_the_masses_energies(machine, request):
    """M(q) is the kinetic energy's Hessian and the gravity term the potential's gradient, both from the masses'
    positions computed here by plain trigonometry; the velocity-product term makes M q'' + b the rate of momentum. On
    the boom and arm (two turning links) and on the crane (two turning, then the telescope sliding on the second)."""
    described = request.getfixturevalue(machine)
    rig = plant.build_rig(described[0] if machine == "k70m" else described, RIG)
    rng = np.random.default_rng(4)
    payload = 120.0

    def points(q: np.ndarray) -> list[tuple[float, np.ndarray, float, float]]:
        """(mass, position, absolute angle, rotational inertia) of every mass and the payload."""
        out, pivot, angle = [], rig.origin.copy(), 0.0
        for j, (length, offset) in enumerate(rig.link):
            slid = q[j] if rig.prismatic[j] else 0.0
            angle += 0.0 if rig.prismatic[j] else q[j]
            along, normal = np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])
            out += [(m, pivot + (a + slid) * along + c * normal, angle, inertia) for link, m, a, c, inertia in rig.mass if int(link) == j]
            pivot = pivot + (length + slid) * along + offset * normal
        return [*out, (payload, pivot, angle, 0.0)]

    def energies(q: np.ndarray, qd: np.ndarray, h: float = 1e-5) -> tuple[float, float]:
        ahead, behind = points(q + h * qd), points(q - h * qd)
        kinetic = sum(0.5 * m * np.sum(((p1 - p0) / (2 * h)) ** 2) + 0.5 * inertia * ((a1 - a0) / (2 * h)) ** 2
                      for (m, p1, a1, inertia), (_, p0, a0, _) in zip(ahead, behind))
        return kinetic, sum(m * rig.gravity * p[1] for m, p, _, _ in points(q))

    joints = len(rig.link)
    for _ in range(5):
        q, qd = rng.uniform(-0.5, 0.5, joints) + np.where(rig.prismatic, 1.5, 0.0), rng.uniform(-0.4, 0.4, joints)
        inertia, weight, bias = plant._mechanics(q, qd, rig.link, rig.prismatic, rig.mass, payload, rig.gravity)
        assert np.allclose(inertia, inertia.T) and np.all(np.linalg.eigvalsh(inertia) > 0)
        assert 0.5 * qd @ inertia @ qd == pytest.approx(energies(q, qd)[0], rel=1e-6)
        h = 1e-4
        gradient = [(energies(q + h * e, qd)[1] - energies(q - h * e, qd)[1]) / (2 * h) for e in np.eye(joints)]
        assert weight == pytest.approx(gradient, rel=1e-6)
        # Lagrange: d/dt(M qd) - dT/dq = M qdd + b at qdd = 0, i.e. b = M' qd - dT/dq
        m_dot = (plant._mechanics(q + h * qd, qd, rig.link, rig.prismatic, rig.mass, payload, rig.gravity)[0]
                 - plant._mechanics(q - h * qd, qd, rig.link, rig.prismatic, rig.mass, payload, rig.gravity)[0]) / (2 * h)
        dt_dq = [(energies(q + h * e, qd)[0] - energies(q - h * e, qd)[0]) / (2 * h) for e in np.eye(joints)]
        assert bias == pytest.approx(m_dot @ qd - np.array(dt_dq), rel=1e-3, abs=1e-3)


def test_the_arm_at_rest_holds_and_its_leak_lowers_its_chamber(boom_arm):
    """Started at rest where the operator holds it, the arm stays within a few milliradians (its P-loop against the
    valve's centre leakage) and its cylinders carry the links' static load, within their static friction; a chamber-B
    leak on the arm's cylinder drains B (a flipped leak would fill it)."""
    rig = plant.build_rig(boom_arm, RIG)
    times, states = plant.simulate(rig, plant.ArmWork(4.0, 1))[:2]
    at_rest = times < plant.OPERATOR_REST[0]  # the operator rests at least this long before the first move
    joints = 4 * 2
    assert np.ptp(states[at_rest, joints:joints + 2], axis=0).max() < 0.005
    last = states[at_rest][-1]
    q = last[joints:joints + 2]
    _, weight, _ = plant._mechanics(q, np.zeros(2), rig.link, rig.prismatic, rig.mass, rig.payload, rig.gravity)
    for i, c in enumerate(rig.cylinder):
        _, arm = plant._piston(c, q[i])
        force = last[4 * i] * c[plant._C_AREA_A] - last[4 * i + 1] * c[plant._C_AREA_B]
        assert abs(arm * force - weight[i]) <= arm * c[plant._C_STATIC], (i, arm * force, weight[i])
    leaking = plant.simulate(rig, plant.ArmWork(4.0, 1, faults=(("arm", "external_leakage_b", 5.0, 0.0),))).states
    assert leaking[at_rest, 4 + 1][-1] < states[at_rest, 4 + 1][-1] - 1.0e5  # arm's p_B, 0.1 MPa lower within 0.5 s


@pytest.mark.slow
def test_the_crane_follows_its_path_on_compensated_valves(k70m):
    """The crane built apart works P-VI's horizontal path (its DP trajectory) forwards and back with the lever's
    feed-forward from the data sheet: each joint within a few centimetres or hundredths of a radian of the path (the
    tilt 0.06: the sheet's feed-forward misses the built valve, and the operator's hand is no heavier than closes an error
    in plant.OPERATOR_RESPONSE, as a heavier one made the lift hunt), and
    the tilt's and telescope's compensators holding about their drop above the chamber they feed while a notch meters
    (a flipped compensator, or one feeding from the supply, fails); the pilot pressure follows the lever."""
    from hydro_ros.studies.crane_monitoring import path_trajectories

    machine, crane = k70m
    rig = plant.build_rig(machine, RIG)
    work = plant.ArmWork(30.0, 3, path=path_trajectories(crane)["horizontal"])
    run = plant.simulate(rig, work)
    reference = plant._path_operator(rig, work, len(run.times), machine.sample_rate_hz)[0]
    joints = run.states[:, 4 * 3:4 * 3 + 3]
    assert np.all(np.abs(joints - reference).max(axis=0) < [0.03, 0.08, 0.05]), np.abs(joints - reference).max(axis=0)
    samples = plant.measure(rig, run, work.seed)
    drop = np.array([a.valve.compensator_pressure_drop for a in machine.actuators])
    for i in range(3):
        opening = np.array([plant._opening(rig.cylinder[i], s) for s in run.states[:, 4 * i + 2]])
        metering = opening > 0.1
        if i == 0:  # the path keeps the lift still (it moves 4 mrad): its spool stays within the overlap
            assert not metering.any()
            continue
        assert metering.sum() > 1000, machine.actuator_names[i]
        fed = np.where(run.states[:, 4 * i + 2] > 0, run.states[:, 4 * i], run.states[:, 4 * i + 1])  # P->A feeds A, P->B feeds B
        above = run.feeds[metering, i] - fed[metering]
        assert np.median(above) == pytest.approx(drop[i] * (1 + plant.COMPENSATOR_RISE * np.median(opening[metering])), rel=0.3)
        lever = np.abs(run.commands[:, i]) > 0.1
        assert np.corrcoef(samples.pilot_pressure_1[lever, i] - samples.pilot_pressure_2[lever, i], run.commands[lever, i])[0, 1] > 0.9


@pytest.mark.slow
@pytest.mark.parametrize("rig", [2, 3])
def test_each_main_spools_overlap_is_identified_on_the_crane_built_apart(k70m, rig):
    """A built crane's main spools overlap 0.14-0.18 where its data sheet says 0.15; commissioning finds each within
    0.015 from 90 s of the operator's work (a fit holding the sheet's value read a difference of 0.015-0.027 as a leak).
    Measured: within 0.004 on rig 2; on rig 3 the lift 0.012 and the tilt 0.008 off, where the data's own optimum lies
    (the model's other form errors bias it), the lift further from its build than the sheet's 0.15. Where a build is
    more than 0.015 from the sheet (rig 2's lift and tilt), the identified overlap halves the sheet's error at least."""
    from hydro_ros.workflows.commissioning import fitted_overlap

    machine, _ = k70m
    samples = plant.recording(machine, rig, plant.ArmWork(90.0, 1, payload_steps=((30.0, 300.0), (60.0, 0.0)), lever_limit=0.5))
    built = plant.build_rig(machine, rig).cylinder[:, plant._C_OVERLAP]
    sheet = machine.first.valve.deadzone
    for index, name in enumerate(machine.actuator_names):
        found = fitted_overlap(machine, name, index, [samples])
        assert found == pytest.approx(built[index], abs=0.015), name
        if abs(built[index] - sheet) > 0.015:  # rig 2's lift and tilt: the sheet's value would fail here
            assert abs(found - built[index]) < 0.5 * abs(sheet - built[index]), name


def test_the_flow_tables_lookup_is_np_interps_arithmetic_bit_for_bit():
    """_table replaces np.interp in the rates' inner loop for speed; the runs the fault-free hours cached stay valid only
    while it gives np.interp's every bit: at and between the knots, past both ends and on a NaN."""
    from numba import njit

    compiled = njit(lambda opening, table: np.interp(opening, plant.TABLE_OPENINGS, table))  # what the rates called before
    rng = np.random.default_rng(7)
    row = rng.uniform(0.1, 2.0, len(plant.TABLE_OPENINGS))
    infinite, flat_infinite = row.copy(), row.copy()
    infinite[3] = np.inf  # a non-finite slope: np.interp's way out
    flat_infinite[3:5] = np.inf
    openings = np.concatenate([plant.TABLE_OPENINGS, np.nextafter(plant.TABLE_OPENINGS, 2.0), np.nextafter(plant.TABLE_OPENINGS, -1.0),
                               rng.uniform(-0.1, 1.1, 2000), [-np.inf, np.inf, np.nan, -0.0]])
    for table in (row, np.full(len(plant.TABLE_OPENINGS), 0.7), infinite, flat_infinite):
        for opening in openings:
            bits = np.float64(plant._table(table, opening)).tobytes()
            assert bits == np.interp(opening, plant.TABLE_OPENINGS, table).tobytes() == np.float64(compiled(opening, table)).tobytes(), opening


def test_the_plant_refuses_what_it_cannot_build(boom_arm, k70m):
    sam_mobile = load_machine_config(REPO / "config" / "sam_mobile.yaml")
    with pytest.raises(InputError, match="the path has no"):
        plant.simulate(plant.build_rig(sam_mobile, RIG), plant.ArmWork(1.0, 1, path=type("Path", (), {
            "joint_names": ["lift"], "time": np.array([0.0, 1.0]), "positions": np.zeros((2, 1))})()))
    with pytest.raises(InputError, match="the path's times must increase"):
        plant.simulate(plant.build_rig(sam_mobile, RIG), plant.ArmWork(1.0, 1, path=type("Path", (), {
            "joint_names": [sam_mobile.first.joint], "time": np.array([0.0, 1.0, 0.5]), "positions": np.zeros((3, 1))})()))
    with pytest.raises(InputError, match=r"spool_too_small_opening 1.5 must be finite, >= 0 and <= 1"):
        plant.simulate(plant.build_rig(boom_arm, RIG), plant.ArmWork(1.0, 1, faults=(("arm", "spool_too_small_opening", 1.5, 0.0),)))
    with pytest.raises(InputError, match=r"lever_limit 0.0"):
        plant.simulate(plant.build_rig(boom_arm, RIG), plant.ArmWork(1.0, 1, lever_limit=0.0))
    with pytest.raises(InputError, match="cannot inject spool_offset on arm"):
        plant.simulate(plant.build_rig(boom_arm, RIG), plant.ArmWork(1.0, 1, faults=(("arm", "spool_offset", 0.1, 0.0),)))
    with pytest.raises(InputError, match="must be finite"):
        plant.simulate(plant.build_rig(boom_arm, RIG), plant.ArmWork(1.0, 1, faults=(("arm", "external_leakage_a", float("nan"), 0.0),)))


def test_the_sams_load_is_one_link_and_its_spool_faults_act_the_way_they_are_named(sam_config):
    """config/sam.yaml (a load, no arm:) is built as the one link its load describes: at rest the cylinder carries
    that link's weight. The same day's work with the spool's drive weakened moves the boom slower, strengthened faster,
    and a spool stuck closed holds it still while the operator keeps pushing (a flipped fault would fail each)."""
    rig = plant.build_rig(sam_config, RIG)
    load = sam_config.first.load
    states = plant.simulate(rig, plant.ArmWork(1.0, 1)).states
    q = states[-1, 4]
    _, arm = plant._piston(rig.cylinder[0], q)
    force = states[-1, 0] * rig.cylinder[0, plant._C_AREA_A] - states[-1, 1] * rig.cylinder[0, plant._C_AREA_B]
    weight = rig.gravity * np.cos(q) * (load.boom_mass * load.boom_cog_distance + (load.left_mass - load.right_mass) * load.load_distance)
    assert abs(arm * force - weight) <= arm * rig.cylinder[0, plant._C_STATIC]

    def travel_per_lever(fault: str, value: float) -> tuple[float, float]:
        """(the boom's travel per unit of lever pushed, the lever pushed on average)."""
        _, states, commands, *_ = plant.simulate(rig, plant.ArmWork(20.0, 4, faults=(("boom", fault, value, 0.0),) if fault else ()))
        return float(np.sum(np.abs(np.diff(states[:, 4]))) / np.sum(np.abs(commands))), float(np.abs(commands).mean())

    healthy, pushed = travel_per_lever("", 0.0)
    weak, _ = travel_per_lever("spool_too_small_opening", 0.5)
    strong, _ = travel_per_lever("spool_too_large_opening", 0.5)
    stuck, pushing = travel_per_lever("spool_stuck_closed", 1.0)
    assert weak < 0.8 * healthy and strong > 1.2 * healthy, (weak, healthy, strong)
    assert stuck < 0.02 * healthy and pushing > pushed  # the operator pushes harder at a boom that does not move


@pytest.fixture(scope="module")
def commissioned(boom_arm):
    """Commissioned from the documented minimum: two recordings of 2 minutes, a payload picked up in one."""
    recordings = [FaultFreeRecording(f"day{w.seed}", plant.recording(boom_arm, RIG, w))
                  for w in plant.work_day(boom_arm, (101, 102), 120.0)]
    block, report = commission(boom_arm, recordings)
    return boom_arm.with_overrides(block["model"]), block, report


@pytest.mark.slow
def test_commissioned_from_the_minimum_the_arm_is_quiet_at_work_it_never_did_and_names_its_leaks(boom_arm, commissioned):
    machine, block, _ = commissioned
    rig = plant.build_rig(boom_arm, RIG)
    for actuator, fit in block["fit"].items():  # the tabulated notches, each drawn off, are found within the table's spread
        index = boom_arm.actuator_names.index(actuator)
        for k, notch in enumerate(NOTCHES):
            side = 1.0 if notch in ("PA", "BT") else -1.0
            drawn = rig.flow_table[index, k, 1:] / np.abs(np.polyval(boom_arm.actuator(actuator).valve.kv_poly[notch],
                                                                     side * plant.TABLE_OPENINGS[1:]))
            assert drawn.min() - 0.03 < fit["notch_gain"][notch] < drawn.max() + 0.03, (actuator, notch, drawn)
    held, evaluated = np.zeros(len(boom_arm.actuators)), 0
    for work in plant.work_day(boom_arm, range(201, 211), 45.0):  # other days: other moves, speeds and payload picks
        monitor = FdiMonitor(machine)
        run = run_monitor(monitor, plant.recording(boom_arm, RIG, work))
        assert run.alarms == [], (work, [a.to_json() for a in run.alarms])
        held += monitor.outside_held_samples
        evaluated += monitor.evaluated_samples
    assert np.all(held / evaluated < MAX_HELD_SHARE), dict(zip(boom_arm.actuator_names, held / evaluated))
    for actuator, fault in (("arm", "external_leakage_b"), ("boom", "external_leakage_a")):
        monitor = FdiMonitor(machine)
        run = run_monitor(monitor, plant.recording(boom_arm, RIG, plant.ArmWork(45.0, 301, faults=((actuator, fault, 1.0, 20.0),))))
        named = [a for a in run.alarms if a.fault.value != "unisolated"]
        assert named and {(a.actuator, a.fault.value) for a in run.alarms if a.fault.value != "unisolated"} == {(actuator, fault)}, \
            [a.to_json() for a in run.alarms]
        assert all(a.time_s > 20.0 for a in run.alarms)
