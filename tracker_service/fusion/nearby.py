"""Spatial pre-selection of the pairs the fuser's chi-square tests can pass: association
(local track, system track) and merging (system track, system track). Without it each
new local track and each touched system track was tested against every live system
track: a cost per update growing with the traffic.

A pair passes a gate d^T S^-1 d <= g only if its positions are within sqrt(g tr(S_pos))
(the marginal form bounds the whole from below, and tr bounds the largest eigenvalue).
Every track is moved to the batch's middle time along its velocity, with a radius that
bounds its share of that distance: its own covariance predicted over the span (the
largest process noise of the models), its sensitivity to every radar's residual bias
times the largest bias covariance, its speed over the batch's time spread and the
largest turn over that span; two tracks are a candidate pair when they lie closer than
the sum of their radii (the local tracker's pre-selection, ``tracking/associate.py``,
with the same safety factor and margin).
"""

from __future__ import annotations

import numpy as np

from tracker_service.fusion.arrays import kernel_indices
from tracker_service.fusion.table import Columns
from tracker_service.tracking import imm
from tracker_service.tracking.associate import candidate_pairs
from tracker_service.tracking.plots import FloatArray, IntArray

RADIUS_SAFETY = 1.2
RADIUS_MARGIN_M = 50.0


def time_span(t: FloatArray) -> tuple[float, float]:
    """The middle and half the range of times t."""
    lo, hi = float(t.min()), float(t.max())
    return 0.5 * (lo + hi), 0.5 * (hi - lo)


def largest_bias(B: FloatArray) -> float:
    """The largest trace of the residual-bias covariances B (..., 2, 2)."""
    return float(np.trace(B, axis1=-2, axis2=-1).max(initial=0.0))


def reach(
    x: FloatArray,
    P: FloatArray,
    t: FloatArray,
    bias_var: FloatArray,
    t_mid: float,
    spread: float,
    gate: float,
    q_max: float,
    turn_max: float,
) -> tuple[FloatArray, FloatArray]:
    """Positions (k, 2) at ``t_mid`` of states x (k, 4) with covariances P (k, 4, 4) at
    times t, and a radius bounding each one's share of a passing pair's distance;
    ``bias_var`` (k,): a bound on the trace of its residual-bias terms over the span."""
    dt = t_mid - t
    a = np.abs(dt) + spread
    var = (
        P[:, 0, 0]
        + P[:, 1, 1]
        + 2.0 * a * np.abs(P[:, 0, 2] + P[:, 1, 3])
        + a * a * (P[:, 2, 2] + P[:, 3, 3])
        + 2.0 * q_max * a**3 / 3.0
        + bias_var
    )
    speed = np.hypot(x[:, 2], x[:, 3])
    turn = 0.5 * speed * turn_max * a * a
    # A turn moves the predicted mean, and the spread of the models' means widens S.
    var += turn * turn
    radius = (
        RADIUS_SAFETY * np.sqrt(gate * np.maximum(var, 0.0))
        + speed * spread
        + turn
        + RADIUS_MARGIN_M
    )
    return x[:, :2] + x[:, 2:] * dt[:, None], radius


def sensitivity_norm(M: FloatArray, t: FloatArray, t_mid: float, spread: float) -> FloatArray:
    """A bound on the squared Frobenius norm of the position rows of sensitivities M
    (k, radars, 4, 2) predicted over up to |t_mid - t| + spread, summed over radars."""
    a = np.abs(t_mid - t) + spread
    position = np.square(M[:, :, :2, :]).sum(axis=(1, 2, 3))
    velocity = np.square(M[:, :, 2:, :]).sum(axis=(1, 2, 3))
    return np.asarray(2.0 * (position + a * a * velocity), dtype=np.float64)


def system_reach(
    sys: Columns,
    numbers: IntArray,
    from_models: bool,
    bias_scale: float,
    t_mid: float,
    spread: float,
    gate: float,
    q_max: float,
    turn_max: float,
    compiled: bool,
) -> tuple[FloatArray, FloatArray]:
    """``reach`` of the system tracks ``numbers`` from their coarse state at their time
    (the IMM's combined models when ``from_models``, else x and P: the state the
    estimator's gate predicts from), their bias term ``bias_scale`` times their
    ``sensitivity_norm``; compiled: read in place by one kernel (a row's models and
    sensitivities are a kilobyte or more, and association takes every open system
    track each batch)."""
    if compiled:
        from tracker_service.fusion.kernels import system_reach as kernel  # numba on use

        return kernel(
            sys["x"],
            sys["P"],
            sys["moments"],
            sys["sensitivity"],
            sys["t"],
            kernel_indices(numbers),
            from_models,
            bias_scale,
            t_mid,
            spread,
            gate,
            q_max,
            turn_max,
        )
    if from_models:
        x, p = imm.combine(sys["mx"][numbers], sys["mP"][numbers], sys["mu"][numbers])
    else:
        x, p = sys["x"][numbers], sys["P"][numbers]
    t = sys["t"][numbers]
    sensitivity = sensitivity_norm(sys["M"][numbers], t, t_mid, spread)
    return reach(x, p, t, bias_scale * sensitivity, t_mid, spread, gate, q_max, turn_max)


