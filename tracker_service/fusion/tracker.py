"""The system tracker: local tracks of several radars to one system track per aircraft.

State lives in two numpy tables: the local tracks seen so far (one row per radar and
local track number, with the latest state and the system track it feeds) and the system
tracks, indexed by their number (1..4095). Per batch the work is vectorised over the
batch's local tracks and the system tracks they touch; Python loops run only over the
few distinct source counts of a fusion and, in the "plots" method, over the rare second
plot of one system track within a batch.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import consider
from tracker_service.fusion.config import FusionConfig
from tracker_service.fusion.messages import (
    COASTING,
    CONFIRMED,
    ENDED,
    MAX_SOURCES,
    MAX_SYSTEM_NUMBER,
    SYSTEM_UPDATE_DTYPE,
)
from tracker_service.fusion.ml import ml_fuse, predict_cv, shared_prediction_noise
from tracker_service.tracking import imm
from tracker_service.tracking.associate import global_nearest_neighbour
from tracker_service.tracking.clock import DataClock
from tracker_service.tracking.models import ModelSet, cv_transition
from tracker_service.tracking.plots import (
    BoolArray,
    FloatArray,
    IntArray,
    PlotArrays,
    as_plot_arrays,
    is_shared_code,
)
from tracker_service.tracking.tracker import CONFIRMED as LOCAL_CONFIRMED
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED
from tracker_service.tracking.tracker import TENTATIVE as LOCAL_TENTATIVE

KEY_SHIFT = 32
"""Local-track key: radar << KEY_SHIFT | local track number."""


def _local_dtype(n_models: int) -> np.dtype[Any]:
    return np.dtype(
        [
            ("key", np.int64),
            ("radar", np.int64),
            ("number", np.int64),
            ("system", np.int64),  # 0: none
            ("status", np.int8),
            ("alive", np.bool_),
            ("t", np.float64),  # time of the state
            ("x", np.float64, (4,)),
            ("P", np.float64, (4, 4)),
            ("extra", np.float64, (2, 2)),  # residual-bias covariance of the latest plot
            ("plot_id", np.int64),
            ("t_plot", np.float64),
            ("fl", np.float64),
            ("rate", np.float64),
            ("t_fl", np.float64),
            ("address", np.int64),
            ("mode3a", np.int64),
            ("fails", np.int64),
            ("t_founder", np.float64),  # first time it could have founded a system track
            ("mu", np.float64, (n_models,)),  # its model probabilities (0: not known)
        ]
    )


def _system_dtype(n_models: int, n_radars: int) -> np.dtype[Any]:
    return np.dtype(
        [
            ("alive", np.bool_),
            ("t", np.float64),  # time of x, P, M: the latest output (or filter) state
            ("x", np.float64, (4,)),
            # "plots": the error's covariance without the residual biases, which enter
            # through M and B (fusion/consider.py); "tracks": the whole covariance, M = 0.
            ("P", np.float64, (4, 4)),
            ("M", np.float64, (n_radars, 4, 2)),  # sensitivity to each radar's bias
            ("B", np.float64, (n_radars, 2, 2)),  # each radar's latest residual bias cov.
            ("t_plot", np.float64),  # latest plot of any of its local tracks
            ("freed_at", np.float64),
            ("born", np.float64),
            ("address", np.int64),
            ("mode3a", np.int64),
            ("solo", np.bool_),  # fed by its founding local track alone so far
            ("mx", np.float64, (n_models, 4)),  # "plots" method: the IMM's models
            ("mP", np.float64, (n_models, 4, 4)),
            ("mu", np.float64, (n_models,)),
            ("mM", np.float64, (n_models, n_radars, 4, 2)),
        ]
    )


@dataclass
class FusionStats:
    """Running counts since the fuser started."""

    batches: int = 0
    rows: int = 0
    system_tracks_created: int = 0
    system_tracks_ended: int = 0
    reassociations: int = 0
    late_plots_skipped: int = 0
    unknown_plot_ids: int = 0
    numbers_exhausted: int = 0
    system_tracks_merged: int = 0
    out_of_line_updates: int = 0
    """Local-track updates refused by the clock: too far ahead of the fuser's clock or
    behind it (see ``tracking.clock``), e.g. a radar whose time is out of step."""
    clock_resyncs: int = 0


@dataclass(frozen=True)
class References:
    """Per update row with a plot whose local track feeds a system track: predictions of
    that system track at the plot's time, from the other radars' local tracks only
    (``others_*``, valid when one contributes within ``max_reference_age_s``) and from all
    its local tracks as they were before this batch (``all_*``); positions (N, 2), their
    covariances (N, 2, 2), the velocity of the others' prediction (N, 2), and which radars
    contribute (N, n_radars)."""

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


class SystemTracker:
    """Feed ``process`` one radar's batch of local-track updates at a time; it returns the
    system-track rows (``SYSTEM_UPDATE_DTYPE``) of the batch."""

    def __init__(self, n_radars: int, config: FusionConfig | None = None) -> None:
        if n_radars < 1:
            raise ValueError(f"n_radars must be >= 1, not {n_radars!r}")
        self.n_radars = n_radars
        self.config = config or FusionConfig()
        self.models = ModelSet.from_config(self.config.plot_filter)
        self.stats = FusionStats()
        self._loc: npt.NDArray[Any] = np.zeros(64, dtype=_local_dtype(self.models.n_models))
        self._n = 0
        self._index_keys = np.zeros(0, dtype=np.int64)
        self._index_rows = np.zeros(0, dtype=np.int64)
        self._sys: npt.NDArray[Any] = np.zeros(
            MAX_SYSTEM_NUMBER + 1, dtype=_system_dtype(self.models.n_models, n_radars)
        )
        self._sys["freed_at"] = -np.inf
        # Ahead: the radars' data interleave within a scan; behind: an update older than
        # the silence would found a system track only to end it at once.
        self.clock = DataClock(
            self.config.longest_period_s,
            self.config.silence_s,
            resync_span_s=2.0 * self.config.longest_period_s,
        )
        self._now = -np.inf
        self._merge_counts: dict[tuple[int, int], int] = {}

    @property
    def system_tracks(self) -> IntArray:
        """The numbers of the live system tracks."""
        return np.flatnonzero(self._sys["alive"])

    # ------------------------------------------------------------------ process

    def process(
        self,
        radar: int,
        updates: npt.NDArray[Any],
        plots: PlotArrays | npt.NDArray[Any],
        extra_R: FloatArray | None = None,
    ) -> npt.NDArray[Any]:
        """One radar's batch: its local-track updates (``track_update_dtype``), the plots
        they used, and optionally the radar's residual-bias covariance (N, 2, 2) at each
        update's plot: a considered error common to the radar's plots in the "plots"
        method (fusion/consider.py), added to that local track's covariance when it is
        fused in the "tracks" method."""
        self._check_radar(radar)
        self.stats.batches += 1
        order = np.argsort(updates["time"], kind="stable")
        u = updates[order]
        extra = np.zeros((len(u), 2, 2)) if extra_R is None else np.asarray(extra_R)[order]
        if len(u) == 0:
            return self._silence(radar)
        step = self.clock.step(u["time"])
        out = [self._resynchronised(radar)] if step.resynchronised else []
        if not step.accepted.all():
            self.stats.out_of_line_updates += int(np.count_nonzero(~step.accepted))
            u, extra = u[step.accepted], extra[step.accepted]
            if len(u) == 0:
                return np.concatenate([*out, self._silence(radar)])
        self._now = self.clock.now
        rows = self._local_rows(radar, u)
        known = rows >= 0
        u, extra, rows = u[known], extra[known], rows[known]
        has_plot = u["plot_id"] >= 0
        self._store(rows, u, extra, has_plot)
        touched = np.unique(rows)
        old_system = self._loc["system"][touched].copy()
        created = self._associate(radar, touched, has_plot, rows)
        if self.config.method == "plots":
            self._filter_plots(radar, rows, u, extra, has_plot, as_plot_arrays(plots), created)
        merged = self._merge(radar, np.unique(self._loc["system"][rows]))
        systems = self._loc["system"][rows]
        fed_rows = systems > 0
        # Emitted before the deleted local tracks leave: their last state still counts.
        out += [merged, self._emit(radar, systems[fed_rows], u[fed_rows], has_plot[fed_rows])]
        deleted = touched[self._loc["status"][touched] == LOCAL_DELETED]
        if deleted.size:
            self._loc["alive"][deleted] = False
            self._loc["system"][deleted] = 0
            self._reindex()
        out.append(self._end_orphans(radar, np.union1d(old_system, systems)))
        out.append(self._silence(radar))
        self._compact()
        result = np.concatenate(out)
        self.stats.rows += len(result)
        return result

    def _resynchronised(self, radar: int) -> npt.NDArray[Any]:
        """Every radar's time jumped for good and the clock followed. Back in time, what
        lies in the abandoned future ends (its rows returned), and no number stays
        blocked or track waits for longer than its delay from the new present."""
        self.stats.clock_resyncs += 1
        now = self.clock.now
        self._now = now
        sys, loc = self._sys, self._loc[: self._n]
        sys["freed_at"] = np.minimum(sys["freed_at"], now)
        loc["t_founder"] = np.where(loc["t_founder"] > now, now, loc["t_founder"])
        future = np.flatnonzero(sys["alive"] & (sys["t_plot"] > now + self.clock.max_ahead_s))
        return self._end(radar, future[future > 0])

    def _check_radar(self, radar: int) -> None:
        if not 0 <= radar < self.n_radars:
            raise ValueError(f"radar must be in 0..{self.n_radars - 1}, not {radar!r}")

    def _local_rows(self, radar: int, u: npt.NDArray[Any], create: bool = True) -> IntArray:
        """Row of each update's local track in the local table (-1: unknown, and not
        created: a deleted track never seen before, or ``create`` false)."""
        keys = (np.int64(radar) << KEY_SHIFT) | u["track_number"].astype(np.int64)
        rows = self._lookup(keys)
        missing = (rows < 0) & (u["status"] != LOCAL_DELETED)
        if create and missing.any():
            new_keys, first = np.unique(keys[missing], return_index=True)
            start = self._grow(new_keys.size)
            fresh = self._loc[start : start + new_keys.size]
            fresh[...] = np.zeros(1, dtype=self._loc.dtype)
            fresh["key"] = new_keys
            fresh["radar"] = radar
            fresh["number"] = u["track_number"][missing][first]
            fresh["alive"] = True
            fresh["t"] = np.nan  # no state yet
            fresh["t_plot"] = -np.inf
            fresh["t_founder"] = np.nan
            fresh["fl"] = np.nan
            fresh["address"] = fresh["mode3a"] = -1
            self._reindex()
            rows = self._lookup(keys)
        return rows

    def _lookup(self, keys: IntArray) -> IntArray:
        pos = np.searchsorted(self._index_keys, keys)
        pos = np.minimum(pos, max(self._index_keys.size - 1, 0))
        if self._index_keys.size == 0:
            return np.full(keys.shape, -1, dtype=np.int64)
        return np.where(self._index_keys[pos] == keys, self._index_rows[pos], -1)

    def _grow(self, k: int) -> int:
        start = self._n
        if start + k > self._loc.shape[0]:
            grown = np.zeros(max(2 * self._loc.shape[0], start + k), dtype=self._loc.dtype)
            grown[:start] = self._loc[:start]
            self._loc = grown
        self._n = start + k
        return start

    def _reindex(self) -> None:
        loc = self._loc[: self._n]
        live = np.flatnonzero(loc["alive"])
        order = np.argsort(loc["key"][live])
        self._index_keys = loc["key"][live][order]
        self._index_rows = live[order]

    def _compact(self) -> None:
        """Drop deleted local tracks once they are half the table (rows move: reindex)."""
        alive = self._loc["alive"][: self._n]
        if np.count_nonzero(~alive) * 2 <= self._n:
            return
        survivors = self._loc[: self._n][alive]
        self._n = survivors.shape[0]
        self._loc[: self._n] = survivors
        self._reindex()

    def _store(
        self, rows: IntArray, u: npt.NDArray[Any], extra: FloatArray, has_plot: BoolArray
    ) -> None:
        """The latest row of each local track: its status and identity; the latest row
        with a plot (or any row of a track without state yet): its state."""
        loc = self._loc
        last = _last_of_each(rows)
        r, v = rows[last], u[last]
        loc["status"][r] = v["status"]
        loc["address"][r] = np.where(v["address"] >= 0, v["address"], loc["address"][r])
        loc["mode3a"][r] = np.where(v["mode3a"] >= 0, v["mode3a"], loc["mode3a"][r])
        with_fl = np.isfinite(v["flight_level"])
        loc["fl"][r[with_fl]] = v["flight_level"][with_fl]
        loc["rate"][r[with_fl]] = np.nan_to_num(v["climb_rate_fl_per_s"][with_fl])
        loc["t_fl"][r[with_fl]] = v["time"][with_fl]
        stateless = np.isnan(loc["t"][rows])
        sel = np.flatnonzero(has_plot | stateless)
        last = sel[_last_of_each(rows[sel])]
        r, v = rows[last], u[last]
        loc["t"][r] = v["time"]
        loc["x"][r] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
        loc["P"][r] = v["P"].reshape(-1, 4, 4)
        loc["extra"][r] = extra[last]
        if v.dtype["model_probabilities"].shape == (self.models.n_models,):
            # The local trackers' IMM is the plot filter's (both TrackerConfig's model
            # set): a system track founded by a local track starts in its models.
            loc["mu"][r] = v["model_probabilities"]
        plotted = has_plot[last]
        loc["plot_id"][r[plotted]] = v["plot_id"][plotted]
        loc["t_plot"][r[plotted]] = v["time"][plotted]

    # -------------------------------------------------------------- association

    def _associate(
        self, radar: int, touched: IntArray, has_plot: BoolArray, rows: IntArray
    ) -> IntArray:
        """Keep, drop or find the system track of each local track of the batch; create
        system tracks for confirmed local tracks that found none. Returns the numbers
        of the system tracks created."""
        cfg = self.config
        loc = self._loc
        live = touched[loc["status"][touched] != LOCAL_DELETED]
        # Only confirmed local tracks feed system tracks: one that its tracker took back
        # to tentative (a slow primary-only track: clutter) leaves its system track.
        demoted = live[(loc["system"][live] > 0) & (loc["status"][live] == LOCAL_TENTATIVE)]
        loc["system"][demoted] = 0
        live = live[loc["status"][live] != LOCAL_TENTATIVE]
        held = live[loc["system"][live] > 0]
        d2 = self._distance(held, loc["system"][held])
        fails = np.where(d2 <= cfg.gate, 0, loc["fails"][held] + 1)
        loc["fails"][held] = fails
        lost = held[fails >= cfg.reassociate_after]
        loc["system"][lost] = 0
        loc["fails"][lost] = 0
        self.stats.reassociations += int(lost.size)

        plotted = np.unique(rows[has_plot])
        free = np.intersect1d(live[loc["system"][live] == 0], plotted)
        if free.size == 0:
            return np.zeros(0, dtype=np.int64)
        candidates = self._open_systems(radar)
        li = np.repeat(free, candidates.size)
        sj = np.tile(candidates, free.size)
        d2 = self._distance(li, sj)
        gated = d2 <= cfg.gate
        li, sj, d2 = li[gated], sj[gated], d2[gated]
        cost = d2 + self._identity_cost(li, sj)
        chosen = global_nearest_neighbour(
            np.searchsorted(free, li), np.searchsorted(candidates, sj), cost
        )
        joined, target = li[chosen], sj[chosen]
        self._join(radar, joined, target)
        rest = np.setdiff1d(free, joined)
        return self._create(rest[self._may_found(rest)])

    def _may_found(self, candidates: IntArray) -> BoolArray:
        """A local track that found no system track founds one, unless a live system
        track carries its Mode S address or its (not shared) Mode 3/A code: then it is
        most likely that aircraft, seen apart while the biases are still unknown, and it
        waits up to ``FusionConfig.found_delay_s`` for the gate to take it (a second
        aircraft with a duplicated address or code founds its own after that)."""
        loc, sys = self._loc, self._sys
        waiting = np.isnan(loc["t_founder"][candidates])
        loc["t_founder"][candidates[waiting]] = self._now
        address, code = loc["address"][candidates], loc["mode3a"][candidates]
        live = sys["alive"].copy()
        live[0] = False
        known = (np.isin(address, sys["address"][live]) & (address >= 0)) | (
            np.isin(code, sys["mode3a"][live]) & (code >= 0) & ~is_shared_code(code)
        )
        waited = self._now - loc["t_founder"][candidates]
        return np.asarray(~known | (waited >= self.config.found_delay), dtype=bool)

    def _merge(self, radar: int, touched: IntArray) -> npt.NDArray[Any]:
        """Merge each touched system track with a live one it duplicates (see
        ``FusionConfig.merge_after``); returns the ended rows of the merged-away ones."""
        sys, loc = self._sys, self._loc[: self._n]
        touched = touched[(touched > 0) & sys["alive"][touched]]
        fed = loc["alive"] & (loc["system"] > 0)
        radars_of = np.zeros((MAX_SYSTEM_NUMBER + 1, self.n_radars), dtype=bool)
        radars_of[loc["system"][fed], loc["radar"][fed]] = True
        alive = np.flatnonzero(sys["alive"])
        alive = alive[alive > 0]
        # A pair's count lives while every check of it passes: the checks of the touched
        # tracks start from the counts of their pairs that pass again now.
        touched_set = set(touched.tolist())
        counts = {
            p: c
            for p, c in self._merge_counts.items()
            if p[0] not in touched_set and p[1] not in touched_set
        }
        young: list[int] = []
        old: list[int] = []
        for a in touched.tolist():
            others = alive[(alive != a) & ~np.any(radars_of[alive] & radars_of[a], axis=1)]
            others = others[self._compatible(a, others)]
            if others.size == 0:
                continue
            dt = sys["t"][a] - sys["t"][others]
            xs, ps = predict_cv(sys["x"][others], sys["P"][others], dt, self.config.q)
            d = xs - sys["x"][a]
            # Their errors differ by their different shares of each radar's bias.
            m = np.einsum("kab,klbc->klac", cv_transition(dt), sys["M"][others]) - sys["M"][a]
            larger = np.trace(sys["B"][others], axis1=-2, axis2=-1) > np.trace(
                sys["B"][a], axis1=-2, axis2=-1
            )
            b = np.where(larger[..., None, None], sys["B"][others], sys["B"][a])
            s = ps + sys["P"][a] + consider.bias_share(m, b)
            d2 = np.einsum("ka,ka->k", d, np.linalg.solve(s, d[..., None])[..., 0])
            for b in others[d2 <= self.config.gate].tolist():
                pair = (min(a, b), max(a, b))
                count = counts[pair] = self._merge_counts.get(pair, 0) + 1
                if count >= self.config.merge_after and a not in young and b not in young:
                    keep, leave = (a, b) if sys["born"][a] <= sys["born"][b] else (b, a)
                    old.append(keep)
                    young.append(leave)
        gone = set(young)
        self._merge_counts = {p: c for p, c in counts.items() if not gone & set(p)}
        if not young:
            return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
        leaving = np.array(young, dtype=np.int64)
        ended = self._end(radar, leaving, moved_to=np.array(old, dtype=np.int64))
        self.stats.system_tracks_merged += len(young)
        return ended

    def _compatible(self, a: int, others: IntArray) -> BoolArray:
        """System tracks whose identities do not tell them from ``a``: no two different
        Mode S addresses, no two different Mode 3/A codes."""
        sys = self._sys
        address, code = sys["address"][a], sys["mode3a"][a]
        other_address, other_code = sys["address"][others], sys["mode3a"][others]
        same_address = (address < 0) | (other_address < 0) | (other_address == address)
        same_code = (code < 0) | (other_code < 0) | (other_code == code)
        return np.asarray(same_address & same_code, dtype=bool)

    def _open_systems(self, radar: int) -> IntArray:
        """Live system tracks a new local track of ``radar`` may join: not those already
        fed by another confirmed local track of the same radar (another aircraft)."""
        loc = self._loc[: self._n]
        busy = loc["alive"] & (loc["radar"] == radar) & (loc["status"] == LOCAL_CONFIRMED)
        open_ = self._sys["alive"].copy()
        open_[loc["system"][busy]] = False
        open_[0] = False
        return np.flatnonzero(open_)

    def _join(self, radar: int, joined: IntArray, target: IntArray) -> None:
        """Attach local tracks to system tracks; a stale local track of the same radar on
        that system track (coasting: the local tracker restarted the aircraft) leaves."""
        loc = self._loc
        if joined.size == 0:
            return
        same = np.flatnonzero(
            loc["alive"][: self._n]
            & (loc["radar"][: self._n] == radar)
            & np.isin(loc["system"][: self._n], target)
        )
        loc["system"][same] = 0
        loc["system"][joined] = target
        self._sys["solo"][target] = False
        loc["fails"][joined] = 0
        loc["t_founder"][joined] = np.nan
        self._sys["t_plot"][target] = np.maximum(self._sys["t_plot"][target], loc["t_plot"][joined])

    def _distance(self, local: IntArray, system: IntArray) -> FloatArray:
        """Chi-square distance (4 dof) of local tracks and system tracks at the local
        tracks' times (the system tracks predicted there: by their IMM in the "plots"
        method, which follows a turn the local track's IMM follows; a constant-velocity
        prediction, with its residual bias no longer widening the gate of a radar's own
        system track, cut aircraft that turned out of their system tracks)."""
        if local.size == 0:
            return np.zeros(0)
        loc, sys = self._loc, self._sys
        t = loc["t"][local]
        dt = t - sys["t"][system]
        if self.config.method == "plots":
            pred = self._predict(system, dt)
            xs, ps, moved = pred.imm.x_comb, pred.imm.P_comb, pred.M_comb
        else:
            xs, ps = predict_cv(sys["x"][system], sys["P"][system], dt, self.config.q)
            moved = np.einsum("kab,klbc->klac", cv_transition(dt), sys["M"][system])
        d = loc["x"][local] - xs
        # The residual biases: the local track carries its radar's whole, the system
        # track its shares of each radar's (M). Before the biases are known, two radars'
        # tracks of one aircraft lie apart by as much; a radar's local track and a system
        # track only it feeds share the same bias, which cancels.
        radar = loc["radar"][local]
        rows = np.arange(local.size)
        m = -moved
        m[rows, radar] += consider.POSITION
        b = sys["B"][system].copy()
        b[rows, radar] = loc["extra"][local]
        s = loc["P"][local] + ps + consider.bias_share(m, b)
        d2: FloatArray = np.einsum("ka,ka->k", d, np.linalg.solve(s, d[..., None])[..., 0])
        return d2

    def _identity_cost(self, local: IntArray, system: IntArray) -> FloatArray:
        """Identity shifts the cost among gated pairs only: it never opens a gate."""
        cfg = self.config
        a_l, a_s = self._loc["address"][local], self._sys["address"][system]
        both = (a_l >= 0) & (a_s >= 0)
        c_l, c_s = self._loc["mode3a"][local], self._sys["mode3a"][system]
        code = (c_l >= 0) & (c_l == c_s) & ~is_shared_code(c_l)
        return np.asarray(
            cfg.address_mismatch_penalty * (both & (a_l != a_s))
            - cfg.address_bonus * (both & (a_l == a_s))
            - cfg.mode3a_bonus * code,
            dtype=np.float64,
        )

    def _create(self, founders: IntArray) -> IntArray:
        sys, loc = self._sys, self._loc
        # A number freed "later" than now (the clock came back from a jump) waits its
        # delay from now, not from a time that never was.
        freed_at = np.minimum(sys["freed_at"], self._now)
        free = np.flatnonzero(
            ~sys["alive"] & (freed_at + self.config.number_reuse_delay_s <= self._now)
        )
        free = free[free > 0]
        if free.size < founders.size:
            self.stats.numbers_exhausted += int(founders.size - free.size)
            founders = founders[: free.size]
        numbers = free[: founders.size]
        if numbers.size == 0:
            return numbers
        sys["alive"][numbers] = True
        sys["born"][numbers] = self._now
        sys["solo"][numbers] = True
        sys["t"][numbers] = loc["t"][founders]
        sys["x"][numbers] = loc["x"][founders]
        sys["P"][numbers] = loc["P"][founders]
        radars = loc["radar"][founders]
        sys["B"][numbers] = 0.0
        sys["B"][numbers, radars] = loc["extra"][founders]
        sys["M"][numbers] = 0.0
        if self.config.method == "plots":
            sys["M"][numbers, radars] = consider.POSITION
        sys["mM"][numbers] = sys["M"][numbers][:, None]
        sys["t_plot"][numbers] = loc["t_plot"][founders]
        sys["address"][numbers] = loc["address"][founders]
        sys["mode3a"][numbers] = loc["mode3a"][founders]
        sys["mx"][numbers] = loc["x"][founders][:, None, :]
        sys["mP"][numbers] = loc["P"][founders][:, None, :, :]
        mu = loc["mu"][founders]
        known = mu.sum(axis=1) > 0.0
        sys["mu"][numbers] = np.where(known[:, None], mu, self.models.initial_probabilities)
        loc["system"][founders] = numbers
        loc["fails"][founders] = 0
        loc["t_founder"][founders] = np.nan
        self.stats.system_tracks_created += int(numbers.size)
        return numbers

    # ------------------------------------------------------------ "plots" method

    def _filter_plots(
        self,
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
        one its founder alone has fed follows it (``_follow_founder``)."""
        systems = self._loc["system"][rows]
        use = np.flatnonzero(has_plot & (systems > 0) & ~np.isin(systems, created))
        if use.size == 0:
            return
        found = _positions(plots.plot_id, u["plot_id"][use])
        self.stats.unknown_plot_ids += int(np.count_nonzero(found < 0))
        use, found = use[found >= 0], found[found >= 0]
        rank = _rank_within(systems[use])
        for r in range(int(rank.max(initial=-1)) + 1):
            now = rank == r
            self._filter_round(radar, systems[use[now]], plots.take(found[now]), extra[use[now]])
        solo = self._sys["solo"][systems[use]]
        self._follow_founder(systems[use[solo]], u[use[solo]])

    def _follow_founder(self, numbers: IntArray, u: npt.NDArray[Any]) -> None:
        """A system track that only its founding local track has fed is that track: the
        same plots through the same IMM, whose per-model states (which the system track's
        models, started from the combined state, take a few scans to regain: a
        measured transient of 9 m and 2 m/s RMS over the next two plots) only the local
        tracker holds. Its IMM runs all the same, so that it has settled when a second
        local track joins; its sensitivity stays that of its radar's bias whole
        (``consider.POSITION``), which its reported covariance adds."""
        if numbers.size == 0:
            return
        last = _last_of_each(numbers)
        n, v = numbers[last], u[last]
        sys = self._sys
        sys["x"][n] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
        sys["P"][n] = v["P"].reshape(-1, 4, 4)

    def _predict(self, numbers: IntArray, dt: FloatArray) -> consider.ConsiderPrediction:
        """The system tracks' IMMs predicted over dt (field by field: a whole row of the
        table holds every radar's sensitivities)."""
        sys = self._sys
        return consider.predict(
            sys["mx"][numbers],
            sys["mP"][numbers],
            sys["mM"][numbers],
            sys["mu"][numbers],
            dt,
            self.models,
        )

    def _filter_round(
        self, radar: int, numbers: IntArray, p: PlotArrays, extra: FloatArray
    ) -> None:
        sys = self._sys
        dt = p.time - sys["t"][numbers]
        late = dt < -self.config.max_backward_s
        self.stats.late_plots_skipped += int(np.count_nonzero(late))
        keep = ~late
        numbers, dt, extra = numbers[keep], dt[keep], extra[keep]
        p = p.select(keep)
        if numbers.size == 0:
            return
        sys["B"][numbers, radar] = extra
        pred = self._predict(numbers, dt)
        z = np.column_stack([p.x, p.y])
        x, pm, mm, mu = consider.update(pred, z, p.R, radar, sys["B"][numbers])
        xc, pc = imm.combine(x, pm, mu)
        sys["mx"][numbers], sys["mP"][numbers], sys["mM"][numbers] = x, pm, mm
        sys["mu"][numbers] = mu
        sys["x"][numbers], sys["P"][numbers], sys["t"][numbers] = xc, pc, p.time
        sys["M"][numbers] = consider.combine(mm, mu)

    # ----------------------------------------------------------------- output

    def _emit(
        self, radar: int, systems: IntArray, u: npt.NDArray[Any], has_plot: BoolArray
    ) -> npt.NDArray[Any]:
        """One row per system track fed by the batch, at the batch's latest update of it."""
        if systems.size == 0:
            return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
        last = _last_of_each(systems)
        numbers, t = systems[last], u["time"][last]
        fresh = np.isin(numbers, systems[has_plot])
        plot_of = np.full(numbers.size, -1, dtype=np.int64)
        with_plot = np.flatnonzero(has_plot)
        latest_plot = with_plot[_last_of_each(systems[with_plot])]
        plot_of[np.searchsorted(numbers, systems[latest_plot])] = u["plot_id"][latest_plot]
        sys = self._sys
        sys["t_plot"][numbers[fresh]] = np.maximum(sys["t_plot"][numbers[fresh]], t[fresh])
        slots = self._slots(numbers)
        if self.config.method == "tracks":
            x, p = self._fuse(slots, t)
            sys["x"][numbers], sys["P"][numbers], sys["t"][numbers] = x, p, t
        else:
            pred = self._predict(numbers, t - sys["t"][numbers])
            x, p = pred.imm.x_comb.copy(), pred.imm.P_comb.copy()
            solo = sys["solo"][numbers]  # its founder's update (``_follow_founder``)
            v = u[last][solo]
            x[solo] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
            p[solo] = v["P"].reshape(-1, 4, 4)
            p += consider.bias_share(pred.M_comb, sys["B"][numbers])
        status = np.where(fresh, CONFIRMED, COASTING).astype(np.int8)
        out = self._rows(numbers, t, x, p, status, slots)
        out["fresh"] = fresh
        out["radar"] = radar
        out["plot_id"] = plot_of
        sys["address"][numbers] = out["address"]
        sys["mode3a"][numbers] = out["mode3a"]
        return out

    def _rows(
        self,
        numbers: IntArray,
        t: FloatArray,
        x: FloatArray,
        p: FloatArray,
        status: npt.NDArray[Any],
        slots: IntArray,
    ) -> npt.NDArray[Any]:
        loc = self._loc
        out = np.zeros(numbers.size, dtype=SYSTEM_UPDATE_DTYPE)
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
        pick = _first_where(np.isfinite(fl))
        rate = loc["rate"][s][np.arange(numbers.size), pick]
        t_fl = loc["t_fl"][s][np.arange(numbers.size), pick]
        out["flight_level"] = fl[np.arange(numbers.size), pick] + rate * (t - t_fl)
        out["climb_rate_fl_per_s"] = np.where(np.isfinite(out["flight_level"]), rate, np.nan)
        for name in ("address", "mode3a"):
            values = np.where(used, loc[name][s], -1)
            known = values[np.arange(numbers.size), _first_where(values >= 0)]
            out[name] = np.where(known >= 0, known, self._sys[name][numbers])
        return out

    def _end_orphans(self, radar: int, numbers: IntArray) -> npt.NDArray[Any]:
        """System tracks (among ``numbers``) left without any local track end."""
        numbers = numbers[numbers > 0]
        numbers = numbers[self._sys["alive"][numbers]]
        loc = self._loc[: self._n]
        fed = np.zeros(MAX_SYSTEM_NUMBER + 1, dtype=bool)
        fed[loc["system"][loc["alive"]]] = True
        return self._end(radar, numbers[~fed[numbers]])

    def _silence(self, radar: int) -> npt.NDArray[Any]:
        sys = self._sys
        quiet = sys["alive"] & (sys["t_plot"] < self._now - self.config.silence_s)
        return self._end(radar, np.flatnonzero(quiet))

    def _end(
        self, radar: int, numbers: IntArray, moved_to: IntArray | None = None
    ) -> npt.NDArray[Any]:
        """End the system tracks ``numbers``; their local tracks go to ``moved_to`` (one
        per number: a merge) or leave."""
        sys = self._sys
        if numbers.size == 0:
            return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
        out = self._rows(
            numbers,
            sys["t"][numbers],
            sys["x"][numbers],
            sys["P"][numbers] + consider.bias_share(sys["M"][numbers], sys["B"][numbers]),
            np.full(numbers.size, ENDED, dtype=np.int8),
            self._slots(numbers),
        )
        out["radar"] = radar
        loc = self._loc[: self._n]
        if moved_to is None:
            loc["system"][np.isin(loc["system"], numbers)] = 0
        else:
            for number, target in zip(numbers.tolist(), moved_to.tolist(), strict=True):
                loc["system"][loc["system"] == number] = target
            sys["solo"][moved_to] = False
        sys["alive"][numbers] = False
        sys["freed_at"][numbers] = self._now
        self.stats.system_tracks_ended += int(numbers.size)
        return out

    # ------------------------------------------------------------------ fusion

    def _slots(self, numbers: IntArray) -> IntArray:
        """Local rows feeding each system track (rows of ``numbers``, which may repeat),
        most recent plot first, at most ``max_sources``, -1 padding: (k, MAX_SOURCES)."""
        loc = self._loc[: self._n]
        k = numbers.size
        slots = np.full((k, MAX_SOURCES), -1, dtype=np.int64)
        unique, inverse = np.unique(numbers, return_inverse=True)
        feeding = np.flatnonzero(loc["alive"] & np.isin(loc["system"], unique))
        if feeding.size == 0 or k == 0:
            return slots
        group = np.searchsorted(unique, loc["system"][feeding])
        order = np.lexsort((-loc["t_plot"][feeding], group))
        feeding, group = feeding[order], group[order]
        rank = _rank_within(group)
        keep = rank < self.config.max_sources
        per_unique = np.full((unique.size, MAX_SOURCES), -1, dtype=np.int64)
        per_unique[group[keep], rank[keep]] = feeding[keep]
        slots[:] = per_unique[inverse.reshape(-1)]
        return slots

    def _fuse(self, slots: IntArray, t: FloatArray) -> tuple[FloatArray, FloatArray]:
        """ML fusion at times t (k,) of the local tracks in ``slots`` (valid first);
        rows without any source get NaN."""
        cfg, loc = self.config, self._loc
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

    # ------------------------------------------------------------- references

    def references(
        self, radar: int, updates: npt.NDArray[Any], plots: PlotArrays | npt.NDArray[Any]
    ) -> References:
        """Predictions at each plot's time that the plot has not updated (call before
        ``process`` on the same batch): from the other radars' local tracks, and from all
        local tracks of its system track (see ``References``)."""
        self._check_radar(radar)
        p = as_plot_arrays(plots)
        with_plot = updates[updates["plot_id"] >= 0]
        rows = self._local_rows(radar, with_plot, create=False)
        numbers = np.where(rows >= 0, self._loc["system"][np.maximum(rows, 0)], 0)
        fed = numbers > 0
        with_plot, numbers = with_plot[fed], numbers[fed]
        at = _positions(p.plot_id, with_plot["plot_id"])
        t = np.where(at >= 0, p.time[np.maximum(at, 0)], with_plot["time"])
        slots = self._slots(numbers)
        loc = self._loc
        s = np.maximum(slots, 0)
        recent = (slots >= 0) & (t[:, None] - loc["t_plot"][s] <= self.config.reference_age_s)
        others = recent & (loc["radar"][s] != radar)
        x_o, p_o = self._fuse(_compact_slots(slots, others), t)
        x_a, p_a = self._fuse(slots, t)
        seen = np.zeros((numbers.size, self.n_radars), dtype=bool)
        r, c = np.nonzero(recent)
        seen[r, loc["radar"][s[r, c]]] = True
        return References(
            plot_id=with_plot["plot_id"].astype(np.int64),
            system_number=numbers,
            time=t,
            others_valid=others.any(axis=1),
            others_xy=x_o[:, :2],
            others_P=p_o[:, :2, :2],
            others_v=x_o[:, 2:],
            all_xy=x_a[:, :2],
            all_P=p_a[:, :2, :2],
            radars_seen=seen,
        )


