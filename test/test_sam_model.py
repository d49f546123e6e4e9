"""The SAM plant model against physics: closed forms, conservation, convergence, injections."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Injection
from hydro_ros.models.chamber import effective_bulk_modulus, leak_coefficient
from hydro_ros.models.sam import Param, SamModel, SamPlant, valve_and_leak_flows
from hydro_ros.models.steady_state import extension_steady_pressures, hydraulic_natural_frequency

RETRACTED_JOINT = 0.728 - 1.6 + 0.005  # just off the retracted end stop (P-I GSA start, App. 2)


def _frictionless(machine: Machine) -> Machine:
    return machine.with_overrides(
        {"actuators": {"boom": {"friction": {"viscous": 0.0, "static": 0.0, "coulomb": 0.0, "bristle_stiffness": 0.0},
                                "valve": {"centre_leakage": {"PA": 0.0, "PB": 0.0, "AT": 0.0, "BT": 0.0}}}}},
    )


def _no_centre_leakage(machine: Machine) -> Machine:
    return machine.with_overrides({"actuators": {"boom": {"valve": {"centre_leakage": {"PA": 0.0, "PB": 0.0, "AT": 0.0, "BT": 0.0}}}}})


def test_leak_coefficient_matches_p1_calibration():
    # P-I: K = 5.27e-9 m^3/(s Pa^0.5) gives 1 L/min at 10 MPa (P-I Section 4.2, Table 5)
    assert leak_coefficient(1.0) == pytest.approx(5.27e-9, rel=2e-3)


def test_bulk_modulus_grows_with_extension(sam_config):
    model = SamModel(sam_config)
    p = model.base
    fluid = (p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], 0.0)
    retracted = effective_bulk_modulus(0.0, p[Param.V0_A], *fluid)
    extended = effective_bulk_modulus(0.0, p[Param.V0_A] + p[Param.AREA_A] * p[Param.STROKE], *fluid)
    # config/sam.yaml: ~0.42 GPa retracted, ~1.2 GPa extended, inside P-I's 300-1200 MPa
    assert 0.38e9 < retracted < 0.46e9
    assert 1.1e9 < extended < 1.25e9


def test_step_extension_reaches_analytic_steady_pressures(sam_config):
    """25 % extension step from retracted (P-I GSA set-up): eqs. (39, corrected) and (40)."""
    model = SamModel(sam_config)
    plant = SamPlant(model, initial_joint=RETRACTED_JOINT)
    plant.advance(500, commands=np.zeros(500))
    _, states, _ = plant.advance(4000, commands=np.full(4000, 0.25))
    window = states[-200:]
    p_a, p_b, spool, x, v = (window[:, i].mean() for i in (0, 1, 2, 4, 5))
    assert spool == pytest.approx(0.25, abs=1e-6)
    fric = sam_config.actuator("boom").friction
    # friction lumped into F_ext (P-I eq. (39)): sliding LuGre force = F_C + (F_S-F_C) e^-(v/vs)^2 + b v
    sliding = fric.coulomb + (fric.static - fric.coulomb) * np.exp(-(v / fric.stribeck_velocity) ** 2) + fric.viscous * v
    expected_a, expected_b = extension_steady_pressures(model, 0.25, model.load_force(x) + sliding)
    assert p_a == pytest.approx(expected_a, rel=0.01)
    assert p_b == pytest.approx(expected_b, rel=0.03, abs=2e4)
    # and the qualitative P-I statement: p_A ~ 7 MPa holds the load, p_B well below
    assert 5e6 < p_a < 9e6 and p_b < p_a


def test_halving_the_step_changes_the_result_little(sam_config):
    commands = np.concatenate([np.full(3000, 0.4), np.full(2000, -0.3), np.full(3000, 0.6), np.zeros(2000)])
    results = []
    for substeps in (10, 20):
        config = sam_config.with_overrides({"simulation": {"substeps": substeps}})
        plant = SamPlant(SamModel(config), initial_joint=-0.3)
        results.append(plant.advance(len(commands), commands=commands)[1])
    coarse, fine = results
    # stated tolerance (docs/monitoring.md): 1 kPa on pressures, 1 um on position over a 10 s manoeuvre
    assert np.max(np.abs(coarse[:, :2] - fine[:, :2])) < 1e3
    assert np.max(np.abs(coarse[:, 4] - fine[:, 4])) < 1e-6


def test_closed_spool_without_leakage_holds_pressure(sam_config):
    model = SamModel(_no_centre_leakage(sam_config))
    plant = SamPlant(model, initial_joint=0.2)
    plant.advance(2000, commands=np.zeros(2000))  # settle
    _, states, _ = plant.advance(10000, commands=np.zeros(10000))
    assert np.ptp(states[:, 0]) < 1e3 and np.ptp(states[:, 1]) < 1e3
    assert np.ptp(states[:, 4]) < 1e-6
    # the held pressures carry the load within the static friction band
    p = model.base
    force = states[-1, 0] * p[Param.AREA_A] - states[-1, 1] * p[Param.AREA_B]
    static = sam_config.actuator("boom").friction.static
    assert abs(force - model.load_force(states[-1, 4])) <= static


@pytest.mark.parametrize("off_balance", [-2500.0, 2500.0])
def test_bristle_state_carries_what_static_friction_holds(sam_config, off_balance):
    """Pressures off the load balance by less than the static friction: started with the bristle state
    that carries the difference the boom stays put; started with z = 0 it lurches (against the oil's stiffness)."""
    model = SamModel(_no_centre_leakage(sam_config))
    p = model.base
    x = model.piston_from_joint(0.2)
    p_b = 2.0e6
    p_a = (model.load_force(x) + off_balance + p_b * p[Param.AREA_B]) / p[Param.AREA_A]
    z = model.bristle_state(x, 0.0, p_a, p_b)
    assert z * p[Param.BRISTLE] == pytest.approx(off_balance)
    travel = {}
    for start in (z, 0.0):
        plant = SamPlant(model, initial_joint=0.2)
        plant.state[:] = [p_a, p_b, 0.0, 0.0, x, 0.0, start]
        _, states, _ = plant.advance(500, commands=np.zeros(500))
        travel[start] = np.ptp(states[:, 4])
    assert travel[z] < 1e-7 and travel[0.0] > 1e-5
    # beyond the static friction the bristles slip: the state saturates at F_S
    static = sam_config.actuator("boom").friction.static
    far = model.bristle_state(x, 0.0, p_a + np.sign(off_balance) * 1e7, p_b)
    assert far * p[Param.BRISTLE] == pytest.approx(np.sign(off_balance) * static)


def test_chamber_mass_balance(sam_config):
    """Oil that entered each chamber = its volume change + oil compressed: int Q dt = dV + int V/B dp."""
    model = SamModel(sam_config)
    injections = [Injection("internal_leakage", 0.8, 1.0), Injection("external_leakage_a", 0.5, 2.0)]
    plant = SamPlant(model, injections=injections, initial_joint=-0.2)
    commands = 0.5 * np.sin(np.linspace(0, 6 * np.pi, 6000))
    times, states, _ = plant.advance(len(commands), commands=commands)
    params = model.parameter_matrix(times, injections)
    flows = valve_and_leak_flows(states, params, model.poly, model.centre_leakage)
    dt = 1.0 / model.sample_rate
    p = model.base
    net_a = flows[:, 0] - flows[:, 2] - flows[:, 3]
    net_b = flows[:, 1] + flows[:, 2] - flows[:, 4]
    x, p_a, p_b = states[:, 4], states[:, 0], states[:, 1]
    vol_a = p[Param.V0_A] + p[Param.AREA_A] * x
    vol_b = p[Param.V0_B] + p[Param.AREA_B] * (p[Param.STROKE] - x)
    bulk_a = np.array([effective_bulk_modulus(pa, va, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], 0.0) for pa, va in zip(p_a, vol_a)])
    bulk_b = np.array([effective_bulk_modulus(pb, vb, p[Param.OIL_MODULUS], p[Param.HOSE_MODULUS], p[Param.HOSE_VOLUME], 0.0) for pb, vb in zip(p_b, vol_b)])
    for net, vol, bulk, pressure in ((net_a, vol_a, bulk_a, p_a), (net_b, vol_b, bulk_b, p_b)):
        inflow = np.trapezoid(net, dx=dt)
        stored = (vol[-1] - vol[0]) + np.trapezoid((vol / bulk)[1:] * np.diff(pressure) / dt, dx=dt)
        assert abs(inflow) > 1e-5  # the manoeuvre really moves oil
        # trapezoid on 1 kHz samples of a 10 kHz integration: 1 % of the oil moved
        assert stored == pytest.approx(inflow, rel=0.01, abs=2e-6)


