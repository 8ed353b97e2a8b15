"""The simulator's plots against their truth, statistically.

Small purpose-built scenarios are simulated to MCAP; every CAT048 record of a radar's LAN A
datagrams is decoded with our codec and paired with its origin on /truth/plots (the i-th
record of datagram number s with records[i] of the message with sequence s). The errors
then have to follow the scenario: means within 4 standard errors (computed from the
scenario's sigmas, quantisation included), standard deviations within the chi-square
99.9 % interval, rates within 4 binomial standard errors. Each check also asserts its
own power: the bound must be well inside the effect it is meant to see (a bias, a
difference of Pd, a 10 % error of sigma), so a simulator that forgot the effect fails.

Truth geometry is recomputed here, not taken from the simulator: PROJ's geodetic to ECEF
transformation (EPSG:4979 -> EPSG:4978) and an east-north-up rotation written out below;
only the geoid undulation comes from the simulator's table.
"""

from __future__ import annotations

import itertools
import math
from collections import Counter, defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from pyproj import Geod, Transformer
from scipy import stats

from asterix import Block, decode_blocks
from tracker_service.simulator.geometry import geoid_undulation_m
from tracker_service.simulator.recording import RecordedDatagram, read_recording
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario

NM = 1852.0
RHO_LSB_M = NM / 256.0
THETA_LSB_DEG = 360.0 / 65536.0
TIME_LSB_S = 1.0 / 128.0
DAY_S = 86400.0
Z = 4.0  # standard errors a mean or a rate may be off by
CHI2_ALPHA = 0.001  # a standard deviation must lie in the chi-square 99.9 % interval
START = datetime(2026, 3, 14, 9, 30, 0, tzinfo=UTC)

GEOD = Geod(ellps="WGS84")
TO_ECEF = Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)

FloatArray = npt.NDArray[np.float64]


# ---------------------------------------------------------------------------
# Statistics
# ---------------------------------------------------------------------------


def assert_mean(
    values: Iterable[float], expected: float, sigma: float, effect: float | None = None
) -> None:
    """The mean is within Z standard errors of ``expected`` (sigma: one value's std).

    ``effect``: the size of what the check is meant to see (a bias); the bound must be
    under half of it, so a simulator without it would fail.
    """
    x = np.asarray(list(values), dtype=np.float64)
    n = x.size
    assert n >= 30, f"only {n} values"
    se = sigma / math.sqrt(n)
    mean = float(x.mean())
    assert abs(mean - expected) <= Z * se, (
        f"mean {mean:.6g} is {abs(mean - expected) / se:.1f} standard errors ({se:.3g}) "
        f"from {expected:.6g}, n={n}"
    )
    assert abs(mean - (expected + 30.0 * se)) > Z * se
    if effect is not None:
        assert Z * se < abs(effect) / 2, f"the bound {Z * se:.3g} cannot see {effect:.3g}"


def assert_std(values: Iterable[float], sigma: float, power: float = 0.1) -> None:
    """The sample standard deviation is within the chi-square 99.9 % interval of sigma,
    and that interval is tight enough to catch a sigma off by ``power`` (10 %)."""
    x = np.asarray(list(values), dtype=np.float64)
    n = x.size
    dof = n - 1
    statistic = dof * float(x.var(ddof=1)) / sigma**2
    low = float(stats.chi2.ppf(CHI2_ALPHA / 2, dof))
    high = float(stats.chi2.ppf(1 - CHI2_ALPHA / 2, dof))
    assert low <= statistic <= high, (
        f"std {float(x.std(ddof=1)):.6g} against sigma {sigma:.6g}: chi2 {statistic:.1f} "
        f"outside [{low:.1f}, {high:.1f}] (n={n})"
    )
    assert math.sqrt(high / dof) < 1 + power and math.sqrt(low / dof) > 1 - power, f"n={n}"


def assert_rate(successes: int, trials: int, p: float, effect: float | None = None) -> None:
    """A binomial count within Z standard errors of n p; ``effect`` as in assert_mean."""
    assert trials >= 30, f"only {trials} trials"
    se = math.sqrt(p * (1 - p) / trials)
    rate = successes / trials
    assert abs(rate - p) <= Z * se, (
        f"rate {rate:.4f} ({successes}/{trials}) is {abs(rate - p) / se:.1f} standard errors "
        f"({se:.4f}) from {p}"
    )
    if effect is not None:
        assert Z * se < abs(effect) / 2, f"the bound {Z * se:.3g} cannot see {effect:.3g}"


def quantised(sigma: float, lsb: float) -> float:
    """The std of a Gaussian value rounded to an LSB grid (Sheppard: + LSB^2 / 12)."""
    return math.sqrt(sigma**2 + lsb**2 / 12.0)


