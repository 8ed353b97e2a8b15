"""Compiled IMM kernels: the textbook loops of ``imm`` (the numpy reference), one pass over
many tracks (or track-plot pairs) per call, compiled by numba.

Why compiled: a sector brings a few to a few tens of pairs, and the numpy reference spends
most of its time in the overhead of its ~60 array calls per batch (issue 12 measured 27 us
per track update against 2.6-2.9 us for the same IMM as a compiled loop). Each function
here computes exactly what its reference in ``imm`` / ``models`` computes, in the same
order of terms where it matters, and ``tests/test_tracking_kernels.py`` holds them to it
(1e-9). ``cache=True`` keeps the compiled code on disk (``__pycache__``), so that only the
first start after an install pays the compilation.

Shapes as in ``imm``: k rows, M models, x (k, M, 4), P (k, M, 4, 4), mu (k, M); the
measurement is the position (H = [I2 0]).
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba
from tracker_service.tracking.imm import ImmPrediction, ImmUpdate
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

LOG_2PI = math.log(2.0 * math.pi)
TINY = 1e-300
SMALL_TURN_RAD_S = 1e-9


@numba.njit(cache=True, inline="always")
def _transition(dt: float, omega: float, f: FloatArray) -> None:  # pragma: no cover - compiled
    """F(dt) of a fixed-rate turn (CV when omega is ~0) into f (4, 4), as
    ``models.ModelSet.transitions``."""
    f[:, :] = 0.0
    f[0, 0] = f[1, 1] = 1.0
    if abs(omega) < SMALL_TURN_RAD_S:
        f[0, 2] = f[1, 3] = dt
        f[2, 2] = f[3, 3] = 1.0
        return
    s = math.sin(dt * omega)
    c = math.cos(dt * omega)
    f[0, 2] = f[1, 3] = s / omega
    f[0, 3] = -((1.0 - c) / omega)
    f[1, 2] = (1.0 - c) / omega
    f[2, 2] = f[3, 3] = c
    f[2, 3] = -s
    f[3, 2] = s


@numba.njit(cache=True, inline="always")
def propagate(
    f: FloatArray, x0: FloatArray, p0: FloatArray, fp: FloatArray, x: FloatArray, p: FloatArray
) -> None:  # pragma: no cover - compiled
    """x = F x0 and p = F p0 F^T of a 4-state (``fp``: scratch for F p0), written in
    place; shared by the local tracker's and the fuser's kernels."""
    for a in range(4):
        acc = 0.0
        for b in range(4):
            acc += f[a, b] * x0[b]
        x[a] = acc
    for a in range(4):
        for b in range(4):
            acc = 0.0
            for e in range(4):
                acc += f[a, e] * p0[e, b]
            fp[a, b] = acc
    for a in range(4):
        for b in range(4):
            acc = 0.0
            for e in range(4):
                acc += fp[a, e] * f[b, e]
            p[a, b] = acc


@numba.njit(cache=True, inline="always")
def white_acceleration_terms(t: float, q: float) -> tuple[float, float, float]:  # pragma: no cover
    """The white-acceleration Q(|t|)'s position, cross and velocity terms
    (``models.white_acceleration_q``)."""
    t = abs(t)
    t2 = t * t
    return q * t2 * t / 3.0, q * t2 / 2.0, q * t


@numba.njit(cache=True, inline="always")
def add_white_acceleration_q(p: FloatArray, t: float, q: float) -> None:  # pragma: no cover
    """p (4, 4) += the white-acceleration Q(|t|) (``white_acceleration_terms``)."""
    q_pos, q_cross, q_vel = white_acceleration_terms(t, q)
    p[0, 0] += q_pos
    p[1, 1] += q_pos
    p[0, 2] += q_cross
    p[2, 0] += q_cross
    p[1, 3] += q_cross
    p[3, 1] += q_cross
    p[2, 2] += q_vel
    p[3, 3] += q_vel


@numba.njit(cache=True, inline="always")
def imm_mixing(
    t: float, sojourn: FloatArray, mu: FloatArray, pi: FloatArray, c: FloatArray, w: FloatArray
) -> None:  # pragma: no cover - compiled
    """The IMM's mixing over a step of ``t`` s (>= 0) from the model probabilities ``mu``
    (M,): Markov switching by mean sojourn times into pi (M, M)
    (``models.ModelSet.switching``), the predicted model probabilities into c (M,) and
    the mixing weights into w (M, M) (``imm.mixing``); shared by the local tracker's
    horizontal and vertical IMMs and the fuser's."""
    m = mu.shape[0]
    for i in range(m):
        if m == 1:
            pi[i, i] = 1.0
            continue
        stay = math.exp(-t / sojourn[i])
        leave = (1.0 - stay) / (m - 1)
        for j in range(m):
            pi[i, j] = stay if i == j else leave
    for j in range(m):
        total = 0.0
        for i in range(m):
            total += pi[i, j] * mu[i]
        c[j] = total
        denominator = max(total, TINY)
        for i in range(m):
            w[i, j] = pi[i, j] * mu[i] / denominator


