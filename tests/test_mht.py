"""MHT (``association = "mht"``): deferred decisions, revisions under a stable track number,
N-scan pruning, bounded hypotheses, GNN's answer where nothing is ambiguous."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from tests.test_tracking import PERIOD, T0, Target, run, simulate, straight
from tracker_service.tracking import CONFIRMED, DELETED, LocalTracker, TrackerConfig
from tracker_service.tracking.association import MultipleHypothesisTracking
from tracker_service.tracking.plots import BASE_PLOT_DTYPE

MHT = TrackerConfig(scan_period_s=PERIOD, association="mht")
SIGMA = 100.0
SPEED = 220.0


def _scan(k: int, offsets: list[float], first_id: int) -> npt.NDArray[np.void]:
    """One batch at scan ``k``: primary plots of an aircraft flying east at 220 m/s from
    (40 km, 60 km), each offset north by one of ``offsets`` (m)."""
    rows = [
        (T0 + k * PERIOD, 40e3 + SPEED * k * PERIOD, 60e3 + dy, np.eye(2) * SIGMA**2,
         np.nan, False, -1, False, -1, 1, first_id + i)
        for i, dy in enumerate(offsets)
    ]  # fmt: skip
    return np.array(rows, dtype=BASE_PLOT_DTYPE)


def _sidestep() -> list[npt.NDArray[np.void]]:
    """Eight scans on the line, then an ambiguous scan: a plot 140 m north (plot 8, the
    nearer) and one 150 m south (plot 9); the aircraft was the southern one and drifts
    south at 30 m/s from then on (plots 10, 11, ...)."""
    batches = [_scan(k, [0.0], k) for k in range(8)]
    batches.append(_scan(8, [140.0, -150.0], 8))
    for k in range(9, 19):
        batches.append(_scan(k, [-150.0 - 30.0 * PERIOD * (k - 8)], k + 1))
    return batches


def test_a_later_scan_revises_the_published_choice_and_the_track_keeps_its_number() -> None:
    batches = _sidestep()
    tracker = LocalTracker(MHT)
    out = [tracker.process(b) for b in batches]
    mht = tracker.associator
    assert isinstance(mht, MultipleHypothesisTracking)
    track = [o[o["track_number"] == 1] for o in out]
    # Scan 8: the nearer (northern) plot is published; scan 9 makes the southern one
    # the better history.
    assert track[8]["plot_id"].tolist() == [8]
    assert track[9]["plot_id"].tolist() == [10]
    assert mht.stats.revisions == 1
    # The plot left over at scan 8, in the track's gate, started a track (a possible
    # second aircraft) that never took a plot again and was deleted tentative.
    assert out[8]["plot_id"][out[8]["track_number"] == 2].tolist() == [9]
    confirmed = {int(r["track_number"]) for o in out for r in o if r["status"] == CONFIRMED}
    assert confirmed == {1}  # one track throughout, under one number
    # The corrected state is the one a tracker that never saw the northern plot has.
    clean = LocalTracker(TrackerConfig(scan_period_s=PERIOD))
    reference = [clean.process(b[b["plot_id"] != 8]) for b in batches]
    for k in (9, 10, 13):
        for name in ("x", "y", "vx", "vy", "P", "model_probabilities"):
            np.testing.assert_allclose(track[k][name], reference[k][name], rtol=1e-9, atol=1e-9)
    # N-scan pruning (N = 3): the choice of scan 8 is fixed three scans on; the new
    # track, tentative in the cluster, outlives its misses until none can be revised
    # (two misses, then N - 1 more: deleted at scan 13); the cluster, down to one
    # hypothesis, has dissolved.
    assert out[13]["status"][out[13]["track_number"] == 2].tolist() == [DELETED]
    assert mht.clusters == []


def test_without_the_revision_the_nearer_plot_stays() -> None:
    """The same ambiguous scan, the aircraft the northern plot: no revision."""
    batches = [_scan(k, [0.0], k) for k in range(8)]
    batches.append(_scan(8, [140.0, -150.0], 8))
    batches += [_scan(k, [140.0 + 30.0 * PERIOD * (k - 8)], k + 1) for k in range(9, 12)]
    tracker = LocalTracker(MHT)
    out = [tracker.process(b) for b in batches]
    assert out[8]["plot_id"][out[8]["track_number"] == 1].tolist() == [8]
    assert isinstance(tracker.associator, MultipleHypothesisTracking)
    assert tracker.associator.stats.revisions == 0
    assert tracker.associator.stats.clusters_formed == 1


def test_the_clutter_density_is_a_plug_in_and_weighs_plot_against_clutter() -> None:
    """A dense clutter cell makes the plots of the ambiguous scan likelier clutter than
    the track's: the best hypothesis misses the scan."""
    seen: list[int] = []

    def dense(p: object) -> npt.NDArray[np.float64]:
        n = len(p)  # type: ignore[arg-type]
        seen.append(n)
        return np.full(n, 1e-3)  # 1,000 plots per km^2

    tracker = LocalTracker(MHT)
    assert isinstance(tracker.associator, MultipleHypothesisTracking)
    out = [tracker.process(b) for b in _sidestep()[:8]]
    tracker.associator.clutter_density = dense
    out.append(tracker.process(_sidestep()[8]))
    assert seen == [2]
    # No update of the track: the scan counts as missed.
    assert out[8]["plot_id"][out[8]["track_number"] == 1].tolist() == []


