"""The gate: which (track, plot) pairs of a batch may be one target, with their likelihoods.

Stone Soup's hypothesiser: spatial pre-selection (``associate.candidate_pairs``), the IMM
prediction of each candidate pair to its plot's time, the chi-square test of the
normalised innovation, and the identity term (Mode S address, Mode 3/A code). Every
associator sees the same ``GatedPairs``; only what it makes of them differs.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.spatial import cKDTree

from tracker_service.tracking import imm
from tracker_service.tracking.associate import KDTREE_LEAF_SIZE, candidate_pairs
from tracker_service.tracking.association import gate_kernels
from tracker_service.tracking.config import SHARED_MODE3A_CODES, TrackerConfig
from tracker_service.tracking.identity import identity_cost
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    BoolArray,
    FloatArray,
    IntArray,
    PlotArrays,
)

TurnPrior = Callable[
    [imm.ImmPrediction, FloatArray, PlotArrays, IntArray], tuple[imm.ImmPrediction, FloatArray]
]

RADIUS_SAFETY = 1.2
RADIUS_MARGIN_M = 50.0
"""The pre-selection radius bounds the gate from the CV prediction of the combined state;
the IMM's mixture can be a little wider, hence the slack."""


@dataclass(frozen=True)
class GatedPairs:
    """The pairs that passed their gate: track rows, plot indices in the batch, the
    normalised innovation squared and log det S of the combined prediction, the identity
    cost (-2 log of the identity likelihood ratio: negative when the identities agree)
    and the IMM prediction of each pair's track to its plot's time."""

    track: IntArray
    plot: IntArray
    nis: FloatArray
    log_det: FloatArray
    identity_cost: FloatArray
    pred: imm.ImmPrediction
    clutter_density: FloatArray | None = None
    """The density (per m^2 and scan) of plots that are nobody's at each pair's plot, from
    the radar's clutter map (``tracking.clutter``); None: the configured constant."""

    def __len__(self) -> int:
        return int(self.track.size)

    def take(self, index: IntArray) -> GatedPairs:
        """The pairs ``index`` (indices or a mask)."""
        density = self.clutter_density
        return GatedPairs(
            track=self.track[index],
            plot=self.plot[index],
            nis=self.nis[index],
            log_det=self.log_det[index],
            identity_cost=self.identity_cost[index],
            pred=self.pred.take(index),
            clutter_density=None if density is None else density[index],
        )

    @property
    def cost(self) -> FloatArray:
        """-2 log of the pair's likelihood (kinematics times identity), up to a constant:
        what a nearest-neighbour assignment minimises."""
        return np.asarray(self.nis + self.log_det + self.identity_cost)

    @property
    def log_likelihood(self) -> FloatArray:
        """log of the Gaussian innovation density (per m^2) times the identity ratio."""
        return np.asarray(-0.5 * self.cost - imm.LOG_2PI)


@dataclass(frozen=True)
class GateResult:
    pairs: GatedPairs | None
    """None when no pair passed (the sparse sector: nothing predicted at all)."""
    too_old: BoolArray
    """Plots older than a candidate track's state by more than ``max_backward_s``."""


