"""Association behind one interface: the gate, GNN and JPDA*, the weighted IMM update."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from tests.test_tracking import PERIOD, Target, flight, run, simulate, straight
from tracker_service.tracking import CONFIRMED, ModelSet, TrackerConfig, imm
from tracker_service.tracking.association import (
    GatedPairs,
    JointProbabilisticDataAssociation,
    WeightedPairs,
    make_associator,
    weighted_update,
)
from tracker_service.tracking.association.gnn import GlobalNearestNeighbour
from tracker_service.tracking.association.jpda import _enumerate, _k_best

JPDA = TrackerConfig(scan_period_s=PERIOD, association="jpda")


def test_the_associator_is_chosen_by_name_and_a_wrong_name_says_which_exist() -> None:
    assert isinstance(make_associator(TrackerConfig()), GlobalNearestNeighbour)
    assert isinstance(make_associator(JPDA), JointProbabilisticDataAssociation)
    with pytest.raises(
        ValueError, match=r"association: 'pmht' is not one of \['gnn', 'jpda', 'mht'\]"
    ):
        TrackerConfig(association="pmht")


def _marginals_by_brute_force(ratio: np.ndarray, log_miss: float) -> np.ndarray:
    """JPDA* marginals from every feasible event, written out plainly."""
    n_tracks, n_plots = ratio.shape
    best: dict[tuple[frozenset[int], frozenset[int]], tuple[float, tuple[int, ...]]] = {}
    for event in np.ndindex(*(n_plots + 1,) * n_tracks):
        plots = [j for j in event if j < n_plots]
        if len(set(plots)) < len(plots):
            continue
        if any(j < n_plots and not np.isfinite(ratio[i, j]) for i, j in enumerate(event)):
            continue
        w = sum(ratio[i, j] if j < n_plots else log_miss for i, j in enumerate(event))
        key = (frozenset(i for i, j in enumerate(event) if j < n_plots), frozenset(plots))
        if key not in best or w > best[key][0]:
            best[key] = (w, event)
    total = sum(math.exp(w) for w, _ in best.values())
    out = np.zeros_like(ratio)
    for w, event in best.values():
        for i, j in enumerate(event):
            if j < n_plots:
                out[i, j] += math.exp(w) / total
    return out


def test_jpda_star_marginals_match_a_brute_force_count_and_exclude_permutations() -> None:
    rng = np.random.default_rng(4)
    jpda = JointProbabilisticDataAssociation(JPDA)
    ratio = rng.normal(2.0, 1.5, (3, 4))
    ratio[0, 3] = ratio[2, 0] = -np.inf  # not gated
    ti, pj = np.nonzero(np.isfinite(ratio))
    got = jpda._cluster(ti, pj, ratio[ti, pj])
    want = _marginals_by_brute_force(ratio, jpda.log_miss)[ti, pj]
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-15)
    # Two tracks, two plots, the plots equally likely for both: plain JPDA would give
    # each track half of each plot (both tracks to the middle); JPDA* keeps one
    # permutation, so each track keeps one plot, the other only through the events
    # where the other track is missed.
    tie = np.array([[3.0, 3.0], [3.0, 3.0]])
    w = np.sort(jpda._cluster(np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), tie.ravel()))
    assert w[1] < 0.01 and w[2] > 0.98


def test_murty_ranking_finds_every_event_in_order() -> None:
    rng = np.random.default_rng(9)
    ratio = rng.normal(1.0, 2.0, (3, 3))
    ratio[1, 2] = -np.inf
    log_miss = math.log(0.1)
    every = list(_enumerate(ratio))

    def log_w(event: tuple[int, ...]) -> float:
        return sum(ratio[i, j] if j >= 0 else log_miss for i, j in enumerate(event))

    ranked = _k_best(ratio, log_miss, k=len(every) + 5)
    assert sorted(ranked) == sorted(every)  # each once, none invented
    weights = [log_w(e) for e in ranked]
    assert all(a >= b - 1e-12 for a, b in itertools.pairwise(weights))
    assert _k_best(ratio, log_miss, k=4) == ranked[:4]


def _pairs(n_plots: int) -> tuple[GatedPairs, np.ndarray, np.ndarray]:
    """One track (two IMM models' worth of the default set) gated with ``n_plots``
    plots near its prediction."""
    config = TrackerConfig()
    models = ModelSet.from_config(config)
    m = models.n_models
    x = np.tile(np.array([1000.0, 2000.0, 200.0, 0.0]), (1, m, 1))
    p = np.tile(np.diag([400.0, 400.0, 25.0, 25.0]), (1, m, 1, 1))
    mu = np.asarray(models.initial_probabilities)[None, :]
    pred = imm.predict(x, p, mu, np.array([5.0]), models)
    pred = pred.take(np.zeros(n_plots, dtype=np.int64))
    rng = np.random.default_rng(2)
    z = pred.x_comb[:, :2] + rng.normal(0.0, 60.0, (n_plots, 2))
    r = np.tile(np.diag([2500.0, 2500.0]), (n_plots, 1, 1))
    nis, log_det = imm.innovation_test(pred, z, r)
    pairs = GatedPairs(
        track=np.zeros(n_plots, dtype=np.int64),
        plot=np.arange(n_plots),
        nis=nis,
        log_det=log_det,
        identity_cost=np.zeros(n_plots),
        pred=pred,
    )
    return pairs, z, r


def test_weighted_update_of_one_plot_of_weight_one_is_the_imm_update() -> None:
    pairs, z, r = _pairs(1)
    got = weighted_update(pairs, WeightedPairs.hard(np.array([0])), z, r)
    x, p, mu = imm.update(pairs.pred, z, r)
    np.testing.assert_allclose(got.x, x, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(got.P, p, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(got.mu, mu, rtol=1e-12, atol=1e-15)


def test_weighted_update_is_the_mixture_of_the_updates_and_the_miss() -> None:
    pairs, z, r = _pairs(2)
    beta = np.array([0.6, 0.3])  # and 0.1 for the miss
    got = weighted_update(pairs, WeightedPairs(np.arange(2), beta), z, r)
    x, p, mu = imm.update(pairs.pred, z, r)
    xs, ps = imm.combine(x, p, mu)
    prior_x, prior_p = pairs.pred.x_comb[0], pairs.pred.P_comb[0]
    mean = beta[0] * xs[0] + beta[1] * xs[1] + 0.1 * prior_x
    spread = sum(
        w * (c + np.outer(m - mean, m - mean))
        for w, m, c in ((beta[0], xs[0], ps[0]), (beta[1], xs[1], ps[1]), (0.1, prior_x, prior_p))
    )
    xc, pc = imm.combine(got.x, got.P, got.mu)
    np.testing.assert_allclose(xc[0], mean, rtol=1e-10)
    np.testing.assert_allclose(pc[0], spread, rtol=1e-9)
    # The innovations' spread widens the covariance beyond the best plot's own update.
    assert np.trace(pc[0][:2, :2]) > np.trace(ps[0][:2, :2])


@pytest.mark.parametrize("association", ["gnn", "jpda"])
def test_two_primary_only_aircraft_1_km_apart_keep_their_tracks_1_km_apart(
    association: str,
) -> None:
    """JPDA's coalescence would pull both tracks to the middle; JPDA* must not."""
    targets = [
        Target(straight(90.0, 40e3, 60e3 + dy, 220.0), mode3a=-1, address=-1)
        for dy in (0.0, 1000.0)
    ]
    scenario = simulate(targets, scans=40, seed=5)
    config = TrackerConfig(scan_period_s=PERIOD, association=association)
    _, out = run(scenario, config)
    rows = out[(out["plot_id"] >= 0) & (out["status"] == CONFIRMED)]
    owners = np.array([scenario.owner[int(p)] for p in rows["plot_id"]])
    numbers = np.unique(rows["track_number"])
    assert len(numbers) == 2
    # Each track follows one aircraft throughout: no swap.
    for number in numbers:
        assert len(np.unique(owners[rows["track_number"] == number])) == 1
    late = rows[[scenario.truth_time[int(p)] > 20 * PERIOD for p in rows["plot_id"]]]
    by_track = [late[late["track_number"] == n] for n in numbers]
    k = min(len(b) for b in by_track)
    gap = np.abs(by_track[1]["y"][:k] - by_track[0]["y"][:k])
    print(f"{association}: track separation {gap.mean():.0f} m (sd {gap.std():.0f})")
    assert abs(gap.mean() - 1000.0) < 100.0
    assert gap.min() > 700.0


def test_jpda_keeps_mode_s_identities_through_a_15_degree_crossing() -> None:
    targets = [
        Target(flight(40e3, 60e3, 90.0, 220.0, []), address=0x3C0001, mode3a=0o1234),
        Target(flight(40e3, 60e3 - 2600.0, 75.0, 220.0, []), address=0x3C0002, mode3a=0o1235),
    ]
    scenario = simulate(targets, scans=40, seed=3)
    _, out = run(scenario, JPDA)
    rows = out[(out["plot_id"] >= 0) & (out["status"] == CONFIRMED)]
    owners = np.array([scenario.owner[int(p)] for p in rows["plot_id"]])
    for number in np.unique(rows["track_number"]):
        assert len(np.unique(owners[rows["track_number"] == number])) == 1
    assert len(np.unique(rows["track_number"])) == 2
