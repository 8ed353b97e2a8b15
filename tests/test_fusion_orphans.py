"""Orphaned system tracks (fusion/lifecycle.py): a system track whose last local track
ended coasts for ``[fusion] orphan_coast_s``; a new local track within its gate whose
identity agrees takes it up, number kept (three_sites seeds 102 and 103: a primary-only
aircraft one radar sees, its local track deleted on three missed scans)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tracker_service.fusion import COASTING, ENDED, FusionConfig, SystemTracker
from tracker_service.tracking import COASTING as LOCAL_COASTING
from tracker_service.tracking import CONFIRMED, DELETED, PLOT_DTYPE, LocalTracker

T0 = 1.7e9
PERIOD = 5.0
SIGMA = 60.0
SPEED = 200.0
LOST, FOUND = 10, 16
"""The aircraft's local track has plots up to scan LOST, coasts two scans, is deleted on
the third; the radar's new track of it is confirmed at scan FOUND."""
OTHER = 9
"""A local track of another aircraft, 50 km away, that keeps the fuser's clock going."""


FL = 240.0

ORPHANS_ON = FusionConfig(orphan_coast_s=None)
"""Orphans on (off by default), coasting 5 x the longest period."""


def _update(
    number: int, k: int, y: float, status: int = CONFIRMED, address: int = -1, mode3a: int = -1
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """A local-track update at scan k (a plot unless coasting or deleted) and its plot."""
    t = T0 + PERIOD * k
    plotted = status == CONFIRMED
    plot_id = 1000 * number + k if plotted else -1
    u = np.zeros(1, dtype=LocalTracker().output_dtype)
    u["track_number"], u["time"], u["status"], u["plot_id"] = number, t, status, plot_id
    u["x"], u["y"], u["vx"], u["vy"] = SPEED * (t - T0), y, SPEED, 0.0
    u["P"] = np.diag([SIGMA**2, SIGMA**2, 9.0, 9.0]).reshape(16)
    u["flight_level"], u["climb_rate_fl_per_s"] = FL, 0.0
    u["mode3a"], u["address"] = mode3a, address
    u["model_probabilities"][0, 0] = 1.0
    p = np.zeros(int(plotted), dtype=PLOT_DTYPE)
    p["time"], p["x"], p["y"], p["plot_id"] = t, u["x"][0], y, plot_id
    p["R"] = np.diag([SIGMA**2, SIGMA**2])
    p["flight_level"], p["mode3a"], p["address"], p["typ"] = FL, mode3a, address, 1
    return u, p


def _run(
    config: FusionConfig,
    scans: int = 24,
    identity: tuple[int, int] = (-1, -1),
    new_identity: tuple[int, int] = (-1, -1),
) -> tuple[npt.NDArray[Any], list[npt.NDArray[Any]]]:
    """One radar: the aircraft's track 3 (lost after scan LOST), its new track 4 from scan
    FOUND, and the other aircraft's track 9 each scan. Returns the rows of the aircraft's
    system track(s) and, per scan, the fuser's output for track 4's update (none before
    it starts)."""
    fuser = SystemTracker(1, config)
    rows, new_track_rows = [], []
    for k in range(scans):
        batches = [_update(OTHER, k, 50_000.0)]
        if k <= LOST + 3:
            status = CONFIRMED if k <= LOST else LOCAL_COASTING if k < LOST + 3 else DELETED
            batches.append(_update(3, k, 0.0, status, *identity))
        if k >= FOUND:
            batches.append(_update(4, k, 0.0, CONFIRMED, *new_identity))
        for n, (u, p) in enumerate(batches):
            out = fuser.process(0, u, p)
            rows.append(out)
            if k >= FOUND and n == len(batches) - 1:
                new_track_rows.append(out[out["local_numbers"][:, 0] == 4])
    every = np.concatenate(rows)
    other = every["system_number"][every["local_numbers"][:, 0] == OTHER][0]
    return every[every["system_number"] != other], new_track_rows


def test_an_orphan_keeps_its_number_when_its_radars_new_track_comes_within_the_gate() -> None:
    rows, new_track_rows = _run(ORPHANS_ON)
    assert np.unique(rows["system_number"]).size == 1  # main: a second number at FOUND
    assert not (rows["status"] == ENDED).any()
    # Published coasting in the gap (CAT062 I080 CST), predicted at the fuser's clock,
    # with no local track left to list.
    gap = rows[(rows["time"] > T0 + PERIOD * (LOST + 3)) & (rows["time"] < T0 + PERIOD * FOUND)]
    assert len(gap) >= 2
    assert (gap["status"] == COASTING).all() and (gap["n_sources"] == 0).all()
    assert (gap["flight_level"] == FL).all()  # the last one known
    sigma_x = np.sqrt(gap["P"][:, 0])
    assert (np.abs(gap["x"] - SPEED * (gap["time"] - T0)) < 3.0 * sigma_x).all()
    assert (np.diff(sigma_x) > 0).all()  # growing as it coasts
    np.testing.assert_allclose(gap["vx"], gap["vx"][0])  # in a straight line
    # The lone radar's new track is followed as a system track it founded would be.
    for out in new_track_rows:
        (row,) = out
        assert row["status"] == CONFIRMED
        assert row["x"] == SPEED * (row["time"] - T0)


@pytest.mark.parametrize(
    ("identity", "new_identity"),
    [((0x3C6544, -1), (0x4B1A2F, -1)), ((-1, 0o1234), (-1, 0o4321))],
    ids=["address", "mode3a"],
)
def test_an_orphan_is_not_taken_up_by_a_track_of_another_identity(
    identity: tuple[int, int], new_identity: tuple[int, int]
) -> None:
    rows, new_track_rows = _run(ORPHANS_ON, identity=identity, new_identity=new_identity)
    orphan = rows["system_number"][0]
    assert all(out["system_number"][0] != orphan for out in new_track_rows)
    # The same identity is taken up.
    rows, new_track_rows = _run(ORPHANS_ON, identity=identity, new_identity=identity)
    assert np.unique(rows["system_number"]).size == 1


def test_an_orphan_ends_after_orphan_coast_s() -> None:
    coast = 3.0 * PERIOD
    rows, new_track_rows = _run(FusionConfig(orphan_coast_s=coast), scans=FOUND + 2)
    orphaned_at = T0 + PERIOD * (LOST + 3)
    (ended,) = rows[rows["status"] == ENDED]
    assert orphaned_at + coast <= ended["time"] < orphaned_at + coast + PERIOD
    assert all(out["system_number"][0] != ended["system_number"] for out in new_track_rows)
    # 0: ended with its last local track (the fuser before orphans coasted).
    rows, _ = _run(FusionConfig(orphan_coast_s=0.0), scans=FOUND)
    (ended,) = rows[rows["status"] == ENDED]
    assert ended["time"] == T0 + PERIOD * LOST  # at once, its last plot's state


def test_orphan_coast_s_is_checked() -> None:
    assert FusionConfig(longest_period_s=8.0).orphan_coast == 0.0  # off by default
    assert FusionConfig(longest_period_s=8.0, orphan_coast_s=None).orphan_coast == 40.0
    with pytest.raises(ValueError, match="orphan_coast_s"):
        FusionConfig(orphan_coast_s=-1.0)
