"""Fault and effect names of the interface contract (docs/interface.md section 4).

One Enum each, so a misspelt name fails at the boundary with a clear message instead of
silently simulating a healthy machine.
"""

from __future__ import annotations

import enum
import math
import re
from dataclasses import dataclass

from hydro_ros.contract.errors import InputError


class Fault(str, enum.Enum):
    """FDI output names (docs/interface.md section 4)."""

    EXTERNAL_LEAKAGE_A = "external_leakage_a"
    EXTERNAL_LEAKAGE_B = "external_leakage_b"
    EXTERNAL_LEAKAGE_AB = "external_leakage_ab"
    INTERNAL_LEAKAGE = "internal_leakage"
    SPOOL_TOO_SMALL_OPENING = "spool_too_small_opening"
    SPOOL_TOO_LARGE_OPENING = "spool_too_large_opening"
    SPOOL_STUCK_CLOSED = "spool_stuck_closed"
    PRESSURE_SENSOR_BIAS_A = "pressure_sensor_bias_a"
    PRESSURE_SENSOR_BIAS_B = "pressure_sensor_bias_b"
    SUPPLY_PRESSURE_SENSOR_BIAS = "supply_pressure_sensor_bias"
    VELOCITY_SENSOR_BIAS = "velocity_sensor_bias"
    MAIN_SPOOL_LOCKING = "main_spool_locking"
    MAIN_SPOOL_EROSION = "main_spool_erosion"
    COMPENSATOR_SPOOL_LOCKING = "compensator_spool_locking"
    COMPENSATOR_SPOOL_EROSION = "compensator_spool_erosion"
    PILOT_PRESSURE_SPOOL_OFFSET = "pilot_pressure_spool_offset"
    PILOT_PRESSURE_SENSOR_BIAS = "pilot_pressure_sensor_bias"
    COMPENSATOR_PRESSURE_SENSOR_BIAS = "compensator_pressure_sensor_bias"
    UNISOLATED = "unisolated"


class Effect(str, enum.Enum):
    """Physical effects of the model-discrepancy vocabulary (docs/interface.md section 4)."""

    INTERNAL_LEAKAGE = "internal_leakage"
    EXTERNAL_LEAKAGE_A = "external_leakage_a"
    EXTERNAL_LEAKAGE_B = "external_leakage_b"
    VALVE_DEADZONE = "valve_deadzone"
    SPOOL_OFFSET = "spool_offset"
    VALVE_DELAY = "valve_delay"
    VALVE_FLOW_GAIN = "valve_flow_gain"
    ENTRAINED_AIR = "entrained_air"
    COULOMB_FRICTION = "coulomb_friction"
    VISCOUS_FRICTION = "viscous_friction"
    PAYLOAD_MASS = "payload_mass"
    PRESSURE_SENSOR_BIAS_A = "pressure_sensor_bias_a"
    PRESSURE_SENSOR_BIAS_B = "pressure_sensor_bias_b"


# What VALUE means in `--fault NAME=VALUE@T` / `--effect NAME=VALUE` and in the plant_sim
# `fault.<name>` / `effect.<name>` parameters. Leak sizes follow the thesis's own habit of
# quoting a leak as its flow at 10 MPa (P-I: "1 L/min at 10 MPa").
INJECTION_UNITS: dict[str, str] = {
    "external_leakage_a": "L/min at 10 MPa across the leak",
    "external_leakage_b": "L/min at 10 MPa across the leak",
    "external_leakage_ab": "L/min at 10 MPa, applied to both chambers",
    "internal_leakage": "L/min at 10 MPa across the piston",
    "spool_too_small_opening": "fractional loss of spool opening (0.3 = opens 70 %)",
    "spool_too_large_opening": "fractional gain of spool opening (0.3 = opens 130 %)",
    "spool_stuck_closed": "1 = stuck at centre, 0 = free",
    "spool_offset": "spool offset as a fraction of full travel (positive extends)",
    "valve_deadzone": "spool overlap as a fraction of full travel",
    "valve_delay": "s of transport delay on the valve command",
    "valve_flow_gain": "fractional change of all notch flows (0.2 = +20 %)",
    "entrained_air": "free-air volume fraction at atmospheric pressure",
    "coulomb_friction": "N added to the Coulomb and static friction",
    "viscous_friction": "N s/m added to the viscous friction",
    "payload_mass": "kg added at the load distance (an arm, a crane: at the tip)",
    "pressure_sensor_bias_a": "Pa added to the p_A reading",
    "pressure_sensor_bias_b": "Pa added to the p_B reading",
    "supply_pressure_sensor_bias": "Pa added to the supply-pressure reading",
    "velocity_sensor_bias": "rad/s added to the joint velocity reading",
    # pressure-compensated mobile valves (P-IV fault list; `valve.type: mobile` machines)
    "main_spool_locking": "1 = main spool locked at centre, 0 = free",
    "main_spool_erosion": "fractional increase of the metering flow (worn edges)",
    "compensator_spool_locking": "1 = compensator locked fully open (flow no longer compensated)",
    "compensator_spool_erosion": "fractional loss of the compensator's regulated pressure drop",
    "pilot_pressure_spool_offset": "main-spool offset against the pilot-pressure balance, fraction of travel",
    "pilot_pressure_sensor_bias": "Pa added to the pilot_pressure_1 reading",
    "compensator_pressure_sensor_bias": "Pa added to the compensator_pressure reading",
}