@pytest.fixture(scope="module")
def close_pair() -> tuple[object, npt.NDArray[np.void], LocalTracker]:
    """Two primary-only aircraft 300 m apart, abeam for 40 scans: ambiguous throughout."""
    targets = [
        Target(straight(90.0, 40e3, 60e3 + dy, 220.0), mode3a=-1, address=-1) for dy in (0.0, 300.0)
    ]
    scenario = simulate(targets, scans=40, seed=5)
    tracker = LocalTracker(MHT)
    assert isinstance(tracker.associator, MultipleHypothesisTracking)
    mht = tracker.associator
    out = []
    for batch in scenario.batches:
        out.append(tracker.process(batch))
        now = float(batch["time"].max())
        cutoff = now - (MHT.mht_n_scan - 0.5) * PERIOD
        for c in mht.clusters:
            assert 2 <= len(c.hypotheses) <= MHT.mht_max_hypotheses
            scores = [h.score for h in c.hypotheses]
            assert scores == sorted(scores, reverse=True)
            assert scores[0] - scores[-1] <= MHT.mht_prune_llr
            best = c.hypotheses[0]
            for h in c.hypotheses:
                # N-scan: every hypothesis holds the best one's past before the cutoff.
                for leaf, anchor in zip(h.leaves, best.leaves, strict=True):
                    assert leaf.anchor(cutoff) is anchor.anchor(cutoff)
                # No plot of the window in two tracks of one hypothesis.
                used = []
                for leaf in h.leaves:
                    node = leaf
                    while node is not None:
                        if node.plot_id >= 0:
                            used.append(node.plot_id)
                        node = node.parent
                assert len(used) == len(set(used))
    return scenario, np.concatenate(out), tracker


def test_close_pair_hypotheses_stay_bounded_pruned_and_consistent(
    close_pair: tuple[object, npt.NDArray[np.void], LocalTracker],
) -> None:
    _, _, tracker = close_pair
    assert isinstance(tracker.associator, MultipleHypothesisTracking)
    stats = tracker.associator.stats
    assert stats.clusters_formed >= 1
    assert stats.cluster_steps >= 20
    assert stats.most_hypotheses <= MHT.mht_max_hypotheses


def test_close_pair_keeps_two_tracks_without_a_swap(
    close_pair: tuple[object, npt.NDArray[np.void], LocalTracker],
) -> None:
    scenario, out, _ = close_pair
    rows = out[(out["plot_id"] >= 0) & (out["status"] == CONFIRMED)]
    owners = np.array([scenario.owner[int(p)] for p in rows["plot_id"]])  # type: ignore[attr-defined]
    numbers = np.unique(rows["track_number"])
    assert len(numbers) == 2
    for number in numbers:
        assert len(np.unique(owners[rows["track_number"] == number])) == 1


