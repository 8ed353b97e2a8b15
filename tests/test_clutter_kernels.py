"""The clutter map's compiled passes (``tracking.clutter_kernels``) against the plain numpy
map: a batch's replies, cells, densities and dense flags equal to ``ClutterMap``'s numpy
methods, and the learning (only the cells that hold a count decayed) equal to the whole
map decayed at every batch, to the bit."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import numpy.typing as npt

from tracker_service.tracking import TrackerConfig
from tracker_service.tracking.clutter import ClutterMap, make_clutter_map, secondary_reply

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


def clutter_map(**changes: object) -> ClutterMap:
    config = dataclasses.replace(TrackerConfig(scan_period_s=4.0), **changes)
    found = make_clutter_map(config)
    assert found is not None
    return found


def positions(rng: np.random.Generator, k: int) -> tuple[FloatArray, FloatArray]:
    """Plots around a site at (3 km, -2 km), some beyond the map's last ring, some on
    the axes (azimuth 0, 90, 180, 270 degrees and the site itself) when k > 8."""
    n = max(k, 9)
    radius = rng.uniform(0.0, 700e3, n)
    bearing = rng.uniform(-np.pi, np.pi, n)
    x = 3000.0 + radius * np.sin(bearing)
    y = -2000.0 + radius * np.cos(bearing)
    x[:4] = 3000.0
    y[4:8] = -2000.0
    x[8], y[8] = 3000.0, -2000.0
    return x[:k], y[:k]


class PlainMap:
    """The map's learning as it was: every cell decayed, then ``np.add.at``."""

    def __init__(self, size: int, time_constant_s: float) -> None:
        self.counts = np.zeros(size)
        self.time = -math.inf
        self.tau = time_constant_s

    def learn_cells(self, cell: IntArray, time: FloatArray) -> None:
        if cell.size == 0:
            return
        latest = float(time.max())
        if latest > self.time:
            if math.isfinite(self.time):
                self.counts *= math.exp(-(latest - self.time) / self.tau)
            self.time = latest
        np.add.at(self.counts, cell, 1.0)


def test_learning_only_the_active_cells_is_the_plain_decay() -> None:
    rng = np.random.default_rng(4)
    compiled = clutter_map(clutter_origin_m=(3000.0, -2000.0), clutter_time_constant_s=20.0)
    plain = PlainMap(compiled.counts.size, 20.0)
    t = 1.7e9
    for batch in range(400):
        # Now and then a silence long enough for counts to decay to zero (and leave the
        # active cells), plots coming back to cells that were zero, repeated cells.
        t += 20000.0 if batch % 97 == 96 else rng.uniform(0.0, 1.0)
        k = int(rng.integers(0, 12))
        x, y = positions(rng, k)
        x[: k // 3] = 3000.0 + 5000.0  # a persistent source: one cell again and again
        y[: k // 3] = -2000.0
        time = t + np.sort(rng.uniform(-0.5, 0.5, k))
        free = rng.random(k) < 0.8
        cell = compiled.cells(x, y)
        compiled.learn_cells(cell, time, free)
        plain.learn_cells(cell[free], time[free])
        assert compiled.counts.tobytes() == plain.counts.tobytes()
        assert compiled.time == plain.time
    active = compiled._active[: compiled._n_active]
    assert np.array_equal(np.sort(active), np.flatnonzero(compiled.counts))
    assert 0 < active.size < compiled.counts.size


def test_a_batch_described_in_one_pass_is_the_numpy_map() -> None:
    rng = np.random.default_rng(8)
    config = TrackerConfig(scan_period_s=4.0, clutter_origin_m=(3000.0, -2000.0))
    floor = config.clutter_density_per_km2 * 1e-6
    clutter = clutter_map(clutter_origin_m=(3000.0, -2000.0))
    for step in range(60):
        k = int(rng.integers(1, 40))
        x, y = positions(rng, k)
        typ = rng.integers(0, 8, k)
        address = np.where(rng.random(k) < 0.3, rng.integers(0, 1 << 24, k), -1)
        mode3a = np.where(rng.random(k) < 0.3, rng.integers(0, 4096, k), -1)
        reply, cell, density, dense = clutter.describe(x, y, typ, address, mode3a)
        expected_cell = clutter.cells(x, y)
        expected_reply = secondary_reply(typ, address, mode3a)
        np.testing.assert_array_equal(cell, expected_cell)
        np.testing.assert_array_equal(reply, expected_reply)
        expected_density = np.where(expected_reply, floor, clutter.density_in(expected_cell))
        assert density.tobytes() == expected_density.tobytes()
        np.testing.assert_array_equal(dense, clutter.dense_in(expected_cell))
        # The first batches describe an empty map; then a dense source builds up.
        source = np.full(8, 3000.0 + 20e3), np.full(8, -2000.0)
        clutter.learn(source[0], source[1], np.full(8, 1.7e9 + 4.0 * step))
        clutter.learn(x, y, np.full(k, 1.7e9 + 4.0 * step))
    assert clutter.dense(*source).all()
