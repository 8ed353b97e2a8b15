"""Ingest: redundant-LAN duplicate recognition and the times of plots."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from asterix import Block, decode_blocks
from asterix.plots import extract_plots
from tracker_service.ingest import (
    DuplicateFilter,
    DuplicateWindow,
    PlotClock,
    TimeSource,
    posix_from_time_of_day,
)
from tracker_service.simulator.recording import read_recording
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario


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


# --- plot times ---------------------------------------------------------------------------


def test_time_of_day_lands_on_the_day_nearest_the_reception() -> None:
    midnight = 1_780_272_000.0  # 2026-06-01T00:00:00Z
    times = posix_from_time_of_day(np.array([86399.9, 0.1, 43200.0]), midnight + 0.2)
    assert np.allclose(times, [midnight - 0.1, midnight + 0.1, midnight + 43200.0])


def test_plots_without_i140_are_timed_from_their_azimuth(tmp_path: Path) -> None:
    scenario = Scenario.model_validate(
        {
            "name": "clock",
            "seed": 4,
            "start": "2026-06-01T23:58:30Z",
            "duration_s": 120.0,
            "system_centre": {"lat": 48.0, "lon": 17.0},
            "radars": [
                {
                    "name": "r",
                    "sac": 1,
                    "sic": 2,
                    "lat": 48.0,
                    "lon": 17.0,
                    "alt_m": 300.0,
                    "antenna_period_s": 6.0,
                    "psr": False,
                    "initial_azimuth_deg": 123.0,
                    "pathologies": {"missing_time": 0.4},
                }
            ],
            "traffic": {
                "count": 30,
                "area": {"lat_min": 47.2, "lat_max": 48.8, "lon_min": 16.0, "lon_max": 18.0},
            },
        }
    )
    out = tmp_path / "clock.mcap"
    simulate(scenario, out)
    recording = read_recording(out)
    origins = {m["sequence"]: m["records"] for m in recording.messages("/truth/plots")}
    clock = PlotClock()
    errors: dict[TimeSource, list[float]] = {source: [] for source in TimeSource}
    for sequence, datagram in enumerate(recording.datagrams()):
        for event in decode_blocks(datagram.payload):
            if isinstance(event, Block) and event.cat == 34:
                for items in event.records:
                    clock.service_message(items, datagram.time)
        plots = extract_plots(datagram.payload).plots
        if len(plots) == 0:
            continue
        times, sources = clock.times(plots, datagram.time)
        for t, source, origin in zip(times, sources, origins[sequence], strict=True):
            errors[TimeSource(int(source))].append(t - origin["detection_time"])
    # Across midnight, I140 and the azimuth both give the time of measurement.
    assert np.abs(errors[TimeSource.I140]).max() <= 1 / 256
    assert len(errors[TimeSource.AZIMUTH]) > 200
    # The azimuth carries the plot's noise (0.06 deg) and the 1/128 s of the north marker.
    assert np.abs(errors[TimeSource.AZIMUTH]).max() < 0.02
    # Before the first north marker only the reception time is known: it is late.
    assert all(0.0 < e < 6.0 / 16 + 0.1 for e in errors[TimeSource.RECEPTION])
