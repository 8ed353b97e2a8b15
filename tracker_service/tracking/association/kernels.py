"""Compiled JPDA* kernels: the association weights of ``jpda`` and the weighted update of
``update``, each one pass over a batch's gated pairs, compiled by numba.

Why compiled: on the ``tma`` recording the numpy JPDA cost 2.5x GNN's CPU per plot
(issue 13 asks for at most 2x), half of it in the Python loops over clusters, events and
Murty's ranking (one scipy assignment per child), the rest in the ~40 array calls of the
weighted update on a few pairs per batch. Each kernel computes what its reference
computes, in the same order where the order decides anything: the clusters' tracks and
plots in ascending order, the events in the reference's order (exact enumeration depth
first; Murty's ranking by cost then by creation), scipy's shortest augmenting path for
the assignments (so that ties resolve alike), the first of equally likely permutations
kept by JPDA*. ``tests/test_association_kernels.py`` holds them to it (1e-9).
``cache=True`` keeps the compiled code on disk (``__pycache__``).
"""

from __future__ import annotations

import math

import numpy as np

from tracker_service.numba_symbols import numba
from tracker_service.tracking.kernels import imm_update
from tracker_service.tracking.plots import FloatArray, IntArray

FORBIDDEN = 1.0e12
"""Cost of a cell no event may use in Murty's ranking (as ``jpda.FORBIDDEN``)."""
TINY = 1e-300


@numba.njit(cache=True)
def _root(parent: IntArray, a: int) -> int:  # pragma: no cover - compiled
    while parent[a] != a:
        parent[a] = parent[parent[a]]
        a = parent[a]
    return a


@numba.njit(cache=True)
def jpda_weights(
    track: IntArray,
    plot: IntArray,
    score: FloatArray,
    log_miss: float,
    max_events: int,
    k_best: int,
) -> FloatArray:  # pragma: no cover - compiled
    """``JointProbabilisticDataAssociation``'s weight of every gated pair (before the
    ``MIN_WEIGHT`` cut): ``score`` is each pair's log likelihood ratio against clutter
    (Pd included), ``log_miss`` log(1 - Pd)."""
    n = track.size
    weight = np.empty(n)
    if n == 0:
        return weight
    n_rows = track.max() + 1
    n_cols = plot.max() + 1
    track_count = np.zeros(n_rows, np.int64)
    plot_count = np.zeros(n_cols, np.int64)
    for k in range(n):
        track_count[track[k]] += 1
        plot_count[plot[k]] += 1
    # Clusters: components of the graph of tracks and plots (plot j is node n_rows + j).
    parent = np.arange(n_rows + n_cols)
    rest = np.empty(n, np.int64)
    n_rest = 0
    for k in range(n):
        if track_count[track[k]] == 1 and plot_count[plot[k]] == 1:
            # A lone pair: the plot is the track's or clutter, the track detected or not.
            weight[k] = 1.0 / (1.0 + math.exp(log_miss - score[k]))
        else:
            a = _root(parent, track[k])
            b = _root(parent, n_rows + plot[k])
            if a != b:
                parent[a] = b
            rest[n_rest] = k
            n_rest += 1
    if n_rest == 0:
        return weight
    rest = rest[:n_rest]
    label = np.empty(n_rest, np.int64)
    for r in range(n_rest):
        label[r] = _root(parent, track[rest[r]])
    order = np.argsort(label, kind="mergesort")
    local_track = np.empty(n_rows, np.int64)
    local_plot = np.empty(n_cols, np.int64)
    start = 0
    while start < n_rest:
        stop = start + 1
        while stop < n_rest and label[order[stop]] == label[order[start]]:
            stop += 1
        members = rest[order[start:stop]]
        weight[members] = _cluster(
            track[members],
            plot[members],
            score[members],
            log_miss,
            max_events,
            k_best,
            local_track,
            local_plot,
        )
        start = stop
    return weight


