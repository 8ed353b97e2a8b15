"""The "tracks" estimator (DOMAIN.md section 7, architecture B): a system track is the ML
fusion of its local tracks predicted to the output time (``ml.py``), each local track's
covariance plus its radar's residual bias; ``fuse_local_tracks`` also gives the bias
estimator its references."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.ml import ml_fuse, predict_cv, shared_prediction_noise
from tracker_service.fusion.state import FusionState
from tracker_service.tracking.models import cv_transition
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, PlotArrays


def fuse_local_tracks(
    state: FusionState, slots: IntArray, t: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """ML fusion at times t (k,) of the local tracks in ``slots`` (valid first);
    rows without any source get NaN."""
    cfg, loc = state.config, state.local.rows
    if state.compiled:
        from tracker_service.fusion.kernels import fuse_local_tracks as compiled

        return compiled(
            slots, t, loc["t"], loc["x"], loc["P"], loc["extra"], cfg.q, cfg.correlation
        )
    k = slots.shape[0]
    x = np.full((k, 4), np.nan)
    p = np.full((k, 4, 4), np.nan)
    counts = (slots >= 0).sum(axis=1)
    for n in np.unique(counts[counts > 0]):
        sel = np.flatnonzero(counts == n)
        rows = slots[sel, :n]
        dt = t[sel, None] - loc["t"][rows]
        f = cv_transition(dt.reshape(-1)).reshape(sel.size, n, 4, 4)
        states = np.einsum("knab,knb->kna", f, loc["x"][rows])
        own = f @ loc["P"][rows] @ np.swapaxes(f, -1, -2)
        noise = shared_prediction_noise(dt, np.ones(dt.shape), cfg.q)
        for i in range(n):
            noise[:, i, i, :2, :2] += loc["extra"][rows[:, i]]
        x[sel], p[sel] = ml_fuse(states, own, cfg.correlation, noise)
    return x, p


def cv_prediction(
    state: FusionState, numbers: IntArray, dt: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """System tracks' latest states (x, P, M) predicted over dt at constant velocity:
    states, covariances, bias sensitivities."""
    sys = state.sys
    xs, ps = predict_cv(sys["x"][numbers], sys["P"][numbers], dt, state.config.q)
    moved = np.einsum("kab,klbc->klac", cv_transition(dt), sys["M"][numbers])
    return xs, ps, moved


class TrackFusionEstimator:
    """The whole covariance in P (M = 0): a constant-velocity prediction for the gate."""

    founder_carries_bias = False
    coarse_from_models = False

    def gate_prediction(
        self, state: FusionState, numbers: IntArray, dt: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        return cv_prediction(state, numbers, dt)

    def absorb(
        self,
        state: FusionState,
        radar: int,
        rows: IntArray,
        u: npt.NDArray[Any],
        extra: FloatArray,
        has_plot: BoolArray,
        plots: PlotArrays,
        created: IntArray,
    ) -> None:
        """Nothing: the local tracks' latest states (in the local table) are fused at output."""

    def output(
        self,
        state: FusionState,
        numbers: IntArray,
        t: FloatArray,
        slots: IntArray,
        latest: npt.NDArray[Any],
    ) -> tuple[FloatArray, FloatArray]:
        sys = state.sys
        x, p = fuse_local_tracks(state, slots, t)
        sys["x"][numbers], sys["P"][numbers], sys["t"][numbers] = x, p, t
        return x, p
