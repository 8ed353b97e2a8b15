"""A clutter map of one radar: the density of plots that belong to no confirmed track, per
range/azimuth cell around the radar's site, learnt online and forgetting with a time
constant of minutes.

Persistent clutter (buildings, masts, wind farms, road traffic) and the reflections of one
site come back scan after scan from the same cells; random clutter and new aircraft spread
over the whole cover. A dense cell therefore says "a plot here is more likely nobody's":

- initiation there asks for more evidence (``extra_hits``: more hits in a longer M-of-N
  window before a track seeded there is confirmed);
- the JPDA likelihood of a pair is weighed against the cell's density instead of one
  constant (``density_per_m2``), and so may any other associator (MHT) through
  ``GatedPairs.clutter_density``.

The counts decay continuously: after ``tau`` of learning a cell holding r plots per scan
holds about r tau / T counts, T the antenna period, so that the rate per scan is the
count times T over the effective window tau (1 - exp(-elapsed / tau)), which is also right
while the map is still young (but see ``YOUNG_WINDOW_FRACTION``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker_service.resident_arrays import resident_zeros
from tracker_service.tracking import clutter_kernels
from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

YOUNG_WINDOW_FRACTION = 0.5
"""A young map divides its counts by at least half its full window: the first plots of
the first aircraft, seen before any track is confirmed, would otherwise make their cells
dense (one plot in one scan is a rate of 1). A persistent source is dense after about
``dense_per_scan`` times half the window's scans (about 8 scans of a 4 s radar)."""


@dataclass(frozen=True)
class ClutterMapConfig:
    """The map's cells and memory (``TrackerConfig.clutter_*`` fields)."""

    origin_m: tuple[float, float]
    """The radar's site in the system plane: the centre of the range/azimuth cells."""
    scan_period_s: float
    range_cell_m: float
    azimuth_cell_deg: float
    max_range_m: float
    time_constant_s: float
    floor_per_km2: float
    """The density of plots that are nobody's anywhere (random clutter, new targets): the
    map never reports less."""
    dense_per_scan: float
    """A cell with more plots of no confirmed track per scan than this is dense."""


