"""System-track life: creation by a confirmed local track that joined none (or waited
long enough beside a system track with its identity), joining, merging of duplicates,
orphans (a system track whose last local track ended coasts for
``FusionConfig.orphan_coast_s``, which a new local track may take up again), ending
(an orphan's coast over, silent, or left in an abandoned future), and number reuse."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import consider, nearby
from tracker_service.fusion.arrays import among, is_member, kernel_indices, marked_numbers
from tracker_service.fusion.associate import compatible_pairs
from tracker_service.fusion.config import FusionConfig
from tracker_service.fusion.estimator import SystemEstimator
from tracker_service.fusion.estimator_tracks import cv_prediction
from tracker_service.fusion.messages import (
    COASTING,
    ENDED,
    MAX_SYSTEM_NUMBER,
    SYSTEM_UPDATE_DTYPE,
)
from tracker_service.fusion.ml import predict_cv
from tracker_service.fusion.rows import joined, system_rows
from tracker_service.fusion.state import FusionState, FusionStats
from tracker_service.tracking.models import cv_transition
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, is_shared_code


def may_found(state: FusionState, candidates: IntArray) -> BoolArray:
    """A local track that found no system track founds one, unless a live system
    track carries its Mode S address or its (not shared) Mode 3/A code: then it is
    most likely that aircraft, seen apart while the biases are still unknown, and it
    waits up to ``FusionConfig.found_delay_s`` for the gate to take it (a second
    aircraft with a duplicated address or code founds its own after that)."""
    loc = state.local.rows
    waiting = np.isnan(loc["t_founder"][candidates])
    loc["t_founder"][candidates[waiting]] = state.now
    address, code = loc["address"][candidates], loc["mode3a"][candidates]
    address_used, code_used = _identities_in_use(state, address, code)
    known = (address_used & (address >= 0)) | (code_used & (code >= 0) & ~is_shared_code(code))
    waited = state.now - loc["t_founder"][candidates]
    return np.asarray(~known | (waited >= state.config.found_delay), dtype=bool)


def _identities_in_use(
    state: FusionState, address: IntArray, code: IntArray
) -> tuple[BoolArray, BoolArray]:
    """Whether a live system track carries each Mode S address, and each Mode 3/A code;
    compiled: one pass over the system table (``kernels.identities_in_use``) where the
    numpy path gathers every live track's address and code."""
    sys = state.sys
    if state.compiled:
        from tracker_service.fusion.kernels import identities_in_use  # numba when compiled

        return identities_in_use(
            kernel_indices(address),
            kernel_indices(code),
            sys["alive"],
            sys["address"],
            sys["mode3a"],
        )
    live = sys["alive"].copy()
    live[0] = False
    return among(address, sys["address"][live]), among(code, sys["mode3a"][live])


def create(state: FusionState, estimator: SystemEstimator, founders: IntArray) -> IntArray:
    """A system track per founding local track (rows), under the lowest free numbers
    whose reuse delay has passed; returns the numbers. When those run short, the numbers
    still within their delay are taken, the longest ended first (counted as
    ``numbers_reused_early``): a display may show a number again sooner than the delay
    promises, but no aircraft goes without a system track while a number is idle. Only
    with every number live does a founder wait (``numbers_exhausted``)."""
    sys = state.sys
    numbers = _free_numbers(state, founders.size)
    founders = founders[: numbers.size]
    if numbers.size == 0:
        return numbers
    if state.compiled:
        _found_compiled(state, estimator, numbers, founders)
    else:
        _found(state, estimator, numbers, founders)
    nearby.refresh(sys, numbers, state.compiled)
    state.local.feed(founders, numbers)
    state.stats.system_tracks_created += int(numbers.size)
    return numbers


