"""What the fuser's parts share: its configuration, its two tables, its clock's present
and its running counts. Each role (association, track life, estimators, references)
is a module of functions over a ``FusionState``."""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from tracker_service.fusion.config import FusionConfig
from tracker_service.fusion.table import Columns, LocalTrackTable, new_system_table
from tracker_service.tracking.daps import DapUpdate
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

if TYPE_CHECKING:
    from tracker_service.fusion.kernels import ModelConstants


@dataclass
class FusionStats:
    """Running counts since the fuser started."""

    batches: int = 0
    rows: int = 0
    system_tracks_created: int = 0
    system_tracks_ended: int = 0
    reassociations: int = 0
    exchanges: int = 0
    """Pairs of local tracks of one radar exchanged between two system tracks."""
    late_plots_skipped: int = 0
    unknown_plot_ids: int = 0
    numbers_reused_early: int = 0
    """System tracks founded under a number still within ``number_reuse_delay_s`` of its
    last track's end, the numbers past it having run out (``lifecycle.create``)."""
    numbers_exhausted: int = 0
    """Foundings put off because every system track number was live."""
    last_number_shortage: float = -math.inf
    """Data time of the latest founding that found no number past its reuse delay."""
    system_tracks_merged: int = 0
    out_of_line_updates: int = 0
    """Local-track updates refused by the clock: too far ahead of the fuser's clock or
    behind it (see ``tracking.clock``), e.g. a radar whose time is out of step."""
    clock_resyncs: int = 0
    dap_velocity_updates: int = 0
    """Plot-filter updates that took their plot's BDS 5,0 velocity (``plot_daps``)."""
    dap_turn_evidence: int = 0
    dap_velocity_gated_out: int = 0


NO_EVIDENCE = (0.0, 0.0, 0.0)
"""A pair's evidence (updates in a row, the running means of the exchange test's delta
and of its agreement) before its first test."""


FORGOTTEN = (*NO_EVIDENCE, -1.0)
"""``PairEvidence``'s entry of a pair it holds none of: older than any drop."""


SWEEP_MIN_PAIRS = 4096
"""``PairEvidence`` sweeps out its forgotten pairs once they may be half its entries, and
not below this many entries."""


