"""Association of local tracks with system tracks: a 4-dof chi-square gate at the local
track's time (the residual biases of both in its covariance), identity as a cost shift
inside the gate, then global nearest neighbour; and the review of the local tracks that
already feed a system track (demoted, or out of the gate too often: they leave it)."""

from __future__ import annotations

import itertools

import numpy as np

from tracker_service.fusion import consider, nearby
from tracker_service.fusion.arrays import kernel_indices, numbers_in
from tracker_service.fusion.estimator import SystemEstimator
from tracker_service.fusion.estimator_tracks import TrackFusionEstimator
from tracker_service.fusion.messages import MAX_SYSTEM_NUMBER
from tracker_service.fusion.ml import predict_cv
from tracker_service.fusion.state import FusionState
from tracker_service.tracking.associate import global_nearest_neighbour
from tracker_service.tracking.identity import identity_cost
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray
from tracker_service.tracking.tracker import CONFIRMED as LOCAL_CONFIRMED
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED
from tracker_service.tracking.tracker import TENTATIVE as LOCAL_TENTATIVE


def review(state: FusionState, estimator: SystemEstimator, touched: IntArray) -> IntArray:
    """Keep or drop the system track of each touched local track; returns the live ones
    that may feed a system track (confirmed or coasting)."""
    loc = state.local.rows
    live: IntArray = touched[loc["status"][touched] != LOCAL_DELETED]
    state.exchange_evidence.drop(loc["key"][touched[loc["status"][touched] == LOCAL_DELETED]])
    # Only confirmed local tracks feed system tracks: one that its tracker took back
    # to tentative (a slow primary-only track: clutter) leaves its system track.
    demoted = live[(loc["system"][live] > 0) & (loc["status"][live] == LOCAL_TENTATIVE)]
    _leave(state, demoted)
    live = live[loc["status"][live] != LOCAL_TENTATIVE]
    held = live[loc["system"][live] > 0]
    _exchange(state, estimator, held)
    lost = _tests(state, estimator, held)
    _leave(state, lost)
    state.stats.reassociations += int(lost.size)
    return live


def _tests(state: FusionState, estimator: SystemEstimator, held: IntArray) -> IntArray:
    """The gate's and the consistency test's updates of the local rows ``held`` in their
    system tracks; returns those that fail either (out of the gate too often, or
    inconsistent). Compiled with the plot filter: one call (``kernels.review_tests``)."""
    cfg, loc = state.config, state.local.rows
    if state.compiled and estimator.coarse_from_models:
        from tracker_service.fusion.kernels import review_tests  # numba only when compiled

        sys, c = state.sys, state.model_constants
        return review_tests(
            sys["mx"],
            sys["mP"],
            sys["mM"],
            sys["mu"],
            sys["t"],
            sys["B"],
            sys["solo"],
            loc["t"],
            loc["x"],
            loc["P"],
            loc["extra"],
            loc["radar"],
            loc["system"],
            loc["fails"],
            loc["nis_n"],
            loc["nis_mean"],
            kernel_indices(held),
            c.omega,
            c.q,
            c.sojourn,
            cfg.gate,
            cfg.reassociate_after,
            cfg.reassociate_window,
            cfg.reassociate_kappa * 4,
        )
    d2 = distance(state, estimator, held, loc["system"][held])
    # A solo system track is its founding local track's state: the distance compares
    # that track with its own prediction (no independent estimate), and leaving would
    # only end the system track and found another from the same local track (a PSR-only
    # aircraft passing over its radar, three_sites seed 101). As in ``_consistency``.
    solo = state.sys["solo"][loc["system"][held]]
    fails = np.where((d2 <= cfg.gate) | solo, 0, loc["fails"][held] + 1)
    loc["fails"][held] = fails
    inconsistent = _consistency(state, held, d2)
    lost: IntArray = held[(fails >= cfg.reassociate_after) | inconsistent]
    return lost


def _consistency(state: FusionState, held: IntArray, d2: FloatArray) -> BoolArray:
    """The consistency test of the local tracks ``held`` in their system tracks, given
    this update's distances: which fail it (see ``FusionConfig.reassociate_kappa``)."""
    cfg, loc = state.config, state.local.rows
    n = loc["nis_n"][held] + 1
    mean = loc["nis_mean"][held]
    mean += (d2 - mean) / np.minimum(n, cfg.reassociate_window)
    loc["nis_n"][held], loc["nis_mean"][held] = n, mean
    dof = 4
    # A system track its founding local track alone has fed follows that track: there is
    # nothing to be inconsistent with (a lone radar's tracks, canalA).
    solo = state.sys["solo"][loc["system"][held]]
    return np.asarray((n >= cfg.reassociate_window) & (mean > cfg.reassociate_kappa * dof) & ~solo)