@numba.njit(cache=True)
def _cluster(
    tracks: IntArray,
    plots: IntArray,
    score: FloatArray,
    log_miss: float,
    max_events: int,
    k_best: int,
    local_track: IntArray,
    local_plot: IntArray,
) -> FloatArray:  # pragma: no cover - compiled
    """``JointProbabilisticDataAssociation._cluster``: the marginal probability of each
    pair of one cluster (``local_*``: scratch maps from rows and plots to the cluster's)."""
    unique_tracks = np.unique(tracks)
    unique_plots = np.unique(plots)
    n_tracks, n_plots = unique_tracks.size, unique_plots.size
    for i in range(n_tracks):
        local_track[unique_tracks[i]] = i
    for j in range(n_plots):
        local_plot[unique_plots[j]] = j
    ti = np.empty(tracks.size, np.int64)
    pj = np.empty(tracks.size, np.int64)
    ratio = np.full((n_tracks, n_plots), -np.inf)
    options = np.ones(n_tracks, np.int64)
    for k in range(tracks.size):
        ti[k] = local_track[tracks[k]]
        pj[k] = local_plot[plots[k]]
        ratio[ti[k], pj[k]] = score[k]
        options[ti[k]] += 1
    product = 1.0
    for i in range(n_tracks):
        product *= float(options[i])
    if product <= max_events:
        events = _enumerate(ratio, options, int(product))
    else:
        events = _k_best(ratio, log_miss, k_best)
    marginal = _jpda_star(ratio, events, log_miss)
    out = np.empty(tracks.size)
    for k in range(tracks.size):
        out[k] = marginal[ti[k], pj[k]]
    return out


@numba.njit(cache=True)
def _enumerate(ratio: FloatArray, options: IntArray, capacity: int) -> IntArray:  # pragma: no cover
    """``jpda._enumerate``: every feasible joint event (rows: for each track its plot or
    -1), depth first, each track's miss before its plots in ascending order."""
    n_tracks, n_plots = ratio.shape
    choices = np.full((n_tracks, options.max()), -1, np.int64)
    for i in range(n_tracks):
        c = 1
        for j in range(n_plots):
            if np.isfinite(ratio[i, j]):
                choices[i, c] = j
                c += 1
    events = np.empty((capacity, n_tracks), np.int64)
    head = np.empty(n_tracks, np.int64)
    position = np.zeros(n_tracks, np.int64)
    used = np.zeros(n_plots, np.bool_)
    count = 0
    i = 0
    while i >= 0:
        if position[i] == options[i]:
            # Track i's choices exhausted: back to the previous track's next choice.
            i -= 1
            if i >= 0:
                if head[i] >= 0:
                    used[head[i]] = False
                position[i] += 1
            continue
        j = choices[i, position[i]]
        if j >= 0 and used[j]:
            position[i] += 1
            continue
        head[i] = j
        if i == n_tracks - 1:
            events[count] = head
            count += 1
            position[i] += 1
        else:
            if j >= 0:
                used[j] = True
            i += 1
            position[i] = 0
    return events[:count]


@numba.njit(cache=True)
def _sum(values: FloatArray) -> float:  # pragma: no cover - compiled
    """numpy's sum of a contiguous float64 array, bit for bit: sequential below 8 terms,
    eight interleaved partial sums up to 128, pairwise halves beyond (Murty's ranking
    orders by these sums, as the reference's ``chosen.sum()``)."""
    n = values.size
    if n < 8:
        total = 0.0
        for i in range(n):
            total += values[i]
        return total
    if n <= 128:
        r = values[:8].copy()
        i = 8
        while i < n - n % 8:
            for a in range(8):
                r[a] += values[i + a]
            i += 8
        total = float(((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7])))
        while i < n:
            total += values[i]
            i += 1
        return total
    half = n // 2
    half -= half % 8
    return _sum(values[:half]) + _sum(values[half:])


