"""Crane kinematics, cylinder mappings, forces, paths and stage costs of the DP (P-V, P-VI)."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.contract.config import ConfigError, default_config_path
from hydro_ros.models.crane import Crane, Motion, load_crane
from hydro_ros.models.crane_hydraulics import driven_pressure, pump_flow
from hydro_ros.planning.costs import Cost, stage_power
from hydro_ros.planning.paths import TipPath, path_from_config
from test.conftest import REPO

CRANES = ("k70m", "crane3dof")


def _random_configurations(crane: Crane, count: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    low = np.array([c.q_min for c in crane.cylinders])
    high = np.array([c.q_max for c in crane.cylinders])
    q = low + (high - low) * rng.random((count, len(low)))
    rho, _ = crane.arm.tip([q[:, -3], q[:, -2], q[:, -1]])
    return q[rho > 0.3]  # the base angle is defined for a tip off the slewing axis


def _pad(task: np.ndarray) -> np.ndarray:
    return np.concatenate([task, np.zeros((task.shape[0], 3 - task.shape[1]))], axis=1)


@pytest.mark.parametrize("machine", CRANES)
def test_inverse_kinematics_inverts_forward_kinematics_at_all_levels(machine: str) -> None:
    crane, _ = load_crane(default_config_path(machine))
    q = _random_configurations(crane, 20000)
    rng = np.random.default_rng(1)
    qd, qdd = 0.1 * rng.normal(size=q.shape), 0.1 * rng.normal(size=q.shape)
    jac = crane.jacobian(q)
    step = 1e-6
    jac_rate = (crane.jacobian(q + step * qd) - crane.jacobian(q - step * qd)) / (2 * step)
    tip_vel = _pad(np.einsum("kij,kj->ki", jac, qd))
    tip_acc = _pad(np.einsum("kij,kj->ki", jac_rate, qd) + np.einsum("kij,kj->ki", jac, qdd))
    ext = crane.extension
    motion = crane.motion(
        tuple(crane.forward(q).T), tuple(tip_vel.T), tuple(tip_acc.T), ext.stroke(q[:, -1]), ext.ratio * qd[:, -1], ext.ratio * qdd[:, -1]
    )
    assert motion.reachable.all()
    assert np.abs(np.stack(motion.q, axis=-1) - q).max() < 1e-9
    assert np.abs(np.stack(motion.qd, axis=-1) - qd).max() < 1e-9
    assert np.abs(np.stack(motion.qdd, axis=-1) - qdd).max() < 1e-6  # J-dot by finite differences


@pytest.mark.parametrize("machine", CRANES)
def test_jacobian_matches_finite_differences(machine: str) -> None:
    crane, _ = load_crane(default_config_path(machine))
    q = _random_configurations(crane, 500)
    step = 1e-6
    eye = np.eye(q.shape[1])
    numeric = np.stack(
        [(crane.forward(q + step * eye[j]) - crane.forward(q - step * eye[j])) / (2 * step) for j in range(q.shape[1])], axis=-1
    )[:, : crane.task_dim]
    assert np.abs(crane.jacobian(q) - numeric).max() < 1e-7


@pytest.mark.parametrize("machine", CRANES)
def test_cylinder_mappings_invert_and_differentiate(machine: str) -> None:
    crane, _ = load_crane(default_config_path(machine))
    for cylinder in crane.cylinders:
        q = np.linspace(cylinder.q_min, cylinder.q_max, 101)
        stroke = cylinder.stroke(q)
        assert stroke.min() == pytest.approx(0.0, abs=1e-12)  # the stroke starts at the retracted end
        assert np.abs(cylinder.joint(stroke) - q).max() < 1e-9
        step = 1e-6
        arm, arm_rate = cylinder.arm(q)
        assert np.allclose(arm, (cylinder.stroke(q + step) - cylinder.stroke(q - step)) / (2 * step), atol=1e-7)
        assert np.allclose(arm_rate, (cylinder.arm(q + step)[0] - cylinder.arm(q - step)[0]) / (2 * step), atol=1e-6)
    tilt = crane.cylinders[-2]
    if machine == "k70m":
        assert (tilt.arm(np.linspace(tilt.q_min, tilt.q_max, 11))[0] < 0).all()  # sigma3 = -1: extends as q3 falls
        assert crane.extension.stroke_max == pytest.approx(1.85)


def test_k70m_reach_is_the_papers_9_1_m() -> None:
    crane, _ = load_crane(default_config_path("k70m"))
    lift = np.linspace(-0.425, 1.097, 400)[:, None]
    tilt = np.linspace(-2.75, -0.25, 400)[None, :]
    rho, _ = crane.arm.tip([lift, tilt, 3.7])
    assert rho.max() == pytest.approx(9.1, abs=0.01)


def test_forces_do_the_work_of_lifting_a_tip_mass() -> None:
    """Static tip mass only: sum F_i v_i = m g dy/dt for any motion (signs of arms, telescope ratio)."""
    path = default_config_path("k70m")
    crane, config = load_crane(path)
    links = [{**link, "masses": []} for link in config.mapping["arm"]["links"]]
    links[-1]["masses"] = [{"name": "load", "mass": 100.0, "along": 2.13, "across": 0.376}]  # at the tip, sliding with the telescope
    crane = Crane(config.with_overrides({"arm": {"links": links}, "planner": {"friction": {"coulomb": 0.0}}}))
    q = _random_configurations(crane, 2000, seed=3)
    rng = np.random.default_rng(4)
    qd = 0.05 * rng.normal(size=q.shape)
    tip_vel = np.einsum("kij,kj->ki", crane.jacobian(q), qd)
    ext = crane.extension
    zero = np.zeros(len(q))
    # velocities enter the forces only through friction (zero here), so a static force field
    static = crane.motion(tuple(crane.forward(q).T), (zero, zero, zero), (zero, zero, zero), ext.stroke(q[:, -1]), zero, zero)
    power = sum(force * cylinder.arm(qi)[0] * qdi for force, cylinder, qi, qdi in zip(static.force, crane.cylinders, q.T, qd.T))
    assert np.allclose(power, 100.0 * config.gravity * tip_vel[:, 1], rtol=1e-9, atol=1e-6)


def test_quintic_and_spline_paths_start_and_end_at_rest() -> None:
    _, config = load_crane(default_config_path("k70m"))
    horizontal = path_from_config(config, "horizontal").sample(0.05)
    speed = np.linalg.norm(horizontal.velocity, axis=1)
    assert speed.max() == pytest.approx(0.60, rel=1e-3)  # 1.875 * 3.2 m / 10 s
    assert horizontal.stages == 200
    half = path_from_config(config, "half_cycle")
    samples = half.sample(0.05)
    assert np.abs(samples.velocity[[0, -1]]).max() < 1e-12
    assert np.linalg.norm(samples.velocity, axis=1).max() == pytest.approx(0.75, abs=0.02)
    via = np.asarray(config.path("half_cycle")["segments"][0]["via"])
    distances = np.linalg.norm(samples.position[:, None, :] - via[None], axis=2).min(axis=0)
    assert distances.max() < 0.05  # the spline passes through its via points


def test_bad_paths_and_configs_fail_with_one_line_errors(tmp_path) -> None:
    _, config = load_crane(default_config_path("k70m"))
    with pytest.raises(ConfigError, match="'diagonal': not in config k70m"):
        path_from_config(config, "diagonal")
    with pytest.raises(ConfigError, match="not a multiple"):
        TipPath("odd", {"start": [3, 0.5, 0], "segments": [{"to": [4, 0.5, 0], "duration": 1.01}]}).sample(0.05)
    with pytest.raises(ConfigError, match=r"nothing to plan .*no redundancy to optimise"):
        load_crane(default_config_path("sam"))
    broken = tmp_path / "crane.yaml"
    broken.write_text(default_config_path("crane3dof").read_text().replace("lift: {velocity_max: 0.2, acceleration_max: 0.5}",
                                                                           "lift: {acceleration_max: 0.5}", 1))
    with pytest.raises(ConfigError, match="velocity_max"):
        load_crane(broken)


def test_pump_flow_and_chamber_pressures_by_hand() -> None:
    assert pump_flow(0.1, 0.01, 0.005) == pytest.approx(1e-3)
    assert pump_flow(-0.1, 0.01, 0.005) == pytest.approx(5e-4)
    assert pump_flow(-0.1, 0.01, 0.0) == 0.0  # single-acting lift lowering: no pump flow
    args = (0.01, 0.005, 0.0, 1.0e6, 0.0, 0.002)  # A_A, A_B, non-differential, dp_c 1 MPa, p_T 0, eps
    # extension: back-pressure (A_B/A_A)^2 dp_c = 0.25 MPa; p_A = F/A_A + A_B/A_A p_B = 1 + 0.125 MPa
    assert driven_pressure(10e3, 0.1, *args) == pytest.approx(1.125e6)
    # retraction: back-pressure (A_A/A_B)^2 dp_c = 4 MPa; p_B = -F/A_B + A_A/A_B p_A = 2 + 8 MPa
    assert driven_pressure(-10e3, -0.1, *args) == pytest.approx(10.0e6)
    assert driven_pressure(-10e3, 0.1, *args) == 0.0  # over-running
    assert driven_pressure(10e3, 0.001, *args) == 0.0  # below the drive threshold
    assert driven_pressure(-10e3, -0.1, 0.01, 0.0, 0.0, 1e6, 0.0, 0.002) == 0.0  # single-acting
    # differential spool (eqs. 27-28): p_B = F/(A_A-A_B) + (A_B^2 A_A/(A_A-A_B)^3 + A_A/(A_A-A_B)) dp_c = 2 + 4 MPa
    p_a = driven_pressure(10e3, 0.1, 0.01, 0.005, 1.0, 1.0e6, 0.0, 0.002)
    assert p_a == pytest.approx(4.0e6)
    assert p_a * 0.01 - 6.0e6 * 0.005 == pytest.approx(10e3)  # the piston is in force balance


def test_stage_powers_by_hand() -> None:
    crane, _ = load_crane(default_config_path("k70m"))
    h = crane.hydraulics
    # base still, lift up 0.05 m/s against 100 kN, tilt retracting (over-running), extension out 0.1 m/s against 5 kN
    v = [np.array(0.0), np.array(0.05), np.array(-0.02), np.array(0.1)]
    force = [np.array(0.0), np.array(100e3), np.array(20e3), np.array(5e3)]
    motion = Motion(q=[], qd=[], qdd=[], c=[], v=v, a=[], force=force, reachable=None)
    lift, tilt, ext = crane.cylinders[1], crane.cylinders[2], crane.cylinders[3]
    flow = 0.05 * lift.area_a + 0.02 * tilt.area_b + 0.1 * (ext.area_a - ext.area_b)
    assert stage_power(Cost.CP, crane, motion) == pytest.approx(h["supply_pressure_cp"] * flow)
    lift_pressure = 100e3 / lift.area_a + lift.area_b / lift.area_a * (lift.area_b / lift.area_a) ** 2 * h["compensator_drop"]
    assert stage_power(Cost.LS, crane, motion) == pytest.approx((lift_pressure + h["ls_margin"]) * flow)
    assert stage_power(Cost.ACTUATOR, crane, motion) == pytest.approx(100e3 * 0.05 + 5e3 * 0.1)  # tilt over-runs: no credit
    assert stage_power(Cost.EXTENSION, crane, motion) == pytest.approx(0.01)
    assert stage_power(Cost.VELOCITY, crane, motion) == pytest.approx(0.05**2 + 0.02**2 + 0.1**2)


def test_a_crane_configs_problems_are_named_at_once_by_the_check_and_the_planner(tmp_path) -> None:
    """Each bad entry of the planner's sections named by its key path (list entries by their name), the same in
    `hydro-ros machine check` and in every loader of the crane; the typed config says where the values went. The same for
    a config in the crane form of earlier releases, checked in its own terms before it is converted."""
    import subprocess
    import sys

    import yaml

    _, good = load_crane(default_config_path("k70m"))
    assert good.joint_names == ["base", "lift", "tilt", "extension"] and good.dp.grid == (356, 101, 151)
    assert good.arm.origin == (-0.208, 1.605) and good.joints[-1].differential and good.joints[1].pump_area_retract == 0.0
    assert good.plant["payload"] == 200.0 and good.controller["position_gain"] == 2.0  # the optional sections' defaults
    unloaded = yaml.safe_load(default_config_path("k70m").read_text())
    unloaded["planner"]["plant"] = {"payload": 0.0}
    unloaded["planner"]["controller"] = None  # an empty section: every default
    (tmp_path / "unloaded.yaml").write_text(yaml.safe_dump(unloaded))
    _, light = load_crane(tmp_path / "unloaded.yaml")
    assert light.plant["payload"] == 0.0 and light.plant["valve_delay"] == good.plant["valve_delay"] and light.controller == good.controller
    broken = yaml.safe_load(default_config_path("k70m").read_text())
    broken["arm"]["links"][0]["length"] = -3.5
    broken["planner"]["actuators"]["lift"]["velocity_max"] = -0.15
    broken["actuators"]["tilt"]["mount"]["kind"] = "triangel"
    broken["actuators"]["extension"]["cylinder"]["piston_diamter"] = broken["actuators"]["extension"]["cylinder"].pop("piston_diameter")
    broken["planner"]["spool"] = "differential"
    broken["planner"]["dp"]["grid"] = [356, 101]
    broken["planner"]["plant"] = {"valve_delay": 50.0, "payload": 0.0, "valve_dead_zone": 0.9, "valve_dead_zone_spread": 0.2}
    broken["planner"]["controller"] = {"postion_gain": 3.0}
    broken["planner"]["catalog"] = {"method": ["dp_cp"]}
    bad = _each_problem_named_once(tmp_path / "k70m_bad.yaml", broken, (
                "planner.plant.valve_delay: 50 s: must be <= 5 s", "planner.plant.valve_dead_zone_spread: with valve_dead_zone it reaches",
                "planner.controller.postion_gain: unknown key (did you mean position_gain?)",
                "planner.catalog.method: unknown key (did you mean methods?)",
                "arm.links[lift].length: -3.5 m: must be >= 0 m", "planner.actuators.lift.velocity_max: -0.15 m/s: must be > 0",
                "actuators.tilt.mount.kind: 'triangel': expected triangle or linear",
                "actuators.extension.cylinder.piston_diamter: unknown key (did you mean piston_diameter?)",
                "actuators.extension.cylinder.piston_diameter: missing [m]", "planner.spool: unknown key",
                "planner.dp.grid: [356, 101]: expected three whole numbers"))
    with pytest.raises(ConfigError, match=r"config .*k70m_bad.yaml: .*planner.actuators.lift.velocity_max: -0.15 m/s") as refused:
        load_crane(bad)
    assert "(hydro-ros machine check" in str(refused.value) and "\n" not in str(refused.value)
    planner_only = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "machine", "check", str(default_config_path("crane3dof")), "--quiet"],
                                  capture_output=True, text=True)
    assert planner_only.returncode == 0 and "not monitored: the monitor would need" in planner_only.stdout
    assert "redundant joint extension, the tip solved by lift and tilt: ok" in planner_only.stdout

    broken = yaml.safe_load((REPO / "test" / "crane_form" / "k70m.yaml").read_text())
    broken["links"]["lift_length"] = -3.5
    broken["joints"][1]["cylinder"]["velocity_max"] = -0.15
    broken["joints"][2]["cylinder"]["mapping"] = "triangel"
    broken["joints"][3]["cylinder"]["are_a"] = broken["joints"][3]["cylinder"].pop("area_a")
    broken["masses"][0]["link"] = "lfit"
    broken["dp"]["grid"] = [356, 101]
    bad = _each_problem_named_once(tmp_path / "k70m_crane_form_bad.yaml", broken, (
                "links.lift_length: -3.5 m: must be > 0 m", "joints[lift].cylinder.velocity_max: -0.15 m/s: must be > 0",
                "joints[tilt].cylinder.mapping: 'triangel': expected linear or triangle",
                "joints[extension].cylinder.are_a: unknown key (did you mean area_a?)", "joints[extension].cylinder.area_a: missing [m^2]",
                "masses[inner_boom].link: 'lfit': expected lift or boom", "dp.grid: [356, 101]: expected three whole numbers"))
    with pytest.raises(ConfigError, match=r"links.lift_length: -3.5 m: must be > 0 m; joints\[lift\]") as refused:
        load_crane(bad)
    assert "and 2 more (hydro-ros machine check" in str(refused.value) and "\n" not in str(refused.value)


def _each_problem_named_once(path, broken: dict, expected: tuple[str, ...]):
    """``broken`` written to ``path``; `hydro-ros machine check` exits 1 without a traceback, each expected problem on one
    line of its own."""
    import subprocess
    import sys

    import yaml

    path.write_text(yaml.safe_dump(broken))
    checked = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "machine", "check", str(path), "--quiet"], capture_output=True, text=True)
    lines = checked.stdout.strip().splitlines()
    assert checked.returncode == 1 and "Traceback" not in checked.stderr
    for problem in expected:
        assert sum(problem in line for line in lines) == 1, (problem, lines)
    return path


def test_a_crane_friction_ramp_that_is_not_a_pair_is_refused_naming_its_key(tmp_path) -> None:
    import yaml

    broken = yaml.safe_load(default_config_path("k70m").read_text())
    broken["planner"]["friction"]["steps"] = [[1.0, 2.0], [3.0]]
    bad = tmp_path / "k70m_steps.yaml"
    bad.write_text(yaml.safe_dump(broken))
    with pytest.raises(ConfigError, match=r"planner.friction.steps: \[\[1.0, 2.0\], \[3.0\]\]: expected a list of \[from, to\]"):
        load_crane(bad)
    broken["planner"]["friction"]["steps"] = [[1.0, 2.0]]
    bad.write_text(yaml.safe_dump(broken))
    assert load_crane(bad)[1].extension_friction.steps == ((1.0, 2.0),)


@pytest.mark.parametrize("machine", ["k70m", "crane3dof"])
def test_a_crane_form_config_is_read_converted_and_upgraded_losslessly(machine, tmp_path) -> None:
    """The crane form of earlier releases (test/crane_form/, the shipped files as they were) is read with a warning into
    the numbers the shipped machine form gives, and `hydro-ros machine upgrade` writes it so with every value's source."""
    import subprocess
    import sys

    from hydro_ros.contract.check import annotated_values
    from hydro_ros.contract.machine import load_machine_config

    old = REPO / "test" / "crane_form" / f"{machine}.yaml"
    with pytest.warns(FutureWarning, match=r"crane form \(kind: crane\) is read converted .* machine upgrade"):
        _, converted = load_crane(old)
    _, shipped = load_crane(default_config_path(machine))
    for got, want in ((converted, shipped), (load_crane(_upgraded(old, tmp_path))[1], shipped)):
        assert got.joint_names == want.joint_names and got.redundant == want.redundant and got.base_rotation == want.base_rotation
        for a, b in zip(got.joints, want.joints):
            for name in ("q_min", "q_max", "area_a", "area_b", "pump_area_extend", "pump_area_retract", "velocity_max", "acceleration_max"):
                assert getattr(a, name) == pytest.approx(getattr(b, name), rel=1e-4), (a.name, name)
        q = np.linspace(0.0, 1.0, 30)
        for a, b in zip(Crane(got).cylinders, Crane(want).cylinders):
            span = a.q_min + (a.q_max - a.q_min) * q
            assert np.allclose(a.stroke(span), b.stroke(span), atol=1e-4), a.name
        assert got.arm.links == want.arm.links and got.arm.origin == want.arm.origin
        assert (got.hydraulics, got.dp, got.paths, got.extension_friction) == (shipped.hydraulics, shipped.dp, shipped.paths,
                                                                              shipped.extension_friction)
    upgraded = _upgraded(old, tmp_path)
    # every value the crane form marked PLACEHOLDER or INFERRED is marked so in the machine form, beside its new key
    kept = "\n".join(annotated_values(upgraded))
    for note in annotated_values(old):
        assert note.split(": ", 1)[1] in kept, note
    # and every full-line note that says so (the masses', the paths' and the friction's sources)
    written = upgraded.read_text()
    for line in old.read_text().splitlines():
        if line.lstrip().startswith("#") and ("PLACEHOLDER" in line or "INFERRED" in line):
            assert line.strip() in written, line
    if machine == "k70m":  # the monitor reads the same machine from it
        assert load_machine_config(upgraded).actuators == load_machine_config(default_config_path("k70m")).actuators
    again = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "machine", "upgrade", str(upgraded), "--out", str(tmp_path / "x.yaml")],
                           capture_output=True, text=True)
    assert again.returncode == 1 and "not in the crane form" in again.stderr and "\n" not in again.stderr.strip()


