"""P-III: the MEMS motion sensor through the complementary filter, as a machine configuration."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.contract.config import ConfigError
from hydro_ros.contract.machine import load_machine_config
from hydro_ros.models.complementary import ComplementaryFilter
from hydro_ros.studies.fdi_evaluation import Case, run_case
from test.conftest import REPO

MEMS_CONFIG = REPO / "config" / "sam_mems.yaml"


def test_complementary_filter_removes_gyro_bias_and_follows_motion():
    rate_hz = 1000.0
    t = np.arange(0, 60, 1 / rate_hz)
    angle = 0.3 * np.sin(0.5 * t)
    rng = np.random.default_rng(1)
    inclination = angle + rng.normal(0, 4e-4, t.size)
    gyro = 0.15 * np.cos(0.5 * t) + 0.01  # constant 0.01 rad/s bias
    estimate, rate = ComplementaryFilter(2.0, 0.5, rate_hz)(inclination, gyro)
    settled = t > 20
    assert np.max(np.abs(estimate[settled] - angle[settled])) < np.radians(0.05)
    assert np.max(np.abs(rate[settled] - 0.15 * np.cos(0.5 * t[settled]))) < 1e-3  # bias learned
    with pytest.raises(ValueError, match="k_p"):
        ComplementaryFilter(0.0, 0.5, rate_hz)


def test_mems_config_extends_the_sam_and_raises_the_threshold():
    mems = load_machine_config(MEMS_CONFIG)
    assert mems.sensors.motion_sensor == "mems"
    assert mems.fdi["threshold_constant"] == pytest.approx(0.023)
    assert mems.actuator("boom").cylinder.piston_diameter == 0.080  # inherited


def test_config_that_extends_itself_fails_clearly(tmp_path):
    path = tmp_path / "loop.yaml"
    path.write_text("extends: loop.yaml\n")
    with pytest.raises(ConfigError, match="extends itself"):
        load_machine_config(path)
    (tmp_path / "a.yaml").write_text("extends: b.yaml\n")
    (tmp_path / "b.yaml").write_text("extends: a.yaml\n")
    with pytest.raises(ConfigError, match=r"b.yaml: extends a config that extends it \(a.yaml -> b.yaml -> a.yaml\)"):
        load_machine_config(tmp_path / "a.yaml")
    (tmp_path / "alias.yaml").write_text("machine: x\narm: &a {payload: [*a]}\n")
    with pytest.raises(ConfigError, match="a YAML alias contains itself"):
        load_machine_config(tmp_path / "alias.yaml")


@pytest.mark.parametrize(("fault", "value"), [(None, 0.0), ("external_leakage_b", 1.5), ("internal_leakage", 2.0)])
def test_mems_monitor_detects_leaks_and_stays_quiet_without(fault, value):
    outcome = run_case(load_machine_config(MEMS_CONFIG), Case(fault, value, seed=7, duration_s=50.0, mismatch=0.0))
    assert not outcome.early_alarm
    assert outcome.isolated == fault


@pytest.mark.slow
def test_p3_tables_the_mems_residuals_exceed_the_encoders_and_both_find_the_leaks():
    """P-III Table I's finding on plants that differ from the model: the MEMS sensor's fault-free residuals are larger
    than the encoder's in both chambers; both sensors detect P-III's two leaks (bench/mems.py has the tables)."""
    from hydro_ros.studies.mems import tables

    result = tables(seeds=3)
    for residual in ("pA", "pB"):
        assert result["table_1"]["mems"][residual] > result["table_1"]["encoder"][residual], result["table_1"]
    for fault, delays in result["delays_s"].items():
        for sensor in ("encoder", "mems"):
            assert delays[sensor]["detected"] >= 2 and delays[sensor]["early"] == 0, (fault, sensor, delays)
