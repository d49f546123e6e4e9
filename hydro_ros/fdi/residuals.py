"""Residual generators behind one interface, chosen by method name (``fdi.method`` of a machine config).

A generator turns a block of measured samples of every actuator into two residuals per actuator
(chamber A, chamber B), gives the thresholds they are compared with and the "Large" evidence of
its signature table, and can be reset and self-checked. The monitor
(:class:`hydro_ros.fdi.monitor.FdiMonitor`) does the rest the same way for every method: masking,
the 5 s means, the crossing codes and isolation.

- ``ukf`` (P-II, P-III): chamber-pressure residuals of a batched unscented Kalman filter [MPa];
  adaptive threshold +-(c0 + c2 mu_p^2) (P-II eq. 25); the P-II Table 3 signatures.
- ``parity`` (P-IV style, mobile valves): chamber-flow balance residuals [L/min]; statistical
  thresholds per operating point (5 s mean opening) fitted by ``hydro-ros fdi fit``; a signature
  table built by simulation, with the crossing code over the closed-valve samples as evidence
  beside the crossing signs (``ParityResiduals.closed_mean``).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from hydro_ros.contract.errors import InputError
from hydro_ros.fdi.isolation import NO_CLOSED_CODE, UKF_TABLE, PatternRow
from hydro_ros.fdi.parity import POINT_CHANNELS, ParityGenerator, passes_nothing
from hydro_ros.fdi.settings import FdiSettings
from hydro_ros.fdi.ukf import PRESSURE_UNIT, UkfBank
from hydro_ros.models.sam import SamModel


class MovingAverage:
    """Eq. (24): mean of the last N samples per channel, zero-initialised like the paper's buffer."""

    def __init__(self, window: int, channels: int) -> None:
        self.window = window
        self.history = np.zeros((window, channels))

    def reset(self) -> None:
        self.history[:] = 0.0

    def __call__(self, block: np.ndarray) -> np.ndarray:
        m = block.shape[0]
        extended = np.concatenate((self.history, block))
        sums = np.cumsum(extended, axis=0)
        # mean of the N samples ending at each block sample; cumsum differences stay exact enough
        # because the whole history is re-summed every block (no recursive drift)
        out = (sums[self.window :] - sums[:m]) / self.window
        self.history = extended[m:].copy()
        return out


@dataclass
class BlockInput:
    """One block of every actuator's measurements, (n, A) arrays, as a generator needs them."""

    piston: np.ndarray  # [m] from the joint angle (P-I eqs. 3-4)
    velocity: np.ndarray  # [m/s]
    command: np.ndarray  # [-]
    supply: np.ndarray  # [Pa]
    pressure: np.ndarray  # (n, A, 2) [Pa] chambers A and B
    valid: np.ndarray  # (n, A) every value of the sample finite
    mobile: np.ndarray | None = None  # (n, A, 3) [Pa] pilot 1, pilot 2, compensator (mobile valves)


CLOSED_WINDOW_S = 2.0  # [s] of closed-valve samples, however far apart, the closed code averages (INFERRED: the mobile SAM's
# simulated operator holds its valve closed 5-15 % of the time, so P-II's 5 s of wall time rarely hold enough of them; 2 s of
# them span about 20 s of work there, and their mean's noise stays near that of a 5 s window's)


class LastSamplesMean:
    """Per channel, the mean of the last N samples that were counted, however far apart; NaN until N have been."""

    def __init__(self, count: int, channels: int) -> None:
        self.count = count
        self.history = [np.zeros(0) for _ in range(channels)]

    def reset(self) -> None:
        self.history = [np.zeros(0) for _ in self.history]

    def __call__(self, block: np.ndarray, counted: np.ndarray) -> np.ndarray:
        """(n, C) samples and whether each counts -> (n, C) the mean of the last N counted up to each sample."""
        out = np.full(block.shape, np.nan)
        for c, history in enumerate(self.history):
            sequence = np.concatenate((history, block[counted[:, c], c]))
            sums = np.concatenate(([0.0], np.cumsum(sequence)))
            seen = len(history) + np.cumsum(counted[:, c])
            full = seen >= self.count
            out[full, c] = (sums[seen[full]] - sums[seen[full] - self.count]) / self.count
            self.history[c] = sequence[-self.count:]
        return out


