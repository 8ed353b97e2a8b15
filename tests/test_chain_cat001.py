"""A real CAT001/CAT002 radar through the chain: canalA.gps (48 min, SAC 20/SIC 130).

The radar is in no configuration, so it is tracked at an assumed site (local tracks are
shaped right there). Its plots carry only the truncated I141; their times come from the
radar's CAT002 north markers and sector messages. The first 700 datagrams (about 70 s,
17 scans) keep the test to a few seconds.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from asterix import encode_block
from asterix.containers import Datagram, read_file
from tests.conftest import REPO, shared_file
from tracker_service.chain import Chain, PlotUse, rejections
from tracker_service.geodesy import SystemPlane
from tracker_service.ingest import TimeSource
from tracker_service.service.config import load_service_config
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay, parse_date
from tracker_service.tracking import CONFIRMED

DAY = 1_780_272_000.0  # any UTC midnight: the GPS capture holds times of day
KT = 1852.0 / 3600.0
DATAGRAMS = 700
GPS_HEADER, GPS_POST = 2200, 10  # SOURCES.md: a header, then [data block][10 octets]


@pytest.fixture(scope="module")
def run() -> tuple[Chain, Any, Any, Any]:
    units = [u for u in read_file(shared_file("reader_network/canalA.gps"))]
    units = [u for u in units if isinstance(u, Datagram)][:DATAGRAMS]
    chain = Chain({}, SystemPlane(40.4, -3.7))
    local, plots, received = [], [], []
    for unit in units:
        assert unit.time is not None
        for output in chain.feed(unit.payload, DAY + unit.time):
            local.append(output.local)
            plots.append(output.plots)
            received.append(np.full(len(output.plots), DAY + unit.time))
    return chain, np.concatenate(local), np.concatenate(plots), np.concatenate(received)


def test_the_plots_are_timed_on_the_radars_clock(run: tuple[Chain, Any, Any, Any]) -> None:
    chain, _, plots, received = run
    assert chain.stats.unknown_radars == ["20/130"]
    assert len(plots) > 700
    sources = plots["time_source"]
    # Until the first CAT002 message only the reception time is a reference.
    assert np.mean(sources == TimeSource.I141_SERVICE) > 0.97
    assert set(np.unique(sources).tolist()) <= {TimeSource.I141_SERVICE, TimeSource.I141_RECEPTION}
    # Each plot is measured before it is sent, within about a sector's buffering.
    lag = received - plots["time"]
    assert np.all(lag > -0.5) and np.median(lag) < 2.0 and np.all(lag < 10.0)
    # The north markers (no I041) give the antenna period: about 4 s.
    period = chain.radar_stage.clock.antenna_period(20, 130)
    assert period is not None and 3.9 < period < 4.1
    # Nothing kept out for its time (its site monitors on 7777 are, for what they are).
    assert not np.any(plots["use"] == PlotUse.TIME_IMPLAUSIBLE)


def test_the_radar_is_tracked_plausibly(run: tuple[Chain, Any, Any, Any]) -> None:
    _, local, _, _ = run
    confirmed = local[local["status"] == CONFIRMED]
    assert len(np.unique(confirmed["track_number"])) >= 30
    speed_kt = np.hypot(confirmed["vx"], confirmed["vy"]) / KT
    assert speed_kt.max() < 650.0
    # A jump: an update more than 1 NM from where the previous one's velocity put it (a
    # missed scan at 500 kt is 2 km of travel, not a jump).
    steps = jumps = 0
    for number in np.unique(confirmed["track_number"]).tolist():
        track = confirmed[confirmed["track_number"] == number]
        track = track[np.argsort(track["time"], kind="stable")]
        dt = np.diff(track["time"])
        x = track["x"][:-1] + track["vx"][:-1] * dt
        y = track["y"][:-1] + track["vy"][:-1] * dt
        off = np.hypot(track["x"][1:] - x, track["y"][1:] - y)
        steps += len(off)
        jumps += int(np.count_nonzero(off > 1852.0))
    assert steps > 500
    assert jumps == 0


def test_replay_of_the_capture_tracks_the_radar(tmp_path: Path) -> None:
    """The first 800 items of the GPS capture (about 80 s) through the service, with
    a configuration that does not know the radar."""
    data = shared_file("reader_network/canalA.gps").read_bytes()
    pos = GPS_HEADER
    for _ in range(800):
        pos += int.from_bytes(data[pos + 1 : pos + 3]) + GPS_POST
    capture = tmp_path / "canalA-start.gps"
    capture.write_bytes(data[:pos])
    config = load_service_config(REPO / "config" / "example.toml")
    source = open_replay(capture, config, parse_date("2026-06-01"))
    service = TrackerService(source.config)
    for name, datagram in source.datagrams:
        service.process(name, datagram)
    status = service.status()
    service.close()
    assert service.counts.plots > 800 and service.counts.errors == 0
    (radar,) = (r for r in status.radars if r.radar == "20/130")
    assert radar.decode_errors == 0 and radar.last_plot_time is not None
    stats = service.chain.radars["20/130"].tracker.stats
    assert stats.tracks_confirmed >= 30 and stats.plots_associated > 0.85 * stats.plots


def test_track_reports_are_kept_out_of_tracking() -> None:
    """A CAT001 track record (I020 TYP = 1) is the radar's own smoothed track: counted as
    such, never fed to our tracker as a measurement."""
    source = {"SAC": 20, "SIC": 130}
    plot = {
        "010": source,
        "020": {"TYP": 0, "SIM": 0, "SSRPSR": 2, "ANT": 0, "SPI": 0, "RAB": 0},
        "040": {"RHO": 50.0, "THETA": 10.0},
        "141": 100.0,
    }
    track = {**plot, "020": {**plot["020"], "TYP": 1}, "161": 12}
    chain = Chain({}, SystemPlane(40.4, -3.7))
    (output,) = chain.feed(encode_block(1, [plot, track]), DAY + 100.5)
    assert output.plots["use"].tolist() == [PlotUse.TRACKED, PlotUse.RADAR_TRACK]
    assert rejections(output.plots["use"]) == {"radar_track": 1}
    assert chain.radars["20/130"].tracker.stats.plots == 1