EXCHANGE_AGREEMENT = 0.75
"""The share (running mean over the window) of the exchange test's updates in which every
other radar's local track favoured the exchange."""


def _exchange(state: FusionState, estimator: SystemEstimator, held: IntArray) -> None:
    """Exchange two confirmed local tracks l, l' of one radar between their system tracks
    S, S' when the crosswise assignment has been the more likely over
    ``reassociate_window`` updates in a row (``FusionConfig.exchange_margin``): the
    one-moment association's crosswise joins of two close aircraft, which neither the
    gate nor the consistency test undoes, since each holds the other's system track
    closed to it. The evidence is the local tracks of the other radars that feed S and S'
    (a system track's own state is a mixture of both aircraft, dominated by the fastest
    radar): delta = sum over S's others m of d2(l, m) - d2(l', m), plus over the others
    m' of S' of d2(l', m') - d2(l, m'), twice the log-likelihood ratio of the crosswise
    assignment against the present one; every one of those tracks must favour it in
    ``EXCHANGE_AGREEMENT`` of the updates."""
    cfg, loc = state.config, state.local.rows
    evidence = state.exchange_evidence
    if cfg.exchange_margin <= 0 or held.size == 0:
        return
    confirmed = held[loc["status"][held] == LOCAL_CONFIRMED]
    tested = loc["key"][confirmed]
    pairs = _exchange_pairs(state, estimator, confirmed, int(loc["radar"][held[0]]))
    if pairs is None:
        # One radar feeds the picture (canalA): no other radar's track can tell the two
        # assignments apart, so the pair search is skipped (a quarter of the fuser's cost
        # there); the tested tracks' evidence ends as below.
        evidence.drop(tested)
        return
    pair_a, pair_b, low, high, deltas, favoured = pairs
    # Each pair's running means, over the batch's pairs at once. Every other radar's
    # track must favour it (in EXCHANGE_AGREEMENT of the updates): where the system
    # tracks are mixtures (each radar's first joins made at one moment), an exchange
    # that one of them opposes moves the mixture around instead of undoing it (PAR10
    # with a shared code). A pair's evidence lives while it is tested in a row: a pair
    # of a tested track not tested now is out of reach (a coasting update, no plot,
    # tests nothing).
    evidence_now = evidence.update(tested, low, high, deltas, favoured, cfg.reassociate_window)
    n, mean, agree = evidence_now.T
    weak = (mean <= cfg.exchange_margin) | (agree < EXCHANGE_AGREEMENT)
    ready = (n >= cfg.reassociate_window) & ~weak
    done: set[int] = set()
    for k in np.flatnonzero(ready).tolist():
        pair = (int(low[k]), int(high[k]))
        if pair[0] in done or pair[1] in done:
            continue
        a, b = int(pair_a[k]), int(pair_b[k])
        state.local.feed(np.array([a, b]), loc["system"][[b, a]])
        _restart_tests(state, np.array([a, b]))
        done.update(pair)
        state.stats.exchanges += 1
    evidence.drop(np.array(sorted(done), dtype=np.int64))


ExchangePairs = tuple[IntArray, IntArray, IntArray, IntArray, FloatArray, BoolArray]
"""The exchange test's pairs: their rows l and l', their keys' lower and higher, each
pair's delta and whether all its votes favour the exchange."""


