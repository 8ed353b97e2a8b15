"""Issue 10 findings 3 and 4: test targets (I020 TST/SIM) and fixed transponders are kept
out of traffic tracking, counted in status, and a surveyed fixed transponder is a field
monitor for the radar's biases whether or not it sets RAB.

Simulated: one radar with an SSR test transponder (TST, code 7776, FL660, exactly
200.0 NM), a primary test target, a fixed transponder on code 7777 with RAB = 0 (address
00020A, 98 km east of the radar), two airliners and two slow helicopters. Real: the
Spanish recordings, whose site monitors send 7777 with RAB = 0 and whose radar sends a
primary test target at 15.0 NM (parsegps.gps), and canalA.gps's two 7777 transponders.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tests.conftest import shared_file
from tracker_service.chain import RAW_PLOT_DTYPE, BatchOutput, PlotUse
from tracker_service.evaluation.real_data import DEFAULT_DAY_POSIX
from tracker_service.fixed_targets import FixedTargetConfig, FixedTargets, FixedTransponder
from tracker_service.geodesy import RadarSite, SystemPlane
from tracker_service.outputs.messages import StatusMessage
from tracker_service.service.config import ConfigError, ServiceConfig, parse_service_config
from tracker_service.service.core import Outputs, TrackerService
from tracker_service.service.replay import open_replay
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario
from tracker_service.tracking import CONFIRMED

SITE = (48.0, 17.0)
FIXED = {"lat": 48.0, "lon": 18.3162, "alt_m": 300.0, "mode3a": "7777", "address": "00020A"}
"""98 km east of the radar."""
FIXED_ADDRESS = 0x00020A
AIRCRAFT = {"3C0001", "3C0002", "3C0003", "3C0004"}
ON_7777 = 0x3C0005
"""An aircraft at 250 kt squawking 7777."""


def scenario(bias: bool = False, reported_fl: float | None = None, rab: bool = False) -> Scenario:
    radar: dict[str, Any] = {
        "name": "R",
        "sac": 30,
        "sic": 1,
        "lat": SITE[0],
        "lon": SITE[1],
        "alt_m": 500.0,
        "antenna_period_s": 5.0,
        "sectors": 4,
        "max_range_nm": 250.0,
        "sigma_range_m": 40.0,
        "sigma_azimuth_deg": 0.05,
        "fixed_transponders": [FIXED | {"reported_fl": reported_fl, "rab": rab}],
        "test_targets": [
            {"range_nm": 200.0, "azimuth_deg": 45.0, "mode3a": "7776", "fl": 660.0},
            {"range_nm": 15.0, "azimuth_deg": 300.0, "mode3a": None, "fl": None},
        ],
    }
    if bias:
        radar["bias"] = {"range_offset_m": 150.0, "azimuth_offset_deg": 0.15}

    def flight(n: int, lat: float, lon: float, fl: float, kt: float, hdg: float) -> dict[str, Any]:
        return {
            "callsign": f"T{n}",
            "address": f"3C000{n}",
            "mode3a": f"400{n}",
            "lat": lat,
            "lon": lon,
            "fl": fl,
            "speed_kt": kt,
            "heading_deg": hdg,
        }

    aircraft = [
        flight(1, 48.3, 18.0, 300.0, 450.0, 180.0),
        flight(2, 47.6, 18.6, 240.0, 380.0, 20.0),
        # A slow helicopter beside the fixed transponder, and one at walking pace.
        flight(3, 48.05, 18.2, 20.0, 20.0, 90.0),
        flight(4, 47.9, 17.3, 15.0, 6.0, 0.0),
        # An aircraft squawking the site monitors' code.
        flight(5, 47.8, 17.5, 100.0, 250.0, 45.0) | {"mode3a": "7777"},
    ]
    return Scenario.model_validate(
        {
            "name": "fixed_targets",
            "duration_s": 300.0,
            "system_centre": {"lat": SITE[0], "lon": SITE[1]},
            "radars": [radar],
            "aircraft": aircraft,
        }
    )


class KeptOutputs(Outputs):
    """The outputs, keeping every batch the chain hands them."""

    def __init__(self, config: ServiceConfig) -> None:
        super().__init__(config)
        self.kept: list[BatchOutput] = []

    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None:
        self.kept.append(output)
        super().batch(output, sources, received)


@dataclass
class Run:
    service: TrackerService
    tables: npt.NDArray[Any]
    """Every plot (``RAW_PLOT_DTYPE``), local-track update and system-track row."""
    local: npt.NDArray[Any]
    system: npt.NDArray[Any]
    status: StatusMessage


def run_service(
    path: Path,
    config: ServiceConfig | None = None,
    day: float | None = None,
    duration_s: float | None = None,
) -> Run:
    """The service over a recording (its own configuration unless given); ``day``: the
    POSIX day of a capture that has times of day only; ``duration_s``: only its first
    seconds of reception."""
    source = open_replay(path, config, day)
    outputs = KeptOutputs(source.config)
    service = TrackerService(source.config, outputs=outputs)
    end = math.inf
    for name, datagram in source.datagrams:
        assert datagram.time is not None
        if duration_s is not None and end == math.inf:
            end = datagram.time + duration_s
        if datagram.time > end:
            break
        service.process(name, datagram)
    kept = outputs.kept
    assert kept, f"{path.name}: the chain read none of its plots"
    return Run(
        service,
        np.concatenate([o.plots for o in kept]),
        np.concatenate([o.local for o in kept]),
        np.concatenate([o.system for o in kept]),
        service.status(),
    )


def with_fixed(config: ServiceConfig, source: str, *entries: dict[str, Any]) -> ServiceConfig:
    """The configuration with fixed transponders listed for one radar."""
    doc = config.model_dump(mode="json", exclude_none=True)
    for radar in doc["radars"]:
        if f"{radar['sac']}/{radar['sic']}" == source:
            radar["fixed_transponders"] = list(entries)
    return parse_service_config(doc)


def fed_to_tracker(run: Run, use: PlotUse) -> npt.NDArray[Any]:
    """Local-track updates made with a plot of the given use."""
    ids = run.tables["plot_id"][run.tables["use"] == use]
    return run.local[np.isin(run.local["plot_id"], ids)]


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("fixed") / "fixed_targets.mcap"
    simulate(scenario(), out)
    return out


@pytest.fixture(scope="module")
def detected(recording: Path) -> Run:
    return run_service(recording)


@pytest.fixture(scope="module")
def configured(recording: Path) -> Run:
    config = with_fixed(open_replay(recording).config, "30/1", {"address": "00020A"})
    return run_service(recording, config)


# --- simulated -----------------------------------------------------------------------


def test_test_targets_are_never_tracked_and_are_checked_in_status(detected: Run) -> None:
    tst = detected.tables["use"] == PlotUse.TEST_TARGET
    assert tst.sum() >= 100  # two test targets, one plot a scan each, for 300 s
    assert len(fed_to_tracker(detected, PlotUse.TEST_TARGET)) == 0
    assert not (detected.system["mode3a"] == 0o7776).any()
    radar = detected.status.radars[0]
    assert radar.rejected["test_target"] == int(tst.sum())
    checks = {(c.kind, c.mode3a): c for c in radar.test_targets}
    assert set(checks) == {("primary", None), ("secondary", "7776")}
    ssr = checks[("secondary", "7776")]
    assert ssr.range_nm == 200.0 and ssr.azimuth_deg == 45.0 and ssr.flight_level == 660.0
    assert abs(checks[("primary", None)].range_nm - 15.0) < 1e-9
    assert ssr.seen + checks[("primary", None)].seen == radar.rejected["test_target"]
    assert ssr.last_time == pytest.approx(detected.status.time, abs=10.0)


def test_a_detected_fixed_transponder_is_never_an_aircraft(detected: Run) -> None:
    fixed = detected.tables["address"] == FIXED_ADDRESS
    use = detected.tables["use"][fixed]
    # On the site monitors' code 7777, kept out from its first plot: no track at all.
    assert len(use) >= 55 and (use == PlotUse.FIXED_TRANSPONDER).all()
    assert not (detected.local["address"] == FIXED_ADDRESS).any()
    assert not (detected.system["address"] == FIXED_ADDRESS).any()
    assert detected.status.radars[0].rejected["fixed_transponder"] == int(
        (detected.tables["use"] == PlotUse.FIXED_TRANSPONDER).sum()
    )


def test_a_configured_fixed_transponder_never_reaches_the_tracker(configured: Run) -> None:
    fixed = configured.tables["address"] == FIXED_ADDRESS
    assert fixed.sum() >= 55
    assert (configured.tables["use"][fixed] == PlotUse.FIXED_TRANSPONDER).all()
    # Not one of its plots seeds or feeds a track (the 1,775 kt tentative track of the
    # issue was one of them paired with a primary plot).
    assert len(fed_to_tracker(configured, PlotUse.FIXED_TRANSPONDER)) == 0
    assert not (configured.system["address"] == FIXED_ADDRESS).any()


@pytest.mark.parametrize("which", ["detected", "configured"])
def test_slow_aircraft_and_helicopters_are_kept(which: str, request: pytest.FixtureRequest) -> None:
    run: Run = request.getfixturevalue(which)
    aircraft = np.isin(run.tables["address"], [int(a, 16) for a in AIRCRAFT])
    assert (run.tables["use"][aircraft] == PlotUse.TRACKED).all()
    assert set(run.system["address"].tolist()) == {int(a, 16) for a in AIRCRAFT} | {ON_7777}


def test_a_moving_aircraft_on_7777_is_tracked_after_a_few_scans(detected: Run) -> None:
    mine = detected.tables["address"] == ON_7777
    use = detected.tables["use"][mine][np.argsort(detected.tables["time"][mine])]
    held = int(np.argmax(use == PlotUse.TRACKED))
    assert 1 <= held <= 4 and (use[held:] == PlotUse.TRACKED).all()
    confirmed = detected.local[
        (detected.local["address"] == ON_7777) & (detected.local["status"] == CONFIRMED)
    ]
    assert len(confirmed) >= len(use) - held - 5


# --- a surveyed fixed transponder as a field monitor ----------------------------------


@pytest.fixture(scope="module", params=[False, True], ids=["rab0", "rab1"])
def biased(tmp_path_factory: pytest.TempPathFactory, request: pytest.FixtureRequest) -> Path:
    # The transponder sends a test level (FL719), not its height: the survey's is used.
    # With RAB = 1 it is the same field monitor, configured as a fixed transponder only.
    out = tmp_path_factory.mktemp("biased") / "biased.mcap"
    simulate(scenario(bias=True, reported_fl=719.0, rab=request.param), out)
    return out


def _bias_at_monitor(run: Run) -> tuple[float, float, float]:
    """The estimated range error at the transponder's range (m), azimuth (deg) and its
    sigma (deg)."""
    s, p = run.service.chain.bias_estimates()["30/1"]
    return s[0] + s[1] * 98_000.0, math.degrees(s[2]), math.degrees(math.sqrt(p[2, 2]))


def test_a_surveyed_fixed_transponder_feeds_bias_estimation(biased: Path) -> None:
    survey = {k: FIXED[k] for k in ("lat", "lon", "alt_m")}
    plain = open_replay(biased).config
    alone = run_service(biased, plain)
    monitored = run_service(biased, with_fixed(plain, "30/1", {"mode3a": "7777"} | survey))
    # One radar, no ADS-B, no RAB: without the survey its biases are not observable.
    range_alone, azimuth_alone, sigma_alone = _bias_at_monitor(alone)
    assert abs(range_alone - 150.0) > 100.0 and abs(azimuth_alone - 0.15) > 0.1
    # With it, range and azimuth at the transponder are pinned (truth: 150 m, 0.15 deg).
    range_error, azimuth, sigma = _bias_at_monitor(monitored)
    assert abs(range_error - 150.0) < 15.0
    assert abs(azimuth - 0.15) < 0.02 and sigma < 0.1 * sigma_alone
    assert not (monitored.system["address"] == FIXED_ADDRESS).any()
    # The aircraft on 7777 elsewhere is still tracked.
    assert (monitored.system["address"] == ON_7777).any()


# --- the detector, plot by plot --------------------------------------------------------


def _table(
    t: npt.NDArray[np.float64],
    x: npt.NDArray[np.float64],
    y: npt.NDArray[np.float64],
    address: int = -1,
    code: int = -1,
    sigma_m: float = 100.0,
) -> npt.NDArray[Any]:
    table = np.zeros(len(t), RAW_PLOT_DTYPE)
    table["time"], table["x"], table["y"] = t, x, y
    table["R"] = np.eye(2) * sigma_m**2
    table["address"], table["mode3a"] = address, code
    table["rho_m"] = np.hypot(x, y)
    table["theta_deg"] = np.degrees(np.arctan2(x, y)) % 360.0
    return table


def _classify(
    stage: FixedTargets, table: npt.NDArray[Any], valid: npt.NDArray[np.bool_] | None = None
) -> npt.NDArray[np.bool_]:
    """One plot per call, as scans come; ``valid``: the codes validated and not garbled
    (all by default)."""
    valid = table["mode3a"] >= 0 if valid is None else valid
    return np.array(
        [
            stage.classify(table[k : k + 1], np.ones(1, bool), valid[k : k + 1]).fixed[0]
            for k in range(len(table))
        ]
    )


def _stage(**config: Any) -> FixedTargets:
    site = RadarSite(SITE[0], SITE[1], 0.0)
    return FixedTargets(site, SystemPlane(*SITE), 5.0, (), FixedTargetConfig(**config))


def _track(speed_mps: float, minutes: float, sigma_m: float = 100.0, seed: int = 0) -> Any:
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, minutes * 60.0, 5.0)
    x = 50_000.0 + speed_mps * t + rng.normal(0.0, sigma_m, len(t))
    y = 20_000.0 + rng.normal(0.0, sigma_m, len(t))
    return t, x, y


@pytest.mark.parametrize("seed", range(5))
def test_a_site_monitor_code_standing_still_is_kept_out_from_its_first_plot(seed: int) -> None:
    for sigma_m in (30.0, 200.0):
        track = _track(0.0, 10.0, sigma_m, seed)
        assert _classify(_stage(), _table(*track, code=0o7777, sigma_m=sigma_m)).all()


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("speed_kt", [10.0, 20.0, 60.0, 150.0, 300.0])
def test_moving_targets_are_never_fixed(seed: int, speed_kt: float) -> None:
    track = _track(speed_kt * 1852.0 / 3600.0, 15.0, 100.0, seed)
    assert not _classify(_stage(), _table(*track, address=0x3C0001, code=0o4321)).any()
    if speed_kt > 60.0:  # on the site monitors' code (bound: 60 kt), after a few plots
        fixed = _classify(_stage(), _table(*track, code=0o7777))
        held = int(np.argmax(~fixed))
        assert 1 <= held <= 4 and not fixed[held:].any()


@pytest.mark.parametrize("seed", range(5))
@pytest.mark.parametrize("speed_kt", [80.0, 100.0])
def test_a_slower_aircraft_on_7777_is_released_by_the_fit(seed: int, speed_kt: float) -> None:
    track = _track(speed_kt * 1852.0 / 3600.0, 15.0, 100.0, seed)
    fixed = _classify(_stage(), _table(*track, code=0o7777))
    held = int(np.argmax(~fixed))
    assert 1 <= held <= 8 and not fixed[held:].any()


def test_another_code_standing_still_needs_minutes() -> None:
    t, x, y = _track(0.0, 10.0, 30.0)
    fixed = _classify(_stage(), _table(t, x, y, address=0x3C0002, code=0o4321))
    assert not fixed[t < 300.0].any() and fixed[t >= 330.0].all()
    # Emergencies and primary plots are never taken.
    assert not _classify(_stage(), _table(t, x, y, code=0o7700)).any()
    assert not _classify(_stage(), _table(t, x, y)).any()


@pytest.mark.parametrize("seed", range(5))
def test_a_fixed_target_that_moves_off_is_tracked_again(seed: int) -> None:
    # Six minutes standing still, then 20 kt: tracked again once out of the area (300 m,
    # 30 s at 10 m/s) and never taken again.
    t, x, y = _track(0.0, 12.0, 100.0, seed)
    x = np.where(t >= 360.0, x + 10.0 * (t - 360.0), x)
    fixed = _classify(_stage(), _table(t, x, y, address=0x3C0002, code=0o4321))
    assert fixed[(t >= 330.0) & (t < 360.0)].all()
    assert not fixed[t >= 400.0].any()


def test_a_site_monitors_ghosts_and_missed_scans() -> None:
    # canalA.gps: now and then a ghost of the 7777 monitor 1.5 km beside it, too rare to
    # stand still on its own; and scans where the monitor is missed.
    t, x, y = _track(0.0, 10.0, 30.0)
    seen = (t < 200.0) | (t > 260.0)  # 60 s without a plot
    ghost = np.isin(np.arange(len(t)), [30, 31, 70, 100])
    x = np.where(ghost, x + 1500.0, x)
    stage = _stage()
    fixed = _classify(stage, _table(t[seen], x[seen], y[seen], code=0o7777))
    assert fixed[t[seen] > 20.0].all()
    # On another code, what stands beside a stationary target stands or falls on its own.
    other = _classify(_stage(), _table(t, x, y, address=0x3C0002, code=0o4321))
    assert other[t > 360.0].sum() > 40 and not other[ghost].any()


def test_a_site_monitors_garbled_replies() -> None:
    # canalA.gps: 89 of one monitor's 716 plots have their code flagged garbled.
    t, x, y = _track(0.0, 5.0, 30.0)
    garbled = np.arange(len(t)) % 5 == 0
    fixed = _classify(_stage(), _table(t, x, y, code=0o7777), ~garbled)
    assert fixed[t > 20.0].all()
    # Any other garbled code is no identity.
    t, x, y = _track(0.0, 10.0, 30.0)
    table = _table(t, x, y, code=0o4321)
    assert not _classify(_stage(), table, np.zeros(len(t), bool)).any()


def test_a_configured_transponder_is_taken_only_near_its_survey() -> None:
    site = RadarSite(SITE[0], SITE[1], 0.0)
    entry = FixedTransponder(mode3a=0o7777, lat_deg=48.0, lon_deg=18.3162, alt_m=300.0)
    stage = FixedTargets(site, SystemPlane(*SITE), 5.0, [entry], FixedTargetConfig(detect=False))
    table = _table(np.zeros(2), np.zeros(2), np.zeros(2), code=0o7777)
    table["rho_m"] = [98_000.0, 60_000.0]  # there, and an aircraft on 7777 elsewhere
    table["theta_deg"] = 90.0
    found = stage.classify(table, np.ones(2, bool), np.ones(2, bool))
    assert found.fixed.tolist() == [True, False]
    assert np.isfinite(found.reference_xy[0]).all() and np.isnan(found.reference_xy[1]).all()


# --- configuration ----------------------------------------------------------------------

BASE = {
    "radars": [
        {
            "name": "R",
            "sac": 30,
            "sic": 1,
            "lat": 48.0,
            "lon": 17.0,
            "alt_m": 500.0,
            "antenna_period_s": 5.0,
            "sigma_range_m": 40.0,
            "sigma_azimuth_deg": 0.05,
        }
    ],
    "system": {"centre_lat": 48.0, "centre_lon": 17.0, "sac": 30, "sic": 100},
}


@pytest.mark.parametrize(
    ("entry", "message"),
    [
        ({"address": "02A"}, "radars.0.fixed_transponders.0.address"),
        ({"mode3a": "7778"}, "radars.0.fixed_transponders.0.mode3a"),
        ({"lat": 48.0}, "needs its address or its mode3a"),
        ({"address": "00020A", "lat": 48.0, "lon": 18.0}, "lat, lon and alt_m together"),
        ({"mode3a": "7777", "tolerance_m": 0.0}, "tolerance_m"),
    ],
)
def test_configuration_errors_name_the_field(entry: dict[str, Any], message: str) -> None:
    doc = {**BASE, "radars": [{**BASE["radars"][0], "fixed_transponders": [entry]}]}
    with pytest.raises(ConfigError, match=message):
        parse_service_config(doc)


def test_detection_settings_are_checked() -> None:
    with pytest.raises(ConfigError, match=r"fixed_targets.*site_monitor_codes"):
        parse_service_config({**BASE, "fixed_targets": {"site_monitor_codes": ["7778"]}})
    with pytest.raises(ConfigError, match=r"fixed_targets.*min_plots must be a number"):
        parse_service_config({**BASE, "fixed_targets": {"min_plots": "20"}})
    with pytest.raises(ConfigError, match=r"fixed_targets.*speed"):
        parse_service_config({**BASE, "fixed_targets": {"speed": 3}})
    config = parse_service_config({**BASE, "fixed_targets": {"detect": False}})
    assert config.fixed_target_config().detect is False


# --- real recordings --------------------------------------------------------------------

NOMINAL = {"lat": 28.0, "lon": -15.5, "alt_m": 500.0}
"""A nominal site for the Spanish radars (their sites are not published): local tracks
do not depend on it."""


def capture_config(sac: int, sic: int, period_s: float) -> ServiceConfig:
    radar = {**BASE["radars"][0], **NOMINAL, "sac": sac, "sic": sic}
    radar["antenna_period_s"] = period_s
    radar["sigma_azimuth_deg"] = 0.07
    system = {"centre_lat": NOMINAL["lat"], "centre_lon": NOMINAL["lon"], "sac": sac, "sic": 250}
    return parse_service_config({"radars": [radar], "system": system})


def test_parsegps_site_monitor_test_target_and_blind_record() -> None:
    # SAC 20/SIC 193: a 7777 site monitor (Mode S 344041, "7777XGCN", RAB = 0, FL60,
    # 49.08 NM) and a primary test target (TST) at exactly 15.0 NM, over three scans.
    path = shared_file("croatiacontrol/parsegps.gps")
    run = run_service(path, capture_config(20, 193, 4.0), DEFAULT_DAY_POSIX)
    radar = run.status.radars[0]
    # On 7777, its three plots are kept out from the first: no track at all.
    # Its TYP 0 record at 8.08 s has no position: counted, never tracked.
    assert radar.rejected == {"fixed_transponder": 3, "no_position": 1, "test_target": 3}
    (blind,) = run.tables[run.tables["use"] == PlotUse.NO_POSITION]
    assert blind["typ"] == 0 and np.isnan(blind["rho_m"])
    assert blind["time"] - DEFAULT_DAY_POSIX == pytest.approx(8.08, abs=0.01)
    assert not np.isnan(run.tables["rho_m"][run.tables["use"] == PlotUse.TRACKED]).any()
    assert len(fed_to_tracker(run, PlotUse.NO_POSITION)) == 0
    (check,) = radar.test_targets
    assert (check.kind, check.seen, check.range_nm) == ("primary", 3, 15.0)
    assert len(fed_to_tracker(run, PlotUse.TEST_TARGET)) == 0
    assert not (run.local["address"] == 0x344041).any()
    assert set(run.system["address"].tolist()) == {0xE48BA7, 0x4CA9EC}
    # Configured (the address alone), it reaches the tracker not even once.
    config = with_fixed(capture_config(20, 193, 4.0), "20/193", {"address": "344041"})
    configured = run_service(path, config, DEFAULT_DAY_POSIX)
    assert not (configured.local["address"] == 0x344041).any()
    assert configured.status.radars[0].rejected["fixed_transponder"] == 3


def test_croatian_site_monitor_is_kept_out_when_configured() -> None:
    # SAC 25/SIC 201 sends 447AC7 on 7777 ("FFMSNE", FL68, 112 NM) in its one scan here.
    path = shared_file("croatiacontrol/cat_034_048.pcap")
    config = with_fixed(capture_config(25, 201, 4.0), "25/201", {"address": "447AC7"})
    run = run_service(path, config)
    mine = run.tables["address"] == 0x447AC7
    assert mine.any() and (run.tables["use"][mine] == PlotUse.FIXED_TRANSPONDER).all()


@pytest.mark.slow
def test_canala_site_monitors() -> None:
    # canalA.gps (CAT001, SAC 20/SIC 130): two transponders on 7777 with RAB = 0 at 90.8
    # and 99.8 NM, both at 150.3 deg, one plot a scan each for the whole 48 minutes; its
    # first 10 minutes here (the whole of it goes through assess, tests/test_assess.py).
    path = shared_file("reader_network/canalA.gps")
    run = run_service(path, capture_config(20, 130, 4.0), DEFAULT_DAY_POSIX, duration_s=600.0)
    for rho_nm in (90.8, 99.8):
        mine = (run.tables["mode3a"] == 0o7777) & (
            np.abs(run.tables["rho_m"] / 1852.0 - rho_nm) < 0.5
        )
        assert mine.sum() > 140
        # Kept out from its first plot (a few of its plots set RAB: field-monitor plots).
        uses = run.tables["use"][mine]
        assert np.isin(uses, [PlotUse.FIXED_TRANSPONDER, PlotUse.FIELD_MONITOR]).all()
        assert (uses == PlotUse.FIXED_TRANSPONDER).mean() > 0.95
    # Not one local or system track on 7777 (they were local tracks 32 and 33 and a
    # system track published for 30 s before the monitors were held from the first plot).
    fed = run.tables["plot_id"][run.tables["mode3a"] == 0o7777]
    assert not np.isin(run.local["plot_id"], fed).any()
    assert not (run.local["mode3a"] == 0o7777).any()
    assert not (run.system["mode3a"] == 0o7777).any()


# --- the compiled detection against its numpy reference ---------------------------------


def _mixed_batches(seed: int) -> list[tuple[npt.NDArray[Any], npt.NDArray[np.bool_]]]:
    """Scans of a busy sector, several plots a batch: site monitors on 7777 (one with
    ghosts), aircraft moving and hovering on addresses and codes (7777 among them, some
    garbled), primary plots, plots whose identity repeats within a batch."""
    rng = np.random.default_rng(seed)
    batches = []
    for scan in range(60):
        t0 = 5.0 * scan
        rows = []
        for k in range(12):
            speed = (0.0, 0.0, 2.0, 40.0, 120.0, 250.0)[k % 6]
            x = 30_000.0 + 4_000.0 * k + speed * t0 + rng.normal(0.0, 80.0)
            y = 15_000.0 + 3_000.0 * (k % 4) + rng.normal(0.0, 80.0)
            address = 0x3C0000 + k if k % 3 else -1
            code = (0o7777, 0o4321 + k, 0o7700, 0o1200, -1)[k % 5]
            rows.append((t0 + 0.01 * k, x, y, address, code))
        if scan % 7 == 3:  # a ghost beside the first monitor, the same identity
            rows.append((t0 + 0.2, rows[0][1] + 1_500.0, rows[0][2], -1, 0o7777))
        if scan % 5 == 1:  # a split: two plots of one candidate in one batch
            rows.append((t0 + 0.3, rows[2][1] + 20.0, rows[2][2], rows[2][3], rows[2][4]))
        t, x, y, address, code = map(np.array, zip(*rows, strict=True))
        table = _table(t, x, y, sigma_m=60.0 + 40.0 * rng.random())
        table["address"], table["mode3a"] = address, code
        valid = (code >= 0) & (rng.random(len(t)) > 0.15)
        batches.append((table, valid))
    return batches


@pytest.mark.parametrize("seed", range(4))
def test_compiled_detection_is_the_numpy_reference_to_the_bit(seed: int) -> None:
    site = RadarSite(SITE[0], SITE[1], 0.0)
    config = FixedTargetConfig(min_plots=6, min_duration_s=40.0)
    stages = [
        FixedTargets(site, SystemPlane(*SITE), 5.0, (), config, compiled=compiled)
        for compiled in (False, True)
    ]
    taken = 0
    for table, valid in _mixed_batches(seed):
        candidates = np.ones(len(table), bool)
        reference, compiled = (s.classify(table, candidates, valid) for s in stages)
        assert np.array_equal(reference.fixed, compiled.fixed)
        for name in ("key", "values", "fixed"):
            a, b = (getattr(s._candidates, name) for s in stages)
            assert a.shape == b.shape and a.tobytes() == b.tobytes(), name
        taken += int(compiled.fixed.sum())
    assert taken > 50  # the monitors and the hovering ones were found