class ResidualGenerator(ABC):
    """What the monitor needs of a method; subclasses register under their ``method`` name."""

    method: str
    unit: str  # of residuals and thresholds
    needs_mobile_pressures: bool = False
    # each chamber's residual is its own equation: a cavitating chamber masks only itself (a leak out of A
    # still shows while B, trapped behind the closed valve, cavitates as the load sinks)
    chambers_independent: bool = False

    def __init__(self, models: list[SamModel], settings: FdiSettings, window: int) -> None:
        self.models = models
        self.settings = settings
        self.window = window

    @property
    @abstractmethod
    def table(self) -> tuple[PatternRow, ...]:
        """The fault signature table the isolator narrows causes with."""

    @abstractmethod
    def residuals(self, block: BlockInput) -> tuple[np.ndarray, np.ndarray | None]:
        """(n, A, 2) raw residuals, and the (n, A, ...) operating point the thresholds depend on, if any."""

    @abstractmethod
    def thresholds(self, mean_pressure: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        """(n, A, 2) positive thresholds from the 5 s mean pressures [MPa] or the operating point."""

    def large(self, mean_residual: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        """(n, A) "Large" evidence of the signature table; methods whose table has none say False."""
        return np.zeros(mean_residual.shape[:2], dtype=bool)

    def closed_mean(self, residual: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """(n, A, 2) mean residuals over closed-valve samples (NaN: not judged; methods without the evidence: everywhere),
        from the block's (n, A, 2) residuals and mask."""
        return np.full(residual.shape, np.nan)

    def closed_code(self, closed_mean: np.ndarray) -> np.ndarray:
        """(n, A) crossing codes of the closed means, ``NO_CLOSED_CODE`` where not known."""
        return np.full(closed_mean.shape[:2], NO_CLOSED_CODE, dtype=np.int8)

    @property
    def closed_threshold(self) -> np.ndarray | None:
        """(A, B) thresholds of the closed means; None for methods without the evidence."""
        return None

    @abstractmethod
    def reset(self) -> None:
        """Restart the generator's state (filters, memories)."""

    def self_check(self) -> list[tuple[str, bool]]:
        """Checks of the generator's own set-up, each (what was checked, passed)."""
        return []


class UkfResiduals(ResidualGenerator):
    method = "ukf"
    unit = "MPa"

    def __init__(self, models: list[SamModel], settings: FdiSettings, window: int) -> None:
        super().__init__(models, settings, window)
        self.bank = UkfBank(models, settings.ukf)

    @property
    def table(self) -> tuple[PatternRow, ...]:
        return UKF_TABLE

    def residuals(self, block: BlockInput) -> tuple[np.ndarray, None]:
        inputs = np.stack([block.piston, block.velocity, block.command, block.supply], axis=2)
        prior, posterior = self.bank.run(inputs, block.pressure, block.valid)
        estimate = posterior if self.settings.residual == "posterior" else prior
        return (block.pressure - estimate) / PRESSURE_UNIT, None

    def thresholds(self, mean_pressure: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        return self.settings.threshold_constant + self.settings.threshold_quadratic * mean_pressure**2

    def large(self, mean_residual: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        return np.all(np.abs(mean_residual) > self.settings.large_residual, axis=2)

    def reset(self) -> None:
        self.bank.reset()

    def self_check(self) -> list[tuple[str, bool]]:
        weights = self.bank.weights
        # mean weights: w0 + 2 n wi with n = 4 states
        return [("unscented weights sum to one", bool(np.all(np.isfinite(weights)) and abs(weights[0] + 8 * weights[2] - 1.0) < 1e-6))]


class ParityResiduals(ResidualGenerator):
    method = "parity"
    unit = "L/min"
    needs_mobile_pressures = True
    chambers_independent = True

    def __init__(self, models: list[SamModel], settings: FdiSettings, window: int) -> None:
        super().__init__(models, settings, window)
        if not all(model.mobile_valve for model in models):
            raise InputError("fdi method parity: needs pressure-compensated mobile valves (valve.type: mobile) and their "
                             "pilot pressures; this machine has neither")
        if settings.parity_thresholds is None:
            raise InputError("fdi method parity: the config has no fdi.parity_thresholds (fit them with hydro-ros fdi fit --write, "
                             "or hydro-ros commission on the machine's recordings)")
        self.generator = ParityGenerator(models)
        self._operating_point_mean = MovingAverage(window, POINT_CHANNELS * len(models))
        self._closed = np.zeros((0, len(models)), dtype=bool)  # the last block's closed-valve samples
        self._closed_mean = LastSamplesMean(int(round(CLOSED_WINDOW_S * models[0].sample_rate)), 2 * len(models))

    @property
    def table(self) -> tuple[PatternRow, ...]:
        return self.settings.parity_signatures

    def residuals(self, block: BlockInput) -> tuple[np.ndarray, np.ndarray]:
        """Residuals, and the operating point (n, A, 5): 5 s means of the opening, the chambers' |valve flow| and their roots'
        noise bias."""
        if block.mobile is None:
            raise InputError("fdi method parity: no pilot/compensator pressures in the samples")
        residual, opening, flow, bias, self._closed = self.generator.run(
            block.piston, block.velocity, block.pressure[:, :, 0], block.pressure[:, :, 1], block.mobile[:, :, 0], block.mobile[:, :, 1],
            block.mobile[:, :, 2], block.valid)
        n, n_act = opening.shape
        point = np.concatenate([opening[:, :, None], flow, bias], axis=2).reshape(n, -1)
        return residual, self._operating_point_mean(point).reshape(n, n_act, POINT_CHANNELS)

    def thresholds(self, mean_pressure: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        return self.settings.parity_thresholds(operating_point)

    def closed_mean(self, residual: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Each chamber's mean residual over its last ``CLOSED_WINDOW_S`` of closed-valve samples (the modelled spool well
        inside its dead zone, ``parity.CLOSED_SHARE``; a masked chamber's samples left out), NaN until that many were seen.

        Why: a leak and a velocity-sensor bias put flow into the residual whether the valve meters or not; a bias of the
        pilot or compensator pressure transmitters and a main-spool fault change only the modelled valve flow, which is
        zero while the spool is closed (the centre leakage aside, in both). Crossings of these means single out the
        first group where the crossing signs while metering are shared with the second, and tell the pilot bias (which
        opens the real spool the model holds closed near the dead zone's edge: B only) from the internal leak (A and B).
        They only name a detected fault; detection stays with the 5 s means over all samples.
        """
        n, n_act = self._closed.shape
        counted = (self._closed[:, :, None] & ~mask).reshape(n, -1)
        return self._closed_mean(residual.reshape(n, -1), counted).reshape(n, n_act, 2)

    def closed_code(self, closed_mean: np.ndarray) -> np.ndarray:
        return self.settings.parity_thresholds.closed_code(closed_mean)

    @property
    def closed_threshold(self) -> np.ndarray | None:
        return self.settings.parity_thresholds.closed_threshold

    def large(self, mean_residual: np.ndarray, operating_point: np.ndarray | None) -> np.ndarray:
        """The valve passed almost none of its modelled flow (``parity.passes_nothing``): a locked main spool, where a pilot
        bias, an internal leak or a main-spool erosion give the same crossing signs."""
        return passes_nothing(mean_residual, operating_point)

    def reset(self) -> None:
        self.generator.reset()
        self._operating_point_mean.reset()
        self._closed_mean.reset()

    def self_check(self) -> list[tuple[str, bool]]:
        thresholds = self.settings.parity_thresholds
        at_rest = np.zeros((len(thresholds.edges), 1, POINT_CHANNELS))
        at_rest[:, 0, 0] = thresholds.edges
        positive = bool(np.all(thresholds(at_rest) > 0.0))
        return [("parity thresholds positive at every operating point", positive),
                ("signature table present", bool(self.table))]


GENERATORS: dict[str, type[ResidualGenerator]] = {generator.method: generator for generator in (UkfResiduals, ParityResiduals)}


def generator_for(method: str, models: list[SamModel], settings: FdiSettings, window: int) -> ResidualGenerator:
    try:
        kind = GENERATORS[method]
    except (KeyError, TypeError):
        raise InputError(f"fdi method {method!r}: expected {' or '.join(GENERATORS)}") from None
    return kind(models, settings, window)