def _exchange_pairs(
    state: FusionState, estimator: SystemEstimator, confirmed: IntArray, radar: int
) -> ExchangePairs | None:
    """The pairs of the confirmed local rows ``confirmed`` of ``radar`` (None: a single
    radar feeds the system tracks) and their votes. Compiled: the four steps below in one
    kernel call (``kernels.exchange_pairs``), where four calls took 7 to 17 arrays each
    and the arrays between them went through Python; the same bits."""
    loc, sys, cfg = state.local.rows, state.sys, state.config
    if state.compiled:
        from tracker_service.fusion.kernels import exchange_pairs  # numba only when compiled

        several, *pairs = exchange_pairs(
            state.local.confirmed_feeders(),
            loc["alive"],
            loc["system"],
            loc["status"],
            loc["radar"],
            loc["key"],
            loc["t"],
            loc["x"],
            loc["P"],
            loc["extra"],
            *state.local.feeder_lists(),
            kernel_indices(confirmed),
            radar,
            LOCAL_CONFIRMED,
            sys["x"],
            sys["P"],
            sys["moments"],
            sys["sensitivity"],
            sys["largest_bias"],
            sys["t"],
            estimator.coarse_from_models,
            cfg.gate,
            *state.reach_constants,
            cfg.q,
        )
        return tuple(pairs) if several else None  # type: ignore[return-value]
    # Only a system track that a track of the batch's radar feeds can hold the l' of a
    # pair (``_exchange_witnesses``): the pre-selection reaches those alone (a fifth of
    # the fed ones on ``scale``), with the bias bound of every fed one as before, so
    # that each pair it finds is one it found among them all.
    several, fed, own = _feeding(state, radar)
    if not several:
        return None
    li, sj = _near(state, estimator, confirmed, own, bias_over=fed)
    # The pairs and their witnesses by array operations, then every distance in two
    # batched calls (one call per pair cost 60 % of the whole chain on ``scale``, the
    # pairs built in Python a third of the fuser).
    pair_a, pair_b, closer, farther, witness, ends = _exchange_witnesses(state, li, sj)
    ka, kb = loc["key"][pair_a], loc["key"][pair_b]
    low, high = np.minimum(ka, kb), np.maximum(ka, kb)
    if low.size:
        deltas, favoured = _votes(state, closer, farther, witness, ends)
    else:
        deltas, favoured = np.zeros(0), np.zeros(0, dtype=bool)
    return pair_a, pair_b, low, high, deltas, favoured


def _feeding(state: FusionState, radar: int) -> tuple[bool, IntArray, IntArray]:
    """Whether more than one radar's rows are among the confirmed live local rows
    feeding a system track, the system tracks they feed and those that ``radar``'s
    feed (ascending); the numpy path (compiled: ``kernels.feeding_sets``, from the
    counts the local table keeps)."""
    used = state.local.used
    feeding = confirmed_feeding(state)
    feeding_radar = used["radar"][feeding]
    several = feeding.size > 0 and not bool((feeding_radar == feeding_radar[0]).all())
    fed = numbers_in(used["system"][feeding])
    own = numbers_in(used["system"][feeding[feeding_radar == radar]])
    return several, fed, own


def confirmed_feeding(state: FusionState) -> IntArray:
    """The confirmed live local rows feeding a system track, ascending (the numpy
    path's pass over the table)."""
    used = state.local.used
    return np.flatnonzero(
        used["alive"] & (used["system"] > 0) & (used["status"] == LOCAL_CONFIRMED)
    )


