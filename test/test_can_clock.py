"""The bus clock (hydro_ros.can.clock): regular stamps from jittered arrivals, lost and late cycles told apart."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from hydro_ros.can.clock import BLOCK_CYCLES, CycleClock

PERIOD = 1e-3  # a 1 kHz bus
LIMIT = 0.02


def _arrivals(n: int, seed: int, drift_ppm: float = 80.0, jitter_s: float = 1.5e-3, stall_share: float = 0.01,
              stall_s: float = 6e-3) -> tuple[np.ndarray, np.ndarray]:
    """Send times of an ECU whose oscillator is ``drift_ppm`` off, and their arrivals at the host: a random delay of up
    to ``jitter_s``, a share of stalls during which the frames queue behind the stalled one."""
    rng = np.random.default_rng(seed)
    sent = 7.0 + np.arange(n) * PERIOD * (1.0 + drift_ppm * 1e-6)
    arrival = sent + rng.uniform(0.0, jitter_s, n)
    arrival[rng.random(n) < stall_share] += stall_s
    return sent, np.maximum.accumulate(arrival)


def _stamps(clock: CycleClock, arrivals: np.ndarray, counters: np.ndarray | None = None) -> np.ndarray:
    return np.array([clock.stamp(int(round(a * 1e9)), None if counters is None else int(c))
                     for a, c in zip(arrivals, counters if counters is not None else arrivals)]) * 1e-9


def _window_rate_errors(stamps: np.ndarray, sent: np.ndarray, start: int, window: int = 100) -> np.ndarray:
    """Relative error of the time each 0.1 s window spans: what a rate differentiated over the window is off by."""
    return np.array([(stamps[i + window] - stamps[i]) / (sent[i + window] - sent[i]) - 1.0
                     for i in range(start, len(stamps) - window, window)])


def test_a_jittered_bus_is_stamped_at_its_own_period():
    sent, arrival = _arrivals(20000, seed=1)
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival)
    locked = 2 * BLOCK_CYCLES  # the first block finds the envelope, the next settles the loop
    clock_error = np.abs(_window_rate_errors(stamps, sent, locked))
    arrival_error = np.abs(_window_rate_errors(arrival, sent, locked))
    assert clock_error.max() < 2e-3, clock_error.max()  # the rate error < 0.2 % in every window
    assert np.median(arrival_error) > 5 * np.median(clock_error)  # what arrival stamps would have cost
    health = clock.health
    assert health.locked and health.lost_cycles == 0 and health.relocks == 0
    assert 60 < health.drift_ppm < 100  # the oscillator's 80 ppm, found
    assert 1e-3 < health.jitter_p99_s < 8e-3  # the 0-1.5 ms delays and 6 ms stalls, seen
    assert np.all(np.diff(stamps) > 0)


def test_lost_cycles_without_counters_are_counted_and_renumbered():
    sent, arrival = _arrivals(6000, seed=2)
    keep = np.ones(len(sent), dtype=bool)
    keep[3000:3003] = False  # three cycles lost inside the latency limit: they look late at first
    keep[4500:4540] = False  # forty lost, longer than the limit: numbered as lost at once
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival[keep])
    assert clock.health.lost_cycles == 43 and clock.health.relocks == 0
    # within two blocks of a loss every stamp is back on its cycle's slot
    offset = stamps - sent[keep]
    index = np.flatnonzero(keep)
    settled = offset[((index >= 3000 + 2 * BLOCK_CYCLES) & (index < 4500)) | (index >= 4540 + 2 * BLOCK_CYCLES)]
    assert np.ptp(settled) < 0.3 * PERIOD, np.ptp(settled)


def test_counters_number_the_cycles_exactly():
    sent, arrival = _arrivals(4000, seed=3, stall_s=12e-3)
    keep = np.ones(len(sent), dtype=bool)
    keep[2000:2005] = False
    counters = np.arange(len(sent)) % 16
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival[keep], counters[keep])
    assert clock.health.lost_cycles == 5
    offset = (stamps - sent[keep])[2 * BLOCK_CYCLES:]
    assert np.ptp(offset) < 0.3 * PERIOD  # no cycle ever off its slot, the loss included


def test_a_silence_relocks_and_a_bus_too_jittery_is_not_trusted():
    _, arrival = _arrivals(3000, seed=4)
    arrival[1500:] += 5.0  # the bus silent for 5 s
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival)
    assert clock.relocks == 1 and clock.health.locked
    # re-locking: from the first arrival at the nominal period until the envelope is found, then one step onto it
    assert stamps[1500] == pytest.approx(arrival[1500], abs=1e-9)
    assert np.allclose(np.diff(stamps[1500:1500 + BLOCK_CYCLES]), PERIOD, atol=1e-9)
    # delays up to 40 ms on a 20 ms limit: numbering is uncertain, the stamps are the arrivals (a monitor then holds)
    _sent, arrival = _arrivals(2000, seed=5, jitter_s=0.04, stall_share=0.0)
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival)
    assert not clock.health.locked
    assert np.allclose(stamps[-100:], arrival[-100:], atol=1e-6)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 10**6), drift=st.floats(-300.0, 300.0), jitter=st.floats(0.0, 3e-3), stalls=st.floats(0.0, 0.03))
def test_random_buses_within_the_limit_are_stamped_regularly(seed, drift, jitter, stalls):
    sent, arrival = _arrivals(1600, seed, drift_ppm=drift, jitter_s=jitter, stall_share=stalls)
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival)
    assert np.all(np.diff(stamps) > 0)
    assert clock.health.lost_cycles == 0 and clock.health.locked
    assert np.abs(_window_rate_errors(stamps, sent, 2 * BLOCK_CYCLES)).max() < 2e-3


def test_a_bad_clock_setting_is_refused():
    with pytest.raises(ValueError, match="period"):
        CycleClock(float("nan"), LIMIT)
    with pytest.raises(ValueError, match="latency limit"):
        CycleClock(PERIOD, 0.0)


def test_cycles_sent_in_bursts_with_counters_stay_on_their_slots():
    """A sender that writes 50 cycles at a time (a simulator's tick, a gateway's buffer): with rolling counters every
    cycle keeps its slot, though most arrive later than the latency limit."""
    sent = 3.0 + np.arange(6000) * PERIOD
    cycle = np.arange(6000)
    arrival = 3.0 + (cycle // 50 + 1) * 0.05 + 2e-5 * (cycle % 50)  # each burst at its end
    clock = CycleClock(PERIOD, LIMIT)
    stamps = _stamps(clock, arrival, np.arange(6000) % 16)
    assert clock.health.locked and clock.health.jitter_max_s > LIMIT and clock.health.lost_cycles == 0
    offset = (stamps - sent)[2 * BLOCK_CYCLES:]
    assert np.ptp(offset) < 0.3 * PERIOD
