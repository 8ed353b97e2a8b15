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
from tests.test_tracking_kernels import close
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, ModelSet, TrackerConfig, imm
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
    # Dense enough to be one cluster, whose product of options is past the exact budget.
    assert np.prod(np.bincount(track)[np.unique(track)] + 1.0) > NUMPY.jpda_max_events
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
    np.testing.assert_array_equal(
        kernels.linear_sum_assignment(cost), linear_sum_assignment(cost)[1]
    )
    ratio = rng.normal(1.0, 2.0, (rows, rows + 2))
    ratio[rng.random(ratio.shape) < 0.3] = -np.inf
    want = np.array(_k_best(ratio, math.log(0.1), 30))
    np.testing.assert_array_equal(kernels._k_best(ratio, math.log(0.1), 30), want)


def test_sums_are_numpy_sums_bit_for_bit() -> None:
    rng = np.random.default_rng(5)
    for n in (*range(1, 40), 127, 128, 129, 300, 1000):
        values = rng.normal(0.0, 1e6, n) * 10.0 ** rng.integers(-8, 8, n)
        assert kernels._sum(values) == float(values.sum())


def _several_tracks(seed: int, n_tracks: int) -> tuple[GatedPairs, np.ndarray, np.ndarray]:
    """Tracks of the default model set, each gated with 1-4 plots near its prediction
    (the pairs interleaved, as the gate gives them); the plots and their covariances."""
    rng = np.random.default_rng(seed)
    models = ModelSet.from_config(TrackerConfig())
    m = models.n_models
    x = np.empty((n_tracks, m, 4))
    x[..., :2] = rng.uniform(-1e5, 1e5, (n_tracks, 1, 2)) + rng.normal(0, 50, (n_tracks, m, 2))
    x[..., 2:] = rng.uniform(-250, 250, (n_tracks, 1, 2)) + rng.normal(0, 5, (n_tracks, m, 2))
    p = np.tile(np.diag([900.0, 900.0, 40.0, 40.0]), (n_tracks, m, 1, 1))
    mu = rng.dirichlet(np.ones(m), n_tracks)
    pred = imm.predict(x, p, mu, rng.uniform(3.0, 6.0, n_tracks), models)
    track = np.repeat(np.arange(n_tracks), rng.integers(1, 5, n_tracks))
    track = track[rng.permutation(track.size)]
    pred = pred.take(track)
    z = pred.x_comb[:, :2] + rng.normal(0.0, 80.0, (track.size, 2))
    r = np.tile(np.diag([2500.0, 2500.0]), (track.size, 1, 1))
    nis, log_det = imm.innovation_test(pred, z, r)
    pairs = GatedPairs(
        track=track,
        plot=np.arange(track.size),
        nis=nis,
        log_det=log_det,
        identity_cost=np.zeros(track.size),
        pred=pred,
    )
    return pairs, z, r


@pytest.mark.parametrize("seed", range(4))
def test_weighted_update_matches_the_reference(seed: int) -> None:
    pairs, z, r = _several_tracks(seed, 12)
    for config in (NUMPY, replace(NUMPY, detection_probability=0.5)):
        # Pd 0.5: some tracks' plots together fall below a detection, and are left out.
        weighted = JointProbabilisticDataAssociation(config).associate(pairs)
        want = weighted_update(pairs, weighted, z, r, "numpy")
        got = weighted_update(pairs, weighted, z, r, "compiled")
        np.testing.assert_array_equal(got.track, want.track)
        np.testing.assert_array_equal(got.reported, want.reported)
        for field in ("x", "P", "mu"):
            close(getattr(want, field), getattr(got, field))
    # Nothing detected, nothing weighted: no track updated.
    one = WeightedPairs(np.array([0]), np.array([0.3]))
    assert weighted_update(pairs, one, z, r, "compiled").track.size == 0
    none = WeightedPairs(np.empty(0, dtype=np.int64), np.empty(0))
    assert weighted_update(pairs, none, z, r, "compiled").x.shape == (0, pairs.pred.x.shape[1], 4)


def _formations(seed: int, scans: int) -> list[np.ndarray]:
    """Primary-only aircraft three abreast, 600 m apart, in a few formations crossing
    each other: one batch per quarter scan, clusters every scan."""
    rng = np.random.default_rng(seed)
    n_groups = 6
    centre = rng.uniform(-4e4, 4e4, (n_groups, 2))
    heading = rng.uniform(0, 2 * np.pi, n_groups)
    direction = np.column_stack([np.sin(heading), np.cos(heading)])
    abreast = np.column_stack([direction[:, 1], -direction[:, 0]])
    offsets = np.array([-600.0, 0.0, 600.0])
    start = (centre[:, None] + offsets[None, :, None] * abreast[:, None]).reshape(-1, 2)
    velocity = np.repeat(direction * 200.0, 3, axis=0)
    n = start.shape[0]
    batches = []
    for scan in range(scans):
        t = scan * PERIOD + rng.uniform(0, PERIOD, n)
        pos = start + velocity * t[:, None] + rng.normal(0.0, 60.0, (n, 2))
        plots = np.zeros(n, dtype=PLOT_DTYPE)
        plots["time"], plots["x"], plots["y"] = 1.7e9 + t, pos[:, 0], pos[:, 1]
        plots["R"] = np.eye(2) * 3600.0
        plots["flight_level"] = np.nan
        plots["mode3a"] = plots["address"] = -1
        plots["typ"] = 2
        plots["plot_id"] = scan * n + np.arange(n)
        quarter = ((t - scan * PERIOD) // (PERIOD / 4)).astype(int)
        for q in range(4):
            chosen = plots[quarter == q]
            batches.append(chosen[np.argsort(chosen["time"])])
    return batches


def test_jpda_trackers_agree_on_close_formations() -> None:
    """The same plots through the compiled and the numpy JPDA tracker: the same tracks
    and plots, states to 1e-9 of their scale."""
    compiled, reference = LocalTracker(COMPILED), LocalTracker(NUMPY)
    rows = 0
    for batch in _formations(3, 30):
        a, b = reference.process(batch), compiled.process(batch)
        for field in ("track_number", "status", "plot_id"):
            np.testing.assert_array_equal(a[field], b[field])
        for field in ("x", "y", "vx", "vy", "P", "model_probabilities"):
            close(a[field], b[field])
        rows += len(a)
    assert rows > 300
    assert (compiled.tracks["status"] == 1).sum() >= 15
