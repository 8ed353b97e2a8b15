"""The clutter map's per-batch work as compiled passes: a batch's cells, densities and
dense flags in one call, and its learning (the decay and the new counts) in another.

Why compiled: the numpy map (``clutter.ClutterMap.cells``, ``density_in``, ``dense_in``)
costs a dozen array calls per batch for about ten plots, and its learning decayed every
cell of the map (some 117,000 for 600 km by 1 NM by 1 degree) at every batch, most of
them zero. ``learn`` multiplies only the cells that hold a count (the ``active`` list:
a zero cell stays zero under the decay), by the same factor in the same order, so the
counts are the same to the bit. The plots' azimuth stays numpy's ``arctan2`` (numpy's
SIMD one differs from the C library's in the last bit of a few percent of values);
every other operation is the numpy reference's, in its order:
``tests/test_clutter_kernels.py`` holds them to ``ClutterMap``'s numpy methods.
"""

from __future__ import annotations

import math

import numpy as np

from tracker_service.numba_symbols import numba
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray


@numba.njit(cache=True)
def plot_cells(
    dx: FloatArray,
    dy: FloatArray,
    azimuth_rad: FloatArray,
    typ: IntArray,
    address: IntArray,
    mode3a: IntArray,
    counts: FloatArray,
    cell_area_m2: FloatArray,
    n_range: int,
    n_azimuth: int,
    range_cell_m: float,
    window_scans: float,
    floor_per_m2: float,
    dense_per_scan: float,
) -> tuple[BoolArray, IntArray, FloatArray, BoolArray]:  # pragma: no cover - compiled
    """Of plots at (dx, dy) from the site, ``azimuth_rad`` = arctan2(dx, dy) by numpy:
    whether each has a secondary reply (``clutter.secondary_reply``), its cell
    (``ClutterMap.cells``), the map's density there (``density_in``; the floor for a
    plot with a reply, as ``LocalTracker._clutter_density``) and whether the cell is
    dense (``dense_in``). ``window_scans``: ``ClutterMap._window_scans``, NaN while
    the map has learnt nothing."""
    n = dx.size
    reply = np.empty(n, np.bool_)
    cell = np.empty(n, np.int64)
    density = np.empty(n)
    dense = np.empty(n, np.bool_)
    learnt = not np.isnan(window_scans)
    sectors_per_degree = n_azimuth / 360.0
    for j in range(n):
        reply[j] = typ[j] >= 2 or address[j] >= 0 or mode3a[j] >= 0
        ring = min(np.hypot(dx[j], dy[j]) / range_cell_m, n_range - 1)
        azimuth = np.mod(np.degrees(azimuth_rad[j]), 360.0)
        sector = min(azimuth * sectors_per_degree, n_azimuth - 1)
        c = int(ring) * n_azimuth + int(sector)
        cell[j] = c
        if not learnt:
            density[j] = floor_per_m2
            dense[j] = dense_per_scan < 0.0
            continue
        rate = counts[c] / window_scans
        cell_density = max(rate / cell_area_m2[c // n_azimuth], floor_per_m2)
        density[j] = floor_per_m2 if reply[j] else cell_density
        dense[j] = rate > dense_per_scan
    return reply, cell, density, dense


@numba.njit(cache=True)
def learn(
    counts: FloatArray,
    active: IntArray,
    n_active: int,
    map_time: float,
    time_constant_s: float,
    cell: IntArray,
    time: FloatArray,
    free: BoolArray,
) -> tuple[int, float, float]:  # pragma: no cover - compiled
    """``ClutterMap.learn_cells`` of the ``free`` plots: the counts decayed from
    ``map_time`` to the latest of their times, then one more in each plot's cell.
    ``active[:n_active]``: the cells whose count is not zero, kept so (a count that
    decays to zero leaves the list). Returns the new ``n_active``, the map's new time
    and the earliest of the plots' times (inf without any)."""
    latest = -np.inf
    earliest = np.inf
    for j in range(cell.size):
        if free[j]:
            latest = max(latest, time[j])
            earliest = min(earliest, time[j])
    if earliest == np.inf:
        return n_active, map_time, earliest
    if latest > map_time:
        if math.isfinite(map_time):
            factor = math.exp(-(latest - map_time) / time_constant_s)
            k = 0
            while k < n_active:
                c = active[k]
                counts[c] *= factor
                if counts[c] == 0.0:
                    n_active -= 1
                    active[k] = active[n_active]
                else:
                    k += 1
        map_time = latest
    for j in range(cell.size):
        if free[j]:
            c = cell[j]
            if counts[c] == 0.0:
                active[n_active] = c
                n_active += 1
            counts[c] += 1.0
    return n_active, map_time, earliest
