"""Compiled fusion kernels: the plot filter's consider IMM (``consider``) and the ML fusion
of local tracks (``ml``, ``estimator_tracks.fuse_local_tracks``) as numba loops over the
rows of a batch, reading and writing the fuser's tables in place.

Why compiled: issue 12 measured the fuser at 3,656 local-track updates per CPU-second at
4,000 aircraft against 20,000, most of it in the numpy overhead of these steps (a few
hundred array calls per batch on stacks of 4x4 and 4x2 matrices, and a batched LAPACK
call per group of equal source counts). Each kernel computes what its numpy reference
computes (``FusionConfig.implementation = "numpy"`` runs the reference), and
``tests/test_fusion_kernels.py`` holds them to it at 1e-9. ``cache=True`` as in
``tracking.kernels``: compiled once after an install, then loaded from ``__pycache__``.

Shapes: M models, L radars; a system track's models x (M, 4), P (M, 4, 4), sensitivities
to each radar's bias (M, L, 4, 2), probabilities (M,); the measurement is the position.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.nearby import RADIUS_MARGIN_M, RADIUS_SAFETY
from tracker_service.fusion.table import KEY_SHIFT
from tracker_service.numba_symbols import numba
from tracker_service.tracking.kernels import (
    _combine_row,
    _transition,
    add_white_acceleration_q,
    imm_mixing,
    propagate,
    white_acceleration_terms,
)
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

LOG_2PI = math.log(2.0 * math.pi)
FLOAT_MAX = float(np.finfo(np.float64).max)
TINY = 1e-300


@numba.njit(cache=True)
def _predict_track(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    n: int,
    step: float,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
    xp: FloatArray,
    pp: FloatArray,
    mp: FloatArray,
    c: FloatArray,
    r: int,
    sensors: IntArray,
    scratch: tuple[FloatArray, ...],
) -> None:  # pragma: no cover - compiled
    """``consider.predict`` of system track n (rows of the table's fields mx, mP, mM, mu)
    over ``step``: per-model states, covariances, sensitivities and predicted
    probabilities into row r of xp (k, M, 4), pp (k, M, 4, 4), mp (k, M, L, 4, 2), c (k, M);
    the sensitivities only to the radars ``sensors`` (``_active_sensors``: ascending, the
    others' left unset); ``scratch``: ``_prediction_scratch``'s arrays, allocated once
    per kernel call."""
    m = mx.shape[1]
    t = abs(step)
    pi, w, x0, p0, m0, fp, f, d = scratch
    imm_mixing(t, sojourn, mu[n], pi, c[r], w)
    for j in range(m):
        # Model j's mixed initial condition, sensitivities included (imm.mix_and_move).
        for a in range(4):
            acc = 0.0
            for i in range(m):
                acc += w[i, j] * mx[n, i, a]
            x0[a] = acc
        p0[:, :] = 0.0
        for sensor in sensors:  # the others are neither summed nor read
            m0[sensor] = 0.0
        for i in range(m):
            wij = w[i, j]
            for a in range(4):
                d[a] = mx[n, i, a] - x0[a]
            for a in range(4):
                for b in range(4):
                    p0[a, b] += wij * mP[n, i, a, b] + wij * d[a] * d[b]
            for sensor in sensors:
                for a in range(4):
                    m0[sensor, a, 0] += wij * mM[n, i, sensor, a, 0]
                    m0[sensor, a, 1] += wij * mM[n, i, sensor, a, 1]
        _transition(step, omega[j], f)
        propagate(f, x0, p0, fp, xp[r, j], pp[r, j])
        add_white_acceleration_q(pp[r, j], step, q[j])
        for sensor in sensors:
            for a in range(4):
                for b in range(2):
                    acc = 0.0
                    for e in range(4):
                        acc += f[a, e] * m0[sensor, e, b]
                    mp[r, j, sensor, a, b] = acc


@numba.njit(cache=True)
def _prediction_scratch(m: int, n_radars: int) -> tuple[FloatArray, ...]:  # pragma: no cover
    """The working arrays of ``_predict_track`` (a few allocations per track and pair
    cost as much as its arithmetic)."""
    return (
        np.empty((m, m)),
        np.empty((m, m)),
        np.empty(4),
        np.empty((4, 4)),
        np.empty((n_radars, 4, 2)),
        np.empty((4, 4)),
        np.empty((4, 4)),
        np.empty(4),
    )


@numba.njit(cache=True, inline="always")
def _active_sensors(active: BoolArray, sensors: IntArray) -> IntArray:  # pragma: no cover
    """The radars ``active`` (L,) marks, ascending, in the first entries of ``sensors``
    (L,): a track's loops over its few sensitive radars (4 of ``artas``' 51 sources)
    take those alone, where a pass over all L with a test each, some thirty passes a
    prediction, cost more than the arithmetic."""
    n = 0
    for sensor in range(active.size):
        if active[sensor]:
            sensors[n] = sensor
            n += 1
    return sensors[:n]


@numba.njit(cache=True, inline="always")
def _combine_sensitivities(
    mp: FloatArray, w: FloatArray, r: int, out: FloatArray, active: BoolArray
) -> None:  # pragma: no cover - compiled
    """Row r of ``consider.combine``: sum_j w[r, j] mp[r, j] into out[r] (L, 4, 2), the
    sensitivities to the radars not ``active`` (``_sensitive``) taken as +0.0 and not
    read. Their sum is +0.0 for finite weights (each term +0.0 or -0.0, added to +0.0):
    written without the arithmetic (a track is sensitive to a few of ``artas``' 51
    sources), which runs only for weights that are not all finite (NaN there)."""
    m, n_radars = mp.shape[1], mp.shape[2]
    finite = True
    for j in range(m):
        finite = finite and math.isfinite(w[r, j])
    for sensor in range(n_radars):
        if not active[sensor]:
            for a in range(4):
                for b in range(2):
                    acc = 0.0
                    if not finite:
                        for j in range(m):
                            acc += w[r, j] * 0.0
                    out[r, sensor, a, b] = acc
            continue
        for a in range(4):
            for b in range(2):
                acc = 0.0
                for j in range(m):
                    acc += w[r, j] * mp[r, j, sensor, a, b]
                out[r, sensor, a, b] = acc


@numba.njit(cache=True, inline="always")
def _sensitive(
    mM: FloatArray, n: int, radar: int, active: BoolArray
) -> None:  # pragma: no cover - compiled
    """active[l]: radar l is ``radar`` or system track n holds a sensitivity to its bias
    in some model. The others' are exactly zero, and stay zero through the prediction,
    the update and the combination (each is linear in them, every sum starting from
    +0.0): the kernels write +0.0 for them without the arithmetic (on ``scale`` a track
    is sensitive to 4 of 20 radars)."""
    m, n_radars = mM.shape[1], mM.shape[2]
    for sensor in range(n_radars):
        active[sensor] = sensor == radar
    # Model by model in memory order (a radar's entries are 8 of a model's 8 L): a
    # pass of the row without branches but one per radar.
    for j in range(m):
        for sensor in range(n_radars):
            nonzero = False
            for a in range(4):
                for b in range(2):
                    nonzero |= mM[n, j, sensor, a, b] != 0.0
            if nonzero:
                active[sensor] = True


@numba.njit(cache=True)
def consider_predict(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    numbers: IntArray,
    dt: FloatArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """System tracks ``numbers`` predicted over dt (``consider.predict``), combined:
    states (k, 4), noise covariances (k, 4, 4), sensitivities (k, L, 4, 2)."""
    k, m, n_radars = numbers.size, mx.shape[1], mM.shape[2]
    xp = np.empty((1, m, 4))
    pp = np.empty((1, m, 4, 4))
    mp = np.empty((1, m, n_radars, 4, 2))
    c = np.empty((1, m))
    xc = np.empty((k, 4))
    pc = np.empty((k, 4, 4))
    mc = np.empty((k, n_radars, 4, 2))
    one_x = np.empty((1, 4))
    one_p = np.empty((1, 4, 4))
    one_m = np.empty((1, n_radars, 4, 2))
    d = np.empty(4)
    active = np.empty(n_radars, dtype=np.bool_)
    order = np.empty(n_radars, dtype=np.int64)
    scratch = _prediction_scratch(m, n_radars)
    for r in range(k):
        _sensitive(mM, numbers[r], -1, active)
        sensors = _active_sensors(active, order)
        _predict_track(
            mx, mP, mM, mu, numbers[r], dt[r], omega, q, sojourn, xp, pp, mp, c, 0, sensors, scratch
        )
        _combine_row(xp, pp, c, 0, one_x, one_p, d)
        _combine_sensitivities(mp, c, 0, one_m, active)
        xc[r] = one_x[0]
        pc[r] = one_p[0]
        mc[r] = one_m[0]
    return xc, pc, mc


@numba.njit(cache=True)
def plot_filter_output(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    sys_t: FloatArray,
    solo: npt.NDArray[np.bool_],
    B: FloatArray,
    numbers: IntArray,
    t: FloatArray,
    latest: npt.NDArray[Any],
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``estimator_plots.PlotFilterEstimator.output`` in one call: the system tracks
    predicted to t (``consider_predict``), a solo track's state and covariance its
    founder's latest update (``latest``, one per number), plus the bias share of its
    sensitivities (``bias_share``): the same arithmetic in the same order."""
    k = numbers.size
    dt = np.empty(k)
    for r in range(k):
        dt[r] = t[r] - sys_t[numbers[r]]
    x, p, m_comb = consider_predict(mx, mP, mM, mu, numbers, dt, omega, q, sojourn)
    for r in range(k):
        if not solo[numbers[r]]:
            continue
        v = latest[r]
        x[r, 0], x[r, 1], x[r, 2], x[r, 3] = v["x"], v["y"], v["vx"], v["vy"]
        for a in range(4):
            for b in range(4):
                p[r, a, b] = v["P"][4 * a + b]
    share = bias_share(m_comb, B, numbers)
    for r in range(k):
        for a in range(4):
            for b in range(4):
                p[r, a, b] = p[r, a, b] + share[r, a, b]
    return x, p


@numba.njit(cache=True)
def emit_index(
    systems: IntArray,
    has_plot: npt.NDArray[np.bool_],
    plot_id: IntArray,
    time: FloatArray,
    sys_t_plot: FloatArray,
    confirmed: int,
    coasting: int,
) -> tuple[IntArray, IntArray, FloatArray, npt.NDArray[np.bool_], IntArray, npt.NDArray[np.int8]]:
    # pragma: no cover - compiled
    """``rows.emit``'s index of a batch's fed rows (system track ``systems``) in one
    pass: each system track's last row (ascending by number), its number and time,
    whether one of its rows has a plot (fresh), the plot of the last such row (-1: none)
    and the row's status; a fresh track's ``t_plot`` moved up to the time, as
    ``np.maximum`` moves it (NaN kept)."""
    size = 1
    for g in systems:
        size = max(size, g + 1)
    last_at = np.full(size, -1, dtype=np.int64)
    plot_at = np.full(size, -1, dtype=np.int64)
    for i in range(systems.size):
        last_at[systems[i]] = i
        if has_plot[i]:
            plot_at[systems[i]] = i
    k = 0
    for g in range(size):
        if last_at[g] >= 0:
            k += 1
    last = np.empty(k, dtype=np.int64)
    numbers = np.empty(k, dtype=np.int64)
    t = np.empty(k)
    fresh = np.empty(k, dtype=np.bool_)
    plot_of = np.empty(k, dtype=np.int64)
    status = np.empty(k, dtype=np.int8)
    r = 0
    for g in range(size):
        if last_at[g] < 0:
            continue
        last[r], numbers[r], t[r] = last_at[g], g, time[last_at[g]]
        fresh[r] = plot_at[g] >= 0
        plot_of[r] = plot_id[plot_at[g]] if fresh[r] else -1
        status[r] = confirmed if fresh[r] else coasting
        if fresh[r] and (t[r] > sys_t_plot[g] or math.isnan(t[r])):
            sys_t_plot[g] = t[r]
        r += 1
    return last, numbers, t, fresh, plot_of, status


@numba.njit(cache=True)
def plotted_updates(
    rows: IntArray,
    loc_system: IntArray,
    has_plot: npt.NDArray[np.bool_],
    created: IntArray,
    plot_ids: IntArray,
    wanted: IntArray,
) -> tuple[IntArray, IntArray, IntArray, IntArray, int]:  # pragma: no cover - compiled
    """``estimator_plots._plotted_updates``: the updates with a plot whose local row
    feeds a system track not ``created``, their system tracks, the row of ``plot_ids``
    holding each one's plot id ``wanted`` (the first of equal ids, as ``positions``
    finds it: a stable sort), each one's rank in order of appearance among its system
    track's, and the number of plot ids not found."""
    k = rows.size
    order = np.argsort(plot_ids, kind="mergesort")
    ordered = plot_ids[order]
    use = np.empty(k, dtype=np.int64)
    systems = np.empty(k, dtype=np.int64)
    found = np.empty(k, dtype=np.int64)
    size = 1
    n = 0
    unknown = 0
    for i in range(k):
        g = loc_system[rows[i]]
        if not has_plot[i] or g <= 0:
            continue
        new = False
        for c in created:
            new = new or c == g
        if new:
            continue
        at = np.searchsorted(ordered, wanted[i])
        if at >= ordered.size or ordered[at] != wanted[i]:
            unknown += 1
            continue
        use[n], systems[n], found[n] = i, g, order[at]
        size = max(size, g + 1)
        n += 1
    seen = np.zeros(size, dtype=np.int64)
    rank = np.empty(n, dtype=np.int64)
    for i in range(n):
        rank[i] = seen[systems[i]]
        seen[systems[i]] += 1
    return use[:n].copy(), systems[:n].copy(), found[:n].copy(), rank, unknown


@numba.njit(cache=True)
def gate_distances(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    sys_t: FloatArray,
    B: FloatArray,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    loc_radar: IntArray,
    local: IntArray,
    system: IntArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> FloatArray:  # pragma: no cover - compiled
    """``associate.distance`` with the "plots" estimator's gate prediction, pair by pair
    from the tables in place: system track system[r]'s IMM predicted to local track
    local[r]'s time (``consider_predict``), the residual biases' share of the pair's
    difference (the local track carries its radar's bias whole, the system track its
    sensitivities M to each radar's), the 4-dof chi-square distance by an LU solve."""
    k, m, n_radars = local.size, mx.shape[1], mM.shape[2]
    xp = np.empty((1, m, 4))
    pp = np.empty((1, m, 4, 4))
    mp = np.empty((1, m, n_radars, 4, 2))
    c = np.empty((1, m))
    one_x = np.empty((1, 4))
    one_p = np.empty((1, 4, 4))
    d = np.empty(4)
    s = np.empty((4, 4))
    g = np.empty((4, 2))
    gb = np.empty((4, 2))
    out = np.empty(k)
    active = np.empty(n_radars, dtype=np.bool_)
    order = np.empty(n_radars, dtype=np.int64)
    scratch = _prediction_scratch(m, n_radars)
    for r in range(k):
        n, row = system[r], local[r]
        radar = loc_radar[row]
        # A radar whose residual bias the system track holds none of (B = 0: none of its
        # plots updated it) adds nothing to S: its sensitivities are not predicted.
        for sensor in range(n_radars):
            active[sensor] = sensor == radar or (
                B[n, sensor, 0, 0] != 0.0
                or B[n, sensor, 0, 1] != 0.0
                or B[n, sensor, 1, 0] != 0.0
                or B[n, sensor, 1, 1] != 0.0
            )
        sensors = _active_sensors(active, order)
        _predict_track(
            mx,
            mP,
            mM,
            mu,
            n,
            loc_t[row] - sys_t[n],
            omega,
            q,
            sojourn,
            xp,
            pp,
            mp,
            c,
            0,
            sensors,
            scratch,
        )
        _combine_row(xp, pp, c, 0, one_x, one_p, d)
        for a in range(4):
            for b in range(4):
                s[a, b] = loc_P[row, a, b] + one_p[0, a, b]
        for sensor in sensors:
            # g = [sensor == radar] POSITION - M_sensor (M combined over the models); the
            # local track's own radar's bias covariance is its own (extra), the others'
            # the system track's.
            for a in range(4):
                for b in range(2):
                    acc = 0.0
                    for j in range(m):
                        acc += c[0, j] * mp[0, j, sensor, a, b]
                    g[a, b] = -acc
            if sensor == radar:
                g[0, 0] += 1.0
                g[1, 1] += 1.0
            for a in range(4):
                for b in range(2):
                    if sensor == radar:
                        gb[a, b] = g[a, 0] * loc_extra[row, 0, b] + g[a, 1] * loc_extra[row, 1, b]
                    else:
                        gb[a, b] = g[a, 0] * B[n, sensor, 0, b] + g[a, 1] * B[n, sensor, 1, b]
            for a in range(4):
                for b in range(4):
                    s[a, b] += gb[a, 0] * g[b, 0] + gb[a, 1] * g[b, 1]
        for a in range(4):
            d[a] = loc_x[row, a] - one_x[0, a]
        out[r] = _quadratic_form_lu(s, d)
    return out


@numba.njit(cache=True)
def review_tests(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    sys_t: FloatArray,
    B: FloatArray,
    solo: npt.NDArray[np.bool_],
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    loc_radar: IntArray,
    loc_system: IntArray,
    fails: IntArray,
    nis_n: IntArray,
    nis_mean: FloatArray,
    held: IntArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
    gate: float,
    reassociate_after: int,
    window: int,
    kappa_dof: float,
) -> IntArray:  # pragma: no cover - compiled
    """``associate.review``'s tests of the local rows ``held`` in their system tracks in
    one call: the gate's distances (``gate_distances``), the count of updates out of the
    gate and the consistency test's running mean written in place (a solo track's founder
    neither fails nor is inconsistent), the same arithmetic as the numpy path; returns
    the rows that fail either (in ``held``'s order)."""
    systems = np.empty(held.size, dtype=np.int64)
    for i in range(held.size):
        systems[i] = loc_system[held[i]]
    d2 = gate_distances(
        mx,
        mP,
        mM,
        mu,
        sys_t,
        B,
        loc_t,
        loc_x,
        loc_P,
        loc_extra,
        loc_radar,
        held,
        systems,
        omega,
        q,
        sojourn,
    )
    lost = np.empty(held.size, dtype=np.int64)
    n_lost = 0
    for i in range(held.size):
        h = held[i]
        alone = solo[systems[i]]
        fails[h] = 0 if (d2[i] <= gate or alone) else fails[h] + 1
        n = nis_n[h] + 1
        mean = nis_mean[h]
        mean += (d2[i] - mean) / min(n, window)
        nis_n[h], nis_mean[h] = n, mean
        if fails[h] >= reassociate_after or (n >= window and mean > kappa_dof and not alone):
            lost[n_lost] = h
            n_lost += 1
    return lost[:n_lost].copy()


@numba.njit(cache=True, inline="always")
def _track_distance(
    t: FloatArray, x: FloatArray, P: FloatArray, extra: FloatArray, i: int, j: int, q: float
) -> float:  # pragma: no cover - compiled
    """``associate.track_distance`` of local rows i and j from the local table's fields
    in place: j predicted to i's time at constant velocity (process noise q), both
    radars' residual biases (``extra``) in the covariance, the 4-dof chi-square
    distance. The constant-velocity prediction F x_j, F P_j F^T is summed term by term
    as ``propagate`` sums it with F's zero terms left out: the same bits for finite
    states at a fifth of the multiplications. In scalars (``_quadratic_form4``), where
    working arrays kept every entry in memory: 105 -> 60 ns a distance."""
    step = t[i] - t[j]
    # s = F P_j F^T: rows of F P_j (position rows take the velocity rows times step),
    # then its columns likewise; row e of s is s_e0..s_e3.
    s00 = P[j, 0, 0] + step * P[j, 2, 0]
    s01 = P[j, 0, 1] + step * P[j, 2, 1]
    s02 = P[j, 0, 2] + step * P[j, 2, 2]
    s03 = P[j, 0, 3] + step * P[j, 2, 3]
    s10 = P[j, 1, 0] + step * P[j, 3, 0]
    s11 = P[j, 1, 1] + step * P[j, 3, 1]
    s12 = P[j, 1, 2] + step * P[j, 3, 2]
    s13 = P[j, 1, 3] + step * P[j, 3, 3]
    s20, s21, s22, s23 = P[j, 2, 0], P[j, 2, 1], P[j, 2, 2], P[j, 2, 3]
    s30, s31, s32, s33 = P[j, 3, 0], P[j, 3, 1], P[j, 3, 2], P[j, 3, 3]
    s00, s01 = s00 + s02 * step, s01 + s03 * step
    s10, s11 = s10 + s12 * step, s11 + s13 * step
    s20, s21 = s20 + s22 * step, s21 + s23 * step
    s30, s31 = s30 + s32 * step, s31 + s33 * step
    q_pos, q_cross, q_vel = white_acceleration_terms(step, q)
    s00 += q_pos
    s11 += q_pos
    s02 += q_cross
    s20 += q_cross
    s13 += q_cross
    s31 += q_cross
    s22 += q_vel
    s33 += q_vel
    d0 = x[i, 0] - (x[j, 0] + step * x[j, 2])
    d1 = x[i, 1] - (x[j, 1] + step * x[j, 3])
    d2 = x[i, 2] - x[j, 2]
    d3 = x[i, 3] - x[j, 3]
    rows = (
        (
            s00 + P[i, 0, 0] + (extra[i, 0, 0] + extra[j, 0, 0]),
            s01 + P[i, 0, 1] + (extra[i, 0, 1] + extra[j, 0, 1]),
            s02 + P[i, 0, 2],
            s03 + P[i, 0, 3],
            d0,
        ),
        (
            s10 + P[i, 1, 0] + (extra[i, 1, 0] + extra[j, 1, 0]),
            s11 + P[i, 1, 1] + (extra[i, 1, 1] + extra[j, 1, 1]),
            s12 + P[i, 1, 2],
            s13 + P[i, 1, 3],
            d1,
        ),
        (s20 + P[i, 2, 0], s21 + P[i, 2, 1], s22 + P[i, 2, 2], s23 + P[i, 2, 3], d2),
        (s30 + P[i, 3, 0], s31 + P[i, 3, 1], s32 + P[i, 3, 2], s33 + P[i, 3, 3], d3),
    )
    return _quadratic_form4(rows)


@numba.njit(cache=True, inline="always")
def _row_pair_table(n: int) -> IntArray:  # pragma: no cover - compiled
    """An empty open-addressing table (-1: a free slot) for up to ``n`` keys of two rows
    (i << ``KEY_SHIFT`` | j), a power of two at least twice as large: a typed
    dictionary's lookup cost several times ``_slot_of``'s."""
    size = 16
    while size < 2 * n:
        size *= 2
    return np.full(size, -1, dtype=np.int64)


@numba.njit(cache=True, inline="always")
def _slot_of(table: IntArray, key: np.int64) -> np.int64:  # pragma: no cover - compiled
    """The slot of ``key`` (>= 0) in ``_row_pair_table``'s ``table``: where it is, or
    the free slot where it goes (Fibonacci hashing, linear probing)."""
    mask = table.size - 1
    at = np.int64((np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(40)) & mask
    while table[at] >= 0 and table[at] != key:
        at = (at + 1) & mask
    return at


@numba.njit(cache=True)
def exchange_votes(
    t: FloatArray,
    x: FloatArray,
    P: FloatArray,
    extra: FloatArray,
    closer: IntArray,
    farther: IntArray,
    witness: IntArray,
    ends: IntArray,
    q: float,
) -> tuple[FloatArray, npt.NDArray[np.bool_]]:  # pragma: no cover - compiled
    """``associate._exchange``'s votes in one pass: each witness's distance to the track
    it should be closer to less its distance to the other (``_track_distance``), then
    each pair's sum of its votes (``segment_sums``: numpy's bits) and whether every one
    of them favours the exchange (the pairs' vote segments are not empty). A distance
    is a function of its two rows alone: each (track, witness) is computed once (a
    track of several pairs meets the same witnesses again: 41 % of the distances of a
    batch on ``artas``) and found again in a table hashed by the two rows."""
    votes = np.empty(witness.size)
    known_key = _row_pair_table(2 * witness.size)
    known = np.empty(known_key.size)
    for r in range(witness.size):
        w = witness[r]
        near_far = 0.0
        for side in range(2):
            i = closer[r] if side == 0 else farther[r]
            key = (np.int64(i) << KEY_SHIFT) | np.int64(w)
            at = _slot_of(known_key, key)
            if known_key[at] < 0:
                known_key[at] = key
                known[at] = _track_distance(t, x, P, extra, i, w, q)
            if side == 0:
                near_far = known[at]
            else:
                votes[r] = near_far - known[at]
    favoured = np.empty(ends.size - 1, dtype=np.bool_)
    for k in range(ends.size - 1):
        agree = True
        for r in range(ends[k], ends[k + 1]):
            agree = agree and votes[r] > 0.0
        favoured[k] = agree
    return segment_sums(votes, ends), favoured


Row4 = tuple[float, float, float, float, float]
"""A row of a 4x4 system and its right-hand side: (s_e0, s_e1, s_e2, s_e3, d_e)."""


@numba.njit(cache=True, inline="always")
def _eliminate(pivot: Row4, row: Row4, col: int) -> Row4:  # pragma: no cover - compiled
    """``row`` less ``pivot`` times row[col] / pivot[col] (Gaussian elimination's step
    below the pivot); the entries left of ``col`` (never read again) as they were."""
    factor = row[col] / pivot[col]
    return (
        row[0] if col > 0 else row[0] - factor * pivot[0],
        row[1] if col > 1 else row[1] - factor * pivot[1],
        row[2] if col > 2 else row[2] - factor * pivot[2],
        row[3] - factor * pivot[3],
        row[4] - factor * pivot[4],
    )


@numba.njit(cache=True, inline="always")
def _quadratic_form4(rows: tuple[Row4, Row4, Row4, Row4]) -> float:  # pragma: no cover
    """d^T s^-1 d for a 4x4 s given as its rows with d (``Row4``), by Gaussian
    elimination with partial pivoting (LAPACK's gesv, as ``np.linalg.solve``: the
    first largest magnitude pivots, rows swapped whole), then back substitution; the
    arithmetic of a loop over working arrays in the same order, in scalars that stay
    in registers (the arrays kept each entry in memory: nearly half a distance's
    time). Inlined into its callers' loops: a call cost an eighth of the exchange
    test's distance."""
    r0, r1, r2, r3 = rows
    d0, d1, d2, d3 = r0[4], r1[4], r2[4], r3[4]
    # Column 0: the pivot among the four rows.
    if abs(r1[0]) > abs(r0[0]):
        if abs(r2[0]) > abs(r1[0]):
            if abs(r3[0]) > abs(r2[0]):
                r0, r3 = r3, r0
            else:
                r0, r2 = r2, r0
        elif abs(r3[0]) > abs(r1[0]):
            r0, r3 = r3, r0
        else:
            r0, r1 = r1, r0
    elif abs(r2[0]) > abs(r0[0]):
        if abs(r3[0]) > abs(r2[0]):
            r0, r3 = r3, r0
        else:
            r0, r2 = r2, r0
    elif abs(r3[0]) > abs(r0[0]):
        r0, r3 = r3, r0
    r1, r2, r3 = _eliminate(r0, r1, 0), _eliminate(r0, r2, 0), _eliminate(r0, r3, 0)
    # Column 1: among rows 1-3.
    if abs(r2[1]) > abs(r1[1]):
        if abs(r3[1]) > abs(r2[1]):
            r1, r3 = r3, r1
        else:
            r1, r2 = r2, r1
    elif abs(r3[1]) > abs(r1[1]):
        r1, r3 = r3, r1
    r2, r3 = _eliminate(r1, r2, 1), _eliminate(r1, r3, 1)
    if abs(r3[2]) > abs(r2[2]):
        r2, r3 = r3, r2
    r3 = _eliminate(r2, r3, 2)
    x3 = r3[4] / r3[3]
    x2 = (r2[4] - r2[3] * x3) / r2[2]
    x1 = ((r1[4] - r1[2] * x2) - r1[3] * x3) / r1[1]
    x0 = (((r0[4] - r0[1] * x1) - r0[2] * x2) - r0[3] * x3) / r0[0]
    return (((0.0 + d0 * x0) + d1 * x1) + d2 * x2) + d3 * x3


@numba.njit(cache=True, inline="always")
def _quadratic_form_lu(s: FloatArray, d: FloatArray) -> float:  # pragma: no cover - compiled
    """``_quadratic_form4`` of a 4x4 s and d (4,) held in arrays."""
    return _quadratic_form4(
        (
            (s[0, 0], s[0, 1], s[0, 2], s[0, 3], d[0]),
            (s[1, 0], s[1, 1], s[1, 2], s[1, 3], d[1]),
            (s[2, 0], s[2, 1], s[2, 2], s[2, 3], d[2]),
            (s[3, 0], s[3, 1], s[3, 2], s[3, 3], d[3]),
        )
    )


@numba.njit(cache=True)
def bias_share(M: FloatArray, B: FloatArray, rows: IntArray) -> FloatArray:  # pragma: no cover
    """``consider.bias_share`` of M (k, L, 4, 2) and B[rows] (B: the system table's field,
    (n, L, 2, 2)): sum_l M_l B_l M_l^T (k, 4, 4), where the numpy reference takes the
    rows of B copied. A radar whose sensitivities are all zero adds nothing when its
    bias is finite (each term +0.0 or -0.0, added to a sum that starts at +0.0 and so
    is never -0.0): skipped, the same bits (most of artas' 51 sources for a track)."""
    k, n_radars = M.shape[0], M.shape[1]
    out = np.zeros((k, 4, 4))
    mb = np.empty((4, 2))
    for r in range(k):
        n = rows[r]
        for sensor in range(n_radars):
            insensitive = True
            for a in range(4):
                for b in range(2):
                    insensitive = insensitive and M[r, sensor, a, b] == 0.0
            if insensitive and (
                math.isfinite(B[n, sensor, 0, 0])
                and math.isfinite(B[n, sensor, 0, 1])
                and math.isfinite(B[n, sensor, 1, 0])
                and math.isfinite(B[n, sensor, 1, 1])
            ):
                continue
            for a in range(4):
                for b in range(2):
                    mb[a, b] = M[r, sensor, a, 0] * B[n, sensor, 0, b] + (
                        M[r, sensor, a, 1] * B[n, sensor, 1, b]
                    )
            for a in range(4):
                for b in range(4):
                    out[r, a, b] += mb[a, 0] * M[r, sensor, b, 0] + mb[a, 1] * M[r, sensor, b, 1]
    return out


@numba.njit(cache=True)
def filter_round(
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    x: FloatArray,
    P: FloatArray,
    M: FloatArray,
    B: FloatArray,
    t: FloatArray,
    numbers: IntArray,
    time: FloatArray,
    z: FloatArray,
    R: FloatArray,
    radar: int,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> None:  # pragma: no cover - compiled
    """One round of ``estimator_plots._filter_round`` in place on the system table's
    fields: each system track of ``numbers`` (distinct) predicted to its plot's time,
    every model updated with the plot z (k, 2), R (k, 2, 2) of ``radar``, the radars'
    residual biases B considered (``consider.update``), then combined."""
    k, m, n_radars = numbers.size, mx.shape[1], mM.shape[2]
    xp = np.empty((1, m, 4))
    pp = np.empty((1, m, 4, 4))
    mp = np.empty((1, m, n_radars, 4, 2))
    c = np.empty((1, m))
    x_new = np.empty((1, m, 4))
    p_new = np.empty((1, m, 4, 4))
    m_new = np.empty((1, m, n_radars, 4, 2))
    mu_new = np.empty((1, m))
    xc = np.empty((1, 4))
    pc = np.empty((1, 4, 4))
    mc = np.empty((1, n_radars, 4, 2))
    g = np.empty((n_radars, 2, 2))
    bg = np.empty((n_radars, 2, 2))
    gain = np.empty((4, 2))
    cross = np.empty((4, 2))
    ikh = np.empty((4, 4))
    tmp = np.empty((4, 4))
    joseph = np.empty((4, 4))
    log_post = np.empty(m)
    d = np.empty(4)
    active = np.empty(n_radars, dtype=np.bool_)
    order = np.empty(n_radars, dtype=np.int64)
    scratch = _prediction_scratch(m, n_radars)
    for r in range(k):
        n = numbers[r]
        _sensitive(mM, n, radar, active)
        sensors = _active_sensors(active, order)
        _predict_track(
            mx, mP, mM, mu, n, time[r] - t[n], omega, q, sojourn, xp, pp, mp, c, 0, sensors, scratch
        )
        r00, r01, r10, r11 = R[r, 0, 0], R[r, 0, 1], R[r, 1, 0], R[r, 1, 1]
        for j in range(m):
            # G_l = H M_l - [l = radar] I, B_l G_l^T, S and the cross-covariance X.
            s00 = pp[0, j, 0, 0] + r00
            s01 = pp[0, j, 0, 1] + r01
            s10 = pp[0, j, 1, 0] + r10
            s11 = pp[0, j, 1, 1] + r11
            for a in range(4):
                cross[a, 0] = pp[0, j, a, 0]
                cross[a, 1] = pp[0, j, a, 1]
            for sensor in sensors:
                for a in range(2):
                    for b in range(2):
                        g[sensor, a, b] = mp[0, j, sensor, a, b]
                if sensor == radar:
                    g[sensor, 0, 0] -= 1.0
                    g[sensor, 1, 1] -= 1.0
                for a in range(2):
                    for b in range(2):
                        bg[sensor, a, b] = (
                            B[n, sensor, a, 0] * g[sensor, b, 0]
                            + B[n, sensor, a, 1] * g[sensor, b, 1]
                        )
                s00 += g[sensor, 0, 0] * bg[sensor, 0, 0] + g[sensor, 0, 1] * bg[sensor, 1, 0]
                s01 += g[sensor, 0, 0] * bg[sensor, 0, 1] + g[sensor, 0, 1] * bg[sensor, 1, 1]
                s10 += g[sensor, 1, 0] * bg[sensor, 0, 0] + g[sensor, 1, 1] * bg[sensor, 1, 0]
                s11 += g[sensor, 1, 0] * bg[sensor, 0, 1] + g[sensor, 1, 1] * bg[sensor, 1, 1]
                for a in range(4):
                    m_a0 = mp[0, j, sensor, a, 0]
                    m_a1 = mp[0, j, sensor, a, 1]
                    cross[a, 0] += m_a0 * bg[sensor, 0, 0] + m_a1 * bg[sensor, 1, 0]
                    cross[a, 1] += m_a0 * bg[sensor, 0, 1] + m_a1 * bg[sensor, 1, 1]
            det = s00 * s11 - s01 * s10
            i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
            y0 = z[r, 0] - xp[0, j, 0]
            y1 = z[r, 1] - xp[0, j, 1]
            for a in range(4):
                gain[a, 0] = cross[a, 0] * i00 + cross[a, 1] * i10
                gain[a, 1] = cross[a, 0] * i01 + cross[a, 1] * i11
                x_new[0, j, a] = xp[0, j, a] + (gain[a, 0] * y0 + gain[a, 1] * y1)
            # Joseph form for the (suboptimal for P alone) gain, symmetrised (imm.joseph).
            for a in range(4):
                for b in range(4):
                    ikh[a, b] = 1.0 if a == b else 0.0
                ikh[a, 0] -= gain[a, 0]
                ikh[a, 1] -= gain[a, 1]
            for a in range(4):
                for b in range(4):
                    acc = 0.0
                    for e in range(4):
                        acc += ikh[a, e] * pp[0, j, e, b]
                    tmp[a, b] = acc
            for a in range(4):
                kr0 = gain[a, 0] * r00 + gain[a, 1] * r10
                kr1 = gain[a, 0] * r01 + gain[a, 1] * r11
                for b in range(4):
                    acc = 0.0
                    for e in range(4):
                        acc += tmp[a, e] * ikh[b, e]
                    joseph[a, b] = acc + (kr0 * gain[b, 0] + kr1 * gain[b, 1])
            for a in range(4):
                for b in range(4):
                    p_new[0, j, a, b] = 0.5 * (joseph[a, b] + joseph[b, a])
            # M_l -= K G_l.
            for sensor in range(n_radars):
                if not active[sensor]:
                    m_new[0, j, sensor, :, :] = 0.0
                    continue
                for a in range(4):
                    for b in range(2):
                        m_new[0, j, sensor, a, b] = mp[0, j, sensor, a, b] - (
                            gain[a, 0] * g[sensor, 0, b] + gain[a, 1] * g[sensor, 1, b]
                        )
            nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
            log_lik = -0.5 * (nis + math.log(max(det, TINY))) - LOG_2PI
            log_post[j] = math.log(max(c[0, j], TINY)) + log_lik
        top = log_post.max()
        total = 0.0
        for j in range(m):
            mu_new[0, j] = math.exp(log_post[j] - top)
            total += mu_new[0, j]
        for j in range(m):
            mu_new[0, j] /= total
        _combine_row(x_new, p_new, mu_new, 0, xc, pc, d)
        _combine_sensitivities(m_new, mu_new, 0, mc, active)
        mx[n] = x_new[0]
        mP[n] = p_new[0]
        mM[n] = m_new[0]
        mu[n] = mu_new[0]
        x[n] = xc[0]
        P[n] = pc[0]
        M[n] = mc[0]
        t[n] = time[r]


@numba.njit(cache=True, inline="always")
def _count_sources(row: IntArray) -> int:  # pragma: no cover - compiled
    """The valid slots (>= 0) of a row of slots."""
    n = 0
    for slot in row:
        if slot >= 0:
            n += 1
    return n


@numba.njit(cache=True)
def _fusion_scratch(width: int) -> tuple[FloatArray, ...]:  # pragma: no cover - compiled
    """The working arrays of ``_predict_sources`` and ``_fuse_sources`` for rows of up to
    ``width`` sources, allocated once per call and sliced per row (allocated per row,
    they cost as much as the arithmetic of a row of two or three sources)."""
    return (
        np.empty((width, 4)),
        np.empty((width, 4, 4)),
        np.empty((width, 4, 4)),
        np.empty(width),
        np.empty((4, 4)),
        np.empty((4, 4)),
        np.empty((4 * width, 4 * width)),
        np.empty((4 * width, 4 * width)),
        np.empty((4 * width, 4)),
        np.empty(4 * width),
        np.empty(4 * width),
        np.empty((4, 4)),
        np.empty((4, 4)),
        np.empty(4),
    )


@numba.njit(cache=True)
def _predict_sources(
    sources: IntArray,
    n: int,
    t: float,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    correlation: float,
    scratch: tuple[FloatArray, ...],
) -> None:  # pragma: no cover - compiled
    """The local tracks ``sources[:n]`` CV-predicted to t: states, covariances, steps
    and (with a correlation) the covariances' symmetric square roots, into ``scratch``."""
    states, own, roots, dt, f, fp = (
        scratch[0],
        scratch[1],
        scratch[2],
        scratch[3],
        scratch[4],
        scratch[5],
    )
    for i in range(n):
        s = sources[i]
        step = t - loc_t[s]
        dt[i] = step
        f[:, :] = 0.0
        f[0, 0] = f[1, 1] = f[2, 2] = f[3, 3] = 1.0
        f[0, 2] = f[1, 3] = step
        propagate(f, loc_x[s], loc_P[s], fp, states[i], own[i])
    if correlation > 0.0:
        for i in range(n):
            _symmetric_sqrt4(own[i], roots[i])


@numba.njit(cache=True)
def _fuse_sources(
    sources: IntArray,
    chosen: IntArray,
    n: int,
    loc_extra: FloatArray,
    q: float,
    correlation: float,
    scratch: tuple[FloatArray, ...],
    x: FloatArray,
    p: FloatArray,
) -> None:  # pragma: no cover - compiled
    """ML fusion into x, p of the predicted sources ``chosen[:n]`` (positions in
    ``_predict_sources``' arrays of the local rows ``sources``): the joint covariance
    (own errors, their correlation, the shared prediction noise and each source's
    residual bias), then ``_ml_solve``."""
    states, own, roots, dt = scratch[0], scratch[1], scratch[2], scratch[3]
    sigma_of, low_of, y_of, wz_of, z_of = (
        scratch[6],
        scratch[7],
        scratch[8],
        scratch[9],
        scratch[10],
    )
    block, info, weighted = scratch[11], scratch[12], scratch[13]
    size = 4 * n
    sigma = sigma_of[:size, :size]
    sigma[:, :] = 0.0
    for i in range(n):
        ci = chosen[i]
        for a in range(4):
            for b in range(4):
                sigma[4 * i + a, 4 * i + b] = (1.0 - correlation) * own[ci, a, b]
    if correlation > 0.0:
        for i in range(n):
            for j in range(n):
                for a in range(4):
                    for b in range(4):
                        acc = 0.0
                        for e in range(4):
                            acc += roots[chosen[i], a, e] * roots[chosen[j], b, e]
                        sigma[4 * i + a, 4 * j + b] += correlation * acc
    for i in range(n):
        for j in range(n):
            di, dj = dt[chosen[i]], dt[chosen[j]]
            same_way = np.sign(di) == np.sign(dj)
            overlap = min(abs(di), abs(dj)) if same_way else 0.0
            block[:, :] = 0.0
            add_white_acceleration_q(block, overlap, q)
            if i == j:
                for a in range(2):
                    for b in range(2):
                        block[a, b] += loc_extra[sources[chosen[i]], a, b]
            for a in range(4):
                for b in range(4):
                    sigma[4 * i + a, 4 * j + b] += block[a, b]
    z = z_of[:size]
    for i in range(n):
        for a in range(4):
            z[4 * i + a] = states[chosen[i], a]
    _ml_solve(sigma, z, x, p, low_of, y_of, wz_of, info, weighted)


@numba.njit(cache=True)
def fuse_local_tracks(
    slots: IntArray,
    t: FloatArray,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    q: float,
    correlation: float,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``estimator_tracks.fuse_local_tracks``: per row, its local tracks (``slots``, valid
    first) CV-predicted to t and fused by ML (``ml.ml_fuse`` with the shared prediction
    noise and each source's residual bias, ``ml.shared_prediction_noise``); rows without
    a source get NaN."""
    k, width = slots.shape
    out_x = np.full((k, 4), np.nan)
    out_p = np.full((k, 4, 4), np.nan)
    scratch = _fusion_scratch(width)
    order = np.arange(width)
    for r in range(k):
        n = _count_sources(slots[r])
        if n == 0:
            continue
        _predict_sources(slots[r], n, t[r], loc_t, loc_x, loc_P, correlation, scratch)
        _fuse_sources(slots[r], order, n, loc_extra, q, correlation, scratch, out_x[r], out_p[r])
    return out_x, out_p


@numba.njit(cache=True)
def fuse_references(
    others: IntArray,
    kept: IntArray,
    t: FloatArray,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    q: float,
    correlation: float,
    everyone: bool,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``fuse_local_tracks`` of both of ``references``' sets of each row at once: its
    sources (``kept``, valid first) predicted once, and fused as a whole and without
    those ``others`` leaves out (a subsequence of ``kept``); the others' x and P, then
    all's. Without ``everyone``, the others' only (all's stay NaN): each source's
    prediction is its own, so the others' are the same numbers predicted alone."""
    k, width = kept.shape
    out = np.full((2, k, 4), np.nan)
    out_p = np.full((2, k, 4, 4), np.nan)
    scratch = _fusion_scratch(width)
    order = np.arange(width)
    chosen = np.empty(width, dtype=np.int64)
    for r in range(k):
        if not everyone:
            m = _count_sources(others[r])
            if m:
                _predict_sources(others[r], m, t[r], loc_t, loc_x, loc_P, correlation, scratch)
                _fuse_sources(
                    others[r], order, m, loc_extra, q, correlation, scratch, out[0, r], out_p[0, r]
                )
            continue
        n = _count_sources(kept[r])
        if n == 0:
            continue
        _predict_sources(kept[r], n, t[r], loc_t, loc_x, loc_P, correlation, scratch)
        m = 0
        for i in range(n):
            if m < width and others[r, m] == kept[r, i]:
                chosen[m] = i
                m += 1
        if m:
            _fuse_sources(
                kept[r], chosen, m, loc_extra, q, correlation, scratch, out[0, r], out_p[0, r]
            )
        _fuse_sources(kept[r], order, n, loc_extra, q, correlation, scratch, out[1, r], out_p[1, r])
    return out[0], out_p[0], out[1], out_p[1]


@numba.njit(cache=True)
def _symmetric_sqrt4(a: FloatArray, root: FloatArray) -> None:  # pragma: no cover - compiled
    """``ml.symmetric_sqrt`` of one symmetric 4x4 into root: cyclic Jacobi rotations to
    the eigenvectors (to rounding: the root is unique, whatever the method), negative
    eigenvalues of rounding clipped to 0."""
    m = a.copy()
    v = np.eye(4)
    scale = 0.0
    for i in range(4):
        for j in range(4):
            scale += m[i, j] * m[i, j]
    for _ in range(60):
        off = 0.0
        for i in range(4):
            for j in range(i + 1, 4):
                off += m[i, j] * m[i, j]
        if off <= 1e-36 * scale:
            break
        for p_ in range(3):
            for q_ in range(p_ + 1, 4):
                apq = m[p_, q_]
                if apq == 0.0:
                    continue
                theta = (m[q_, q_] - m[p_, p_]) / (2.0 * apq)
                t = 1.0 / (abs(theta) + math.sqrt(theta * theta + 1.0))
                if theta < 0.0:
                    t = -t
                c = 1.0 / math.sqrt(t * t + 1.0)
                s = t * c
                for e in range(4):
                    mep, meq = m[e, p_], m[e, q_]
                    m[e, p_] = c * mep - s * meq
                    m[e, q_] = s * mep + c * meq
                for e in range(4):
                    mpe, mqe = m[p_, e], m[q_, e]
                    m[p_, e] = c * mpe - s * mqe
                    m[q_, e] = s * mpe + c * mqe
                for e in range(4):
                    vep, veq = v[e, p_], v[e, q_]
                    v[e, p_] = c * vep - s * veq
                    v[e, q_] = s * vep + c * veq
    for a_ in range(4):
        for b in range(4):
            acc = 0.0
            for e in range(4):
                acc += v[a_, e] * math.sqrt(max(m[e, e], 0.0)) * v[b, e]
            root[a_, b] = acc


@numba.njit(cache=True)
def _ml_solve(
    sigma: FloatArray,
    z: FloatArray,
    x: FloatArray,
    p: FloatArray,
    low_of: FloatArray,
    y_of: FloatArray,
    wz_of: FloatArray,
    info: FloatArray,
    weighted: FloatArray,
) -> None:  # pragma: no cover - compiled
    """``ml.ml_fuse``'s estimate from the joint covariance sigma (4n, 4n) of the stacked
    estimates z (4n,): P = (H^T sigma^-1 H)^-1, x = P H^T sigma^-1 z, H the stacked
    identities; by a Cholesky factor sigma = L L^T (Y = L^-1 H, info = Y^T Y), and by
    LAPACK's LU, as the reference, when sigma is not numerically positive definite.
    ``low_of``, ``y_of``, ``wz_of`` (sliced), ``info`` and ``weighted``: working arrays."""
    size = sigma.shape[0]
    low = low_of[:size, :size]
    low[:, :] = 0.0
    for j in range(size):
        acc = sigma[j, j]
        for e in range(j):
            acc -= low[j, e] * low[j, e]
        if not acc > 0.0:
            _ml_solve_lu(np.ascontiguousarray(sigma), z, x, p)
            return
        low[j, j] = math.sqrt(acc)
        for i in range(j + 1, size):
            acc = sigma[i, j]
            for e in range(j):
                acc -= low[i, e] * low[j, e]
            low[i, j] = acc / low[j, j]
    y = y_of[:size]
    y[:, :] = 0.0
    wz = wz_of[:size]
    for i in range(size):
        for b in range(4):
            acc = 1.0 if i % 4 == b else 0.0
            for e in range(i):
                acc -= low[i, e] * y[e, b]
            y[i, b] = acc / low[i, i]
        acc = z[i]
        for e in range(i):
            acc -= low[i, e] * wz[e]
        wz[i] = acc / low[i, i]
    info[:, :] = 0.0
    weighted[:] = 0.0
    for a in range(4):
        for i in range(size):
            weighted[a] += y[i, a] * wz[i]
        for b in range(4):
            acc = 0.0
            for i in range(size):
                acc += y[i, a] * y[i, b]
            info[a, b] = acc
    _finish(np.linalg.inv(info), weighted, x, p)


@numba.njit(cache=True)
def _ml_solve_lu(
    sigma: FloatArray, z: FloatArray, x: FloatArray, p: FloatArray
) -> None:  # pragma: no cover - compiled
    """``_ml_solve`` as the reference computes it (LU solve of sigma against H)."""
    size = sigma.shape[0]
    h = np.zeros((size, 4))
    for i in range(size):
        h[i, i % 4] = 1.0
    gain = np.linalg.solve(sigma, h)
    info = np.zeros((4, 4))
    weighted = np.zeros(4)
    for i in range(size):
        for a in range(4):
            weighted[a] += gain[i, a] * z[i]
            for b in range(4):
                info[a, b] += gain[i, b] if i % 4 == a else 0.0
    _finish(np.linalg.inv(info), weighted, x, p)


@numba.njit(cache=True, inline="always")
def _finish(
    inverse: npt.NDArray[Any], weighted: FloatArray, x: FloatArray, p: FloatArray
) -> None:  # pragma: no cover - compiled
    """P symmetrised, then x = P (H^T sigma^-1 z), as ``ml.ml_fuse``."""
    for a in range(4):
        for b in range(4):
            p[a, b] = 0.5 * (inverse[a, b] + inverse[b, a])
    for a in range(4):
        acc = 0.0
        for b in range(4):
            acc += p[a, b] * weighted[b]
        x[a] = acc


@numba.njit(cache=True)
def store_updates(
    rows: IntArray,
    u: npt.NDArray[Any],
    extra: FloatArray,
    has_plot: npt.NDArray[np.bool_],
    with_mu: bool,
    system: IntArray,
    alive: npt.NDArray[np.bool_],
    radar: IntArray,
    confirmed: int,
    counts: IntArray,
    status: npt.NDArray[np.int8],
    address: IntArray,
    mode3a: IntArray,
    fl: FloatArray,
    rate: FloatArray,
    t_fl: FloatArray,
    t: FloatArray,
    x: FloatArray,
    P: FloatArray,
    extra_of: FloatArray,
    mu: FloatArray,
    plot_id: IntArray,
    t_plot: FloatArray,
) -> None:  # pragma: no cover - compiled
    """``table.LocalTrackTable.store`` into the local table's fields: per row, its
    batch's last update (``u``, ``track_update_dtype``) gives the status, the identity
    where known and the flight level where finite; its last update with a plot (or its
    last, while it has no state) gives the state, the residual bias, the model
    probabilities (``with_mu``) and the plot. A live feeding row that becomes or stops
    being ``confirmed`` is counted in or out of ``counts`` (``_count_feeder``)."""
    k = rows.size
    size = 1
    for i in range(k):
        size = max(size, rows[i] + 1)
    stateless = np.empty(k, dtype=np.bool_)
    for i in range(k):
        stateless[i] = math.isnan(t[rows[i]])
    done = np.zeros(size, dtype=np.bool_)
    for i in range(k - 1, -1, -1):
        r = rows[i]
        if done[r]:
            continue
        done[r] = True
        v = u[i]
        if alive[r] and system[r] > 0 and (status[r] == confirmed) != (v["status"] == confirmed):
            _count_feeder(counts, radar[r], system[r], 1 if v["status"] == confirmed else -1)
        status[r] = v["status"]
        if v["address"] >= 0:
            address[r] = v["address"]
        if v["mode3a"] >= 0:
            mode3a[r] = v["mode3a"]
        level = v["flight_level"]
        if math.isfinite(level):
            fl[r] = level
            climb = v["climb_rate_fl_per_s"]
            # np.nan_to_num: NaN to 0, infinities to the largest finite values.
            if math.isnan(climb):
                climb = 0.0
            elif math.isinf(climb):
                climb = FLOAT_MAX if climb > 0.0 else -FLOAT_MAX
            rate[r] = climb
            t_fl[r] = v["time"]
    done[:] = False
    for i in range(k - 1, -1, -1):
        r = rows[i]
        if done[r] or not (has_plot[i] or stateless[i]):
            continue
        done[r] = True
        v = u[i]
        t[r] = v["time"]
        x[r, 0] = v["x"]
        x[r, 1] = v["y"]
        x[r, 2] = v["vx"]
        x[r, 3] = v["vy"]
        for a in range(4):
            for b in range(4):
                P[r, a, b] = v["P"][4 * a + b]
        extra_of[r] = extra[i]
        if with_mu:
            for m in range(mu.shape[1]):
                mu[r, m] = v["model_probabilities"][m]
        if has_plot[i]:
            plot_id[r] = v["plot_id"]
            t_plot[r] = v["time"]


@numba.njit(cache=True)
def fill_system_rows(
    out: npt.NDArray[Any],
    numbers: IntArray,
    t: FloatArray,
    x: FloatArray,
    p: FloatArray,
    status: npt.NDArray[np.int8],
    slots: IntArray,
    loc_radar: IntArray,
    loc_number: IntArray,
    loc_plot_id: IntArray,
    loc_fl: FloatArray,
    loc_rate: FloatArray,
    loc_t_fl: FloatArray,
    loc_address: IntArray,
    loc_mode3a: IntArray,
    sys_address: IntArray,
    sys_mode3a: IntArray,
) -> None:  # pragma: no cover - compiled
    """``rows.system_rows`` into ``out`` (zeros of ``SYSTEM_UPDATE_DTYPE``): each row's
    state and status, its local tracks (``slots``, valid first), the flight level and
    rate of the first of them with a level (extrapolated to t), the identity of the first
    that knows it (else the system track's)."""
    width = slots.shape[1]
    for r in range(numbers.size):
        row = out[r]
        row["system_number"] = numbers[r]
        row["time"] = t[r]
        row["x"] = x[r, 0]
        row["y"] = x[r, 1]
        row["vx"] = x[r, 2]
        row["vy"] = x[r, 3]
        for a in range(4):
            for b in range(4):
                row["P"][4 * a + b] = p[r, a, b]
        row["status"] = status[r]
        row["plot_id"] = -1
        n = 0
        level = -1
        address = -1
        mode3a = -1
        for i in range(width):
            s = slots[r, i]
            if s < 0:
                row["local_radars"][i] = -1
                row["local_numbers"][i] = -1
                row["local_plot_ids"][i] = -1
                continue
            n += 1
            row["local_radars"][i] = loc_radar[s]
            row["local_numbers"][i] = loc_number[s]
            row["local_plot_ids"][i] = loc_plot_id[s]
            if level < 0 and math.isfinite(loc_fl[s]):
                level = s
            if address < 0 and loc_address[s] >= 0:
                address = loc_address[s]
            if mode3a < 0 and loc_mode3a[s] >= 0:
                mode3a = loc_mode3a[s]
        row["n_sources"] = n
        if level >= 0:
            rate = loc_rate[level]
            row["flight_level"] = loc_fl[level] + rate * (t[r] - loc_t_fl[level])
            row["climb_rate_fl_per_s"] = rate if math.isfinite(row["flight_level"]) else np.nan
        else:
            row["flight_level"] = np.nan
            row["climb_rate_fl_per_s"] = np.nan
        row["address"] = address if address >= 0 else sys_address[numbers[r]]
        row["mode3a"] = mode3a if mode3a >= 0 else sys_mode3a[numbers[r]]


@numba.njit(cache=True)
def near_pairs(
    xy_a: FloatArray, radius_a: FloatArray, xy_b: FloatArray, radius_b: FloatArray
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """``nearby.near_pairs``: the larger set's points in the box around the smaller one,
    then each pair's distance (as ``pairs_within`` computes it) against the sum of the
    radii; found in (i, j) order."""
    a_larger = xy_a.shape[0] >= xy_b.shape[0]
    big, r_big, small, r_small = xy_a, radius_a, xy_b, radius_b
    if not a_larger:
        big, r_big, small, r_small = xy_b, radius_b, xy_a, radius_a
    n_small = small.shape[0]
    if n_small == 0 or big.shape[0] == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    reach = r_big.max() + r_small.max()
    lo0, lo1 = small[:, 0].min() - reach, small[:, 1].min() - reach
    hi0, hi1 = small[:, 0].max() + reach, small[:, 1].max() + reach
    near = np.empty(big.shape[0], dtype=np.int64)
    n_near = 0
    for k in range(big.shape[0]):
        if lo0 <= big[k, 0] <= hi0 and lo1 <= big[k, 1] <= hi1:
            near[n_near] = k
            n_near += 1
    passing = np.zeros((n_near, n_small), dtype=np.bool_)
    count = 0
    for q in range(n_near):
        k = near[q]
        for m in range(n_small):
            dx = big[k, 0] - small[m, 0]
            dy = big[k, 1] - small[m, 1]
            if math.sqrt(dx * dx + dy * dy) <= r_big[k] + r_small[m]:
                passing[q, m] = True
                count += 1
    i = np.empty(count, dtype=np.int64)
    j = np.empty(count, dtype=np.int64)
    at = 0
    if a_larger:
        for q in range(n_near):
            for m in range(n_small):
                if passing[q, m]:
                    i[at], j[at] = near[q], m
                    at += 1
    else:
        for m in range(n_small):
            for q in range(n_near):
                if passing[q, m]:
                    i[at], j[at] = m, near[q]
                    at += 1
    return i, j


@numba.njit(cache=True)
def lookup_rows(
    index_keys: IntArray, index_rows: IntArray, radar: int, numbers: IntArray
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """``table.LocalTrackTable.find``'s lookup: each local track's key (radar <<
    ``KEY_SHIFT`` | number) and its row by binary search in the sorted index (-1: none)."""
    k = numbers.size
    keys = np.empty(k, dtype=np.int64)
    rows = np.full(k, -1, dtype=np.int64)
    for i in range(k):
        key = (np.int64(radar) << KEY_SHIFT) | np.int64(numbers[i])
        keys[i] = key
        at = np.searchsorted(index_keys, key)
        if at < index_keys.size and index_keys[at] == key:
            rows[i] = index_rows[at]
    return keys, rows


@numba.njit(cache=True)
def feeding_sets(counts: IntArray, own_radar: int) -> tuple[bool, IntArray, IntArray]:
    # pragma: no cover - compiled
    """``associate._feeding`` from ``table.LocalTrackTable.confirmed_feeders``' counts,
    where a pass over the ~20,000 rows of the local table took 45 us a batch: whether
    the confirmed live rows feeding a system track come from more than one radar, the
    system tracks they feed and those fed by ``own_radar``'s (ascending)."""
    every_radar = counts.shape[0] - 1
    radars = 0
    for radar in range(every_radar):
        if counts[radar, 0] > 0:
            radars += 1
    fed = np.flatnonzero(counts[every_radar, 1:]) + 1
    return radars > 1, fed, np.flatnonzero(counts[own_radar, 1:]) + 1


@numba.njit(cache=True)
def radars_feeding(
    alive: npt.NDArray[np.bool_], system: IntArray, radar: IntArray, size: int, n_radars: int
) -> npt.NDArray[np.bool_]:  # pragma: no cover - compiled
    """``lifecycle.merge``'s table of the radars feeding each system track (size,
    n_radars), from the live local rows in one pass."""
    out = np.zeros((size, n_radars), dtype=np.bool_)
    for r in range(system.size):
        if alive[r] and system[r] > 0:
            out[system[r], radar[r]] = True
    return out


@numba.njit(cache=True)
def exchange_witnesses(
    li: IntArray,
    sj: IntArray,
    head: IntArray,
    next_row: IntArray,
    loc_alive: npt.NDArray[np.bool_],
    loc_status: npt.NDArray[np.int8],
    confirmed: int,
    loc_system: IntArray,
    loc_radar: IntArray,
    size: int,
) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray, IntArray]:  # pragma: no cover
    """``associate._exchange_witnesses`` from the local table's fields: the confirmed
    live rows that feed a candidate's S or S' (candidates near their own system track
    left out), each track's from its list of feeders (``assign_feeders``: ``head``,
    ``next_row``) in ascending row order, as a pass over the table would give them;
    each candidate's l' (the first row of its radar in S') and the other radars' rows of
    S and S', the pairs kept the first time they come (a table of their rows), then
    the votes pair by pair."""
    wanted = np.zeros(size, dtype=np.bool_)
    numbers = np.empty(2 * li.size, dtype=np.int64)
    n_numbers = 0
    for i in range(li.size):
        if sj[i] != loc_system[li[i]]:
            for g in (sj[i], loc_system[li[i]]):
                if not wanted[g]:
                    wanted[g] = True
                    numbers[n_numbers] = g
                    n_numbers += 1
    n_involved = 0
    for k in range(n_numbers):
        r = head[numbers[k]]
        while r >= 0:
            if loc_alive[r] and loc_status[r] == confirmed:
                n_involved += 1
            r = next_row[r]
    # Each wanted track's rows at grouped[start[g]:end[g]] (read for wanted tracks only).
    start = np.empty(size, dtype=np.int64)
    end = np.empty(size, dtype=np.int64)
    grouped = np.empty(n_involved, dtype=np.int64)
    filled = 0
    for k in range(n_numbers):
        g = numbers[k]
        start[g] = filled
        r = head[g]
        while r >= 0:
            if loc_alive[r] and loc_status[r] == confirmed:
                # Insertion in ascending row order (a list holds a few rows).
                at = filled
                while at > start[g] and grouped[at - 1] > r:
                    grouped[at] = grouped[at - 1]
                    at -= 1
                grouped[at] = r
                filled += 1
            r = next_row[r]
        end[g] = filled
    k = li.size
    pair_a = np.empty(k, dtype=np.int64)
    pair_b = np.empty(k, dtype=np.int64)
    pair_s = np.empty(k, dtype=np.int64)
    n_pairs = 0
    n_votes = 0
    seen = _row_pair_table(k)
    for i in range(k):
        here, there, radar = loc_system[li[i]], sj[i], loc_radar[li[i]]
        if here == there:
            continue
        partner = -1
        others_there = 0
        for q in range(start[there], end[there]):
            if loc_radar[grouped[q]] != radar:
                others_there += 1
            elif partner < 0:
                partner = grouped[q]
        others_here = 0
        for q in range(start[here], end[here]):
            if loc_radar[grouped[q]] != radar:
                others_here += 1
        if partner < 0 or others_there == 0 or others_here == 0:
            continue
        # A pair of rows is a pair of keys (the live rows' keys are distinct).
        rows_key = (np.int64(min(li[i], partner)) << KEY_SHIFT) | np.int64(max(li[i], partner))
        slot = _slot_of(seen, rows_key)
        if seen[slot] >= 0:
            continue
        seen[slot] = rows_key
        pair_a[n_pairs], pair_b[n_pairs], pair_s[n_pairs] = li[i], partner, there
        n_pairs += 1
        n_votes += others_here + others_there
    closer = np.empty(n_votes, dtype=np.int64)
    farther = np.empty(n_votes, dtype=np.int64)
    witness = np.empty(n_votes, dtype=np.int64)
    ends = np.zeros(n_pairs + 1, dtype=np.int64)
    at = 0
    for p in range(n_pairs):
        a, b = pair_a[p], pair_b[p]
        radar = loc_radar[a]
        # S's feeders vote for a, then S''s for b.
        for number, near, far in ((loc_system[a], a, b), (pair_s[p], b, a)):
            for q in range(start[number], end[number]):
                row = grouped[q]
                if loc_radar[row] != radar:
                    closer[at], farther[at], witness[at] = near, far, row
                    at += 1
        ends[p + 1] = at
    return pair_a[:n_pairs].copy(), pair_b[:n_pairs].copy(), closer, farther, witness, ends


IDENTITY_HASH = 4096
"""``identity_candidates``' tables of low bits (a power of two)."""


@numba.njit(cache=True, inline="always")
def _in_sorted(values: IntArray, value: int) -> bool:  # pragma: no cover - compiled
    """Whether ``value`` is among the sorted ``values``."""
    at = np.searchsorted(values, value)
    return bool(at < values.size and values[at] == value)


@numba.njit(cache=True)
def identity_candidates(
    address: IntArray, mode3a: IntArray, touched: IntArray, alive: IntArray
) -> IntArray:  # pragma: no cover - compiled
    """``lifecycle._identity_candidates`` from the system table's fields: the live tracks
    ``alive`` whose address is unknown or some touched track's (any, when a touched
    track's is unknown), and likewise their Mode 3/A code. A table of the touched
    tracks' values' low bits rules most live tracks out before a search."""
    addresses = np.sort(address[touched])
    codes = np.sort(mode3a[touched])
    any_address = addresses.size > 0 and addresses[0] < 0
    any_code = codes.size > 0 and codes[0] < 0
    address_bits = np.zeros(IDENTITY_HASH, dtype=np.bool_)
    code_bits = np.zeros(IDENTITY_HASH, dtype=np.bool_)
    for a in addresses:
        address_bits[a & (IDENTITY_HASH - 1)] = True
    for c in codes:
        code_bits[c & (IDENTITY_HASH - 1)] = True
    keep = np.empty(alive.size, dtype=np.int64)
    n = 0
    for i in range(alive.size):
        a, c = address[alive[i]], mode3a[alive[i]]
        if not (
            any_address
            or a < 0
            or (address_bits[a & (IDENTITY_HASH - 1)] and _in_sorted(addresses, a))
        ):
            continue
        if any_code or c < 0 or (code_bits[c & (IDENTITY_HASH - 1)] and _in_sorted(codes, c)):
            keep[n] = alive[i]
            n += 1
    return keep[:n].copy()


@numba.njit(cache=True)
def identities_in_use(
    address: IntArray,
    code: IntArray,
    alive: npt.NDArray[np.bool_],
    sys_address: IntArray,
    sys_mode3a: IntArray,
) -> tuple[npt.NDArray[np.bool_], npt.NDArray[np.bool_]]:  # pragma: no cover - compiled
    """``lifecycle._identities_in_use``: whether a live system track (number 1 and up)
    carries each of ``address`` and each of ``code``; the live tracks' values looked up
    among the few sorted ones (a table of their low bits first)."""
    address_used = np.zeros(address.size, dtype=np.bool_)
    code_used = np.zeros(code.size, dtype=np.bool_)
    for values, column, used in (
        (address, sys_address, address_used),
        (code, sys_mode3a, code_used),
    ):
        order = np.argsort(values)
        ordered = values[order]
        bits = np.zeros(IDENTITY_HASH, dtype=np.bool_)
        for v in ordered:
            bits[v & (IDENTITY_HASH - 1)] = True
        for g in range(1, alive.size):
            v = column[g]
            if not (alive[g] and bits[v & (IDENTITY_HASH - 1)]):
                continue
            at = np.searchsorted(ordered, v)
            while at < ordered.size and ordered[at] == v:
                used[order[at]] = True
                at += 1
    return address_used, code_used


@numba.njit(cache=True)
def _insert_most_recent_first(
    rows: IntArray, lo: int, hi: int, row: int, t_plot: FloatArray
) -> None:  # pragma: no cover - compiled
    """``row`` inserted into ``rows[lo:hi]`` (ordered by descending t_plot), after the
    rows of equal t_plot: one step of a stable insertion sort (``rows[hi]`` is free)."""
    at = hi
    while at > lo and t_plot[rows[at - 1]] < t_plot[row]:
        rows[at] = rows[at - 1]
        at -= 1
    rows[at] = row


@numba.njit(cache=True)
def slots_of(
    numbers: IntArray,
    system: IntArray,
    alive: npt.NDArray[np.bool_],
    t_plot: FloatArray,
    max_sources: int,
    width: int,
) -> IntArray:  # pragma: no cover - compiled
    """``table.LocalTrackTable.slots``: the alive local rows feeding each system track of
    ``numbers`` (which may repeat), most recent plot first (ties in row order), at most
    ``max_sources``, -1 padding to ``width``; one pass over the table, then over the
    few rows it found."""
    size = 1
    for n in numbers:
        size = max(size, n + 1)
    wanted = np.zeros(size, dtype=np.bool_)
    for n in numbers:
        wanted[n] = True
    found = np.empty(system.size, dtype=np.int64)
    n_found = 0
    for r in range(system.size):
        g = system[r]
        if 0 <= g < size and wanted[g] and alive[r]:
            found[n_found] = r
            n_found += 1
    count = np.zeros(size + 1, dtype=np.int64)
    for q in range(n_found):
        count[system[found[q]] + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    rows = np.empty(n_found, dtype=np.int64)
    for q in range(n_found):
        r = found[q]
        g = system[r]
        _insert_most_recent_first(rows, start[g], fill[g], r, t_plot)
        fill[g] += 1
    out = np.full((numbers.size, width), -1, dtype=np.int64)
    for i in range(numbers.size):
        g = numbers[i]
        for j in range(min(max_sources, start[g + 1] - start[g])):
            out[i, j] = rows[start[g] + j]
    return out


@numba.njit(cache=True)
def reference_sources(
    slots: IntArray,
    t: FloatArray,
    loc_radar: IntArray,
    loc_t_plot: FloatArray,
    radar: int,
    sources: int,
    reference_age: float,
    n_radars: int,
) -> tuple[IntArray, IntArray, npt.NDArray[np.bool_]]:  # pragma: no cover - compiled
    """``references.references``' choice of sources per row, from the local table's
    fields: its slots of sources below ``sources`` (order kept, -1 after), those of them
    of other radars than ``radar`` with a plot within ``reference_age`` of t (the
    same), and the radars of the recent ones (k, n_radars)."""
    k, width = slots.shape
    kept = np.full((k, width), -1, dtype=np.int64)
    others = np.full((k, width), -1, dtype=np.int64)
    seen = np.zeros((k, n_radars), dtype=np.bool_)
    for r in range(k):
        n_kept = 0
        n_others = 0
        for i in range(width):
            s = slots[r, i]
            if s < 0 or loc_radar[s] >= sources:
                continue
            kept[r, n_kept] = s
            n_kept += 1
            if t[r] - loc_t_plot[s] <= reference_age:
                seen[r, loc_radar[s]] = True
                if loc_radar[s] != radar:
                    others[r, n_others] = s
                    n_others += 1
    return kept, others, seen


@numba.njit(cache=True)
def absorb_plots(
    rows: IntArray,
    loc_system: IntArray,
    has_plot: BoolArray,
    created: IntArray,
    plot_ids: IntArray,
    wanted: IntArray,
    plot_time: FloatArray,
    plot_x: FloatArray,
    plot_y: FloatArray,
    plot_R: FloatArray,
    extra: FloatArray,
    radar: int,
    max_backward: float,
    mx: FloatArray,
    mP: FloatArray,
    mM: FloatArray,
    mu: FloatArray,
    x: FloatArray,
    P: FloatArray,
    M: FloatArray,
    B: FloatArray,
    t: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    largest_bias: FloatArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> tuple[IntArray, IntArray, int, int]:  # pragma: no cover - compiled
    """``PlotFilterEstimator.absorb``'s plots without DAPs in one call, its steps' kernels
    in a row: the plotted updates (``plotted_updates``), then round by round
    ``_filter_round``: the plots more than ``max_backward`` seconds older than their
    system track skipped, the radar's residual biases ``extra`` (of the batch's updates)
    written, ``filter_round`` and ``refresh_moments``. Returns the updates used and their
    system tracks, the plot ids not found and the late plots skipped. One call where each
    round took some fifteen numpy calls and two kernel calls."""
    use, systems, found, rank, unknown = plotted_updates(
        rows, loc_system, has_plot, created, plot_ids, wanted
    )
    k = use.size
    numbers = np.empty(k, dtype=np.int64)
    time = np.empty(k)
    z = np.empty((k, 2))
    R = np.empty((k, 2, 2))
    late = 0
    rounds = rank.max() + 1 if k else 0
    for r in range(rounds):
        n = 0
        for i in range(k):
            if rank[i] != r:
                continue
            number, plot = systems[i], found[i]
            if plot_time[plot] - t[number] < -max_backward:
                late += 1
                continue
            numbers[n], time[n] = number, plot_time[plot]
            z[n, 0], z[n, 1] = plot_x[plot], plot_y[plot]
            R[n] = plot_R[plot]
            B[number, radar] = extra[use[i]]
            n += 1
        if n == 0:
            continue
        filter_round(
            mx,
            mP,
            mM,
            mu,
            x,
            P,
            M,
            B,
            t,
            numbers[:n],
            time[:n],
            z[:n],
            R[:n],
            radar,
            omega,
            q,
            sojourn,
        )
        refresh_moments(mx, mP, mu, M, B, numbers[:n], moments, sensitivity, largest_bias)
    return use, systems, unknown, late


@numba.njit(cache=True)
def refresh_moments(
    mx: FloatArray,
    mP: FloatArray,
    mu: FloatArray,
    M: FloatArray,
    B: FloatArray,
    numbers: IntArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    largest_bias: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The pre-selection's per-track terms of system tracks ``numbers`` into the table's
    fields ``moments`` (the IMM's combined state and the entries of its covariance that
    ``nearby.reach`` reads: x (4), P00 + P11, P02 + P13, P22 + P33), ``sensitivity`` (the
    squared norms of M's position and velocity rows, over every radar) and
    ``largest_bias`` (the largest trace of the radars' B, from 0): what
    ``system_reach`` read from each candidate's models and sensitivities per call (a
    kilobyte or more a track, every open system track each batch)."""
    m = mu.shape[1]
    for i in range(numbers.size):
        r = numbers[i]
        for a in range(4):
            acc = 0.0
            for j in range(m):
                acc += mu[r, j] * mx[r, j, a]
            moments[r, a] = acc
        pos = 0.0
        cross = 0.0
        vel = 0.0
        for j in range(m):
            d0 = mx[r, j, 0] - moments[r, 0]
            d1 = mx[r, j, 1] - moments[r, 1]
            d2 = mx[r, j, 2] - moments[r, 2]
            d3 = mx[r, j, 3] - moments[r, 3]
            w = mu[r, j]
            pos += w * (mP[r, j, 0, 0] + d0 * d0) + w * (mP[r, j, 1, 1] + d1 * d1)
            cross += w * (mP[r, j, 0, 2] + d0 * d2) + w * (mP[r, j, 1, 3] + d1 * d3)
            vel += w * (mP[r, j, 2, 2] + d2 * d2) + w * (mP[r, j, 3, 3] + d3 * d3)
        moments[r, 4] = pos
        moments[r, 5] = cross
        moments[r, 6] = vel
        m_position = 0.0
        m_velocity = 0.0
        largest = 0.0
        for radar in range(M.shape[1]):
            for j in range(2):
                for c in range(2):
                    m_position += M[r, radar, j, c] * M[r, radar, j, c]
                    m_velocity += M[r, radar, j + 2, c] * M[r, radar, j + 2, c]
            largest = max(largest, B[r, radar, 0, 0] + B[r, radar, 1, 1])
        sensitivity[r, 0] = m_position
        sensitivity[r, 1] = m_velocity
        largest_bias[r] = largest


@numba.njit(cache=True)
def _radius(
    pos: float,
    cross: float,
    vel: float,
    bias_var: float,
    a: float,
    speed: float,
    spread: float,
    gate: float,
    q_max: float,
    turn_max: float,
) -> float:  # pragma: no cover - compiled
    """``nearby.reach``'s radius of one track from its covariance's P00 + P11, P02 + P13
    and P22 + P33, its bias term, the time a it is moved over (|dt| + spread) and its
    speed."""
    var = pos + 2.0 * a * abs(cross) + a * a * vel + 2.0 * q_max * a**3 / 3.0 + bias_var
    turn = 0.5 * speed * turn_max * a * a
    var += turn * turn
    return RADIUS_SAFETY * math.sqrt(gate * max(var, 0.0)) + speed * spread + turn + RADIUS_MARGIN_M


@numba.njit(cache=True)
def system_reach(
    x: FloatArray,
    P: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    t: FloatArray,
    numbers: IntArray,
    from_models: bool,
    bias_scale: float,
    t_mid: float,
    spread: float,
    gate: float,
    q_max: float,
    turn_max: float,
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``nearby.system_reach`` from the system table's fields in place: the coarse state
    (the IMM's moment-matched combination, ``moments``, when ``from_models``, else x and
    P), the sensitivity norm and ``nearby.reach``, for every candidate (association takes
    every open system track, each batch); ``moments`` and ``sensitivity`` as
    ``refresh_moments`` keeps them."""
    k = numbers.size
    xy = np.empty((k, 2))
    radius = np.empty(k)
    xc = np.empty(4)
    for i in range(k):
        r = numbers[i]
        # The entries of the covariance that ``reach`` reads: P00 + P11, P02 + P13,
        # P22 + P33.
        if from_models:
            xc[:] = moments[r, :4]
            pos = moments[r, 4]
            cross = moments[r, 5]
            vel = moments[r, 6]
        else:
            xc[:] = x[r]
            pos = P[r, 0, 0] + P[r, 1, 1]
            cross = P[r, 0, 2] + P[r, 1, 3]
            vel = P[r, 2, 2] + P[r, 3, 3]
        dt = t_mid - t[r]
        a = abs(dt) + spread
        norm = 2.0 * (sensitivity[r, 0] + a * a * sensitivity[r, 1])
        speed = math.hypot(xc[2], xc[3])
        radius[i] = _radius(
            pos, cross, vel, bias_scale * norm, a, speed, spread, gate, q_max, turn_max
        )
        xy[i, 0] = xc[0] + xc[2] * dt
        xy[i, 1] = xc[1] + xc[3] * dt
    return xy, radius


class ModelConstants:
    """The plot filter's model constants as the kernels take them (contiguous float64)."""

    def __init__(self, models: ModelSet) -> None:
        self.omega = np.ascontiguousarray(models.turn_rates_rad_s, dtype=np.float64)
        self.q = np.ascontiguousarray(models.q, dtype=np.float64)
        self.sojourn = np.ascontiguousarray(models.mean_sojourn_s, dtype=np.float64)


PAIRWISE_BLOCK = 128
"""numpy's ``PW_BLOCKSIZE``: its float sum splits runs longer than this in halves."""


@numba.njit(cache=True)
def _pairwise_sum(values: FloatArray, lo: int, n: int) -> float:  # pragma: no cover - compiled
    """``values[lo:lo + n].sum()`` as numpy computes it (``pairwise_sum`` in its loops:
    a plain loop below 8 terms, eight running sums up to a block, halves beyond), so
    that a sum by segments is the bits of a sum per slice."""
    if n < 8:
        total = 0.0
        for i in range(n):
            total += values[lo + i]
        return total
    if n <= PAIRWISE_BLOCK:
        r = np.empty(8)
        for j in range(8):
            r[j] = values[lo + j]
        i = 8
        while i < n - n % 8:
            for j in range(8):
                r[j] += values[lo + i + j]
            i += 8
        total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
        while i < n:
            total += values[lo + i]
            i += 1
        return float(total)
    half = n // 2
    half -= half % 8
    return float(_pairwise_sum(values, lo, half) + _pairwise_sum(values, lo + half, n - half))


@numba.njit(cache=True)
def segment_sums(values: FloatArray, ends: IntArray) -> FloatArray:  # pragma: no cover - compiled
    """``values[ends[k]:ends[k + 1]].sum()`` for each k, to the bit."""
    out = np.empty(ends.size - 1)
    for k in range(ends.size - 1):
        out[k] = _pairwise_sum(values, ends[k], ends[k + 1] - ends[k])
    return out


EVIDENCE_PAIR = numba.types.UniTuple(numba.types.int64, 2)  # type: ignore[no-untyped-call]
EVIDENCE_ENTRY = numba.types.UniTuple(numba.types.float64, 4)  # type: ignore[no-untyped-call]
"""``state.PairEvidence``'s entries: (low key, high key) -> (updates, mean, agreement,
stamp of the write)."""


@numba.njit(cache=True)
def new_pair_evidence() -> tuple[Any, Any]:  # pragma: no cover - compiled
    """The compiled ``state.PairEvidence``'s dictionaries: its entries, and each dropped
    key's stamp of its latest drop (made in a cached kernel: from Python, each process
    compiled the typed dictionaries' constructor, 0.4 s)."""
    return (
        numba.typed.Dict.empty(EVIDENCE_PAIR, EVIDENCE_ENTRY),
        numba.typed.Dict.empty(numba.types.int64, numba.types.int64),
    )


@numba.njit(cache=True)
def evidence_table(
    of_pair: Any, dropped: Any, low: IntArray, high: IntArray
) -> FloatArray:  # pragma: no cover - compiled
    """``state.PairEvidence.table``: each pair's entry written after both its keys'
    latest drops, else zeros."""
    out = np.zeros((low.size, 3))
    for i in range(low.size):
        pair = (low[i], high[i])
        if pair in of_pair:
            entry = of_pair[pair]
            if entry[3] > dropped.get(low[i], -1) and entry[3] > dropped.get(high[i], -1):
                out[i, 0], out[i, 1], out[i, 2] = entry[0], entry[1], entry[2]
    return out


@numba.njit(cache=True)
def evidence_renew(
    of_pair: Any,
    dropped: Any,
    stamp: int,
    tested: IntArray,
    low: IntArray,
    high: IntArray,
    evidence: FloatArray,
) -> int:  # pragma: no cover - compiled
    """``state.PairEvidence.renew``: the tested keys dropped at ``stamp`` - 1, then each
    pair's entry stamped ``stamp``; returns the number of entries and drop stamps held."""
    _drop_keys(dropped, stamp - 1, tested)
    for i in range(low.size):
        of_pair[(low[i], high[i])] = (evidence[i, 0], evidence[i, 1], evidence[i, 2], float(stamp))
    return len(of_pair) + len(dropped)


@numba.njit(cache=True)
def evidence_update(
    of_pair: Any,
    dropped: Any,
    stamp: int,
    tested: IntArray,
    low: IntArray,
    high: IntArray,
    deltas: FloatArray,
    favoured: npt.NDArray[np.bool_],
    window: float,
) -> tuple[FloatArray, int]:  # pragma: no cover - compiled
    """``state.PairEvidence.update``: each pair's running means from its entry
    (``evidence_table``'s, read before any write), then ``evidence_renew``; the evidence
    now and the number of entries and drop stamps held."""
    now = evidence_table(of_pair, dropped, low, high)
    for i in range(low.size):
        n = now[i, 0] + 1.0
        weight = 1.0 / min(n, window)
        now[i, 0] = n
        now[i, 1] = now[i, 1] + (deltas[i] - now[i, 1]) * weight
        now[i, 2] = now[i, 2] + ((1.0 if favoured[i] else 0.0) - now[i, 2]) * weight
    return now, evidence_renew(of_pair, dropped, stamp, tested, low, high, now)


@numba.njit(cache=True)
def _drop_keys(dropped: Any, stamp: int, keys: IntArray) -> None:  # pragma: no cover
    """Each key's stamp of its latest drop."""
    for key in keys:
        dropped[key] = stamp


@numba.njit(cache=True)
def evidence_drop(
    of_pair: Any, dropped: Any, stamp: int, keys: IntArray
) -> int:  # pragma: no cover - compiled
    """``state.PairEvidence.drop``: each key's stamp of its latest drop; the number of
    entries and drop stamps held (a typed dictionary's ``len`` from Python costs
    microseconds)."""
    _drop_keys(dropped, stamp, keys)
    return len(of_pair) + len(dropped)


@numba.njit(cache=True)
def evidence_sweep(of_pair: Any, dropped: Any) -> None:  # pragma: no cover - compiled
    """``state.PairEvidence``'s sweep: the entries written before a drop of one of their
    keys go, and the drops with them."""
    gone = []
    for pair, entry in of_pair.items():
        if entry[3] <= dropped.get(pair[0], -1) or entry[3] <= dropped.get(pair[1], -1):
            gone.append(pair)
    for pair in gone:
        del of_pair[pair]
    dropped.clear()


@numba.njit(cache=True)
def _largest_of(values: FloatArray, numbers: IntArray) -> float:  # pragma: no cover - compiled
    """``values[numbers].max(initial=0.0)`` (values never NaN: traces of covariances)."""
    largest = 0.0
    for r in numbers:
        if values[r] > largest:
            largest = values[r]
    return largest


@numba.njit(cache=True)
def merge_candidates(
    alive: BoolArray,
    orphaned: FloatArray,
    t: FloatArray,
    x: FloatArray,
    P: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    largest_bias: FloatArray,
    address: IntArray,
    mode3a: IntArray,
    touched: IntArray,
    gate: float,
    q_max: float,
    turn_max: float,
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """``lifecycle._merge_candidates`` in one call: the live fed (not orphaned) tracks,
    ``identity_candidates`` among them, the time span and bias bound, both sets' reach
    from their latest output state (``system_reach``), ``near_pairs`` and the pairs'
    identity test, by the kernels each step of the numpy path calls (a batch's merge
    test was some 25 numpy and kernel calls for, mostly, no pair at all)."""
    empty = np.zeros(0, dtype=np.int64)
    live = np.empty(alive.size, dtype=np.int64)
    n_live = 0
    for r in range(1, alive.size):
        if alive[r] and np.isnan(orphaned[r]):
            live[n_live] = r
            n_live += 1
    others = identity_candidates(address, mode3a, touched, live[:n_live])
    if touched.size == 0 or others.size == 0:
        return empty, empty
    lo = hi = t[touched[0]]
    for r in touched:
        lo = min(lo, t[r])
        hi = max(hi, t[r])
    t_mid, spread = 0.5 * (lo + hi), 0.5 * (hi - lo)
    bias_scale = 2.0 * max(_largest_of(largest_bias, others), _largest_of(largest_bias, touched))
    reach = (bias_scale, t_mid, spread, gate, q_max, turn_max)
    xy_a, r_a = system_reach(x, P, moments, sensitivity, t, touched, False, *reach)
    xy_b, r_b = system_reach(x, P, moments, sensitivity, t, others, False, *reach)
    i, j = near_pairs(xy_a, r_a, xy_b, r_b)
    a = np.empty(i.size, dtype=np.int64)
    b = np.empty(i.size, dtype=np.int64)
    n = 0
    for k in range(i.size):
        p, q = touched[i[k]], others[j[k]]
        if p == q:
            continue
        pa, qa, pc, qc = address[p], address[q], mode3a[p], mode3a[q]
        if (pa < 0 or qa < 0 or pa == qa) and (pc < 0 or qc < 0 or pc == qc):
            a[n], b[n] = p, q
            n += 1
    return a[:n].copy(), b[:n].copy()


@numba.njit(cache=True)
def near_local_system(
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    free: IntArray,
    sys_x: FloatArray,
    sys_P: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    largest_bias: FloatArray,
    sys_t: FloatArray,
    candidates: IntArray,
    bias_over: IntArray,
    from_models: bool,
    gate: float,
    q_max: float,
    turn_max: float,
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """``associate._near`` in one call: the local rows ``free``'s time span and bias
    bound, the system tracks' reach (``system_reach``), each local track's
    (``nearby.reach``, its bits: libm's pow and hypot as numpy calls them) and
    ``near_pairs``; the (local row, system number) pairs in (row, number) order."""
    empty = np.zeros(0, dtype=np.int64)
    if free.size == 0 or candidates.size == 0:
        return empty, empty
    lo = hi = loc_t[free[0]]
    own_bias = 0.0
    for r in free:
        lo = min(lo, loc_t[r])
        hi = max(hi, loc_t[r])
        own_bias = max(own_bias, loc_extra[r, 0, 0] + loc_extra[r, 1, 1])
    t_mid, spread = 0.5 * (lo + hi), 0.5 * (hi - lo)
    b = max(_largest_of(largest_bias, bias_over), own_bias)
    k = free.size
    xy_l = np.empty((k, 2))
    r_l = np.empty(k)
    bias_var = 4.0 * b
    for i in range(k):
        r = free[i]
        p = loc_P[r]
        dt = t_mid - loc_t[r]
        speed = math.hypot(loc_x[r, 2], loc_x[r, 3])
        r_l[i] = _radius(
            p[0, 0] + p[1, 1],
            p[0, 2] + p[1, 3],
            p[2, 2] + p[3, 3],
            bias_var,
            abs(dt) + spread,
            speed,
            spread,
            gate,
            q_max,
            turn_max,
        )
        xy_l[i, 0] = loc_x[r, 0] + loc_x[r, 2] * dt
        xy_l[i, 1] = loc_x[r, 1] + loc_x[r, 3] * dt
    # Association takes every open system track (thousands) for a batch's few free
    # tracks: only those a cheap bound of their reach leaves near one of them have it
    # computed as ``system_reach`` computes it; ``near_pairs`` on them gives the same
    # pairs in the same (row, number) order.
    if from_models and candidates.size > k:
        candidates = _within_bound(
            xy_l,
            r_l,
            moments,
            sensitivity,
            sys_t,
            candidates,
            2.0 * b,
            t_mid,
            spread,
            gate,
            q_max,
            turn_max,
        )
    xy_s, r_s = system_reach(
        sys_x,
        sys_P,
        moments,
        sensitivity,
        sys_t,
        candidates,
        from_models,
        2.0 * b,
        t_mid,
        spread,
        gate,
        q_max,
        turn_max,
    )
    i_l, j_s = near_pairs(xy_l, r_l, xy_s, r_s)
    return free[i_l], candidates[j_s]


@numba.njit(cache=True)
def exchange_pairs(
    confirmed_feeders: IntArray,
    loc_alive: npt.NDArray[np.bool_],
    loc_system: IntArray,
    loc_status: npt.NDArray[np.int8],
    loc_radar: IntArray,
    loc_key: IntArray,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_extra: FloatArray,
    head: IntArray,
    next_row: IntArray,
    tested: IntArray,
    radar: int,
    confirmed: int,
    sys_x: FloatArray,
    sys_P: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    largest_bias: FloatArray,
    sys_t: FloatArray,
    from_models: bool,
    gate: float,
    q_max: float,
    turn_max: float,
    q: float,
) -> tuple[bool, IntArray, IntArray, IntArray, IntArray, FloatArray, BoolArray]:  # pragma: no cover
    """``associate._exchange_pairs`` in one call, its four steps' kernels in a row: the
    feeding sets from the table's counts of confirmed feeders (``feeding_sets``), the
    pre-selection of the confirmed rows ``tested`` of ``radar`` near the tracks its rows
    feed (``near_local_system``, the bias bound over every fed track), the pairs and
    their witnesses (``exchange_witnesses``) and the votes (``exchange_votes``).
    Returns whether more than one radar feeds a system track (when not, the rest is
    empty), the pairs' rows l and l', their keys' lower and higher, each pair's delta
    and whether every vote favours the exchange. One call where four took 7 to 17
    arrays each, and none of the arrays between them leaves the compiled code (the
    system-track numbers are those below ``head.size``, one list of feeders each)."""
    several, fed, own = feeding_sets(confirmed_feeders, radar)
    empty = np.zeros(0, dtype=np.int64)
    if not several:
        return False, empty, empty, empty, empty, np.zeros(0), np.zeros(0, dtype=np.bool_)
    li, sj = near_local_system(
        loc_t,
        loc_x,
        loc_P,
        loc_extra,
        tested,
        sys_x,
        sys_P,
        moments,
        sensitivity,
        largest_bias,
        sys_t,
        own,
        fed,
        from_models,
        gate,
        q_max,
        turn_max,
    )
    pair_a, pair_b, closer, farther, witness, ends = exchange_witnesses(
        li,
        sj,
        head,
        next_row,
        loc_alive,
        loc_status,
        confirmed,
        loc_system,
        loc_radar,
        head.size,
    )
    low = np.empty(pair_a.size, dtype=np.int64)
    high = np.empty(pair_a.size, dtype=np.int64)
    for p in range(pair_a.size):
        ka, kb = loc_key[pair_a[p]], loc_key[pair_b[p]]
        low[p], high[p] = min(ka, kb), max(ka, kb)
    deltas, favoured = exchange_votes(
        loc_t, loc_x, loc_P, loc_extra, closer, farther, witness, ends, q
    )
    return True, pair_a, pair_b, low, high, deltas, favoured


BOUND_RELATIVE = 1e-9
BOUND_MARGIN_M = 1e-6
"""``_within_bound``'s radius exceeds ``_radius``'s by this much at least (its terms
differ from it by a few rounding errors: 1e-15 relative)."""


@numba.njit(cache=True)
def _within_bound(
    xy_l: FloatArray,
    r_l: FloatArray,
    moments: FloatArray,
    sensitivity: FloatArray,
    sys_t: FloatArray,
    candidates: IntArray,
    bias_scale: float,
    t_mid: float,
    spread: float,
    gate: float,
    q_max: float,
    turn_max: float,
) -> IntArray:  # pragma: no cover - compiled
    """The candidates (in order) that may pass ``near_pairs`` with a track of ``xy_l``,
    ``r_l``: within the tracks' bounding box widened by the largest ``r_l`` and their
    own radius bounded from above (``system_reach``'s position and radius from the
    IMM's ``moments``, with the power and ``hypot`` of ``_radius`` as products and a
    square root, widened by ``BOUND_RELATIVE`` and ``BOUND_MARGIN_M``), without the
    library calls."""
    lo0, lo1 = xy_l[:, 0].min(), xy_l[:, 1].min()
    hi0, hi1 = xy_l[:, 0].max(), xy_l[:, 1].max()
    widest = r_l.max()
    kept = np.empty(candidates.size, dtype=np.int64)
    n = 0
    for i in range(candidates.size):
        r = candidates[i]
        x0, x1, x2, x3 = moments[r, 0], moments[r, 1], moments[r, 2], moments[r, 3]
        pos, cross, vel = moments[r, 4], moments[r, 5], moments[r, 6]
        dt = t_mid - sys_t[r]
        x = x0 + x2 * dt
        y = x1 + x3 * dt
        a = abs(dt) + spread
        speed = math.sqrt(x2 * x2 + x3 * x3)
        turn = 0.5 * speed * turn_max * a * a
        var = (
            pos
            + 2.0 * a * abs(cross)
            + a * a * vel
            + 2.0 * q_max * (a * a * a) / 3.0
            + bias_scale * (2.0 * (sensitivity[r, 0] + a * a * sensitivity[r, 1]))
            + turn * turn
        )
        bound = RADIUS_SAFETY * math.sqrt(gate * max(var, 0.0)) + speed * spread + turn
        reach = (bound + RADIUS_MARGIN_M) * (1.0 + BOUND_RELATIVE) + BOUND_MARGIN_M + widest
        # Kept unless surely out: a NaN (reach or position) keeps the track, whose exact
        # reach then decides as the reference's does (a NaN radius blanks the batch).
        if not (x < lo0 - reach or x > hi0 + reach or y < lo1 - reach or y > hi1 + reach):
            kept[n] = r
            n += 1
    return kept[:n].copy()


@numba.njit(cache=True)
def expiring(
    alive: BoolArray, orphaned: FloatArray, t_plot: FloatArray, silent_before: float
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """``lifecycle.expire``'s two sets in one pass over the system table: the live fed
    tracks whose latest plot is before ``silent_before``, and the live orphans."""
    silent = np.empty(alive.size, dtype=np.int64)
    orphans = np.empty(alive.size, dtype=np.int64)
    n_silent = n_orphans = 0
    for r in range(alive.size):
        if not alive[r]:
            continue
        if np.isnan(orphaned[r]):
            if t_plot[r] < silent_before:
                silent[n_silent] = r
                n_silent += 1
        else:
            orphans[n_orphans] = r
            n_orphans += 1
    return silent[:n_silent].copy(), orphans[:n_orphans].copy()


@numba.njit(cache=True)
def due_numbers(
    alive: BoolArray, freed_at: FloatArray, now: float, reuse_delay: float, k: int
) -> IntArray:  # pragma: no cover - compiled
    """``lifecycle.create``'s lowest k free numbers (above 0, not alive) whose reuse
    delay has passed, a number freed "later" than now taken as freed now; fewer when
    fewer are due. The pass stops at the k-th (the numpy path tests all 4,096)."""
    out = np.empty(k, dtype=np.int64)
    n = 0
    for r in range(1, alive.size):
        if n == k:
            break
        if alive[r]:
            continue
        # np.minimum's: NaN stays NaN (never due).
        ended = now if freed_at[r] > now else freed_at[r]
        if ended + reuse_delay <= now:
            out[n] = r
            n += 1
    return out[:n].copy()


@numba.njit(cache=True)
def found_system_tracks(
    numbers: IntArray,
    founders: IntArray,
    now: float,
    founder_bias: FloatArray,
    initial_mu: FloatArray,
    sys_alive: BoolArray,
    sys_born: FloatArray,
    sys_solo: BoolArray,
    sys_orphaned: FloatArray,
    sys_t_row: FloatArray,
    sys_row_interval: FloatArray,
    sys_fl: FloatArray,
    sys_t: FloatArray,
    sys_x: FloatArray,
    sys_P: FloatArray,
    sys_founder_radar: IntArray,
    sys_B: FloatArray,
    sys_M: FloatArray,
    sys_mM: FloatArray,
    sys_t_plot: FloatArray,
    sys_address: IntArray,
    sys_mode3a: IntArray,
    sys_mx: FloatArray,
    sys_mP: FloatArray,
    sys_mu: FloatArray,
    loc_t: FloatArray,
    loc_x: FloatArray,
    loc_P: FloatArray,
    loc_radar: IntArray,
    loc_extra: FloatArray,
    loc_t_plot: FloatArray,
    loc_address: IntArray,
    loc_mode3a: IntArray,
    loc_mu: FloatArray,
    loc_fails: IntArray,
    loc_nis_n: IntArray,
    loc_t_founder: FloatArray,
) -> None:  # pragma: no cover - compiled
    """``lifecycle.create``'s writes, row by row: system track numbers[i] from local row
    founders[i] (its state in every model, its radar's residual bias, ``founder_bias``
    (4, 2) its sensitivity to that radar's bias, zero when the founder carries none),
    its model probabilities the founder's when known (any above 0) else
    ``initial_mu``; the founder's tests restarted (it joins by ``assign_feeders``)."""
    m, n_radars = sys_mx.shape[1], sys_M.shape[1]
    for i in range(numbers.size):
        n, f = numbers[i], founders[i]
        radar = loc_radar[f]
        sys_alive[n] = True
        sys_born[n] = now
        sys_solo[n] = True
        sys_orphaned[n] = np.nan
        sys_t_row[n] = -np.inf
        sys_row_interval[n] = np.nan
        sys_fl[n] = np.nan
        sys_t[n] = loc_t[f]
        sys_x[n] = loc_x[f]
        sys_P[n] = loc_P[f]
        sys_founder_radar[n] = radar
        sys_B[n] = 0.0
        sys_B[n, radar] = loc_extra[f]
        sys_M[n] = 0.0
        sys_M[n, radar] = founder_bias
        for j in range(m):
            for sensor in range(n_radars):
                sys_mM[n, j, sensor] = sys_M[n, sensor]
            sys_mx[n, j] = loc_x[f]
            sys_mP[n, j] = loc_P[f]
        sys_t_plot[n] = loc_t_plot[f]
        sys_address[n] = loc_address[f]
        sys_mode3a[n] = loc_mode3a[f]
        total = 0.0
        for j in range(m):
            total += loc_mu[f, j]
        sys_mu[n] = loc_mu[f] if total > 0.0 else initial_mu
        loc_fails[f] = 0
        loc_nis_n[f] = 0
        loc_t_founder[f] = np.nan


@numba.njit(cache=True)
def assign_feeders(
    rows: IntArray,
    numbers: IntArray,
    system: IntArray,
    head: IntArray,
    next_row: IntArray,
    status: npt.NDArray[np.int8],
    alive: npt.NDArray[np.bool_],
    radar: IntArray,
    confirmed: int,
    counts: IntArray,
) -> None:  # pragma: no cover - compiled
    """``table.LocalTrackTable.feed``: system[rows[i]] = numbers[i] in order (0: none),
    each row moved from its old system track's list of feeders (``head``, ``next_row``:
    singly linked, a few rows each) to its new one's, and in ``counts`` from the old
    track's to the new one's if it is live and ``confirmed`` (``_count_feeder``)."""
    for i in range(rows.size):
        r, g = rows[i], numbers[i]
        old = system[r]
        if old == g:
            continue
        counted = alive[r] and status[r] == confirmed
        if counted and old > 0:
            _count_feeder(counts, radar[r], old, -1)
        if counted and g > 0:
            _count_feeder(counts, radar[r], g, 1)
        if old > 0:
            if head[old] == r:
                head[old] = next_row[r]
            else:
                q = head[old]
                while next_row[q] != r:
                    q = next_row[q]
                next_row[q] = next_row[r]
            next_row[r] = -1
        system[r] = g
        if g > 0:
            next_row[r] = head[g]
            head[g] = r


@numba.njit(cache=True)
def radar_feeders(
    numbers: IntArray,
    head: IntArray,
    next_row: IntArray,
    alive: npt.NDArray[np.bool_],
    loc_radar: IntArray,
    radar: int,
) -> IntArray:  # pragma: no cover - compiled
    """``table.LocalTrackTable.radar_feeders`` from the lists of ``assign_feeders``: the
    live rows of ``radar`` in the lists of ``numbers`` (each list once), ascending."""
    found = np.empty(16, dtype=np.int64)
    n_found = 0
    for i in range(numbers.size):
        g = numbers[i]
        repeated = False
        for j in range(i):
            repeated = repeated or numbers[j] == g
        if repeated or g <= 0:
            continue
        r = head[g]
        while r >= 0:
            if alive[r] and loc_radar[r] == radar:
                if n_found == found.size:
                    grown = np.empty(2 * found.size, dtype=np.int64)
                    grown[:n_found] = found[:n_found]
                    found = grown
                found[n_found] = r
                n_found += 1
            r = next_row[r]
    return np.sort(found[:n_found])


@numba.njit(cache=True)
def link_feeders(
    system: IntArray,
    head: IntArray,
    next_row: IntArray,
    status: npt.NDArray[np.int8],
    alive: npt.NDArray[np.bool_],
    radar: IntArray,
    confirmed: int,
    counts: IntArray,
) -> None:  # pragma: no cover - compiled
    """The lists and counts of ``assign_feeders`` built afresh from the columns (the
    rows in use: ``system``'s)."""
    head[:] = -1
    next_row[:] = -1
    counts[:] = 0
    for r in range(system.size - 1, -1, -1):
        g = system[r]
        if g > 0:
            next_row[r] = head[g]
            head[g] = r
            if alive[r] and status[r] == confirmed:
                _count_feeder(counts, radar[r], g, 1)


@numba.njit(cache=True, inline="always")
def _count_feeder(counts: IntArray, radar: int, number: int, step: int) -> None:  # pragma: no cover
    """A confirmed live row of ``radar`` feeding system track ``number`` counted in
    (``step`` 1) or out (-1) of ``table.LocalTrackTable.confirmed_feeders``' counts:
    its radar's and track's, its radar's (column 0), its track's (the last row) and
    the count of all."""
    every_radar = counts.shape[0] - 1
    counts[radar, number] += step
    counts[radar, 0] += step
    counts[every_radar, number] += step
    counts[every_radar, 0] += step


@numba.njit(cache=True)
def feeder_slots(
    numbers: IntArray,
    head: IntArray,
    next_row: IntArray,
    system: IntArray,
    alive: npt.NDArray[np.bool_],
    t_plot: FloatArray,
    max_sources: int,
    width: int,
) -> IntArray:  # pragma: no cover - compiled
    """``slots_of`` from the lists of each system track's feeders (``assign_feeders``)
    instead of a pass over the table: a track's alive rows in row order, then placed as
    ``slots_of`` places them (by descending t_plot, after the equal ones). Numbers below
    1 (those of no system track: every unfed row) by ``slots_of``'s pass."""
    for n in numbers:
        if n <= 0:
            return slots_of(numbers, system, alive, t_plot, max_sources, width)
    out = np.full((numbers.size, width), -1, dtype=np.int64)
    found = np.empty(16, dtype=np.int64)
    placed = np.empty(16, dtype=np.int64)
    for i in range(numbers.size):
        n_found = 0
        r = head[numbers[i]]
        while r >= 0:
            if alive[r]:
                if n_found == found.size:
                    grown = np.empty(2 * found.size, dtype=np.int64)
                    grown[:n_found] = found[:n_found]
                    found = grown
                    placed = np.empty(found.size, dtype=np.int64)
                # Insertion in ascending row order: the order of ``slots_of``'s pass.
                at = n_found
                while at > 0 and found[at - 1] > r:
                    found[at] = found[at - 1]
                    at -= 1
                found[at] = r
                n_found += 1
            r = next_row[r]
        for q in range(n_found):
            _insert_most_recent_first(placed, 0, q, found[q], t_plot)
        for j in range(min(max_sources, n_found)):
            out[i, j] = placed[j]
    return out
