"""The data clock's compiled look at a batch (``clock._judge``) against the numpy it
replaced: ``np.partition``'s middle time, the times within reach and the latest of them."""

from __future__ import annotations

import math

import numpy as np

from tracker_service.tracking.clock import _judge


def test_judge_is_the_numpy_reference() -> None:
    rng = np.random.default_rng(2)
    for trial in range(500):
        k = int(rng.integers(1, 30))
        times = 1.7e9 + rng.normal(0.0, 3.0, k)
        times[rng.random(k) < 0.1] += rng.choice([-7200.0, 3600.0])  # bad stamps
        if trial % 5 == 0:
            times[: k // 2] = times[0]  # equal times
        times_view = np.zeros(2 * k)[::2]  # a strided column, as the fuser passes
        times_view[:] = times
        now = -math.inf if trial % 7 == 0 else 1.7e9 + rng.normal(0.0, 2.0)  # first batch
        centre, accepted, latest = _judge(times_view, now, 30.0, 20.0)
        expected_centre = float(np.partition(times, k // 2)[k // 2])
        around = expected_centre if now == -math.inf else now
        expected = (times <= around + 30.0) & (times >= around - 20.0)
        assert centre == expected_centre
        np.testing.assert_array_equal(accepted, expected)
        assert latest == (float(times[expected].max()) if expected.any() else -math.inf)