class PairEvidence:
    """The exchange test's evidence per pair of local-track keys (low, high) of one radar
    (``associate._exchange``); compiled: in numba's typed dictionaries, read and written
    by kernels (``kernels.evidence_*``) a batch's pairs at a time.

    Forgetting is lazy: each dropped key holds the stamp of its latest drop, each entry
    the stamp of its latest write, and an entry counts only while it was written after
    both its keys' latest drops. A batch drops the pairs of its own tracks in one update
    of their keys, where a pass over each key's pairs (kept in sets of pairs per key)
    cost a tenth of the fuser on ``artas``, with some 80,000 pairs held. The entries
    that no longer count are swept out when the entries and drop stamps together have
    doubled since the last sweep (the drops count too: a site with few pairs still ends
    tracks, and ended keys are never reused); after a sweep every entry counts, and no
    drop before it matters."""

    def __init__(self, compiled: bool = False) -> None:
        self.compiled = compiled
        self._of_pair: Any
        self._dropped: Any
        if compiled:
            from tracker_service.fusion.kernels import new_pair_evidence  # numba on use

            self._of_pair, self._dropped = new_pair_evidence()
        else:
            self._of_pair, self._dropped = {}, {}
        self._stamp = 0
        self._sweep_at = SWEEP_MIN_PAIRS

    def table(self, low: IntArray, high: IntArray) -> FloatArray:
        """Each pair's evidence as a row (updates, mean, agreement), ``NO_EVIDENCE`` for
        a pair not tested before or forgotten since."""
        if self.compiled:
            from tracker_service.fusion.kernels import evidence_table

            return evidence_table(self._of_pair, self._dropped, low, high)
        pairs = list(zip(low.tolist(), high.tolist(), strict=True))
        found = map(self._of_pair.get, pairs, itertools.repeat(FORGOTTEN))
        flat = np.fromiter(itertools.chain.from_iterable(found), np.float64, 4 * len(pairs))
        rows = flat.reshape(-1, 4)
        dropped = [
            np.fromiter(map(self._dropped.get, keys.tolist(), itertools.repeat(-1)), np.float64)
            for keys in (low, high)
        ]
        rows[(rows[:, 3] <= dropped[0]) | (rows[:, 3] <= dropped[1]), :3] = NO_EVIDENCE
        return rows[:, :3]

    def renew(self, tested: IntArray, low: IntArray, high: IntArray, evidence: FloatArray) -> None:
        """Forget every pair with one of the keys ``tested``, then hold each pair's
        evidence (k, 3), in order (the pairs a batch's tested tracks found)."""
        self._stamp += 2
        if self.compiled:
            from tracker_service.fusion.kernels import evidence_renew

            held = evidence_renew(
                self._of_pair, self._dropped, self._stamp, tested, low, high, evidence
            )
        else:
            self._dropped.update(zip(tested.tolist(), itertools.repeat(self._stamp - 1)))
            stamp = float(self._stamp)
            self._of_pair.update(
                zip(
                    zip(low.tolist(), high.tolist(), strict=True),
                    ((*e, stamp) for e in evidence.tolist()),
                    strict=True,
                )
            )
            held = len(self._of_pair) + len(self._dropped)
        self._sweep_if(held)

    def update(
        self,
        tested: IntArray,
        low: IntArray,
        high: IntArray,
        deltas: FloatArray,
        favoured: BoolArray,
        window: int,
    ) -> FloatArray:
        """One batch's exchange test: each pair's evidence (updates, mean of ``deltas``,
        agreement: the share of ``favoured``, both running means over ``window``
        updates) from the evidence it holds, then ``renew``'s forgetting and writes;
        returns the evidence now (k, 3). Compiled: one kernel (``evidence_update``), the
        arithmetic of the numpy path below element by element: the same bits."""
        if self.compiled:
            from tracker_service.fusion.kernels import evidence_update

            self._stamp += 2
            now, held = evidence_update(
                self._of_pair,
                self._dropped,
                self._stamp,
                tested,
                low,
                high,
                deltas,
                favoured,
                float(window),
            )
            self._sweep_if(held)
            return now
        before = self.table(low, high)
        now = np.zeros((low.size, 3))
        n = before[:, 0] + 1.0
        weight = 1.0 / np.minimum(n, window)
        now[:, 0] = n
        now[:, 1] = before[:, 1] + (deltas - before[:, 1]) * weight
        now[:, 2] = before[:, 2] + (favoured.astype(np.float64) - before[:, 2]) * weight
        self.renew(tested, low, high, now)
        return now

    def drop(self, keys: IntArray) -> None:
        """Forget every pair with one of ``keys``. Dropping none changes nothing (the
        stamps only order the writes and drops): no call."""
        if keys.size == 0:
            return
        self._stamp += 1
        if self.compiled:
            from tracker_service.fusion.kernels import evidence_drop

            self._sweep_if(evidence_drop(self._of_pair, self._dropped, self._stamp, keys))
            return
        self._dropped.update(zip(keys.tolist(), itertools.repeat(self._stamp)))
        self._sweep_if(len(self._of_pair) + len(self._dropped))

    def _sweep_if(self, held: int) -> None:
        """Sweep when the entries and drop stamps ``held`` have doubled since the last."""
        if held >= self._sweep_at:
            self.sweep()

    @property
    def held(self) -> int:
        """Entries and drop stamps held (what the sweep bounds)."""
        return len(self._of_pair) + len(self._dropped)

    def sweep(self) -> None:
        """The entries that no longer count swept out now (what ``_sweep_if`` does when
        the evidence has doubled: the warm-up calls it, as 30 aircraft never get there)."""
        if self.compiled:
            from tracker_service.fusion.kernels import evidence_sweep

            evidence_sweep(self._of_pair, self._dropped)
        else:
            dropped = self._dropped
            self._of_pair = {
                pair: entry
                for pair, entry in self._of_pair.items()
                if entry[3] > dropped.get(pair[0], -1) and entry[3] > dropped.get(pair[1], -1)
            }
            dropped.clear()
        self._sweep_at = max(2 * len(self._of_pair), SWEEP_MIN_PAIRS)


@dataclass
class FusionState:
    config: FusionConfig
    n_radars: int
    models: ModelSet
    stats: FusionStats = field(default_factory=FusionStats)
    local: LocalTrackTable = field(init=False)
    sys: Columns = field(init=False)
    """The system-track table (``table.system_dtype``), indexed by number."""
    now: float = -np.inf
    """The fuser's clock at the batch in hand."""
    merge_counts: dict[tuple[int, int], int] = field(default_factory=dict)
    """Consecutive joint gate passes of each pair of system tracks (track life's merge)."""
    exchange_evidence: PairEvidence = field(init=False)
    """Per pair of local-track keys of one radar in two system tracks."""

    @property
    def compiled(self) -> bool:
        """The compiled kernels (``fusion/kernels.py``) rather than the numpy reference."""
        return self.config.implementation == "compiled"

    @cached_property
    def model_constants(self) -> ModelConstants:
        """The plot filter's models as the kernels take them (numba imported on first use)."""
        from tracker_service.fusion.kernels import ModelConstants

        return ModelConstants(self.models)

    @cached_property
    def daps(self) -> DapUpdate | None:
        """The plot filter's DAP step (``fusion.plot_daps``), None unless ``use_daps``."""
        if not self.config.use_daps:
            return None
        return DapUpdate(self.config.plot_filter, self.models, self.stats)

    @cached_property
    def reach_constants(self) -> tuple[float, float]:
        """The pre-selection's bounds of a track's motion (``nearby.py``): the largest
        process noise of the models and of the constant-velocity prediction, and the
        largest turn rate (rad/s) of the models. Cached: two numpy reductions a call,
        in each of the exchange test's, association's and merging's pre-selections."""
        return (
            max(float(self.models.q.max()), self.config.q),
            float(np.abs(self.models.turn_rates_rad_s).max()),
        )

    def __post_init__(self) -> None:
        self.local = LocalTrackTable(self.models.n_models, self.n_radars, compiled=self.compiled)
        self.sys = new_system_table(self.models.n_models, self.n_radars)
        self.exchange_evidence = PairEvidence(self.compiled)
