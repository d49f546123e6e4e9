"""The ``fdi:`` section of a machine config, typed (defaults = P-II; see config/sam.yaml)."""

from __future__ import annotations

from dataclasses import dataclass, field

from hydro_ros.contract.errors import InputError
from hydro_ros.contract.machine import Machine
from hydro_ros.contract.names import Fault
from hydro_ros.fdi.coverage import Coverage
from hydro_ros.fdi.isolation import PatternRow, signature_rows
from hydro_ros.fdi.parity import ParityThresholds
from hydro_ros.fdi.ukf import UkfSettings

DEFAULT_SEVERE = (
    Fault.SPOOL_TOO_SMALL_OPENING,
    Fault.SPOOL_TOO_LARGE_OPENING,
    Fault.SPOOL_STUCK_CLOSED,
    Fault.MAIN_SPOOL_LOCKING,
    Fault.COMPENSATOR_SPOOL_LOCKING,
)


@dataclass(frozen=True)
class FdiSettings:
    """The ``fdi:`` section of a machine config (defaults = P-II; see config/sam.yaml)."""

    method: str = "ukf"  # a residual generator of hydro_ros.fdi.residuals.GENERATORS
    window_s: float = 5.0
    threshold_constant: float = 0.012  # [MPa] c0 of eq. (25); P-III: 0.015 encoder, 0.023 MEMS
    threshold_quadratic: float = 4.0e-4  # [1/MPa] c2 of eq. (25)
    residual: str = "posterior"  # which estimate p_hat is: a-posteriori (default) or a-priori
    mask_pressure: float = 2.0e5  # [Pa] residuals zeroed while a chamber is below this: P-II's p_B "close to zero" of a
    # lowered boom, and the p_A of a cylinder that pulls (a crane's tilt); the chamber law changes at cavitation. The UKF's
    # two residuals come from one filter, so both go; the parity method's are one equation per chamber, so only that one
    mask_retracted: float = 2.0e-3  # [m] ... or while the piston is within this of full retraction (P-III)
    mask_average_s: float = 0.05  # [s] the chambers are averaged this long for the mask: 0.1 MPa sensor noise around a
    # cavitating chamber otherwise lets every twentieth sample through, and those read the clipped transmitter (INFERRED)
    startup_s: float = 1.0  # [s] residuals after a start or restart are left out this long while the filter
    # forgets its initial state; detection arms one window after that (INFERRED)
    large_residual: float = 1.0  # [MPa] "Large" of Table 3: both |mean residuals| above this (INFERRED, tuned in
    # simulation: a spool stuck closed gives 1.5-1.8 MPa, a 40 % too small opening < 0.8 MPa, leaks < 0.2 MPa)
    settle_s: float = 1.0  # [s] a crossing pattern must hold this long before it narrows the cause
    command_deadband: float = 0.005  # |5 s mean valve command| below this leaves the command sign unknown
    stale_timeout_s: float = 0.2  # [s] a sensor silent this long makes the actuator STALE
    severe_faults: tuple[Fault, ...] = DEFAULT_SEVERE
    ukf: UkfSettings = field(default_factory=UkfSettings)
    parity_thresholds: ParityThresholds | None = None  # fitted by `fdi fit` on fault-free data
    parity_signatures: tuple[PatternRow, ...] = ()  # built by simulation (`fdi fit`)
    coverage: Coverage | None = None  # what commissioning saw: outside it detection holds (hydro_ros.fdi.coverage)

    @classmethod
    def from_machine(cls, machine: Machine) -> FdiSettings:
        """The machine's ``fdi:`` section typed; a bad key or value is refused with its name."""
        section = dict(machine.fdi)
        ukf = UkfSettings.from_config(section.pop("ukf", None))
        severe = section.pop("severe_faults", None)
        thresholds = ParityThresholds.from_config(section.pop("parity_thresholds", None))
        signatures = signature_rows(section.pop("parity_signatures", None) or [])
        coverage = Coverage.from_config(section.pop("coverage", None))
        unknown = [name for name in section if name not in cls.__dataclass_fields__]
        if unknown:
            raise InputError(f"fdi: unknown key(s) {', '.join(sorted(unknown))}")
        if severe is not None:
            try:
                section["severe_faults"] = tuple(Fault(name) for name in severe)
            except ValueError as exc:
                raise InputError(f"fdi.severe_faults: {exc}") from None
        settings = cls(ukf=ukf, parity_thresholds=thresholds, parity_signatures=signatures, coverage=coverage, **section)
        if coverage is not None and set(coverage.ranges) != set(machine.actuator_names):
            raise InputError(f"fdi.coverage: describes {', '.join(sorted(coverage.ranges))}, the machine has "
                             f"{', '.join(machine.actuator_names)}: commission again")
        if settings.residual not in ("posterior", "prior"):
            raise InputError(f"fdi.residual {settings.residual!r}: expected posterior or prior")
        return settings


def unset_threshold(machine: Machine) -> str | None:
    """Why a UKF monitor of ``machine`` would run on a threshold nobody chose for it, or None."""
    if FdiSettings.from_machine(machine).method != "ukf" or "threshold_constant" in machine.fdi:
        return None
    return (f"fdi.threshold_constant: not set: the monitor uses P-II's {FdiSettings.threshold_constant:g} MPa, fitted to P-II's own "
            f"identified rig, and will raise false alarms on another machine; derive this machine's with "
            f"`hydro-ros machine threshold {machine.source}` (or commission it)")