def _free_numbers(state: FusionState, k: int) -> IntArray:
    """``create``'s numbers for k founders (fewer only with every number live): the
    lowest free ones whose reuse delay has passed, then those still within it, the
    longest ended first; compiled, the pass over the table stops at the k-th due one."""
    sys = state.sys
    delay = state.config.number_reuse_delay_s
    if state.compiled:
        from tracker_service.fusion.kernels import due_numbers  # numba when compiled

        free = due_numbers(sys["alive"], sys["freed_at"], state.now, delay, k)
        if free.size == k:
            return free
    # A number freed "later" than now (the clock came back from a jump) waits its
    # delay from now, not from a time that never was.
    ended = np.minimum(sys["freed_at"], state.now)
    idle = ~sys["alive"]
    idle[0] = False
    due = ended + delay <= state.now
    free = np.flatnonzero(idle & due)
    if free.size < k:
        state.stats.last_number_shortage = state.now
        waiting = np.flatnonzero(idle & ~due)
        early = waiting[np.argsort(ended[waiting], kind="stable")]
        early = early[: k - free.size]
        state.stats.numbers_reused_early += int(early.size)
        free = np.concatenate([free, early])
    if free.size < k:
        state.stats.numbers_exhausted += int(k - free.size)
    return free[:k]


def _found(
    state: FusionState, estimator: SystemEstimator, numbers: IntArray, founders: IntArray
) -> None:
    """``create``'s writes: each system track from its founding local track, whose
    tests start again (it joins the track by ``LocalTrackTable.feed``)."""
    sys, loc = state.sys, state.local.rows
    sys["alive"][numbers] = True
    sys["born"][numbers] = state.now
    sys["solo"][numbers] = True
    sys["orphaned"][numbers] = np.nan
    sys["t_row"][numbers] = -np.inf
    sys["row_interval"][numbers] = np.nan
    sys["fl"][numbers] = np.nan
    sys["t"][numbers] = loc["t"][founders]
    sys["x"][numbers] = loc["x"][founders]
    sys["P"][numbers] = loc["P"][founders]
    radars = loc["radar"][founders]
    sys["founder_radar"][numbers] = radars
    sys["B"][numbers] = 0.0
    sys["B"][numbers, radars] = loc["extra"][founders]
    sys["M"][numbers] = 0.0
    if estimator.founder_carries_bias:
        sys["M"][numbers, radars] = consider.POSITION
    sys["mM"][numbers] = sys["M"][numbers][:, None]
    sys["t_plot"][numbers] = loc["t_plot"][founders]
    sys["address"][numbers] = loc["address"][founders]
    sys["mode3a"][numbers] = loc["mode3a"][founders]
    sys["mx"][numbers] = loc["x"][founders][:, None, :]
    sys["mP"][numbers] = loc["P"][founders][:, None, :, :]
    mu = loc["mu"][founders]
    known = mu.sum(axis=1) > 0.0
    sys["mu"][numbers] = np.where(known[:, None], mu, state.models.initial_probabilities)
    loc["fails"][founders] = 0
    loc["nis_n"][founders] = 0
    loc["t_founder"][founders] = np.nan


def _found_compiled(
    state: FusionState, estimator: SystemEstimator, numbers: IntArray, founders: IntArray
) -> None:
    """``_found`` in one kernel call (``kernels.found_system_tracks``; some forty numpy
    writes a founding batch cost more than the founding's arithmetic)."""
    from tracker_service.fusion.kernels import found_system_tracks  # numba when compiled

    sys, loc = state.sys, state.local.rows
    founder_bias = consider.POSITION if estimator.founder_carries_bias else np.zeros((4, 2))
    found_system_tracks(
        kernel_indices(numbers),
        kernel_indices(founders),
        state.now,
        np.ascontiguousarray(founder_bias, dtype=np.float64),
        np.ascontiguousarray(state.models.initial_probabilities, dtype=np.float64),
        *(sys[name] for name in FOUNDED_SYSTEM_FIELDS),
        *(loc[name] for name in FOUNDING_LOCAL_FIELDS),
    )


FOUNDED_SYSTEM_FIELDS = (
    "alive",
    "born",
    "solo",
    "orphaned",
    "t_row",
    "row_interval",
    "fl",
    "t",
    "x",
    "P",
    "founder_radar",
    "B",
    "M",
    "mM",
    "t_plot",
    "address",
    "mode3a",
    "mx",
    "mP",
    "mu",
)
"""The system table's fields ``kernels.found_system_tracks`` writes, in its order."""

FOUNDING_LOCAL_FIELDS = (
    "t",
    "x",
    "P",
    "radar",
    "extra",
    "t_plot",
    "address",
    "mode3a",
    "mu",
    "fails",
    "nis_n",
    "t_founder",
)
"""The local table's fields it reads and writes, in its order."""

NUMBER_SHORTAGE_SHOWN_S = 60.0
"""How long (data time) the status says the numbers ran short after they last did."""