class Gate:
    """Builds the ``GatedPairs`` of a batch from the track table's columns."""

    def __init__(
        self,
        config: TrackerConfig,
        models: ModelSet,
        imm_filter: imm.ImmFilter,
        turn_prior: TurnPrior | None = None,
    ) -> None:
        self.config = config
        self.models = models
        self.imm = imm_filter
        self.turn_prior = turn_prior
        """The plots' reported turn rates weighing each pair's models and widening the
        gate (``tracking.daps.DapUpdate.turn_prior``), None without DAPs."""
        # Per-tracker constants of the pre-selection radius, hoisted out of every batch.
        self._q_max = float(models.q.max())
        self._turn_max = float(np.abs(models.turn_rates_rad_s).max())
        self._widest_gate = max(config.gate, config.address_gate)
        self._compiled = config.implementation == "compiled"
        self._tree_port = self._compiled and not _scipy_trees_only and tree_port_follows_scipy()
        """``gate_kernels``' own k-d tree build gives scipy's leaf orders here, else the
        compiled gate takes scipy's trees for every batch."""
        self._shared_codes = np.array(SHARED_MODE3A_CODES, dtype=np.int64)
        self._omega = np.ascontiguousarray(models.turn_rates_rad_s, dtype=np.float64)
        self._q = np.ascontiguousarray(models.q, dtype=np.float64)
        self._sojourn = np.ascontiguousarray(models.mean_sojourn_s, dtype=np.float64)
        self._constants = np.array(
            [
                self._q_max,
                self._turn_max,
                self._widest_gate,
                RADIUS_SAFETY,
                RADIUS_MARGIN_M,
                config.max_backward_s,
                config.gate,
                config.address_gate,
                config.address_mismatch_penalty,
                config.address_bonus,
                config.mode3a_bonus,
            ]
        )
        """``gate_kernels.gate_batch``'s floats."""

    def __call__(self, cols: dict[str, npt.NDArray[Any]], n: int, p: PlotArrays) -> GateResult:
        """The gated pairs of the batch ``p`` against the ``n`` live rows of ``cols``."""
        if self._compiled:
            return self._compiled_gate(cols, n, p)
        cfg = self.config
        too_old = np.zeros(len(p), dtype=bool)
        time = p.time
        plot_xy = np.column_stack([p.x, p.y])
        t_min, t_max = float(time.min()), float(time.max())
        t_mid = 0.5 * (t_min + t_max)
        # max |t - t_mid| over the batch: rounding keeps t - t_mid monotonic in t.
        spread = max(t_max - t_mid, t_mid - t_min)
        coarse_xy, radius = self._reach(cols, n, t_mid, spread)
        r = p.R
        plot_radius = np.sqrt(cfg.gate * (r[:, 0, 0] + r[:, 1, 1]))
        ti, pj = candidate_pairs(coarse_xy, radius, plot_xy, plot_radius)
        if ti.size == 0:
            # No track near the sector (common for sparse sectors): nothing to predict.
            return GateResult(None, too_old)
        dt = time[pj] - cols["t"][ti]
        late = dt < -cfg.max_backward_s
        if late.any():
            too_old[pj[late]] = True
            ti, pj, dt = ti[~late], pj[~late], dt[~late]
        if ti.size == 0:
            return GateResult(None, too_old)

        pred = self.imm.predict(cols["x"][ti], cols["P"][ti], cols["mu"][ti], dt)
        nis, log_det = self.imm.innovation_test(pred, plot_xy[pj], r[pj])
        gate_nis = nis
        if self.turn_prior is not None:
            pred, gate_nis = self.turn_prior(pred, nis, p, pj)
        addr_t, addr_p = cols["address"][ti], p.address[pj]
        same_address = (addr_t >= 0) & (addr_t == addr_p)
        gated = np.flatnonzero(gate_nis <= np.where(same_address, cfg.address_gate, cfg.gate))
        if gated.size == 0:
            return GateResult(None, too_old)
        tg, pg = ti[gated], pj[gated]
        pairs = GatedPairs(
            track=tg,
            plot=pg,
            nis=nis[gated],
            log_det=log_det[gated],
            identity_cost=self._identity_cost(cols, tg, p, pg),
            pred=pred.take(gated),
        )
        return GateResult(pairs, too_old)

    def _compiled_gate(
        self, cols: dict[str, npt.NDArray[Any]], n: int, p: PlotArrays
    ) -> GateResult:
        """``__call__`` by ``gate_kernels``: the same pairs, in the same order, with the
        same values."""
        too_old = np.zeros(len(p), dtype=bool)
        turn_prior = self.turn_prior
        ok = False
        if self._tree_port:
            ok, ti, pj, xp, pp, c, xc, pc, nis, log_det, cost = gate_kernels.gate_batch(
                p.time, p.x, p.y, p.R, p.address, p.mode3a, p.mode3a_valid, n, cols["t"],
                cols["xc"], cols["Pc"], cols["x"], cols["P"], cols["mu"], cols["address"],
                cols["mode3a"], self._omega, self._q, self._sojourn, self._constants,
                turn_prior is None, self._shared_codes, too_old,
            )  # fmt: skip
        if not ok:
            ti, pj, xp, pp, c, xc, pc, nis, log_det, cost = self._gate_with_scipy_trees(
                cols, n, p, too_old
            )
        if ti.size == 0:
            return GateResult(None, too_old)
        pred = imm.ImmPrediction(xp, pp, c, xc, pc)
        if turn_prior is not None:
            cfg = self.config
            pred, gate_nis = turn_prior(pred, nis, p, pj)
            same_address = (cols["address"][ti] >= 0) & (cols["address"][ti] == p.address[pj])
            gated = np.flatnonzero(gate_nis <= np.where(same_address, cfg.address_gate, cfg.gate))
            if gated.size == 0:
                return GateResult(None, too_old)
            ti, pj, nis, log_det, cost = (
                ti[gated],
                pj[gated],
                nis[gated],
                log_det[gated],
                cost[gated],
            )
            pred = pred.take(gated)
        pairs = GatedPairs(
            track=ti, plot=pj, nis=nis, log_det=log_det, identity_cost=cost, pred=pred
        )
        return GateResult(pairs, too_old)

    def _gate_with_scipy_trees(
        self, cols: dict[str, npt.NDArray[Any]], n: int, p: PlotArrays, too_old: BoolArray
    ) -> tuple[Any, ...]:
        """``gate_kernels.gate_batch``'s pairs with the trees' leaf orders from scipy
        itself, for the rare points where the compiled build cannot follow libstdc++'s
        ``nth_element`` (``gate_kernels._tree_paths``)."""
        cfg = self.config
        time, px, py, r = p.time, p.x, p.y, p.R
        t_min, t_max = float(time.min()), float(time.max())
        t_mid = 0.5 * (t_min + t_max)
        spread = max(t_max - t_mid, t_mid - t_min)
        dt = t_mid - cols["t"][:n]
        a = np.abs(dt) + spread
        plot_radius = np.sqrt(cfg.gate * (r[:, 0, 0] + r[:, 1, 1]))
        near, coarse_x, coarse_y, radius, reach = gate_kernels.preselect(
            cols["xc"], cols["Pc"], dt, a, a * a * a, spread, self._q_max, self._turn_max,
            self._widest_gate, RADIUS_SAFETY, RADIUS_MARGIN_M, px, py, plot_radius,
        )  # fmt: skip
        return gate_kernels.gate_pairs(
            near, coarse_x, coarse_y, radius, _leaf_order(coarse_x, coarse_y), px, py,
            plot_radius, _leaf_order(px, py), reach, time, r, p.address, p.mode3a,
            p.mode3a_valid, cols["t"], cols["x"], cols["P"], cols["mu"], cols["address"],
            cols["mode3a"], self._omega, self._q, self._sojourn, cfg.max_backward_s,
            cfg.gate, cfg.address_gate, self.turn_prior is None, self._shared_codes,
            cfg.address_mismatch_penalty, cfg.address_bonus, cfg.mode3a_bonus, False, too_old,
        )[1:]  # fmt: skip

    def _reach(
        self, cols: dict[str, npt.NDArray[Any]], n: int, t_mid: float, spread: float
    ) -> tuple[FloatArray, FloatArray]:
        """Coarse positions at the batch's middle time and a radius bounding every gate."""
        xc, pc = cols["xc"][:n], cols["Pc"][:n]
        dt = t_mid - cols["t"][:n]
        a = np.abs(dt) + spread
        var = (
            pc[:, 0, 0]
            + pc[:, 1, 1]
            + 2.0 * a * np.abs(pc[:, 0, 2] + pc[:, 1, 3])
            + a * a * (pc[:, 2, 2] + pc[:, 3, 3])
            + 2.0 * self._q_max * a**3 / 3.0
        )
        speed = np.hypot(xc[:, 2], xc[:, 3])
        turn = self._turn_max
        radius = (
            RADIUS_SAFETY * np.sqrt(self._widest_gate * var)
            + speed * spread
            + 0.5 * speed * turn * a * a
            + RADIUS_MARGIN_M
        )
        return xc[:, :2] + xc[:, 2:] * dt[:, None], radius

    def _identity_cost(
        self, cols: dict[str, npt.NDArray[Any]], ti: IntArray, p: PlotArrays, pj: IntArray
    ) -> FloatArray:
        """Identity shifts the cost among gated pairs only: it never opens a gate."""
        return identity_cost(
            cols["address"][ti],
            p.address[pj],
            cols["mode3a"][ti],
            p.mode3a[pj],
            self.config,
            code_usable=p.mode3a_valid[pj],
        )


