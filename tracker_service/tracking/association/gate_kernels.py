"""The gate of ``gate.Gate`` as compiled passes over a batch: the pre-selection radius of
every live track, the box around the batch, the (track, plot) pairs within reach in the
order of scipy's k-d tree search, the IMM prediction of each pair, its normalised
innovation, the identity cost and the gate itself.

Why compiled: a sector of about 10 plots paid some 60 numpy and scipy calls here (350 us
of a 600-900 us batch on ``tma``), not arithmetic. The numpy reference is ``Gate`` with
``implementation = "numpy"`` (``_reach``, ``associate.candidate_pairs``, the IMM's
``predict`` and ``innovation_test``, ``identity.identity_cost``);
``tests/test_gate_kernels.py`` holds these passes to it: the same pairs in the same order
and the same values to the bit (every operation in the reference's order, the IMM by the
same kernels as ``tracking.kernels``).

The order of the pairs numbers the output rows (GNN keeps its chosen pairs in this order)
and orders JPDA's and MHT's sums, so it must be scipy's: ``cKDTree(a)
.sparse_distance_matrix(cKDTree(b), reach)`` walks both trees at once, depth first, the
lesser child before the greater, both trees' children in turn while both nodes are inner
(``traverse`` in scipy's sparse_distances.cxx), and each pair of leaves row by row in the
trees' leaf order. A balanced cKDTree (scipy's default) splits a node of n > leafsize
points at its middle point's value, unless all its points are equal, and its leaf order
(``indices``) is what libstdc++'s ``std::nth_element`` and ``std::partition`` leave in
each node: ``_tree_paths`` builds it so (a port of both; the rare arrangements that
would take libstdc++ into its heap selection are left to scipy's own build, in
``Gate._gate_with_scipy_trees``), or reads the shape off scipy's ``indices``. So each
point's path from the root is known, and a pair's rank in the search is its two paths
interleaved as the walk takes them, then the two leaf positions.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tracker_service.numba_symbols import numba
from tracker_service.tracking.kernels import imm_predict, innovation_test, nan_max, nan_min
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

KDTREE_LEAF_SIZE = 16
"""scipy's default leaf size, spelt out (``associate.KDTREE_LEAF_SIZE``)."""


@numba.njit(cache=True)
def preselect(
    xc: FloatArray,
    pc: FloatArray,
    dt: FloatArray,
    a: FloatArray,
    a_cubed: FloatArray,
    spread: float,
    q_max: float,
    turn_max: float,
    widest_gate: float,
    radius_safety: float,
    radius_margin_m: float,
    plot_x: FloatArray,
    plot_y: FloatArray,
    plot_radius: FloatArray,
) -> tuple[IntArray, FloatArray, FloatArray, FloatArray, float]:  # pragma: no cover
    """``Gate._reach`` of the n = dt.size live tracks (dt: the batch's middle time less
    each track's time; a = |dt| + the batch's half spread, a_cubed = a**3 by numpy, whose
    SIMD power differs from the C library's in the last bit), then the box around the
    batch of ``associate.candidate_pairs``: the tracks ``near`` it, their coarse positions
    (x, y) and radii, and the search reach over them."""
    n = dt.size
    coarse_x = np.empty(n)
    coarse_y = np.empty(n)
    radius = np.empty(n)
    reach_max = -np.inf
    for r in range(n):
        ar = a[r]
        var = (
            pc[r, 0, 0]
            + pc[r, 1, 1]
            + 2.0 * ar * abs(pc[r, 0, 2] + pc[r, 1, 3])
            + ar * ar * (pc[r, 2, 2] + pc[r, 3, 3])
            + 2.0 * q_max * a_cubed[r] / 3.0
        )
        speed = np.hypot(xc[r, 2], xc[r, 3])
        radius[r] = (
            radius_safety * np.sqrt(widest_gate * var)
            + speed * spread
            + 0.5 * speed * turn_max * ar * ar
            + radius_margin_m
        )
        coarse_x[r] = xc[r, 0] + xc[r, 2] * dt[r]
        coarse_y[r] = xc[r, 1] + xc[r, 3] * dt[r]
        reach_max = nan_max(reach_max, radius[r])
    plot_reach = -np.inf
    lo_x = hi_x = plot_x[0]
    lo_y = hi_y = plot_y[0]
    for j in range(plot_x.size):
        plot_reach = nan_max(plot_reach, plot_radius[j])
        lo_x = nan_min(lo_x, plot_x[j])
        hi_x = nan_max(hi_x, plot_x[j])
        lo_y = nan_min(lo_y, plot_y[j])
        hi_y = nan_max(hi_y, plot_y[j])
    reach = reach_max + plot_reach
    lo_x -= reach
    hi_x += reach
    lo_y -= reach
    hi_y += reach
    near = np.empty(n, np.int64)
    k = 0
    near_max = -np.inf
    for r in range(n):
        inside_x = coarse_x[r] >= lo_x and coarse_x[r] <= hi_x
        if inside_x and coarse_y[r] >= lo_y and coarse_y[r] <= hi_y:
            near[k] = r
            near_max = nan_max(near_max, radius[r])
            k += 1
    near = near[:k]
    return near, coarse_x[near], coarse_y[near], radius[near], near_max + plot_reach


