"""tracker_service.small_arrays against the numpy functions they stand in for."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from tracker_service.radar_stage import RAW_PLOT_DTYPE
from tracker_service.small_arrays import (
    concatenate_rows,
    copy_rows,
    is_one_of,
    median,
    take_rows,
)


def test_median_matches_numpy_to_the_bit() -> None:
    """Odd and even counts, with and without NaN, arrays and a deque."""
    rng = np.random.default_rng(7)
    for n in range(1, 40):
        for _ in range(20):
            times = 1.7e9 + rng.normal(0.0, 3.0, n)
            if rng.random() < 0.2:
                times[rng.integers(n)] = np.nan
            expected = float(np.median(times))
            got = median(times)
            assert got == expected or (math.isnan(got) and math.isnan(expected))
    phases = deque(rng.uniform(-0.5, 0.5, 32), maxlen=32)
    assert median(phases) == float(np.median(phases))


def test_is_one_of_matches_isin() -> None:
    rng = np.random.default_rng(8)
    wanted = np.array([2, 5], np.int64)
    for n in range(0, 30):
        codes = rng.integers(0, 8, n)
        np.testing.assert_array_equal(is_one_of(codes, wanted), np.isin(codes, wanted))
    assert not is_one_of(np.array([1, 2], np.int64), np.zeros(0, np.int64)).any()


def test_structured_rows_match_numpy_to_the_byte() -> None:
    """Copies, takes (integers, masks, none) and joins of plot rows, strided too."""
    rng = np.random.default_rng(9)
    rows = np.zeros(7, dtype=RAW_PLOT_DTYPE)
    rows["x"] = rng.normal(size=7)
    rows["time"][2] = np.nan
    rows["R"] = rng.normal(size=(7, 2, 2))
    rows["callsign"] = "KLM1234"
    for part in (rows, rows[::2], rows[:0]):
        copied = copy_rows(part)
        assert copied.dtype == part.dtype and copied.tobytes() == part.copy().tobytes()
        copied["x"] = 5.0  # a copy, not a view
        assert not (part["x"] == 5.0).any()
    for index in (np.array([4, 0, 4]), rows["x"] > 0, np.zeros(0, np.int64)):
        taken = take_rows(rows, index)
        assert taken.dtype == rows.dtype and taken.tobytes() == rows[index].tobytes()
    joined = concatenate_rows([rows[:3], rows[:0], rows[5:]])
    expected = np.concatenate([rows[:3], rows[:0], rows[5:]])
    assert joined.dtype == rows.dtype and joined.tobytes() == expected.tobytes()
