"""Commissioning: the monitor's model identified from fault-free recordings of a plant that differs from it."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest
import yaml

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import NOTCHES, load_machine_config
from hydro_ros.contract.names import Injection
from hydro_ros.contract.samples import Samples
from hydro_ros.fdi.monitor import FdiMonitor
from hydro_ros.fdi.offline import run_monitor
from hydro_ros.fdi.parity import POINT_CHANNELS
from hydro_ros.fdi.settings import FdiSettings
from hydro_ros.models.identification import flow_regression
from hydro_ros.models.sam import SamModel
from hydro_ros.sim.scenario import Scenario, simulate
from hydro_ros.studies.commissioning import (
    PARITY_FLOOR,
    PARITY_FLOOR_L_MIN,
    PARITY_MARGIN,
    FaultFreeRecording,
    commission,
    evaluated_maximum,
    identify,
    threshold_excess,
)
from hydro_ros.studies.fdi_evaluation import calibrate_threshold_constant, mismatched_config
from test.conftest import REPO

# each notch off in its own direction, both moduli off, the centre leakage, friction and noise drawn too
NOTCH_FACTORS = {"PA": 1.045, "PB": 0.96, "AT": 1.035, "BT": 0.955}
PAYLOAD_STEPS = [Injection("payload_mass", 300.0, 30.0), Injection("payload_mass", -300.0, 80.0)]


def _plant(sam_config):
    drawn = mismatched_config(sam_config, seed=5)
    valve, fluid = drawn.first.valve, drawn.first.fluid
    return drawn.with_overrides({"actuators": {"boom": {
        "valve": {"kv_poly": {n: [c * NOTCH_FACTORS[n] for c in sam_config.first.valve.kv_poly[n]] for n in NOTCHES}},
        "fluid": {"oil_bulk_modulus": 0.78 * sam_config.first.fluid.oil_bulk_modulus,
                  "hose_bulk_modulus": 1.2 * sam_config.first.fluid.hose_bulk_modulus}}}}), valve, fluid


def _samples(machine, seed: int, duration: float, injections=()) -> Samples:
    return simulate(machine, Scenario(duration, list(injections), seed=seed))


@pytest.fixture(scope="module")
def commissioned(sam_config):
    plant, _, _ = _plant(sam_config)
    recordings = [FaultFreeRecording(f"run{seed}", _samples(plant, seed, 120.0)) for seed in (1, 2, 3)]
    block, report = commission(sam_config, recordings)
    return plant, block, report


def test_commissioning_recovers_each_notch_the_bulk_modulus_and_the_centre_leakage(sam_config, commissioned):
    plant, block, report = commissioned
    (ident,) = report["identification"]
    for notch, factor in NOTCH_FACTORS.items():
        assert ident["notch_gain"][notch] == pytest.approx(factor, rel=0.02), notch
    true_model = SamModel(plant)
    hose_volume = sam_config.first.fluid.hose_volume

    def compliance(oil: float, hose: float, volume: float) -> float:
        return 1.0 / oil + hose_volume / (volume * hose)

    for volume in (3e-4, 1.5e-3, 3e-3):  # retracted, mid-stroke, extended chamber volumes
        true = compliance(plant.first.fluid.oil_bulk_modulus, plant.first.fluid.hose_bulk_modulus, volume)
        assert compliance(ident["oil_bulk_modulus"], ident["hose_bulk_modulus"], volume) == pytest.approx(true, rel=0.1), volume
    for k, notch in enumerate(NOTCHES):
        assert ident["centre_leakage"][notch] == pytest.approx(true_model.centre_leakage[k], rel=0.1), notch
    assert ident["rms_error_l_min"]["commissioned"] < 0.5 * ident["rms_error_l_min"]["nominal"]
    # the threshold is sharper than the paper's, cross-validated across the three recordings, above the residual's noise
    c0 = block["model"]["fdi"]["threshold_constant"]
    threshold = report["threshold"]
    assert 0.0 < threshold["floor"] <= c0 < 0.012 and threshold["cross_validated"] == 3
    assert threshold["reached_left_out"] > threshold["reached"]  # judged by the others' model: further than by its own


@pytest.mark.slow
def test_the_commissioned_monitor_never_alarms_on_its_own_training_recordings(sam_config, commissioned):
    plant, block, _ = commissioned
    machine = sam_config.with_overrides(block["model"])
    for seed in (1, 2, 3):  # the recordings it was commissioned from, whole
        run = run_monitor(FdiMonitor(machine), _samples(plant, seed, 120.0))
        assert run.alarms == [], (seed, [a.to_json() for a in run.alarms])


@pytest.mark.slow
def test_outside_what_commissioning_saw_the_monitor_holds_and_never_alarms(sam_config, commissioned):
    plant, block, report = commissioned
    machine = sam_config.with_overrides(block["model"])
    seen = block["model"]["fdi"]["coverage"]["boom"]
    assert seen["valve_command"][1] <= 0.8 and seen["pressure_a"][0] < seen["pressure_a"][1]  # the operator's lever stops at 0.8
    # the same kind of work as the recordings: monitored nearly all the time
    usual = FdiMonitor(machine)
    assert run_monitor(usual, _samples(plant, 31, 120.0)).alarms == []
    assert usual.outside_held_samples[0] < 0.10 * usual.evaluated_samples
    # moves at full opening and 500 kg more than the recordings ever held: held there, never an alarm
    harder = FdiMonitor(machine)
    wider = plant.with_overrides({"excitation": {"max_command": 1.0, "move_speed": [0.2, 0.5]}})
    run = run_monitor(harder, _samples(wider, 32, 120.0, [Injection("payload_mass", 500.0, 20.0)]))
    assert run.alarms == [], [a.to_json() for a in run.alarms]
    assert harder.outside_held_samples[0] > 0.2 * harder.evaluated_samples and harder.outside(0)
    assert any("faster" in motion or "heavier" in motion for motion in block["record_next"]["boom"])


@pytest.mark.slow
def test_after_commissioning_a_small_leak_is_isolated_and_payload_steps_raise_no_alarm(sam_config, commissioned):
    plant, block, _ = commissioned
    machine = sam_config.with_overrides(block["model"])
    for seed in (11, 12):
        run = run_monitor(FdiMonitor(machine), _samples(plant, seed, 120.0, PAYLOAD_STEPS))
        assert run.alarms == [], (seed, [a.to_json() for a in run.alarms])
    # the shipped config stays silent through the same payload steps on its own plant
    run = run_monitor(FdiMonitor(sam_config), _samples(sam_config, 11, 120.0, PAYLOAD_STEPS))
    assert run.alarms == [], [a.to_json() for a in run.alarms]
    run = run_monitor(FdiMonitor(machine), _samples(plant, 21, 60.0, [Injection("external_leakage_b", 0.4, 20.0)]))
    named = [a for a in run.alarms if a.fault is not None and a.fault.value != "unisolated"]
    assert run.alarms and run.alarms[0].time_s > 20.0 and named and named[0].fault.value == "external_leakage_b"


@pytest.mark.slow
def test_mobile_valve_commissioning_fits_the_notches_from_the_pilot_pressures_and_p_iv_thresholds(sam_config):
    """The parity method's machine: spool from the pilot pressures, notches fed by the compensator; thresholds
    per operating point from the recordings, sharper on the whole than fdi-fit's from simulated plants, and
    still quiet through payload steps the recordings did not hold."""
    mobile = load_machine_config(REPO / "config" / "sam_mobile.yaml")
    plant, _, _ = _plant(mobile)
    block, report = commission(mobile, [FaultFreeRecording(f"run{seed}", _samples(plant, seed, 120.0)) for seed in (1, 2, 3)])
    (ident,) = report["identification"]
    for notch, factor in NOTCH_FACTORS.items():
        assert ident["notch_gain"][notch] == pytest.approx(factor, rel=0.02), notch
    assert ident["oil_bulk_modulus"] == pytest.approx(plant.first.fluid.oil_bulk_modulus, rel=0.1)
    fitted = block["model"]["fdi"]["parity_thresholds"]
    assert "threshold_constant" not in block["model"]["fdi"]
    assert np.all(np.asarray(fitted["factor"]) >= PARITY_MARGIN * np.asarray(report["threshold"]["reached"]))
    assert fitted["bins"] == "flow" and fitted["floor"] == PARITY_FLOOR_L_MIN
    # the closed-valve evidence from this machine's own rests: at least the margin over the held-out closed means' spread
    assert np.all(np.asarray(fitted["closed"]["factor"]) >= PARITY_MARGIN * PARITY_FLOOR) and np.all(np.asarray(fitted["closed"]["std"]) > 0)
    machine = mobile.with_overrides(block["model"])
    shipped, commissioned = (FdiSettings.from_machine(m).parity_thresholds for m in (mobile, machine))
    run = run_monitor(FdiMonitor(machine), _samples(plant, 11, 120.0, PAYLOAD_STEPS))
    assert run.alarms == [], [a.to_json() for a in run.alarms]
    worked = run.operating_point.reshape(-1, POINT_CHANNELS)[run.monitor.startup + run.monitor.window:]  # where this machine's work took it
    assert commissioned(worked).mean() < 0.8 * shipped(worked).mean()
    run = run_monitor(FdiMonitor(machine), _samples(plant, 21, 60.0, [Injection("external_leakage_a", 0.4, 20.0)]))
    named = [a for a in run.alarms if a.fault is not None and a.fault.value != "unisolated"]
    assert run.alarms and run.alarms[0].time_s > 20.0 and named and named[0].fault.value == "external_leakage_a"


def test_commissioning_refuses_a_leaking_machine_and_a_recording_without_retracting_moves(sam_config):
    plant, _, _ = _plant(sam_config)
    leaking = [FaultFreeRecording(f"leak{seed}", _samples(plant, seed, 90.0, [Injection("external_leakage_a", 0.5)])) for seed in (1, 2)]
    with pytest.raises(InputError, match=r"loses oil: external_leakage_a of 0\.[45]\d L/min"):
        commission(sam_config, leaking)
    samples = _samples(plant, 1, 90.0)
    samples.valve_command = np.maximum(samples.valve_command, 0.0)
    with pytest.raises(InputError, match=r"notch (PB|AT) was open 0\.0 s.*record retracting moves"):
        identify(SamModel(sam_config), flow_regression(SamModel(sam_config), samples), "extending only")


@pytest.mark.slow
def test_commission_cli_writes_a_config_the_monitor_loads_and_refuses_what_it_cannot_fit(sam_config, tmp_path):
    plant, _, _ = _plant(sam_config)
    plant_config = tmp_path / "plant.yaml"
    plant_config.write_text(yaml.safe_dump(plant.to_yaml_mapping()))
    bags = []
    for seed in (1, 2, 3):
        bag = tmp_path / f"run{seed}"
        done = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "sim", "--config", str(plant_config), "--duration", "120",
                               "--seed", str(seed), "--out", str(bag), "--quiet"], capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr
        bags += ["--bag", str(bag)]
    out = tmp_path / "machine.yaml"
    config = REPO / "config" / "sam.yaml"
    done = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "commission", *bags, "--config", str(config), "--out", str(out),
                           "--report", str(tmp_path / "report"), "--quiet"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    machine = load_machine_config(out)
    assert FdiMonitor(machine).settings.threshold_constant < 0.012
    assert machine.first.valve.kv_poly["PA"] != sam_config.first.valve.kv_poly["PA"]
    report = json.loads((tmp_path / "report" / "commissioning.json").read_text())
    assert report["block"]["recordings"] == [str(tmp_path / f"run{seed}") for seed in (1, 2, 3)]
    assert (tmp_path / "report" / "commissioning.png").stat().st_size > 10_000
    assert (tmp_path / "report" / "coverage.png").stat().st_size > 10_000

    other = tmp_path / "other.yaml"
    other.write_text(f"extends: {config}\nactuators:\n  boom:\n    joint: stick_joint\n")
    for name, variant in (("another layout", other), ("a mobile valve without pilot pressures", REPO / "config" / "sam_mobile.yaml")):
        refused = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "commission", *bags, "--config", str(variant),
                                  "--out", str(tmp_path / "refused.yaml"), "--quiet"], capture_output=True, text=True, timeout=120)
        assert refused.returncode == 1 and len(refused.stderr.strip().splitlines()) == 1, (name, refused.stderr)
        assert not (tmp_path / "refused.yaml").exists(), name


def test_live_commissioned_monitor_names_a_leak_the_shipped_threshold_cannot_see(sam_config, commissioned, ros_domain, tmp_path):
    """plant_sim runs the mismatched plant, fdi_node the config commissioned on it; a 0.5 L/min B leak
    (undetected at the shipped c0: docs/monitoring.md, evaluation) is injected through plant_sim's parameter."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.parameter import Parameter
    from rclpy.parameter_client import AsyncParameterClient

    from hydro_ros.studies.commissioning import write_config
    from test.ros_graph import node_process, probe_node, spin_until

    plant, block, _ = commissioned
    plant_config, machine_config = tmp_path / "plant.yaml", tmp_path / "machine.yaml"
    plant_config.write_text(yaml.safe_dump(plant.to_yaml_mapping()))
    write_config(REPO / "config" / "sam.yaml", machine_config, block)
    diags: list[DiagnosticArray] = []

    def statuses() -> list:
        return [s for m in diags for s in m.status if s.name == "hydro_ros/fdi/boom"]

    with node_process("hydro_ros.nodes.plant_sim", "-p", f"config:={plant_config}", "-p", "seed:=3", "-p", "real_time_factor:=1.0"), \
            node_process("hydro_ros.nodes.fdi_node", "-p", f"config:={machine_config}"), probe_node("probe") as node:
        node.create_subscription(DiagnosticArray, "/diagnostics", diags.append, 10)
        assert spin_until(node, lambda: any(s.message == "ok" for s in statuses()), 60), [s.message for s in statuses()]
        spin_until(node, lambda: False, 8.0)
        assert all(s.message in ("ok", "stale", "not_monitored", "overloaded") for s in statuses()), [s.message for s in statuses()]
        client = AsyncParameterClient(node, "plant_sim")
        assert client.wait_for_services(10.0)
        future = client.set_parameters([Parameter("fault.external_leakage_b", value=0.5)])
        assert spin_until(node, future.done, 10)
        assert spin_until(node, lambda: statuses()[-1].message == "external_leakage_b", 60), [s.message for s in statuses()[-5:]]
        assert statuses()[-1].level == bytes([1])