@pytest.mark.parametrize("joint", [0.15, 0.4, 0.6])
def test_natural_frequency_matches_hydraulic_spring(sam_config, joint):
    """Free oscillation of the frictionless boom on its oil springs = Merritt's omega_h."""
    model = SamModel(_frictionless(sam_config))
    plant = SamPlant(model, initial_joint=joint)
    plant.state[0] += 2e5  # a pressure kick
    times, states, _ = plant.advance(3000, commands=np.zeros(3000))
    v = states[:, 5]
    crossings = times[1:][(v[:-1] < 0) & (v[1:] >= 0)]
    measured = 1.0 / np.mean(np.diff(crossings))
    x = states[:, 4].mean()
    analytic = hydraulic_natural_frequency(model, x, states[:, 0].mean(), states[:, 1].mean())
    assert measured == pytest.approx(analytic, rel=0.05)


def test_natural_frequency_within_seed_maximum_over_the_upper_stroke(sam_config):
    """P-I Section 2.1: <= 4.5 Hz. config/sam.yaml's INFERRED hose values meet it for x >= 0.32 m;
    towards full retraction the small chamber-A volume gives up to 6.3 Hz (docs/reproduction.md)."""
    model = SamModel(sam_config)
    upper = [hydraulic_natural_frequency(model, x) for x in np.linspace(0.32, 0.45, 14)]
    assert max(upper) <= 4.5
    lower = [hydraulic_natural_frequency(model, x) for x in np.linspace(0.0, 0.32, 9)]
    assert max(lower) < 6.5


