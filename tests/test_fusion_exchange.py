"""The fuser's exchange test (fusion/associate.py ``_exchange``): a radar's two local
tracks of two close aircraft joined crosswise to two system tracks go back to the right
ones; and a local track the review gave back does not rejoin the system track it left;
the test's evidence store (fusion/state.py ``PairEvidence``) against a plain dictionary."""

from __future__ import annotations

from typing import Any
from unittest import mock

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.fuser_inputs import east_batch, system_of
from tracker_service.fusion import FusionConfig, SystemTracker, state
from tracker_service.fusion.state import NO_EVIDENCE, PairEvidence

T0 = 1.7e9
SIGMA = 150.0
SPEED = 200.0
APART = 500.0
PERIODS = (4.0, 5.0, 6.0)


def _batch(
    numbers: list[int],
    t: float,
    ys: list[float],
    rng: np.random.Generator,
    first_id: int,
    sigma: float = SIGMA,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """One radar's batch at ``ys`` abeam, 20 m of noise on each coordinate."""
    k = len(numbers)
    x = SPEED * (t - T0) + rng.normal(0, 20, k)
    y = np.array(ys) + rng.normal(0, 20, k)
    return east_batch(numbers, t, x, y, sigma, first_id, SPEED)


def _crosswise(margin: float, kappa: float = 1e9, sigma: float = SIGMA) -> SystemTracker:
    """Aircraft A (y = 0) and B (500 m abeam), parallel, primary only, seen by three
    radars, each with local tracks 10+r (A) and 20+r (B). Radar 0's two tracks swap
    aircraft after 40 s (a local swap, as in the first scans of a close pair): its track
    10 now follows B inside A's system track, and its track 20 A inside B's. The
    consistency test is off unless ``kappa`` is given (at 500 m abeam and 150 m it may fire
    too; in the recordings' close pairs, with the radars' residual biases in the
    covariance, it mostly does not)."""
    fuser = SystemTracker(3, FusionConfig(exchange_margin=margin, reassociate_kappa=kappa))
    rng = np.random.default_rng(7)
    events = sorted(
        (T0 + 0.5 * r + period * k, r)
        for r, period in enumerate(PERIODS)
        for k in range(int(200 / period))
    )
    for plot_id, (t, radar) in enumerate(events):
        swapped = radar == 0 and t - T0 > 40.0
        ys = [APART, 0.0] if swapped else [0.0, APART]
        u, p = _batch([10 + radar, 20 + radar], t, ys, rng, 2 * plot_id, sigma)
        fuser.process(radar, u, p)
    return fuser


def _assert_right(fuser: SystemTracker) -> None:
    # Radar 0's track 10 now follows B: it feeds B's system track (radar 1's 21's).
    assert system_of(fuser, 0, 10) == system_of(fuser, 1, 21) == system_of(fuser, 2, 22)
    assert system_of(fuser, 0, 20) == system_of(fuser, 1, 11) == system_of(fuser, 2, 12)


def test_a_radars_two_tracks_joined_crosswise_are_exchanged() -> None:
    fuser = _crosswise(margin=2.0)
    assert fuser.state.stats.exchanges == 1
    assert fuser.state.stats.reassociations == 0
    _assert_right(fuser)
    # Off: each blocks the other's system track, so they never get there.
    off = _crosswise(margin=0.0)
    assert off.state.stats.exchanges == 0
    assert system_of(off, 0, 10) != system_of(off, 1, 21)


def test_given_back_tracks_join_the_right_system_tracks() -> None:
    """Local tracks of 60 m: 500 m off, both of radar 0's tracks fail the gate and are
    given back; each joins the other's system track: two re-associations, no
    oscillation (the rule against rejoining: tests/test_fusion_reassociation.py)."""
    fuser = _crosswise(margin=0.0, kappa=FusionConfig().reassociate_kappa, sigma=60.0)
    assert fuser.state.stats.reassociations == 2
    _assert_right(fuser)


def test_two_tracks_that_never_swapped_are_not_exchanged() -> None:
    fuser = SystemTracker(3, FusionConfig())
    rng = np.random.default_rng(8)
    for k in range(150):
        radar = k % 3
        u, p = _batch([10 + radar, 20 + radar], T0 + 1.5 * k, [0.0, APART], rng, 2 * k)
        fuser.process(radar, u, p)
    assert fuser.state.stats.exchanges == 0
    assert system_of(fuser, 0, 10) == system_of(fuser, 1, 11) == system_of(fuser, 2, 12)
    assert system_of(fuser, 0, 10) != system_of(fuser, 0, 20)


class PlainEvidence:
    """``PairEvidence``'s reference: a dictionary of pairs, every pair of a dropped key
    deleted at once."""

    def __init__(self) -> None:
        self.of_pair: dict[tuple[int, int], tuple[float, ...]] = {}

    def table(self, pairs: list[tuple[int, int]]) -> npt.NDArray[np.float64]:
        rows = [self.of_pair.get(pair, NO_EVIDENCE) for pair in pairs]
        return np.array(rows, dtype=np.float64).reshape(-1, 3)

    def renew(
        self, tested: list[int], pairs: list[tuple[int, int]], evidence: npt.NDArray[np.float64]
    ) -> None:
        self.drop(tested)
        self.of_pair.update(zip(pairs, map(tuple, evidence.tolist()), strict=True))

    def drop(self, keys: list[int]) -> None:
        gone = set(keys)
        self.of_pair = {p: e for p, e in self.of_pair.items() if not gone & set(p)}


def _columns(pairs: list[tuple[int, int]]) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.int64]]:
    """The pairs' low and high keys."""
    both = np.array(pairs, dtype=np.int64).reshape(-1, 2)
    return both[:, 0].copy(), both[:, 1].copy()


