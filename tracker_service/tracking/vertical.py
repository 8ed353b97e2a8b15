"""The vertical tracker: flight level and climb rate of each track, an IMM of three
models on Mode C / Mode S levels and, where the aircraft downlinks them, its vertical
rates and selected altitude (BDS 6,0 and 4,0). The numpy reference; the compiled kernel is
``kernels.vertical_update``, held to this to 1e-9 by tests/test_tracking_kernels.py.

Kept apart from the horizontal IMM because Mode C is pressure altitude with its own
quantisation and its own failures (garbling), and a plot without a valid flight level
still updates the horizontal track.

State per model: [FL, climb rate FL/s] (1 FL/s = 6,000 ft/min). The models:

0. level: the aircraft holds its level. The rate is 0 (F = [[1, 0], [0, 0]], the rate's
   variance ``level_rate_variance``), the level a slow random walk (``vertical_q[0]``,
   FL^2/s): the quantised Mode C of a level aircraft averages down to a few feet.
1. steady climb or descent: constant rate, white noise of intensity ``vertical_q[1]``
   (FL^2/s^3) on it: airliners climb at a rate that drifts slowly (it falls with height
   at constant IAS / Mach).
2. vertical manoeuvre: the onset of a climb or descent and the level-off, white noise of
   ``vertical_q[2]`` on the rate (a rate change of 2,000 ft/min in 10-20 s).

Climb and descent are one model for a linear filter (the sign is in the state); a level,
a steady change and a change of rate are what differ, and what the mean sojourn times
(``vertical_sojourn_s``) describe. The switching is the horizontal IMM's (Markov, by
sojourn times, for any time step).

Measurements, as sequential scalar updates in each model (independent noises: the same
as one joint update):

- the level: uniform quantisation noise step^2 / 12, 25 ft for Mode S or any level that
  is not a whole FL, 100 ft for Gillham Mode C. A level outside the 1-dof gate
  ``fl_gate`` of the combined prediction (garbled Mode C) is ignored; ``fl_max_rejects``
  in a row restart the filter (a real jump: a wrong association or a new aircraft);
- the climb rate where the plot carries one (``inertial_rate_fpm`` preferred, else
  ``baro_rate_fpm``), with sigma ``inertial_rate_sigma_fpm`` / ``baro_rate_sigma_fpm``:
  the level model's rate variance is tiny, so a downlinked rate of 1,000 ft/min takes
  the probability away from it at once, before the quantised levels show the climb;
- the selected altitude (``selected_altitude_ft``, BDS 4,0) bounds the climb: a moving
  model's prediction that would cross it stops at it with rate 0 (the autopilot captures
  the level), so the level-off is not overshot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import FloatArray, IntArray

MODE_S_TYP_MIN = 4
N_VERTICAL_MODELS = 3
LEVEL, STEADY, MANOEUVRE = 0, 1, 2
FPM_PER_FL_S = 6000.0
LOG_2PI = math.log(2.0 * math.pi)
TINY = 1e-300


def measurement_variance(
    flight_level: FloatArray, typ: IntArray, config: TrackerConfig
) -> FloatArray:
    """Uniform quantisation noise, step^2 / 12: 25 ft for Mode S or any level that is not a
    whole FL (it cannot come from 100 ft Gillham code), 100 ft otherwise."""
    mode_s = typ >= MODE_S_TYP_MIN
    if mode_s.all():  # the usual batch: no level to inspect
        return np.full(typ.shape, config.fl_step_mode_s * config.fl_step_mode_s / 12.0)
    fine = mode_s | (np.abs(flight_level - np.round(flight_level)) > 1e-6)
    step = np.where(fine, config.fl_step_mode_s, config.fl_step_mode_c)
    return np.asarray(step * step / 12.0, dtype=np.float64)


@dataclass(frozen=True)
class VerticalMeasurements:
    """Per plot: the level z and its variance, the downlinked climb rate (FL/s, NaN
    absent) and its variance, and the selected level (FL, NaN absent)."""

    time: FloatArray
    level: FloatArray
    level_variance: FloatArray
    rate: FloatArray
    rate_variance: FloatArray
    selected_level: FloatArray


def rate_measurements(
    baro_fpm: FloatArray | None, inertial_fpm: FloatArray | None, config: TrackerConfig, n: int
) -> tuple[FloatArray, FloatArray]:
    """The climb rate each plot says (FL/s, NaN absent) and its variance: the inertial
    (hybrid) rate where present, smoother and without the barometric lag, else the
    barometric one."""
    rate = np.full(n, np.nan)
    variance = np.full(n, np.nan)
    for column, sigma_fpm in (
        (baro_fpm, config.baro_rate_sigma_fpm),
        (inertial_fpm, config.inertial_rate_sigma_fpm),
    ):
        if column is None:
            continue
        known = np.isfinite(column)
        rate = np.where(known, column / FPM_PER_FL_S, rate)
        variance = np.where(known, (sigma_fpm / FPM_PER_FL_S) ** 2, variance)
    return rate, variance


@dataclass(frozen=True)
class VerticalState:
    """The vertical IMM of some tracks: per-model x (k, 3, 2), P (k, 3, 2, 2), mu (k, 3)."""

    x: FloatArray
    P: FloatArray
    mu: FloatArray


def switching(dt: FloatArray, sojourn: FloatArray) -> FloatArray:
    """Markov matrix pi[i, j] (k, M, M) over |dt|: stay exp(-|dt| / sojourn_i), leave to
    each other model equally."""
    m = sojourn.shape[0]
    stay = np.exp(-np.abs(dt)[:, None] / sojourn[None, :])
    pi = np.repeat(((1.0 - stay) / (m - 1))[:, :, None], m, axis=2)
    index = np.arange(m)
    pi[:, index, index] = stay
    return np.asarray(pi, dtype=np.float64)


def predict(
    state: VerticalState, dt: FloatArray, selected_level: FloatArray, config: TrackerConfig
) -> VerticalState:
    """IMM mixing and each model's prediction over dt: the per-model predictions, with
    the predicted model probabilities c as their ``mu``."""
    q = np.asarray(config.vertical_q, dtype=np.float64)
    pi = switching(dt, np.asarray(config.vertical_sojourn_s, dtype=np.float64))
    # Sums over models written as loops in model order, as the compiled kernel adds them
    # (an einsum's order differs in the last bits, and a zero rate must stay zero).
    c = _model_sum(pi * state.mu[:, :, None])
    w = pi * state.mu[:, :, None] / np.maximum(c, TINY)[:, None, :]  # w[k, i, j]
    t = np.abs(dt)
    xp = np.empty_like(state.x)
    pp = np.empty_like(state.P)
    for j in range(N_VERTICAL_MODELS):
        x0, p0 = _mixture(w[:, :, j], state.x, state.P)
        if j == LEVEL:
            # F = [[1, 0], [0, 0]]: the level holds, its rate is 0.
            xp[:, j, 0] = x0[:, 0]
            xp[:, j, 1] = 0.0
            pp[:, j, 0, 0] = p0[:, 0, 0] + q[j] * t
            pp[:, j, 0, 1] = pp[:, j, 1, 0] = 0.0
            pp[:, j, 1, 1] = config.level_rate_variance
            continue
        # Constant rate, white noise on the rate (DOMAIN.md section 4's CV per axis).
        level = x0[:, 0] + x0[:, 1] * dt
        pp[:, j, 0, 0] = (
            p0[:, 0, 0] + 2.0 * dt * p0[:, 0, 1] + dt * dt * p0[:, 1, 1] + q[j] * t**3 / 3.0
        )
        pp[:, j, 0, 1] = pp[:, j, 1, 0] = p0[:, 0, 1] + dt * p0[:, 1, 1] + q[j] * dt * t / 2.0
        pp[:, j, 1, 1] = p0[:, 1, 1] + q[j] * t
        # A climb stops at the selected level it would cross (the autopilot captures it).
        crosses = (selected_level - x0[:, 0]) * (level - selected_level) > 0.0
        xp[:, j, 0] = np.where(crosses, selected_level, level)
        xp[:, j, 1] = np.where(crosses, 0.0, x0[:, 1])
    return VerticalState(xp, pp, c)


def combine(state: VerticalState) -> tuple[FloatArray, FloatArray]:
    """The moment-matched mean (k, 2) and covariance (k, 2, 2) of each track's mixture."""
    return _mixture(state.mu, state.x, state.P)