_NO_TREE = np.zeros(0, dtype=np.int64)


_scipy_trees_only = False


@contextmanager
def scipy_trees_only() -> Iterator[None]:
    """Gates made meanwhile take scipy's trees for every batch, as where the compiled
    build does not follow scipy's (``tree_port_follows_scipy``): the warm-up's way to
    that path's kernels, which data here takes only at the rare points where libstdc++'s
    introselect gives up (``gate_kernels._nth_element``; two batches in 60 s of
    ``scale``), else compiled then, on live data."""
    global _scipy_trees_only
    _scipy_trees_only = True
    try:
        yield
    finally:
        _scipy_trees_only = False


@functools.cache
def tree_port_follows_scipy() -> bool:
    """Whether ``gate_kernels``' k-d tree build gives scipy's leaf order in this process:
    it follows libstdc++'s ``nth_element``, what scipy's Linux wheels are built with;
    with another C++ library the pair order (GNN's ties, JPDA's and MHT's sums) would
    differ from the numpy gate's without a word. Checked once, on points full of ties."""
    rng = np.random.default_rng(7)
    x = np.round(rng.normal(0.0, 4.0, 400))
    y = np.repeat(rng.normal(0.0, 1.0, 80), 5)[rng.permutation(400)]
    order, ok = gate_kernels.kdtree_indices(x, y)
    return ok and bool(np.array_equal(order, _leaf_order(x, y)))


def _leaf_order(x: FloatArray, y: FloatArray) -> IntArray:
    """The points' leaf order in scipy's k-d tree (its ``indices``), which
    ``gate_kernels.gate_pairs`` orders the pairs by; empty when they fit in one leaf (the
    tree keeps them in their order)."""
    if x.size <= KDTREE_LEAF_SIZE:
        return _NO_TREE
    indices: IntArray = cKDTree(np.column_stack([x, y]), leafsize=KDTREE_LEAF_SIZE).indices
    return indices
