"""The local tracker on a real capture: 068test_bds30.gps (one Spanish radar, SAC 20/SIC 4).

Two aircraft hold in view for the whole 79 minutes: Mode S 343085 (951 plots, FL56-80,
never a missed scan) and 3430D8 (879 plots, FL39-51). 3430D8 first shows 150 s into the
capture and has two gaps beyond the deletion threshold (3 missed scans at 4.98 s: a plot
gap over 16.2 s), 44.9 s and 54.9 s: a confirmed track cannot bridge those, so each run
of its plots with no longer gap must keep one track, and the aircraft gets three.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tracker_service.chain import PlotUse
from tracker_service.evaluation.real_data import (
    NOMINAL_SITE_068,
    CaptureRun,
    address_stretches,
    north_marker_periods,
    prediction_residuals,
    summarise,
    track_capture,
)
from tracker_service.tracking import CONFIRMED

CAPTURE = (
    Path(__file__).resolve().parents[1].parent
    / "shared/data/asterix/reader_network/068test_bds30.gps"
)
ADDRESSES = ("343085", "3430D8")
SOURCE = "20/4"


@pytest.fixture(scope="module")
def run() -> CaptureRun:
    if not CAPTURE.is_file():
        pytest.skip(f"{CAPTURE} is absent: the shared sample data is not beside the repo")
    runs = track_capture(CAPTURE, NOMINAL_SITE_068, None, 50.0, 0.07, None)
    assert list(runs) == [SOURCE]
    return runs[SOURCE]


def test_scan_period_from_north_markers(run: CaptureRun) -> None:
    assert run.tracker_config.scan_period_s == pytest.approx(4.99, abs=0.01)
    assert run.info.period_s == run.tracker_config.scan_period_s


def test_plots_as_described(run: CaptureRun) -> None:
    assert len(run.plots) == 1830
    summary, _ = summarise(run)
    assert sorted(summary) == sorted(ADDRESSES)
    assert summary["343085"].plots == 951
    assert summary["3430D8"].plots == 879
    assert summary["3430D8"].largest_gap_s == pytest.approx(54.9, abs=0.1)
    span = float(run.plots["time"].max() - run.plots["time"].min())
    assert span / 60 == pytest.approx(79, abs=0.5)


def test_every_plot_time_is_plausible(run: CaptureRun) -> None:
    """79 minutes of a real radar: time sanity keeps every plot (none is implausible
    against its north markers, its azimuth or its reception)."""
    assert np.all(run.plots["use"] == PlotUse.TRACKED)


def test_one_confirmed_track_per_continuous_stretch(run: CaptureRun) -> None:
    summary, _ = summarise(run)
    # 343085 is never lost: exactly one track. 3430D8: one per stretch (three).
    assert len(summary["343085"].stretches) == 1
    assert len(summary["3430D8"].stretches) == 3
    for address in ADDRESSES:
        entry = summary[address]
        assert len(entry.tracks) == len(entry.stretches), address
        # Each stretch is held by its own track from (nearly) its first plot to its last:
        # confirmation takes 3 of 4 scans; the first plot only initiates.
        for (first, last), track in zip(entry.stretches, entry.tracks, strict=True):
            assert track.first_s - first <= 3 * run.tracker_config.scan_period_s + 0.1
            assert track.last_s == pytest.approx(last)
            assert track.first_s >= first


def test_no_track_mixes_the_aircraft(run: CaptureRun) -> None:
    summary, _ = summarise(run)
    numbers = [t.track_number for entry in summary.values() for t in entry.tracks]
    assert len(numbers) == len(set(numbers))


def test_no_false_confirmed_track(run: CaptureRun) -> None:
    """No confirmed track living more than 3 scans without plots of the two aircraft."""
    summary, anonymous = summarise(run)
    assert anonymous == []
    ours = {t.track_number for entry in summary.values() for t in entry.tracks}
    updates = run.updates
    for number in set(updates["track_number"][updates["status"] == CONFIRMED].tolist()) - ours:
        rows = updates[updates["track_number"] == number]
        life = float(rows["time"].max() - rows["time"].min())
        assert life <= 3 * run.tracker_config.scan_period_s, number


def test_tracks_follow_their_plots(run: CaptureRun) -> None:
    """Plots against the track's prediction: the RMS per axis within twice the plots' own
    nominal sigma (50 m, 0.07 deg; about 1.1 measured), and under 250 m."""
    summary, _ = summarise(run)
    for address in ADDRESSES:
        for track in summary[address].tracks:
            assert track.residual_rms_sigma < 2.0, (address, track)
            assert track.residual_rms_m < 250.0, (address, track)
            assert track.plots >= 0.9 * track.duration_s / run.tracker_config.scan_period_s
    ids, residuals, sigmas = prediction_residuals(run.updates, run.plots)
    assert len(ids) > 1800
    assert np.all(np.isfinite(residuals)) and np.all(sigmas > 0)


def test_north_marker_periods(run: CaptureRun) -> None:
    from asterix.containers import Datagram, read_file

    periods = north_marker_periods([d for d in read_file(CAPTURE) if isinstance(d, Datagram)])
    assert periods == {SOURCE: pytest.approx(4.984375)}


def test_address_stretches() -> None:
    times = np.array([0.0, 5.0, 10.0, 40.0, 45.0, 100.0])
    assert address_stretches(times, 16.0) == [(0.0, 10.0), (40.0, 45.0), (100.0, 100.0)]
    assert address_stretches(np.zeros(0), 16.0) == []
