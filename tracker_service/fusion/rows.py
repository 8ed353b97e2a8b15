"""The fuser's output rows (``SYSTEM_UPDATE_DTYPE``): one per system track a batch fed,
and the last row of each track that ends."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.arrays import first_where, is_member, kernel_indices, last_of_each
from tracker_service.fusion.estimator import SystemEstimator
from tracker_service.fusion.messages import COASTING, CONFIRMED, SYSTEM_UPDATE_DTYPE
from tracker_service.fusion.state import FusionState
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray


def emit(
    state: FusionState,
    estimator: SystemEstimator,
    radar: int,
    systems: IntArray,
    u: npt.NDArray[Any],
    has_plot: BoolArray,
) -> npt.NDArray[Any]:
    """One row per system track fed by the batch, at the batch's latest update of it."""
    if systems.size == 0:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    sys = state.sys
    last, numbers, t, fresh, plot_of, status = emit_index_of(state, systems, u, has_plot)
    slots = state.local.slots(numbers, state.config.max_sources)
    x, p = estimator.output(state, numbers, t, slots, u[last])
    out = system_rows(state, numbers, t, x, p, status, slots)
    out["fresh"] = fresh
    out["radar"] = radar
    out["plot_id"] = plot_of
    sys["address"][numbers] = out["address"]
    sys["mode3a"][numbers] = out["mode3a"]
    return out


def emit_index_of(
    state: FusionState, systems: IntArray, u: npt.NDArray[Any], has_plot: BoolArray
) -> tuple[IntArray, IntArray, FloatArray, BoolArray, IntArray, npt.NDArray[np.int8]]:
    """``emit``'s index of the batch's fed rows: each system track's last row (by
    number), its number, time, freshness (a row with a plot), latest plot and status;
    the fresh tracks' ``t_plot`` moved up. Compiled: one call (``kernels.emit_index``)
    where the numpy path below makes some fifteen."""
    if state.compiled:
        from tracker_service.fusion.kernels import emit_index  # numba only when compiled

        return emit_index(
            systems, has_plot, u["plot_id"], u["time"], state.sys["t_plot"], CONFIRMED, COASTING
        )
    last = last_of_each(systems)
    numbers, t = systems[last], u["time"][last]
    fresh = is_member(numbers, systems[has_plot])
    plot_of = np.full(numbers.size, -1, dtype=np.int64)
    with_plot = np.flatnonzero(has_plot)
    latest_plot = with_plot[last_of_each(systems[with_plot])]
    plot_of[np.searchsorted(numbers, systems[latest_plot])] = u["plot_id"][latest_plot]
    sys = state.sys
    sys["t_plot"][numbers[fresh]] = np.maximum(sys["t_plot"][numbers[fresh]], t[fresh])
    status = np.where(fresh, CONFIRMED, COASTING).astype(np.int8)
    return last, numbers, t, fresh, plot_of, status


def joined(parts: list[npt.NDArray[Any]]) -> npt.NDArray[Any]:
    """The rows of ``parts`` (``SYSTEM_UPDATE_DTYPE``, fresh arrays) one after another:
    the one part with rows as it is, several joined as bytes. ``np.concatenate`` promotes
    a structured dtype field by field in Python (about 75 us a call, three calls a batch)."""
    full = [p for p in parts if len(p)]
    if not full:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    if len(full) == 1:
        return full[0]
    raw = np.concatenate(
        [np.ascontiguousarray(p, dtype=SYSTEM_UPDATE_DTYPE).view(np.uint8) for p in full]
    )
    return raw.view(SYSTEM_UPDATE_DTYPE)


def system_rows(
    state: FusionState,
    numbers: IntArray,
    t: FloatArray,
    x: FloatArray,
    p: FloatArray,
    status: npt.NDArray[Any],
    slots: IntArray,
) -> npt.NDArray[Any]:
    """Rows of system tracks ``numbers`` at t with state x, covariance p, fed by the local
    rows ``slots``: their flight level and identity from those local tracks."""
    loc = state.local.rows
    out = np.zeros(numbers.size, dtype=SYSTEM_UPDATE_DTYPE)
    if state.compiled:
        from tracker_service.fusion.kernels import fill_system_rows  # numba only when compiled

        fill_system_rows(
            out,
            kernel_indices(numbers),
            np.ascontiguousarray(t, dtype=np.float64),
            np.ascontiguousarray(x, dtype=np.float64),
            np.ascontiguousarray(p, dtype=np.float64),
            status,
            slots,
            loc["radar"],
            loc["number"],
            loc["plot_id"],
            loc["fl"],
            loc["rate"],
            loc["t_fl"],
            loc["address"],
            loc["mode3a"],
            state.sys["address"],
            state.sys["mode3a"],
        )
        return out
    out["system_number"] = numbers
    out["time"] = t
    out["x"], out["y"], out["vx"], out["vy"] = x.T
    out["P"] = p.reshape(-1, 16)
    out["status"] = status
    out["plot_id"] = -1
    used = slots >= 0
    s = np.where(used, slots, 0)
    out["n_sources"] = used.sum(axis=1)
    out["local_radars"] = np.where(used, loc["radar"][s], -1)
    out["local_numbers"] = np.where(used, loc["number"][s], -1)
    out["local_plot_ids"] = np.where(used, loc["plot_id"][s], -1)
    fl = np.where(used, loc["fl"][s], np.nan)
    pick = first_where(np.isfinite(fl))
    rate = loc["rate"][s][np.arange(numbers.size), pick]
    t_fl = loc["t_fl"][s][np.arange(numbers.size), pick]
    out["flight_level"] = fl[np.arange(numbers.size), pick] + rate * (t - t_fl)
    out["climb_rate_fl_per_s"] = np.where(np.isfinite(out["flight_level"]), rate, np.nan)
    for name in ("address", "mode3a"):
        values = np.where(used, loc[name][s], -1)
        known = values[np.arange(numbers.size), first_where(values >= 0)]
        out[name] = np.where(known >= 0, known, state.sys[name][numbers])
    return out
