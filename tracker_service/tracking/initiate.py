"""Two-point initiation: a plot left over from an earlier scan and one of this scan whose
distance implies a plausible speed start a tentative track.

Plots that join nothing wait for the next scan; plots older than the pairing window are
forgotten.
"""

from __future__ import annotations

import numpy as np

from tracker_service.tracking import kernels
from tracker_service.tracking.associate import (
    KDTREE_LEAF_SIZE,
    global_nearest_neighbour,
    leaf_order,
    pairs_within,
)
from tracker_service.tracking.config import SHARED_MODE3A_CODES, TrackerConfig
from tracker_service.tracking.identity import identity_cost
from tracker_service.tracking.plots import FloatArray, IntArray, PlotArrays

NOISE_SIGMAS = 3.0
IDENTITY_SCALE = 0.1
"""The identity cost's weight against the kinematic cost of a pair (up to 1)."""
SHARED_CODES = np.array(SHARED_MODE3A_CODES, np.int64)


class TwoPointInitiator:
    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        self.pending = PlotArrays.empty()

    def pair(self, plots: PlotArrays, now: float) -> tuple[PlotArrays, PlotArrays]:
        """Pairs (earlier plot, later plot) that start tracks; the other plots wait."""
        cfg = self.config
        period = cfg.scan_period_s
        max_dt = cfg.init_max_dt_periods * period
        # Both ways: a plot stamped ahead of the clock (it was refused or re-synchronised
        # away) must not wait forever.
        age = now - self.pending.time
        pending = self.pending.select((age <= max_dt) & (age >= -max_dt))
        if len(pending) == 0 or len(plots) == 0:
            self.pending = PlotArrays.concat(pending, plots)
            return PlotArrays.empty(), PlotArrays.empty()
        if cfg.implementation == "compiled":
            first, second = self._compiled_pairs(pending, plots, max_dt)
        else:
            first, second = self._pairs(pending, plots, max_dt)
        keep_pending = np.ones(len(pending), dtype=bool)
        keep_pending[first] = False
        waiting = np.ones(len(plots), dtype=bool)
        waiting[second] = False
        self.pending = PlotArrays.concat(pending.select(keep_pending), plots.select(waiting))
        return pending.take(first), plots.take(second)

    def _compiled_pairs(
        self, pending: PlotArrays, plots: PlotArrays, max_dt: float
    ) -> tuple[IntArray, IntArray]:
        """``_pairs`` with its candidate pairs from one compiled pass
        (``kernels.initiation_pairs``), in (pending, plot) order: the same pairs are
        chosen; their order, which numbers the new tracks, is the k-d tree's that
        ``_pairs`` meets, looked up only when two or more are chosen."""
        cfg = self.config
        # Contiguous copies of the columns (views of the rows, strided unless one row
        # long): numba compiles a kernel for each layout it meets, and with both sides
        # free to be either it made four copies of this one, each a compilation at its
        # first meeting (on live data, after an installation: service/warm_up.py).
        c = np.ascontiguousarray
        i, j, cost, reach = kernels.initiation_pairs(
            c(pending.time), c(pending.x), c(pending.y), c(pending.R), c(pending.address),
            c(pending.mode3a), c(pending.mode3a_valid), c(plots.time), c(plots.x),
            c(plots.y), c(plots.R), c(plots.address), c(plots.mode3a), c(plots.mode3a_valid),
            cfg.max_speed_m_s, cfg.min_speed_m_s,
            cfg.init_min_dt_periods * cfg.scan_period_s, max_dt, NOISE_SIGMAS, SHARED_CODES,
            cfg.address_mismatch_penalty, cfg.address_bonus, cfg.mode3a_bonus, IDENTITY_SCALE,
        )  # fmt: skip
        chosen = global_nearest_neighbour(i, j, cost)
        first, second = i[chosen], j[chosen]
        if chosen.size < 2 or max(len(pending), len(plots)) <= KDTREE_LEAF_SIZE:
            return first, second  # both searches in (pending, plot) order
        pending_xy = np.column_stack([pending.x, pending.y])
        if len(plots) <= KDTREE_LEAF_SIZE:
            # pairs_within's order: by the waiting plots' leaves (each chosen once).
            order = np.argsort(leaf_order(pending_xy)[first], kind="stable")
            return first[order], second[order]
        found, partner, _ = pairs_within(pending_xy, np.column_stack([plots.x, plots.y]), reach)
        rank = np.argsort(found * len(plots) + partner, kind="stable")
        keys = (found * len(plots) + partner)[rank]
        at = np.searchsorted(keys, first * len(plots) + second)
        assert (keys[at] == first * len(plots) + second).all(), "the searches disagree"
        order = np.argsort(rank[at], kind="stable")
        return first[order], second[order]

    def _pairs(
        self, pending: PlotArrays, plots: PlotArrays, max_dt: float
    ) -> tuple[IntArray, IntArray]:
        """The pairs (index of the waiting plot, index of the new plot) that start tracks,
        in the order of the search's k-d tree."""
        cfg = self.config
        period = cfg.scan_period_s
        noise = (
            np.sqrt(np.trace(pending.R, axis1=1, axis2=2)).max()
            + np.sqrt(np.trace(plots.R, axis1=1, axis2=2)).max()
        )
        reach = cfg.max_speed_m_s * max_dt + NOISE_SIGMAS * noise
        i, j, dist = pairs_within(
            np.column_stack([pending.x, pending.y]), np.column_stack([plots.x, plots.y]), reach
        )
        dt = plots.time[j] - pending.time[i]
        sigma = np.sqrt(
            np.trace(pending.R[i], axis1=1, axis2=2) + np.trace(plots.R[j], axis1=1, axis2=2)
        )
        ok = (
            (dt >= cfg.init_min_dt_periods * period)
            & (dt <= max_dt)
            & (dist <= cfg.max_speed_m_s * dt + NOISE_SIGMAS * sigma)
            & (dist >= cfg.min_speed_m_s * dt - NOISE_SIGMAS * sigma)
        )
        i, j, dist, dt = i[ok], j[ok], dist[ok], dt[ok]
        cost = dist / (cfg.max_speed_m_s * dt) + _identity_cost(pending, i, plots, j, cfg)
        chosen = global_nearest_neighbour(i, j, cost)
        return i[chosen], j[chosen]


