"""The "plots" estimator (DOMAIN.md section 7, architecture C, the default): each system
track is an IMM of its own, updated by every plot of its local tracks in time order, each
radar's residual bias a Schmidt "consider" term (``consider.py``); the local tracks then
serve only association and initiation."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import consider, nearby, plot_daps
from tracker_service.fusion.arrays import (
    is_member,
    kernel_indices,
    last_of_each,
    positions,
    rank_within,
)
from tracker_service.fusion.state import FusionState
from tracker_service.tracking import imm
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, PlotArrays


def predict(state: FusionState, numbers: IntArray, dt: FloatArray) -> consider.ConsiderPrediction:
    """The system tracks' IMMs predicted over dt (field by field: a whole row of the
    table holds every radar's sensitivities)."""
    sys = state.sys
    return consider.predict(
        sys["mx"][numbers],
        sys["mP"][numbers],
        sys["mM"][numbers],
        sys["mu"][numbers],
        dt,
        state.models,
    )


def combined_prediction(
    state: FusionState, numbers: IntArray, dt: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``predict``'s combined state, noise covariance and sensitivities (k, radars, 4, 2)."""
    if state.compiled:
        from tracker_service.fusion import kernels  # numba only when compiled

        sys, c = state.sys, state.model_constants
        return kernels.consider_predict(
            sys["mx"],
            sys["mP"],
            sys["mM"],
            sys["mu"],
            kernel_indices(numbers),
            np.ascontiguousarray(dt, dtype=np.float64),
            c.omega,
            c.q,
            c.sojourn,
        )
    pred = predict(state, numbers, dt)
    return pred.imm.x_comb, pred.imm.P_comb, pred.M_comb


class PlotFilterEstimator:
    founder_carries_bias = True
    coarse_from_models = True

    def gate_prediction(
        self, state: FusionState, numbers: IntArray, dt: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """By the IMM, which follows a turn the local track's IMM follows (a constant-
        velocity prediction cut aircraft that turned out of their system tracks)."""
        return combined_prediction(state, numbers, dt)

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
        """Update each system track's IMM with the batch's plots of its local tracks, in
        time order; a system track created by this batch already holds its founder's, and
        one its founder alone has fed follows it (``_follow_founder``). Compiled without
        DAPs: one call (``kernels.absorb_plots``), the rounds below in a row."""
        if state.compiled and state.daps is None:
            use, systems = _absorb_compiled(state, radar, rows, u, extra, has_plot, plots, created)
        else:
            use, systems, found, rank, unknown = _plotted_updates(
                state, rows, u, has_plot, plots, created
            )
            state.stats.unknown_plot_ids += unknown
            for r in range(int(rank.max(initial=-1)) + 1):
                now = rank == r
                _filter_round(state, radar, systems[now], plots.take(found[now]), extra[use[now]])
        if use.size == 0:
            return
        solo = state.sys["solo"][systems]
        _follow_founder(state, systems[solo], u[use[solo]])

    def output(
        self,
        state: FusionState,
        numbers: IntArray,
        t: FloatArray,
        slots: IntArray,
        latest: npt.NDArray[Any],
    ) -> tuple[FloatArray, FloatArray]:
        sys = state.sys
        if state.compiled:
            from tracker_service.fusion.kernels import plot_filter_output  # numba on use

            c = state.model_constants
            return plot_filter_output(
                sys["mx"],
                sys["mP"],
                sys["mM"],
                sys["mu"],
                sys["t"],
                sys["solo"],
                sys["B"],
                kernel_indices(numbers),
                np.ascontiguousarray(t, dtype=np.float64),
                latest,
                c.omega,
                c.q,
                c.sojourn,
            )
        x, p, m_comb = combined_prediction(state, numbers, t - sys["t"][numbers])
        x, p = x.copy(), p.copy()
        solo = sys["solo"][numbers]  # its founder's update (``_follow_founder``)
        v = latest[solo]
        x[solo] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
        p[solo] = v["P"].reshape(-1, 4, 4)
        p += consider.bias_share(m_comb, sys["B"][numbers])
        return x, p


def _absorb_compiled(
    state: FusionState,
    radar: int,
    rows: IntArray,
    u: npt.NDArray[Any],
    extra: FloatArray,
    has_plot: BoolArray,
    plots: PlotArrays,
    created: IntArray,
) -> tuple[IntArray, IntArray]:
    """``absorb``'s plotted updates and filter rounds in one kernel call
    (``kernels.absorb_plots``: ``_plotted_updates``, then each round's ``_filter_round``
    without DAPs, the same bits); returns the updates used and their system tracks."""
    from tracker_service.fusion.kernels import absorb_plots  # numba only when compiled

    sys, c = state.sys, state.model_constants
    # Contiguous float64 and int64 whatever the plots' layout: one compiled signature.
    use, systems, unknown, late = absorb_plots(
        kernel_indices(rows),
        state.local.rows["system"],
        has_plot,
        kernel_indices(created),
        kernel_indices(plots.plot_id),
        kernel_indices(u["plot_id"]),
        np.ascontiguousarray(plots.time, dtype=np.float64),
        np.ascontiguousarray(plots.x, dtype=np.float64),
        np.ascontiguousarray(plots.y, dtype=np.float64),
        np.ascontiguousarray(plots.R, dtype=np.float64),
        np.ascontiguousarray(extra, dtype=np.float64),
        radar,
        state.config.max_backward_s,
        sys["mx"],
        sys["mP"],
        sys["mM"],
        sys["mu"],
        sys["x"],
        sys["P"],
        sys["M"],
        sys["B"],
        sys["t"],
        sys["moments"],
        sys["sensitivity"],
        sys["largest_bias"],
        c.omega,
        c.q,
        c.sojourn,
    )
    state.stats.unknown_plot_ids += unknown
    state.stats.late_plots_skipped += late
    return use, systems


def _plotted_updates(
    state: FusionState,
    rows: IntArray,
    u: npt.NDArray[Any],
    has_plot: BoolArray,
    plots: PlotArrays,
    created: IntArray,
) -> tuple[IntArray, IntArray, IntArray, IntArray, int]:
    """The updates (of local rows ``rows``) whose plot a system track takes: with a plot
    among ``plots``, of a local track feeding a system track the batch did not create;
    their system tracks, their plots' rows, their rank among their system track's (the
    filter's round) and the number of plot ids not found. Compiled: one call
    (``kernels.plotted_updates``), where the numpy path below makes some fifteen."""
    loc_system = state.local.rows["system"]
    if state.compiled:
        from tracker_service.fusion.kernels import plotted_updates  # numba when compiled

        return plotted_updates(
            kernel_indices(rows),
            loc_system,
            has_plot,
            kernel_indices(created),
            kernel_indices(plots.plot_id),
            kernel_indices(u["plot_id"]),
        )
    systems = loc_system[rows]
    use = np.flatnonzero(has_plot & (systems > 0) & ~is_member(systems, created))
    found = positions(plots.plot_id, u["plot_id"][use])
    unknown = int(np.count_nonzero(found < 0))
    use, found = use[found >= 0], found[found >= 0]
    return use, systems[use], found, rank_within(systems[use]), unknown


def _follow_founder(state: FusionState, numbers: IntArray, u: npt.NDArray[Any]) -> None:
    """A system track that only its founding local track has fed is that track: the
    same plots through the same IMM, whose per-model states (which the system track's
    models, started from the combined state, take a few scans to regain: a
    measured transient of 9 m and 2 m/s RMS over the next two plots) only the local
    tracker holds. Its IMM runs all the same, so that it has settled when a second
    local track joins; its sensitivity stays that of its radar's bias whole
    (``consider.POSITION``), which its reported covariance adds."""
    if numbers.size == 0:
        return
    last = last_of_each(numbers)
    n, v = numbers[last], u[last]
    sys = state.sys
    sys["x"][n] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
    sys["P"][n] = v["P"].reshape(-1, 4, 4)


def _filter_round(
    state: FusionState, radar: int, numbers: IntArray, p: PlotArrays, extra: FloatArray
) -> None:
    sys = state.sys
    dt = p.time - sys["t"][numbers]
    late = dt < -state.config.max_backward_s
    state.stats.late_plots_skipped += int(np.count_nonzero(late))
    keep = ~late
    numbers, dt, extra = numbers[keep], dt[keep], extra[keep]
    p = p.select(keep)
    if numbers.size == 0:
        return
    sys["B"][numbers, radar] = extra
    z = np.column_stack([p.x, p.y])
    if state.compiled:
        from tracker_service.fusion.kernels import filter_round

        c = state.model_constants
        # Contiguous float64 and int64 whatever the plots' layout: one compiled signature.
        filter_round(
            sys["mx"],
            sys["mP"],
            sys["mM"],
            sys["mu"],
            sys["x"],
            sys["P"],
            sys["M"],
            sys["B"],
            sys["t"],
            kernel_indices(numbers),
            np.ascontiguousarray(p.time, dtype=np.float64),
            z.astype(np.float64, copy=False),
            np.ascontiguousarray(p.R, dtype=np.float64),
            radar,
            c.omega,
            c.q,
            c.sojourn,
        )
    else:
        pred = predict(state, numbers, dt)
        x, pm, mm, mu = consider.update(pred, z, p.R, radar, sys["B"][numbers])
        xc, pc = imm.combine(x, pm, mu)
        sys["mx"][numbers], sys["mP"][numbers], sys["mM"][numbers] = x, pm, mm
        sys["mu"][numbers] = mu
        sys["x"][numbers], sys["P"][numbers], sys["t"][numbers] = xc, pc, p.time
        sys["M"][numbers] = consider.combine(mm, mu)
    if state.daps is not None:
        plot_daps.apply(state, state.daps, numbers, p)
    nearby.refresh(sys, numbers, state.compiled)
