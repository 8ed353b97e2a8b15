"""The system tracker: local tracks of several radars to one system track per aircraft.

``SystemTracker`` composes the fuser's roles, each a module of functions over one
``FusionState`` (``state.py``): the local-track and system-track tables (``table.py``),
association of local tracks with system tracks (``associate.py``), system-track life
(``lifecycle.py``: creation, joining, merging, ending, number reuse), the estimator
``FusionConfig.method`` names (``estimator.py``: "tracks" or "plots"), the output rows
(``rows.py``) and the bias estimator's references (``references.py``). Per batch the work
is vectorised over the batch's local tracks and the system tracks they touch.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import associate, lifecycle, rows
from tracker_service.fusion.arrays import is_member, marked_numbers
from tracker_service.fusion.config import FusionConfig
from tracker_service.fusion.estimator import make_system_estimator
from tracker_service.fusion.references import References, references
from tracker_service.fusion.state import FusionState, FusionStats
from tracker_service.fusion.table import Columns
from tracker_service.tracking.clock import DataClock
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    BoolArray,
    FloatArray,
    IntArray,
    PlotArrays,
    as_plot_arrays,
)
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED

__all__ = ["FusionStats", "References", "SystemTracker"]


class SystemTracker:
    """Feed ``process`` one radar's batch of local-track updates at a time; it returns the
    system-track rows (``SYSTEM_UPDATE_DTYPE``) of the batch."""

    def __init__(self, n_radars: int, config: FusionConfig | None = None) -> None:
        if n_radars < 1:
            raise ValueError(f"n_radars must be >= 1, not {n_radars!r}")
        config = config or FusionConfig()
        self.state = FusionState(config, n_radars, ModelSet.from_config(config.plot_filter))
        self.estimator = make_system_estimator(config.method)
        # Ahead: the radars' data interleave within a scan; behind: an update older than
        # the silence would found a system track only to end it at once.
        self.clock = DataClock(
            config.longest_period_s,
            config.silence_s,
            resync_span_s=2.0 * config.longest_period_s,
        )

    @property
    def n_radars(self) -> int:
        return self.state.n_radars

    @property
    def config(self) -> FusionConfig:
        return self.state.config

    @property
    def models(self) -> ModelSet:
        return self.state.models

    @property
    def stats(self) -> FusionStats:
        return self.state.stats

    @property
    def _sys(self) -> Columns:
        return self.state.sys

    @property
    def system_tracks(self) -> IntArray:
        """The numbers of the live system tracks."""
        return np.flatnonzero(self.state.sys["alive"])

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
        state, table = self.state, self.state.local
        state.stats.batches += 1
        order = np.argsort(updates["time"], kind="stable")
        u = updates[order]
        extra = np.zeros((len(u), 2, 2)) if extra_R is None else np.asarray(extra_R)[order]
        if len(u) == 0:
            return lifecycle.expire(state, radar)
        step = self.clock.step(u["time"])
        out = [self._resynchronised(radar)] if step.resynchronised else []
        if not step.accepted.all():
            state.stats.out_of_line_updates += int(np.count_nonzero(~step.accepted))
            u, extra = u[step.accepted], extra[step.accepted]
            if len(u) == 0:
                return rows.joined([*out, lifecycle.expire(state, radar)])
        state.now = self.clock.now
        local_rows = table.find(radar, u)
        known = local_rows >= 0
        if not known.all():
            u, extra, local_rows = u[known], extra[known], local_rows[known]
        has_plot = u["plot_id"] >= 0
        table.store(local_rows, u, extra, has_plot)
        touched = np.unique(local_rows)
        old_system = table.rows["system"][touched].copy()
        created = self._associate(radar, touched, has_plot, local_rows)
        self.estimator.absorb(
            state, radar, local_rows, u, extra, has_plot, as_plot_arrays(plots), created
        )
        merged = lifecycle.merge(state, radar, np.unique(table.rows["system"][local_rows]))
        systems = table.rows["system"][local_rows]
        fed_rows = systems > 0
        # Emitted before the deleted local tracks leave: their last state still counts.
        batch = (systems, u, has_plot)
        if not fed_rows.all():
            batch = (systems[fed_rows], u[fed_rows], has_plot[fed_rows])
        fed = rows.emit(state, self.estimator, radar, *batch)
        lifecycle.published(state, fed)
        out += [merged, fed]
        table.remove(touched[table.rows["status"][touched] == LOCAL_DELETED])
        # A system track that a touched local track still feeds is no orphan: only those
        # the batch's tracks left take the pass over the table (mostly none).
        left = marked_numbers(old_system)
        left[systems] = True
        left[table.rows["system"][touched]] = False
        out.append(lifecycle.orphan(state, radar, np.flatnonzero(left)))
        out.append(lifecycle.expire(state, radar))
        table.compact()
        result = rows.joined(out)
        state.stats.rows += len(result)
        return result

    def references(
        self,
        radar: int,
        updates: npt.NDArray[Any],
        plots: PlotArrays | npt.NDArray[Any],
        sources: int | None = None,
        *,
        everyone: bool = True,
    ) -> References:
        """Predictions at each plot's time that the plot has not updated (call before
        ``process`` on the same batch): from the other radars' local tracks, and from all
        local tracks of its system track (see ``References``); ``sources``: only the
        sources below this index serve (the radars, not ADS-B: fusion/adsb_source.py);
        ``everyone`` False: the others' predictions only (the one from all local tracks
        is a second fusion per row, which only the macro bias filter takes)."""
        self._check_radar(radar)
        return references(self.state, radar, updates, as_plot_arrays(plots), sources, everyone)

    def _associate(
        self, radar: int, touched: IntArray, has_plot: BoolArray, local_rows: IntArray
    ) -> IntArray:
        """Keep, drop or find the system track of each local track of the batch; create
        system tracks for confirmed local tracks that found none. Returns the numbers
        of the system tracks created."""
        state = self.state
        live = associate.review(state, self.estimator, touched)
        loc = state.local.rows
        # ``live`` is sorted and distinct (of ``np.unique``): membership tests keep it
        # so, as ``np.intersect1d`` and ``np.setdiff1d`` would at several times the cost
        # on a batch's few rows.
        unfed = live[loc["system"][live] == 0]
        free = unfed[is_member(unfed, local_rows[has_plot])]
        if free.size == 0:
            return np.zeros(0, dtype=np.int64)
        joined, target, waiting = associate.assign(state, self.estimator, radar, free)
        lifecycle.join(state, radar, joined, target)
        rest = free[~is_member(free, np.concatenate([joined, waiting]))]
        return lifecycle.create(state, self.estimator, rest[lifecycle.may_found(state, rest)])

    def _resynchronised(self, radar: int) -> npt.NDArray[Any]:
        self.state.stats.clock_resyncs += 1
        self.state.now = self.clock.now
        return lifecycle.end_future(self.state, radar, self.clock.max_ahead_s)

    def _check_radar(self, radar: int) -> None:
        if not 0 <= radar < self.n_radars:
            raise ValueError(f"radar must be in 0..{self.n_radars - 1}, not {radar!r}")
