"""Motion models with variable steps (DOMAIN.md section 4), vectorised over tracks.

The state is [x, y, vx, vy] in every model, so that the IMM mixes like with like. The turn
models have a fixed turn rate each (the fixed-rate alternative to an EKF on omega):
linear, no Jacobian, and a turn of another rate is followed by the mixture of models.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import FloatArray

STATE_DIM = 4
SMALL_TURN_RAD_S = 1e-9


def cv_transition(dt: FloatArray) -> FloatArray:
    """F(T) of the constant-velocity model, one (4, 4) per step."""
    f = np.zeros((dt.shape[0], 4, 4))
    f[:, 0, 0] = f[:, 1, 1] = f[:, 2, 2] = f[:, 3, 3] = 1.0
    f[:, 0, 2] = f[:, 1, 3] = dt
    return f


def ct_transition(dt: FloatArray, omega: float) -> FloatArray:
    """F(T) of a coordinated turn at a known rate omega (rad/s, counter-clockwise)."""
    if abs(omega) < SMALL_TURN_RAD_S:
        return cv_transition(dt)
    wt = omega * dt
    s, c = np.sin(wt), np.cos(wt)
    f = np.zeros((dt.shape[0], 4, 4))
    f[:, 0, 0] = f[:, 1, 1] = 1.0
    f[:, 0, 2] = f[:, 1, 3] = s / omega
    f[:, 0, 3] = -(1.0 - c) / omega
    f[:, 1, 2] = (1.0 - c) / omega
    f[:, 2, 2] = f[:, 3, 3] = c
    f[:, 2, 3] = -s
    f[:, 3, 2] = s
    return f


def white_acceleration_q(dt: FloatArray, q: float) -> FloatArray:
    """Q(T) = q [[T^3/3, T^2/2], [T^2/2, T]] per axis.

    |T| is used so that a plot predicted backwards still gets a positive covariance: going
    back in time loses knowledge too. The turn models use the same Q (exact for CV, a
    common approximation for a fixed-rate turn whose rate error it absorbs through q).
    """
    t = np.abs(dt)
    t2 = t * t
    qm = np.zeros((dt.shape[0], 4, 4))
    qm[:, 0, 0] = qm[:, 1, 1] = q * t2 * t / 3.0
    qm[:, 0, 2] = qm[:, 2, 0] = qm[:, 1, 3] = qm[:, 3, 1] = q * t2 / 2.0
    qm[:, 2, 2] = qm[:, 3, 3] = q * t
    return qm


@dataclass(frozen=True)
class ModelSet:
    """The IMM's models: model 0 is CV, the others fixed-rate turns."""

    turn_rates_rad_s: FloatArray
    """One per model, 0 for CV."""
    q: FloatArray
    mean_sojourn_s: FloatArray
    initial_probabilities: FloatArray

    @staticmethod
    def from_config(config: TrackerConfig) -> ModelSet:
        n = config.n_models
        return ModelSet(
            turn_rates_rad_s=np.radians(np.array((0.0, *config.turn_rates_deg_s))),
            q=np.array([config.q_cv] + [config.q_ct] * (n - 1)),
            mean_sojourn_s=np.array(config.mean_sojourn_s, dtype=np.float64),
            initial_probabilities=np.array(config.initial_model_probabilities)
            / np.sum(config.initial_model_probabilities),
        )

    @property
    def n_models(self) -> int:
        return int(self.q.shape[0])

    def transition(self, model: int, dt: FloatArray) -> tuple[FloatArray, FloatArray]:
        return (
            ct_transition(dt, float(self.turn_rates_rad_s[model])),
            white_acceleration_q(dt, float(self.q[model])),
        )

    def transitions(self, dt: FloatArray) -> tuple[FloatArray, FloatArray]:
        """F and Q of every model at once, (k, M, 4, 4) each: the same values as
        ``transition`` model by model, built with a few array operations per batch instead
        of a few per model."""
        k, m = dt.shape[0], self.n_models
        omega, straight = self._turn_rates_for_division
        s = np.sin(dt[:, None] * omega)
        c = np.cos(dt[:, None] * omega)
        s_w = s / omega
        c_w = (1.0 - c) / omega
        for j in straight:
            # The CV entries: dt for the position-velocity terms, no velocity rotation.
            s_w[:, j] = dt
            c_w[:, j] = 0.0
            c[:, j] = 1.0
            s[:, j] = 0.0
        # Written through the flat view of each 4x4, by basic slicing only (far cheaper
        # than fancy indexing on small arrays): equal entries that lie a fixed stride
        # apart (5 on the diagonal) take one assignment.
        f = np.zeros((k, m, 16))
        f[..., 0:6:5] = 1.0
        f[..., 2:8:5] = s_w[..., None]
        f[..., 3] = -c_w
        f[..., 6] = c_w
        f[..., 10::5] = c[..., None]
        f[..., 11] = -s
        f[..., 14] = s
        t = np.abs(dt)[:, None]
        t2 = t * t
        q = self.q
        qm = np.zeros((k, m, 16))
        qm[..., 0:6:5] = (q * t2 * t / 3.0)[..., None]
        qm[..., 2:8:5] = qm[..., 8:14:5] = (q * t2 / 2.0)[..., None]
        qm[..., 10::5] = (q * t)[..., None]
        return f.reshape(k, m, 4, 4), qm.reshape(k, m, 4, 4)

    @cached_property
    def _turn_rates_for_division(self) -> tuple[FloatArray, tuple[int, ...]]:
        """Turn rates with 1 in place of the straight models' (so that dividing by them is
        safe; ``transitions`` overwrites those models' entries), and the straight models."""
        straight = np.abs(self.turn_rates_rad_s) < SMALL_TURN_RAD_S
        omega = np.where(straight, 1.0, self.turn_rates_rad_s)
        return omega, tuple(int(j) for j in np.flatnonzero(straight))

    def switching(self, dt: FloatArray) -> FloatArray:
        """Markov matrices pi[k, i, j] = P(model j after dt | model i before), from each
        model's mean sojourn time, so that a long gap allows more switching than a short one."""
        m = self.n_models
        stay = np.exp(-np.abs(dt)[:, None] / self.mean_sojourn_s[None, :])
        if m == 1:
            return np.ones((dt.shape[0], 1, 1))
        pi = np.empty((dt.shape[0], m, m))
        pi[...] = ((1.0 - stay) / (m - 1))[:, :, None]
        # The diagonal is every (m + 1)-th entry of each flat m x m: one basic-slice write.
        pi.reshape(-1, m * m)[:, :: m + 1] = stay
        return pi