@pytest.mark.slow
def test_a_leak_that_begins_in_the_held_out_part_is_refused_never_learnt(sam_config):
    """The leak starts inside the last third, which only sets the threshold: refused by the held-out leak check, and a
    threshold above the config's safe one is refused unless forced."""
    plant, _, _ = _plant(sam_config)
    leaking = [FaultFreeRecording("leak_at_200", _samples(plant, 1, 300.0, [Injection("internal_leakage", 1.0, 200.0)]))]
    with pytest.raises(InputError, match="held-out part .*internal_leakage"):
        commission(sam_config, leaking)
    fault_free = [FaultFreeRecording(f"run{seed}", _samples(plant, seed, 120.0)) for seed in (1, 2)]
    strict = sam_config.with_overrides({"fdi": {"threshold_constant": 0.001}})  # a config whose own c0 is sharper than the data's
    with pytest.raises(InputError, match="c0 .* above the config's 0.0010 MPa.*--force"):
        commission(strict, fault_free)
    block, report = commission(strict, fault_free, force=True)
    assert block["threshold"]["forced"] and block["model"]["fdi"]["threshold_constant"] > 0.001


def test_long_recordings_give_rows_at_the_row_rate_and_the_blocks_do_not_change_the_fit(sam_config, monkeypatch):
    """A long recording is fitted from ROW_RATE_HZ rows per second, computed in blocks: memory that does not grow with
    the sample rate, and a fit the block edges do not move."""
    from hydro_ros.models import identification

    model = SamModel(sam_config)
    samples = _samples(sam_config, 4, 150.0)
    whole = flow_regression(model, samples)
    assert len(whole.flows) <= 2 * identification.ROW_RATE_HZ * whole.seconds + 2
    monkeypatch.setattr(identification, "BLOCK_S", 7.0)
    blocked = flow_regression(model, samples)
    assert blocked.seconds == pytest.approx(whole.seconds) and blocked.open_s == pytest.approx(whole.open_s, abs=0.01)
    assert len(blocked.flows) == pytest.approx(len(whole.flows), rel=0.01)
    gains = [identify(model, regression, "run4").notch_gain for regression in (whole, blocked)]
    for notch in NOTCHES:
        assert gains[0][notch] == pytest.approx(gains[1][notch], rel=2e-3), notch