def _exchange_witnesses(
    state: FusionState, li: IntArray, sj: IntArray
) -> tuple[IntArray, IntArray, IntArray, IntArray, IntArray, IntArray]:
    """The exchange test's pairs and votes. For each candidate (local row li[i] of radar
    r in system track S, near system track sj[i] = S', another), l' is the first row of
    ``involved`` (the confirmed live rows feeding S or S', in ascending order) of radar
    r in S'; the
    pair (l, l') is kept the first time it comes (each of its tracks' candidates names
    it) and only when other radars' rows feed both S and S'. Returns the pairs' rows l
    and l', then per vote the track its witness should be closer to, the one it should
    be farther from and the witness (S's other feeders, then S''s, in ``involved``'s
    order), and the bounds of each pair's votes (``ends``, from 0)."""
    loc = state.local.rows
    empty = np.zeros(0, dtype=np.int64)
    # Each candidate row feeds a system track: with none, no row feeds any.
    if li.size == 0:
        return empty, empty, empty, empty, empty, np.zeros(1, dtype=np.int64)
    feeding = confirmed_feeding(state)
    other = sj != loc["system"][li]
    li, sj = li[other], sj[other]
    wanted = np.zeros(MAX_SYSTEM_NUMBER + 1, dtype=bool)
    wanted[sj] = True
    wanted[loc["system"][li]] = True
    involved = feeding[wanted[loc["system"][feeding]]]
    if li.size == 0 or involved.size == 0:
        return empty, empty, empty, empty, empty, np.zeros(1, dtype=np.int64)
    radars = np.int64(state.n_radars)
    system, radar = loc["system"][involved], loc["radar"][involved]
    here, own = loc["system"][li], loc["radar"][li]
    # Every S and S' is fed by a row of ``involved`` (l itself, or the row that made S'
    # a candidate): ``numbers`` holds them all.
    codes, first, per_code = np.unique(
        system * radars + radar, return_index=True, return_counts=True
    )
    by_system = np.argsort(system, kind="stable")
    numbers, start, per_system = np.unique(system[by_system], return_index=True, return_counts=True)

    def own_radar_rows(number: IntArray) -> tuple[IntArray, BoolArray]:
        """Where (number, the candidate's radar) is in ``codes``, and whether it is."""
        code = number * radars + own
        at = np.minimum(np.searchsorted(codes, code), codes.size - 1)
        return at, codes[at] == code

    def other_radar_rows(number: IntArray) -> IntArray:
        at, present = own_radar_rows(number)
        return per_system[np.searchsorted(numbers, number)] - np.where(present, per_code[at], 0)

    at, found = own_radar_rows(sj)
    valid = np.flatnonzero(found & (other_radar_rows(here) > 0) & (other_radar_rows(sj) > 0))
    ka, kb = loc["key"][li[valid]], loc["key"][involved[first[at[valid]]]]
    low, high = np.minimum(ka, kb), np.maximum(ka, kb)
    order = np.lexsort((valid, high, low))
    first_of_pair = np.ones(valid.size, dtype=bool)
    first_of_pair[1:] = (low[order][1:] != low[order][:-1]) | (high[order][1:] != high[order][:-1])
    valid = valid[np.sort(order[first_of_pair])]
    a, b = li[valid], involved[first[at[valid]]]
    if a.size == 0:
        return empty, empty, empty, empty, empty, np.zeros(1, dtype=np.int64)
    # Two segments a pair (S's feeders, then S''s) of the rows grouped by system track
    # in ``involved``'s order; the candidate's own radar's rows left out.
    segment_number = np.column_stack([here[valid], sj[valid]]).reshape(-1)
    group = np.searchsorted(numbers, segment_number)
    size = per_system[group]
    segment = np.repeat(np.arange(segment_number.size), size)
    offset = np.arange(segment.size) - np.repeat(np.cumsum(size) - size, size)
    witness = involved[by_system[start[group][segment] + offset]]
    pair = segment // 2
    other = loc["radar"][witness] != own[valid][pair]
    witness, pair, of_s = witness[other], pair[other], segment[other] % 2 == 0
    closer = np.where(of_s, a[pair], b[pair])
    farther = np.where(of_s, b[pair], a[pair])
    ends = np.zeros(a.size + 1, dtype=np.int64)
    ends[1:] = np.cumsum(np.bincount(pair, minlength=a.size))
    return a, b, closer, farther, witness, ends


def _votes(
    state: FusionState,
    closer: IntArray,
    farther: IntArray,
    witness: IntArray,
    ends: IntArray,
) -> tuple[FloatArray, BoolArray]:
    """The exchange test's pairs' deltas (each the sum of its votes: a witness's distance
    to the track it should be closer to less that to the other) and whether all of a
    pair's votes favour the exchange; the numpy path (compiled: in one pass,
    ``kernels.exchange_votes``, the same bits)."""
    votes = track_distance(state, closer, witness)
    votes -= track_distance(state, farther, witness)
    deltas = np.array([votes[lo:hi].sum() for lo, hi in itertools.pairwise(ends.tolist())])
    return deltas, np.logical_and.reduceat(votes > 0, ends[:-1])


def track_distance(state: FusionState, a: IntArray, b: IntArray) -> FloatArray:
    """Chi-square distance (4 dof) of local tracks a and b (of other radars) at a's
    times, b predicted there (constant velocity), both radars' residual biases in the
    covariance: the exchange test's votes by the numpy path (compiled, each pair's in
    ``kernels.exchange_votes``)."""
    loc = state.local.rows
    xb, pb = predict_cv(loc["x"][b], loc["P"][b], loc["t"][a] - loc["t"][b], state.config.q)
    d = loc["x"][a] - xb
    s = loc["P"][a] + pb
    s[:, :2, :2] += loc["extra"][a] + loc["extra"][b]
    d2: FloatArray = np.einsum("ka,ka->k", d, np.linalg.solve(s, d[..., None])[..., 0])
    return d2