INJECTABLE = frozenset(INJECTION_UNITS)

# [low, high] a VALUE can have on a machine (None: unbounded); what lies outside is a typo or a wrong unit, not a fault
_FRACTION, _SIGNED_FRACTION, _NONNEGATIVE = (0.0, 1.0), (-1.0, 1.0), (0.0, None)
INJECTION_LIMITS: dict[str, tuple[float | None, float | None]] = {
    "external_leakage_a": _NONNEGATIVE, "external_leakage_b": _NONNEGATIVE, "external_leakage_ab": _NONNEGATIVE,
    "internal_leakage": _NONNEGATIVE, "spool_too_small_opening": _FRACTION, "spool_too_large_opening": _NONNEGATIVE,
    "spool_stuck_closed": _FRACTION, "spool_offset": _SIGNED_FRACTION, "valve_deadzone": (0.0, 0.95), "valve_delay": _NONNEGATIVE,
    "valve_flow_gain": (-1.0, None), "entrained_air": _FRACTION, "main_spool_locking": _FRACTION, "main_spool_erosion": _NONNEGATIVE,
    "compensator_spool_locking": _FRACTION, "compensator_spool_erosion": _FRACTION, "pilot_pressure_spool_offset": _SIGNED_FRACTION,
}


# The physical forms an effect of the vocabulary takes on a real machine; the first is the form a bare
# `effects:` entry has. A config picks another in `effect_forms:`, and `hydro-ros discrepancy` reports
# which form fits (the effect is named by its family, the contract name).
EFFECT_FORMS: dict[str, dict[str, str]] = {
    "valve_deadzone": {"rescaled": "overlap, the rest of the travel rescaled so full travel opens fully",
                       "overlap": "plain overlap: the opening is the travel beyond it, full travel opens 1 - overlap"},
    "internal_leakage": {"orifice": "flow with the square root of the pressure drop", "laminar": "flow in proportion to the drop"},
    "external_leakage_a": {"orifice": "flow with the square root of the pressure drop", "laminar": "flow in proportion to the drop"},
    "external_leakage_b": {"orifice": "flow with the square root of the pressure drop", "laminar": "flow in proportion to the drop"},
    "valve_delay": {"transport": "the command arrives VALUE s late", "lag": "first-order lag of time constant VALUE s"},
    "coulomb_friction": {"coulomb": "sliding and breakaway friction both rise by VALUE",
                         "stribeck": "breakaway friction rises by VALUE and fades above the Stribeck velocity"},
}


def first_form(effect: str) -> str | None:
    """The form a bare ``effects:`` entry has; None for an effect with one form."""
    return next(iter(EFFECT_FORMS[effect])) if effect in EFFECT_FORMS else None


@dataclass(frozen=True)
class Injection:
    """One fault or effect switched on at ``onset_s``, reaching ``value`` after ``ramp_s``."""

    name: str
    value: float
    onset_s: float = 0.0
    ramp_s: float = 0.0

    def __post_init__(self) -> None:
        if self.name not in INJECTABLE:
            raise InputError(
                f"unknown fault or effect {self.name!r}; known: {', '.join(sorted(INJECTABLE))}"
            )
        if not (self.onset_s >= 0.0 and self.ramp_s >= 0.0):
            raise InputError(f"{self.name}: onset and ramp must be >= 0 s")
        if not math.isfinite(self.value):
            raise InputError(f"{self.name}: value {self.value} is not finite")
        low, high = INJECTION_LIMITS.get(self.name, (None, None))
        if (low is not None and self.value < low) or (high is not None and self.value > high):
            bounds = f"within [{low:g}, {high:g}]" if low is not None and high is not None else f">= {low:g}"
            raise InputError(f"{self.name} = {self.value:g}: must be {bounds} ({INJECTION_UNITS[self.name]})")

    def level(self, t: float) -> float:
        """Injected value at time ``t`` [s]."""
        if t < self.onset_s:
            return 0.0
        if self.ramp_s > 0.0 and t < self.onset_s + self.ramp_s:
            return self.value * (t - self.onset_s) / self.ramp_s
        return self.value


_SPEC = re.compile(
    r"^(?P<name>[a-z_]+)=(?P<value>[-+0-9.eE]+)(?:@(?P<onset>[0-9.eE+]+)(?::(?P<ramp>[0-9.eE+]+))?)?$"
)


def parse_injection(text: str) -> Injection:
    """Parse ``NAME=VALUE[@T[:RAMP]]``; RAMP (s) makes the fault develop linearly from T."""
    match = _SPEC.match(text.strip())
    if match is None:
        raise InputError(f"cannot parse {text!r}: expected NAME=VALUE[@T[:RAMP]], e.g. internal_leakage=0.5@20")
    try:
        return Injection(
            name=match["name"],
            value=float(match["value"]),
            onset_s=float(match["onset"] or 0.0),
            ramp_s=float(match["ramp"] or 0.0),
        )
    except ValueError as exc:
        raise InputError(f"{text!r}: {exc}") from None
