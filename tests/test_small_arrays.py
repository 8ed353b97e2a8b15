"""tracker_service.small_arrays against the numpy functions they stand in for."""

from __future__ import annotations

import math
from collections import deque

import numpy as np

from tracker_service.small_arrays import is_one_of, median


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