def number_shortage_reasons(stats: FusionStats, config: FusionConfig, now: float) -> list[str]:
    """The status's reason line while system track numbers ran short in the last
    ``NUMBER_SHORTAGE_SHOWN_S``: more tracks ended within ``number_reuse_delay_s`` than
    the numbers beside the live tracks allow (``create``)."""
    # Not "> shown": before any data both times are -inf, and their difference NaN.
    if not now - stats.last_number_shortage <= NUMBER_SHORTAGE_SHOWN_S:
        return []
    return [
        f"fusion: system track numbers ran short: {stats.numbers_reused_early} track(s) "
        "founded under a number ended less than [fusion] number_reuse_delay_s "
        f"({config.number_reuse_delay_s:g} s) ago, {stats.numbers_exhausted} founding "
        f"attempt(s) put off with all {MAX_SYSTEM_NUMBER} numbers live (since start): shorten the "
        "delay if tracks end this often"
    ]


def join(state: FusionState, radar: int, joined: IntArray, target: IntArray) -> None:
    """Attach local tracks to system tracks; a stale local track of the same radar on
    that system track (coasting: the local tracker restarted the aircraft) leaves. An
    orphan taken up by a new track of the radar that alone fed it stays solo: it follows
    its one local track again, as a system track that track founded would."""
    loc, sys = state.local.rows, state.sys
    if joined.size == 0:
        return
    state.local.feed(state.local.radar_feeders(target, radar), 0)
    state.local.feed(joined, target)
    orphaned = ~np.isnan(sys["orphaned"][target])
    sys["solo"][target] &= orphaned & (sys["founder_radar"][target] == radar)
    sys["orphaned"][target] = np.nan
    loc["fails"][joined] = 0
    loc["nis_n"][joined] = 0  # the consistency test starts again (associate._consistency)
    loc["t_founder"][joined] = np.nan
    sys["t_plot"][target] = np.maximum(sys["t_plot"][target], loc["t_plot"][joined])


def merge(state: FusionState, radar: int, touched: IntArray) -> npt.NDArray[Any]:
    """Merge each touched system track with a live one it duplicates (see
    ``FusionConfig.merge_after``); returns the ended rows of the merged-away ones."""
    sys = state.sys
    touched = touched[(touched > 0) & sys["alive"][touched]]
    # A pair's count lives while every check of it passes: the checks of the touched
    # tracks start from the counts of their pairs that pass again now.
    touched_set = set(touched.tolist())
    counts = {
        p: c
        for p, c in state.merge_counts.items()
        if p[0] not in touched_set and p[1] not in touched_set
    }
    pair_a, pair_b, d2 = _merge_tests(state, touched)
    passing = d2 <= state.config.gate
    if not passing.any():
        # Mostly (artas: in each of 7,000 batches): no pass over the local tracks follows.
        state.merge_counts = counts
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    radars_of = _radars_feeding(state)
    young: list[int] = []
    old: list[int] = []
    for a, b in zip(pair_a[passing].tolist(), pair_b[passing].tolist(), strict=True):
        pair = (min(a, b), max(a, b))
        count = counts[pair] = state.merge_counts.get(pair, 0) + 1
        # A track that took another in this batch now holds that one's radars too: two
        # local tracks of one radar are two aircraft, never one system track (a radar's
        # two tracks that founded together next to a third radar's system track merged
        # both into it: `encounters` seed 2, CLIMB primary only).
        shared = bool(np.any(radars_of[a] & radars_of[b]))
        if count >= state.config.merge_after and a not in young and b not in young and not shared:
            keep, leave = (a, b) if sys["born"][a] <= sys["born"][b] else (b, a)
            old.append(keep)
            young.append(leave)
            radars_of[keep] |= radars_of[leave]
    gone = set(young)
    state.merge_counts = {p: c for p, c in counts.items() if not gone & set(p)}
    if not young:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    leaving = np.array(young, dtype=np.int64)
    ended = end(state, radar, leaving, moved_to=np.array(old, dtype=np.int64))
    state.stats.system_tracks_merged += len(young)
    return ended