def _upgraded(old, tmp_path):
    out = tmp_path / f"{old.stem}_upgraded.yaml"
    if not out.exists():
        from hydro_ros.cli import main

        assert main(["machine", "upgrade", str(old), "--out", str(out)]) == 0
    return out


def test_every_rule_the_config_reference_lists_is_one_machine_check_applies() -> None:
    """docs/reference/config.md is generated from check.REFERENCE: each listed rule, broken in a shipped config that has
    its section, is refused naming the key (so the page lists what the check does, not a copy of it)."""
    import copy

    import yaml

    from hydro_ros.contract.check import REFERENCE, config_problems, planner_problems

    configs = {name: yaml.safe_load(default_config_path(name).read_text()) for name in ("k70m", "boom_arm", "sam", "sam_mems")}
    tried = 0
    for section, rules, _ in REFERENCE:
        base, _, kind = section.partition(" (")
        for config in configs.values():
            node, path = config, []
            for part in base.split(".") if base else []:
                name = part.removesuffix("[]")
                if not isinstance(node, dict) or (name not in node and name != "<name>"):
                    node = None
                    break
                if name == "<name>":
                    name = next(iter(node))
                node = node[name]
                path.append(name)
                if part.endswith("[]"):
                    node, path[-1] = node[0], f"{name}[{node[0].get('joint', node[0].get('name'))}]"
            if not isinstance(node, dict) or (kind and kind.rstrip(")").split(": ")[1] not in (node.get("kind", "triangle"),
                                                                                                 node.get("type"))):
                continue
            for key, rule in rules.items():
                if key not in node or rule.high is None:
                    continue
                broken = copy.deepcopy(config)
                target = broken
                for part in base.split(".") if base else []:
                    name = part.removesuffix("[]")
                    target = target[next(iter(target)) if name == "<name>" else name]
                    target = target[0] if part.endswith("[]") else target
                target[key] = rule.high * 10 + 1
                found = config_problems(broken) + (planner_problems(broken) if "planner" in broken else [])
                named = ".".join([*path, key]) if path else key
                assert any(problem.startswith(f"{named}: ") for problem in found), (section, named, found)
                tried += 1
                break
            break
    assert tried >= 15


