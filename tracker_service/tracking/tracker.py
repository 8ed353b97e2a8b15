"""The per-radar local tracker: association, IMM update, initiation, confirmation, coasting
and deletion of every track of one radar, held in numpy arrays, one per field.

Per batch the work is vectorised over the batch's candidate track-plot pairs, the tracks
updated and the tracks aged; the only Python loops run over the IMM's models.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.resident_arrays import resident_zeros
from tracker_service.small_arrays import concatenate_rows, is_one_of
from tracker_service.tracking import imm, kernels, vertical
from tracker_service.tracking.association import (
    Gate,
    GatedPairs,
    MultipleHypothesisTracking,
    WeightedUpdate,
    make_associator,
    weighted_update,
)
from tracker_service.tracking.association.mht import Branch, branch_states
from tracker_service.tracking.clock import DataClock
from tracker_service.tracking.clutter import (
    make_clutter_map,
    primary_seed_takes_reply,
    secondary_reply,
)
from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.daps import DapUpdate
from tracker_service.tracking.initiate import (
    TwoPointInitiator,
    neighbour_state,
    two_point_state,
)
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    DAP_SELECTED_ALTITUDE,
    DAP_VERTICAL_RATE,
    BoolArray,
    FloatArray,
    IntArray,
    PlotArrays,
    as_plot_arrays,
)

TENTATIVE, CONFIRMED, COASTING, DELETED = 0, 1, 2, 3

CONFIRM_SPEED_SIGMAS = 2.0


def track_update_dtype(n_models: int) -> np.dtype[Any]:
    """One row of ``LocalTracker.process`` output."""
    return np.dtype(
        [
            ("track_number", np.int64),
            ("time", np.float64),
            ("x", np.float64),
            ("y", np.float64),
            ("vx", np.float64),
            ("vy", np.float64),
            ("P", np.float64, (16,)),
            ("flight_level", np.float64),
            ("climb_rate_fl_per_s", np.float64),
            ("status", np.int8),
            ("plot_id", np.int64),
            ("mode3a", np.int64),
            ("address", np.int64),
            ("model_probabilities", np.float64, (n_models,)),
        ]
    )


def _table_dtype(n_models: int) -> np.dtype[Any]:
    """The track table's fields; ``LocalTracker`` keeps one array per field."""
    return np.dtype(
        [
            ("number", np.int64),
            ("status", np.int8),
            ("x", np.float64, (n_models, 4)),
            ("P", np.float64, (n_models, 4, 4)),
            ("mu", np.float64, (n_models,)),
            ("xc", np.float64, (4,)),
            ("Pc", np.float64, (4, 4)),
            ("t", np.float64),  # time of the state
            ("t_hit", np.float64),  # latest plot time: the clock of misses
            ("misses", np.int64),
            ("hist", np.int64),  # one bit per scan, newest in bit 0: the M-of-N window
            ("address", np.int64),
            ("mode3a", np.int64),
            ("fl", np.float64),
            ("rate", np.float64),
            ("Pv", np.float64, (2, 2)),  # fl, rate, Pv: the vertical IMM's combination
            ("xv", np.float64, (vertical.N_VERTICAL_MODELS, 2)),
            ("Pvm", np.float64, (vertical.N_VERTICAL_MODELS, 2, 2)),
            ("muv", np.float64, (vertical.N_VERTICAL_MODELS,)),
            ("t_fl", np.float64),
            ("fl_ok", np.bool_),
            ("fl_rejects", np.int64),
            # Before this time no further scan can count as missed (see _age).
            ("due", np.float64),
            ("dense_seed", np.bool_),  # seeded in a dense clutter cell: more hits to confirm
            ("secondary", np.bool_),  # some plot of the track had a secondary reply
            ("clutter_cell", np.int64),  # the clutter map's cell of the latest plot
        ]
    )


DUE_MARGIN_S = 1e-3
"""Slack that keeps ``due`` earlier than the exact missed-scan test, whatever its rounding."""


@dataclass
class TrackerStats:
    """Running counts since the tracker started."""

    plots: int = 0
    invalid_plots: int = 0
    late_plots_dropped: int = 0
    plots_associated: int = 0
    tracks_initiated: int = 0
    tracks_confirmed: int = 0
    tracks_deleted: int = 0
    out_of_line_plots: int = 0
    """Plots refused by the clock (too far ahead of or behind it) and never tracked."""
    clock_resyncs: int = 0
    """Times the clock followed a sustained jump of the radar's time."""
    last_clock_jump_s: float = 0.0
    dap_velocity_updates: int = 0
    """Updates that took their plot's BDS 5,0 velocity (``tracking.daps``)."""
    dap_turn_evidence: int = 0
    dap_velocity_gated_out: int = 0
    """BDS 5,0 velocities too far from their track to be used."""


@dataclass(frozen=True)
class _BatchPlots:
    """What the compiled path works out once per batch about its plots (the numpy
    reference asks the clutter map again at each step, the same answers: the map
    learns only at the batch's end)."""

    reply: BoolArray
    """``clutter.secondary_reply`` of each plot."""
    cell: IntArray
    """The clutter map's cell of each plot (empty without a map)."""
    density: FloatArray
    """``LocalTracker._clutter_density`` at each plot (empty without a map)."""
    dense: BoolArray
    """Whether each plot lies in a dense cell (empty without a map)."""


