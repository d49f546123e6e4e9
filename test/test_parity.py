"""P-IV-style parity FDI on the mobile-valve SAM (config/sam_mobile.yaml)."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.contract.machine import load_machine_config
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.parity import ParityGenerator
from hydro_ros.fdi.residuals import LastSamplesMean
from hydro_ros.models.sam import Param, SamModel
from hydro_ros.models.valve import pilot_drive
from hydro_ros.studies.fdi_evaluation import Case, _blocks, run_case
from test.conftest import REPO

MOBILE = REPO / "config" / "sam_mobile.yaml"


@pytest.fixture(scope="module")
def mobile():
    return load_machine_config(MOBILE)


def test_parity_residual_is_the_leak_flow(mobile):
    """Equation-error residual of chamber A = the flow leaving it that the model lacks [L/min]."""
    case = Case("external_leakage_a", 2.0, seed=1, onset_s=10.0, duration_s=30.0, mismatch=0.0)
    monitor = FdiMonitor(mobile, "parity")
    residual, leak = [], []
    for states, result in _blocks(mobile, case, monitor):
        residual.append(result.residual[:, 0, 0])
        leak.append(2.0 * np.sqrt(np.maximum(states[:, 0], 0.0) / 1e7) * (result.times >= 10.0))
    residual, leak = np.concatenate(residual), np.concatenate(leak)
    used = residual != 0.0  # masked samples (p_B near zero) are zeroed, as P-II does
    after = used & (np.arange(len(residual)) >= 12000)
    assert np.mean(leak[after]) > 1.5
    assert np.mean(residual[after]) == pytest.approx(np.mean(leak[after]), abs=0.15)
    assert np.mean(residual[used & (np.arange(len(residual)) < 10000)]) == pytest.approx(0.0, abs=0.1)  # before


def test_parity_needs_fitted_thresholds(mobile):
    bare = mobile.with_overrides({"fdi": {"parity_thresholds": None}})
    with pytest.raises(ValueError, match="fdi fit"):
        FdiMonitor(bare, "parity")


@pytest.mark.parametrize(
    ("fault", "value", "isolated"),
    [(None, 0.0, None), ("pressure_sensor_bias_a", 5e5, "pressure_sensor_bias_a"),
     ("pressure_sensor_bias_b", 5e5, "pressure_sensor_bias_b"), ("external_leakage_a", 2.0, "external_leakage_a"),
     # named by the closed-valve evidence: crossings while the spool is closed (their metering signs are shared)
     ("velocity_sensor_bias", 0.02, "velocity_sensor_bias"), ("internal_leakage", 2.0, "internal_leakage"),
     ("internal_leakage", 1.0, "internal_leakage"), ("pilot_pressure_sensor_bias", 3e5, "pilot_pressure_sensor_bias"),
     ("compensator_pressure_sensor_bias", 5e5, "compensator_pressure_sensor_bias"),
     # B is the meter-in chamber of a retraction, where a compensator bias adds what a leak out of B takes: named by
     # its crossing while closed (+0.26 L/min on this plant; seed 1 holds B near 0.1 MPa at rest, +0.02 L/min, unnamed)
     ("external_leakage_b", 2.0, "external_leakage_b"),
     # named by "Large": the valve passes none of its modelled flow
     ("main_spool_locking", 1.0, "main_spool_locking")],
)
def test_parity_on_mismatched_plants(mobile, fault, value, isolated):
    """Seeds 1 and 2 are neither training (100+) nor held-out (300+) plants of the fitted config."""
    outcome = run_case(mobile, Case(fault, value, seed=2, duration_s=60.0))
    assert not outcome.early_alarm
    if fault is None:
        assert outcome.crossing_episodes == 0
        return
    assert outcome.detected and outcome.delay_s < 20.0
    assert outcome.isolated == isolated


def _closed_mean_change(machine, fault: str | None, value: float) -> np.ndarray:
    """(A, B) change of the closed-valve mean residual [L/min] from the 10 s before a fault's onset (20 s) to its last 25 s,
    on a mismatched plant (seed 1)."""
    monitor = FdiMonitor(machine, "parity")
    means, times = [], []
    for _, result in _blocks(machine, Case(fault, value, seed=1, onset_s=20.0, duration_s=70.0), monitor):
        means.append(result.closed_mean[:, 0])
        times.append(result.times)
    mean, time = np.concatenate(means), np.concatenate(times)
    return np.nanmean(mean[time > 45.0], axis=0) - np.nanmean(mean[(time > 10.0) & (time < 20.0)], axis=0)


def test_closed_valve_evidence_follows_the_physics_of_each_fault(mobile):
    """With the spool closed, an internal leak takes from A what it gives to B (equal magnitudes), a velocity bias takes
    A_A b from A and gives A_B b to B (their ratio is the area ratio), while a compensator-pressure bias and a main-spool
    erosion, which act through the metering valve, leave the closed means within what the centre leakage's dependence on
    the compensator pressure moves (0.15 L/min, INFERRED from a 0.5 MPa bias on the 5-10 % laminar centre leakage)."""
    internal = _closed_mean_change(mobile, "internal_leakage", 2.0)
    assert internal[0] > 0.3 and internal[1] < -0.3
    assert -internal[0] / internal[1] == pytest.approx(1.0, rel=0.2)
    velocity = _closed_mean_change(mobile, "velocity_sensor_bias", 0.02)
    model = SamModel(mobile)
    assert velocity[0] < -0.3 and velocity[1] > 0.3
    assert -velocity[0] / velocity[1] == pytest.approx(model.base[Param.AREA_A] / model.base[Param.AREA_B], rel=0.2)
    for fault, value in ((None, 0.0), ("compensator_pressure_sensor_bias", 5e5), ("main_spool_erosion", 0.3)):
        assert np.all(np.abs(_closed_mean_change(mobile, fault, value)) < 0.15), fault


@pytest.mark.slow
def test_every_actuator_gets_its_own_evidence(mobile):
    """A second cylinder like the boom, with its own mismatch and operator: its internal leak and its velocity-sensor bias are
    named there (by the closed-valve evidence: their signs while metering are shared), and the boom raises nothing."""
    boom = mobile.to_yaml_mapping()["actuators"]["boom"]
    machine = mobile.with_overrides({"actuators": {"boom_2": {**boom, "joint": "boom_2_joint"}}})
    for fault, value in (("internal_leakage", 2.0), ("velocity_sensor_bias", 0.02)):
        # 120 s: this operator rests its valve 4 % of the time, so the 2 s of closed samples take a while
        outcome = run_case(machine, Case(fault, value, seed=2, duration_s=120.0, actuator="boom_2"))
        assert outcome.correct and not outcome.early_alarm, outcome


def test_closed_valve_mean_is_that_of_the_last_closed_samples_across_blocks():
    rng = np.random.default_rng(5)
    values, counted = rng.normal(size=(3000, 2)), rng.random((3000, 2)) < 0.1
    average = LastSamplesMean(40, 2)
    out = np.concatenate([average(values[i:i + 700], counted[i:i + 700]) for i in range(0, 3000, 700)])
    for c in range(2):
        index = np.flatnonzero(counted[:, c])
        for k in (index[38], index[39], index[200], 2999):
            last = index[index <= k][-40:]
            assert (np.isnan(out[k, c]) if len(last) < 40 else out[k, c] == pytest.approx(values[last, c].mean()))


def test_a_pilot_at_tank_read_by_a_transmitter_clipped_at_zero_does_not_shrink_the_opening(mobile):
    """One pilot acts, the other is at tank; its transmitter cannot read below zero, so it reports its noise rectified.
    Read as p_1 - p_2 that is a closing bias of 0.4 sigma on every opening; the drive takes such a reading as tank, while a
    real back pressure on both pilot lines still cancels."""
    model = SamModel(mobile)
    sigma, pilot_max = mobile.sensors.pilot_pressure_noise_std, model.base[Param.PILOT_MAX]
    rng = np.random.default_rng(3)
    acting = 0.4 * pilot_max + rng.normal(0.0, sigma, 100_000)
    at_tank = np.clip(rng.normal(0.0, sigma, 100_000), 0.0, None)
    assert np.mean((acting - at_tank) / pilot_max) < 0.4 - 0.3 * sigma / pilot_max  # the bias the drive must not have
    assert np.mean(pilot_drive(acting, at_tank, pilot_max, model.pilot_tank_band)) == pytest.approx(0.4, abs=0.02 * sigma / pilot_max)
    back = 3.0e5  # [Pa] a tank line's back pressure on both pilots, read with the transmitter's noise either side
    at_back = back + rng.normal(0.0, sigma, 100_000)
    assert np.mean(pilot_drive(acting + back, at_back, pilot_max, model.pilot_tank_band)) == pytest.approx(0.4, abs=0.02 * sigma / pilot_max)


def test_the_roots_noise_bias_bounds_a_stalled_notchs_misreading(mobile):
    """A compensator at its supply limit, the boom stalled under a load the pump cannot lift: the meter-in notch is open but
    its drop is zero, read by two transmitters with 0.1 MPa noise. The root reads flows of either sign, and their 5 s mean
    misses zero by more than a fitted threshold's spread; the curvature term that joins the thresholds covers it there and
    adds next to nothing where the notch meters on its regulated drop."""
    model = SamModel(mobile)
    sigma, n = mobile.sensors.pressure_noise_std, 5000
    rng = np.random.default_rng(7)

    def window(drop: float) -> tuple[float, float]:
        generator = ParityGenerator([model])
        column = np.ones((n, 1))
        supply = 10.0e6
        residual, _, _, bias, _ = generator.run(
            0.3 * column, 0.0 * column, supply - drop + rng.normal(0.0, sigma, (n, 1)), 1.0e6 + rng.normal(0.0, sigma, (n, 1)),
            0.8 * model.base[Param.PILOT_MAX] * column, 0.0 * column, supply + rng.normal(0.0, sigma, (n, 1)), column.astype(bool))
        return float(np.mean(residual[1000:, 0, 0])), float(np.mean(bias[1000:, 0, 0]))

    stalled = [window(0.0) for _ in range(8)]
    assert max(abs(r) for r, _ in stalled) > 0.05  # what the noise alone puts into a 5 s mean [L/min]
    assert all(abs(r) < b for r, b in stalled), stalled
    assert min(b for _, b in stalled) > 0.2
    assert window(mobile.actuators[0].valve.compensator_pressure_drop)[1] < 0.02


def test_the_monitor_keeps_the_latest_closed_valve_means_for_its_diagnostics(mobile):
    """fdi_node shows ``last_closed_mean`` beside ``closed_threshold``: filled once the valve rested closed 2 s, fault-free
    below the threshold; the UKF method has neither."""
    monitor = FdiMonitor(mobile)
    assert np.all(np.isnan(monitor.last_closed_mean))
    for _ in _blocks(mobile, Case(None, 0.0, seed=2, duration_s=10.0), monitor):
        pass
    assert np.all(np.isfinite(monitor.last_closed_mean))
    assert np.all(np.abs(monitor.last_closed_mean) < monitor.generator.closed_threshold)
    assert FdiMonitor(load_machine_config(REPO / "config" / "sam.yaml")).generator.closed_threshold is None
