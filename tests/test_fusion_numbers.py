"""System track numbers at ARTAS-class load: 4,000 aircraft in the air, with the tracks
ended in the last ``number_reuse_delay_s`` still holding theirs (docs/benchmarks.md,
"Session 15": 4,095 numbers ran out 90 s into `artas`, and new aircraft went without a
system track until numbers came free)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.fusion.messages import MAX_SYSTEM_NUMBER
from tracker_service.tracking import PLOT_DTYPE, LocalTracker

CONFIRMED, DELETED = 1, 3


def _updates(numbers: npt.NDArray[np.int64], t: float, status: int = CONFIRMED) -> Any:
    """One update of each local track, the tracks 20 km apart on a line, none with an
    identity: each founds a system track of its own."""
    rows = np.zeros(len(numbers), dtype=LocalTracker().output_dtype)
    rows["track_number"] = numbers
    rows["time"] = t
    rows["x"] = 20_000.0 * numbers
    rows["vx"] = 200.0
    rows["P"] = np.diag([900.0, 900.0, 25.0, 25.0]).reshape(-1)
    rows["status"] = status
    rows["plot_id"] = 1_000_000 * int(t) + numbers
    rows["address"] = rows["mode3a"] = -1
    return rows


def test_4000_live_tracks_and_600_ended_within_the_delay_all_have_numbers() -> None:
    fuser = SystemTracker(1, FusionConfig(method="tracks", number_reuse_delay_s=300.0))
    empty = np.zeros(0, dtype=PLOT_DTYPE)
    first = np.arange(1, 4601)
    fuser.process(0, _updates(first, 0.0), empty)
    assert len(fuser.system_tracks) == 4600
    # 600 end (their aircraft left), 600 new ones enter within the reuse delay: their
    # numbers must not be the ended tracks', nor missing.
    fuser.process(0, _updates(first[:600], 10.0, DELETED), empty)
    t = 10.0
    while len(fuser.system_tracks) > 4000 and t < 120.0:
        t += 10.0
        fuser.process(0, _updates(first[600:], t), empty)
    assert len(fuser.system_tracks) == 4000
    ended = set(range(1, 4601)) - set(fuser.system_tracks.tolist())
    fuser.process(0, _updates(np.arange(5001, 5601), t + 10.0), empty)
    live = fuser.system_tracks
    assert len(live) == 4600
    assert fuser.stats.numbers_exhausted == 0
    assert not ended & set(live.tolist())
    assert live.max() <= MAX_SYSTEM_NUMBER