class LocalTracker:
    """The tracks of one radar. Feed ``process`` one batch of plots (one data block, a
    sector) at a time, batches in time order; it returns the track updates of the batch."""

    def __init__(self, config: TrackerConfig | None = None, first_track_number: int = 1) -> None:
        self.config = config or TrackerConfig()
        self.models = ModelSet.from_config(self.config)
        self.imm = imm.make_imm(self.config.implementation, self.models)
        self._compiled = self.config.implementation == "compiled"
        self.stats = TrackerStats()
        self.daps = (
            DapUpdate(self.config, self.models, self.stats) if self.config.use_daps else None
        )
        self.initiator = TwoPointInitiator(self.config)
        self.output_dtype = track_update_dtype(self.models.n_models)
        self._table_dtype = _table_dtype(self.models.n_models)
        # One contiguous array per field, rows [0, _n) live: a sector touches a few rows
        # of a few fields, and gathering them from a structured array costs a strided
        # pass per field.
        self._cols: dict[str, npt.NDArray[Any]] = {}
        self._allocate(64)
        self._n = 0
        self._next_number = first_track_number
        jump = self.config.max_clock_jump_periods * self.config.scan_period_s
        self.clock = DataClock(
            jump, jump, self.config.clock_resync_batches, self.config.scan_period_s
        )
        self._held: list[PlotArrays] = []
        """The out-of-line plots of the current run of batches, counted when dropped."""
        self._now = -np.inf
        self.clutter = make_clutter_map(self.config)
        """The radar's clutter map (``tracking.clutter``), None when configured off."""
        extra = self.config.clutter_extra_hits if self.clutter is not None else 0
        self._hist_mask = (1 << (self.config.confirm_n + extra)) - 1
        self._window_mask = (1 << self.config.confirm_n) - 1
        self._dense_window_mask = self._hist_mask
        self.gate = Gate(
            self.config, self.models, self.imm, None if self.daps is None else self.daps.turn_prior
        )
        self.associator = make_associator(self.config)
        if self.clutter is not None and isinstance(self.associator, MultipleHypothesisTracking):
            self.associator.clutter_density = self._clutter_density
        self._scan_tolerance_s = (1.0 + self.config.miss_tolerance) * self.config.scan_period_s
        self._vertical_q = np.array(self.config.vertical_q, dtype=np.float64)
        self._vertical_sojourn = np.array(self.config.vertical_sojourn_s, dtype=np.float64)
        self._vertical_mu0 = np.array(self.config.vertical_initial_probabilities, dtype=np.float64)
        self._batch: _BatchPlots | None = None
        cfg = self.config
        self._record_constants = np.array(
            [
                0.5 * cfg.scan_period_s,
                self._scan_tolerance_s - DUE_MARGIN_S,
                float(cfg.use_daps),
                cfg.fl_step_mode_s,
                cfg.fl_step_mode_c,
                vertical.FPM_PER_FL_S,
                (cfg.baro_rate_sigma_fpm / vertical.FPM_PER_FL_S) ** 2,
                (cfg.inertial_rate_sigma_fpm / vertical.FPM_PER_FL_S) ** 2,
                cfg.fl_gate,
                cfg.initial_climb_variance,
                cfg.level_rate_variance,
            ]
        )
        """``kernels.record_pairs``' floats."""
        self._record_masks = np.array(
            [
                self._hist_mask,
                self._dense_window_mask,
                self._window_mask,
                vertical.MODE_S_TYP_MIN,
                DAP_VERTICAL_RATE,
                DAP_SELECTED_ALTITUDE,
                cfg.fl_max_rejects,
                cfg.confirm_m,
                cfg.clutter_extra_hits,
            ],
            dtype=np.int64,
        )
        """``kernels.record_pairs``' integers."""

    def _allocate(self, capacity: int) -> None:
        """(Re)allocate every field for ``capacity`` rows, keeping the live ones."""
        for name in self._table_dtype.names or ():
            field = self._table_dtype[name]
            grown = resident_zeros((capacity, *field.shape), field.base)
            if name in self._cols:
                grown[: self._n] = self._cols[name][: self._n]
            self._cols[name] = grown

    @property
    def _no_rows(self) -> npt.NDArray[Any]:
        return np.zeros(0, dtype=self.output_dtype)

    @property
    def tracks(self) -> npt.NDArray[Any]:
        """The live tracks' internal rows (a copy, as one structured array): for
        inspection and tests."""
        out = np.zeros(self._n, dtype=self._table_dtype)
        for name in self._table_dtype.names or ():
            out[name] = self._cols[name][: self._n]
        return out

    def process(self, plots: PlotArrays | npt.NDArray[Any]) -> npt.NDArray[Any]:
        p = as_plot_arrays(plots)
        self.stats.plots += len(p)
        r = p.R
        if self._compiled:
            valid = kernels.valid_plots(p.time, p.x, p.y, r)
        else:
            valid = (
                np.isfinite(p.time)
                & np.isfinite(p.x)
                & np.isfinite(p.y)
                & np.all(np.isfinite(r), axis=(1, 2))
                & (r[:, 0, 0] > 0)
                & (r[:, 0, 0] * r[:, 1, 1] - r[:, 0, 1] * r[:, 1, 0] > 0)
            )
        n_valid = int(np.count_nonzero(valid))
        self.stats.invalid_plots += len(p) - n_valid
        if n_valid < len(p):
            p = p.take(valid)
        if n_valid == 0:
            return self._no_rows
        step = self.clock.step(p.time)
        if step.resynchronised:
            return self._resynchronise(step.jump_s, p.take(step.accepted))
        if self._held and step.out_of_line != len(self._held) + 1:
            # The run ended: the held batches were no jump, only bad stamps.
            self.stats.out_of_line_plots += sum(len(h) for h in self._held)
            self._held = []
        if step.out_of_line:
            self._held.append(p.take(~step.accepted))
        if not step.accepted.all():
            if not step.out_of_line:
                self.stats.out_of_line_plots += int(np.count_nonzero(~step.accepted))
            p = p.take(step.accepted)
            if len(p) == 0:
                return self._no_rows
        return self._track(p)

    def _resynchronise(self, jump_s: float, p: PlotArrays) -> npt.NDArray[Any]:
        """The radar's time jumped for good (a restart with another clock, or data again
        after an outage): follow it. Back in time, every track (and every waiting plot)
        lies in the abandoned future and is deleted; forward, the tracks age as after
        any silence. The held batches are not tracked: every update of a batch must
        come from its own plots (the chain, the fuser and the outputs look them up)."""
        self.stats.clock_resyncs += 1
        self.stats.last_clock_jump_s = jump_s
        self.stats.out_of_line_plots += sum(len(h) for h in self._held)
        self._held = []
        parts = []
        if jump_s < 0:
            parts.append(self._delete_all())
            self.initiator.pending = PlotArrays.empty()
            self._now = -np.inf
        if len(p):
            parts.append(self._track(p))
        return _join(parts, self.output_dtype)

    def live_rows(self) -> npt.NDArray[Any]:
        """Every live track as an output row at its own latest time, without a plot: what
        a fuser that starts while this tracker runs needs to rebuild its picture."""
        n, cols = self._n, self._cols
        return self._rows(
            np.arange(n),
            cols["t"][:n].copy(),
            cols["status"][:n].copy(),
            np.full(n, -1, dtype=np.int64),
            cols["mu"][:n].copy(),
            cols["xc"][:n].copy(),
            cols["Pc"][:n].copy(),
        )

    def _delete_all(self) -> npt.NDArray[Any]:
        """Every live track deleted, at its own latest time."""
        n, cols = self._n, self._cols
        rows = np.arange(n)
        out = self._rows(
            rows,
            cols["t"][:n].copy(),
            np.full(n, DELETED, dtype=np.int8),
            np.full(n, -1, dtype=np.int64),
            cols["mu"][:n].copy(),
            cols["xc"][:n].copy(),
            cols["Pc"][:n].copy(),
        )
        self.stats.tracks_deleted += n
        self._n = 0
        return out

    def _track(self, p: PlotArrays) -> npt.NDArray[Any]:
        """Association, initiation and ageing of one batch the clock accepted."""
        now = max(self._now, float(p.time.max()))
        self._now = now
        n_old = self._n
        if self._compiled:
            self._batch = self._batch_plots(p)
        rows: list[npt.NDArray[Any]] = []

        used, blocked, updated = self._associate(p, rows)
        self._learn_clutter(p, rows)
        # A copy: the initiator keeps plots across batches, never the caller's array.
        first, second = self.initiator.pair(p.take(~used & ~blocked), now)
        if len(second):
            rows.append(self._create(first, second))
        self._age(now, updated, n_old, rows)
        return _join(rows, self.output_dtype)

    def _associate(
        self, p: PlotArrays, rows: list[npt.NDArray[Any]]
    ) -> tuple[BoolArray, BoolArray, BoolArray]:
        """Gate and assign the batch, update the assigned tracks.

        Returns the plots used, the plots kept from initiation (too late, or in a confirmed
        track's gate: a split or a second plot of a known target), and the tracks updated."""
        cols = self._cols
        n = self._n
        used = np.zeros(len(p), dtype=bool)
        blocked = np.zeros(len(p), dtype=bool)
        updated = np.zeros(n, dtype=bool)
        if n == 0:
            return used, blocked, updated
        gated = self.gate(cols, n, p)
        too_old = gated.too_old
        blocked |= too_old
        pairs = gated.pairs
        if pairs is not None:
            pairs = self._screen(pairs, p)
        if pairs is None:
            self.stats.late_plots_dropped += int(np.count_nonzero(too_old))
            return used, blocked, updated
        if isinstance(self.associator, MultipleHypothesisTracking):
            return self._associate_hypotheses(p, pairs, too_old, rows, used, blocked, updated)
        weighted = self.associator.associate(pairs)
        if weighted.is_hard and self._compiled:
            tracks, plot_index, late = kernels.hard_assignment(
                pairs.track, pairs.plot, weighted.pair, cols["status"], too_old, used, blocked,
                updated, CONFIRMED,
            )  # fmt: skip
            self.stats.late_plots_dropped += late
            if tracks.size:
                self.stats.plots_associated += int(tracks.size)
                rows.append(self._apply_pairs(tracks, p, plot_index, pairs.pred, weighted.pair))
            return used, blocked, updated
        if weighted.is_hard:
            # One plot per track (GNN): the plain IMM update.
            blocked[pairs.plot[cols["status"][pairs.track] == CONFIRMED]] = True
            sel = weighted.pair
            tracks, plot_index, posterior = pairs.track[sel], pairs.plot[sel], None
            used[plot_index] = True
        else:
            posterior = weighted_update(
                pairs, weighted, np.column_stack([p.x, p.y]), p.R, self.config.implementation
            )
            # Nor does a plot that a track's mixture takes in good part: left to the
            # initiator, it pairs with the next scan's left-over plot of the other
            # aircraft (the swaps of primary-only encounters, docs/association.md).
            shared = weighted.weight >= self.config.initiation_max_weight
            blocked[pairs.plot[weighted.pair[shared]]] = True
            sel = posterior.reported
            tracks, plot_index = posterior.track, pairs.plot[sel]
            # A plot goes to initiation unless it is a track's most likely plot: blocking
            # every plot in a confirmed track's gate (or every plot the tracks together
            # probably take) leaves a second aircraft 1 km away without a track of its
            # own, and the first track's mixture takes both for good.
            used[plot_index] = True
        if tracks.size == 0:
            self.stats.late_plots_dropped += int(np.count_nonzero(too_old & ~used))
            return used, blocked, updated
        updated[tracks] = True
        self.stats.late_plots_dropped += int(np.count_nonzero(too_old & ~used))
        self.stats.plots_associated += int(tracks.size)
        if posterior is None:
            rows.append(self._apply_pairs(tracks, p, plot_index, pairs.pred, sel))
        else:
            rows.append(self._apply(tracks, p.take(plot_index), pairs.pred.take(sel), posterior))
        return used, blocked, updated

    def _associate_hypotheses(
        self,
        p: PlotArrays,
        pairs: GatedPairs,
        too_old: BoolArray,
        rows: list[npt.NDArray[Any]],
        used: BoolArray,
        blocked: BoolArray,
        updated: BoolArray,
    ) -> tuple[BoolArray, BoolArray, BoolArray]:
        """MHT: GNN's assignment outside the ambiguous clusters, the best global
        hypothesis's leaves inside them; the tracks a later batch revised take their
        branch's state (published with their next update)."""
        assert isinstance(self.associator, MultipleHypothesisTracking)
        cols = self._cols
        decision = self.associator.decide(self.gate, self.imm, cols, self._n, p, pairs)
        gnn, hard = decision.gnn, decision.hard
        # As GNN: a plot in a confirmed track's gate starts no track; in a cluster, the
        # plots the best hypothesis leaves are clutter or new aircraft.
        blocked[pairs.plot[gnn][cols["status"][pairs.track[gnn]] == CONFIRMED]] = True
        if decision.revised_rows.size:
            self._revise(decision.revised_rows, decision.revised)
        tracks = np.concatenate([pairs.track[hard], decision.rows])
        plot_index = np.concatenate([pairs.plot[hard], decision.plots])
        used[plot_index] = True
        updated[tracks] = True
        self.stats.plots_associated += int(tracks.size)
        if hard.size:
            rows.append(self._apply_pairs(pairs.track[hard], p, pairs.plot[hard], pairs.pred, hard))
        if decision.rows.size:
            step = branch_states(decision.detected)
            rows.append(self._apply(decision.rows, p.take(decision.plots), None, step))
        self.stats.late_plots_dropped += int(np.count_nonzero(too_old & ~used))
        used |= self._start_next_to_tracks(p, pairs, ~used & ~blocked, rows)
        return used, blocked, updated

    def _revise(self, ti: IntArray, leaves: list[Branch]) -> None:
        """A revision: the tracks ``ti`` take the states of their branches in the new best
        hypothesis (the hit history and the vertical filter stay as published)."""
        cols = self._cols
        step = branch_states(leaves)
        cols["x"][ti], cols["P"][ti], cols["mu"][ti] = step.x, step.P, step.mu
        cols["xc"][ti], cols["Pc"][ti] = step.x_comb, step.P_comb
        cols["t"][ti] = [b.t for b in leaves]
        cols["address"][ti] = [b.address for b in leaves]
        cols["mode3a"][ti] = [b.mode3a for b in leaves]

    def _screen(self, pairs: GatedPairs, p: PlotArrays) -> GatedPairs | None:
        """The gated pairs an associator may weigh, with the clutter map's density at their
        plots: a tentative track seeded only by primary plots takes no plot with a
        secondary reply (``clutter.primary_seed_takes_reply``)."""
        cols = self._cols
        t, j = pairs.track, pairs.plot
        batch = self._batch
        if batch is not None:
            kept, density = kernels.screen_pairs(
                t, j, cols["status"], cols["secondary"], batch.reply, batch.density, TENTATIVE
            )
            if kept.size < t.size:
                if kept.size == 0:
                    return None
                pairs = pairs.take(kept)
            if self.clutter is None:
                return pairs
            return GatedPairs(
                pairs.track, pairs.plot, pairs.nis, pairs.log_det, pairs.identity_cost,
                pairs.pred, density,
            )  # fmt: skip
        reply = secondary_reply(p.typ[j], p.address[j], p.mode3a[j])
        refused = (cols["status"][t] == TENTATIVE) & primary_seed_takes_reply(
            cols["secondary"][t], reply
        )
        if refused.any():
            if refused.all():
                return None
            pairs = pairs.take(np.flatnonzero(~refused))
        if self.clutter is not None:
            density = self._clutter_density(p.take(pairs.plot))
            pairs = dataclasses.replace(pairs, clutter_density=density)
        return pairs

    def _batch_plots(self, p: PlotArrays) -> _BatchPlots:
        """The batch's ``_BatchPlots``."""
        if self.clutter is None:
            reply = secondary_reply(p.typ, p.address, p.mode3a)
            return _BatchPlots(reply, _NO_CELLS, _NO_FLOATS, _NO_FLAGS)
        return _BatchPlots(*self.clutter.describe(p.x, p.y, p.typ, p.address, p.mode3a))

    def _clutter_density(self, p: PlotArrays) -> FloatArray:
        """The clutter map's density (per m^2) at each plot, for JPDA's and MHT's
        likelihoods. Clutter has no secondary reply: against a plot with one, the density
        of others is the floor (new targets), whatever the cell (tma seed 2: an aircraft's
        plots weighed against a dense cell lost their track)."""
        assert self.clutter is not None
        density = self.clutter.density_per_m2(p.x, p.y)
        reply = secondary_reply(p.typ, p.address, p.mode3a)
        floor = self.config.clutter_density_per_km2 * 1e-6
        return np.asarray(np.where(reply, floor, density), dtype=np.float64)

    def _in_clutter(self, ti: IntArray, p: PlotArrays) -> BoolArray:
        """Which tracks ``ti`` got their plot ``p`` in a dense clutter cell, the cell of
        their previous plot too; every track's cell recorded. A primary-only track stuck
        there is held tentative: the plots of a persistent source keep a track alive
        whose first velocity, made of a plot near the site (ground range uncertain by
        kilometres) and the source, decays for minutes (tma: one lived 90 scans), while
        an aircraft crosses a 1 NM by 1 degree cell in a few scans."""
        if self.clutter is None:
            return np.zeros(ti.shape, dtype=bool)
        cell = self.clutter.cells(p.x, p.y)
        stuck = (cell == self._cols["clutter_cell"][ti]) & self.clutter.dense(p.x, p.y)
        self._cols["clutter_cell"][ti] = cell
        return np.asarray(stuck)

    def _learn_clutter(self, p: PlotArrays, rows: list[npt.NDArray[Any]]) -> None:
        """Teach the clutter map the batch's plots that no confirmed track took, and the
        primary-only plots: a clutter track confirmed before the map knew its cell
        (early in a run) would otherwise hide its source from the map for good, while
        a primary-only aircraft adds one plot to each cell it crosses."""
        if self.clutter is None:
            return
        batch = self._batch
        if batch is None:
            taken = [r["plot_id"][r["status"] == CONFIRMED] for r in rows]
            free = ~is_one_of(p.plot_id, np.concatenate(taken)) if taken else np.ones(len(p), bool)
            free |= ~secondary_reply(p.typ, p.address, p.mode3a)
            self.clutter.learn(p.x[free], p.y[free], p.time[free])
        else:
            joined = _join(rows, self.output_dtype)
            free = kernels.untaken_plots(
                p.plot_id, batch.reply, joined["plot_id"], joined["status"], CONFIRMED
            )
            self.clutter.learn_cells(batch.cell, p.time, free)

    def _apply_pairs(
        self,
        ti: IntArray,
        p: PlotArrays,
        plot_index: IntArray,
        pred: imm.ImmPrediction,
        sel: IntArray,
    ) -> npt.NDArray[Any]:
        """``_apply`` of the tracks ``ti`` each with one plot, ``p``'s ``plot_index``, from
        their pairs' predictions ``pred``'s ``sel``: in two compiled passes
        (``kernels.record_pairs``, ``finish_pairs``) around ``_confirm`` when the
        compiled path has them (no DAPs)."""
        batch = self._batch
        if batch is None or self.daps is not None:
            return self._apply(ti, p.take(plot_index), pred.take(sel))
        cols = self._cols
        mu, xc, pc, candidates = kernels.record_pairs(
            ti, plot_index, sel, pred.x, pred.P, pred.c, p.rows, batch.reply, cols["x"],
            cols["P"], cols["mu"], cols["xc"], cols["Pc"], cols["t"], cols["t_hit"],
            cols["hist"], cols["due"], cols["misses"], cols["address"], cols["mode3a"],
            cols["secondary"], cols["status"], cols["dense_seed"], cols["xv"], cols["Pvm"],
            cols["muv"], cols["fl"], cols["rate"], cols["Pv"], cols["t_fl"], cols["fl_ok"],
            cols["fl_rejects"], self._vertical_q, self._vertical_sojourn, self._vertical_mu0,
            self._record_constants, self._record_masks,
        )  # fmt: skip
        status = cols["status"][ti]
        if candidates:
            self._confirm(ti, status, cols["hist"][ti])
        out = np.zeros(ti.size, dtype=self.output_dtype)
        kernels.finish_pairs(
            ti, plot_index, status, mu, xc, pc, p.rows, batch.cell, batch.dense,
            self.clutter is not None, self.config.min_confirm_speed_psr_only_m_s,
            cols["number"], cols["address"], cols["mode3a"], cols["clutter_cell"],
            cols["status"], cols["fl"], cols["rate"], cols["t_fl"], cols["fl_ok"], out,
        )  # fmt: skip
        return out

    def _apply(
        self,
        ti: IntArray,
        p: PlotArrays,
        pred: imm.ImmPrediction | None,
        posterior: WeightedUpdate | imm.ImmUpdate | None = None,
    ) -> npt.NDArray[Any]:
        """Update the tracks ``ti`` with their plots ``p`` (or, weighted over several
        plots, to ``posterior``: ``p`` is then each track's most likely plot; or to an
        update already made, MHT's branches); their output rows."""
        cfg = self.config
        cols = self._cols
        time = p.time
        if posterior is None:
            assert pred is not None
            step = self.imm.update(pred, np.column_stack([p.x, p.y]), p.R)
        elif isinstance(posterior, imm.ImmUpdate):
            step = posterior
        else:
            combine = kernels.combine if self._compiled else imm.combine
            xc, pc = combine(posterior.x, posterior.P, posterior.mu)
            step = imm.ImmUpdate(posterior.x, posterior.P, posterior.mu, xc, pc)
        if self.daps is not None:
            step = self.daps.apply(step, p)
        x_new, p_new, mu_new, xc, pc = step.x, step.P, step.mu, step.x_comb, step.P_comb
        if self._compiled:
            kernels.record_updates(
                ti, time, p.address, p.mode3a, p.mode3a_valid, x_new, p_new, mu_new, xc, pc,
                cols["x"], cols["P"], cols["mu"], cols["xc"], cols["Pc"], cols["t"],
                cols["t_hit"], cols["hist"], cols["due"], cols["misses"], cols["address"],
                cols["mode3a"], 0.5 * cfg.scan_period_s, self._hist_mask,
                self._scan_tolerance_s - DUE_MARGIN_S,
            )  # fmt: skip
            hist, address, mode3a = cols["hist"][ti], cols["address"][ti], cols["mode3a"][ti]
        else:
            hist, address, mode3a = self._record_updates(ti, p, step)
        self._update_vertical(ti, p)
        cols["secondary"][ti] |= secondary_reply(p.typ, p.address, p.mode3a)
        status = cols["status"][ti]
        self._confirm(ti, status, hist)  # after every other field is written
        # A confirmed track without any secondary reply that has slowed to clutter speed
        # goes back to tentative: its first, noisy velocity may have passed the speed test.
        primary_only = (address < 0) & (mode3a < 0)
        stuck = self._in_clutter(ti, p)
        if primary_only.any():
            speed = np.hypot(xc[:, 2], xc[:, 3])
            slow = primary_only & ((speed < cfg.min_confirm_speed_psr_only_m_s) | stuck)
            status[slow & (status == CONFIRMED)] = TENTATIVE
        cols["status"][ti] = status
        return self._rows(ti, time, status, p.plot_id, mu_new, xc, pc)

    def _record_updates(
        self, ti: IntArray, p: PlotArrays, step: imm.ImmUpdate
    ) -> tuple[IntArray, IntArray, IntArray]:
        """The numpy reference of ``kernels.record_updates``: the IMM's new state, the
        hit history and the identity of the tracks ``ti`` written; their hist, address
        and Mode 3/A."""
        cfg = self.config
        cols = self._cols
        time = p.time
        cols["x"][ti] = step.x
        cols["P"][ti] = step.P
        cols["mu"][ti] = step.mu
        cols["xc"][ti] = step.x_comb
        cols["Pc"][ti] = step.P_comb
        cols["t"][ti] = time
        # A plot of the scan already counted (a late one) must not count a second hit.
        t_hit = cols["t_hit"][ti]
        hist = cols["hist"][ti]
        same_scan = time < t_hit + 0.5 * cfg.scan_period_s
        hist = np.where(same_scan, hist | 1, ((hist << 1) | 1) & self._hist_mask)
        cols["hist"][ti] = hist
        t_hit = np.maximum(t_hit, time)
        cols["t_hit"][ti] = t_hit
        cols["due"][ti] = t_hit + (self._scan_tolerance_s - DUE_MARGIN_S)
        cols["misses"][ti] = 0
        address = np.where(p.address >= 0, p.address, cols["address"][ti])
        cols["address"][ti] = address
        mode3a = np.where(p.mode3a_valid & (p.mode3a >= 0), p.mode3a, cols["mode3a"][ti])
        cols["mode3a"][ti] = mode3a
        return hist, address, mode3a

    def _update_vertical(self, ti: IntArray, p: PlotArrays) -> None:
        """Vertical IMM (``tracking.vertical``) of the tracks ``ti`` with their plots ``p``."""
        cfg = self.config
        cols = self._cols
        has = p.fl_valid & np.isfinite(p.flight_level)
        if not has.any():
            return  # a primary-only batch: no vertical work at all
        if not has.all():
            ti, p = ti[has], p.take(has)
        m = self._vertical_measurements(p)
        if self._compiled:
            kernels.vertical_update(
                ti, m.time, m.level, m.level_variance, m.rate, m.rate_variance,
                m.selected_level, cols["xv"], cols["Pvm"], cols["muv"], cols["fl"],
                cols["rate"], cols["Pv"], cols["t_fl"], cols["fl_ok"], cols["fl_rejects"],
                self._vertical_q, self._vertical_sojourn, self._vertical_mu0, cfg.fl_gate,
                cfg.fl_max_rejects, cfg.initial_climb_variance, cfg.level_rate_variance,
            )  # fmt: skip
            return
        old = vertical.VerticalState(cols["xv"][ti], cols["Pvm"][ti], cols["muv"][ti])
        t_fl = cols["t_fl"][ti]
        with np.errstate(over="ignore", invalid="ignore"):  # new rows: no state to predict
            pred = vertical.predict(old, m.time - t_fl, m.selected_level, cfg)
            xc, pc = vertical.combine(pred)
            y = m.level - xc[:, 0]
            ok = y * y / (pc[:, 0, 0] + m.level_variance) <= cfg.fl_gate
            updated, xu, pu = vertical.update(pred, m)
        started = ~cols["fl_ok"][ti]
        rejects = np.where(ok, 0, cols["fl_rejects"][ti] + 1)
        restart = started | (rejects >= cfg.fl_max_rejects)
        accepted = ok & ~started
        fresh = vertical.start(m, cfg)
        fresh_xc, fresh_pc = vertical.combine(fresh)
        # A rejected level (garbled Mode C) leaves the old state at its old time.
        for name, new, renewed in (
            ("xv", fresh.x, updated.x),
            ("Pvm", fresh.P, updated.P),
            ("muv", fresh.mu, updated.mu),
        ):
            shape = (-1,) + (1,) * (new.ndim - 1)
            cols[name][ti] = np.where(
                restart.reshape(shape),
                new,
                np.where(accepted.reshape(shape), renewed, cols[name][ti]),
            )
        cols["fl"][ti] = np.where(
            restart, fresh_xc[:, 0], np.where(accepted, xu[:, 0], cols["fl"][ti])
        )
        cols["rate"][ti] = np.where(
            restart, fresh_xc[:, 1], np.where(accepted, xu[:, 1], cols["rate"][ti])
        )
        cols["Pv"][ti] = np.where(
            restart[:, None, None],
            fresh_pc,
            np.where(accepted[:, None, None], pu, cols["Pv"][ti]),
        )
        renewed_rows = restart | accepted
        cols["t_fl"][ti] = np.where(renewed_rows, m.time, t_fl)
        cols["fl_rejects"][ti] = np.where(renewed_rows, 0, rejects)
        cols["fl_ok"][ti] = True

    def _vertical_measurements(self, p: PlotArrays) -> vertical.VerticalMeasurements:
        """The vertical measurements of plots with a valid level: the level, and the
        downlinked rates and selected altitude where the plot columns exist."""
        names = p.rows.dtype.names or ()
        if self._compiled and "selected_altitude_ft" in names:
            cfg = self.config
            rows = p.rows
            variance, rate, rate_variance, selected = kernels.vertical_measurements(
                p.flight_level, p.typ, rows["dap_flags"], rows["baro_rate_fpm"],
                rows["inertial_rate_fpm"], rows["selected_altitude_ft"], cfg.use_daps,
                vertical.MODE_S_TYP_MIN, cfg.fl_step_mode_s, cfg.fl_step_mode_c,
                vertical.FPM_PER_FL_S, (cfg.baro_rate_sigma_fpm / vertical.FPM_PER_FL_S) ** 2,
                (cfg.inertial_rate_sigma_fpm / vertical.FPM_PER_FL_S) ** 2, DAP_VERTICAL_RATE,
                DAP_SELECTED_ALTITUDE,
            )  # fmt: skip
            return vertical.VerticalMeasurements(
                p.time, p.flight_level, variance, rate, rate_variance, selected
            )
        level_variance = vertical.measurement_variance(p.flight_level, p.typ, self.config)
        if "selected_altitude_ft" not in names or not self.config.use_daps:
            # Plots without DAP columns: one NaN column stands for all three (read only).
            absent = np.full(len(p), np.nan)
            return vertical.VerticalMeasurements(
                p.time, p.flight_level, level_variance, absent, absent, absent
            )
        # Only what dap_flags vouches for: rows made with np.zeros hold 0 there.
        flags = p.rows["dap_flags"]
        has_rate = (flags & DAP_VERTICAL_RATE) != 0
        rate, rate_variance = vertical.rate_measurements(
            np.where(has_rate, p.rows["baro_rate_fpm"], np.nan),
            np.where(has_rate, p.rows["inertial_rate_fpm"], np.nan),
            self.config,
            len(p),
        )
        selected = np.where(
            (flags & DAP_SELECTED_ALTITUDE) != 0, p.rows["selected_altitude_ft"] / 100.0, np.nan
        )
        return vertical.VerticalMeasurements(
            p.time, p.flight_level, level_variance, rate, rate_variance, selected
        )

    def _confirm(self, ti: IntArray, status: npt.NDArray[Any], hist: IntArray) -> None:
        """M of N, except for a tentative track that echoes a confirmed track that is
        associating (a reflection or a split, since the original follows the
        kinematics; see ``_echoes``), for a slow track that never had a secondary reply
        (clutter), and for a track surely faster than ``max_speed_m_s``. ``ti``: the
        tracks to confirm, every field but ``status`` already written; ``status``: theirs
        (changed in place)."""
        cols = self._cols
        dense = cols["dense_seed"][ti]
        extra = self.config.clutter_extra_hits
        hits = np.bitwise_count(hist & np.where(dense, self._dense_window_mask, self._window_mask))
        candidates = np.flatnonzero(
            (status == TENTATIVE) & (hits >= self.config.confirm_m + np.where(dense, extra, 0))
        )
        if candidates.size == 0:
            return
        n = self._n
        live = np.flatnonzero(
            (cols["status"][:n] == CONFIRMED)
            & (cols["misses"][:n] == 0)
            & (cols["address"][:n] >= 0)
        )
        rows = ti[candidates]
        clash = self._echoes(rows, live)
        address = cols["address"][rows]
        primary_only = (address < 0) & (cols["mode3a"][rows] < 0)
        xc = cols["xc"][rows]
        speed = np.hypot(xc[:, 2], xc[:, 3])
        # The speed must be known to be above the threshold, not merely estimated
        # above it: a primary plot without Mode C near the radar has a height, hence a
        # ground range, uncertain by kilometres, and two clutter plots make a "fast"
        # track whose speed is mostly noise (tma: one lived 87 scans).
        direction = xc[:, 2:] / np.maximum(speed, 1e-9)[:, None]
        pv = cols["Pc"][rows][:, 2:, 2:]
        speed_sigma = np.sqrt(np.einsum("ni,nij,nj->n", direction, pv, direction))
        lowest = speed - CONFIRM_SPEED_SIGMAS * speed_sigma
        slow = primary_only & (lowest < self.config.min_confirm_speed_psr_only_m_s)
        if self.clutter is not None:
            # Nor a primary-only track in a dense clutter cell: a persistent source
            # repeats its plots there, evidence of nothing (``_in_clutter``).
            slow |= primary_only & self.clutter.dense(xc[:, 0], xc[:, 1])
        # Nor is a track confirmed that is surely faster than any aircraft.
        impossible = lowest > self.config.max_speed_m_s
        confirmed = candidates[~clash & ~slow & ~impossible]
        status[confirmed] = CONFIRMED
        self.stats.tracks_confirmed += int(confirmed.size)

    def _echoes(self, new: IntArray, live: IntArray) -> BoolArray:
        """Which ``new`` tracks look like an echo (a reflection or a split) of a ``live``
        confirmed track: the same address with nothing to tell them apart. An echo
        repeats its original's Mode 3/A and Mode C; a second aircraft with the same
        address (DOMAIN.md section 2) flies with its own code or at its own level."""
        cols = self._cols
        echo = np.zeros(len(new), dtype=bool)
        live_address = cols["address"][live]
        for k, row in enumerate(new.tolist()):
            if cols["address"][row] < 0:
                continue
            twins = live[live_address == cols["address"][row]]
            if len(twins) == 0:
                continue
            code, fl = cols["mode3a"][row], cols["fl"][row]
            twin_code = cols["mode3a"][twins]
            other_code = (code >= 0) & (twin_code >= 0) & (twin_code != code)
            twin_fl_ok = cols["fl_ok"][twins]
            other_level = (
                cols["fl_ok"][row]
                & twin_fl_ok
                & (np.abs(cols["fl"][twins] - fl) > self.config.echo_level_tolerance_fl)
            )
            echo[k] = bool(np.any(~other_code & ~other_level))
        return echo

    def _create(self, first: PlotArrays, second: PlotArrays) -> npt.NDArray[Any]:
        """Start tentative tracks from the initiator's pairs; their output rows."""
        cfg = self.config
        x, pm = two_point_state(
            first, second, float(self.models.q[0]), cfg.init_velocity_variance_scale
        )
        missed_between = second.time - first.time > 1.5 * cfg.scan_period_s
        hist = np.where(missed_between, 0b101, 0b11) & self._hist_mask
        return self._start(x, pm, hist, [first, second])

    def _start_next_to_tracks(
        self, p: PlotArrays, pairs: GatedPairs, free: BoolArray, rows: list[npt.NDArray[Any]]
    ) -> BoolArray:
        """MHT: each ``free`` plot of the batch in the gate of a confirmed or coasting track
        starts a tentative track at once with the velocity of its likeliest such
        neighbour (``initiate.neighbour_state``); which plots did. Left to the two-point
        initiator, a left-over plot of a close pair pairs with the other aircraft's next
        one, and its velocity is too uncertain for the new track's hypotheses to compete
        with the neighbour's."""
        cols = self._cols
        born = np.zeros(len(p), dtype=bool)
        near = free[pairs.plot] & (cols["status"][pairs.track] != TENTATIVE)
        idx = np.flatnonzero(near)
        if idx.size == 0:
            return born
        idx = idx[np.lexsort((pairs.cost[idx], pairs.plot[idx]))]
        plot_index, first = np.unique(pairs.plot[idx], return_index=True)
        likeliest = idx[first]
        pred = pairs.pred.take(likeliest)
        plots = p.take(plot_index)
        x, pm = neighbour_state(
            plots,
            pred.x_comb[:, 2:],
            pred.P_comb[:, 2:, 2:],
            self.config.birth_relative_speed_sigma_m_s,
        )
        hist = np.full(len(plots), 0b1, dtype=np.int64) & self._hist_mask
        rows.append(self._start(x, pm, hist, [plots]))
        born[plot_index] = True
        return born

    def _start(
        self, x: FloatArray, pm: FloatArray, hist: IntArray, plots: list[PlotArrays]
    ) -> npt.NDArray[Any]:
        """Start tentative tracks in state ``x``, ``pm`` at the last of their ``plots``
        (in time order, one entry per track in each: the identity, the vertical filter
        and the clutter cells come from them), with the hit history ``hist``; their
        output rows."""
        k = len(plots[-1])
        last = plots[-1]
        start = self._n
        if start + k > self._cols["t"].shape[0]:
            self._allocate(max(2 * self._cols["t"].shape[0], start + k))
        self._n = start + k
        new = np.arange(start, start + k)
        cols = self._cols
        # Every field is written: rows past the live ones hold deleted tracks.
        cols["number"][new] = np.arange(self._next_number, self._next_number + k)
        self._next_number += k
        cols["x"][new] = x[:, None, :]
        cols["P"][new] = pm[:, None, :, :]
        mu = np.broadcast_to(self.models.initial_probabilities, (k, self.models.n_models))
        cols["mu"][new] = mu
        cols["xc"][new] = x
        cols["Pc"][new] = pm
        cols["t"][new] = cols["t_hit"][new] = last.time
        cols["due"][new] = last.time + (self._scan_tolerance_s - DUE_MARGIN_S)
        cols["misses"][new] = 0
        cols["hist"][new] = hist
        # The latest known identity of the plots.
        address = np.full(k, -1, dtype=np.int64)
        mode3a = np.full(k, -1, dtype=np.int64)
        secondary = np.zeros(k, dtype=bool)
        dense = np.zeros(k, dtype=bool)
        for plot in plots:
            address = np.where(plot.address >= 0, plot.address, address)
            code = np.where(plot.mode3a_valid, plot.mode3a, -1)
            mode3a = np.where(code >= 0, code, mode3a)
            secondary |= secondary_reply(plot.typ, plot.address, plot.mode3a)
            if self.clutter is not None:
                dense |= self.clutter.dense(plot.x, plot.y)
        cols["address"][new] = address
        cols["mode3a"][new] = mode3a
        cols["fl"][new] = np.nan
        cols["rate"][new] = 0.0
        cols["Pv"][new] = 0.0
        cols["t_fl"][new] = 0.0
        cols["fl_ok"][new] = False
        cols["fl_rejects"][new] = 0
        cols["secondary"][new] = secondary
        cols["clutter_cell"][new] = (
            -1 if self.clutter is None else self.clutter.cells(last.x, last.y)
        )
        cols["dense_seed"][new] = dense
        for plot in plots:
            self._update_vertical(new, plot)
        self.stats.tracks_initiated += k
        status = np.full(k, TENTATIVE, dtype=np.int8)
        cols["status"][new] = status
        self._confirm(new, status, hist)
        cols["status"][new] = status
        return self._rows(new, last.time, status, last.plot_id, mu, x, pm)

    def _age(
        self, now: float, updated: BoolArray, n_old: int, rows: list[npt.NDArray[Any]]
    ) -> None:
        """Count missed scans of the tracks without a plot; coast or delete them. Their
        output rows, if any, are appended to ``rows``."""
        cfg = self.config
        cols = self._cols
        if n_old == 0:
            return
        if self._compiled:
            idle, n_miss = kernels.missed_scans(
                now, updated, cols["t_hit"], cols["misses"], cols["due"], n_old,
                cfg.scan_period_s, cfg.miss_tolerance,
            )  # fmt: skip
        else:
            if now < cols["due"][:n_old].min():
                return  # no track can have missed a scan yet: the usual sector
            idle = np.flatnonzero(~updated[:n_old])
            elapsed = now - cols["t_hit"][idle]
            n_miss = np.maximum(np.floor(elapsed / cfg.scan_period_s - cfg.miss_tolerance), 0)
            n_miss = n_miss.astype(np.int64)
            grow = n_miss > cols["misses"][idle]
            idle, n_miss = idle[grow], n_miss[grow]
        if idle.size == 0:
            return
        shift = np.minimum(n_miss - cols["misses"][idle], 32)
        cols["hist"][idle] = (cols["hist"][idle] << shift) & self._hist_mask
        cols["misses"][idle] = n_miss
        cols["due"][idle] = cols["t_hit"][idle] + (
            (n_miss + cfg.miss_tolerance + 1.0) * cfg.scan_period_s - DUE_MARGIN_S
        )
        dt = now - cols["t"][idle]
        pred = self.imm.predict(cols["x"][idle], cols["P"][idle], cols["mu"][idle], dt)
        status = cols["status"][idle]
        limit = np.where(status == CONFIRMED, cfg.delete_misses, cfg.tentative_delete_misses)
        position_var = pred.P_comb[:, 0, 0] + pred.P_comb[:, 1, 1]
        spread = position_var > cfg.max_position_variance_m2
        missed = n_miss >= limit
        if isinstance(self.associator, MultipleHypothesisTracking):
            # A track of a live cluster is not deleted for its spread: its hypotheses
            # (other histories, other plots) decide it, and deleting it would drop them.
            # Nor is a tentative one for the best hypothesis's misses while N-scan
            # pruning may still revise them: a young track's wide prediction loses one
            # scan's plot to a confirmed neighbour's hypothesis, and the scans after
            # tell them apart (`encounters` seed 13, three abreast on the 12 s radar:
            # deleted, its aircraft's plots went to the neighbours, which shifted over).
            clustered = np.isin(cols["number"][idle], self.associator.clustered_numbers)
            spread &= ~clustered
            revisable = n_miss < limit + cfg.mht_n_scan - 1
            missed &= ~(clustered & (status == TENTATIVE) & revisable)
        dead = missed | spread
        coasting = (status == CONFIRMED) & ~dead
        report = np.flatnonzero(dead | coasting)
        if report.size:
            k = report.size
            rows.append(
                self._rows(
                    idle[report],
                    np.full(k, now),
                    np.where(dead, DELETED, COASTING).astype(np.int8)[report],
                    np.full(k, -1, dtype=np.int64),
                    pred.c[report],
                    pred.x_comb[report],
                    pred.P_comb[report],
                )
            )
        if dead.any():
            keep = np.ones(self._n, dtype=bool)
            keep[idle[dead]] = False
            survivors = int(np.count_nonzero(keep))
            for column in cols.values():
                column[:survivors] = column[: self._n][keep]
            self._n = survivors
            self.stats.tracks_deleted += int(np.count_nonzero(dead))

    def _rows(
        self,
        ti: IntArray,
        time: FloatArray,
        status: npt.NDArray[Any],
        plot_id: IntArray,
        mu: FloatArray,
        xc: FloatArray,
        pc: FloatArray,
    ) -> npt.NDArray[Any]:
        """Output rows of the tracks ``ti`` with the combined state ``xc``, ``pc``."""
        cols = self._cols
        out = np.zeros(ti.shape[0], dtype=self.output_dtype)
        out["track_number"] = cols["number"][ti]
        out["time"] = time
        out["x"], out["y"], out["vx"], out["vy"] = xc.T
        out["P"] = pc.reshape(-1, 16)
        fl_ok = cols["fl_ok"][ti]
        rate = cols["rate"][ti]
        out["flight_level"] = np.where(
            fl_ok, cols["fl"][ti] + rate * (time - cols["t_fl"][ti]), np.nan
        )
        out["climb_rate_fl_per_s"] = np.where(fl_ok, rate, np.nan)
        out["status"] = status
        out["plot_id"] = plot_id
        out["mode3a"] = cols["mode3a"][ti]
        out["address"] = cols["address"][ti]
        out["model_probabilities"] = mu
        return out


_NO_CELLS = np.zeros(0, dtype=np.int64)
_NO_FLOATS = np.zeros(0, dtype=np.float64)
_NO_FLAGS = np.zeros(0, dtype=bool)


def _join(rows: list[npt.NDArray[Any]], dtype: np.dtype[Any]) -> npt.NDArray[Any]:
    """Output rows of several parts as one array."""
    # Concatenating structured arrays promotes their dtypes field by field: join only
    # when there are several parts (most batches have one), and as raw rows.
    if len(rows) == 1:
        return rows[0]
    if not rows:
        return np.zeros(0, dtype=dtype)
    return concatenate_rows(rows)
