"""What the bias estimator takes from the fuser: predictions of each plot's system track
at the plot's time that the plot has not updated (DOMAIN.md section 6, variant 3)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.arrays import compact_slots, positions
from tracker_service.fusion.estimator_tracks import fuse_local_tracks
from tracker_service.fusion.state import FusionState
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, PlotArrays


@dataclass(frozen=True)
class References:
    """Per update row with a plot whose local track feeds a system track: predictions of
    that system track at the plot's time, from the other radars' local tracks only
    (``others_*``, valid when one contributes within ``max_reference_age_s``) and from all
    its local tracks as they were before this batch (``all_*``, NaN unless asked for:
    ``references``' ``everyone``); positions (N, 2), their covariances (N, 2, 2), the
    velocity of the others' prediction (N, 2), and which radars contribute (N,
    n_radars)."""

    plot_id: IntArray
    system_number: IntArray
    time: FloatArray
    others_valid: BoolArray
    others_xy: FloatArray
    others_P: FloatArray
    others_v: FloatArray
    all_xy: FloatArray
    all_P: FloatArray
    radars_seen: BoolArray


Fused = tuple[BoolArray, FloatArray, FloatArray, FloatArray, FloatArray, BoolArray]
"""Whether the others give a prediction, the others' x and P, all's x and P, and the
radars with a recent local track (``References``' fields)."""


def references(
    state: FusionState,
    radar: int,
    updates: npt.NDArray[Any],
    p: PlotArrays,
    sources: int | None = None,
    everyone: bool = True,
) -> References:
    """See ``SystemTracker.references``; only the local tracks of sources below
    ``sources`` serve (None: all). ``everyone`` False: the others' predictions only (the
    prediction from all local tracks is a second fusion per row, which only the macro
    bias filter takes)."""
    with_plot = updates[updates["plot_id"] >= 0]
    rows = state.local.find(radar, with_plot, create=False)
    loc = state.local.rows
    numbers = np.where(rows >= 0, loc["system"][np.maximum(rows, 0)], 0)
    fed = numbers > 0
    with_plot, numbers = with_plot[fed], numbers[fed]
    at = positions(p.plot_id, with_plot["plot_id"])
    t = np.where(at >= 0, p.time[np.maximum(at, 0)], with_plot["time"])
    slots = state.local.slots(numbers, state.config.max_sources)
    chosen = _compiled if state.compiled else _reference
    others_valid, x_o, p_o, x_a, p_a, seen = chosen(state, radar, t, slots, sources, everyone)
    return References(
        plot_id=with_plot["plot_id"].astype(np.int64),
        system_number=numbers,
        time=t,
        others_valid=others_valid,
        others_xy=x_o[:, :2],
        others_P=p_o[:, :2, :2],
        others_v=x_o[:, 2:],
        all_xy=x_a[:, :2],
        all_P=p_a[:, :2, :2],
        radars_seen=seen,
    )


def _reference(
    state: FusionState,
    radar: int,
    t: FloatArray,
    slots: IntArray,
    sources: int | None,
    everyone: bool,
) -> Fused:
    """``references`` past the slots in numpy (the reference of ``_compiled``)."""
    loc = state.local.rows
    if sources is not None:
        slots = compact_slots(slots, loc["radar"][np.maximum(slots, 0)] < sources)
    s = np.maximum(slots, 0)
    recent = (slots >= 0) & (t[:, None] - loc["t_plot"][s] <= state.config.reference_age_s)
    others = recent & (loc["radar"][s] != radar)
    x_o, p_o = fuse_local_tracks(state, compact_slots(slots, others), t)
    if everyone:
        x_a, p_a = fuse_local_tracks(state, slots, t)
    else:
        x_a, p_a = np.full((t.size, 4), np.nan), np.full((t.size, 4, 4), np.nan)
    seen = np.zeros((t.size, state.n_radars), dtype=bool)
    r, c = np.nonzero(recent)
    seen[r, loc["radar"][s[r, c]]] = True
    return others.any(axis=1), x_o, p_o, x_a, p_a, seen


def _compiled(
    state: FusionState,
    radar: int,
    t: FloatArray,
    slots: IntArray,
    sources: int | None,
    everyone: bool,
) -> Fused:
    """``references`` past the slots by the compiled kernels: the sources chosen in one
    pass, both fusions of each row from one prediction of its sources (the others' alone
    without ``everyone``)."""
    from tracker_service.fusion.kernels import fuse_references, reference_sources

    loc, cfg = state.local.rows, state.config
    kept, others, seen = reference_sources(
        slots,
        t,
        loc["radar"],
        loc["t_plot"],
        radar,
        state.n_radars if sources is None else sources,
        cfg.reference_age_s,
        state.n_radars,
    )
    x_o, p_o, x_a, p_a = fuse_references(
        others,
        kept,
        t,
        loc["t"],
        loc["x"],
        loc["P"],
        loc["extra"],
        cfg.q,
        cfg.correlation,
        everyone,
    )
    return others[:, 0] >= 0, x_o, p_o, x_a, p_a, seen
