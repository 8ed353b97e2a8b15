"""System track numbers at ARTAS-class load: 4,000 aircraft in the air, with the tracks
ended in the last ``number_reuse_delay_s`` still holding theirs (docs/benchmarks.md,
"Session 15": 4,095 numbers ran out 90 s into `artas`, and new aircraft went without a
system track until numbers came free)."""

from __future__ import annotations

import os
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.fusion.lifecycle import number_shortage_reasons
from tracker_service.fusion.messages import MAX_SYSTEM_NUMBER
from tracker_service.fusion.table import LOCAL_ROWS
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


def test_numbers_within_their_delay_are_taken_longest_ended_first_when_none_is_free() -> None:
    """Every number live or ended within the delay: a new aircraft still gets a system
    track, under the number whose track ended longest ago, and the status says so; only
    with every number live does a founding wait."""
    fuser = SystemTracker(1, FusionConfig(method="tracks", number_reuse_delay_s=300.0))
    empty = np.zeros(0, dtype=PLOT_DTYPE)
    every = np.arange(1, MAX_SYSTEM_NUMBER + 1)
    fuser.process(0, _updates(every, 0.0), empty)
    assert len(fuser.system_tracks) == MAX_SYSTEM_NUMBER

    def end(gone: npt.NDArray[np.int64], staying: npt.NDArray[np.int64], t: float) -> float:
        """The local tracks ``gone`` deleted at t, the others updated until their system
        tracks' coast is over; returns the time then."""
        fuser.process(0, _updates(gone, t, DELETED), empty)
        target = len(staying)
        while len(fuser.system_tracks) > target:
            t += 10.0
            fuser.process(0, _updates(staying, t), empty)
        return t

    live = set(fuser.system_tracks.tolist())
    t = end(every[:3], every[3:], 10.0)
    first = sorted(live - set(fuser.system_tracks.tolist()))
    live = set(fuser.system_tracks.tolist())
    t = end(every[3:6], every[6:], t + 10.0)
    second = sorted(live - set(fuser.system_tracks.tolist()))
    assert len(first) == len(second) == 3
    stats = fuser.stats
    assert stats.numbers_reused_early == stats.numbers_exhausted == 0
    assert number_shortage_reasons(stats, fuser.config, t) == []
    assert t < 300.0  # every ended number is still within its delay

    t += 10.0
    fuser.process(0, _updates(np.array([20_001, 20_002]), t), empty)
    assert stats.numbers_reused_early == 2 and stats.numbers_exhausted == 0
    assert set(fuser.system_tracks.tolist()) - live == set(first[:2])
    (reason,) = number_shortage_reasons(stats, fuser.config, t)
    assert reason.startswith("fusion: system track numbers ran short: 2 track(s)"), reason
    assert "number_reuse_delay_s (300 s)" in reason
    assert number_shortage_reasons(stats, fuser.config, t + 61.0) == []

    # Four numbers idle (one of the first ended, three of the second): five aircraft.
    fuser.process(0, _updates(np.arange(20_003, 20_008), t + 1.0), empty)
    assert len(fuser.system_tracks) == MAX_SYSTEM_NUMBER
    assert stats.numbers_reused_early == 6 and stats.numbers_exhausted == 1


def resident_share(array: npt.NDArray[Any]) -> float:
    """The share of an array's pages in memory (/proc/self/pagemap's "present" bit)."""
    page = os.sysconf("SC_PAGE_SIZE")
    first, last = array.ctypes.data // page, (array.ctypes.data + array.nbytes - 1) // page
    with open("/proc/self/pagemap", "rb") as pagemap:
        pagemap.seek(8 * first)
        entries = np.frombuffer(pagemap.read(8 * (last - first + 1)), dtype="<u8")
    return float(np.mean(entries >> np.uint64(63)))


def test_the_table_of_every_number_is_resident_from_the_start() -> None:
    """Sized for every number (about 20 kB a number with 48 radars), the system table
    once grew the fusion process's memory for the whole of a half-hour run as numbers
    were first used (lazily mapped zeros): written at start, it shows at once."""
    fuser = SystemTracker(48, FusionConfig())
    columns = fuser.state.sys.values()
    assert sum(column.nbytes for column in columns) > 100 * 2**20
    assert min(resident_share(column) for column in columns) == 1.0


def test_the_local_track_table_is_sized_for_the_system_and_resident() -> None:
    """The local-track table holds four local tracks a system number, twice over for
    the deleted rows awaiting compaction, from the start: grown by doubling at the
    traffic's peak, it took 24 MB in one step some fifteen minutes into ``artas``."""
    fuser = SystemTracker(48, FusionConfig())
    local = fuser.state.local
    assert local.rows.shape[0] == LOCAL_ROWS == 8 * (MAX_SYSTEM_NUMBER + 1)
    assert min(resident_share(column) for column in local.rows.values()) == 1.0