def test_every_value_a_field_declares_is_read_into_the_typed_machine() -> None:
    """The parser reads the numbers the dataclass fields declare (contract.schema), not a list of its own: each declared
    value set in range in config/sam.yaml (a boom with its load) arrives in the typed machine, where machine check accepts it."""
    import copy
    from dataclasses import fields

    import yaml

    from hydro_ros.contract.check import config_problems
    from hydro_ros.contract.machine import parse_machine
    from hydro_ros.contract.schema import GROUP, RULE, Cylinder, Excitation, Fluid, Friction, Load, Sensors, Simulation, Valve

    path = default_config_path("sam")
    config = yaml.safe_load(path.read_text())
    boom = next(iter(config["actuators"]))
    sections = ((Cylinder, ("actuators", boom, "cylinder"), lambda m: m.first.cylinder),
                (Valve, ("actuators", boom, "valve"), lambda m: m.first.valve), (Fluid, ("actuators", boom, "fluid"), lambda m: m.first.fluid),
                (Friction, ("actuators", boom, "friction"), lambda m: m.first.friction), (Load, ("actuators", boom, "load"), lambda m: m.first.load),
                (Sensors, ("sensors",), lambda m: m.sensors), (Simulation, ("simulation",), lambda m: m.simulation),
                (Excitation, ("excitation",), lambda m: m.excitation))
    read, crossed = [], []
    for declaration, keys, typed in sections:
        for item in fields(declaration):
            if RULE not in item.metadata or item.metadata[GROUP]:
                continue
            rule = item.metadata[RULE]
            changed = copy.deepcopy(config)
            node = changed
            for key in keys:
                node = node.setdefault(key, {})
            low = rule.low if rule.low is not None else -1.0
            high = rule.high if rule.high is not None else low + 10.0
            value = 7 if item.type == "int" else low + 0.37 * (high - low)
            node[item.name] = value
            if config_problems(changed):  # in range, but against another value of the file (a rod wider than its bore)
                crossed.append(f"{declaration.__name__}.{item.name}")
                continue
            assert getattr(typed(parse_machine(changed, path)), item.name) == pytest.approx(value), (declaration.__name__, item.name)
            read.append(f"{declaration.__name__}.{item.name}")
    assert crossed == ["Cylinder.rod_diameter", "Simulation.end_stop_upper"] and len(read) == 39, (crossed, read)


