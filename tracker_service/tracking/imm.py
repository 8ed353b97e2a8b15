"""IMM predictor and updater over arrays of tracks (or of track-plot pairs).

Shapes: k rows (tracks or candidate pairs), M models, per-model states x (k, M, 4) and
covariances P (k, M, 4, 4), model probabilities mu (k, M). The measurement is the
position: H = [I2 0].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import FloatArray, IntArray

LOG_2PI = float(np.log(2.0 * np.pi))
TINY = 1e-300


@dataclass(frozen=True)
class ImmPrediction:
    """Per-model predicted states, predicted model probabilities, and their combination."""

    x: FloatArray
    P: FloatArray
    c: FloatArray
    x_comb: FloatArray
    P_comb: FloatArray

    def take(self, index: IntArray) -> ImmPrediction:
        return ImmPrediction(
            x=self.x[index],
            P=self.P[index],
            c=self.c[index],
            x_comb=self.x_comb[index],
            P_comb=self.P_comb[index],
        )


@dataclass(frozen=True)
class ImmUpdate:
    """Per-model updated states, the updated model probabilities, and their combination."""

    x: FloatArray
    P: FloatArray
    mu: FloatArray
    x_comb: FloatArray
    P_comb: FloatArray


class ImmFilter(Protocol):
    """The IMM steps the local tracker runs, over arrays of tracks or track-plot pairs."""

    def predict(
        self, x: FloatArray, P: FloatArray, mu: FloatArray, dt: FloatArray
    ) -> ImmPrediction:
        """Mixing and each model's prediction over its own step dt (k,)."""
        ...

    def innovation_test(
        self, pred: ImmPrediction, z: FloatArray, R: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        """NIS and log det S of the combined prediction at the plots z (k, 2), R (k, 2, 2)."""
        ...

    def update(self, pred: ImmPrediction, z: FloatArray, R: FloatArray) -> ImmUpdate:
        """Every model updated with its plot, the model probabilities, the combination."""
        ...


class NumpyImm:
    """The reference: the textbook equations as numpy array operations (this module)."""

    def __init__(self, models: ModelSet) -> None:
        self.models = models

    def predict(
        self, x: FloatArray, P: FloatArray, mu: FloatArray, dt: FloatArray
    ) -> ImmPrediction:
        return predict(x, P, mu, dt, self.models)

    def innovation_test(
        self, pred: ImmPrediction, z: FloatArray, R: FloatArray
    ) -> tuple[FloatArray, FloatArray]:
        return innovation_test(pred, z, R)

    def update(self, pred: ImmPrediction, z: FloatArray, R: FloatArray) -> ImmUpdate:
        x, p, mu = update(pred, z, R)
        xc, pc = combine(x, p, mu)
        return ImmUpdate(x, p, mu, xc, pc)


def make_imm(implementation: str, models: ModelSet) -> ImmFilter:
    """The IMM by name: "compiled" (``kernels``, numba) or "numpy" (the reference)."""
    if implementation == "numpy":
        return NumpyImm(models)
    if implementation == "compiled":
        from tracker_service.tracking.kernels import CompiledImm  # kernels imports this module

        return CompiledImm(models)
    raise ValueError(f"implementation {implementation!r}: use 'compiled' or 'numpy'")


def inv2(s: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Inverse and determinant of stacked 2x2 matrices in closed form (faster than LAPACK
    calls on thousands of tiny matrices)."""
    flat = s.reshape(*s.shape[:-2], 4)
    det = flat[..., 0] * flat[..., 3] - flat[..., 1] * flat[..., 2]
    inv = np.empty_like(flat)
    # Through the flat view: [d, a] and -[b, c] are each one strided slice.
    inv[..., 0::3] = flat[..., 3::-3] / det[..., None]
    inv[..., 1:3] = -flat[..., 1:3] / det[..., None]
    return inv.reshape(s.shape), det


def combine(x: FloatArray, P: FloatArray, w: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Moment-matched mean and covariance of a mixture (weights w (k, M))."""
    xc = np.einsum("km,kma->ka", w, x)
    d = x - xc[:, None, :]
    spread = P + d[..., :, None] * d[..., None, :]
    return xc, np.einsum("km,kmab->kab", w, spread)


def mixing(mu: FloatArray, dt: FloatArray, models: ModelSet) -> tuple[FloatArray, FloatArray]:
    """Predicted model probabilities c (k, M) and mixing weights w[k, i, j] = P(model i
    before | model j after) over steps dt (k,)."""
    pi = models.switching(dt)
    c = np.einsum("kij,ki->kj", pi, mu)
    return c, pi * mu[:, :, None] / np.maximum(c[:, None, :], TINY)


def predict(
    x: FloatArray, P: FloatArray, mu: FloatArray, dt: FloatArray, models: ModelSet
) -> ImmPrediction:
    """IMM mixing, then each model's prediction over its own step dt (k,)."""
    c, w = mixing(mu, dt, models)
    f, q = models.transitions(dt)
    return mix_and_move(x, P, c, w, f, q)


def mix_and_move(
    x: FloatArray, P: FloatArray, c: FloatArray, w: FloatArray, f: FloatArray, q: FloatArray
) -> ImmPrediction:
    """``predict`` given the mixing (``mixing``) and the models' F and Q (k, M, 4, 4)."""
    x0 = np.einsum("kij,kia->kja", w, x)
    d = x[:, :, None, :] - x0[:, None, :, :]
    p0 = np.einsum("kij,kiab->kjab", w, P) + np.einsum("kija,kijb->kjab", w[..., None] * d, d)
    # All models in one stacked product: a loop over models cost more in call overhead
    # than in arithmetic on the few pairs of a sector.
    xp = np.einsum("kmab,kmb->kma", f, x0)
    pp = f @ p0 @ np.swapaxes(f, -1, -2) + q
    xc, pc = combine(xp, pp, c)
    return ImmPrediction(x=xp, P=pp, c=c, x_comb=xc, P_comb=pc)


def innovation_test(
    pred: ImmPrediction, z: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """NIS and log det S of the combined prediction: what gating and assignment compare."""
    y = z - pred.x_comb[:, :2]
    s_inv, det = inv2(pred.P_comb[:, :2, :2] + R)
    nis = np.einsum("ka,kab,kb->k", y, s_inv, y)
    return nis, np.log(np.maximum(det, TINY))


def update(
    pred: ImmPrediction, z: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Model-matched Joseph-form updates and the model-probability update.

    Returns per-model states, covariances and the updated probabilities.
    """
    xp, pp = pred.x, pred.P
    y = z[:, None, :] - xp[:, :, :2]
    s = pp[:, :, :2, :2] + R[:, None]
    s_inv, det = inv2(s)
    k_gain = pp[:, :, :, :2] @ s_inv
    x_new = xp + np.einsum("kmab,kmb->kma", k_gain, y)
    p_new = joseph(pp, k_gain, R[:, None])
    return x_new, p_new, model_probabilities(pred.c, y, s_inv, det)


def joseph(pp: FloatArray, k_gain: FloatArray, R: FloatArray) -> FloatArray:
    """(I - K H) P (I - K H)^T + K R K^T for H = [I2 0]: the updated covariance for any
    gain K (..., 4, 2), optimal or not."""
    # I - K H, written entry by entry (the diagonal is every fifth entry of the flat 4x4):
    # cheaper than copying a broadcast identity.
    ikh = np.zeros((*pp.shape[:-2], 16))
    ikh[..., ::5] = 1.0
    ikh = ikh.reshape(pp.shape)
    ikh[..., :, :2] -= k_gain
    p_new = ikh @ pp @ np.swapaxes(ikh, -1, -2) + k_gain @ R @ np.swapaxes(k_gain, -1, -2)
    return 0.5 * (p_new + np.swapaxes(p_new, -1, -2))


def model_probabilities(
    c: FloatArray, y: FloatArray, s_inv: FloatArray, det: FloatArray
) -> FloatArray:
    """Updated model probabilities (k, M) from the predicted ones and each model's
    innovation y (k, M, 2) with its covariance's inverse and determinant."""
    nis = np.einsum("kma,kmab,kmb->km", y, s_inv, y)
    log_lik = -0.5 * (nis + np.log(np.maximum(det, TINY))) - LOG_2PI
    log_post = np.log(np.maximum(c, TINY)) + log_lik
    # Log-sum-exp: far from every model, the plain likelihoods all underflow to 0.
    log_post -= log_post.max(axis=1, keepdims=True)
    mu = np.exp(log_post)
    mu /= mu.sum(axis=1, keepdims=True)
    return np.asarray(mu)