@numba.njit(cache=True, inline="always")
def _precedes(values: FloatArray, a: int, b: int) -> bool:  # pragma: no cover - compiled
    """scipy's ``index_compare`` (build.cxx): by value alone."""
    return bool(values[a] < values[b])


@numba.njit(cache=True)
def _nth_element(
    values: FloatArray, index: IntArray, first: int, nth: int, last: int
) -> bool:  # pragma: no cover - compiled
    """``std::nth_element(index + first, index + nth, index + last)`` of libstdc++ (its
    introselect: the median of three moved to the front, the unguarded partition,
    insertion sort below four elements), arranging ``index`` in place as scipy's build
    does. False, with ``index`` partly arranged, where libstdc++ would go on with a
    heap selection (its depth limit, 2 log2 n, reached): the caller asks scipy."""
    if first == last or nth == last:
        return True
    depth_limit = 0
    size = last - first
    while size > 1:
        size >>= 1
        depth_limit += 1
    depth_limit *= 2
    while last - first > 3:
        if depth_limit == 0:
            return False
        depth_limit -= 1
        a, b, c = first + 1, first + (last - first) // 2, last - 1
        if _precedes(values, index[a], index[b]):
            if _precedes(values, index[b], index[c]):
                median = b
            elif _precedes(values, index[a], index[c]):
                median = c
            else:
                median = a
        elif _precedes(values, index[a], index[c]):
            median = a
        elif _precedes(values, index[b], index[c]):
            median = c
        else:
            median = b
        index[first], index[median] = index[median], index[first]
        pivot = index[first]
        lo, hi = first + 1, last
        while True:
            while _precedes(values, index[lo], pivot):
                lo += 1
            hi -= 1
            while _precedes(values, pivot, index[hi]):
                hi -= 1
            if not lo < hi:
                break
            index[lo], index[hi] = index[hi], index[lo]
            lo += 1
        if lo <= nth:
            first = lo
        else:
            last = lo
    for p in range(first + 1, last):
        moving = index[p]
        if _precedes(values, moving, index[first]):
            index[first + 1 : p + 1] = index[first:p].copy()
            index[first] = moving
            continue
        q = p
        while q > first and _precedes(values, moving, index[q - 1]):
            index[q] = index[q - 1]
            q -= 1
        index[q] = moving
    return True


@numba.njit(cache=True)
def _partition_below(
    values: FloatArray, index: IntArray, first: int, last: int, split: float
) -> int:  # pragma: no cover - compiled
    """``std::partition`` of libstdc++ (bidirectional) of ``index[first:last]`` by
    ``values < split``: where the greater part starts."""
    while True:
        while True:
            if first == last:
                return first
            if values[index[first]] < split:
                first += 1
            else:
                break
        last -= 1
        while True:
            if first == last:
                return first
            if not values[index[last]] < split:
                last -= 1
            else:
                break
        index[first], index[last] = index[last], index[first]
        first += 1


@numba.njit(cache=True)
def kdtree_indices(x: FloatArray, y: FloatArray) -> tuple[IntArray, bool]:  # pragma: no cover
    """``cKDTree(np.column_stack([x, y]), leafsize=KDTREE_LEAF_SIZE).indices`` and True,
    or False where ``_nth_element`` cannot follow libstdc++ (``_tree_paths``)."""
    index = np.arange(x.size)
    ok = _tree_paths(x, y, index, True)[3]
    return index, ok


