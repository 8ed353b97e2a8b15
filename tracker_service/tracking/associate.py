"""Association of a batch of plots to tracks: spatial pre-selection, then global nearest
neighbour.

Pre-selection keeps the cost per plot flat as the number of tracks grows: a box around
the batch (a sector is narrow) leaves the tracks near it, and a k-d tree of their coarse
predicted positions gives the pairs within a radius that bounds every gate.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from tracker_service.tracking.plots import FloatArray, IntArray

UNASSIGNABLE = 1.0e9
KDTREE_LEAF_SIZE = 16
"""scipy's default leaf size, spelt out: the small-batch path relies on it."""


def candidate_pairs(
    track_xy: FloatArray,
    track_radius: FloatArray,
    plot_xy: FloatArray,
    plot_radius: FloatArray,
) -> tuple[IntArray, IntArray]:
    """(track, plot) index pairs closer than the sum of their radii."""
    empty = np.zeros(0, dtype=np.int64)
    if track_xy.shape[0] == 0 or plot_xy.shape[0] == 0:
        return empty, empty
    reach = float(track_radius.max() + plot_radius.max())
    lo = plot_xy.min(axis=0) - reach
    hi = plot_xy.max(axis=0) + reach
    near = np.flatnonzero(np.all((track_xy >= lo) & (track_xy <= hi), axis=1))
    if near.size == 0:
        return empty, empty
    reach = float(track_radius[near].max() + plot_radius.max())
    i, pj, v = pairs_within(track_xy[near], plot_xy, reach)
    ti = near[i]
    keep = v <= track_radius[ti] + plot_radius[pj]
    return ti[keep], pj[keep]


def pairs_within(
    a: FloatArray, b: FloatArray, reach: float
) -> tuple[IntArray, IntArray, FloatArray]:
    """(i, j, distance) of the points a[i], b[j] within ``reach``, in the order of
    ``cKDTree(a).sparse_distance_matrix(cKDTree(b), reach, output_type="ndarray")``.

    When both sets fit in one leaf, both trees are a single leaf, whose search is a double
    loop in (i, j) order with these same distances: done here directly, without the cost
    of building two trees for a few points (the usual sector batch)."""
    if a.shape[0] <= KDTREE_LEAF_SIZE and b.shape[0] <= KDTREE_LEAF_SIZE:
        d = a[:, None, :] - b[None, :, :]
        dist = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
        i, j = np.nonzero(dist <= reach)
        return i, j, dist[i, j]
    found = cKDTree(a, leafsize=KDTREE_LEAF_SIZE).sparse_distance_matrix(
        cKDTree(b, leafsize=KDTREE_LEAF_SIZE), reach, output_type="ndarray"
    )
    return found["i"].astype(np.int64), found["j"].astype(np.int64), found["v"]


def global_nearest_neighbour(rows: IntArray, cols: IntArray, cost: FloatArray) -> IntArray:
    """Indices of the pairs chosen by a minimum-cost one-to-one assignment.

    Pairs whose row and column have no other candidate are taken directly; the rest go to
    ``linear_sum_assignment`` on the dense matrix of the rows and columns involved.
    """
    if rows.size == 0:
        return np.zeros(0, dtype=np.int64)
    row_count = np.bincount(rows)
    col_count = np.bincount(cols)
    lone = (row_count[rows] == 1) & (col_count[cols] == 1)
    chosen = [np.flatnonzero(lone)]
    rest = np.flatnonzero(~lone)
    if rest.size:
        ur, ri = np.unique(rows[rest], return_inverse=True)
        uc, ci = np.unique(cols[rest], return_inverse=True)
        matrix = np.full((ur.size, uc.size), UNASSIGNABLE)
        matrix[ri, ci] = cost[rest]
        pair_at = np.full((ur.size, uc.size), -1, dtype=np.int64)
        pair_at[ri, ci] = rest
        a, b = linear_sum_assignment(matrix)
        taken = pair_at[a, b]
        chosen.append(taken[taken >= 0])
    return np.sort(np.concatenate(chosen))