def test_a_threshold_is_not_taken_from_data_the_monitor_never_evaluated(sam_config):
    """`machine threshold --duration 5` wrote threshold_constant 0.0: no armed window, no excess, a margin over nothing."""
    assert np.isnan(threshold_excess(FdiMonitor(sam_config), simulate(sam_config, Scenario(5.0, seed=1))))
    with pytest.raises(InputError, match=r"5 s of simulated data: too short for the monitor to evaluate"):
        calibrate_threshold_constant(sam_config, [1], 5.0)
    # a short recording beside long ones contributes nothing; only when none was evaluated is there no threshold
    assert evaluated_maximum([float("nan"), 0.02, 0.01], "held-out parts") == 0.02


@pytest.mark.slow
def test_a_leaky_recording_among_good_ones_is_refused_naming_it_and_its_chamber(sam_config):
    """Two fault-free recordings and one with a 1 L/min chamber-B leak from its start: the joint fit spreads the leak thin
    (it passed); the check of each recording on its own names the leaky one and the leak."""
    plant, _, _ = _plant(sam_config)
    recordings = [FaultFreeRecording(f"run{seed}", _samples(plant, seed, 120.0)) for seed in (1, 2)]
    recordings.append(FaultFreeRecording("leaky", _samples(plant, 3, 120.0, [Injection("external_leakage_b", 1.0)])))
    with pytest.raises(InputError, match=r"^leaky: actuator boom loses oil in this recording: external_leakage_b of"):
        commission(sam_config, recordings)