def _radars_feeding(state: FusionState) -> npt.NDArray[np.bool_]:
    """Whether each radar feeds each system track (MAX_SYSTEM_NUMBER + 1, radars): by one
    of its live local tracks."""
    loc = state.local.used
    if state.compiled:
        from tracker_service.fusion.kernels import radars_feeding  # numba only when compiled

        return radars_feeding(
            loc["alive"], loc["system"], loc["radar"], MAX_SYSTEM_NUMBER + 1, state.n_radars
        )
    fed = loc["alive"] & (loc["system"] > 0)
    radars_of = np.zeros((MAX_SYSTEM_NUMBER + 1, state.n_radars), dtype=bool)
    radars_of[loc["system"][fed], loc["radar"][fed]] = True
    return radars_of


def _merge_tests(state: FusionState, touched: IntArray) -> tuple[IntArray, IntArray, FloatArray]:
    """Each touched system track a against the live ones b that no radar feeds both and
    whose identities do not tell apart, near enough to pass (``_merge_candidates``): the
    4-dof distance at a's time, b predicted there, their errors differing by their
    different shares of each radar's bias. Pairs in the order of (a, b)."""
    sys, cfg = state.sys, state.config
    empty = np.zeros(0, dtype=np.int64)
    a, b = _merge_candidates(state, touched)
    if a.size == 0:
        return empty, empty, np.zeros(0)
    # The radars' table (a pass over the local tracks) for the few pairs left, if any.
    radars_of = _radars_feeding(state)
    apart = ~np.any(radars_of[a] & radars_of[b], axis=1)
    a, b = a[apart], b[apart]
    if a.size == 0:
        return empty, empty, np.zeros(0)
    dt = sys["t"][a] - sys["t"][b]
    xs, ps = predict_cv(sys["x"][b], sys["P"][b], dt, cfg.q)
    d = xs - sys["x"][a]
    m = np.einsum("kab,klbc->klac", cv_transition(dt), sys["M"][b]) - sys["M"][a]
    larger = np.trace(sys["B"][b], axis1=-2, axis2=-1) > np.trace(sys["B"][a], axis1=-2, axis2=-1)
    bias = np.where(larger[..., None, None], sys["B"][b], sys["B"][a])
    s = ps + sys["P"][a] + consider.bias_share(m, bias)
    d2 = np.einsum("ka,ka->k", d, np.linalg.solve(s, d[..., None])[..., 0])
    return a, b, d2


def _merge_candidates(state: FusionState, touched: IntArray) -> tuple[IntArray, IntArray]:
    """The pairs (a touched system track, a live fed one) near enough for merging's test
    to pass (``nearby.py``) whose identities do not tell them apart, in the order of
    (a, b); compiled: in one call (``kernels.merge_candidates``), the same pairs."""
    sys, cfg = state.sys, state.config
    empty = np.zeros(0, dtype=np.int64)
    q, turn = state.reach_constants
    if state.compiled:
        from tracker_service.fusion.kernels import merge_candidates  # numba when compiled

        return merge_candidates(
            sys["alive"],
            sys["orphaned"],
            sys["t"],
            sys["x"],
            sys["P"],
            sys["moments"],
            sys["sensitivity"],
            sys["largest_bias"],
            sys["address"],
            sys["mode3a"],
            kernel_indices(touched),
            cfg.gate,
            q,
            turn,
        )
    # An orphan is taken up through the gate only (``associate.assign``), where its
    # identity must agree: merged, its number would pass to a track it never gated.
    alive = np.flatnonzero(sys["alive"] & np.isnan(sys["orphaned"]))
    alive = _identity_candidates(state, touched, alive[alive > 0])
    if touched.size == 0 or alive.size == 0:
        return empty, empty
    t_mid, spread = nearby.time_span(sys["t"][touched])
    b_max = max(
        nearby.system_largest_bias(sys, alive, False),
        nearby.system_largest_bias(sys, touched, False),
    )

    def reach(numbers: IntArray) -> tuple[FloatArray, FloatArray]:
        # The latest output state (x, P), which merging's test predicts from.
        return nearby.system_reach(
            sys, numbers, False, 2.0 * b_max, t_mid, spread, cfg.gate, q, turn, False
        )

    i, j = nearby.near_pairs(*reach(touched), *reach(alive))
    a, b = touched[i], alive[j]
    same = (a != b) & compatible_pairs(state, a, b)
    return a[same], b[same]


