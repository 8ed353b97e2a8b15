"""ADS-B as a surveillance source (fusion/adsb_source.py): the position covariance from
the quality indicators, the latency rule, the spoof flag, the roles of the reports, the
configuration, and the adsb_cover scenario end to end."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from asterix.codec import Block, decode_blocks, encode_block
from tracker_service.adsb import (
    NACP_EPU_M,
    SIGMA_PER_EPU,
    UNKNOWN_VELOCITY_SIGMA_M_S,
    AdsbReports,
    decode_reports,
    position_sigma_m,
    velocity_sigma_m_s,
)
from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.fusion.adsb_source import (
    CHECK_TIMEOUT_PERIODS,
    CLEAR_AFTER,
    AdsbSource,
    ReportUse,
)
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.cat062 import encode_system_tracks
from tracker_service.outputs.messages import SystemTrackMessage
from tracker_service.service import SystemConfig
from tracker_service.service.config import ConfigError, parse_service_config
from tracker_service.tracking import PLOT_DTYPE, track_update_dtype
from tracker_service.tracking.tracker import CONFIRMED

NM = 1852.0
ADDRESS = 0x4D0001
SPEED = 200.0  # m/s east


def test_position_sigma_follows_the_mops_version() -> None:
    # (version, NACp, NUCp or NIC), -1 absent -> 1-sigma.
    cases = [
        # Version 2: NACp's 95 % bound (EPU) over 2.448.
        ((2, 9, 8), 30.0 / 2.448),
        ((-1, 10, -1), 10.0 / 2.448),
        # Version 1 without NACp: the NIC's containment radius as the bound (on the safe side).
        ((1, -1, 8), 185.2 / 2.448),
        # Version 0 (DO-260): NUCp's accuracy, whatever a NACp field would say.
        ((0, 11, 7), 92.6 / 2.448),
        ((-1, -1, 9), 3.0 / 2.448),
        # Worse than 1 NM, or no quality at all: not fit for use.
        ((2, 3, 8), math.nan),
        ((0, -1, 0), math.nan),
        ((2, -1, -1), math.nan),
    ]
    version, nacp, nucp = (np.array(column) for column in zip(*(c for c, _ in cases), strict=True))
    expected = np.array([sigma for _, sigma in cases])
    np.testing.assert_allclose(position_sigma_m(version, nacp, nucp), expected)
    np.testing.assert_allclose(
        velocity_sigma_m_s(np.array([2, -1])), [3.0 / 2.448, UNKNOWN_VELOCITY_SIGMA_M_S]
    )


def _record(**changes: Any) -> dict[str, Any]:
    item: dict[str, Any] = {
        "010": {"SAC": 40, "SIC": 50},
        "040": {"ATP": 1, "ARC": 1, "RC": 0, "RAB": 0},
        "071": 36000.0,
        "130": {"LAT": 48.0, "LON": 17.0},
        "080": "4D0001",
        "090": {"NUCRNACV": 2, "NUCPNIC": 8, "NICBARO": 1, "SIL": 3, "NACP": 9},
        "210": {"VNS": 0, "VN": 2, "LTT": 2},
        "145": 310.0,
        "160": {"RE": 0, "GS": 0.1, "TA": 90.0},
    }
    item.update(changes)
    return {k: v for k, v in item.items() if v is not None}


def test_decode_reads_low_resolution_position_and_reception_time() -> None:
    plane = SystemPlane(48.0, 17.0)
    block = encode_block(
        21,
        [
            _record(),
            _record(**{"071": None, "073": 36001.0}),  # I073 when I071 is absent
            _record(**{"080": None}),  # no address: unfit
            _record(**{"090": {"NUCRNACV": 2, "NUCPNIC": 8, "NICBARO": 1, "SIL": 3, "NACP": 2}}),
        ],
    )
    received = 1_780_300_800.0 + 36002.0  # 2026-06-01 10:00:02 UTC
    reports = decode_reports(block, received, plane)
    assert reports.records == 4
    assert reports.record.tolist() == [0, 1]
    assert reports.station == "40/50"
    assert reports.time[1] - reports.time[0] == pytest.approx(1.0)
    assert np.hypot(reports.x[0], reports.y[0]) < 1.0  # at the plane's centre
    assert reports.sigma[0] == pytest.approx(NACP_EPU_M[9] * SIGMA_PER_EPU)
    assert reports.vx[0] == pytest.approx(0.1 * NM, rel=1e-2)  # spherical step
    assert reports.flight_level[0] == pytest.approx(310.0)


def _reports(times: list[float], east_m: float = 0.0, address: int = ADDRESS) -> AdsbReports:
    t = np.array(times)
    n = t.size
    return AdsbReports(
        address=np.full(n, address, dtype=np.int64),
        time=t,
        x=SPEED * t + east_m,
        y=np.zeros(n),
        vx=np.full(n, SPEED),
        vy=np.zeros(n),
        sigma=np.full(n, 12.0),
        sigma_v=np.full(n, 1.2),
        flight_level=np.full(n, 310.0),
        mode3a=np.full(n, -1, dtype=np.int64),
        record=np.arange(n, dtype=np.int64),
        station="40/50",
        records=n,
    )


def _radar_track(fuser: SystemTracker, t: float, plot_id: int, number: int = 7) -> npt.NDArray[Any]:
    """A confirmed radar local track (radar 0) of ADDRESS at its true position at t."""
    u = np.zeros(1, dtype=track_update_dtype(fuser.models.n_models))
    u["track_number"], u["time"], u["status"] = number, t, CONFIRMED
    u["x"], u["y"], u["vx"], u["vy"] = SPEED * t, 0.0, SPEED, 0.0
    u["P"] = np.diag([900.0, 900.0, 25.0, 25.0]).reshape(1, 16)
    u["plot_id"], u["address"], u["mode3a"] = plot_id, ADDRESS, -1
    u["flight_level"], u["climb_rate_fl_per_s"] = 310.0, 0.0
    p = np.zeros(1, dtype=PLOT_DTYPE)
    p["time"], p["x"], p["y"] = t, SPEED * t, 0.0
    p["R"] = np.eye(2) * 900.0
    p["address"], p["plot_id"], p["mode3a"], p["flight_level"] = ADDRESS, plot_id, -1, 310.0
    fuser.process(0, u, p)
    return u


def _step(source: AdsbSource, reports: AdsbReports, first_id: int) -> Any:
    step = source.step(reports, first_id)
    source.fuser.process(source.index, step.updates, step.plots)
    return step


def test_adsb_only_aircraft_gets_a_system_track() -> None:
    fuser = SystemTracker(2, FusionConfig(adsb="fuse", longest_period_s=5.0))
    source = AdsbSource(fuser, 1, share_reference=True)
    for k in range(5):
        _step(source, _reports([float(k)]), 1000 + k)
    live = fuser.system_tracks
    assert live.size == 1
    assert fuser.state.sys["address"][live[0]] == ADDRESS
    assert source.stats.fused == 5 and source.stats.references == 0  # no radar: all fused


def test_report_older_than_its_system_track_moves_it_forward_not_back() -> None:
    fuser = SystemTracker(2, FusionConfig(adsb="fuse", longest_period_s=5.0))
    source = AdsbSource(fuser, 1, share_reference=False)
    for k in range(4):
        _step(source, _reports([float(k)]), 1000 + k)
    number = int(fuser.system_tracks[0])
    # A radar plot at 10.0 joins it; then the ADS-B report of 9.5 arrives, late.
    for t, plot_id in ((4.0, 1), (6.0, 2), (8.0, 3), (10.0, 4)):
        _radar_track(fuser, t, plot_id)
    _step(source, _reports([8.0]), 2000)
    assert fuser.state.sys["t"][number] == pytest.approx(10.0)
    step = _step(source, _reports([9.5]), 2001)
    assert step.use.tolist() == [ReportUse.FUSED]
    assert step.plots["time"][0] == pytest.approx(10.0)
    assert step.plots["x"][0] == pytest.approx(SPEED * 10.0)  # along its own velocity
    assert step.plots["R"][0, 0, 0] > 12.0**2  # grown by the velocity's error
    assert fuser.state.sys["t"][number] >= 10.0
    assert source.stats.moved_forward >= 1
    # A copy of a report already had (another station's) adds nothing.
    again = _step(source, _reports([9.5]), 2002)
    assert again.use.tolist() == [ReportUse.REPEATED]


def test_spoofed_position_is_flagged_and_not_fused() -> None:
    fuser = SystemTracker(2, FusionConfig(adsb="fuse", longest_period_s=5.0))
    source = AdsbSource(fuser, 1, share_reference=False)
    uses: list[int] = []
    checks = []
    for k in range(8):
        t = float(k)
        step = _step(source, _reports([t], east_m=2.0 * NM), 100 + k)
        uses += step.use.tolist()
        if k % 2 == 0:  # a radar update every 2 s, where the aircraft truly is
            checks.append(source.check_radar(_radar_track(fuser, t + 0.2, k + 1), None))
    # Fused until the radars first disagree, withheld from then on, flagged at the third.
    assert uses == [ReportUse.FUSED] + [ReportUse.INCONSISTENT] * 7
    assert checks == [1, 1, 1, 1]
    assert source.stats.flagged == {ADDRESS}
    assert source.stats.flags_raised == 1
    # Its ADS-B track left fusion when flagged: a deletion went to the fuser.
    assert source.stats.disagreements == 4
    # Consistent again for CLEAR_AFTER radar updates in a row: fusion resumes.
    fused = []
    for k in range(2 * CLEAR_AFTER + 2):
        t = 8.0 + k
        fused += _step(source, _reports([t]), 200 + k).use.tolist()
        if k % 2 == 0:
            source.check_radar(_radar_track(fuser, t + 0.2, 20 + k), None)
    assert source.stats.flagged == set()
    assert fused[0] == ReportUse.INCONSISTENT
    assert fused[-1] == ReportUse.FUSED


def _radar_plots(t: float, x: float) -> npt.NDArray[Any]:
    """One radar plot at (x, 0) at time t, as the central stage feeds the cover."""
    p = np.zeros(1, dtype=PLOT_DTYPE)
    p["time"], p["x"], p["y"], p["typ"] = t, x, 0.0, 5
    return p


def test_adsb_inside_radar_cover_feeds_no_system_track_until_checked() -> None:
    fuser = SystemTracker(2, FusionConfig(adsb="fuse", longest_period_s=10.0))
    source = AdsbSource(fuser, 1, share_reference=False, radar_periods={0: 10.0})
    # The radar has swept once and sees a target where the spoofed position lies.
    source.cover.note(0, _radar_plots(-10.0, 0.0))
    source.cover.note(0, _radar_plots(0.0, 0.0))
    uses: list[int] = []
    for k in range(12):
        t = float(k)
        uses += _step(source, _reports([t], east_m=2.0 * NM), 100 + k).use.tolist()
        if k == 9:  # the radar's track of the aircraft is confirmed: the first comparison
            assert source.check_radar(_radar_track(fuser, t + 0.2, 1), None) == 1
    assert uses == [ReportUse.UNCHECKED] * 10 + [ReportUse.INCONSISTENT] * 2
    # No system track from the ADS-B reports: the only one is the radar's.
    assert fuser.state.local.used["radar"][fuser.state.local.used["alive"]].tolist() == [0]
    # An honest one is fused from its first agreeing comparison on.
    honest = AdsbSource(SystemTracker(2, FusionConfig(adsb="fuse")), 1, False, {0: 10.0})
    honest.cover.note(0, _radar_plots(-10.0, 0.0))
    honest.cover.note(0, _radar_plots(0.0, 0.0))
    first = _step(honest, _reports([0.0]), 1).use.tolist()
    honest.check_radar(_radar_track(honest.fuser, 0.2, 1), None)
    assert first + _step(honest, _reports([1.0]), 2).use.tolist() == [
        ReportUse.UNCHECKED,
        ReportUse.FUSED,
    ]


def test_adsb_outside_radar_cover_is_fused_at_once_and_inside_after_a_time_out() -> None:
    source = AdsbSource(SystemTracker(2, FusionConfig(adsb="fuse")), 1, False, {0: 10.0})
    source.cover.note(0, _radar_plots(-10.0, 0.0))
    source.cover.note(0, _radar_plots(0.0, 0.0))
    # 100 km from any radar plot: nothing to check it with.
    far = _step(source, _reports([0.0, 1.0], east_m=100_000.0), 1).use.tolist()
    assert far == [ReportUse.FUSED] * 2
    assert source.fuser.system_tracks.size == 1
    # Inside cover, never compared (a radar that sees it without its address): fused
    # after CHECK_TIMEOUT_PERIODS antenna periods.
    inside = AdsbSource(SystemTracker(2, FusionConfig(adsb="fuse")), 1, False, {0: 10.0})
    inside.cover.note(0, _radar_plots(-10.0, 0.0))
    inside.cover.note(0, _radar_plots(0.0, 0.0))
    timeout = CHECK_TIMEOUT_PERIODS * 10.0
    times = np.arange(0.0, timeout + 2.0)
    uses = [u for t in times for u in _step(inside, _reports([float(t)]), int(t)).use.tolist()]
    assert uses == [ReportUse.UNCHECKED] * int(timeout) + [ReportUse.FUSED] * 2
    # Before the radar's first full sweep its cover is unknown: held, though far.
    early = AdsbSource(SystemTracker(2, FusionConfig(adsb="fuse")), 1, False, {0: 10.0})
    early.cover.note(0, _radar_plots(0.0, 0.0))
    assert _step(early, _reports([1.0], east_m=100_000.0), 1).use.tolist() == [ReportUse.UNCHECKED]


def test_no_report_is_both_fused_and_a_reference() -> None:
    fuser = SystemTracker(2, FusionConfig(adsb="fuse", longest_period_s=5.0))
    source = AdsbSource(fuser, 1, share_reference=True)
    for k, t in enumerate((0.0, 2.0, 4.0)):
        _radar_track(fuser, t, k + 1)
    step = source.step(_reports([4.1, 4.6, 5.1, 5.6]), 10)
    assert step.use.tolist() == [ReportUse.FUSED, ReportUse.REFERENCE] * 2
    assert step.reference.tolist() == [False, True, False, True]
    assert (step.plot_id >= 0).tolist() == [True, False, True, False]


def test_inconsistent_flag_reaches_cat062_i080_aff() -> None:
    system = SystemConfig(centre_lat=48.0, centre_lon=17.0, sac=40, sic=100)
    fields: dict[str, Any] = {
        "time": 1_780_315_200.0,
        "x_m": 0.0,
        "y_m": 0.0,
        "vx_mps": 200.0,
        "vy_mps": 0.0,
        "covariance": np.diag([100.0, 100.0, 4.0, 4.0]).tolist(),
        "climb_rate_fl_per_s": None,
        "number": 12,
        "lat": 48.0,
        "lon": 17.0,
        "address": "4D0001",
        "sources": [{"radar": "40/1", "local_track": 3, "age_s": 0.0}],
        "status": "confirmed",
    }
    flags = []
    for inconsistent in (False, True):
        message = SystemTrackMessage.from_state(**fields, adsb_inconsistent=inconsistent)
        blocks = [e for e in decode_blocks(encode_system_tracks([message], system))]
        assert isinstance(blocks[0], Block)
        flags.append(blocks[0].records[0]["080"]["AFF"])
    assert flags == [0, 1]


def test_adsb_mode_is_validated_with_the_field_named() -> None:
    with pytest.raises(ValueError, match=r"\[fusion\] adsb must be one of"):
        FusionConfig(adsb="maybe")  # type: ignore[arg-type]
    doc: dict[str, Any] = {
        "radars": [
            {
                "name": "r",
                "sac": 40,
                "sic": 1,
                "lat": 48.0,
                "lon": 17.0,
                "alt_m": 0.0,
                "antenna_period_s": 10.0,
                "sigma_range_m": 50.0,
                "sigma_azimuth_deg": 0.07,
            }
        ],
        "system": {"centre_lat": 48.0, "centre_lon": 17.0, "sac": 40, "sic": 100},
        "fusion": {"adsb": "always"},
    }
    with pytest.raises(ConfigError, match=r"\[fusion\] adsb must be one of .* not 'always'"):
        parse_service_config(doc)
    doc["fusion"] = {"adsb": "fuse"}
    assert parse_service_config(doc).fusion == {"adsb": "fuse"}


# --- the adsb_cover scenario, end to end ----------------------------------------------

SCENARIO = Path(__file__).parent.parent / "config" / "scenarios" / "adsb_cover.toml"


@pytest.fixture(scope="module")
def fused(tmp_path_factory: pytest.TempPathFactory) -> Any:
    from tracker_service.evaluation.command import evaluate
    from tracker_service.evaluation.pipeline import EvaluationConfig
    from tracker_service.simulator.run import simulate
    from tracker_service.simulator.scenario import load_scenario

    path = tmp_path_factory.mktemp("adsb") / "adsb_cover.mcap"
    simulate(load_scenario(SCENARIO), path, duration_s=150.0)
    return evaluate(path, EvaluationConfig(fusion=FusionConfig(adsb="fuse")))


@pytest.mark.slow
def test_scenario_adsb_only_tracks_and_spoof_flag(fused: Any) -> None:
    doc = fused.as_json()
    only = doc["system_by_coverage"]["adsb_only"]
    assert only["probability_of_update"] >= 0.98
    assert only["position_rms_m"] <= 50.0
    rows: npt.NDArray[Any] = fused.pipeline.system
    spoofed = rows["address"] == 0x4D00FF
    assert rows["adsb_inconsistent"][spoofed].any()
    assert not rows["adsb_inconsistent"][~spoofed].any()
    # No system row of that address ever comes from an ADS-B report: inside radar cover
    # its reports wait for a radar comparison, which flags them; so it founds no false
    # system track (its only ones are the radars').
    adsb = len(fused.pipeline.sources) - 1
    assert not (spoofed & (rows["radar"] == adsb)).any()
    assert doc["system"]["false_tracks"] == 0


def test_chain_reports_what_became_of_each_cat021_record() -> None:
    from tracker_service.chain import Chain, radar_infos, rejections, system_plane

    infos = radar_infos({"radars": {"40/1": {"lat": 48.0, "lon": 17.0, "alt_m": 0.0}}})
    chain = Chain(infos, system_plane({}, infos), fusion=FusionConfig(adsb="fuse"))
    received = 1_780_300_800.0 + 36002.0
    block = encode_block(21, [_record(), _record(), _record(**{"080": None})])
    outputs = chain.feed(block, received)
    assert [o.source for o in outputs] == ["40/50"]
    assert chain.sources == ["40/1", "40/50"]  # the fuser's ADS-B source, named
    # What status counts for the feed: a copy, a record without address, and the report
    # held back because the radar has not swept its cover yet (it could check it).
    assert rejections(outputs[0].plots["use"]) == {
        "adsb_repeated": 1,
        "adsb_unfit": 1,
        "adsb_unchecked": 1,
    }
    assert len(outputs[0].local) == 0