def angle_diff(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """a - b in degrees, wrapped to [-180, 180)."""
    return np.asarray((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0, dtype=np.float64)


def tod_diff(a: npt.ArrayLike, b: npt.ArrayLike) -> FloatArray:
    """a - b between times of day in seconds, wrapped to [-43200, 43200)."""
    return np.asarray((np.asarray(a) - np.asarray(b) + DAY_S / 2) % DAY_S - DAY_S / 2)


# ---------------------------------------------------------------------------
# Independent geometry
# ---------------------------------------------------------------------------


def ecef(lat: npt.ArrayLike, lon: npt.ArrayLike, h_msl: npt.ArrayLike) -> FloatArray:
    """ECEF (3, n) of points at heights above mean sea level."""
    lat_a, lon_a, h_a = np.broadcast_arrays(
        np.atleast_1d(np.asarray(lat, dtype=np.float64)),
        np.atleast_1d(np.asarray(lon, dtype=np.float64)),
        np.atleast_1d(np.asarray(h_msl, dtype=np.float64)),
    )
    h_ell = h_a + geoid_undulation_m(lat_a, lon_a)
    x, y, z = TO_ECEF.transform(lon_a, lat_a, h_ell)
    return np.array([x, y, z], dtype=np.float64)


def enu_rows(lat: float, lon: float) -> FloatArray:
    """East, north and up unit vectors (rows) at a geodetic position, in ECEF."""
    la, lo = math.radians(lat), math.radians(lon)
    return np.array(
        [
            [-math.sin(lo), math.cos(lo), 0.0],
            [-math.sin(la) * math.cos(lo), -math.sin(la) * math.sin(lo), math.cos(la)],
            [math.cos(la) * math.cos(lo), math.cos(la) * math.sin(lo), math.sin(la)],
        ]
    )


def range_azimuth(site: dict[str, Any], points: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Slant range (m) and azimuth (deg, clockwise from north) of ECEF points (3, n)."""
    antenna = ecef(site["lat"], site["lon"], site["alt_m"])
    local = enu_rows(site["lat"], site["lon"]) @ (points - antenna)
    slant = np.linalg.norm(local, axis=0)
    azimuth = np.degrees(np.arctan2(local[0], local[1])) % 360.0
    return slant, azimuth


# ---------------------------------------------------------------------------
# Scenarios
# ---------------------------------------------------------------------------


def radar(name: str, sic: int, lat: float, lon: float, **fields: Any) -> dict[str, Any]:
    base: dict[str, Any] = {
        "name": name,
        "sac": 10,
        "sic": sic,
        "lat": lat,
        "lon": lon,
        "alt_m": 150.0,
        "antenna_period_s": 4.0,
        "max_range_nm": 220.0,
    }
    return base | fields


def fleet(
    rng: np.random.Generator,
    centre: tuple[float, float],
    transponders: Sequence[str],
    range_nm: tuple[float, float],
    first: int = 0,
) -> list[dict[str, Any]]:
    """Straight and level aircraft around ``centre`` (lat, lon), one per transponder."""
    out = []
    for k, transponder in enumerate(transponders):
        i = first + k
        distance = float(rng.uniform(*range_nm)) * NM
        lon, lat, _ = GEOD.fwd(centre[1], centre[0], float(rng.uniform(0, 360)), distance)
        aircraft: dict[str, Any] = {
            "callsign": f"TST{i:04d}",
            "transponder": transponder,
            "lat": float(lat),
            "lon": float(lon),
            "fl": float(rng.integers(80, 380)),
            "speed_kt": float(rng.uniform(250.0, 460.0)),
            "heading_deg": float(rng.uniform(0.0, 360.0)),
            "mode3a": None if transponder == "none" else f"{0o1000 + i:04o}",
        }
        if transponder == "mode_s":
            aircraft["address"] = f"{0x4C0000 + i:06X}"
        out.append(aircraft)
    return out


def make_scenario(radars: list[dict[str, Any]], **fields: Any) -> Scenario:
    data: dict[str, Any] = {
        "name": "statistics",
        "start": START,
        "duration_s": 120.0,
        "system_centre": {"lat": radars[0]["lat"], "lon": radars[0]["lon"]},
        "radars": radars,
    }
    return Scenario.model_validate(data | fields)


# ---------------------------------------------------------------------------
# A simulated run, decoded and paired with its truth
# ---------------------------------------------------------------------------


@dataclass
class Plot:
    record: dict[str, Any]
    origin: dict[str, Any]
    received: float
    """Reception time of the datagram, POSIX seconds."""
    sequence: int


@dataclass
class Run:
    scenario: Scenario
    start: float
    """The scenario's start, POSIX seconds."""
    duration: float
    radars: dict[str, dict[str, Any]] = field(default_factory=dict)
    """The scenario's radars (with every default) by "SAC/SIC"."""
    plots: dict[str, list[Plot]] = field(default_factory=dict)
    services: dict[str, list[tuple[float, dict[str, Any]]]] = field(default_factory=dict)
    """CAT034 records of each radar with their datagram's reception time."""
    datagrams: list[RecordedDatagram] = field(default_factory=list)
    coverage: dict[str, dict[int, list[int]]] = field(default_factory=dict)
    biases: dict[str, list[dict[str, Any]]] = field(default_factory=dict)
    snapshots: list[dict[str, Any]] = field(default_factory=list)

    def aircraft_plots(self, key: str, psr_only: bool | None = False) -> list[Plot]:
        """Plots of kind "aircraft" (SSR ones by default; None: all)."""
        return [
            p
            for p in self.plots[key]
            if p.origin["kind"] == "aircraft"
            and (psr_only is None or p.origin["psr_only"] is psr_only)
        ]

    def scan_of(self, key: str, detection_time: float) -> int:
        return math.floor((detection_time - self.start) / self.radars[key]["antenna_period_s"])

    def full_scans(self, key: str) -> int:
        """Scans all of whose sectors were sent before the end of the run."""
        return math.floor((self.duration - 0.1) / self.radars[key]["antenna_period_s"])


def r_key(radar: dict[str, Any]) -> str:
    return f"{radar['sac']}/{radar['sic']}"


def decoded(payload: bytes) -> list[Block]:
    events = list(decode_blocks(payload))
    blocks = [e for e in events if isinstance(e, Block)]
    assert len(blocks) == len(events), [e for e in events if not isinstance(e, Block)]
    assert all(b.supported for b in blocks)
    return blocks


def run(
    path: Path,
    scenario: Scenario,
    seed: int,
    no_bias: bool = False,
    duration: float | None = None,
) -> Run:
    simulate(scenario, path, seed=seed, duration_s=duration, no_bias=no_bias)
    rec = read_recording(path)
    assert rec.metadata["seed"] == seed and rec.metadata["no_bias"] is no_bias
    out = Run(scenario, scenario.start.timestamp(), rec.metadata["duration_s"])
    out.radars = {r_key(r): r for r in scenario.model_dump(mode="json")["radars"]}
    out.datagrams = list(rec.datagrams())
    origins: dict[tuple[str, int], dict[str, Any]] = {}
    for message in rec.messages("/truth/plots"):
        origins[message["source"], message["sequence"]] = message
    sequences: Counter[str] = Counter()
    keys = set(out.radars)
    for key in keys:
        out.plots[key], out.services[key] = [], []
    for datagram in out.datagrams:
        if datagram.lan != "A" or datagram.source not in keys:
            continue
        key = datagram.source
        sequence = sequences[key]
        sequences[key] += 1
        records: list[dict[str, Any]] = []
        for block in decoded(datagram.payload):
            assert block.cat in (34, 48), block.cat
            if block.cat == 48:
                records += block.records
            else:
                out.services[key] += [(datagram.time, r) for r in block.records]
        truth = origins.pop((key, sequence), None)
        if not records:
            assert truth is None, f"{key} datagram {sequence} has origins but no CAT048"
            continue
        assert truth is not None, f"{key} datagram {sequence} has no /truth/plots message"
        assert truth["time"] == datagram.time
        assert len(truth["records"]) == len(records), (key, sequence)
        out.plots[key] += [
            Plot(r, o, datagram.time, sequence)
            for r, o in zip(records, truth["records"], strict=True)
        ]
    assert not origins, f"/truth/plots messages without a datagram: {sorted(origins)[:5]}"
    for message in rec.messages("/truth/coverage"):
        out.coverage.setdefault(message["source"], {})[message["scan"]] = message["aircraft"]
    for message in rec.messages("/truth/biases"):
        out.biases.setdefault(message["source"], []).append(message)
    out.snapshots = list(rec.messages("/truth/aircraft"))
    return out


# ---------------------------------------------------------------------------
# The main scenario: two radars over 88 explicit aircraft
# ---------------------------------------------------------------------------

ALPHA = radar(
    "alpha",
    1,
    50.0,
    5.0,
    alt_m=120.0,
    antenna_period_s=4.0,
    psr=False,
    pd_mode_s=0.97,
    pd_ssr=0.8,
    sigma_range_m=40.0,
    sigma_azimuth_deg=0.05,
    bias={
        "range_offset_m": 60.0,
        "range_gain_m_per_nm": 1.5,
        "azimuth_offset_deg": 0.12,
        "time_offset_s": 0.05,
    },
    dual_lan=True,
    output={"group": "232.1.1.1", "port": 8600, "second_lan_group": "232.2.1.1"},
)
BRAVO = radar(
    "bravo",
    2,
    50.6,
    5.9,
    alt_m=420.0,
    antenna_period_s=5.0,
    rotation="counterclockwise",
    sectors=32,
    pd_mode_s=0.97,
    pd_ssr=0.9,
    pd_psr=0.7,
    psr_max_range_nm=80.0,
    sigma_range_m=55.0,
    sigma_azimuth_deg=0.07,
    psr_sigma_range_m=90.0,
    psr_sigma_azimuth_deg=0.11,
    bias={
        "range_offset_m": -80.0,
        "range_gain_m_per_nm": -1.0,
        "azimuth_offset_deg": -0.09,
        "time_offset_s": -0.04,
        "time_drift_s_per_h": 20.0,
    },
    psr_bias={"range_offset_m": 150.0, "azimuth_offset_deg": 0.2},
    clutter={"persistent_per_scan": 4, "random_per_scan": 25.0},
)
KEY_A, KEY_B = r_key(ALPHA), r_key(BRAVO)
TRANSPONDERS = ["mode_s"] * 46 + ["mode_ac"] * 14 + ["none"] * 4
NEAR_BRAVO = range(len(TRANSPONDERS), len(TRANSPONDERS) + 24)
TRANSPONDER = TRANSPONDERS + ["none"] * len(NEAR_BRAVO)


def main_scenario() -> Scenario:
    rng = np.random.default_rng(20260314)
    aircraft = fleet(rng, (50.0, 5.0), TRANSPONDERS, (15.0, 140.0))
    # PSR-only aircraft close to bravo, inside its primary coverage for the whole run.
    aircraft += fleet(rng, (50.6, 5.9), ["none"] * len(NEAR_BRAVO), (10.0, 50.0), len(aircraft))
    return make_scenario([ALPHA, BRAVO], aircraft=aircraft)


@pytest.fixture(scope="module")
def main_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    return run(tmp_path_factory.mktemp("main") / "main.mcap", main_scenario(), seed=7)


@pytest.fixture(scope="module")
def unbiased_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    path = tmp_path_factory.mktemp("unbiased") / "unbiased.mcap"
    return run(path, main_scenario(), seed=8, no_bias=True)


def _range_errors(plots: list[Plot]) -> tuple[FloatArray, FloatArray]:
    rho = np.array([p.record["040"]["RHO"] * NM for p in plots])
    true = np.array([p.origin["true_range_m"] for p in plots])
    return rho - true, true


def _azimuth_errors(plots: list[Plot]) -> FloatArray:
    theta = np.array([p.record["040"]["THETA"] for p in plots])
    return angle_diff(theta, [p.origin["true_azimuth_deg"] for p in plots])


@pytest.mark.parametrize("key", [KEY_A, KEY_B])
def test_range_and_azimuth_errors_follow_bias_and_sigma(main_run: Run, key: str) -> None:
    r = main_run.radars[key]
    bias = r["bias"]
    offset = bias["range_offset_m"]["value"]
    gain = bias["range_gain_m_per_nm"]["value"] / NM
    plots = main_run.aircraft_plots(key)
    assert len(plots) > 800
    error, true = _range_errors(plots)
    sigma_r = quantised(r["sigma_range_m"], RHO_LSB_M)
    residual = error - (offset + gain * true)
    assert_mean(residual, 0.0, sigma_r)
    assert_std(residual, sigma_r)
    # The offset and the gain apart: a straight-line fit of the error against the range,
    # its coefficients' standard errors from the known sigma.
    design = np.column_stack([np.ones_like(true), true])
    fitted, *_ = np.linalg.lstsq(design, error, rcond=None)
    covariance = sigma_r**2 * np.linalg.inv(design.T @ design)
    se_offset, se_gain = np.sqrt(np.diag(covariance))
    assert abs(fitted[0] - offset) <= Z * se_offset, (fitted, offset, se_offset)
    assert abs(fitted[1] - gain) <= Z * se_gain, (fitted, gain, se_gain)
    assert Z * se_offset < abs(offset) / 2 and Z * se_gain < abs(gain) / 2

    azimuth = _azimuth_errors(plots)
    sigma_az = quantised(r["sigma_azimuth_deg"], THETA_LSB_DEG)
    az_bias = bias["azimuth_offset_deg"]["value"]
    assert_mean(azimuth, az_bias, sigma_az, effect=az_bias)
    assert_std(azimuth, sigma_az)


def test_psr_only_plots_follow_the_psr_bias_and_sigma(main_run: Run) -> None:
    r = main_run.radars[KEY_B]
    psr_bias = r["psr_bias"]
    offset = psr_bias["range_offset_m"]["value"]
    az_bias = psr_bias["azimuth_offset_deg"]["value"]
    sigma_r = quantised(r["psr_sigma_range_m"], RHO_LSB_M)
    sigma_az = quantised(r["psr_sigma_azimuth_deg"], THETA_LSB_DEG)
    ssr_offset = r["bias"]["range_offset_m"]["value"]
    everything: list[Plot] = []
    for kind in ("aircraft", "clutter"):
        plots = [
            p for p in main_run.plots[KEY_B] if p.origin["kind"] == kind and p.origin["psr_only"]
        ]
        assert all(p.record["020"]["TYP"] == 1 for p in plots)
        error, _true = _range_errors(plots)
        assert_mean(error, offset, sigma_r, effect=offset - ssr_offset)
        assert_mean(_azimuth_errors(plots), az_bias, sigma_az, effect=az_bias)
        everything += plots
    error, _true = _range_errors(everything)
    assert_std(error - offset, sigma_r)
    assert_std(_azimuth_errors(everything), sigma_az)


@pytest.mark.parametrize("key", [KEY_A, KEY_B])
def test_without_bias_the_errors_have_zero_mean(main_run: Run, unbiased_run: Run, key: str) -> None:
    r = unbiased_run.radars[key]
    assert all(
        b[name] == 0.0
        for b in unbiased_run.biases[key]
        for name in ("range_offset_m", "range_gain", "azimuth_deg", "time_s")
    )
    plots = unbiased_run.aircraft_plots(key)
    error, true = _range_errors(plots)
    sigma_r = quantised(r["sigma_range_m"], RHO_LSB_M)
    # The biased run's mean range error, to show the bound would see the bias missing.
    biased_error, _ = _range_errors(main_run.aircraft_plots(key))
    assert_mean(error, 0.0, sigma_r, effect=float(biased_error.mean()))
    assert_std(error, sigma_r)
    design = np.column_stack([np.ones_like(true), true])
    fitted, *_ = np.linalg.lstsq(design, error, rcond=None)
    se_gain = sigma_r * math.sqrt(np.linalg.inv(design.T @ design)[1, 1])
    assert abs(fitted[1]) <= Z * se_gain
    sigma_az = quantised(r["sigma_azimuth_deg"], THETA_LSB_DEG)
    assert_mean(
        _azimuth_errors(plots), 0.0, sigma_az, effect=r["bias"]["azimuth_offset_deg"]["value"]
    )
    times = [p for p in unbiased_run.plots[key] if "140" in p.record]
    late = tod_diff(
        [p.record["140"] for p in times], [p.origin["detection_time"] % DAY_S for p in times]
    )
    assert np.abs(late).max() <= TIME_LSB_S / 2 + 1e-6


def _time_errors(plots: list[Plot]) -> tuple[FloatArray, FloatArray]:
    """I140 minus the true time of day of detection, and the detection times (POSIX)."""
    detection = np.array([p.origin["detection_time"] for p in plots])
    return tod_diff([p.record["140"] for p in plots], detection % DAY_S), detection


def _scan_time_bias(run: Run, key: str, detection: FloatArray) -> FloatArray:
    """The time_s that /truth/biases reports for each detection's scan."""
    period = run.radars[key]["antenna_period_s"]
    by_scan = {round((b["time"] - run.start) / period): b["time_s"] for b in run.biases[key]}
    return np.array([by_scan[run.scan_of(key, t)] for t in detection])


def _psr_stamped(p: Plot) -> bool:
    """Plots the simulator stamps with its PSR-only errors (split plots copy their
    parent's I140)."""
    return p.origin["kind"] == "clutter" or (
        p.origin["kind"] == "aircraft" and p.origin["psr_only"] is True
    )


@pytest.mark.parametrize("key", [KEY_A, KEY_B])
def test_i140_is_the_detection_time_plus_the_time_bias(main_run: Run, key: str) -> None:
    r = main_run.radars[key]
    offset = r["bias"]["time_offset_s"]["value"]
    drift = r["bias"]["time_drift_s_per_h"]
    period = r["antenna_period_s"]
    plots = [p for p in main_run.plots[key] if "140" in p.record and not _psr_stamped(p)]
    assert len(plots) > 800
    late, detection = _time_errors(plots)
    # Continuous drift; the simulator holds the time bias for a scan (drift x period at most).
    expected = offset + drift * (detection - main_run.start) / 3600.0
    assert np.abs(late - expected).max() <= TIME_LSB_S / 2 + abs(drift) * period / 3600 + 1e-6
    # Exactly, against the bias the truth reports for the plot's scan.
    per_scan = _scan_time_bias(main_run, key, detection)
    assert np.abs(late - per_scan).max() <= TIME_LSB_S / 2 + 1e-6
    reported = np.array([b["time_s"] for b in main_run.biases[key]])
    scan_times = np.array([b["time"] - main_run.start for b in main_run.biases[key]])
    assert np.allclose(reported, offset + drift * scan_times / 3600.0, atol=1e-9)


def test_psr_only_i140_carries_the_reported_time_bias(main_run: Run) -> None:
    plots = [p for p in main_run.plots[KEY_B] if "140" in p.record and _psr_stamped(p)]
    assert len(plots) > 300
    late, detection = _time_errors(plots)
    per_scan = _scan_time_bias(main_run, KEY_B, detection)
    assert np.abs(late - per_scan).max() <= TIME_LSB_S / 2 + 1e-6


def test_wandering_biases_follow_the_reported_truth(tmp_path: Path) -> None:
    """Biases that random-walk: the plots follow the per-scan values of /truth/biases, and
    those walk with the scenario's std per sqrt(hour)."""
    wander = {"range": 300.0, "gain": 20.0, "azimuth": 0.4, "time": 0.2}
    period = 1.0
    scenario = make_scenario(
        [
            radar(
                "wander",
                20,
                51.5,
                -0.5,
                antenna_period_s=period,
                sectors=4,
                psr=False,
                sigma_range_m=30.0,
                sigma_azimuth_deg=0.04,
                bias={
                    "range_offset_m": {"value": 50.0, "wander_per_sqrt_h": wander["range"]},
                    "range_gain_m_per_nm": {"value": 0.0, "wander_per_sqrt_h": wander["gain"]},
                    "azimuth_offset_deg": {"value": 0.1, "wander_per_sqrt_h": wander["azimuth"]},
                    "time_offset_s": {"value": 0.02, "wander_per_sqrt_h": wander["time"]},
                },
                field_monitor={"lat": 51.6, "lon": -0.3, "alt_m": 90.0, "address": "FFFFF4"},
            )
        ],
        duration_s=900.0,
    )
    result = run(tmp_path / "wander.mcap", scenario, seed=19)
    key = "10/20"
    biases = result.biases[key]
    assert len(biases) == 900
    step = math.sqrt(period / 3600.0)
    columns = {"range": "range_offset_m", "gain": "range_gain", "azimuth": "azimuth_deg"}
    columns["time"] = "time_s"
    for name, column in columns.items():
        values = np.array([b[column] for b in biases])
        scale = 1.0 / NM if name == "gain" else 1.0
        assert_std(np.diff(values), wander[name] * scale * step, power=0.15)
    plots = result.plots[key]
    assert len(plots) > 850
    scans = [result.scan_of(key, p.origin["detection_time"]) for p in plots]
    truth = {round((b["time"] - result.start) / period): b for b in biases}
    rho = np.array([p.record["040"]["RHO"] * NM for p in plots])
    true = np.array([p.origin["true_range_m"] for p in plots])
    gain = np.array([truth[k]["range_gain"] for k in scans])
    offset = np.array([truth[k]["range_offset_m"] for k in scans])
    sigma_r = quantised(30.0, RHO_LSB_M)
    residual = rho - (1 + gain) * true - offset
    assert_mean(residual, 0.0, sigma_r, effect=float(np.std(offset)))
    assert_std(residual, sigma_r, power=0.15)
    azimuth = _azimuth_errors(plots) - np.array([truth[k]["azimuth_deg"] for k in scans])
    sigma_az = quantised(0.04, THETA_LSB_DEG)
    assert_mean(azimuth, 0.0, sigma_az)
    assert_std(azimuth, sigma_az, power=0.15)
    late, _detection = _time_errors(plots)
    per_scan = np.array([truth[k]["time_s"] for k in scans])
    assert np.abs(late - per_scan).max() <= TIME_LSB_S / 2 + 1e-6


def test_detection_rates_match_pd(main_run: Run) -> None:
    """Alpha (no PSR): Mode S aircraft at pd_mode_s, Mode A/C at pd_ssr, PSR-only never.
    Bravo: the PSR-only aircraft (all inside its primary range) at pd_psr."""
    mode_s = [a for a, t in enumerate(TRANSPONDER) if t == "mode_s"]
    mode_ac = [a for a, t in enumerate(TRANSPONDER) if t == "mode_ac"]
    checks = [
        (KEY_A, mode_s, ALPHA["pd_mode_s"], ALPHA["pd_mode_s"] - ALPHA["pd_ssr"]),
        (KEY_A, mode_ac, ALPHA["pd_ssr"], ALPHA["pd_mode_s"] - ALPHA["pd_ssr"]),
        (KEY_B, list(NEAR_BRAVO), BRAVO["pd_psr"], 0.9 - BRAVO["pd_psr"]),
    ]
    for key, which, pd, effect in checks:
        # An aircraft near the azimuth where scans start, flying against the beam, can be
        # crossed twice in one scan window: coverage then lists it twice.
        detected: Counter[tuple[int, int]] = Counter()
        for p in main_run.aircraft_plots(key, psr_only=None):
            scan = main_run.scan_of(key, p.origin["detection_time"])
            assert p.origin["aircraft"] in main_run.coverage[key][scan]
            detected[(p.origin["aircraft"], scan)] += 1
        trials = hits = 0
        for scan in range(main_run.full_scans(key)):
            crossings = Counter(main_run.coverage[key][scan])
            for a, count in crossings.items():
                assert detected[(a, scan)] <= count, "more plots than beam crossings"
                if a in which:
                    trials += count
                    hits += detected[(a, scan)]
        assert_rate(hits, trials, pd, effect)
    seen_by_a = {p.origin["aircraft"] for p in main_run.aircraft_plots(KEY_A, psr_only=None)}
    assert not {a for a, t in enumerate(TRANSPONDER) if t == "none"} & seen_by_a
    # Coverage lists what the radar can see at all: not PSR-only aircraft for Alpha.
    covered = {a for scans in main_run.coverage[KEY_A].values() for a in scans}
    assert covered == {a for a, t in enumerate(TRANSPONDER) if t != "none"}


def test_plot_contents_match_the_aircraft(main_run: Run) -> None:
    identities = {a["index"]: a for a in main_run.snapshots[0]["aircraft"]}
    for key in (KEY_A, KEY_B):
        r = main_run.radars[key]
        for p in main_run.aircraft_plots(key, psr_only=None):
            rec, a = p.record, p.origin["aircraft"]
            transponder = TRANSPONDER[a]
            assert rec["010"] == {"SAC": r["sac"], "SIC": r["sic"]}
            if p.origin["psr_only"]:
                assert rec["020"]["TYP"] == 1
                assert not {"070", "090", "220"} & rec.keys()
                continue
            combined = (7,) if transponder == "mode_s" else (3,)
            alone = (5,) if transponder == "mode_s" else (2,)
            assert rec["020"]["TYP"] in (alone + combined if r["psr"] else alone)
            assert rec["020"]["RAB"] == 0
            assert rec["070"]["MODE3A"] == identities[a]["mode3a"]
            step = 0.25 if transponder == "mode_s" else 1.0
            assert abs(rec["090"]["FL"] - p.origin["true_fl"]) <= step / 2 + 1e-9
            if transponder == "mode_s":
                assert rec["220"] == identities[a]["address"]
                assert rec["240"].rstrip() == identities[a]["callsign"]
            else:
                assert "220" not in rec


def test_truth_of_the_plots_is_where_the_aircraft_is(main_run: Run) -> None:
    """Each origin's true range and azimuth, recomputed from /truth/aircraft (1 Hz snapshots
    of straight and level flights, moved to the detection time along their velocity), and
    the beam: at the detection time it points at the aircraft's true azimuth."""
    snapshots = {round(s["time"] - main_run.start): s["aircraft"] for s in main_run.snapshots}
    for key in (KEY_A, KEY_B):
        r = main_run.radars[key]
        plots = main_run.aircraft_plots(key, psr_only=None)
        points, expected_range, expected_az, fl_error = [], [], [], []
        for p in plots:
            t = p.origin["detection_time"] - main_run.start
            second = min(round(t), max(snapshots))
            state = next(s for s in snapshots[second] if s["index"] == p.origin["aircraft"])
            dt = t - second
            velocity = enu_rows(state["lat"], state["lon"]).T @ np.array(
                [state["vel_east_mps"], state["vel_north_mps"], state["vel_up_mps"]]
            )
            points.append(ecef(state["lat"], state["lon"], state["h_msl_m"])[:, 0] + velocity * dt)
            expected_range.append(p.origin["true_range_m"])
            expected_az.append(p.origin["true_azimuth_deg"])
            fl_error.append(p.origin["true_fl"] - state["fl"])
        slant, azimuth = range_azimuth(r, np.array(points).T)
        assert np.abs(slant - expected_range).max() < 0.05
        assert np.abs(angle_diff(azimuth, expected_az)).max() < 1e-5
        assert np.abs(fl_error).max() < 1e-6

        period = r["antenna_period_s"]
        direction = 1.0 if r["rotation"] == "clockwise" else -1.0
        phase = np.array([(p.origin["detection_time"] - main_run.start) % period for p in plots])
        beam = r["initial_azimuth_deg"] + direction * 360.0 * phase / period
        assert np.abs(angle_diff(beam, expected_az)).max() < 1e-3


def test_aircraft_crossing_the_scan_start_azimuth_are_seen_once_per_beam_crossing(
    tmp_path: Path,
) -> None:
    site = (50.0, 5.0)
    aircraft = []
    # Ten miles out at 450 kt, 0.7 deg/s: one flies north to east with the beam, crossing
    # azimuth 0 just before the beam at the end of scan 0; the other flies west against
    # it, crossing in scan 1, whose window then holds two beam crossings.
    for i, (bearing, heading) in enumerate([(359.0, 90.0), (4.0, 270.0)]):
        lon, lat, _ = GEOD.fwd(site[1], site[0], bearing, 10 * NM)
        aircraft.append(
            {
                "callsign": f"CROSS{i}",
                "address": f"{0x3C0000 + i:06X}",
                "lat": float(lat),
                "lon": float(lon),
                "fl": 50.0,
                "speed_kt": 450.0,
                "heading_deg": heading,
            }
        )
    scenario = make_scenario(
        [radar("north", 8, *site, psr=False, pd_mode_s=1.0)], aircraft=aircraft, duration_s=20.0
    )
    result = run(tmp_path / "north.mcap", scenario, seed=16)
    key = "10/8"
    period = 4.0
    for a in (0, 1):
        plots = [p for p in result.aircraft_plots(key) if p.origin["aircraft"] == a]
        times = np.array([p.origin["detection_time"] - result.start for p in plots])
        azimuth = np.array([p.origin["true_azimuth_deg"] for p in plots])
        beam = 360.0 * (times % period) / period
        off_beam = np.abs(angle_diff(beam, azimuth))
        turned = angle_diff(azimuth[1:], azimuth[:-1])
        intervals = np.diff(times) - period * (1.0 + turned / 360.0)
        assert off_beam.max() < 1e-3 and np.abs(intervals).max() < 1e-3, (a, times, azimuth)


@pytest.mark.parametrize("key", [KEY_A, KEY_B])
def test_scans_come_every_antenna_period(main_run: Run, key: str) -> None:
    r = main_run.radars[key]
    period = r["antenna_period_s"]
    direction = 1.0 if r["rotation"] == "clockwise" else -1.0
    seen: dict[int, list[tuple[int, float, float, float]]] = defaultdict(list)
    for p in main_run.aircraft_plots(key, psr_only=None):
        o = p.origin
        scan = main_run.scan_of(key, o["detection_time"])
        seen[o["aircraft"]].append(
            (scan, o["detection_time"], o["true_azimuth_deg"], o["true_range_m"])
        )
    pairs = 0
    for detections in seen.values():
        for (_k1, t1, az1, rho1), (_k2, t2, az2, _) in itertools.pairwise(detections):
            if round((t2 - t1) / period) != 1:  # a missed detection in between
                continue
            pairs += 1
            dt = t2 - t1
            # The beam has to turn by the aircraft's change of azimuth as well.
            turned = float(angle_diff(direction * (az2 - az1), 0.0))
            assert abs(dt - (period + turned / 360.0 * period)) < 1e-3
            if rho1 > 20 * NM:
                assert abs(dt - period) < 0.1
    assert pairs > 500

    # Service messages: one per sector boundary the beam crosses, north markers at north
    # (sectors are fixed in azimuth, counted from north in the sense of rotation), each
    # stamped by the station's clock, which runs with the radar's time bias as I140 does.
    services = main_run.services[key]
    sectors = r["sectors"]
    sector_s = period / sectors
    first_north = (direction * -r["initial_azimuth_deg"]) % 360.0 / 360.0 * period
    first = math.floor(-first_north / sector_s) + 1
    boundaries = np.arange(first, first + len(services))
    true = main_run.start + first_north + boundaries * sector_s
    expected = true + _scan_time_bias(main_run, key, true)
    stamped = main_run.start + tod_diff(
        [rec["030"] for _t, rec in services], main_run.start % DAY_S
    )
    assert np.abs(stamped - expected).max() <= TIME_LSB_S / 2 + 1e-6
    markers = [rec for _t, rec in services if rec["000"] == 1]
    assert len(markers) == math.floor((main_run.duration - 0.1) / period)
    assert all(rec["041"] == period for rec in markers)
    assert all(rec["010"] == {"SAC": r["sac"], "SIC": r["sic"]} for _t, rec in services)
    for (_t, rec), boundary in zip(services, boundaries, strict=True):
        index = int(boundary) % sectors
        assert (rec["000"] == 1) == (index == 0)
        if index:
            azimuth = (direction * index * 360.0 / sectors) % 360.0
            assert abs(angle_diff(rec["020"], azimuth)) <= 360.0 / 512


def test_north_markers_come_when_the_beam_crosses_north(tmp_path: Path) -> None:
    rng = np.random.default_rng(17)
    scenario = make_scenario(
        [radar("east", 9, 44.0, 2.0, initial_azimuth_deg=90.0, psr=False, pd_mode_s=1.0)],
        aircraft=fleet(rng, (44.0, 2.0), ["mode_s"] * 12, (20.0, 100.0)),
        duration_s=40.0,
    )
    result = run(tmp_path / "east.mcap", scenario, seed=18)
    key, period = "10/9", 4.0
    start_tod = result.start % DAY_S
    markers = [rec for _t, rec in result.services[key] if rec["000"] == 1]
    marker_times = result.start + tod_diff([rec["030"] for rec in markers], start_tod)
    assert len(markers) >= 9
    pointing = []
    for p in result.aircraft_plots(key):
        t = p.origin["detection_time"]
        nearest = marker_times[np.argmin(np.abs(marker_times - t))]
        # Clockwise: the beam is at the aircraft's azimuth at t, 90 deg/s further later.
        pointing.append(p.origin["true_azimuth_deg"] + 360.0 * (nearest - t) / period)
    assert len(pointing) > 100
    assert np.abs(angle_diff(pointing, 0.0)).max() < 1.0
    crossings = [rec for _t, rec in result.services[key] if rec["000"] == 2]
    assert all(rec["020"] != 0.0 for rec in crossings)


@pytest.mark.parametrize("key", [KEY_A, KEY_B])
def test_plots_are_sent_per_sector(main_run: Run, key: str) -> None:
    r = main_run.radars[key]
    sector_s = r["antenna_period_s"] / r["sectors"]
    by_datagram: dict[int, list[Plot]] = defaultdict(list)
    for p in main_run.plots[key]:
        by_datagram[p.sequence].append(p)
    for plots in by_datagram.values():
        detection = np.array([p.origin["detection_time"] - main_run.start for p in plots])
        sector = np.floor(detection / sector_s)
        assert np.all(sector == sector[0])
        received = plots[0].received - main_run.start
        # Sent when the beam leaves the sector, after a processing delay of 60-80 ms.
        assert 0.06 - 1e-6 <= received - (sector[0] + 1) * sector_s <= 0.08 + 1e-6
        stamped = [p.record["140"] for p in plots if "140" in p.record and not _psr_stamped(p)]
        if len(stamped) > 1:
            assert float(tod_diff(max(stamped), min(stamped))) <= sector_s + TIME_LSB_S
    for d in main_run.datagrams:
        assert len(d.payload) <= 1472


def test_dual_lan_copies(main_run: Run) -> None:
    lan_a = [d for d in main_run.datagrams if d.source == KEY_A and d.lan == "A"]
    lan_b = [d for d in main_run.datagrams if d.source == KEY_A and d.lan == "B"]
    assert len(lan_a) == len(lan_b) > 100
    for a, b in zip(lan_a, lan_b, strict=True):
        assert a.payload == b.payload
        assert a.src == b.src
        assert a.dst == ("232.1.1.1", 8600) and b.dst == ("232.2.1.1", 8600)
        assert 0.0 < b.time - a.time < 0.001
    assert not [d for d in main_run.datagrams if d.source == KEY_B and d.lan == "B"]


# ---------------------------------------------------------------------------
# Clutter, pathologies, the field monitor, big sectors, midnight
# ---------------------------------------------------------------------------


def test_clutter_per_scan(tmp_path: Path) -> None:
    persistent, random_rate = 20, 15.0
    scenario = make_scenario(
        [
            radar(
                "clutter",
                3,
                47.0,
                8.0,
                antenna_period_s=1.0,
                clutter={"persistent_per_scan": persistent, "random_per_scan": random_rate},
                psr_max_range_nm=60.0,
                min_range_nm=1.0,
            )
        ],
        duration_s=300.0,
    )
    result = run(tmp_path / "clutter.mcap", scenario, seed=11)
    key = "10/3"
    scans = result.full_scans(key)
    clutter = [p for p in result.plots[key] if p.origin["kind"] == "clutter"]
    assert len(clutter) == len(result.plots[key])
    per_scan = Counter(result.scan_of(key, p.origin["detection_time"]) for p in clutter)
    counts = np.array([per_scan[k] for k in range(scans)], dtype=np.float64)
    # Persistent clutter seen at 0.9 each scan (binomial), random clutter Poisson.
    sigma = math.sqrt(persistent * 0.9 * 0.1 + random_rate)
    assert_mean(counts, persistent * 0.9 + random_rate, sigma, effect=persistent * 0.1)
    positions = Counter(
        (p.origin["true_range_m"], p.origin["true_azimuth_deg"])
        for p in clutter
        if result.scan_of(key, p.origin["detection_time"]) < scans
    )
    fixed = [n for n in positions.values() if n > 1]
    assert len(fixed) == persistent
    assert_rate(sum(fixed), persistent * scans, 0.9, effect=0.1)
    ranges = np.array([p.origin["true_range_m"] for p in clutter]) / NM
    assert ranges.min() >= 1.0 and ranges.max() <= 60.0
    assert all(p.record["020"]["TYP"] == 1 for p in clutter)


def test_missing_time_reflections_and_splits(tmp_path: Path) -> None:
    rates = {"missing_time": 0.1, "reflection": 0.08, "split": 0.06}
    rng = np.random.default_rng(5)
    aircraft = fleet(rng, (45.0, -1.0), ["mode_s"] * 40, (20.0, 120.0))
    scenario = make_scenario(
        [
            radar(
                "ghosts",
                4,
                45.0,
                -1.0,
                antenna_period_s=2.0,
                psr=False,
                pd_mode_s=1.0,
                sigma_range_m=30.0,
                sigma_azimuth_deg=0.04,
                bias={"range_offset_m": 40.0, "azimuth_offset_deg": 0.1},
                pathologies=rates,
            )
        ],
        aircraft=aircraft,
    )
    result = run(tmp_path / "ghosts.mcap", scenario, seed=12)
    key = "10/4"
    identities = {a["index"]: a for a in result.snapshots[0]["aircraft"]}
    plots = result.plots[key]
    kinds = Counter(p.origin["kind"] for p in plots)
    primary = result.aircraft_plots(key)
    assert kinds["aircraft"] == len(primary) > 2000
    missing = sum("140" not in p.record for p in primary)
    assert_rate(missing, len(primary), rates["missing_time"], effect=rates["missing_time"])
    assert_rate(kinds["reflection"], len(primary), rates["reflection"], effect=rates["reflection"])
    assert_rate(kinds["split"], len(primary), rates["split"], effect=rates["split"])
    # Each pathology follows the plot it comes from, in the same datagram.
    parent: dict[tuple[int, float], Plot] = {
        (p.origin["aircraft"], p.origin["detection_time"]): p for p in primary
    }
    reflectors, swings = [], []
    for p in plots:
        if p.origin["kind"] not in ("reflection", "split"):
            continue
        source = parent[p.origin["aircraft"], p.origin["detection_time"]]
        assert source.sequence == p.sequence
        assert ("140" in p.record) == ("140" in source.record)
        if "140" in p.record:
            assert p.record["140"] == source.record["140"]
        rec, true_az = p.record, p.origin["true_azimuth_deg"]
        if p.origin["kind"] == "reflection":
            address = identities[p.origin["aircraft"]]["address"]
            assert rec["220"] == address == source.record["220"]
            assert rec["070"] == source.record["070"]
            assert rec["070"]["MODE3A"] == identities[p.origin["aircraft"]]["mode3a"]
            assert rec["020"] == source.record["020"]
            further = rec["040"]["RHO"] - source.record["040"]["RHO"]
            assert 0.5 - 1 / 256 <= further <= 3.0 + 1 / 256
            # A mirror image: the reflector's azimuth is halfway (modulo 180 degrees).
            reflectors.append((rec["040"]["THETA"] + source.record["040"]["THETA"]) / 2 % 180)
            swings.append(abs(float(angle_diff(rec["040"]["THETA"], true_az))))
        else:
            assert p.origin["psr_only"] is True
            assert rec["020"]["TYP"] == 1
            assert not {"070", "090", "220", "240", "250"} & rec.keys()
            assert rec["040"]["RHO"] == source.record["040"]["RHO"]
            apart = abs(float(angle_diff(rec["040"]["THETA"], source.record["040"]["THETA"])))
            assert 0.4 - THETA_LSB_DEG <= apart <= 1.2 + THETA_LSB_DEG
    # Two reflectors: every midpoint is within 0.01 degrees of one of two azimuths.
    left = np.array(reflectors)
    for _reflector in range(2):
        if left.size:
            left = left[np.abs((left - left[0] + 90.0) % 180.0 - 90.0) > 0.01]
    assert left.size == 0, left
    assert len(reflectors) > 100 and float(np.median(swings)) > 5.0


@pytest.fixture(scope="module")
def far_run(tmp_path_factory: pytest.TempPathFactory) -> Run:
    """One aircraft at FL450 270 NM out, beyond what I040 RHO holds (256 NM)."""
    lon, lat, _ = GEOD.fwd(5.0, 50.0, 45.0, 270 * NM)
    aircraft = {"callsign": "FAR1", "address": "3C0FA1", "lat": lat, "lon": lon}
    aircraft |= {"fl": 450.0, "speed_kt": 300.0, "heading_deg": 45.0}
    far = radar("far", 30, 50.0, 5.0, max_range_nm=400.0, psr=False, sigma_range_m=40.0)
    far["pathologies"] = {"reflection": 0.5, "split": 0.5}
    scenario = make_scenario([far], aircraft=[aircraft], duration_s=60.0)
    return run(tmp_path_factory.mktemp("far") / "far.mcap", scenario, seed=21)


def _extended_range_nm(record: dict[str, Any]) -> float:
    """The plot's range: the Reserved Expansion's extended range when there is one."""
    return float(record["RE"]["ERR"] if "RE" in record else record["040"]["RHO"])


def test_plots_beyond_256_nm_carry_the_extended_range(far_run: Run) -> None:
    plots = far_run.aircraft_plots("10/30")
    assert len(plots) >= 10
    for p in plots:
        assert p.record["020"]["ERR"] == 1 and "RE" in p.record
        assert p.record["040"]["RHO"] == 65535 / 256
        error = _extended_range_nm(p.record) * NM - p.origin["true_range_m"]
        assert abs(error - 60.0) < 5 * 40.0  # the default offset of radar(), 5 sigma


def test_reflections_and_splits_beyond_256_nm_keep_the_extended_range(far_run: Run) -> None:
    plots = far_run.plots["10/30"]
    parent = {p.origin["detection_time"]: p for p in far_run.aircraft_plots("10/30")}
    extra = [p for p in plots if p.origin["kind"] in ("reflection", "split")]
    assert Counter(p.origin["kind"] for p in extra).keys() == {"reflection", "split"}
    for p in extra:
        source = parent[p.origin["detection_time"]]
        further = _extended_range_nm(p.record) - _extended_range_nm(source.record)
        if p.origin["kind"] == "split":
            assert abs(further) <= 1 / 256
        else:
            assert 0.5 - 1 / 256 <= further <= 3.0 + 1 / 256
        assert (p.record["020"].get("ERR", 0) == 1) == ("RE" in p.record)


MONITOR_SITES = [
    # (radar lat, lon, alt; monitor lat, lon, alt; address or None)
    (49.2, 16.6, 600.0, 49.27, 16.71, 380.0, "FFFFF1"),
    (-33.9, 151.1, 80.0, -33.8, 150.95, 250.0, None),
]


def test_field_monitor_sits_at_its_surveyed_position_plus_the_bias(tmp_path: Path) -> None:
    radars = []
    for i, (lat, lon, alt, m_lat, m_lon, m_alt, address) in enumerate(MONITOR_SITES):
        monitor: dict[str, Any] = {"lat": m_lat, "lon": m_lon, "alt_m": m_alt, "mode3a": "7777"}
        if address is not None:
            monitor["address"] = address
        radars.append(
            radar(
                f"monitor{i}",
                10 + i,
                lat,
                lon,
                alt_m=alt,
                antenna_period_s=1.0,
                sectors=4,
                psr=False,
                sigma_range_m=35.0,
                sigma_azimuth_deg=0.045,
                bias={
                    "range_offset_m": 45.0 - 90.0 * i,
                    "range_gain_m_per_nm": 30.0,
                    "azimuth_offset_deg": 0.11 - 0.25 * i,
                },
                field_monitor=monitor,
            )
        )
    result = run(tmp_path / "monitor.mcap", make_scenario(radars, duration_s=700.0), seed=13)
    for spec, (*_site, m_lat, m_lon, m_alt, address) in zip(radars, MONITOR_SITES, strict=True):
        key = r_key(spec)
        r = result.radars[key]
        plots = result.plots[key]
        assert plots and all(p.origin["kind"] == "field_monitor" for p in plots)
        slant, azimuth = range_azimuth(r, ecef(m_lat, m_lon, m_alt))
        true_range, true_az = float(slant[0]), float(azimuth[0])
        assert all(abs(p.origin["true_range_m"] - true_range) < 1e-3 for p in plots)
        assert all(
            abs(float(angle_diff(p.origin["true_azimuth_deg"], true_az))) < 1e-6 for p in plots
        )
        for p in plots:
            assert p.record["020"]["RAB"] == 1
            assert p.record["020"]["TYP"] == (5 if address else 2)
            assert p.record["070"]["MODE3A"] == "7777"
            assert p.record.get("220") == address
        gain = r["bias"]["range_gain_m_per_nm"]["value"] / NM
        offset = r["bias"]["range_offset_m"]["value"]
        az_bias = r["bias"]["azimuth_offset_deg"]["value"]
        rho = np.array([p.record["040"]["RHO"] * NM for p in plots])
        sigma_r = quantised(r["sigma_range_m"], RHO_LSB_M)
        expected = (1 + gain) * true_range + offset
        assert_mean(rho, expected, sigma_r, effect=offset + gain * true_range)
        assert_std(rho, sigma_r)
        theta = angle_diff([p.record["040"]["THETA"] for p in plots], true_az)
        sigma_az = quantised(r["sigma_azimuth_deg"], THETA_LSB_DEG)
        assert_mean(theta, az_bias, sigma_az, effect=az_bias)
        assert_std(theta, sigma_az)
        scans = result.full_scans(key)
        seen = sum(result.scan_of(key, p.origin["detection_time"]) < scans for p in plots)
        assert_rate(seen, scans, r["pd_mode_s"] if address else r["pd_ssr"])


def test_full_sectors_are_split_into_datagrams_under_the_mtu(tmp_path: Path) -> None:
    sectors = 8
    scenario = make_scenario(
        [
            radar(
                "busy",
                5,
                52.0,
                13.0,
                antenna_period_s=4.0,
                sectors=sectors,
                clutter={"random_per_scan": 1600.0},
                bias={"time_offset_s": 0.3},
            )
        ],
        duration_s=16.0,
    )
    result = run(tmp_path / "busy.mcap", scenario, seed=14)
    key = "10/5"
    sector_s = 4.0 / sectors
    by_time: dict[float, list[RecordedDatagram]] = defaultdict(list)
    for d in result.datagrams:
        assert len(d.payload) <= 1472
        blocks = decoded(d.payload)
        if blocks[0].cat == 48:
            by_time[d.time].append(d)
    assert max(len(v) for v in by_time.values()) >= 2
    by_datagram: dict[int, list[Plot]] = defaultdict(list)
    for p in result.plots[key]:
        by_datagram[p.sequence].append(p)
    start_tod = result.start % DAY_S
    for plots in by_datagram.values():
        received = plots[0].received - result.start
        sector = round((received - 0.07) / sector_s) - 1
        for p in plots:
            stamped = float(tod_diff(p.record["140"], start_tod)) - 0.3
            assert sector * sector_s - TIME_LSB_S <= stamped <= (sector + 1) * sector_s + TIME_LSB_S


def test_midnight_wraps_the_time_of_day(tmp_path: Path) -> None:
    rng = np.random.default_rng(9)
    scenario = make_scenario(
        [
            radar("late", 6, 40.0, -4.0, bias={"time_offset_s": 0.4}),
            radar("early", 7, 40.3, -3.6, bias={"time_offset_s": -0.5}, antenna_period_s=5.0),
        ],
        start=datetime(2026, 12, 31, 23, 59, 0, tzinfo=UTC),
        aircraft=fleet(rng, (40.0, -4.0), ["mode_s"] * 10, (10.0, 80.0)),
    )
    result = run(tmp_path / "midnight.mcap", scenario, seed=15)
    for key, offset in (("10/6", 0.4), ("10/7", -0.5)):
        plots = [p for p in result.plots[key] if "140" in p.record]
        stamps = np.array([p.record["140"] for p in plots])
        assert stamps.min() >= 0.0 and stamps.max() < DAY_S
        assert (stamps > 86340.0).sum() > 20 and (stamps < 60.0).sum() > 20
        detection = np.array([p.origin["detection_time"] for p in plots]) % DAY_S
        assert np.abs(tod_diff(stamps, detection) - offset).max() <= TIME_LSB_S / 2 + 1e-6
        services = np.array([rec["030"] for _t, rec in result.services[key]])
        assert services.min() >= 0.0 and services.max() < DAY_S
        assert services.min() < 60.0 and services.max() > 86340.0
        sector_s = result.radars[key]["antenna_period_s"] / result.radars[key]["sectors"]
        steps = tod_diff(services[1:], services[:-1])
        assert np.abs(steps - sector_s).max() <= TIME_LSB_S
