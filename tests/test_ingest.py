"""Redundant-LAN duplicate recognition."""

from __future__ import annotations

from tracker_service.ingest import DuplicateFilter, DuplicateWindow


def test_a_copy_within_the_window_is_a_duplicate_and_a_later_one_is_not() -> None:
    dedup = DuplicateFilter(DuplicateWindow(seconds=1.0))
    assert not dedup.is_duplicate(b"a", 100.0)
    assert dedup.is_duplicate(b"a", 100.0004)  # LAN B, a moment later
    assert not dedup.is_duplicate(b"b", 100.5)
    assert not dedup.is_duplicate(b"a", 101.5)  # the same bytes a scan later: new data
    assert dedup.duplicates == 1


def test_a_copy_stamped_before_the_original_is_still_a_duplicate() -> None:
    dedup = DuplicateFilter(DuplicateWindow(seconds=1.0))
    assert not dedup.is_duplicate(b"a", 100.0)
    assert dedup.is_duplicate(b"a", 99.9999)


def test_midnight_wrap_of_time_of_day_ends_the_window() -> None:
    dedup = DuplicateFilter(DuplicateWindow(seconds=1.0))
    assert not dedup.is_duplicate(b"a", 86399.9)
    assert not dedup.is_duplicate(b"a", 5.0)


def test_without_times_the_window_counts_datagrams() -> None:
    dedup = DuplicateFilter(DuplicateWindow(datagrams=3))
    assert not dedup.is_duplicate(b"a", None)
    assert dedup.is_duplicate(b"a", None)
    for payload in (b"b", b"c", b"d"):
        dedup.is_duplicate(payload, None)
    assert not dedup.is_duplicate(b"a", None)