def test_each_effect_form_acts_as_its_physics_says(sam_config):
    """names.EFFECT_FORMS in the model: a laminar leak flows as much as an orifice at 10 MPa and in proportion
    below it; a plain overlap opens 1 - overlap at full travel; a lag reaches 63 % after its time constant;
    Stribeck friction raises the breakaway level only."""
    from hydro_ros.models.valve import spool_opening

    def model(effect, value, form=None):
        forms = {"effect_forms": {effect: form}} if form else {}
        return SamModel(sam_config.with_overrides({"effects": {effect: value}, **forms}))

    state = np.array([[2.5e6, 1.0e7, 0.0, 0.0, 0.1, 0.0, 0.0]])  # p_A 2.5 MPa, p_B 10 MPa (over tank ~0)
    orifice, laminar = model("external_leakage_b", 1.0), model("external_leakage_b", 1.0, "laminar")
    flows = [valve_and_leak_flows(state, m.base[None, :], m.poly, m.centre_leakage)[0] * 60000.0 for m in (orifice, laminar)]
    tank = sam_config.tank_pressure
    assert flows[0][4] == pytest.approx(np.sqrt((1.0e7 - tank) / 1.0e7), rel=1e-9)
    assert flows[1][4] == pytest.approx((1.0e7 - tank) / 1.0e7, rel=1e-9)
    internal = model("internal_leakage", 1.0, "laminar")
    assert valve_and_leak_flows(state, internal.base[None, :], internal.poly, internal.centre_leakage)[0][2] * 60000.0 == pytest.approx(-0.75)

    assert spool_opening(1.0, 0.0, 0.1, 1.0, False) == pytest.approx(1.0)
    assert spool_opening(1.0, 0.0, 0.1, 1.0, False, False) == pytest.approx(0.9)
    assert spool_opening(0.5, 0.0, 0.1, 1.0, False, False) == pytest.approx(0.4)

    lagged, transported = SamPlant(model("valve_delay", 0.05, "lag")), SamPlant(model("valve_delay", 0.05))
    step = np.full(100, 0.3)
    spool_lag = lagged.advance(100, commands=step)[1][:, 2]
    spool_transport = transported.advance(100, commands=step)[1][:, 2]
    assert abs(spool_transport[40]) < 1e-6 < spool_lag[10]  # the lag starts at once, the transport after 50 ms
    assert 0.3 * 0.45 < spool_lag[49] < 0.3 * 0.7  # 1 - 1/e of the step after one time constant (the spool's own lag added)

    # a fault injected on top of an effect in another form keeps that form (the leak grows, still laminar)
    grown = laminar.parameter_matrix(np.array([0.0, 2.0]), [Injection("external_leakage_b", 1.0, onset_s=1.0)])
    grown_flows = valve_and_leak_flows(np.repeat(state, 2, axis=0), grown, laminar.poly, laminar.centre_leakage) * 60000.0
    assert grown_flows[1][4] == pytest.approx(2.0 * (1.0e7 - tank) / 1.0e7, rel=1e-9)

    nominal, stribeck, coulomb = SamModel(sam_config), model("coulomb_friction", 500.0, "stribeck"), model("coulomb_friction", 500.0)
    assert stribeck.base[Param.STATIC] == nominal.base[Param.STATIC] + 500.0 and stribeck.base[Param.COULOMB] == nominal.base[Param.COULOMB]
    assert coulomb.base[Param.COULOMB] == nominal.base[Param.COULOMB] + 500.0


