"""Residual radar biases as Schmidt "consider" terms of a system track's IMM.

A radar's residual bias (what its bias estimate has not taken off its plots) is one error
common to all its plots of an aircraft for minutes, not white noise on each plot. Added
to every plot's R, it makes the filter trust each plot less and lag (issue 10 finding 5:
one radar's system tracks worse than its local tracks). Here it is what it is: per system
track and radar l, the plane offset b_l ~ N(0, B_l) (B_l = C P_s C^T at the aircraft,
from the bias estimator) is a state that is considered, never estimated (DOMAIN.md
section 6's Schmidt form), and the filter keeps, beside the noise-only covariance P of its
state error, the error's sensitivity M_l (4x2) to each radar's bias:

    error = n - sum_l M_l b_l,  cov = P + sum_l M_l B_l M_l^T   (n, the b_l independent)

A plot z = H x + b_r + w of radar r (bias-corrected, w ~ N(0, R)) then has the innovation
covariance and state cross-covariance

    G_l = H M_l - [l = r] I
    S   = H P H^T + R + sum_l G_l B_l G_l^T,   X = P H^T + sum_l M_l B_l G_l^T

and the update K = X S^-1, x += K nu, P = Joseph(P, K, R), M_l -= K G_l, is the optimal
linear one for that error model. Prediction and IMM mixing are linear: M_l propagates and
mixes like the state. A track founded by radar r's local track starts with M_r = [I2; 0]
(the local track carries that bias whole); then G_r = 0 and the system track of an
aircraft only r sees follows r's plots exactly as r's local tracker does, while its
reported covariance still holds B_r. With several radars, S weighs each radar by its
plot noise and its bias uncertainty together, and the sensitivities fall as the radars
average their biases.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker_service.tracking import imm
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import FloatArray

POSITION = np.vstack([np.eye(2), np.zeros((2, 2))])
"""The sensitivity [I2; 0] of a track that carries a radar's bias whole (a local track)."""


@dataclass(frozen=True)
class ConsiderPrediction:
    """The IMM's prediction and each model's sensitivities M (k, models, radars, 4, 2),
    with their combination (k, radars, 4, 2)."""

    imm: imm.ImmPrediction
    M: FloatArray
    M_comb: FloatArray


def predict(
    x: FloatArray,
    P: FloatArray,
    M: FloatArray,
    mu: FloatArray,
    dt: FloatArray,
    models: ModelSet,
) -> ConsiderPrediction:
    """IMM mixing and prediction over dt (k,), sensitivities included."""
    c, w = imm.mixing(mu, dt, models)
    f, q = models.transitions(dt)
    pred = imm.mix_and_move(x, P, c, w, f, q)
    k, n, radars = M.shape[:3]
    # As matrix products (einsum loops over every index of such small stacks).
    mixed = (np.swapaxes(w, 1, 2) @ M.reshape(k, n, radars * 8)).reshape(M.shape)
    moved = f[:, :, None] @ mixed
    return ConsiderPrediction(imm=pred, M=moved, M_comb=combine(moved, c))


def combine(M: FloatArray, w: FloatArray) -> FloatArray:
    """The sensitivities (k, radars, 4, 2) of the mixture of models with weights w (k, M)."""
    k, n = w.shape
    return np.asarray((w[:, None, :] @ M.reshape(k, n, -1)).reshape(k, *M.shape[2:]))


def bias_share(M: FloatArray, B: FloatArray) -> FloatArray:
    """sum_l M_l B_l M_l^T (..., 4, 4): the residual biases' part of the state covariance,
    for sensitivities M (..., radars, 4, 2) and bias covariances B (..., radars, 2, 2)."""
    return np.asarray((M @ B @ np.swapaxes(M, -1, -2)).sum(axis=-3))


def update(
    pred: ConsiderPrediction, z: FloatArray, R: FloatArray, radar: int, B: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Each model's update with plots z (k, 2) of ``radar`` (noise R (k, 2, 2)), the radars'
    residual bias covariances B (k, radars, 2, 2) considered. Returns per-model states,
    noise covariances, sensitivities and the updated model probabilities."""
    xp, pp, mp = pred.imm.x, pred.imm.P, pred.M
    g = mp[..., :2, :].copy()
    g[:, :, radar] -= np.eye(2)
    bg = B[:, None] @ np.swapaxes(g, -1, -2)
    s = pp[..., :2, :2] + R[:, None] + (g @ bg).sum(axis=2)
    cross = pp[..., :, :2] + (mp @ bg).sum(axis=2)
    s_inv, det = imm.inv2(s)
    k_gain = cross @ s_inv
    y = z[:, None, :] - xp[..., :2]
    x_new = xp + np.einsum("kmab,kmb->kma", k_gain, y)
    p_new = imm.joseph(pp, k_gain, R[:, None])
    m_new = mp - k_gain[:, :, None] @ g
    return x_new, p_new, m_new, imm.model_probabilities(pred.imm.c, y, s_inv, det)
