"""The compiled JPDA* kernels (``association.kernels``) against the numpy reference
(``association.jpda``, ``association.update``): integers equal, floats to 1e-9."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from scipy.optimize import linear_sum_assignment

from tests.test_association import _pairs
from tests.test_tracking import PERIOD
from tracker_service.tracking import TrackerConfig
from tracker_service.tracking.association import (
    GatedPairs,
    JointProbabilisticDataAssociation,
    WeightedPairs,
    kernels,
    weighted_update,
)
from tracker_service.tracking.association.jpda import FORBIDDEN, _k_best

COMPILED = TrackerConfig(scan_period_s=PERIOD, association="jpda")
NUMPY = replace(COMPILED, implementation="numpy")
RTOL = 1e-9


def _score_pairs(
    rng: np.random.Generator, n_tracks: int, n_plots: int, density: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Random gated pairs: rows and batch indices with gaps (as a batch's), scores about
    as spread as real ones."""
    gated = rng.random((n_tracks, n_plots)) < density
    ti, pj = np.nonzero(gated)
    rows = np.sort(rng.choice(4 * n_tracks + 5, n_tracks, replace=False))
    cols = np.sort(rng.choice(4 * n_plots + 5, n_plots, replace=False))
    shuffle = rng.permutation(ti.size)
    score = rng.normal(3.0, 2.0, ti.size)
    return rows[ti[shuffle]], cols[pj[shuffle]], score


def _both(
    track: np.ndarray, plot: np.ndarray, score: np.ndarray, config: TrackerConfig = NUMPY
) -> tuple[np.ndarray, np.ndarray]:
    reference = JointProbabilisticDataAssociation(config)
    want = reference._weights(_gated(track, plot), score)
    got = kernels.jpda_weights(
        track, plot, score, reference.log_miss, config.jpda_max_events, config.jpda_k_best
    )
    return got, want


def _gated(track: np.ndarray, plot: np.ndarray) -> GatedPairs:
    """Pairs holding only what ``_weights`` reads (the scores are given apart)."""
    pairs, _, _ = _pairs(1)
    return replace(pairs, track=track, plot=plot)


@pytest.mark.parametrize("seed", range(12))
def test_random_batches_match_the_reference_exact_and_k_best(seed: int) -> None:
    rng = np.random.default_rng(seed)
    n_tracks, n_plots = int(rng.integers(1, 14)), int(rng.integers(1, 16))
    track, plot, score = _score_pairs(rng, n_tracks, n_plots, rng.uniform(0.1, 0.6))
    # A small event budget sends the larger clusters down Murty's ranking.
    config = replace(NUMPY, jpda_max_events=int(rng.choice([5000, 40])), jpda_k_best=12)
    got, want = _both(track, plot, score, config)
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-15)


def test_a_large_cluster_takes_the_k_best_path_and_matches() -> None:
    rng = np.random.default_rng(21)
    track, plot, score = _score_pairs(rng, 14, 16, 0.5)
    ratio_events = np.prod(np.bincount(track)[np.unique(track)] + 1.0)
    assert ratio_events > NUMPY.jpda_max_events
    got, want = _both(track, plot, score)
    np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-15)


def test_edge_cases_empty_lone_pairs_and_one_track_with_many_plots() -> None:
    log_miss = math.log(0.1)
    empty = np.empty(0, dtype=np.int64)
    assert kernels.jpda_weights(empty, empty, np.empty(0), log_miss, 5000, 64).size == 0
    # Lone pairs only (no cluster at all).
    track, plot = np.array([3, 0, 7]), np.array([2, 5, 0])
    score = np.array([1.0, -4.0, 9.0])
    got, want = _both(track, plot, score)
    np.testing.assert_allclose(got, want, rtol=RTOL)
    # One track, many plots (an exact enumeration of one track's choices); then so many
    # that the ranking takes over.
    for n_plots in (40, 6000):
        rng = np.random.default_rng(n_plots)
        track = np.zeros(n_plots, dtype=np.int64)
        plot = rng.permutation(n_plots)
        score = rng.normal(0.0, 3.0, n_plots)
        got, want = _both(track, plot, score)
        np.testing.assert_allclose(got, want, rtol=RTOL, atol=1e-15)
    # Equal scores: JPDA* keeps the first of equally likely permutations, as the reference.
    got, want = _both(np.array([0, 0, 1, 1]), np.array([0, 1, 0, 1]), np.full(4, 3.0))
    np.testing.assert_array_equal(got, want)


@pytest.mark.parametrize("seed", range(6))
def test_assignment_and_ranking_match_scipy_and_the_reference(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    rows = int(rng.integers(1, 9))
    cost = rng.normal(0.0, 3.0, (rows, rows + int(rng.integers(0, 9))))
    cost[rng.random(cost.shape) < 0.3] = FORBIDDEN
    cost = np.round(cost, 1)  # ties: the same solution among equal ones as scipy
    np.testing.assert_array_equal(kernels.linear_sum_assignment(cost), linear_sum_assignment(cost)[1])
    ratio = rng.normal(1.0, 2.0, (rows, rows + 2))
    ratio[rng.random(ratio.shape) < 0.3] = -np.inf
    want = np.array(_k_best(ratio, math.log(0.1), 30))
    np.testing.assert_array_equal(kernels._k_best(ratio, math.log(0.1), 30), want)


def test_sums_are_numpy_sums_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    for n in (*range(1, 40), 127, 128, 129, 300, 1000):
        values = rng.normal(0.0, 1e6, n) * 10.0 ** rng.integers(-8, 8, n)
        assert kernels._sum(values) == float(values.sum())