@numba.njit(cache=True)
def _tree_paths(
    x: FloatArray, y: FloatArray, indices: IntArray, arrange: bool
) -> tuple[IntArray, IntArray, IntArray, bool]:  # pragma: no cover - compiled
    """Each point's position in the leaf order of ``cKDTree`` (``indices``: empty for
    one leaf, in the points' order), its path from the root as bits (first step in the
    highest of ``depth`` bits, 1 for the greater child), its depth, and True.

    scipy's balanced build with compact nodes (build.cxx, ``split_and_partition``): a
    node of more than a leaf is split in the dimension of the widest spread of its
    points (the first of equal ones; a node of equal points is a leaf) at its middle
    point's value by ``std::nth_element``, the points below that value moved ahead of
    the others in the lesser half (``std::partition``); none below it, the node's least
    value is the split. With ``arrange`` the build is made here: ``indices`` (then
    ``np.arange``) arranged in place into scipy's leaf order, or False returned where
    ``_nth_element`` cannot follow libstdc++. Without, ``indices`` is scipy's own, and
    the splits are found from it: the lesser child takes the node's points strictly
    below its middle value (all those equal to the least value when none is)."""
    n = x.size
    rank = np.empty(n, np.int64)
    path = np.zeros(n, np.int64)
    depth = np.zeros(n, np.int64)
    if indices.size == 0:
        for p in range(n):
            rank[p] = p
        return rank, path, depth, True
    # Nodes as (start, end) ranges of the leaf order, visited depth first.
    stack_start = np.empty(2 * n + 2, np.int64)
    stack_end = np.empty(2 * n + 2, np.int64)
    stack_start[0] = 0
    stack_end[0] = n
    top = 1
    while top > 0:
        top -= 1
        start = stack_start[top]
        end = stack_end[top]
        if end - start <= KDTREE_LEAF_SIZE:
            continue
        first = indices[start]
        hi_x = lo_x = x[first]
        hi_y = lo_y = y[first]
        for p in range(start + 1, end):
            q = indices[p]
            hi_x = hi_x if hi_x > x[q] else x[q]
            lo_x = lo_x if lo_x < x[q] else x[q]
            hi_y = hi_y if hi_y > y[q] else y[q]
            lo_y = lo_y if lo_y < y[q] else y[q]
        spread = 0.0
        if hi_x - lo_x > spread:
            spread = hi_x - lo_x
        values = x
        if hi_y - lo_y > spread:
            values = y
        elif hi_x == lo_x:
            continue  # all points equal: a leaf
        if arrange:
            middle = start + (end - start) // 2
            if not _nth_element(values, indices, start, middle, end):
                return rank, path, depth, False
            split = values[indices[middle]]
            cut = _partition_below(values, indices, start, middle, split)
            if cut == start:
                least = indices[start]
                for p in range(start + 1, end):
                    if values[indices[p]] < values[least]:
                        least = indices[p]
                split = np.nextafter(values[least], np.inf)
                cut = _partition_below(values, indices, start, end, split)
        else:
            node = np.empty(end - start)
            for p in range(start, end):
                node[p - start] = values[indices[p]]
            node.sort()
            split = node[(end - start) // 2]
            if split == node[0]:
                split = np.nextafter(split, np.inf)
            cut = start
            for p in range(start, end):
                if node[p - start] < split:
                    cut += 1
        for p in range(start, end):
            q = indices[p]
            path[q] = 2 * path[q] + (1 if p >= cut else 0)
            depth[q] += 1
        stack_start[top] = start
        stack_end[top] = cut
        stack_start[top + 1] = cut
        stack_end[top + 1] = end
        top += 2
    for p in range(n):
        rank[indices[p]] = p
    return rank, path, depth, True


@numba.njit(cache=True, inline="always")
def _search_rank(
    path_a: int, depth_a: int, path_b: int, depth_b: int, width: int
) -> int:  # pragma: no cover - compiled
    """The two leaves' paths interleaved as scipy's dual-tree walk takes them (a's step,
    then b's, while both are inner nodes; then the rest of the deeper one), left-aligned
    in ``width`` bits: pairs of leaves compare as the walk visits them."""
    key = 0
    bits = 0
    ia = depth_a
    ib = depth_b
    while ia > 0 or ib > 0:
        if ia > 0:
            ia -= 1
            key = 2 * key + ((path_a >> ia) & 1)
            bits += 1
        if ib > 0:
            ib -= 1
            key = 2 * key + ((path_b >> ib) & 1)
            bits += 1
    return key << (width - bits)


@numba.njit(cache=True)
def gate_pairs(
    near: IntArray,
    coarse_x: FloatArray,
    coarse_y: FloatArray,
    track_radius: FloatArray,
    tree_a: IntArray,
    plot_x: FloatArray,
    plot_y: FloatArray,
    plot_radius: FloatArray,
    tree_b: IntArray,
    reach: float,
    plot_time: FloatArray,
    plot_r: FloatArray,
    plot_address: IntArray,
    plot_code: IntArray,
    plot_code_valid: BoolArray,
    t: FloatArray,
    x: FloatArray,
    P: FloatArray,
    mu: FloatArray,
    address: IntArray,
    code: IntArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
    max_backward_s: float,
    gate: float,
    address_gate: float,
    apply_gate: bool,
    shared_codes: IntArray,
    address_mismatch_penalty: float,
    address_bonus: float,
    mode3a_bonus: float,
    arrange: bool,
    too_old: BoolArray,
) -> tuple[Any, ...]:  # pragma: no cover - compiled
    """The rest of ``Gate.__call__`` after ``preselect``: the pairs of ``near`` tracks
    (coarse positions, radii; ``tree_a``: ``cKDTree(coarse).indices`` when they are more
    than a leaf, else empty) and plots (``tree_b`` likewise) within ``reach`` and within
    the sum of their radii, in scipy's search order; the plots of pairs more than
    ``max_backward_s`` older than their track marked in ``too_old`` and those pairs
    dropped; the IMM prediction of the rest to their plots' times, the NIS and log det S
    and the identity cost; and, with ``apply_gate``, only the pairs inside their gate
    (``address_gate`` for the same Mode S address). With ``arrange``, the trees are
    built here (``_tree_paths``: ``tree_a``, ``tree_b`` then ``np.arange`` or empty).
    Returns whether the trees could be built (False: nothing else written, no pairs),
    then the track rows, plot indices, xp, Pp, c, xc, Pc, NIS, log det S and identity
    cost of the pairs."""
    rank_a, path_a, depth_a, ok_a = _tree_paths(coarse_x, coarse_y, tree_a, arrange)
    rank_b, path_b, depth_b, ok_b = _tree_paths(plot_x, plot_y, tree_b, arrange)
    ok = ok_a and ok_b
    na = near.size if ok else 0
    nb = plot_x.size
    width = depth_a.max() + depth_b.max() if na and nb else 0
    found_a = np.empty(na * nb, np.int64)
    found_b = np.empty(na * nb, np.int64)
    key = np.empty(na * nb, np.int64)
    k = 0
    for i in range(na):
        for j in range(nb):
            d0 = coarse_x[i] - plot_x[j]
            d1 = coarse_y[i] - plot_y[j]
            distance = np.sqrt(d0 * d0 + d1 * d1)
            if not distance <= reach:
                continue
            if not distance <= track_radius[i] + plot_radius[j]:
                continue
            found_a[k] = i
            found_b[k] = j
            leaves = _search_rank(path_a[i], depth_a[i], path_b[j], depth_b[j], width)
            key[k] = (leaves << 32) | (rank_a[i] << 16) | rank_b[j]
            k += 1
    order = np.argsort(key[:k], kind="mergesort")
    ti = np.empty(k, np.int64)
    pj = np.empty(k, np.int64)
    dt = np.empty(k)
    kept = 0
    for s in range(k):
        row = near[found_a[order[s]]]
        j = found_b[order[s]]
        step = plot_time[j] - t[row]
        if step < -max_backward_s:
            too_old[j] = True
            continue
        ti[kept] = row
        pj[kept] = j
        dt[kept] = step
        kept += 1
    ti = ti[:kept]
    pj = pj[:kept]
    xp, pp, c, xc, pc = imm_predict(x[ti], P[ti], mu[ti], dt[:kept], omega, q, sojourn)
    z = np.empty((kept, 2))
    for s in range(kept):
        z[s, 0] = plot_x[pj[s]]
        z[s, 1] = plot_y[pj[s]]
    r = plot_r[pj]
    nis, log_det = innovation_test(xc, pc, z, r)
    cost = np.empty(kept)
    inside = np.empty(kept, np.int64)
    n_inside = 0
    for s in range(kept):
        a_t = address[ti[s]]
        a_p = plot_address[pj[s]]
        same_address = a_t >= 0 and a_t == a_p
        if apply_gate and not nis[s] <= (address_gate if same_address else gate):
            continue
        inside[n_inside] = s
        n_inside += 1
        both = a_t >= 0 and a_p >= 0
        code_t = code[ti[s]]
        code_match = code_t >= 0 and code_t == plot_code[pj[s]] and plot_code_valid[pj[s]]
        if code_match:
            for shared in shared_codes:
                if code_t == shared:
                    code_match = False
        cost[s] = (
            address_mismatch_penalty * (1.0 if both and a_t != a_p else 0.0)
            - address_bonus * (1.0 if same_address and both else 0.0)
            - mode3a_bonus * (1.0 if code_match else 0.0)
        )
    if n_inside == kept:
        return ok, ti, pj, xp, pp, c, xc, pc, nis, log_det, cost
    g = inside[:n_inside]
    return ok, ti[g], pj[g], xp[g], pp[g], c[g], xc[g], pc[g], nis[g], log_det[g], cost[g]


@numba.njit(cache=True)
def gate_batch(
    plot_time: FloatArray,
    plot_x: FloatArray,
    plot_y: FloatArray,
    plot_r: FloatArray,
    plot_address: IntArray,
    plot_code: IntArray,
    plot_code_valid: BoolArray,
    n: int,
    t: FloatArray,
    xc: FloatArray,
    pc: FloatArray,
    x: FloatArray,
    P: FloatArray,
    mu: FloatArray,
    address: IntArray,
    code: IntArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
    constants: FloatArray,
    apply_gate: bool,
    shared_codes: IntArray,
    too_old: BoolArray,
) -> tuple[Any, ...]:  # pragma: no cover - compiled
    """``Gate.__call__`` of a batch against the ``n`` live tracks in one call: the
    batch's middle time and half spread, each track's step to it, the plots' radii,
    ``preselect`` and ``gate_pairs``, which builds the two trees.
    ``constants``: q_max, turn_max, the widest gate, the radius's safety factor and
    margin, max_backward_s, the gate, the address gate, the address mismatch penalty,
    the address bonus and the Mode 3/A bonus. The step's cube is this loop's, where
    numpy's SIMD power differs in the last bit of some values: the pre-selection
    radius is a bound that no gated pair comes near. Returns ``gate_pairs``' flag (False:
    a tree needs scipy, nothing written) and arrays."""
    t_min = t_max = plot_time[0]
    for j in range(1, plot_time.size):
        t_min = nan_min(t_min, plot_time[j])
        t_max = nan_max(t_max, plot_time[j])
    t_mid = 0.5 * (t_min + t_max)
    spread = max(t_max - t_mid, t_mid - t_min)
    dt = np.empty(n)
    a = np.empty(n)
    a_cubed = np.empty(n)
    for r in range(n):
        dt[r] = t_mid - t[r]
        a[r] = abs(dt[r]) + spread
        a_cubed[r] = a[r] * a[r] * a[r]
    gate = constants[6]
    plot_radius = np.empty(plot_x.size)
    for j in range(plot_x.size):
        plot_radius[j] = np.sqrt(gate * (plot_r[j, 0, 0] + plot_r[j, 1, 1]))
    near, coarse_x, coarse_y, radius, reach = preselect(
        xc, pc, dt, a, a_cubed, spread, constants[0], constants[1], constants[2],
        constants[3], constants[4], plot_x, plot_y, plot_radius,
    )  # fmt: skip
    # Trees of more than a leaf, built in gate_pairs; one leaf: the points' own order.
    tree_a = np.arange(near.size if near.size > KDTREE_LEAF_SIZE else 0)
    tree_b = np.arange(plot_x.size if plot_x.size > KDTREE_LEAF_SIZE else 0)
    return gate_pairs(
        near, coarse_x, coarse_y, radius, tree_a, plot_x, plot_y, plot_radius, tree_b,
        reach, plot_time, plot_r, plot_address, plot_code, plot_code_valid, t, x, P, mu,
        address, code, omega, q, sojourn, constants[5], gate, constants[7], apply_gate,
        shared_codes, constants[8], constants[9], constants[10], True, too_old,
    )  # fmt: skip