OPERATIONS = st.lists(
    st.tuples(
        st.booleans(),  # a drop (else a renewal)
        st.lists(st.tuples(st.integers(0, 30), st.integers(0, 30)), max_size=12),
        st.lists(st.integers(0, 30), max_size=6),  # a renewal's tested keys
    ),
    max_size=200,
)


@pytest.mark.parametrize("compiled", [False, True])
@settings(max_examples=40, deadline=None)
@given(operations=OPERATIONS, sweep_min=st.integers(1, 40))
def test_pair_evidence_forgets_as_the_plain_reference(
    compiled: bool,
    operations: list[tuple[bool, list[tuple[int, int]], list[int]]],
    sweep_min: int,
) -> None:
    """Drops and renewals in any order, keys dropped before and after their pairs'
    writes, pairs written again after a drop, a renewal's tested keys among its pairs'
    and not, sweeps at every size, in Python's
    dictionaries and in the kernels' typed ones: each lookup finds what the plain
    dictionary holds (the evidence of a written pair, ``NO_EVIDENCE`` of one forgotten
    or never written)."""
    with mock.patch.object(state, "SWEEP_MIN_PAIRS", sweep_min):
        _replay_against_plain(PairEvidence(compiled), operations)


def _replay_against_plain(
    evidence: PairEvidence, operations: list[tuple[bool, list[tuple[int, int]], list[int]]]
) -> None:
    plain = PlainEvidence()
    every = [(a, b) for a in range(31) for b in range(a, 31) if (a * b) % 7 == 0]
    for step, (is_drop, drawn, tested) in enumerate(operations):
        pairs = sorted({(min(a, b), max(a, b)) for a, b in drawn})
        if is_drop:
            keys = [a for a, _ in drawn]
            evidence.drop(np.array(keys, dtype=np.int64))
            plain.drop(keys)
        else:
            k = np.arange(len(pairs))
            values = np.column_stack([np.full(k.size, step), 0.5 * step + k, 1.0 / (k + 1)])
            evidence.renew(np.array(tested, dtype=np.int64), *_columns(pairs), values)
            plain.renew(tested, pairs, values)
        np.testing.assert_array_equal(evidence.table(*_columns(every)), plain.table(every))


@pytest.mark.parametrize("compiled", [False, True])
def test_pair_evidence_stays_bounded_when_tracks_end_without_pairs(compiled: bool) -> None:
    """A site with few pairs still ends local tracks, whose keys are never used again
    (ADS-B tracks and a restarted radar stage number on): their drop stamps are swept
    like the entries, so the store does not grow with the daemon's age."""
    evidence = PairEvidence(compiled)
    pair = np.array([1], dtype=np.int64), np.array([2], dtype=np.int64)
    for batch in range(3 * state.SWEEP_MIN_PAIRS // 50):
        evidence.renew(np.array([1], dtype=np.int64), *pair, np.array([[batch, 0.5, 1.0]]))
        evidence.drop(np.arange(1000 + 50 * batch, 1000 + 50 * (batch + 1), dtype=np.int64))
        assert evidence.held <= state.SWEEP_MIN_PAIRS
    np.testing.assert_array_equal(
        evidence.table(*pair), [[3 * state.SWEEP_MIN_PAIRS // 50 - 1, 0.5, 1.0]]
    )