def _last_of_each(keys: IntArray) -> IntArray:
    """Index of the last occurrence of each distinct key (sorted by key)."""
    _, first_reversed = np.unique(keys[::-1], return_index=True)
    return keys.size - 1 - first_reversed


def _rank_within(group: IntArray) -> IntArray:
    """0, 1, ... in order of appearance among the equal values of ``group``."""
    order = np.argsort(group, kind="stable")
    sorted_group = group[order]
    start = np.searchsorted(sorted_group, sorted_group, side="left")
    rank = np.empty(group.size, dtype=np.int64)
    rank[order] = np.arange(group.size) - start
    return rank


def _positions(ids: IntArray, wanted: IntArray) -> IntArray:
    """Index in ``ids`` of each wanted id (-1: absent)."""
    if ids.size == 0:
        return np.full(wanted.shape, -1, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    pos = np.minimum(np.searchsorted(ids[order], wanted), ids.size - 1)
    return np.where(ids[order][pos] == wanted, order[pos], -1)


def _first_where(mask: BoolArray) -> IntArray:
    """Column of the first true entry per row (0 when none)."""
    return np.asarray(np.argmax(mask, axis=1), dtype=np.int64)


def _compact_slots(slots: IntArray, keep: BoolArray) -> IntArray:
    """The kept slots moved to the front of each row, order kept, -1 after them."""
    order = np.argsort(~keep, axis=1, kind="stable")
    out = np.take_along_axis(np.where(keep, slots, -1), order, axis=1)
    return out