def _restart_tests(state: FusionState, rows: IntArray) -> None:
    loc = state.local.rows
    loc["fails"][rows] = 0
    loc["nis_n"][rows] = 0
    loc["nis_mean"][rows] = 0.0


def _leave(state: FusionState, rows: IntArray) -> None:
    """The local tracks ``rows`` leave their system tracks, their tests restarted."""
    if rows.size == 0:
        return  # the usual batch: four writes of nothing saved
    state.local.feed(rows, 0)
    _restart_tests(state, rows)


def assign(
    state: FusionState, estimator: SystemEstimator, radar: int, free: IntArray
) -> tuple[IntArray, IntArray, IntArray]:
    """The free local tracks (rows) of ``radar`` that join a system track, and which; and
    those that wait (an ambiguous first join, ``FusionConfig.join_ambiguity_margin``)."""
    candidates = open_systems(state, radar)
    li, sj = _near(state, estimator, free, candidates)
    d2 = distance(state, estimator, li, sj)
    loc, sys = state.local.rows, state.sys
    # An orphan (``lifecycle.orphan``) is taken up only by a track whose identity agrees
    # (with no local track left, its identity is the aircraft's last known one), and
    # where it is published: coasting in a straight line. By the IMM's prediction, whose
    # turn models widen it, a lone radar's new tracks of aircraft that had turned took
    # their orphans up 1 NM and more off them (canalA: 10 jumps, main none).
    orphan = ~np.isnan(sys["orphaned"][sj])
    d2[orphan] = distance(state, STRAIGHT_LINE, li[orphan], sj[orphan])
    agree = identities_agree(
        loc["address"][li], sys["address"][sj], loc["mode3a"][li], sys["mode3a"][sj]
    )
    gated = (d2 <= state.config.gate) & (agree | ~orphan)
    li, sj, d2 = li[gated], sj[gated], d2[gated]
    cost = d2 + identity_cost(
        loc["address"][li], sys["address"][sj], loc["mode3a"][li], sys["mode3a"][sj], state.config
    )
    waiting = _ambiguous_joins(state, li, sj, cost)
    if waiting.size:
        keep = ~np.isin(li, waiting)
        li, sj, cost = li[keep], sj[keep], cost[keep]
    chosen = global_nearest_neighbour(
        np.searchsorted(free, li), np.searchsorted(candidates, sj), cost
    )
    return li[chosen], sj[chosen], waiting


def _ambiguous_joins(state: FusionState, li: IntArray, sj: IntArray, cost: FloatArray) -> IntArray:
    """The local tracks (rows) among the gated pairs whose join waits: one of two
    candidates within ``join_ambiguity_margin`` of each other, for a local track (its two
    likeliest system tracks) or for a system track (its two likeliest local tracks), and
    not waiting for longer than ``found_delay`` yet (the wait is counted from
    ``t_founder``, the first time the track could have founded a system track)."""
    margin = state.config.join_ambiguity_margin
    empty = np.zeros(0, dtype=np.int64)
    if margin <= 0 or li.size < 2:
        return empty
    close: set[int] = set()
    for keys, others in ((li, sj), (sj, li)):
        order = np.lexsort((cost, keys))
        k, c, o = keys[order], cost[order], others[order]
        # Each key's likeliest pair (the first of its sorted run) against its second.
        second = np.flatnonzero((k[1:] == k[:-1]) & (np.r_[True, k[1:-1] != k[:-2]]))
        near = second[c[second + 1] - c[second] < margin]
        if keys is li:
            close.update(k[near].tolist())
        else:
            close.update(o[near].tolist())
            close.update(o[near + 1].tolist())
    if not close:
        return empty
    rows = np.array(sorted(close), dtype=np.int64)
    loc = state.local.rows
    first = np.isnan(loc["t_founder"][rows])
    loc["t_founder"][rows[first]] = state.now
    return rows[state.now - loc["t_founder"][rows] < state.config.found_delay]


STRAIGHT_LINE = TrackFusionEstimator()
"""The gate of a system track's latest state predicted at constant velocity."""


