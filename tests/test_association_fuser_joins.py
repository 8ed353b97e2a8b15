"""The fuser's first join of a local track that two system tracks could take alike waits
(``FusionConfig.join_ambiguity_margin``, fusion/associate.py ``_ambiguous_joins``); a
radar's two tracks that founded together never merge into one system track
(docs/association.md "Session 9", "Session 10")."""

from __future__ import annotations

from tests.fuser_inputs import east_batch, system_of
from tracker_service.fusion import FusionConfig, SystemTracker

T0 = 1.7e9
SPEED = 200.0
APART = 1000.0
YOUNG_S = 12.0


def _crosswise_moments(margin: float) -> int:
    """Aircraft A (y = 0) and B (1 km abeam) parallel, primary only. Radar 0 (4 s) tracks
    them from the start (tracks 10, 20: 150 m); radar 1 (5 s) confirms its tracks 11 (A)
    and 21 (B) at T0 + 2.5 s, young (400 m) and, for their first ``YOUNG_S`` seconds, 300
    and 200 m north of the line (noise and bias of a new track): A's nearer B's system
    track, B's nearer A's. The radar-1 updates after which track 11 feeds B's system
    track or 21 A's."""
    fuser = SystemTracker(2, FusionConfig(join_ambiguity_margin=margin, found_delay_s=30.0))
    events = sorted(
        (T0 + 2.5 * r + period * k, r) for r, period in enumerate((4.0, 5.0)) for k in range(12)
    )
    crosswise = 0
    for plot_id, (t, radar) in enumerate(events):
        young = radar == 1 and t - T0 < YOUNG_S
        ys = [300.0, 200.0] if young else [0.0, APART]
        u, p = east_batch(
            [10 + radar, 20 + radar],
            t,
            SPEED * (t - T0),
            ys,
            400.0 if young else 150.0,
            2 * plot_id,
            SPEED,
        )
        fuser.process(radar, u, p)
        if radar == 1:
            a, b = system_of(fuser, 1, 11), system_of(fuser, 1, 21)
            crosswise += (a > 0 and a == system_of(fuser, 0, 20)) or (
                b > 0 and b == system_of(fuser, 0, 10)
            )
    assert system_of(fuser, 0, 10) != system_of(fuser, 0, 20)
    return crosswise


def test_an_ambiguous_first_join_waits_for_the_tracks_to_tell() -> None:
    # Off (the default): radar 1's young tracks join crosswise at once and stay so.
    assert _crosswise_moments(margin=0.0) > 0
    # On: they wait, then join the right system tracks.
    assert _crosswise_moments(margin=4.0) == 0


def test_the_wait_ends_after_the_found_delay() -> None:
    """Two tracks of radar 1 that stay ambiguous (both on the line between the aircraft)
    join after ``found_delay_s``, as GNN would have at once."""
    fuser = SystemTracker(2, FusionConfig(join_ambiguity_margin=4.0, found_delay_s=20.0))
    joined_at = []
    for k in range(20):
        t = T0 + 2.5 * k
        radar = k % 2
        ys = [500.0, 500.0] if radar == 1 else [0.0, APART]
        u, p = east_batch([10 + radar, 20 + radar], t, SPEED * (t - T0), ys, 600.0, 2 * k, SPEED)
        fuser.process(radar, u, p)
        if radar == 1 and system_of(fuser, 1, 11) > 0 and system_of(fuser, 1, 21) > 0:
            joined_at.append(t)
    # First seen at T0 + 2.5 s; every 5 s since; joined at the first update 20 s later.
    assert joined_at and joined_at[0] == T0 + 22.5


def test_two_tracks_of_one_radar_never_merge_into_one_system_track() -> None:
    """Radar 0 (4 s) holds one track (10) on two aircraft 300 m apart; radar 1's two
    tracks of them (11, 21) first lie 3 km off (an unknown bias), each founds a system
    track, then come onto the aircraft: both system tracks pass the merge test with radar
    0's for ``merge_after`` updates in a row, in the same batches. One merges into it; the
    other may not follow, since radar 1's tracks are two aircraft."""
    fuser = SystemTracker(2, FusionConfig(join_ambiguity_margin=0.0))
    for k in range(16):
        t = T0 + 2.5 * k
        radar = k % 2
        if radar == 0:
            u, p = east_batch([10], t, SPEED * (t - T0), 0.0, 150.0, 2 * k, SPEED)
        else:
            off = 3000.0 if k < 4 else 0.0
            ys = [off - 150.0, off + 150.0]
            u, p = east_batch([11, 21], t, SPEED * (t - T0), ys, 150.0, 2 * k, SPEED)
        fuser.process(radar, u, p)
    a, b = system_of(fuser, 1, 11), system_of(fuser, 1, 21)
    assert a > 0 and b > 0 and a != b
    assert fuser.state.stats.system_tracks_merged == 1
    assert system_of(fuser, 0, 10) in (a, b)