def _model_sum(terms: FloatArray) -> FloatArray:
    """terms (k, M, ...) summed over the models (axis 1) in model order."""
    total = terms[:, 0].copy()
    for i in range(1, terms.shape[1]):
        total += terms[:, i]
    return total


def _mixture(w: FloatArray, x: FloatArray, P: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Mean sum_i w_i x_i and covariance sum_i w_i (P_i + d_i d_i'), d_i = x_i - mean."""
    mean = _model_sum(w[:, :, None] * x)
    d = x - mean[:, None, :]
    spread = P + d[:, :, :, None] * d[:, :, None, :]
    return mean, _model_sum(w[:, :, None, None] * spread)


def scalar_update(
    x: FloatArray, P: FloatArray, z: FloatArray, r: FloatArray, component: int
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Joseph update of (k, 2) states with a measurement of one component; returns x, P
    and the log-likelihood of z. P = (I - K H) P (I - K H)' + K r K'."""
    y = z - x[:, component]
    s = P[:, component, component] + r
    k = P[:, :, component] / s[:, None]
    ikh = np.broadcast_to(np.eye(2), P.shape).copy()
    ikh[:, :, component] -= k
    p_new = ikh @ P @ np.swapaxes(ikh, 1, 2) + r[:, None, None] * k[:, :, None] * k[:, None, :]
    log_likelihood = -0.5 * (y * y / s + np.log(np.maximum(s, TINY)) + LOG_2PI)
    return x + k * y[:, None], p_new, log_likelihood


def update(
    pred: VerticalState, m: VerticalMeasurements
) -> tuple[VerticalState, FloatArray, FloatArray]:
    """Every model updated with the level and, where known, the downlinked rate; the
    model probabilities from their likelihoods. Returns the state and its combination."""
    x = pred.x.copy()
    p = pred.P.copy()
    log_post = np.log(np.maximum(pred.mu, TINY))
    has_rate = np.isfinite(m.rate)
    for j in range(N_VERTICAL_MODELS):
        xj, pj, ll = scalar_update(x[:, j], p[:, j], m.level, m.level_variance, 0)
        if has_rate.any():
            xr, pr, llr = scalar_update(
                xj, pj, np.where(has_rate, m.rate, 0.0), np.where(has_rate, m.rate_variance, 1.0), 1
            )
            xj = np.where(has_rate[:, None], xr, xj)
            pj = np.where(has_rate[:, None, None], pr, pj)
            ll = ll + np.where(has_rate, llr, 0.0)
        x[:, j], p[:, j] = xj, pj
        log_post[:, j] += ll
    log_post -= log_post.max(axis=1, keepdims=True)
    mu = np.exp(log_post)
    mu /= mu.sum(axis=1, keepdims=True)
    state = VerticalState(x, p, mu)
    xc, pc = combine(state)
    return state, xc, pc


def start(m: VerticalMeasurements, config: TrackerConfig) -> VerticalState:
    """A new vertical track at each plot's level: rate 0 (or the downlinked one)."""
    k = m.level.shape[0]
    has_rate = np.isfinite(m.rate)
    x = np.zeros((k, N_VERTICAL_MODELS, 2))
    x[:, :, 0] = m.level[:, None]
    x[:, 1:, 1] = np.where(has_rate, m.rate, 0.0)[:, None]
    p = np.zeros((k, N_VERTICAL_MODELS, 2, 2))
    p[:, :, 0, 0] = m.level_variance[:, None]
    p[:, LEVEL, 1, 1] = config.level_rate_variance
    p[:, 1:, 1, 1] = np.where(has_rate, m.rate_variance, config.initial_climb_variance)[:, None]
    mu = np.broadcast_to(
        np.asarray(config.vertical_initial_probabilities, dtype=np.float64),
        (k, N_VERTICAL_MODELS),
    ).copy()
    return VerticalState(x, p, mu)
