"""The IMM update of a track from several weighted plots (the probabilistic update).

A track's posterior after a batch is the mixture, over its weighted plots j and the miss,
of the IMM posteriors given each: p(x, m | Z) = sum_j beta_j p(x, m | z_j) + beta_0
p(x, m | no plot). Reduced per model to its first two moments, each model's state is
updated with the weighted innovations and its covariance gains their spread; the model
probabilities are mu_m = sum_j beta_j mu_jm + beta_0 c_m. With one plot of weight 1 it is
the plain IMM update. Each pair is updated at its own plot's time; the plots a track
shares with another one are close together, so these times differ by the few
milliseconds the beam takes between them, and the track takes the time of its most
likely plot.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tracker_service.tracking import imm
from tracker_service.tracking.association import kernels
from tracker_service.tracking.association.base import WeightedPairs
from tracker_service.tracking.association.gate import GatedPairs
from tracker_service.tracking.plots import FloatArray, IntArray

MIN_DETECTION_WEIGHT = 0.5
"""A track whose gated plots together are less likely than a miss is not updated: it
counts the scan as missed (the weights the plots had are not spread on it)."""


@dataclass(frozen=True)
class WeightedUpdate:
    """The updated tracks, the pair of each one's most likely plot, and their per-model
    posterior states, covariances and model probabilities."""

    track: IntArray
    reported: IntArray
    x: FloatArray
    P: FloatArray
    mu: FloatArray


def weighted_update(
    pairs: GatedPairs,
    weighted: WeightedPairs,
    plot_xy: FloatArray,
    R: FloatArray,
    implementation: str = "compiled",
) -> WeightedUpdate:
    """The tracks' posteriors; ``implementation`` as ``TrackerConfig.implementation``:
    "compiled" (``kernels.weighted_update``) or "numpy" (the reference, here)."""
    track_of = pairs.track[weighted.pair]
    # By track, each track's most likely pair first.
    order = np.lexsort((-weighted.weight, track_of))
    if implementation == "compiled":
        reported, x, p, mu = kernels.weighted_update(
            np.ascontiguousarray(weighted.pair[order], dtype=np.int64),
            np.ascontiguousarray(weighted.weight[order], dtype=np.float64),
            np.ascontiguousarray(track_of[order], dtype=np.int64),
            np.ascontiguousarray(pairs.plot, dtype=np.int64),
            pairs.pred.x,
            pairs.pred.P,
            pairs.pred.c,
            np.ascontiguousarray(plot_xy, dtype=np.float64),
            np.ascontiguousarray(R, dtype=np.float64),
            MIN_DETECTION_WEIGHT,
        )
        return WeightedUpdate(pairs.track[reported], reported, x, p, mu)
    sel, w, owner_track = weighted.pair[order], weighted.weight[order], track_of[order]
    starts = np.flatnonzero(np.r_[True, owner_track[1:] != owner_track[:-1]])
    total = np.add.reduceat(w, starts)
    detected = total >= MIN_DETECTION_WEIGHT
    group = np.cumsum(np.r_[True, owner_track[1:] != owner_track[:-1]]) - 1
    keep = detected[group]
    sel, w = sel[keep], w[keep]
    new_group = np.cumsum(detected) - 1
    group = new_group[group[keep]]
    starts, total = starts[detected], total[detected]
    reported = weighted.pair[order][starts]
    n = reported.size

    plot = pairs.plot[sel]
    x_j, p_j, mu_j = imm.update(pairs.pred.take(sel), plot_xy[plot], R[plot])
    prior = pairs.pred.take(reported)
    miss = np.clip(1.0 - total, 0.0, 1.0)
    owner = np.r_[group, np.arange(n)]
    xs = np.concatenate([x_j, prior.x])
    ps = np.concatenate([p_j, prior.P])
    ws = np.concatenate([w[:, None] * mu_j, miss[:, None] * prior.c])
    n_models = xs.shape[1]
    mu = np.zeros((n, n_models))
    np.add.at(mu, owner, ws)
    safe = np.maximum(mu, imm.TINY)
    x = np.zeros((n, n_models, 4))
    np.add.at(x, owner, ws[..., None] * xs)
    x /= safe[..., None]
    d = xs - x[owner]
    spread = ps + d[..., :, None] * d[..., None, :]
    p = np.zeros((n, n_models, 4, 4))
    np.add.at(p, owner, ws[..., None, None] * spread)
    p /= safe[..., None, None]
    # Models whose every component underflowed keep the prediction of the best plot.
    empty = mu <= imm.TINY
    if empty.any():
        x = np.where(empty[..., None], prior.x, x)
        p = np.where(empty[..., None, None], prior.P, p)
    mu /= mu.sum(axis=1, keepdims=True)
    p = 0.5 * (p + np.swapaxes(p, -1, -2))
    return WeightedUpdate(pairs.track[reported], reported, x, p, mu)