def _identity_cost(
    a: PlotArrays,
    i: IntArray,
    b: PlotArrays,
    j: IntArray,
    cfg: TrackerConfig,
) -> FloatArray:
    """Scaled to the kinematic cost of up to 1."""
    usable = a.mode3a_valid[i] & b.mode3a_valid[j]
    return IDENTITY_SCALE * identity_cost(
        a.address[i], b.address[j], a.mode3a[i], b.mode3a[j], cfg, usable
    )


def two_point_state(
    first: PlotArrays, second: PlotArrays, q: float, velocity_scale: float
) -> tuple[FloatArray, FloatArray]:
    """State at the later plot and its covariance from the two plots' covariances.

    v = (z2 - z1) / dt, so cov(p, v) = R2 / dt and cov(v) = (R1 + R2) / dt^2; the process
    noise between the plots adds q dt / 3 (the velocity error of a straight-line fit); the
    velocity block is then scaled by ``velocity_scale``."""
    dt = second.time - first.time
    x = np.column_stack([second.x, second.y, (second.x - first.x) / dt, (second.y - first.y) / dt])
    r1, r2 = first.R, second.R
    p = np.zeros((dt.shape[0], 4, 4))
    p[:, :2, :2] = r2
    p[:, :2, 2:] = r2 / dt[:, None, None]
    p[:, 2:, :2] = r2 / dt[:, None, None]
    p[:, 2:, 2:] = velocity_scale * (
        (r1 + r2) / (dt * dt)[:, None, None] + (q * dt / 3.0)[:, None, None] * np.eye(2)
    )
    return x, p


def neighbour_state(
    plots: PlotArrays, velocity: FloatArray, velocity_cov: FloatArray, relative_sigma: float
) -> tuple[FloatArray, FloatArray]:
    """State at a plot born next to a live track, and its covariance: the position is the
    plot's (covariance R), the velocity the neighbour's (``velocity``, ``velocity_cov``:
    its prediction to the plot's time), widened by ``relative_sigma`` (m/s) per axis for
    the new aircraft's speed relative to it.

    Aircraft that share a gate fly nearly alike (a parallel pair, a formation, a slow
    crossing); a two-point start would pair the plot with a left-over plot of either
    aircraft and carry a velocity variance of 2 R / dt^2 scaled up, so its gate and its
    likelihoods could not compete with the neighbour's in the MHT's hypotheses."""
    k = len(plots)
    x = np.column_stack([plots.x, plots.y, velocity[:, 0], velocity[:, 1]])
    p = np.zeros((k, 4, 4))
    p[:, :2, :2] = plots.R
    p[:, 2:, 2:] = velocity_cov + relative_sigma**2 * np.eye(2)
    return x, p
