"""The per-radar local tracker: association, IMM update, initiation, confirmation, coasting
and deletion of every track of one radar, held in one structured numpy array.

Per batch the work is vectorised over the batch's candidate track-plot pairs, the tracks
updated and the tracks aged; the only Python loops run over the IMM's models.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.tracking import imm, vertical
from tracker_service.tracking.associate import candidate_pairs, global_nearest_neighbour
from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.initiate import TwoPointInitiator, two_point_state
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    BoolArray,
    FloatArray,
    IntArray,
    PlotArrays,
    as_plot_arrays,
    is_shared_code,
)

TENTATIVE, CONFIRMED, COASTING, DELETED = 0, 1, 2, 3

RADIUS_SAFETY = 1.2
RADIUS_MARGIN_M = 50.0
"""The pre-selection radius bounds the gate from the CV prediction of the combined state;
the IMM's mixture can be a little wider, hence the slack."""


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
            ("Pv", np.float64, (2, 2)),
            ("t_fl", np.float64),
            ("fl_ok", np.bool_),
            ("fl_rejects", np.int64),
        ]
    )


def as_bytes(rows: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """A structured array's rows as opaque fixed-size bytes (a view). numpy copies these
    whole rows at once, where a structured copy goes field by field: several times
    slower on the few rows of a sector. ``.view(dtype)`` turns the copy back."""
    return rows.view(np.dtype((np.void, rows.dtype.itemsize)))


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


class LocalTracker:
    """The tracks of one radar. Feed ``process`` one batch of plots (one data block, a
    sector) at a time, batches in time order; it returns the track updates of the batch."""

    def __init__(self, config: TrackerConfig | None = None, first_track_number: int = 1) -> None:
        self.config = config or TrackerConfig()
        self.models = ModelSet.from_config(self.config)
        self.stats = TrackerStats()
        self.initiator = TwoPointInitiator(self.config)
        self.output_dtype = track_update_dtype(self.models.n_models)
        self._tab: npt.NDArray[Any] = np.zeros(64, dtype=_table_dtype(self.models.n_models))
        self._n = 0
        self._next_number = first_track_number
        self._now = -np.inf
        self._hist_mask = (1 << self.config.confirm_n) - 1
        # Per-tracker constants of the pre-selection radius, hoisted out of every batch.
        self._q_max = float(self.models.q.max())
        self._turn_max = float(np.abs(self.models.turn_rates_rad_s).max())
        self._widest_gate = max(self.config.gate, self.config.address_gate)

    @property
    def _no_rows(self) -> npt.NDArray[Any]:
        return np.zeros(0, dtype=self.output_dtype)

    @property
    def tracks(self) -> npt.NDArray[Any]:
        """The live tracks' internal rows (a copy): for inspection and tests."""
        return self._tab[: self._n].copy()

    def process(self, plots: PlotArrays | npt.NDArray[Any]) -> npt.NDArray[Any]:
        p = as_plot_arrays(plots)
        self.stats.plots += len(p)
        valid = (
            np.isfinite(p.time)
            & np.isfinite(p.x)
            & np.isfinite(p.y)
            & np.all(np.isfinite(p.R), axis=(1, 2))
            & (p.R[:, 0, 0] > 0)
            & (p.R[:, 0, 0] * p.R[:, 1, 1] - p.R[:, 0, 1] * p.R[:, 1, 0] > 0)
        )
        n_valid = int(np.count_nonzero(valid))
        self.stats.invalid_plots += len(p) - n_valid
        if n_valid < len(p):
            p = p.take(valid)  # not select: the count is known already
        if n_valid == 0:
            return self._no_rows
        now = max(self._now, float(p.time.max()))
        self._now = now
        n_old = self._n
        rows: list[npt.NDArray[Any]] = []

        used, blocked, updated = self._associate(p, rows)
        unused = ~used & ~blocked
        # The initiator keeps plots across batches: never the caller's own arrays.
        first, second = self.initiator.pair(p.take(unused) if p is plots else p.select(unused), now)
        rows.append(self._create(first, second))
        rows.append(self._age(now, updated, n_old))
        # Concatenating structured arrays promotes their dtypes field by field: join only
        # the non-empty parts (most batches have one), and as raw rows (see as_bytes).
        rows = [r for r in rows if r.size]
        if len(rows) == 1:
            return rows[0]
        if not rows:
            return self._no_rows
        return np.concatenate([as_bytes(r) for r in rows]).view(self.output_dtype)

    def _associate(
        self, p: PlotArrays, rows: list[npt.NDArray[Any]]
    ) -> tuple[BoolArray, BoolArray, BoolArray]:
        """Gate and assign the batch, update the assigned tracks.

        Returns the plots used, the plots kept from initiation (too late, or in a confirmed
        track's gate: a split or a second plot of a known target), and the tracks updated."""
        cfg = self.config
        n = self._n
        tab = self._tab[:n]
        used = np.zeros(len(p), dtype=bool)
        blocked = np.zeros(len(p), dtype=bool)
        updated = np.zeros(n, dtype=bool)
        plot_xy = np.column_stack([p.x, p.y])
        t_mid = 0.5 * float(p.time.min() + p.time.max())
        spread = float(np.max(np.abs(p.time - t_mid)))
        coarse_xy, radius = self._reach(tab, t_mid, spread)
        plot_radius = np.sqrt(cfg.gate * (p.R[:, 0, 0] + p.R[:, 1, 1]))
        ti, pj = candidate_pairs(coarse_xy, radius, plot_xy, plot_radius)
        if ti.size == 0:
            # No track near the sector (common for sparse sectors): nothing to predict.
            return used, blocked, updated
        dt = p.time[pj] - tab["t"][ti]
        late = dt < -cfg.max_backward_s
        too_old = np.zeros(len(p), dtype=bool)
        if late.any():
            too_old[pj[late]] = True
            blocked |= too_old
            ti, pj, dt = ti[~late], pj[~late], dt[~late]
        if ti.size == 0:
            self.stats.late_plots_dropped += int(np.count_nonzero(too_old))
            return used, blocked, updated

        pred = imm.predict(tab["x"][ti], tab["P"][ti], tab["mu"][ti], dt, self.models)
        z, r = plot_xy[pj], p.R[pj]
        nis, log_det = imm.innovation_test(pred, z, r)
        addr_t, addr_p = tab["address"][ti], p.address[pj]
        same_address = (addr_t >= 0) & (addr_t == addr_p)
        gated = np.flatnonzero(nis <= np.where(same_address, cfg.address_gate, cfg.gate))
        if gated.size == 0:
            # Skip the assignment and the IMM update: no pair passed its gate.
            self.stats.late_plots_dropped += int(np.count_nonzero(too_old))
            return used, blocked, updated
        blocked[pj[gated[tab["status"][ti[gated]] == CONFIRMED]]] = True
        cost = nis[gated] + log_det[gated] + self._identity_cost(tab, ti[gated], p, pj[gated])
        sel = gated[global_nearest_neighbour(ti[gated], pj[gated], cost)]
        tracks, plot_index = ti[sel], pj[sel]
        used[plot_index] = True
        updated[tracks] = True
        self.stats.late_plots_dropped += int(np.count_nonzero(too_old & ~used))
        self.stats.plots_associated += int(tracks.size)
        rows.append(self._apply(tab, tracks, p.take(plot_index), pred.take(sel)))
        return used, blocked, updated

    def _reach(
        self, tab: npt.NDArray[Any], t_mid: float, spread: float
    ) -> tuple[FloatArray, FloatArray]:
        """Coarse positions at the batch's middle time and a radius bounding every gate."""
        xc, pc = tab["xc"], tab["Pc"]
        dt = t_mid - tab["t"]
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
        self, tab: npt.NDArray[Any], ti: IntArray, p: PlotArrays, pj: IntArray
    ) -> FloatArray:
        """Identity shifts the cost among gated pairs only: it never opens a gate."""
        cfg = self.config
        addr_t, addr_p = tab["address"][ti], p.address[pj]
        both = (addr_t >= 0) & (addr_p >= 0)
        code_t, code_p = tab["mode3a"][ti], p.mode3a[pj]
        code_match = (
            p.mode3a_valid[pj] & (code_t >= 0) & (code_t == code_p) & ~is_shared_code(code_p)
        )
        return np.asarray(
            cfg.address_mismatch_penalty * (both & (addr_t != addr_p))
            - cfg.address_bonus * (both & (addr_t == addr_p))
            - cfg.mode3a_bonus * code_match,
            dtype=np.float64,
        )

    def _apply(
        self,
        tab: npt.NDArray[Any],
        ti: IntArray,
        p: PlotArrays,
        pred: imm.ImmPrediction,
    ) -> npt.NDArray[Any]:
        cfg = self.config
        z = np.column_stack([p.x, p.y])
        x_new, p_new, mu_new = imm.update(pred, z, p.R)
        xc, pc = imm.combine(x_new, p_new, mu_new)
        # One gather of the assigned rows, updated field by field, and one scatter back:
        # indexing each field at ti would cost a gather and a scatter per field.
        r = as_bytes(tab)[ti].view(tab.dtype)
        r["x"] = x_new
        r["P"] = p_new
        r["mu"] = mu_new
        r["xc"] = xc
        r["Pc"] = pc
        r["t"] = p.time
        # A plot of the scan already counted (a late one) must not count a second hit.
        same_scan = p.time < r["t_hit"] + 0.5 * cfg.scan_period_s
        hist = r["hist"]
        r["hist"] = np.where(same_scan, hist | 1, ((hist << 1) | 1) & self._hist_mask)
        r["t_hit"] = np.maximum(r["t_hit"], p.time)
        r["misses"] = 0
        r["address"] = np.where(p.address >= 0, p.address, r["address"])
        r["mode3a"] = np.where(p.mode3a_valid & (p.mode3a >= 0), p.mode3a, r["mode3a"])
        self._update_vertical(r, p)
        as_bytes(tab)[ti] = as_bytes(r)  # before _confirm, which looks at every live track
        self._confirm(tab, r)
        self._demote_slow_primary(r)
        tab["status"][ti] = r["status"]
        return self._rows(r, p.time, r["status"], p.plot_id, mu_new)

    def _demote_slow_primary(self, r: npt.NDArray[Any]) -> None:
        """A confirmed track without any secondary reply that has slowed to clutter speed
        goes back to tentative: its first, noisy velocity may have passed the speed test.
        ``r``: the updated tracks' rows, changed in place."""
        primary_only = (r["address"] < 0) & (r["mode3a"] < 0)
        speed = np.hypot(r["xc"][:, 2], r["xc"][:, 3])
        slow = primary_only & (speed < self.config.min_confirm_speed_psr_only_m_s)
        r["status"][slow & (r["status"] == CONFIRMED)] = TENTATIVE

    def _update_vertical(self, r: npt.NDArray[Any], p: PlotArrays) -> None:
        """Vertical filter of the tracks' rows ``r`` (changed in place) with their plots."""
        cfg = self.config
        has = p.fl_valid & np.isfinite(p.flight_level)
        if not has.any():
            return  # a primary-only batch: no vertical work at all
        if has.all():
            rows, fl, t, typ = r, p.flight_level, p.time, p.typ
        else:
            rows, fl, t, typ = r[has], p.flight_level[has], p.time[has], p.typ[has]
        var = vertical.measurement_variance(fl, typ, cfg)
        fl_old, rate_old, pv_old = rows["fl"], rows["rate"], rows["Pv"]
        start = ~rows["fl_ok"]
        fl_p, rate_p, pv_p = vertical.predict(
            fl_old, rate_old, pv_old, t - rows["t_fl"], cfg.q_vertical
        )
        fl_u, rate_u, pv_u, ok = vertical.update(fl_p, rate_p, pv_p, fl, var, cfg.fl_gate)
        rejects = np.where(ok, 0, rows["fl_rejects"] + 1)
        start |= rejects >= cfg.fl_max_rejects
        fresh = np.zeros((fl.shape[0], 2, 2))
        fresh[:, 0, 0] = var
        fresh[:, 1, 1] = cfg.initial_climb_variance
        # A rejected level (garbled Mode C) leaves the old state at its old time.
        rows["fl"] = np.where(start, fl, np.where(ok, fl_u, fl_old))
        rows["rate"] = np.where(start, 0.0, np.where(ok, rate_u, rate_old))
        rows["Pv"] = np.where(
            start[:, None, None], fresh, np.where(ok[:, None, None], pv_u, pv_old)
        )
        rows["t_fl"] = np.where(start | ok, t, rows["t_fl"])
        rows["fl_rejects"] = np.where(start, 0, rejects)
        rows["fl_ok"] = True
        if rows is not r:
            r[has] = rows

    def _confirm(self, tab: npt.NDArray[Any], r: npt.NDArray[Any]) -> None:
        """M of N, except for a tentative track that echoes a confirmed track that is
        associating (a reflection or a split, since the original follows the
        kinematics; see ``_echoes``), and for a slow track that never had a secondary
        reply (clutter). ``r``: the rows to confirm (changed in place), already written
        to ``tab``."""
        candidates = np.flatnonzero(
            (r["status"] == TENTATIVE) & (np.bitwise_count(r["hist"]) >= self.config.confirm_m)
        )
        if candidates.size == 0:
            return
        live = (tab["status"] == CONFIRMED) & (tab["misses"] == 0) & (tab["address"] >= 0)
        clash = self._echoes(r[candidates], tab[live])
        address = r["address"][candidates]
        primary_only = (address < 0) & (r["mode3a"][candidates] < 0)
        xc = r["xc"][candidates]
        speed = np.hypot(xc[:, 2], xc[:, 3])
        slow = primary_only & (speed < self.config.min_confirm_speed_psr_only_m_s)
        confirmed = candidates[~clash & ~slow]
        r["status"][confirmed] = CONFIRMED
        self.stats.tracks_confirmed += int(confirmed.size)

    def _echoes(self, new: npt.NDArray[Any], live: npt.NDArray[Any]) -> BoolArray:
        """Which ``new`` tracks look like an echo (a reflection or a split) of a ``live``
        confirmed track: the same address with nothing to tell them apart. An echo
        repeats its original's Mode 3/A and Mode C; a second aircraft with the same
        address (DOMAIN.md section 2) flies with its own code or at its own level."""
        echo = np.zeros(len(new), dtype=bool)
        for k in np.flatnonzero(new["address"] >= 0).tolist():
            twins = live[live["address"] == new["address"][k]]
            if len(twins) == 0:
                continue
            code, fl = new["mode3a"][k], new["fl"][k]
            other_code = (code >= 0) & (twins["mode3a"] >= 0) & (twins["mode3a"] != code)
            other_level = (
                new["fl_ok"][k]
                & twins["fl_ok"]
                & (np.abs(twins["fl"] - fl) > self.config.echo_level_tolerance_fl)
            )
            echo[k] = bool(np.any(~other_code & ~other_level))
        return echo

    def _create(self, first: PlotArrays, second: PlotArrays) -> npt.NDArray[Any]:
        k = len(second)
        if k == 0:
            return np.zeros(0, dtype=self.output_dtype)
        cfg = self.config
        start = self._n
        if start + k > self._tab.shape[0]:
            grown = np.zeros(max(2 * self._tab.shape[0], start + k), dtype=self._tab.dtype)
            grown[:start] = self._tab[:start]
            self._tab = grown
        self._n = start + k
        tab = self._tab[: self._n]
        fresh: npt.NDArray[Any] = np.zeros(k, dtype=self._tab.dtype)
        x, pm = two_point_state(
            first, second, float(self.models.q[0]), cfg.init_velocity_variance_scale
        )
        m = self.models.n_models
        fresh["number"] = np.arange(self._next_number, self._next_number + k)
        self._next_number += k
        fresh["status"] = TENTATIVE
        fresh["x"] = x[:, None, :]
        fresh["P"] = pm[:, None, :, :]
        fresh["mu"] = np.broadcast_to(self.models.initial_probabilities, (k, m))
        fresh["xc"] = x
        fresh["Pc"] = pm
        fresh["t"] = fresh["t_hit"] = second.time
        missed_between = second.time - first.time > 1.5 * cfg.scan_period_s
        fresh["hist"] = np.where(missed_between, 0b101, 0b11) & self._hist_mask
        fresh["address"] = np.where(second.address >= 0, second.address, first.address)
        code2 = np.where(second.mode3a_valid, second.mode3a, -1)
        code1 = np.where(first.mode3a_valid, first.mode3a, -1)
        fresh["mode3a"] = np.where(code2 >= 0, code2, code1)
        fresh["fl"] = np.nan
        self._update_vertical(fresh, first)
        self._update_vertical(fresh, second)
        as_bytes(tab)[start:] = as_bytes(fresh)
        self.stats.tracks_initiated += k
        self._confirm(tab, fresh)
        tab["status"][start:] = fresh["status"]
        return self._rows(fresh, second.time, fresh["status"], second.plot_id, fresh["mu"])

    def _age(self, now: float, updated: BoolArray, n_old: int) -> npt.NDArray[Any]:
        """Count missed scans of the tracks without a plot; coast or delete them."""
        cfg = self.config
        tab = self._tab[: self._n]
        idle = np.flatnonzero(~updated[:n_old])
        elapsed = now - tab["t_hit"][idle]
        n_miss = np.maximum(np.floor(elapsed / cfg.scan_period_s - cfg.miss_tolerance), 0)
        n_miss = n_miss.astype(np.int64)
        grow = n_miss > tab["misses"][idle]
        idle, n_miss = idle[grow], n_miss[grow]
        if idle.size == 0:
            return np.zeros(0, dtype=self.output_dtype)
        shift = np.minimum(n_miss - tab["misses"][idle], 32)
        tab["hist"][idle] = (tab["hist"][idle] << shift) & self._hist_mask
        tab["misses"][idle] = n_miss
        dt = now - tab["t"][idle]
        pred = imm.predict(tab["x"][idle], tab["P"][idle], tab["mu"][idle], dt, self.models)
        status = tab["status"][idle]
        limit = np.where(status == CONFIRMED, cfg.delete_misses, cfg.tentative_delete_misses)
        position_var = pred.P_comb[:, 0, 0] + pred.P_comb[:, 1, 1]
        dead = (n_miss >= limit) | (position_var > cfg.max_position_variance_m2)
        coasting = (status == CONFIRMED) & ~dead
        report = dead | coasting
        out_status = np.where(dead, DELETED, COASTING).astype(np.int8)
        rows = self._rows(
            as_bytes(tab)[idle[report]].view(tab.dtype),
            np.full(int(np.count_nonzero(report)), now),
            out_status[report],
            np.full(int(np.count_nonzero(report)), -1, dtype=np.int64),
            pred.c[report],
            pred.take(np.flatnonzero(report)),
        )
        if dead.any():
            keep = np.ones(self._n, dtype=bool)
            keep[idle[dead]] = False
            survivors = as_bytes(tab)[keep]
            self._n = survivors.shape[0]
            as_bytes(self._tab)[: self._n] = survivors
            self.stats.tracks_deleted += int(np.count_nonzero(dead))
        return rows

    def _rows(
        self,
        r: npt.NDArray[Any],
        time: FloatArray,
        status: npt.NDArray[Any],
        plot_id: IntArray,
        mu: FloatArray,
        pred: imm.ImmPrediction | None = None,
    ) -> npt.NDArray[Any]:
        """Output rows of the tracks whose internal rows are ``r``."""
        out = np.zeros(r.shape[0], dtype=self.output_dtype)
        xc = r["xc"] if pred is None else pred.x_comb
        pc = r["Pc"] if pred is None else pred.P_comb
        out["track_number"] = r["number"]
        out["time"] = time
        out["x"], out["y"], out["vx"], out["vy"] = xc.T
        out["P"] = pc.reshape(-1, 16)
        fl_ok = r["fl_ok"]
        rate = r["rate"]
        out["flight_level"] = np.where(fl_ok, r["fl"] + rate * (time - r["t_fl"]), np.nan)
        out["climb_rate_fl_per_s"] = np.where(fl_ok, rate, np.nan)
        out["status"] = status
        out["plot_id"] = plot_id
        out["mode3a"] = r["mode3a"]
        out["address"] = r["address"]
        out["model_probabilities"] = mu
        return out