def system_largest_bias(sys: Columns, numbers: IntArray, compiled: bool) -> float:
    """``largest_bias`` of the system tracks ``numbers`` (their field B (N, radars, 2, 2));
    compiled: from each track's ``largest_bias`` field (``refresh``)."""
    if not compiled:
        return largest_bias(sys["B"][numbers])
    return float(sys["largest_bias"][numbers].max(initial=0.0))


def refresh(sys: Columns, numbers: IntArray, compiled: bool) -> None:
    """After the models, sensitivities or residual biases of system tracks ``numbers``
    changed: their terms of the compiled pre-selection (the fields ``moments``,
    ``sensitivity`` and ``largest_bias``, ``kernels.refresh_moments``), which every
    writer of mx, mP, mu, M or B calls; the numpy path reads the fields themselves."""
    if not compiled or numbers.size == 0:
        return
    from tracker_service.fusion.kernels import refresh_moments

    refresh_moments(
        sys["mx"],
        sys["mP"],
        sys["mu"],
        sys["M"],
        sys["B"],
        kernel_indices(numbers),
        sys["moments"],
        sys["sensitivity"],
        sys["largest_bias"],
    )


DENSE_PAIRS_MAX = 1 << 20
"""Distances computed pair by pair up to this many (an 8 MB matrix); beyond, k-d trees."""


def near_pairs(
    xy_a: FloatArray,
    radius_a: FloatArray,
    xy_b: FloatArray,
    radius_b: FloatArray,
    compiled: bool = False,
) -> tuple[IntArray, IntArray]:
    """(i, j) with a[i] and b[j] closer than the sum of their radii, sorted by (i, j);
    compiled: in one pass (``kernels.near_pairs``), the same pairs.

    A box around the smaller set (a batch's few local or touched tracks) leaves the
    larger set's tracks near it; their distances to the smaller set are then computed
    all at once as ``tracking.associate.pairs_within`` computes them (the same test on
    the same numbers: the same pairs as its k-d trees, whose construction cost more than
    the fuser's tests per batch), or by ``candidate_pairs`` when the matrix would be
    large."""
    if compiled:
        from tracker_service.fusion.kernels import near_pairs as kernel  # numba on use

        return kernel(
            np.ascontiguousarray(xy_a, dtype=np.float64),
            np.ascontiguousarray(radius_a, dtype=np.float64),
            np.ascontiguousarray(xy_b, dtype=np.float64),
            np.ascontiguousarray(radius_b, dtype=np.float64),
        )
    empty = np.zeros(0, dtype=np.int64)
    a_larger = xy_a.shape[0] >= xy_b.shape[0]
    big, r_big, small, r_small = (
        (xy_a, radius_a, xy_b, radius_b) if a_larger else (xy_b, radius_b, xy_a, radius_a)
    )
    if small.shape[0] == 0:
        return empty, empty
    reach = float(r_big.max() + r_small.max())
    lo = small.min(axis=0) - reach
    hi = small.max(axis=0) + reach
    bx, by = big[:, 0], big[:, 1]
    near = np.flatnonzero((bx >= lo[0]) & (bx <= hi[0]) & (by >= lo[1]) & (by <= hi[1]))
    if near.size * small.shape[0] > DENSE_PAIRS_MAX:
        bi, si = candidate_pairs(big, r_big, small, r_small)
    else:
        dx = big[near, 0][:, None] - small[None, :, 0]
        dy = big[near, 1][:, None] - small[None, :, 1]
        distance = np.sqrt(dx * dx + dy * dy)
        rows, si = np.nonzero(distance <= r_big[near][:, None] + r_small[None, :])
        bi = near[rows]
    i, j = (bi, si) if a_larger else (si, bi)
    order = np.lexsort((j, i))
    return i[order], j[order]
