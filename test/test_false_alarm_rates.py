"""False-alarm rates and their exact Poisson interval (hydro_ros.fdi.rates): the numbers the docs quote."""

import math
from itertools import pairwise

import numpy as np
import pytest
from scipy.stats import chi2

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.rates import false_alarm_rate, false_alarm_text


def test_no_event_in_one_hour_bounds_the_rate_by_the_two_sided_garwood_value_not_the_one_sided():
    rate, low, high = false_alarm_rate(0, 1.0)
    assert (rate, low) == (0.0, 0.0)
    assert high == pytest.approx(3.689, abs=1e-3)
    assert chi2.ppf(0.95, 2) / 2.0 == pytest.approx(2.996, abs=1e-3)  # the one-sided 95 % bound the docs do not use


def test_the_interval_scales_with_the_hours_and_holds_the_rate():
    rate, low, high = false_alarm_rate(6, 0.5)
    assert rate == 12.0
    assert low == pytest.approx(chi2.ppf(0.025, 12) / 1.0) and high == pytest.approx(chi2.ppf(0.975, 14) / 1.0)
    assert 0.0 < low < rate < high
    assert false_alarm_rate(6, 1.0)[2] == pytest.approx(high / 2.0)


def test_both_ends_grow_with_the_count():
    intervals = [false_alarm_rate(k, 0.37) for k in range(30)]
    for (_, low, high), (_, next_low, next_high) in pairwise(intervals):
        assert next_low > low and next_high > high


@pytest.mark.parametrize(("events", "hours", "message"), [
    (-1, 1.0, "events must be a count"), (1.5, 1.0, "events must be a count"), (True, 1.0, "events must be a count"),
    (0, 0.0, "hours must be finite and > 0"), (0, -0.5, "hours must be finite and > 0"),
    (0, math.inf, "hours must be finite and > 0"), (0, math.nan, "hours must be finite and > 0")])
def test_a_count_or_an_exposure_that_is_not_one_is_refused_in_one_line(events, hours, message):
    with pytest.raises(InputError, match=message) as refused:
        false_alarm_rate(events, hours)
    assert "\n" not in str(refused.value)


def test_the_printed_bounds_round_away_from_the_rate():
    assert false_alarm_text(0, 0.801) == "0 false alarms in 0.80 h (<= 4.7 per hour, 95 % exact Poisson interval)"
    assert false_alarm_text(6, 0.534) == "6 false alarms in 0.53 h (11 per hour, 4.1-25, 95 % exact Poisson interval)"
    assert false_alarm_text(1, 1.0, "alarm").startswith("1 alarm in 1.00 h (1.0 per hour, 0.025-5.6,")


def test_counts_and_hours_summed_with_numpy_are_taken():
    assert false_alarm_rate(np.int64(4), np.float64(0.25)) == pytest.approx(false_alarm_rate(4, 0.25))


def test_a_leak_run_is_detected_only_when_every_alarm_is_its_own_and_named_only_when_no_other_name_came():
    from hydro_ros.studies.fdi_evaluation import leak_run_verdict, smallest_leaks

    def alarm(t: float, actuator: str, fault: str) -> dict:
        return {"time_s": t, "actuator": actuator, "fault": fault, "code": "1000"}

    onset = 20.0
    assert leak_run_verdict([alarm(21.0, "lift", "unisolated"), alarm(23.5, "lift", "external_leakage_a")], "lift",
                            "external_leakage_a", onset) == (1.0, 3.5)
    assert leak_run_verdict([alarm(21.0, "lift", "external_leakage_b")], "lift", "external_leakage_a", onset) == (1.0, None)
    assert leak_run_verdict([alarm(21.0, "lift", "external_leakage_b"), alarm(22.0, "lift", "external_leakage_a")], "lift",
                            "external_leakage_a", onset) == (1.0, None)  # another name came first
    assert leak_run_verdict([alarm(21.0, "lift", "external_leakage_a"), alarm(22.0, "lift", "internal_leakage")], "lift",
                            "external_leakage_a", onset) == (1.0, None)  # another name came after
    assert leak_run_verdict([alarm(19.0, "lift", "unisolated"), alarm(22.0, "lift", "external_leakage_a")], "lift",
                            "external_leakage_a", onset) == (None, None)  # an alarm before onset
    assert leak_run_verdict([alarm(22.0, "tilt", "unisolated"), alarm(22.0, "lift", "external_leakage_a")], "lift",
                            "external_leakage_a", onset) == (None, None)  # an alarm on another cylinder
    assert leak_run_verdict([], "lift", "external_leakage_a", onset) == (None, None)
    runs = [{"faults": [["lift", "external_leakage_a", size, onset]], "alarms": alarms}
            for size, alarms in ((0.5, []), (1.0, [alarm(25.0, "lift", "unisolated")]), (2.0, [alarm(22.0, "lift", "external_leakage_a")]))]
    found = smallest_leaks(runs, ["lift"], ["external_leakage_a", "internal_leakage"], onset, lambda run: run["alarms"])
    assert found["lift/external_leakage_a"] == {"named_l_min": 2.0, "delay_s": 2.0, "detected_l_min": 1.0}
    assert found["lift/internal_leakage"] == {"named_l_min": None, "delay_s": None, "detected_l_min": None}