@numba.njit(cache=True)
def linear_sum_assignment(cost: FloatArray) -> IntArray:  # pragma: no cover - compiled
    """scipy's ``linear_sum_assignment`` of a matrix of no more rows than columns (the
    shortest augmenting path of Crouse 2016, step for step, so that ties resolve alike):
    each row's column, or an empty array when no full assignment is finite."""
    nr, nc = cost.shape
    c = cost - cost.min()
    u = np.zeros(nr)
    v = np.zeros(nc)
    shortest = np.empty(nc)
    path = np.full(nc, -1, np.int64)
    col4row = np.full(nr, -1, np.int64)
    row4col = np.full(nc, -1, np.int64)
    row_seen = np.zeros(nr, np.bool_)
    col_seen = np.zeros(nc, np.bool_)
    remaining = np.empty(nc, np.int64)
    for current in range(nr):
        for it in range(nc):
            # In reverse: a constant matrix gets the identity (scipy #11602).
            remaining[it] = nc - it - 1
        row_seen[:] = False
        col_seen[:] = False
        shortest[:] = np.inf
        n_remaining = nc
        min_val = 0.0
        i = current
        sink = -1
        while sink == -1:
            index = -1
            lowest = np.inf
            row_seen[i] = True
            for it in range(n_remaining):
                j = remaining[it]
                r = min_val + c[i, j] - u[i] - v[j]
                if r < shortest[j]:
                    path[j] = i
                    shortest[j] = r
                if shortest[j] < lowest or (shortest[j] == lowest and row4col[j] == -1):
                    lowest = shortest[j]
                    index = it
            min_val = lowest
            if min_val == np.inf:
                return np.empty(0, np.int64)
            j = remaining[index]
            if row4col[j] == -1:
                sink = j
            else:
                i = row4col[j]
            col_seen[j] = True
            n_remaining -= 1
            remaining[index] = remaining[n_remaining]
        u[current] += min_val
        for i in range(nr):
            if row_seen[i] and i != current:
                u[i] += min_val - shortest[col4row[i]]
        for j in range(nc):
            if col_seen[j]:
                v[j] -= min_val - shortest[j]
        j = sink
        while True:
            i = path[j]
            row4col[j] = i
            col4row[i], j = j, col4row[i]
            if i == current:
                break
    return col4row


@numba.njit(cache=True)
def _solve(cost: FloatArray, chosen: FloatArray) -> tuple[float, IntArray]:  # pragma: no cover
    """``jpda._k_best``'s ``solve``: the least-cost assignment and its cost, or an empty
    assignment when it must use a forbidden cell."""
    cols = linear_sum_assignment(cost)
    if cols.size == 0:
        return 0.0, cols
    for i in range(cols.size):
        chosen[i] = cost[i, cols[i]]
        if chosen[i] >= FORBIDDEN:
            return 0.0, np.empty(0, np.int64)
    return _sum(chosen), cols


@numba.njit(cache=True)
def _fix_row(c: FloatArray, i: int, j: int) -> None:  # pragma: no cover - compiled
    """Row i of ``c`` to column j only, and column j to row i only."""
    keep = c[i, j]
    c[i, :] = FORBIDDEN
    c[:, j] = FORBIDDEN
    c[i, j] = keep


