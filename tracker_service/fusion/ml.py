"""Maximum-likelihood fusion of correlated estimates, vectorised over system tracks.

Several estimates z_i of one state x (all components observed) with errors e_i: the ML
(best linear unbiased) estimate is x = (H^T S^-1 H)^-1 H^T S^-1 z with H the stacked
identities and S the joint covariance of the e_i; its covariance is (H^T S^-1 H)^-1. With
independent errors this is DOMAIN.md section 7's formula; for two correlated errors it is
the Bar-Shalom-Campo formula.

Local tracks of one aircraft are not independent: they share the aircraft's manoeuvres
(process noise). Their joint covariance is built in two parts, each positive semidefinite,
so S stays a covariance whatever the inputs:

- the sources' own estimation errors, with the cross-covariance approximated as
  P_ij = rho sqrt(P_i) sqrt(P_j) (symmetric square roots; rho = 0: independent, rho -> 1:
  the same error, so fusing gains nothing);
- an exactly known joint error (``noise``): the process noise of predicting each source
  from its own time to the common one, shared over the overlap of the prediction spans,
  and per-source residual-bias covariances (independent across radars).
"""

from __future__ import annotations

import numpy as np

from tracker_service.tracking.models import cv_transition, white_acceleration_q
from tracker_service.tracking.plots import FloatArray


def symmetric_sqrt(p: FloatArray) -> FloatArray:
    """The symmetric square root of stacked covariances (negative eigenvalues of rounding
    clipped to 0): independent of the axes' order, unlike a Cholesky factor."""
    w, v = np.linalg.eigh(p)
    root: FloatArray = (v * np.sqrt(np.maximum(w, 0.0))[..., None, :]) @ np.swapaxes(v, -1, -2)
    return root


def ml_fuse(
    states: FloatArray,
    covariances: FloatArray,
    correlation: float = 0.0,
    noise: FloatArray | None = None,
) -> tuple[FloatArray, FloatArray]:
    """Fuse n estimates per row: states (k, n, d), covariances (k, n, d, d) of the sources'
    own errors, ``correlation`` rho between them, ``noise`` (k, n, n, d, d) an exactly
    known joint error added on top (None: none). Returns x (k, d) and P (k, d, d)."""
    k, n, d = states.shape
    if n == 1 and noise is None:
        return states[:, 0].copy(), covariances[:, 0].copy()
    sigma = np.zeros((k, n, d, n, d))
    for i in range(n):
        sigma[:, i, :, i, :] = (1.0 - correlation) * covariances[:, i]
    if correlation > 0.0:
        g = symmetric_sqrt(covariances).reshape(k, n * d, d)
        sigma += correlation * (g @ np.swapaxes(g, -1, -2)).reshape(k, n, d, n, d)
    if noise is not None:
        sigma += np.swapaxes(noise, 2, 3)
    h = np.broadcast_to(np.tile(np.eye(d), (n, 1)), (k, n * d, d))
    a = np.linalg.solve(sigma.reshape(k, n * d, n * d), h)
    info = a.reshape(k, n, d, d).sum(axis=1)
    p = np.linalg.inv(info)
    p = 0.5 * (p + np.swapaxes(p, -1, -2))
    x = np.einsum("kab,kb->ka", p, np.einsum("kia,ki->ka", a, states.reshape(k, n * d)))
    return x, p


def predict_cv(
    x: FloatArray, p: FloatArray, dt: FloatArray, q: float
) -> tuple[FloatArray, FloatArray]:
    """CV prediction of states x (k, 4) and covariances p (k, 4, 4) over dt (k,), with the
    process noise included."""
    f = cv_transition(dt)
    return np.einsum("kab,kb->ka", f, x), f @ p @ np.swapaxes(f, -1, -2) + white_acceleration_q(
        dt, q
    )


def shared_prediction_noise(dt: FloatArray, valid: FloatArray, q: float) -> FloatArray:
    """Joint process noise (k, n, n, 4, 4) of predicting n sources per row over dt (k, n) to
    one common time: the white acceleration over the overlap of two spans is the same for
    both, Q(min(|dt_i|, |dt_j|)) when they go the same way, and spans of opposite signs do
    not overlap. ``valid`` (k, n) masks padding rows out."""
    k, n = dt.shape
    same_way = (np.sign(dt)[:, :, None] == np.sign(dt)[:, None, :]) & (
        valid[:, :, None] * valid[:, None, :] > 0
    )
    overlap = np.where(same_way, np.minimum(np.abs(dt)[:, :, None], np.abs(dt)[:, None, :]), 0.0)
    return white_acceleration_q(overlap.reshape(-1), q).reshape(k, n, n, 4, 4)