@numba.njit(cache=True)
def imm_predict(
    x: FloatArray,
    P: FloatArray,
    mu: FloatArray,
    dt: FloatArray,
    omega: FloatArray,
    q: FloatArray,
    sojourn: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover
    """``imm.predict``: IMM mixing (switching by mean sojourn times), each model's
    prediction over dt, and the moment-matched combination. Returns the per-model
    predictions xp, Pp, the predicted model probabilities c, and the combined xc, Pc."""
    k, m = x.shape[0], x.shape[1]
    xp = np.empty((k, m, 4))
    pp = np.empty((k, m, 4, 4))
    c = np.empty((k, m))
    xc = np.empty((k, 4))
    pc = np.empty((k, 4, 4))
    pi = np.empty((m, m))
    w = np.empty((m, m))
    x0 = np.empty(4)
    p0 = np.empty((4, 4))
    fp = np.empty((4, 4))
    f = np.empty((4, 4))
    d = np.empty(4)
    for r in range(k):
        step = dt[r]
        t = abs(step)
        imm_mixing(t, sojourn, mu[r], pi, c[r], w)
        for j in range(m):
            # Mixed initial condition of model j (imm.mix_and_move).
            for a in range(4):
                acc = 0.0
                for i in range(m):
                    acc += w[i, j] * x[r, i, a]
                x0[a] = acc
            for a in range(4):
                for b in range(4):
                    p0[a, b] = 0.0
            for i in range(m):
                wij = w[i, j]
                for a in range(4):
                    d[a] = x[r, i, a] - x0[a]
                for a in range(4):
                    for b in range(4):
                        p0[a, b] += wij * P[r, i, a, b] + wij * d[a] * d[b]
            _transition(step, omega[j], f)
            propagate(f, x0, p0, fp, xp[r, j], pp[r, j])
            add_white_acceleration_q(pp[r, j], step, q[j])
        _combine_row(xp, pp, c, r, xc, pc, d)
    return xp, pp, c, xc, pc


@numba.njit(cache=True, inline="always")
def _combine_row(
    x: FloatArray,
    P: FloatArray,
    w: FloatArray,
    r: int,
    xc: FloatArray,
    pc: FloatArray,
    d: FloatArray,
) -> None:  # pragma: no cover - compiled
    """Row r of ``imm.combine``: the mixture's mean and covariance into xc[r], pc[r]."""
    m = x.shape[1]
    for a in range(4):
        acc = 0.0
        for j in range(m):
            acc += w[r, j] * x[r, j, a]
        xc[r, a] = acc
    for a in range(4):
        for b in range(4):
            pc[r, a, b] = 0.0
    for j in range(m):
        wj = w[r, j]
        for a in range(4):
            d[a] = x[r, j, a] - xc[r, a]
        for a in range(4):
            for b in range(4):
                pc[r, a, b] += wj * (P[r, j, a, b] + d[a] * d[b])


@numba.njit(cache=True)
def combine(
    x: FloatArray, P: FloatArray, w: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``imm.combine``: the moment-matched mean and covariance of each row's mixture."""
    k = x.shape[0]
    xc = np.empty((k, 4))
    pc = np.empty((k, 4, 4))
    d = np.empty(4)
    for r in range(k):
        _combine_row(x, P, w, r, xc, pc, d)
    return xc, pc


@numba.njit(cache=True)
def innovation_test(
    xc: FloatArray, pc: FloatArray, z: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:  # pragma: no cover - compiled
    """``imm.innovation_test``: NIS and log det S of the combined prediction."""
    k = xc.shape[0]
    nis = np.empty(k)
    log_det = np.empty(k)
    for r in range(k):
        y0 = z[r, 0] - xc[r, 0]
        y1 = z[r, 1] - xc[r, 1]
        s00 = pc[r, 0, 0] + R[r, 0, 0]
        s01 = pc[r, 0, 1] + R[r, 0, 1]
        s10 = pc[r, 1, 0] + R[r, 1, 0]
        s11 = pc[r, 1, 1] + R[r, 1, 1]
        det = s00 * s11 - s01 * s10
        i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
        nis[r] = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
        log_det[r] = math.log(max(det, TINY))
    return nis, log_det


@numba.njit(cache=True)
def imm_update(
    xp: FloatArray, pp: FloatArray, c: FloatArray, z: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover
    """``imm.update`` then ``imm.combine``: the model-matched Joseph-form updates, the
    model-probability update (log-sum-exp), and the combined state. Returns the per-model
    x, P, the probabilities mu, and the combined xc, Pc."""
    k, m = xp.shape[0], xp.shape[1]
    x_new = np.empty((k, m, 4))
    p_new = np.empty((k, m, 4, 4))
    mu = np.empty((k, m))
    xc = np.empty((k, 4))
    pc = np.empty((k, 4, 4))
    gain = np.empty((4, 2))
    ikh = np.empty((4, 4))
    tmp = np.empty((4, 4))
    joseph = np.empty((4, 4))
    log_post = np.empty(m)
    d = np.empty(4)
    for r in range(k):
        r00, r01, r10, r11 = R[r, 0, 0], R[r, 0, 1], R[r, 1, 0], R[r, 1, 1]
        for j in range(m):
            y0 = z[r, 0] - xp[r, j, 0]
            y1 = z[r, 1] - xp[r, j, 1]
            s00 = pp[r, j, 0, 0] + r00
            s01 = pp[r, j, 0, 1] + r01
            s10 = pp[r, j, 1, 0] + r10
            s11 = pp[r, j, 1, 1] + r11
            det = s00 * s11 - s01 * s10
            i00, i01, i10, i11 = s11 / det, -s01 / det, -s10 / det, s00 / det
            for a in range(4):
                gain[a, 0] = pp[r, j, a, 0] * i00 + pp[r, j, a, 1] * i10
                gain[a, 1] = pp[r, j, a, 0] * i01 + pp[r, j, a, 1] * i11
                x_new[r, j, a] = xp[r, j, a] + (gain[a, 0] * y0 + gain[a, 1] * y1)
            # Joseph form (I - K H) P (I - K H)^T + K R K^T, symmetrised (imm.joseph).
            for a in range(4):
                for b in range(4):
                    ikh[a, b] = 1.0 if a == b else 0.0
                ikh[a, 0] -= gain[a, 0]
                ikh[a, 1] -= gain[a, 1]
            for a in range(4):
                for b in range(4):
                    acc = 0.0
                    for e in range(4):
                        acc += ikh[a, e] * pp[r, j, e, b]
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
                    p_new[r, j, a, b] = 0.5 * (joseph[a, b] + joseph[b, a])
            # Model likelihood (imm.model_probabilities).
            nis = y0 * (i00 * y0 + i01 * y1) + y1 * (i10 * y0 + i11 * y1)
            log_lik = -0.5 * (nis + math.log(max(det, TINY))) - LOG_2PI
            log_post[j] = math.log(max(c[r, j], TINY)) + log_lik
        top = log_post.max()
        total = 0.0
        for j in range(m):
            mu[r, j] = math.exp(log_post[j] - top)
            total += mu[r, j]
        for j in range(m):
            mu[r, j] /= total
        _combine_row(x_new, p_new, mu, r, xc, pc, d)
    return x_new, p_new, mu, xc, pc


class CompiledImm:
    """``imm.ImmFilter`` by the kernels above; the model constants are taken once."""

    def __init__(self, models: ModelSet) -> None:
        self.models = models
        self._omega = np.ascontiguousarray(models.turn_rates_rad_s, dtype=np.float64)
        self._q = np.ascontiguousarray(models.q, dtype=np.float64)
        self._sojourn = np.ascontiguousarray(models.mean_sojourn_s, dtype=np.float64)

    def predict(
        self, x: FloatArray, P: FloatArray, mu: FloatArray, dt: FloatArray
    ) -> ImmPrediction:
        xp, pp, c, xc, pc = imm_predict(x, P, mu, dt, self._omega, self._q, self._sojourn)
        return ImmPrediction(x=xp, P=pp, c=c, x_comb=xc, P_comb=pc)

    def innovation_test(
        self, pred: ImmPrediction, z: FloatArray, R: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        return innovation_test(pred.x_comb, pred.P_comb, z, R)

    def update(self, pred: ImmPrediction, z: FloatArray, R: FloatArray) -> ImmUpdate:
        x, p, mu, xc, pc = imm_update(pred.x, pred.P, pred.c, z, R)
        return ImmUpdate(x, p, mu, xc, pc)


@numba.njit(cache=True, inline="always")
def _vertical_scalar(
    x: FloatArray, p: FloatArray, z: float, r: float, c: int
) -> float:  # pragma: no cover - compiled
    """``vertical.scalar_update`` of one model's x (2,), P (2, 2) in place with a
    measurement of component c; returns the log-likelihood."""
    y = z - x[c]
    s = p[c, c] + r
    k0 = p[0, c] / s
    k1 = p[1, c] / s
    # (I - K H) P (I - K H)' + K r K', H = e_c.
    i00 = 1.0 - (k0 if c == 0 else 0.0)
    i01 = -(k0 if c == 1 else 0.0)
    i10 = -(k1 if c == 0 else 0.0)
    i11 = 1.0 - (k1 if c == 1 else 0.0)
    a00 = i00 * p[0, 0] + i01 * p[1, 0]
    a01 = i00 * p[0, 1] + i01 * p[1, 1]
    a10 = i10 * p[0, 0] + i11 * p[1, 0]
    a11 = i10 * p[0, 1] + i11 * p[1, 1]
    n00 = a00 * i00 + a01 * i01 + r * k0 * k0
    n01 = a00 * i10 + a01 * i11 + r * k0 * k1
    n10 = a10 * i00 + a11 * i01 + r * k1 * k0
    n11 = a10 * i10 + a11 * i11 + r * k1 * k1
    p[0, 0], p[0, 1], p[1, 0], p[1, 1] = n00, n01, n10, n11
    x[0] += k0 * y
    x[1] += k1 * y
    log_likelihood: float = -0.5 * (y * y / s + math.log(max(s, TINY)) + LOG_2PI)
    return log_likelihood


@numba.njit(cache=True, inline="always")
def _level_moments(
    weights: FloatArray, x: FloatArray, p: FloatArray
) -> tuple[float, float, float, float, float]:  # pragma: no cover - compiled
    """The vertical IMM's moment matching: the mean (level, rate) and covariance (its
    three terms) of the mixture of the models' x (M, 2) and p (M, 2, 2) by ``weights``
    (M,): a model's mixed initial condition (its column of mixing weights) or the
    combination (the model probabilities)."""
    m = weights.shape[0]
    x0 = 0.0
    r0 = 0.0
    for i in range(m):
        x0 += weights[i] * x[i, 0]
        r0 += weights[i] * x[i, 1]
    p00 = p01 = p11 = 0.0
    for i in range(m):
        d0 = x[i, 0] - x0
        d1 = x[i, 1] - r0
        p00 += weights[i] * (p[i, 0, 0] + d0 * d0)
        p01 += weights[i] * (p[i, 0, 1] + d0 * d1)
        p11 += weights[i] * (p[i, 1, 1] + d1 * d1)
    return x0, r0, p00, p01, p11


@numba.njit(cache=True)
def vertical_update(
    rows: IntArray,
    t: FloatArray,
    z: FloatArray,
    var: FloatArray,
    rate_z: FloatArray,
    rate_var: FloatArray,
    selected: FloatArray,
    xv: FloatArray,
    pvm: FloatArray,
    muv: FloatArray,
    fl: FloatArray,
    rate: FloatArray,
    pv: FloatArray,
    t_fl: FloatArray,
    fl_ok: BoolArray,
    fl_rejects: IntArray,
    q: FloatArray,
    sojourn: FloatArray,
    mu_start: FloatArray,
    gate: float,
    max_rejects: int,
    initial_climb_variance: float,
    level_rate_variance: float,
) -> None:  # pragma: no cover - compiled
    """``LocalTracker``'s vertical step of the tracks ``rows`` with their levels z (variance
    var), downlinked rates (FL/s, NaN absent) and selected levels (NaN absent) at t, in
    place in the track table's columns: the vertical IMM of ``vertical`` (mixing, the
    level / steady / manoeuvre predictions, sequential scalar Joseph updates, model
    probabilities, combination), a level outside the gate of the combined prediction
    leaving the old state, and a (re)start after ``max_rejects`` rejections in a row or
    on the first level. The numpy reference: ``LocalTracker._update_vertical`` with
    ``implementation = "numpy"`` (``vertical.predict``, ``update``, ``start``)."""
    m = 3
    pi = np.empty((m, m))
    c = np.empty(m)
    w = np.empty((m, m))
    xp = np.empty((m, 2))
    pp = np.empty((m, 2, 2))
    log_post = np.empty(m)
    for n in range(rows.shape[0]):
        row = rows[n]
        has_rate = not math.isnan(rate_z[n])
        restart = not fl_ok[row]
        if not restart:
            dt = t[n] - t_fl[row]
            tt = abs(dt)
            imm_mixing(tt, sojourn, muv[row], pi, c, w)
            for j in range(m):
                x0, r0, p00, p01, p11 = _level_moments(w[:, j], xv[row], pvm[row])
                if j == 0:
                    xp[j, 0] = x0
                    xp[j, 1] = 0.0
                    pp[j, 0, 0] = p00 + q[j] * tt
                    pp[j, 0, 1] = pp[j, 1, 0] = 0.0
                    pp[j, 1, 1] = level_rate_variance
                    continue
                level = x0 + r0 * dt
                pp[j, 0, 0] = p00 + 2.0 * dt * p01 + dt * dt * p11 + q[j] * tt**3 / 3.0
                pp[j, 0, 1] = pp[j, 1, 0] = p01 + dt * p11 + q[j] * dt * tt / 2.0
                pp[j, 1, 1] = p11 + q[j] * tt
                sel = selected[n]
                if (sel - x0) * (level - sel) > 0.0:  # False for a NaN selected level
                    xp[j, 0] = sel
                    xp[j, 1] = 0.0
                else:
                    xp[j, 0] = level
                    xp[j, 1] = r0
            # The gate: the combined prediction's level.
            xc = 0.0
            for j in range(m):
                xc += c[j] * xp[j, 0]
            pc = 0.0
            for j in range(m):
                d0 = xp[j, 0] - xc
                pc += c[j] * (pp[j, 0, 0] + d0 * d0)
            y = z[n] - xc
            if y * y / (pc + var[n]) > gate:
                fl_rejects[row] += 1
                if fl_rejects[row] < max_rejects:
                    continue  # a garbled level: the old state stays, at its old time
                restart = True
        if restart:
            for j in range(m):
                xv[row, j, 0] = z[n]
                xv[row, j, 1] = rate_z[n] if (has_rate and j > 0) else 0.0
                pvm[row, j, 0, 0] = var[n]
                pvm[row, j, 0, 1] = pvm[row, j, 1, 0] = 0.0
                if j == 0:
                    pvm[row, j, 1, 1] = level_rate_variance
                else:
                    pvm[row, j, 1, 1] = rate_var[n] if has_rate else initial_climb_variance
                muv[row, j] = mu_start[j]
        else:
            for j in range(m):
                ll = _vertical_scalar(xp[j], pp[j], z[n], var[n], 0)
                if has_rate:
                    ll += _vertical_scalar(xp[j], pp[j], rate_z[n], rate_var[n], 1)
                log_post[j] = math.log(max(c[j], TINY)) + ll
            top = log_post.max()
            total = 0.0
            for j in range(m):
                muv[row, j] = math.exp(log_post[j] - top)
                total += muv[row, j]
            for j in range(m):
                muv[row, j] /= total
                for a in range(2):
                    xv[row, j, a] = xp[j, a]
                    for b in range(2):
                        pvm[row, j, a, b] = pp[j, a, b]
        # The combination: the track's level, rate and their covariance.
        f0, r0, p00, p01, p11 = _level_moments(muv[row], xv[row], pvm[row])
        fl[row] = f0
        rate[row] = r0
        pv[row, 0, 0] = p00
        pv[row, 0, 1] = pv[row, 1, 0] = p01
        pv[row, 1, 1] = p11
        t_fl[row] = t[n]
        fl_rejects[row] = 0
        fl_ok[row] = True


@numba.njit(cache=True)
def record_updates(
    rows: IntArray,
    t: FloatArray,
    plot_address: IntArray,
    plot_mode3a: IntArray,
    plot_mode3a_valid: BoolArray,
    x_new: FloatArray,
    p_new: FloatArray,
    mu_new: FloatArray,
    xc_new: FloatArray,
    pc_new: FloatArray,
    x: FloatArray,
    P: FloatArray,
    mu: FloatArray,
    xc: FloatArray,
    pc: FloatArray,
    t_state: FloatArray,
    t_hit: FloatArray,
    hist: IntArray,
    due: FloatArray,
    misses: IntArray,
    address: IntArray,
    mode3a: IntArray,
    half_period_s: float,
    hist_mask: int,
    due_after_s: float,
) -> None:  # pragma: no cover - compiled
    """The updated tracks ``rows`` written into the track table's columns, in place: the
    IMM's new state at t, a hit in the M-of-N history (a second plot of the same scan
    counts no second hit), the time due for a miss, and the plots' identity where they
    carry one. The numpy reference: ``LocalTracker._record_updates``."""
    m = x.shape[1]
    for n in range(rows.shape[0]):
        row = rows[n]
        for j in range(m):
            mu[row, j] = mu_new[n, j]
            for a in range(4):
                x[row, j, a] = x_new[n, j, a]
                for b in range(4):
                    P[row, j, a, b] = p_new[n, j, a, b]
        for a in range(4):
            xc[row, a] = xc_new[n, a]
            for b in range(4):
                pc[row, a, b] = pc_new[n, a, b]
        t_state[row] = t[n]
        if t[n] < t_hit[row] + half_period_s:
            hist[row] = hist[row] | 1
        else:
            hist[row] = ((hist[row] << 1) | 1) & hist_mask
        t_hit[row] = max(t_hit[row], t[n])
        due[row] = t_hit[row] + due_after_s
        misses[row] = 0
        if plot_address[n] >= 0:
            address[row] = plot_address[n]
        if plot_mode3a_valid[n] and plot_mode3a[n] >= 0:
            mode3a[row] = plot_mode3a[n]


@numba.njit(cache=True, error_model="numpy")
def initiation_pairs(
    at: FloatArray,
    ax: FloatArray,
    ay: FloatArray,
    ar: FloatArray,
    a_address: IntArray,
    a_code: IntArray,
    a_code_valid: BoolArray,
    bt: FloatArray,
    bx: FloatArray,
    by: FloatArray,
    br: FloatArray,
    b_address: IntArray,
    b_code: IntArray,
    b_code_valid: BoolArray,
    max_speed: float,
    min_speed: float,
    min_dt: float,
    max_dt: float,
    noise_sigmas: float,
    shared_codes: IntArray,
    address_mismatch_penalty: float,
    address_bonus: float,
    mode3a_bonus: float,
    identity_scale: float,
) -> tuple[IntArray, IntArray, FloatArray, float]:  # pragma: no cover - compiled
    """``TwoPointInitiator.pair``'s candidate pairs of waiting plots a and new plots b, in
    (a, b) order: those within the search radius (returned: the largest speed over
    ``max_dt`` plus ``noise_sigmas`` of both sets' largest position sigma) whose time step
    and distance fit a plausible speed, with their cost (distance over the largest
    speed's reach, plus the identity cost scaled by ``identity_scale``, as
    ``identity.identity_cost``). The numpy reference: ``pair`` with ``implementation =
    "numpy"``."""
    na = at.shape[0]
    nb = bt.shape[0]
    noise_a = -np.inf
    for i in range(na):
        noise_a = max(noise_a, np.sqrt(ar[i, 0, 0] + ar[i, 1, 1]))
    noise_b = -np.inf
    for j in range(nb):
        noise_b = max(noise_b, np.sqrt(br[j, 0, 0] + br[j, 1, 1]))
    reach = max_speed * max_dt + noise_sigmas * (noise_a + noise_b)
    first = np.empty(na * nb, np.int64)
    second = np.empty(na * nb, np.int64)
    cost = np.empty(na * nb)
    k = 0
    for i in range(na):
        trace_a = ar[i, 0, 0] + ar[i, 1, 1]
        for j in range(nb):
            d0 = ax[i] - bx[j]
            d1 = ay[i] - by[j]
            dist = np.sqrt(d0 * d0 + d1 * d1)
            if not dist <= reach:
                continue
            dt = bt[j] - at[i]
            sigma = np.sqrt(trace_a + (br[j, 0, 0] + br[j, 1, 1]))
            if not (dt >= min_dt and dt <= max_dt):
                continue
            if not (
                dist <= max_speed * dt + noise_sigmas * sigma
                and dist >= min_speed * dt - noise_sigmas * sigma
            ):
                continue
            both = a_address[i] >= 0 and b_address[j] >= 0
            code_match = a_code[i] >= 0 and a_code[i] == b_code[j]
            code_match = code_match and a_code_valid[i] and b_code_valid[j]
            for shared in shared_codes:
                if a_code[i] == shared:
                    code_match = False
            mismatch = 1.0 if both and a_address[i] != b_address[j] else 0.0
            same = 1.0 if both and a_address[i] == b_address[j] else 0.0
            identity = (
                address_mismatch_penalty * mismatch
                - address_bonus * same
                - mode3a_bonus * (1.0 if code_match else 0.0)
            )
            first[k] = i
            second[k] = j
            cost[k] = dist / (max_speed * dt) + identity_scale * identity
            k += 1
    return first[:k], second[:k], cost[:k], reach


@numba.njit(cache=True)
def valid_plots(
    t: FloatArray, x: FloatArray, y: FloatArray, r: FloatArray
) -> BoolArray:  # pragma: no cover - compiled
    """Plots the tracker can take: finite time, position and covariance, R positive
    definite (R00 > 0, det R > 0). The numpy reference: ``LocalTracker.process``."""
    valid = np.empty(t.shape[0], np.bool_)
    for i in range(t.shape[0]):
        finite = np.isfinite(t[i]) and np.isfinite(x[i]) and np.isfinite(y[i])
        for a in range(2):
            for b in range(2):
                finite = finite and np.isfinite(r[i, a, b])
        positive = r[i, 0, 0] > 0 and r[i, 0, 0] * r[i, 1, 1] - r[i, 0, 1] * r[i, 1, 0] > 0
        valid[i] = finite and positive
    return valid


@numba.njit(cache=True)
def vertical_measurements(
    level: FloatArray,
    typ: IntArray,
    flags: npt.NDArray[np.uint8],
    baro_fpm: FloatArray,
    inertial_fpm: FloatArray,
    selected_ft: FloatArray,
    use_daps: bool,
    mode_s_typ_min: int,
    step_mode_s: float,
    step_mode_c: float,
    fpm_per_fl_s: float,
    baro_variance: float,
    inertial_variance: float,
    rate_bit: int,
    selected_bit: int,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # pragma: no cover - compiled
    """Per plot with a level: its variance (the quantisation step's, 25 ft for Mode S or a
    level that is no whole FL), the downlinked climb rate (FL/s, the inertial one where
    present) and its variance, and the selected level (FL); NaN where absent or without
    ``use_daps``. The numpy reference: ``LocalTracker._vertical_measurements``."""
    n = level.shape[0]
    variance = np.empty(n)
    rate = np.full(n, np.nan)
    rate_variance = np.full(n, np.nan)
    selected = np.full(n, np.nan)
    all_mode_s = True
    for i in range(n):
        if typ[i] < mode_s_typ_min:
            all_mode_s = False
    for i in range(n):
        fine = all_mode_s or typ[i] >= mode_s_typ_min
        fine = fine or abs(level[i] - np.round(level[i])) > 1e-6
        step = step_mode_s if fine else step_mode_c
        variance[i] = step * step / 12.0
        if not use_daps:
            continue
        if flags[i] & rate_bit:
            if np.isfinite(baro_fpm[i]):
                rate[i] = baro_fpm[i] / fpm_per_fl_s
                rate_variance[i] = baro_variance
            if np.isfinite(inertial_fpm[i]):
                rate[i] = inertial_fpm[i] / fpm_per_fl_s
                rate_variance[i] = inertial_variance
        if flags[i] & selected_bit:
            selected[i] = selected_ft[i] / 100.0
    return variance, rate, rate_variance, selected


@numba.njit(cache=True, inline="always")
def _bit_count(value: int) -> int:  # pragma: no cover - compiled
    count = 0
    while value:
        value &= value - 1
        count += 1
    return count


@numba.njit(cache=True)
def record_pairs(
    ti: IntArray,
    pj: IntArray,
    sel: IntArray,
    xp: FloatArray,
    pp: FloatArray,
    c: FloatArray,
    plots: npt.NDArray[np.void],
    reply: BoolArray,
    x: FloatArray,
    P: FloatArray,
    mu: FloatArray,
    xc: FloatArray,
    pc: FloatArray,
    t_state: FloatArray,
    t_hit: FloatArray,
    hist: IntArray,
    due: FloatArray,
    misses: IntArray,
    address: IntArray,
    mode3a: IntArray,
    secondary: BoolArray,
    status: npt.NDArray[np.int8],
    dense_seed: BoolArray,
    xv: FloatArray,
    pvm: FloatArray,
    muv: FloatArray,
    fl: FloatArray,
    rate: FloatArray,
    pv: FloatArray,
    t_fl: FloatArray,
    fl_ok: BoolArray,
    fl_rejects: IntArray,
    vertical_q: FloatArray,
    vertical_sojourn: FloatArray,
    vertical_mu0: FloatArray,
    constants: FloatArray,
    masks: IntArray,
) -> tuple[FloatArray, FloatArray, FloatArray, bool]:  # pragma: no cover - compiled
    """``LocalTracker._apply`` of one plot per track up to the M-of-N test: the tracks
    ``ti`` updated by the IMM with the batch's plots ``plots[pj]`` from their pairs'
    predictions ``xp[sel]``, ``pp[sel]``, ``c[sel]`` (``imm_update``), written into the
    track table (``record_updates``), their vertical filters (``vertical_measurements``
    over the plots with a level, then ``vertical_update``) and their secondary-reply flag
    (``reply``: the batch plots'). ``constants``: the configuration's floats in
    ``LocalTracker._record_constants``' order; ``masks``: the M-of-N window's masks and
    counts. Returns the new model probabilities and combined states, and whether a
    tentative track among them reached its M of N (``LocalTracker._confirm`` decides)."""
    k = ti.size
    z = np.empty((k, 2))
    r = np.empty((k, 2, 2))
    time = np.empty(k)
    plot_address = np.empty(k, np.int64)
    plot_code = np.empty(k, np.int64)
    plot_code_valid = np.empty(k, np.bool_)
    n_level = 0
    for s in range(k):
        row = plots[pj[s]]
        z[s, 0] = row.x
        z[s, 1] = row.y
        for a in range(2):
            for b in range(2):
                r[s, a, b] = row.R[a, b]
        time[s] = row.time
        plot_address[s] = row.address
        plot_code[s] = row.mode3a
        plot_code_valid[s] = row.mode3a_valid
        if row.fl_valid and np.isfinite(row.flight_level):
            n_level += 1
    x_new, p_new, mu_new, xc_new, pc_new = imm_update(xp[sel], pp[sel], c[sel], z, r)
    record_updates(
        ti, time, plot_address, plot_code, plot_code_valid, x_new, p_new, mu_new, xc_new,
        pc_new, x, P, mu, xc, pc, t_state, t_hit, hist, due, misses, address, mode3a,
        constants[0], masks[0], constants[1],
    )  # fmt: skip
    if n_level:
        level_rows = np.empty(n_level, np.int64)
        level_time = np.empty(n_level)
        level = np.empty(n_level)
        typ = np.empty(n_level, np.int64)
        flags = np.empty(n_level, np.uint8)
        baro = np.empty(n_level)
        inertial = np.empty(n_level)
        selected_ft = np.empty(n_level)
        n = 0
        for s in range(k):
            row = plots[pj[s]]
            if row.fl_valid and np.isfinite(row.flight_level):
                level_rows[n] = ti[s]
                level_time[n] = row.time
                level[n] = row.flight_level
                typ[n] = row.typ
                flags[n] = row.dap_flags
                baro[n] = row.baro_rate_fpm
                inertial[n] = row.inertial_rate_fpm
                selected_ft[n] = row.selected_altitude_ft
                n += 1
        variance, climb, climb_variance, selected = vertical_measurements(
            level, typ, flags, baro, inertial, selected_ft, constants[2] != 0.0, masks[3],
            constants[3], constants[4], constants[5], constants[6], constants[7], masks[4],
            masks[5],
        )  # fmt: skip
        vertical_update(
            level_rows, level_time, level, variance, climb, climb_variance, selected, xv,
            pvm, muv, fl, rate, pv, t_fl, fl_ok, fl_rejects, vertical_q, vertical_sojourn,
            vertical_mu0, constants[8], masks[6], constants[9], constants[10],
        )  # fmt: skip
    candidates = False
    for s in range(k):
        row = ti[s]
        secondary[row] = secondary[row] or reply[pj[s]]
        dense = dense_seed[row]
        hits = _bit_count(hist[row] & (masks[1] if dense else masks[2]))
        if status[row] == 0 and hits >= masks[7] + (masks[8] if dense else 0):
            candidates = True
    return mu_new, xc_new, pc_new, candidates


@numba.njit(cache=True)
def finish_pairs(
    ti: IntArray,
    pj: IntArray,
    track_status: npt.NDArray[np.int8],
    mu_new: FloatArray,
    xc_new: FloatArray,
    pc_new: FloatArray,
    plots: npt.NDArray[np.void],
    plot_cell: IntArray,
    plot_dense: BoolArray,
    use_clutter: bool,
    min_speed: float,
    number: IntArray,
    address: IntArray,
    mode3a: IntArray,
    clutter_cell: IntArray,
    status: npt.NDArray[np.int8],
    fl: FloatArray,
    rate: FloatArray,
    t_fl: FloatArray,
    fl_ok: BoolArray,
    out: npt.NDArray[np.void],
) -> None:  # pragma: no cover - compiled
    """The rest of ``LocalTracker._apply``: a confirmed primary-only track that has
    slowed below ``min_speed`` or is stuck in a dense clutter cell (``_in_clutter``: the
    plot's cell ``plot_cell[pj]``, dense, as its previous plot's) goes back to tentative,
    each track's clutter cell recorded; the statuses (``track_status``: after the M-of-N
    test) written into the table; and the output rows (``_rows``) into ``out``."""
    for s in range(ti.size):
        row = ti[s]
        plot = plots[pj[s]]
        new_status = track_status[s]
        stuck = False
        if use_clutter:
            cell = plot_cell[pj[s]]
            stuck = cell == clutter_cell[row] and plot_dense[pj[s]]
            clutter_cell[row] = cell
        if address[row] < 0 and mode3a[row] < 0 and new_status == 1:
            speed = np.hypot(xc_new[s, 2], xc_new[s, 3])
            if speed < min_speed or stuck:
                new_status = 0
        status[row] = new_status
        o = out[s]
        o.track_number = number[row]
        o.time = plot.time
        o.x = xc_new[s, 0]
        o.y = xc_new[s, 1]
        o.vx = xc_new[s, 2]
        o.vy = xc_new[s, 3]
        for a in range(4):
            for b in range(4):
                o.P[4 * a + b] = pc_new[s, a, b]
        if fl_ok[row]:
            o.flight_level = fl[row] + rate[row] * (plot.time - t_fl[row])
            o.climb_rate_fl_per_s = rate[row]
        else:
            o.flight_level = np.nan
            o.climb_rate_fl_per_s = np.nan
        o.status = new_status
        o.plot_id = plot.plot_id
        o.mode3a = mode3a[row]
        o.address = address[row]
        for j in range(mu_new.shape[1]):
            o.model_probabilities[j] = mu_new[s, j]


@numba.njit(cache=True)
def untaken_plots(
    plot_id: IntArray,
    reply: BoolArray,
    taken_plot_id: IntArray,
    taken_status: npt.NDArray[np.int8],
    confirmed: int,
) -> BoolArray:  # pragma: no cover - compiled
    """The plots ``LocalTracker._learn_clutter`` teaches the clutter map: those without a
    secondary reply, and those of no output row (``taken_*``) of a confirmed track."""
    free = np.empty(plot_id.size, np.bool_)
    for j in range(plot_id.size):
        free[j] = not reply[j]
        if free[j]:
            continue
        free[j] = True
        for k in range(taken_plot_id.size):
            if taken_plot_id[k] == plot_id[j] and taken_status[k] == confirmed:
                free[j] = False
                break
    return free


@numba.njit(cache=True)
def screen_pairs(
    track: IntArray,
    plot: IntArray,
    status: npt.NDArray[np.int8],
    secondary: BoolArray,
    reply: BoolArray,
    density: FloatArray,
    tentative: int,
) -> tuple[IntArray, FloatArray]:  # pragma: no cover - compiled
    """``LocalTracker._screen`` of the gated pairs (``track``, ``plot``) with the
    batch's ``_BatchPlots`` (``reply``, ``density``: empty without a clutter map): the
    pairs kept, ascending (not those of a tentative track seeded only by primary plots
    and a plot with a secondary reply, ``clutter.primary_seed_takes_reply``), and the
    density at each kept pair's plot (empty without a map)."""
    n = track.size
    kept = np.empty(n, np.int64)
    n_kept = 0
    for k in range(n):
        t = track[k]
        if not (status[t] == tentative and not secondary[t] and reply[plot[k]]):
            kept[n_kept] = k
            n_kept += 1
    kept = kept[:n_kept]
    kept_density = np.empty(n_kept if density.size else 0)
    for s in range(kept_density.size):
        kept_density[s] = density[plot[kept[s]]]
    return kept, kept_density


@numba.njit(cache=True)
def hard_assignment(
    track: IntArray,
    plot: IntArray,
    chosen: IntArray,
    status: npt.NDArray[np.int8],
    too_old: BoolArray,
    used: BoolArray,
    blocked: BoolArray,
    updated: BoolArray,
    confirmed: int,
) -> tuple[IntArray, IntArray, int]:  # pragma: no cover - compiled
    """``LocalTracker._associate``'s bookkeeping of a hard assignment (GNN): every plot
    in a confirmed track's gate ``blocked`` from initiation, the ``chosen`` pairs'
    plots ``used`` and tracks ``updated`` (all three written in place); returns the
    chosen pairs' tracks and plots and the number of plots too old for any track that
    none took (dropped late)."""
    for k in range(track.size):
        if status[track[k]] == confirmed:
            blocked[plot[k]] = True
    tracks = track[chosen]
    plot_index = plot[chosen]
    for s in range(chosen.size):
        used[plot_index[s]] = True
        updated[tracks[s]] = True
    late = 0
    for j in range(too_old.size):
        if too_old[j] and not used[j]:
            late += 1
    return tracks, plot_index, late


@numba.njit(cache=True)
def missed_scans(
    now: float,
    updated: BoolArray,
    t_hit: FloatArray,
    misses: IntArray,
    due: FloatArray,
    n: int,
    scan_period_s: float,
    miss_tolerance: float,
) -> tuple[IntArray, IntArray]:  # pragma: no cover - compiled
    """The first part of ``LocalTracker._age``: of the ``n`` oldest rows, those not
    ``updated`` that missed a scan more than they had counted (none while ``now`` is
    before every ``due``), and each one's count of missed scans."""
    idle = np.empty(0, np.int64)
    n_miss = np.empty(0, np.int64)
    earliest_due = np.inf
    for r in range(n):
        earliest_due = nan_min(earliest_due, due[r])
    if now < earliest_due:
        return idle, n_miss
    idle = np.empty(n, np.int64)
    n_miss = np.empty(n, np.int64)
    k = 0
    for r in range(n):
        if updated[r]:
            continue
        missed = max(np.floor((now - t_hit[r]) / scan_period_s - miss_tolerance), 0.0)
        if int(missed) > misses[r]:
            idle[k] = r
            n_miss[k] = int(missed)
            k += 1
    return idle[:k], n_miss[:k]


@numba.njit(cache=True, inline="always")
def nan_max(a: float, b: float) -> float:  # pragma: no cover - compiled
    """numpy's ``max``: NaN wins."""
    if np.isnan(a) or np.isnan(b):
        return np.nan
    return max(a, b)


@numba.njit(cache=True, inline="always")
def nan_min(a: float, b: float) -> float:  # pragma: no cover - compiled
    """numpy's ``min``: NaN wins."""
    if np.isnan(a) or np.isnan(b):
        return np.nan
    return min(a, b)
