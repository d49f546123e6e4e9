"""False-alarm rates with their exact Poisson (Garwood) two-sided 95 % interval, for every figure the docs quote.

A count of alarms over a few monitored hours says little on its own ("0 in 0.37 h" allows up to 10 per hour); the
interval says how much. Two-sided, so that ``low`` and ``high`` together hold the rate with 95 %: for 0 events ``high``
is then a 97.5 % one-sided bound (3.689 events, not 2.996), the stricter of the two usual statements.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from numbers import Integral, Real

from scipy.stats import chi2

from hydro_ros.contract.errors import InputError

CONFIDENCE = 0.95  # two-sided: 2.5 % of the probability beyond each bound
INTERVAL = "95 % exact Poisson interval"  # how a rate's interval is named wherever the docs quote one


def false_alarm_rate(events: int, hours: float) -> tuple[float, float, float]:
    """[1/h] the rate of ``events`` in ``hours`` of monitoring and the ends of its exact Poisson (Garwood) two-sided
    CONFIDENCE interval: ``(rate, low, high)``, ``low`` 0 for no event."""
    if isinstance(events, bool) or not isinstance(events, Integral) or events < 0:
        raise InputError(f"false_alarm_rate: events must be a count (an int >= 0), got {events!r}")
    if not isinstance(hours, Real) or not math.isfinite(hours) or hours <= 0.0:
        raise InputError(f"false_alarm_rate: hours must be finite and > 0, got {hours!r}")
    tail = (1.0 - CONFIDENCE) / 2.0
    low = float(chi2.ppf(tail, 2 * events)) / (2.0 * hours) if events else 0.0
    high = float(chi2.ppf(1.0 - tail, 2 * events + 2)) / (2.0 * hours)
    return float(events / hours), low, high


def _two_digits(value: float, outward: Callable[[float], float] = round) -> str:
    """Two significant digits, never in exponent form (1140, not 1.1e+03); ``outward`` (math.floor, math.ceil) rounds a
    bound away from the rate, so that the interval printed still holds the one computed."""
    if value == 0.0:
        return "0"
    decimals = max(0, 1 - math.floor(math.log10(abs(value))))
    return f"{outward(value * 10 ** decimals) / 10 ** decimals:.{decimals}f}"


def false_alarm_text(events: int, hours: float, what: str = "false alarm") -> str:
    """``events`` in ``hours`` as the docs quote it: "0 false alarms in 0.37 h (<= 9.9 per hour, 95 % exact Poisson
    interval)", or with a count the rate and both ends: "6 ... (11 per hour, 4.1-24, ...)"."""
    rate, low, high = false_alarm_rate(events, hours)
    count = f"{events} {what}{'' if events == 1 else 's'} in {hours:.2f} h"
    if not events:
        return f"{count} (<= {_two_digits(high, math.ceil)} per hour, {INTERVAL})"
    return (f"{count} ({_two_digits(rate)} per hour, {_two_digits(low, math.floor)}-{_two_digits(high, math.ceil)}, "
            f"{INTERVAL})")