@numba.njit(cache=True)
def _k_best(ratio: FloatArray, log_miss: float, k: int) -> IntArray:  # pragma: no cover
    """``jpda._k_best``: the ``k`` most likely joint events by Murty's ranking (rows as
    ``_enumerate``'s). A candidate keeps its solution and how it was made from the event
    it descends from (which row was forbidden its column, the rows before fixed); its
    matrix is rebuilt only when it is ranked, from its parent's."""
    n_tracks, n_plots = ratio.shape
    nc = n_plots + n_tracks
    cost = np.full((n_tracks, nc), FORBIDDEN)
    for i in range(n_tracks):
        for j in range(n_plots):
            if np.isfinite(ratio[i, j]):
                cost[i, j] = -ratio[i, j]
        cost[i, n_plots + i] = -log_miss
    chosen = np.empty(n_tracks)
    capacity = 1 + k * n_tracks
    cand_cost = np.empty(capacity)
    cand_cols = np.empty((capacity, n_tracks), np.int64)
    cand_parent = np.empty(capacity, np.int64)
    cand_row = np.empty(capacity, np.int64)
    waiting = np.zeros(capacity, np.bool_)
    ranked_cost = np.empty((k, n_tracks, nc))
    ranked_cols = np.empty((k, n_tracks), np.int64)
    events = np.empty((k, n_tracks), np.int64)
    total, cols = _solve(cost, chosen)  # every track may miss: always feasible
    cand_cost[0] = total
    cand_cols[0] = cols
    cand_parent[0] = -1
    cand_row[0] = 0
    waiting[0] = True
    n_cand = 1
    n_events = 0
    while n_events < k:
        best = -1
        for c in range(n_cand):
            # Least cost first, the earliest made among equals (the heap's tie counter).
            if waiting[c] and (best < 0 or cand_cost[c] < cand_cost[best]):
                best = c
        if best < 0:
            break
        waiting[best] = False
        e = n_events
        n_events += 1
        cols = cand_cols[best]
        ranked_cols[e] = cols
        for i in range(n_tracks):
            events[e, i] = cols[i] if cols[i] < n_plots else -1
        if n_events == k:
            break  # its children could not be ranked any more
        matrix = ranked_cost[e]
        parent = cand_parent[best]
        if parent < 0:
            matrix[:, :] = cost
        else:
            matrix[:, :] = ranked_cost[parent]
            parent_cols = ranked_cols[parent]
            row = cand_row[best]
            for i in range(row):
                _fix_row(matrix, i, parent_cols[i])
            matrix[row, parent_cols[row]] = FORBIDDEN
        fixed = matrix.copy()
        for i in range(n_tracks):
            child = fixed.copy()
            child[i, cols[i]] = FORBIDDEN
            total, child_cols = _solve(child, chosen)
            if child_cols.size:
                cand_cost[n_cand] = total
                cand_cols[n_cand] = child_cols
                cand_parent[n_cand] = e
                cand_row[n_cand] = i
                waiting[n_cand] = True
                n_cand += 1
            _fix_row(fixed, i, cols[i])
    return events[:n_events]


@numba.njit(cache=True)
def _key_hash(key: IntArray) -> np.uint64:  # pragma: no cover - compiled
    h = np.uint64(14695981039346656037)
    for v in key:
        h = (h ^ np.uint64(v + 1)) * np.uint64(1099511628211)
    return h


@numba.njit(cache=True)
def _jpda_star(
    ratio: FloatArray, events: IntArray, log_miss: float
) -> FloatArray:  # pragma: no cover
    """The marginal of each (track, plot) of a cluster from its events, JPDA*: of the
    events that detect the same tracks with the same plots, the first most likely only;
    the kept events in the order of their key's first appearance (the reference's dict)."""
    n_events, n_tracks = events.shape
    n_plots = ratio.shape[1]
    # The key of an event: which tracks are detected, then the plots taken, ascending.
    keys = np.full((n_events, 2 * n_tracks), -1, np.int64)
    log_w = np.empty(n_events)
    for e in range(n_events):
        w = 0.0
        for i in range(n_tracks):
            j = events[e, i]
            if j >= 0:
                w += ratio[i, j]
                keys[e, i] = 1
            else:
                w += log_miss
        log_w[e] = w
        plots = np.sort(events[e][events[e] >= 0])
        keys[e, n_tracks : n_tracks + plots.size] = plots
    # Open addressing on the keys' hashes; each group's best event.
    size = 1
    while size < 2 * n_events:
        size *= 2
    slot_group = np.full(size, -1, np.int64)
    group_event = np.empty(n_events, np.int64)
    n_groups = 0
    for e in range(n_events):
        s = np.int64(_key_hash(keys[e]) & np.uint64(size - 1))
        while True:
            g = slot_group[s]
            if g < 0:
                slot_group[s] = n_groups
                group_event[n_groups] = e
                n_groups += 1
                break
            if np.all(keys[group_event[g]] == keys[e]):
                if log_w[e] > log_w[group_event[g]]:
                    group_event[g] = e
                break
            s = (s + 1) & (size - 1)
    kept = log_w[group_event[:n_groups]]
    top = kept.max()
    probability = np.exp(kept - top)
    probability /= probability.sum()
    marginal = np.zeros((n_tracks, n_plots))
    for g in range(n_groups):
        e = group_event[g]
        for i in range(n_tracks):
            j = events[e, i]
            if j >= 0:
                marginal[i, j] += probability[g]
    return marginal


