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
    # Column by column: a reduction along a 2-long axis costs more than the comparisons.
    tx, ty = track_xy[:, 0], track_xy[:, 1]
    near = np.flatnonzero((tx >= lo[0]) & (tx <= hi[0]) & (ty >= lo[1]) & (ty <= hi[1]))
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

    When b fits in one leaf (the usual sector batch), its tree is that single leaf, and
    the search visits a's leaves in the order of a's tree (``indices``), each with a
    double loop in (i, j) order, with these same distances (scipy's ``traverse`` in
    sparse_distances.cxx): done here directly. a's tree is built only when a does not
    fit in one leaf, and only for that order."""
    if b.shape[0] > KDTREE_LEAF_SIZE:
        found = cKDTree(a, leafsize=KDTREE_LEAF_SIZE).sparse_distance_matrix(
            cKDTree(b, leafsize=KDTREE_LEAF_SIZE), reach, output_type="ndarray"
        )
        return found["i"].astype(np.int64), found["j"].astype(np.int64), found["v"]
    d = a[:, None, :] - b[None, :, :]
    dist = np.sqrt(d[..., 0] * d[..., 0] + d[..., 1] * d[..., 1])
    i, j = np.nonzero(dist <= reach)
    if a.shape[0] > KDTREE_LEAF_SIZE:
        by_leaf = np.argsort(leaf_order(a)[i], kind="stable")
        i, j = i[by_leaf], j[by_leaf]
    return i, j, dist[i, j]


def leaf_order(a: FloatArray) -> IntArray:
    """Each point's position in the leaves of ``cKDTree(a)`` (the order its search visits
    them in)."""
    order = np.empty(a.shape[0], dtype=np.int64)
    order[cKDTree(a, leafsize=KDTREE_LEAF_SIZE).indices] = np.arange(a.shape[0])
    return order


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
    if lone.all():
        return np.arange(rows.size)  # no conflict: the usual sector
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