class ClutterMap:
    """See the module docstring. ``learn`` the plots of no confirmed track after each batch;
    ask ``rate_per_scan``, ``density_per_m2`` or ``dense`` of any positions."""

    def __init__(self, config: ClutterMapConfig) -> None:
        self.config = config
        self._n_range = max(1, math.ceil(config.max_range_m / config.range_cell_m))
        self._n_azimuth = max(1, round(360.0 / config.azimuth_cell_deg))
        self.counts = resident_zeros(self._n_range * self._n_azimuth)
        """Decayed number of plots per cell (flat: range-major), as of ``time``."""
        self._active = resident_zeros(self.counts.size, np.int64)
        self._n_active = 0
        """``_active[:_n_active]``: the cells whose count is not zero (``learn_cells``
        decays only those)."""
        self.time = -math.inf
        """Time of the latest learnt plot: the counts are decayed to it."""
        self._start = math.inf
        # Cell areas by range ring: (r_out^2 - r_in^2) * dphi / 2.
        edges = np.arange(self._n_range + 1) * config.range_cell_m
        ring = 0.5 * (edges[1:] ** 2 - edges[:-1] ** 2) * math.radians(360.0 / self._n_azimuth)
        self._cell_area_m2 = ring
        self._floor_per_m2 = config.floor_per_km2 * 1e-6

    def cells(self, x: FloatArray, y: FloatArray) -> IntArray:
        """The flat cell index of each position (beyond the last ring: the last ring)."""
        dx, dy = x - self.config.origin_m[0], y - self.config.origin_m[1]
        ring = np.minimum(np.hypot(dx, dy) / self.config.range_cell_m, self._n_range - 1)
        azimuth = np.mod(np.degrees(np.arctan2(dx, dy)), 360.0)  # clockwise from north
        sector = np.minimum(azimuth * (self._n_azimuth / 360.0), self._n_azimuth - 1)
        return np.asarray(ring.astype(np.int64) * self._n_azimuth + sector.astype(np.int64))

    def learn(self, x: FloatArray, y: FloatArray, time: FloatArray) -> None:
        """Count plots that belong to no confirmed track (one batch, in time order with the
        batches before it)."""
        if x.size:
            self.learn_cells(self.cells(x, y), time)

    def learn_cells(self, cell: IntArray, time: FloatArray, free: BoolArray | None = None) -> None:
        """``learn`` of plots given by their cells (``cells``); only the ``free`` ones when
        given. Every count decays by exp(-(latest - ``time``) / tau), then each plot
        adds one to its cell (``clutter_kernels.learn``)."""
        if cell.size == 0:
            return
        self._n_active, self.time, earliest = clutter_kernels.learn(
            self.counts,
            self._active,
            self._n_active,
            self.time,
            self.config.time_constant_s,
            cell,
            time,
            np.ones(cell.size, dtype=bool) if free is None else free,
        )
        self._start = min(self._start, earliest)

    def _window_scans(self) -> float:
        """The number of scans the counts stand for (see the module docstring)."""
        tau = self.config.time_constant_s
        elapsed = max(self.time - self._start, 0.0) + self.config.scan_period_s
        window = tau * max(-math.expm1(-elapsed / tau), YOUNG_WINDOW_FRACTION)
        return window / self.config.scan_period_s

    def rate_per_scan(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """Plots of no confirmed track per scan in the cells of these positions."""
        return self.rate_in(self.cells(x, y))

    def rate_in(self, cell: IntArray) -> FloatArray:
        """``rate_per_scan`` in these cells (``cells``)."""
        if not math.isfinite(self.time):
            return np.zeros(cell.shape)
        return np.asarray(self.counts[cell] / self._window_scans())

    def density_per_m2(self, x: FloatArray, y: FloatArray) -> FloatArray:
        """The density of plots of no confirmed track per m^2 and scan at these positions,
        at least the floor: the lambda of a JPDA (or MHT) likelihood."""
        return self.density_in(self.cells(x, y))

    def density_in(self, cell: IntArray) -> FloatArray:
        """``density_per_m2`` in these cells (``cells``)."""
        if not math.isfinite(self.time):
            return np.full(cell.shape, self._floor_per_m2)
        area = self._cell_area_m2[cell // self._n_azimuth]
        rate = self.counts[cell] / self._window_scans()
        return np.asarray(np.maximum(rate / area, self._floor_per_m2))

    def dense(self, x: FloatArray, y: FloatArray) -> BoolArray:
        """Which positions lie in a dense cell."""
        return self.dense_in(self.cells(x, y))

    def dense_in(self, cell: IntArray) -> BoolArray:
        """``dense`` of these cells (``cells``)."""
        return np.asarray(self.rate_in(cell) > self.config.dense_per_scan)

    def describe(
        self, x: FloatArray, y: FloatArray, typ: IntArray, address: IntArray, mode3a: IntArray
    ) -> tuple[BoolArray, IntArray, FloatArray, BoolArray]:
        """Of a batch's plots in one pass (``clutter_kernels.plot_cells``): whether each
        has a secondary reply (``secondary_reply``), its cell (``cells``), the density
        of others there (``density_in``, the floor for a plot with a reply) and whether
        its cell is dense (``dense_in``)."""
        dx, dy = x - self.config.origin_m[0], y - self.config.origin_m[1]
        return clutter_kernels.plot_cells(
            dx,
            dy,
            np.arctan2(dx, dy),
            typ,
            address,
            mode3a,
            self.counts,
            self._cell_area_m2,
            self._n_range,
            self._n_azimuth,
            self.config.range_cell_m,
            self._window_scans() if math.isfinite(self.time) else math.nan,
            self._floor_per_m2,
            self.config.dense_per_scan,
        )


def make_clutter_map(config: TrackerConfig) -> ClutterMap | None:
    """The clutter map ``config`` asks for (None when ``clutter_map`` is off)."""
    if not config.clutter_map:
        return None
    return ClutterMap(
        ClutterMapConfig(
            origin_m=config.clutter_origin_m,
            scan_period_s=config.scan_period_s,
            range_cell_m=config.clutter_range_cell_m,
            azimuth_cell_deg=config.clutter_azimuth_cell_deg,
            max_range_m=config.clutter_max_range_m,
            time_constant_s=config.clutter_time_constant_s,
            floor_per_km2=config.clutter_density_per_km2,
            dense_per_scan=config.clutter_dense_per_scan,
        )
    )


def secondary_reply(typ: IntArray, address: IntArray, mode3a: IntArray) -> BoolArray:
    """Which plots hold a secondary (SSR or Mode S) reply: I048/020 TYP 2-7, or an address
    or a code (sources that leave TYP out)."""
    return np.asarray((typ >= 2) | (address >= 0) | (mode3a >= 0))


def primary_seed_takes_reply(track_secondary: BoolArray, plot_secondary: BoolArray) -> BoolArray:
    """The pairs a tentative track seeded only by primary plots may not take: a plot with a
    secondary reply. A transponder replies in nearly every scan (SSR Pd about 0.98), so two
    primary-only plots in a row are hardly ever its aircraft's: such a seed is clutter, or
    another, primary-only target, and an identified plot that falls in its (wide, young)
    gate belongs to an aircraft of its own. Taking it would confirm the clutter track with
    the aircraft's address and code (the issue 13 case: clutter 4.6 km from an aircraft)."""
    return np.asarray(~track_secondary & plot_secondary)