@numba.njit(cache=True)
def weighted_update(
    pair: IntArray,
    weight: FloatArray,
    owner_track: IntArray,
    pair_plot: IntArray,
    xp: FloatArray,
    pp: FloatArray,
    c: FloatArray,
    plot_xy: FloatArray,
    R: FloatArray,
    min_detection_weight: float,
) -> tuple[IntArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``update.weighted_update`` from the weighted pairs sorted by track, each track's
    most likely first (``pair``, ``weight``, the track of each in ``owner_track``):
    ``pair_plot``, ``xp``, ``pp``, ``c`` are the gated pairs' plots and per-model
    predictions. Returns the reported pair of each updated track and its per-model
    posterior x, P, mu: the mixture over its plots' IMM updates and its miss."""
    n = pair.size
    starts = np.empty(n + 1, np.int64)
    n_groups = 0
    for k in range(n):
        if k == 0 or owner_track[k] != owner_track[k - 1]:
            starts[n_groups] = k
            n_groups += 1
    starts[n_groups] = n
    total = np.zeros(n_groups)
    n_detected = 0
    n_kept = 0
    for g in range(n_groups):
        for k in range(starts[g], starts[g + 1]):
            total[g] += weight[k]
        if total[g] >= min_detection_weight:
            n_detected += 1
            n_kept += starts[g + 1] - starts[g]
    # The kept pairs' own IMM updates, in one call.
    kept = np.empty(n_kept, np.int64)
    group_of = np.empty(n_kept, np.int64)
    first = np.empty(n_detected, np.int64)
    group_total = np.empty(n_detected)
    r = 0
    g_new = 0
    for g in range(n_groups):
        if total[g] < min_detection_weight:
            continue
        first[g_new] = r
        group_total[g_new] = total[g]
        for k in range(starts[g], starts[g + 1]):
            kept[r] = k
            group_of[r] = g_new
            r += 1
        g_new += 1
    sel = pair[kept]
    x_j, p_j, mu_j, _, _ = imm_update(
        xp[sel], pp[sel], c[sel], plot_xy[pair_plot[sel]], R[pair_plot[sel]]
    )
    m = xp.shape[1]
    reported = np.empty(n_detected, np.int64)
    x = np.zeros((n_detected, m, 4))
    p = np.zeros((n_detected, m, 4, 4))
    mu = np.zeros((n_detected, m))
    d = np.empty(4)
    for g in range(n_detected):
        lo = first[g]
        hi = first[g + 1] if g + 1 < n_detected else n_kept
        best = sel[lo]
        reported[g] = best
        miss = min(max(1.0 - group_total[g], 0.0), 1.0)
        w_pair = weight[kept[lo:hi]]
        for j in range(m):
            # The components in the reference's order: the plots, then the miss.
            mass = 0.0
            for q in range(lo, hi):
                mass += w_pair[q - lo] * mu_j[q, j]
            mass += miss * c[best, j]
            safe = max(mass, TINY)
            for a in range(4):
                acc = 0.0
                for q in range(lo, hi):
                    acc += w_pair[q - lo] * mu_j[q, j] * x_j[q, j, a]
                acc += miss * c[best, j] * xp[best, j, a]
                x[g, j, a] = acc / safe
            for q in range(lo, hi + 1):
                if q < hi:
                    wq = w_pair[q - lo] * mu_j[q, j]
                    xs, ps = x_j[q, j], p_j[q, j]
                else:
                    wq = miss * c[best, j]
                    xs, ps = xp[best, j], pp[best, j]
                for a in range(4):
                    d[a] = xs[a] - x[g, j, a]
                for a in range(4):
                    for b in range(4):
                        p[g, j, a, b] += wq * (ps[a, b] + d[a] * d[b])
            for a in range(4):
                for b in range(4):
                    p[g, j, a, b] /= safe
            if mass <= TINY:
                # Every component underflowed: the prediction of the best plot.
                x[g, j] = xp[best, j]
                p[g, j] = pp[best, j]
            mu[g, j] = mass
        norm = 0.0
        for j in range(m):
            norm += mu[g, j]
        for j in range(m):
            mu[g, j] /= norm
            for a in range(4):
                for b in range(a + 1, 4):
                    s = 0.5 * (p[g, j, a, b] + p[g, j, b, a])
                    p[g, j, a, b] = s
                    p[g, j, b, a] = s
    return reported, x, p, mu


@numba.njit(cache=True)
def gnn_assignment(
    rows: IntArray, cols: IntArray, cost: FloatArray, unassignable: float
) -> IntArray:  # pragma: no cover - compiled
    """``associate.global_nearest_neighbour``: the indices of the pairs (rows[k], cols[k])
    of a least-cost one-to-one assignment, ascending. Pairs whose row and column have no
    other candidate are taken directly; the rest are solved as scipy's
    ``linear_sum_assignment`` solves the dense matrix of their rows and columns (cells
    without a pair ``unassignable``; a matrix of more rows than columns transposed, as
    scipy does), so that ties resolve alike."""
    n = rows.size
    if n == 0:
        return np.zeros(0, np.int64)
    row_count = np.zeros(rows.max() + 1, np.int64)
    col_count = np.zeros(cols.max() + 1, np.int64)
    for k in range(n):
        row_count[rows[k]] += 1
        col_count[cols[k]] += 1
    chosen = np.empty(n, np.int64)
    n_chosen = 0
    rest = np.empty(n, np.int64)
    n_rest = 0
    for k in range(n):
        if row_count[rows[k]] == 1 and col_count[cols[k]] == 1:
            chosen[n_chosen] = k
            n_chosen += 1
        else:
            rest[n_rest] = k
            n_rest += 1
    if n_rest == 0:
        return chosen
    # The rest's rows and columns in ascending order (np.unique), as matrix indices.
    row_index = np.full(row_count.size, -1, np.int64)
    col_index = np.full(col_count.size, -1, np.int64)
    for s in range(n_rest):
        row_index[rows[rest[s]]] = 0
        col_index[cols[rest[s]]] = 0
    n_r = 0
    for r in range(row_index.size):
        if row_index[r] == 0:
            row_index[r] = n_r
            n_r += 1
    n_c = 0
    for c in range(col_index.size):
        if col_index[c] == 0:
            col_index[c] = n_c
            n_c += 1
    matrix = np.full((n_r, n_c), unassignable)
    pair_at = np.full((n_r, n_c), -1, np.int64)
    for s in range(n_rest):
        k = rest[s]
        matrix[row_index[rows[k]], col_index[cols[k]]] = cost[k]
        pair_at[row_index[rows[k]], col_index[cols[k]]] = k
    if n_r <= n_c:
        col_of = linear_sum_assignment(matrix)
        for r in range(n_r):
            if pair_at[r, col_of[r]] >= 0:
                chosen[n_chosen] = pair_at[r, col_of[r]]
                n_chosen += 1
    else:
        row_of = linear_sum_assignment(np.ascontiguousarray(matrix.T))
        for c in range(n_c):
            if pair_at[row_of[c], c] >= 0:
                chosen[n_chosen] = pair_at[row_of[c], c]
                n_chosen += 1
    return np.sort(chosen[:n_chosen])