def test_where_nothing_is_ambiguous_mht_is_gnn() -> None:
    """Two aircraft 1 km apart, a third crossing 20 km away: no cluster is branched and
    every output row is GNN's, bit for bit."""
    targets = [
        Target(straight(90.0, 40e3, 60e3 + dy, 220.0), mode3a=-1, address=-1)
        for dy in (0.0, 1000.0)
    ]
    targets.append(Target(straight(0.0, 60e3, 40e3, 200.0), address=0x3C0001))
    scenario = simulate(targets, scans=30, seed=5)
    tracker, out = run(scenario, MHT)
    _, gnn = run(scenario, TrackerConfig(scan_period_s=PERIOD))
    assert isinstance(tracker.associator, MultipleHypothesisTracking)
    assert tracker.associator.stats.clusters_formed == 0
    assert out.tobytes() == gnn.tobytes()


def test_mht_settings_are_checked() -> None:
    with pytest.raises(ValueError, match="mht_n_scan >= 2"):
        TrackerConfig(association="mht", mht_n_scan=1)
    with pytest.raises(ValueError, match="mht_ambiguity_llr <= mht_prune_llr"):
        TrackerConfig(association="mht", mht_ambiguity_llr=10.0, mht_prune_llr=5.0)


def test_a_plot_left_over_next_to_a_track_starts_a_track_with_the_neighbours_velocity() -> None:
    """The ambiguous scan of ``_sidestep``: the plot the best hypothesis leaves (150 m
    south) starts a track at once, at the plot, with the neighbour's predicted velocity
    and that velocity's covariance widened by ``birth_relative_speed_sigma_m_s``
    (before, it waited for a two-point start with the next scan's left-over plot)."""
    batches = _sidestep()
    tracker = LocalTracker(MHT)
    for b in batches[:8]:
        tracker.process(b)
    before = tracker.tracks
    assert before.size == 1 and before["status"][0] == CONFIRMED
    plot = batches[8][batches[8]["plot_id"] == 9]
    dt = float(plot["time"][0]) - float(before["t"][0])
    neighbour = tracker.imm.predict(before["x"], before["P"], before["mu"], np.array([dt]))
    out = tracker.process(batches[8])
    born = out[out["track_number"] == 2]
    assert born["plot_id"].tolist() == [9]
    new = tracker.tracks[tracker.tracks["number"] == 2][0]
    np.testing.assert_allclose(new["xc"][:2], [plot["x"][0], plot["y"][0]], atol=1e-9)
    np.testing.assert_allclose(new["xc"][2:], neighbour.x_comb[0, 2:], rtol=1e-12)
    sigma = MHT.birth_relative_speed_sigma_m_s
    np.testing.assert_allclose(
        new["Pc"][2:, 2:], neighbour.P_comb[0, 2:, 2:] + sigma**2 * np.eye(2), rtol=1e-12
    )
    np.testing.assert_allclose(new["Pc"][:2, :2], plot["R"][0], rtol=1e-12)


def test_a_close_pair_far_out_keeps_its_identities_when_the_second_aircraft_appears() -> None:
    """Two primary-only aircraft 1 km abeam at 180 km (cross-range sigma 220 m), Pd 0.9,
    the second seen from scan 6 on. Before births next to a track, the second aircraft's
    left-over plots made a two-point track that started on the first aircraft's plots,
    and the two confirmed tracks exchanged aircraft three times."""
    targets = [
        Target(straight(0.0, dx, 180e3, 220.0), mode3a=-1, address=-1) for dx in (0.0, 1000.0)
    ]
    scenario = simulate(targets, scans=40, seed=8)
    drop = np.random.default_rng(108)
    tracker = LocalTracker(MHT)
    out = []
    for batch in scenario.batches:
        late = np.array(
            [scenario.owner[int(p)] == 1 and scenario.truth_time[int(p)] < 6 * PERIOD
             for p in batch["plot_id"]], dtype=bool,
        )  # fmt: skip
        detected = drop.random(len(batch)) < 0.9
        out.append(tracker.process(batch[detected & ~late]))
    rows = np.concatenate(out)
    rows = rows[(rows["plot_id"] >= 0) & (rows["status"] == CONFIRMED)]
    owners = np.array([scenario.owner[int(p)] for p in rows["plot_id"]])
    numbers = np.unique(rows["track_number"])
    assert len(numbers) == 2
    for number in numbers:
        mine = owners[rows["track_number"] == number]
        assert np.count_nonzero(mine[1:] != mine[:-1]) == 0
