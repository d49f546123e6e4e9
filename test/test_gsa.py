"""P-I GSA: Sobol' indices of the SAM model reproduce the paper's qualitative findings."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from hydro_ros.studies.gsa import LEAKS, PARAMETERS, TIMES, run_once, sobol_indices
from test.conftest import SAM_CONFIG

# Sobol' sampling of the SAM model: tens of seconds; make test runs it, make test-fast does not
pytestmark = pytest.mark.slow

NOTCH = ("q_n_pa", "dp_n_pa", "q_n_bt", "dp_n_bt")


@pytest.fixture(scope="module")
def parameters(sam_config):
    return sobol_indices(sam_config, PARAMETERS, samples=64, workers=2, resamples=100)


def test_run_once_is_the_step_response(sam_config):
    nominal = {"q_n_pa": 4e-4, "dp_n_pa": 3.5e6, "q_n_bt": 4e-4, "dp_n_bt": 3.5e6, "bulk_modulus": 8e8, "viscous": 2500.0, "offset": 0.0}
    out = run_once(sam_config, nominal).reshape(3, len(TIMES))
    p_a, p_b, v = out
    assert np.all(v[3:] > 0.0)  # extending after the step
    assert 5e6 < p_a[-1] < 1e7 and p_b[-1] < p_a[-1]
    slower = run_once(sam_config, {**nominal, "q_n_pa": 2.5e-4}).reshape(3, len(TIMES))
    assert slower[2, -1] < v[-1]  # a smaller supply notch moves the piston slower


def test_notch_parameters_dominate_and_friction_is_negligible(parameters):
    for output in ("p_a", "p_b", "velocity"):
        steady = parameters["indices"][output]["4"]
        assert sum(steady[name]["ST"] for name in NOTCH) > 0.7, output  # P-I: flow coefficients first
        for instant, table in parameters["indices"][output].items():
            assert table["viscous"]["ST"] < 0.05, (output, instant)  # P-I: b negligible throughout


def test_bulk_modulus_matters_only_in_the_transient(parameters):
    p_a = parameters["indices"]["p_a"]
    early = max(p_a[t]["bulk_modulus"]["ST"] for t in ("0.05", "0.1", "0.2"))
    assert early > 0.05 and p_a["4"]["bulk_modulus"]["ST"] < early / 2


def test_leak_indices_rank_internal_leakage_first_for_velocity(sam_config):
    leaks = sobol_indices(sam_config, LEAKS, samples=64, workers=2, resamples=100)
    steady = leaks["indices"]["velocity"]["4"]
    assert max(steady, key=lambda name: steady[name]["ST"]) == "k_int"  # P-I Table 6
    p_b = leaks["indices"]["p_b"]["4"]
    assert max(p_b, key=lambda name: p_b[name]["ST"]) == "k_ext_a"  # P-I Table 6


def test_gsa_cli_writes_json_and_plot(tmp_path):
    out = tmp_path / "gsa.json"
    result = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "gsa", "--config", str(SAM_CONFIG), "--samples", "8",
                             "--out", str(out), "--quiet"], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    report = json.loads(out.read_text())
    assert set(report["parameters"]["ranking_4s"]) == {"p_a", "p_b", "velocity"}
    assert report["leakages"]["runs"] == 8 * 5 and out.with_suffix(".png").stat().st_size > 10000
    bad = subprocess.run([sys.executable, "-m", "hydro_ros.cli", "gsa", "--config", str(SAM_CONFIG), "--samples", "100",
                          "--out", str(out)], capture_output=True, text=True, timeout=60)
    assert bad.returncode == 1 and "power of two" in bad.stderr