@pytest.mark.parametrize(("forms", "message"), [({"valve_deadzone": "sticky"}, "effect_forms.valve_deadzone 'sticky': expected rescaled or overlap"),
                                                ({"payload_mass": "heavy"}, "effect_forms.payload_mass: no effect with forms")])
def test_an_unknown_effect_form_is_refused_by_name(sam_config, forms, message):
    from hydro_ros.contract.config import ConfigError

    with pytest.raises(ConfigError, match=message):
        sam_config.with_overrides({"effect_forms": forms})


def test_an_overlap_effect_holds_the_chambers_shut_where_a_configured_overlap_leaks(sam_config):
    """The centre leakage (P-I eqs. 13-14) acts where the valve's own lands leave under 1 % open: near the centre of the
    SAM's zero-lapped spool, across the neutral band of a mobile valve's configured overlap. An overlap the model adds
    as an effect closes the notches over more travel without leaking across it (it did: a boom held inside the band
    drifted in the model, and the discrepancy workflow's fit of the overlap fell below every resting command)."""
    from hydro_ros.contract.machine import load_machine_config
    from test.conftest import REPO

    def flows(model: SamModel, spool: float) -> np.ndarray:
        state = np.array([[8.0e6, 3.0e6, spool, 0.0, 0.2, 0.0, 0.0]])
        return valve_and_leak_flows(state, model.base[None, :], model.poly, model.centre_leakage)[0, :2]

    overlapped = SamModel(sam_config.with_overrides({"effects": {"valve_deadzone": 0.06}, "effect_forms": {"valve_deadzone": "overlap"}}))
    centre = flows(overlapped, 0.0)
    assert np.all(np.abs(centre) > 1e-6)  # ~1 L/min at these pressures
    assert np.array_equal(flows(overlapped, 0.005), centre) and np.array_equal(flows(overlapped, -0.005), centre)
    assert np.all(flows(overlapped, 0.03) == 0.0) and np.all(flows(overlapped, -0.059) == 0.0)
    mobile = SamModel(load_machine_config(REPO / "config" / "sam_mobile.yaml"))
    assert np.array_equal(flows(mobile, 0.1), flows(mobile, 0.0)) and np.all(np.abs(flows(mobile, 0.0)) > 0.0)