def test_the_units_the_shipped_configs_comment_are_the_ones_their_keys_declare() -> None:
    """A shipped config's "[unit]" comment beside a key says the unit the key's rule declares (contract.schema, check's
    tables): a hand-written comment cannot drift from the declaration machine check applies."""
    import re

    from hydro_ros.contract.check import keyed_lines, rules_for
    from hydro_ros.contract.config import config_dir

    compared, differ = 0, []
    for path in sorted(config_dir().glob("*.yaml")):
        for _, key, comment in keyed_lines(path.read_text()):
            written = re.match(r"\[([^\]]*)\]", comment)
            declared = {rule.unit or "-" for rule in rules_for(key)}
            if written and declared:
                compared += 1
                if written.group(1) not in declared:
                    differ.append(f"{path.name}: {key}: [{written.group(1)}], declared {' or '.join(sorted(declared))}")
    assert differ == [] and compared >= 50, (compared, differ)


def test_machine_new_writes_what_check_accepts_beside_each_declared_value(tmp_path) -> None:
    """`machine new` comments each value a rule declares with its unit and accepted range, from the declarations (not
    copied text), keeping the shipped comment's words; the values themselves are the shipped file's."""
    import yaml

    from hydro_ros.cli import main
    from hydro_ros.cli.machine import with_accepted_ranges
    from hydro_ros.contract.config import config_dir

    for path in sorted(config_dir().glob("*.yaml")):
        text = path.read_text()
        assert yaml.safe_load(with_accepted_ranges(text)) == yaml.safe_load(text), path.name
    out = tmp_path / "mine.yaml"
    assert main(["machine", "new", "--like", "boom_arm", "--out", str(out)]) == 0
    lines = out.read_text().splitlines()
    assert any(line.strip().startswith("piston_diameter: 0.100") and line.endswith("# [m; >= 0.005, <= 1] PLACEHOLDER: 100/56 cylinder")
               for line in lines), lines
    assert any(line.strip().startswith("substeps:") and "default 10" in line for line in lines) or "substeps" not in out.read_text()
    assert main(["machine", "check", str(out), "--quiet"]) == 0
