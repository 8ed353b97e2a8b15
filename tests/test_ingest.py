"""Ingest: redundant-LAN duplicate recognition and the times of plots."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from asterix import Block, decode_blocks, encode_block
from asterix.plots import extract_plots
from tracker_service.ingest import (
    SERVICE_REFERENCE_S,
    DuplicateFilter,
    DuplicateWindow,
    PlotClock,
    TimeSource,
    posix_from_time_of_day,
    unroll_truncated_time,
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


# --- CAT001: the truncated time of day (I141, modulo 512 s) -------------------------------

MIDNIGHT = 1_780_272_000.0  # 2026-06-01T00:00:00Z


def _truncated(posix: np.ndarray) -> np.ndarray:
    """I141 of a time: the time of day in 1/128 s, its low 16 bits (written out here
    independently of the clock)."""
    ticks = np.round(np.mod(posix, 86400.0) * 128).astype(np.int64)
    return np.asarray((ticks & 0xFFFF) / 128.0)


def test_truncated_time_unrolls_to_the_time_nearest_the_reference() -> None:
    rng = np.random.default_rng(7)
    # True times quantised to I141's 1/128 s: within a day, the reference may be up to
    # 256 s away; around midnight the day's last period is 384 s long, so 192 s.
    within = MIDNIGHT + rng.uniform(600.0, 86400.0 - 600.0, 10_000)
    around = MIDNIGHT + rng.uniform(-600.0, 600.0, 10_000)
    true = np.round(np.concatenate([within, around]) * 128) / 128
    offsets = np.concatenate(
        [rng.uniform(-255.0, 255.0, len(within)), rng.uniform(-191.0, 191.0, len(around))]
    )
    for t, offset in zip(true.tolist(), offsets.tolist(), strict=True):
        (got,) = unroll_truncated_time(_truncated(np.array([t])), t + offset)
        assert got == t, (t, offset, got)


def test_midnight_in_both_directions() -> None:
    # Received just after midnight, measured just before (I141 383.0 = 86399 s mod 512).
    assert unroll_truncated_time(np.array([383.0]), MIDNIGHT + 1.0)[0] == MIDNIGHT - 1.0
    # Received just before midnight, measured just after.
    assert unroll_truncated_time(np.array([2.0]), MIDNIGHT - 0.5)[0] == MIDNIGHT + 2.0


def _cat001_plot(truncated: float, sac: int = 20, sic: int = 130) -> np.ndarray:
    payload = encode_block(
        1,
        [
            {
                "010": {"SAC": sac, "SIC": sic},
                "020": {"TYP": 0, "SIM": 0, "SSRPSR": 2, "ANT": 0, "SPI": 0, "RAB": 0},
                "040": {"RHO": 50.0, "THETA": 10.0},
                "141": truncated,
            }
        ],
    )
    return extract_plots(payload).plots


def _cat002(kind: int, time_of_day: float, sac: int = 20, sic: int = 130) -> dict[str, Any]:
    block = encode_block(2, [{"010": {"SAC": sac, "SIC": sic}, "000": kind, "030": time_of_day}])
    (event,) = decode_blocks(block)
    assert isinstance(event, Block)
    return event.records[0]


def test_cat001_plots_are_timed_on_the_radars_own_clock() -> None:
    # The capture's clock is an hour ahead of the radar's: only the radar's service
    # messages (CAT002 I030) give the plots their time.
    lag = 3600.0
    measured = MIDNIGHT + 40_000.25
    clock = PlotClock()
    plots = _cat001_plot(float(_truncated(np.array([measured]))[0]))
    times, sources = clock.times(plots, measured + lag)
    assert sources.tolist() == [TimeSource.I141_RECEPTION]
    assert abs(times[0] - (measured + lag)) <= 256.0 and times[0] != measured
    # A sector crossing 2 s before the plot, received 0.1 s after its I030.
    clock.service_message(_cat002(2, measured - 2.0 - MIDNIGHT), measured - 1.9 + lag)
    times, sources = clock.times(plots, measured + 0.5 + lag)
    assert sources.tolist() == [TimeSource.I141_SERVICE]
    assert times[0] == measured
    # Another radar's messages are no reference for this one.
    other = PlotClock()
    other.service_message(_cat002(1, measured - MIDNIGHT, sic=131), measured + lag)
    assert other.times(plots, measured + lag)[1].tolist() == [TimeSource.I141_RECEPTION]
    # A reference too old is not used.
    times, sources = clock.times(plots, measured + lag + SERVICE_REFERENCE_S + 1.0)
    assert sources.tolist() == [TimeSource.I141_RECEPTION]


def test_cat002_north_markers_time_plots_without_any_time() -> None:
    clock = PlotClock()
    record = _cat002(1, 1000.0)
    record["041"] = 4.0
    clock.service_message(record, MIDNIGHT + 1000.1)
    plots = _cat001_plot(0.0)
    plots["truncated_time"] = np.nan  # a plot without I141
    times, sources = clock.times(plots, MIDNIGHT + 1003.0)
    assert sources.tolist() == [TimeSource.AZIMUTH]
    assert abs(times[0] - (MIDNIGHT + 1000.0 + plots["theta"][0] / 360.0 * 4.0)) < 1e-9


def test_antenna_period_from_north_markers_without_i041() -> None:
    clock = PlotClock()
    assert clock.antenna_period(20, 130) is None
    for tod in (1000.0, 1004.0):
        clock.service_message(_cat002(1, tod), MIDNIGHT + tod + 0.1)
    assert clock.antenna_period(20, 130) == 4.0
    # A lost north marker: one turn looks 8 s long and is not taken.
    clock.service_message(_cat002(1, 1012.0), MIDNIGHT + 1012.1)
    assert clock.antenna_period(20, 130) == 4.0
    clock.service_message(_cat002(1, 1016.0), MIDNIGHT + 1016.1)
    assert clock.antenna_period(20, 130) == 4.0
    # Sector messages say nothing of the period.
    clock.service_message(_cat002(2, 1017.0), MIDNIGHT + 1017.1)
    assert clock.antenna_period(20, 130) == 4.0