def _identity_candidates(state: FusionState, touched: IntArray, alive: IntArray) -> IntArray:
    """The live tracks that some touched track's address and some touched track's code
    do not tell apart from it: a cheap superset of the pairs ``compatible_pairs`` keeps
    (with Mode S traffic, mostly the tracks of the touched tracks' own addresses)."""
    sys = state.sys
    if state.compiled:
        from tracker_service.fusion.kernels import identity_candidates  # numba when compiled

        return identity_candidates(
            sys["address"], sys["mode3a"], kernel_indices(touched), kernel_indices(alive)
        )
    address, code = sys["address"][touched], sys["mode3a"][touched]
    other_address, other_code = sys["address"][alive], sys["mode3a"][alive]
    address_ok = (other_address < 0) | is_member(other_address, address) | bool((address < 0).any())
    code_ok = (other_code < 0) | is_member(other_code, code) | bool((code < 0).any())
    return alive[address_ok & code_ok]


def orphan(state: FusionState, radar: int, numbers: IntArray) -> npt.NDArray[Any]:
    """System tracks (among ``numbers``) left without any local track become orphans,
    coasting from now (``coast_orphans``); with ``orphan_coast_s`` 0 they end at once
    (their rows returned)."""
    sys = state.sys
    numbers = numbers[numbers > 0]
    numbers = numbers[sys["alive"][numbers] & np.isnan(sys["orphaned"][numbers])]
    if numbers.size == 0:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)  # no pass over the table for none
    # Fed: a first slot (a live local track feeding it); compiled, one pass over the
    # table for the few numbers.
    orphans = numbers[state.local.slots(numbers, 1)[:, 0] < 0]
    if state.config.orphan_coast <= 0:
        return end(state, radar, orphans)
    sys["orphaned"][orphans] = state.now
    return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)


def expire(state: FusionState, radar: int) -> npt.NDArray[Any]:
    """The orphans' coasting and last rows (``coast_orphans``), and the silent system
    tracks' ends: system tracks none of whose local tracks had a plot for ``silence_s``
    (orphans at the end of their own coast instead). Both sets from one pass over the
    system table, compiled (``kernels.expiring``): the orphans' coast changes neither
    (an orphan ending leaves both sets, as it was in none of the silent)."""
    sys = state.sys
    silent_before = state.now - state.config.silence_s
    if state.compiled:
        from tracker_service.fusion.kernels import expiring  # numba only when compiled

        silent, orphans = expiring(sys["alive"], sys["orphaned"], sys["t_plot"], silent_before)
    else:
        fed = np.isnan(sys["orphaned"])
        silent = np.flatnonzero(sys["alive"] & fed & (sys["t_plot"] < silent_before))
        orphans = np.flatnonzero(sys["alive"] & ~fed)
    return joined([coast_orphans(state, radar, orphans), end(state, radar, silent)])


def coast_orphans(state: FusionState, radar: int, orphans: IntArray) -> npt.NDArray[Any]:
    """Rows of the ``orphans`` (every live orphaned system track) at the fuser's clock,
    their latest state extrapolated in a straight line (an ATC display's coasting
    track): the last row of those whose ``orphan_coast_s`` is over, which end; a coasting
    row of those due one (``due``). The gate that takes an orphan up predicts it so too
    (``associate.assign``). Not the "plots" IMM's prediction: its turn models, averaged,
    slow the mean down (a 160 m/s aircraft leaving cover coasted at 60 m/s after 60 s,
    three_sites seed 102)."""
    sys, now = state.sys, state.now
    if state.config.orphan_coast <= 0 or orphans.size == 0:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)  # off: no orphan
    over = now >= sys["orphaned"][orphans] + state.config.orphan_coast
    ending, coasting = orphans[over], orphans[~over & due(state, orphans)]
    out = [
        _predicted_rows(state, radar, coasting, COASTING),
        _predicted_rows(state, radar, ending, ENDED),
    ]
    _release(state, ending)
    published(state, out[0])
    return joined(out)


def due(state: FusionState, numbers: IntArray) -> BoolArray:
    """The system tracks whose next row is due: at the interval of their latest two rows
    (a lone radar's period, the shorter interval of several radars), between
    ``MIN_ROW_INTERVAL_S`` and ``longest_period_s``."""
    sys = state.sys
    interval = np.nan_to_num(sys["row_interval"][numbers], nan=state.config.longest_period_s)
    interval = np.clip(interval, MIN_ROW_INTERVAL_S, state.config.longest_period_s)
    return np.asarray(state.now >= sys["t_row"][numbers] + interval, dtype=bool)


