"""What commissioning saw of each actuator, and whether the machine now works outside it.

A commissioned model and threshold are known only where the recordings took them: the valve openings in each
direction and the chamber pressures (the load) they held. Outside that region the residual carries what the
identification could not see (a notch extrapolated past its widest opening, a load the threshold never met), and a
two-joint arm commissioned from 2 x 120 s false-alarmed exactly there (issue 50). So commissioning writes the region
(``fdi.coverage``: per actuator the range of the valve command and of each chamber's pressure over every recording),
and the monitor holds detection for an actuator (never an alarm) while its 5 s window holds a valve command beyond the
openings seen (not widened: COMMAND_MARGIN); it monitors again a whole window after the last such sample (hysteresis). The
chamber pressures are recorded and said (what loads to record next) but never hold: a leak moves its chamber's
pressure, and a hold on pressure hid the very leak it should name (a commissioned excavator held 51-75 % of a fresh
run and never named a 1 L/min leak).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from hydro_ros.contract.errors import InputError

QUANTITIES = ("valve_command", "pressure_a", "pressure_b")  # recorded; only the valve command holds
PERCENTILES = (0.0, 100.0)  # the widest openings seen: a valve command is not noisy
# [-] of the valve command beyond what was seen: none. At 0.05 a SAM built apart from the model (studies/independent_arm)
# false-alarmed at openings 0.02-0.04 beyond those its commissioning saw (the notch's table between its points is where
# it parts most from the fitted polynomial): the identified notches are not extrapolated at all
COMMAND_MARGIN = 0.0


@dataclass(frozen=True)
class Coverage:
    """Per actuator and quantity the (low, high) range commissioning saw [-, Pa]."""

    ranges: Mapping[str, Mapping[str, tuple[float, float]]]

    @classmethod
    def seen(cls, actuators: Sequence[str], recordings: Sequence[Any]) -> Coverage:
        """The region of Samples ``recordings`` ((n, A) columns in ``actuators`` order), valid samples only."""
        ranges: dict[str, dict[str, tuple[float, float]]] = {}
        for index, actuator in enumerate(actuators):
            ranges[actuator] = {}
            for quantity in QUANTITIES:
                values = np.concatenate([np.asarray(getattr(r, quantity), dtype=float).reshape(len(r), -1)[:, index] for r in recordings])
                values = values[np.isfinite(values)]
                if not values.size:
                    raise InputError(f"commission: actuator {actuator}: no finite {quantity} in the recordings")
                low, high = np.percentile(values, PERCENTILES)
                ranges[actuator][quantity] = (float(low), float(high))
        return cls(ranges)

    @classmethod
    def from_config(cls, section: Any) -> Coverage | None:
        if section is None:
            return None
        try:
            ranges = {str(a): {q: (float(entry[q][0]), float(entry[q][1])) for q in QUANTITIES} for a, entry in dict(section).items()}
        except (KeyError, TypeError, ValueError, IndexError) as exc:
            raise InputError(f"fdi.coverage: expected per actuator {', '.join(QUANTITIES)} as [low, high] ({exc})") from None
        for actuator, entry in ranges.items():
            for quantity, (low, high) in entry.items():
                if not (np.isfinite(low) and np.isfinite(high) and low <= high):
                    raise InputError(f"fdi.coverage.{actuator}.{quantity}: [{low:g}, {high:g}] is not a range")
        return cls(ranges)

    def to_config(self) -> dict[str, dict[str, list[float]]]:
        return {a: {q: [float(v) for v in r] for q, r in entry.items()} for a, entry in self.ranges.items()}

    def outside(self, actuator: str, command: np.ndarray) -> tuple[np.ndarray, str]:
        """Which samples of the valve ``command`` lie beyond the openings seen (widened by COMMAND_MARGIN), and why the
        last of them does ("" if none): the identified notches are not extrapolated."""
        low, high = self.ranges[actuator]["valve_command"]
        series = np.asarray(command, dtype=float)
        beyond = (series < low - COMMAND_MARGIN) | (series > high + COMMAND_MARGIN)
        if not beyond.any():
            return beyond, ""
        last = series[np.flatnonzero(beyond)[-1]]
        return beyond, f"valve_command {last:.2f} outside the commissioned {low:.2f}..{high:.2f}"

    def advice(self, actuator: str, supply_pressure: float) -> list[str]:
        """The motions to record so the monitor covers more of the machine's work (its valve's full stroke, its
        chambers up to the supply)."""
        entry = self.ranges[actuator]
        (c_low, c_high), (_a_low, a_high), (_b_low, b_high) = (entry[q] for q in QUANTITIES)
        out = []
        if c_high < 0.9:
            out.append(f"extending faster (valve openings above {c_high:.2f} were not seen)")
        if c_low > -0.9:
            out.append(f"retracting faster (valve openings below {c_low:.2f} were not seen)")
        if max(a_high, b_high) < 0.8 * supply_pressure:
            out.append(f"heavier loads (chamber pressures above {max(a_high, b_high) * 1e-6:.1f} MPa of the "
                       f"{supply_pressure * 1e-6:.0f} MPa supply were not seen)")
        return out