def _near(
    state: FusionState,
    estimator: SystemEstimator,
    free: IntArray,
    candidates: IntArray,
    bias_over: IntArray | None = None,
) -> tuple[IntArray, IntArray]:
    """The (local row, system number) pairs the gate may pass (``nearby.py``), in the
    order of (local row, number); the radii's bias bound from the system tracks
    ``bias_over`` (default: the candidates), a superset of the candidates."""
    empty = np.zeros(0, dtype=np.int64)
    if free.size == 0 or candidates.size == 0:
        return empty, empty
    loc, sys, cfg = state.local.rows, state.sys, state.config
    q, turn = state.reach_constants
    if state.compiled:
        from tracker_service.fusion.kernels import near_local_system  # numba when compiled

        return near_local_system(
            loc["t"],
            loc["x"],
            loc["P"],
            loc["extra"],
            kernel_indices(free),
            sys["x"],
            sys["P"],
            sys["moments"],
            sys["sensitivity"],
            sys["largest_bias"],
            sys["t"],
            kernel_indices(candidates),
            kernel_indices(candidates if bias_over is None else bias_over),
            estimator.coarse_from_models,
            cfg.gate,
            q,
            turn,
        )
    t_local = loc["t"][free]
    t_mid, spread = nearby.time_span(t_local)
    b = max(
        nearby.system_largest_bias(sys, candidates if bias_over is None else bias_over, False),
        nearby.largest_bias(loc["extra"][free]),
    )
    xy_s, r_s = nearby.system_reach(
        sys,
        candidates,
        estimator.coarse_from_models,
        2.0 * b,
        t_mid,
        spread,
        cfg.gate,
        q,
        turn,
        False,
    )
    xy_l, r_l = nearby.reach(
        loc["x"][free],
        loc["P"][free],
        t_local,
        np.full(free.size, 4.0 * b),
        t_mid,
        spread,
        cfg.gate,
        q,
        turn,
    )
    i, j = nearby.near_pairs(xy_l, r_l, xy_s, r_s)
    return free[i], candidates[j]


def open_systems(state: FusionState, radar: int) -> IntArray:
    """Live system tracks a new local track of ``radar`` may join: not those already
    fed by another confirmed local track of the same radar (another aircraft)."""
    loc = state.local.used
    busy = loc["alive"] & (loc["radar"] == radar) & (loc["status"] == LOCAL_CONFIRMED)
    open_ = state.sys["alive"].copy()
    open_[loc["system"][busy]] = False
    open_[0] = False
    return np.flatnonzero(open_)


def distance(
    state: FusionState, estimator: SystemEstimator, local: IntArray, system: IntArray
) -> FloatArray:
    """Chi-square distance (4 dof) of local tracks and system tracks at the local
    tracks' times (the system tracks predicted there by the estimator: see
    ``SystemEstimator.gate_prediction``)."""
    if local.size == 0:
        return np.zeros(0)
    loc, sys = state.local.rows, state.sys
    if state.compiled and estimator.coarse_from_models:
        # The "plots" estimator's gate prediction, from the table's IMM models: the whole
        # test in one pass over the pairs (``kernels.gate_distances``).
        from tracker_service.fusion.kernels import gate_distances  # numba only when compiled

        c = state.model_constants
        return gate_distances(
            sys["mx"],
            sys["mP"],
            sys["mM"],
            sys["mu"],
            sys["t"],
            sys["B"],
            loc["t"],
            loc["x"],
            loc["P"],
            loc["extra"],
            loc["radar"],
            kernel_indices(local),
            kernel_indices(system),
            c.omega,
            c.q,
            c.sojourn,
        )
    t = loc["t"][local]
    dt = t - sys["t"][system]
    xs, ps, moved = estimator.gate_prediction(state, system, dt)
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


def compatible_pairs(state: FusionState, a: IntArray, b: IntArray) -> BoolArray:
    """Pairs of system tracks whose identities do not tell them apart: no two different
    Mode S addresses, no two different Mode 3/A codes."""
    sys = state.sys
    return identities_agree(
        sys["address"][a], sys["address"][b], sys["mode3a"][a], sys["mode3a"][b]
    )


def identities_agree(
    address_a: IntArray, address_b: IntArray, code_a: IntArray, code_b: IntArray
) -> BoolArray:
    """Neither two different Mode S addresses nor two different Mode 3/A codes (-1:
    unknown, which agrees with any)."""
    same_address = (address_a < 0) | (address_b < 0) | (address_a == address_b)
    same_code = (code_a < 0) | (code_b < 0) | (code_a == code_b)
    return np.asarray(same_address & same_code, dtype=bool)