MIN_ROW_INTERVAL_S = 1.0
"""An orphan's coasting rows come at most this often (a track fed by several radars is
published at each of their updates: a fraction of a second apart at times)."""


def published(state: FusionState, rows: npt.NDArray[Any]) -> None:
    """Note the rows of distinct system tracks: the pace of their rows, which an
    orphan's coasting rows keep (``due``), and their flight level, which its rows carry
    on (with no local track left to give it). Nothing to note with orphans off."""
    if state.config.orphan_coast <= 0:
        return
    sys = state.sys
    rows = rows[rows["time"] > sys["t_row"][rows["system_number"]]]
    numbers, t = rows["system_number"], rows["time"]
    sys["row_interval"][numbers] = t - sys["t_row"][numbers]
    sys["t_row"][numbers] = t
    level = rows[np.isfinite(rows["flight_level"])]
    numbers = level["system_number"]
    sys["fl"][numbers] = level["flight_level"]
    sys["rate"][numbers] = np.nan_to_num(level["climb_rate_fl_per_s"])
    sys["t_fl"][numbers] = level["time"]


def _predicted_rows(
    state: FusionState, radar: int, numbers: IntArray, status: int
) -> npt.NDArray[Any]:
    sys, now = state.sys, state.now
    if numbers.size == 0:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    t = np.full(numbers.size, now)
    x, p, moved = cv_prediction(state, numbers, t - sys["t"][numbers])
    p = p + consider.bias_share(moved, sys["B"][numbers])
    out = system_rows(
        state,
        numbers,
        t,
        x,
        p,
        np.full(numbers.size, status, dtype=np.int8),
        state.local.slots(numbers, state.config.max_sources),
    )
    out["radar"] = radar
    known = np.isfinite(sys["fl"][numbers])
    n = numbers[known]
    out["flight_level"][known] = sys["fl"][n] + sys["rate"][n] * (now - sys["t_fl"][n])
    out["climb_rate_fl_per_s"][known] = sys["rate"][n]
    return out


def end_future(state: FusionState, radar: int, max_ahead_s: float) -> npt.NDArray[Any]:
    """Every radar's time jumped for good and the clock followed (``state.now``). Back in
    time, what lies in the abandoned future ends (its rows returned), and no number
    stays blocked or track waits for longer than its delay from the new present."""
    now = state.now
    sys, loc = state.sys, state.local.used
    sys["freed_at"] = np.minimum(sys["freed_at"], now)
    sys["orphaned"] = np.minimum(sys["orphaned"], now)  # NaN (fed) stays NaN
    sys["t_row"] = np.minimum(sys["t_row"], now)
    loc["t_founder"] = np.where(loc["t_founder"] > now, now, loc["t_founder"])
    future = np.flatnonzero(sys["alive"] & (sys["t_plot"] > now + max_ahead_s))
    return end(state, radar, future[future > 0])


def end(
    state: FusionState, radar: int, numbers: IntArray, moved_to: IntArray | None = None
) -> npt.NDArray[Any]:
    """End the system tracks ``numbers``; their local tracks go to ``moved_to`` (one
    per number: a merge) or leave."""
    sys = state.sys
    if numbers.size == 0:
        return np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
    out = system_rows(
        state,
        numbers,
        sys["t"][numbers],
        sys["x"][numbers],
        sys["P"][numbers] + consider.bias_share(sys["M"][numbers], sys["B"][numbers]),
        np.full(numbers.size, ENDED, dtype=np.int8),
        state.local.slots(numbers, state.config.max_sources),
    )
    out["radar"] = radar
    _release(state, numbers, moved_to)
    return out


def _release(state: FusionState, numbers: IntArray, moved_to: IntArray | None = None) -> None:
    """The bookkeeping of ``end``: the numbers freed, their local tracks moved or gone."""
    sys = state.sys
    loc = state.local.used
    if moved_to is None:
        state.local.feed(np.flatnonzero(marked_numbers(numbers)[loc["system"]]), 0)
    else:
        for number, target in zip(numbers.tolist(), moved_to.tolist(), strict=True):
            state.local.feed(np.flatnonzero(loc["system"] == number), target)
        sys["solo"][moved_to] = False
    sys["alive"][numbers] = False
    sys["freed_at"][numbers] = state.now
    sys["orphaned"][numbers] = np.nan
    state.stats.system_tracks_ended += int(numbers.size)
