"""The one sample aligner the live node and the bag reader share."""

from __future__ import annotations

import numpy as np
import pytest

from hydro_ros.bags.align import SampleAligner, SampleLayout, place_at_keys
from hydro_ros.bags.reader import read_bag
from test.conftest import REPO

MS = 1_000_000


def _stream(aligner: SampleAligner, stamps_ms: range, skip: dict[int, int] | None = None) -> None:
    """Values of every column at each stamp, one message at a time as subscriptions deliver them."""
    for t in stamps_ms:
        for column in range(aligner.width):
            if (skip or {}).get(t) != column:
                aligner.put(column, t * MS, float(column))


def test_a_sample_missing_a_topic_waits_for_the_sync_window_then_passes_as_a_gap():
    aligner = SampleAligner(3, sync_window_ns=50 * MS)
    _stream(aligner, range(0, 40), skip={20: 2})
    stamps, rows = aligner.take()
    assert stamps[-1] == 19 * MS and aligner.incomplete == 0  # row 20 may still be completed
    _stream(aligner, range(40, 100))
    stamps, rows = aligner.take()
    assert stamps[0] == 20 * MS and np.isnan(rows[0, 2]) and aligner.incomplete == 1
    assert stamps[-1] == 99 * MS and not np.isnan(rows[1:]).any()


def test_values_after_their_sample_was_released_are_counted_not_reordered():
    aligner = SampleAligner(2)
    _stream(aligner, range(0, 10))
    aligner.take()
    aligner.put(0, 5 * MS, 1.0)
    assert aligner.out_of_order == 1
    assert len(aligner.take(final=True)[0]) == 0


def test_a_nan_value_is_a_value_that_arrived():
    """A sensor sending NaN does not hold its sample back: the monitor sees the NaN as a gap at once."""
    aligner = SampleAligner(2, sync_window_ns=10**12)
    aligner.put(0, MS, np.nan)
    aligner.put(1, MS, 1.0)
    aligner.put(0, 2 * MS, 1.0)
    aligner.put(1, 2 * MS, 1.0)
    stamps, rows = aligner.take()
    assert list(stamps) == [MS, 2 * MS] and np.isnan(rows[0, 0]) and aligner.incomplete == 0


def test_the_key_stamps_decide_which_values_are_samples():
    column = np.full(3, np.nan)
    place_at_keys(column, np.array([1, 2, 3]) * MS, np.array([2, 3, 4, 3]) * MS, np.array([20.0, 30.0, 40.0, 31.0]))
    assert np.isnan(column[0]) and list(column[1:]) == [20.0, 31.0]


def test_layout_rows_become_per_actuator_samples():
    layout = SampleLayout(["lift", "tilt"], ["lift_joint", "tilt_joint"])
    rows = np.arange(3 * len(layout.columns), dtype=float).reshape(3, -1)
    samples = layout.samples(np.arange(3.0), rows)
    assert samples.pressure_a.shape == (3, 2)
    assert samples.pressure_b[0, 1] == rows[0, layout.index("pressure_b", "tilt")]
    assert samples.joint_velocity[2, 0] == rows[2, layout.index("joint_velocity", "lift_joint")]
    assert list(samples.supply_pressure) == list(rows[:, -1])


def test_bag_samples_name_a_missing_topic():
    data = read_bag(REPO / "bags" / "fault_free")
    samples = data.samples(SampleLayout(["boom"], ["boom_joint"]))
    assert samples.pressure_a.shape == (len(data.stamps_ns), 1)
    assert np.array_equal(samples.pressure_a[:, 0], data.pressure_a["boom"], equal_nan=True)
    with pytest.raises(ValueError, match="no /hydraulics/stick/pressure_a"):
        data.samples(SampleLayout(["stick"], ["boom_joint"]))
