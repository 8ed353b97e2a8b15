"""The radar stage's compiled passes against their numpy references, to the bit:
``geodesy.compiled.convert_batch_plots`` against ``convert_plots`` and
``tracking.dap_kernels.fill_daps`` against ``tracking.daps.plot_daps``, on drawn batches
(sites with a north offset and a geoid, heights out of reach, ranges of 0 and NaN, one
plot and many) and on the plots of the bundled recording. NaN's sign bit is the one
thing allowed to differ."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from asterix.plots import PLOT_DTYPE as RAW_DTYPE
from asterix.plots import extract_plots
from tracker_service.geodesy import HeightModel, RadarSite, SystemPlane, convert_plots
from tracker_service.geodesy.compiled import convert_batch_plots
from tracker_service.ingest import PlotClock
from tracker_service.radar_stage import convert_batch
from tracker_service.service.core import build_radar_stage
from tracker_service.service.replay import open_replay
from tracker_service.tracking.dap_kernels import INPUTS, fill_daps
from tracker_service.tracking.daps import plot_daps
from tracker_service.tracking.plots import DAP_FIELDS

RECORDING = Path(__file__).resolve().parent.parent / "recordings" / "three_sites.mcap"
SITES = (
    RadarSite(48.2, 17.1, 350.0),
    RadarSite(49.5, 16.2, 780.0, geoid_m=44.6, north_offset_deg=0.37),
    RadarSite(-33.9, 151.2, 12.0, geoid_m=22.0, north_offset_deg=-1.2),
)
PLANE = SystemPlane(48.7, 17.6)


def _same(a: npt.NDArray[Any], b: npt.NDArray[Any]) -> bool:
    """The same bits, zeros' signs included; NaN where the other is NaN (its sign bit,
    which no output shows, may differ)."""
    if a.shape != b.shape or a.dtype != b.dtype:
        return False
    if a.dtype.kind != "f":
        return a.tobytes() == b.tobytes()
    nan = np.isnan(a)
    return bool((nan == np.isnan(b)).all()) and a[~nan].tobytes() == b[~nan].tobytes()


def _drawn(rng: np.random.Generator, n: int) -> list[npt.NDArray[np.float64]]:
    rho = rng.uniform(0.0, 480_000.0, n)
    rho[rng.random(n) < 0.05] = 0.0
    rho[rng.random(n) < 0.05] = np.nan
    theta = rng.uniform(0.0, 360.0, n)
    height = rng.uniform(-100.0, 15_000.0, n)
    height[rng.random(n) < 0.05] = 400_000.0  # above the slant range: unreachable
    height_sigma = rng.uniform(0.0, 3_500.0, n)
    sigma_rho = rng.choice([30.0, 70.0], n)
    sigma_theta = rng.choice([0.05, 0.1], n)
    return [rho, theta, height, height_sigma, sigma_rho, sigma_theta]


@pytest.mark.parametrize("n", [1, 2, 13, 40, 300])
@pytest.mark.parametrize("site", SITES)
def test_compiled_conversion_is_convert_plots_to_the_bit(n: int, site: RadarSite) -> None:
    rng = np.random.default_rng(n)
    for _ in range(5):
        columns = _drawn(rng, n)
        reference = convert_plots(site, PLANE, *columns)
        compiled, _ = convert_batch_plots(site, PLANE, *columns)
        for name in reference.__dataclass_fields__:
            assert _same(getattr(reference, name), getattr(compiled, name)), name


def _raw_with_daps(rng: np.random.Generator, n: int) -> npt.NDArray[Any]:
    """Plot rows with registers drawn inside and outside their plausible bounds, some
    absent, some winds and turn rates that disagree."""
    raw = np.zeros(n, RAW_DTYPE)
    spans = {
        "roll_deg": 80.0,
        "true_track_deg": 360.0,
        "ground_speed_kt": 800.0,
        "track_angle_rate_deg_s": 10.0,
        "magnetic_heading_deg": 360.0,
        "indicated_airspeed_kt": 600.0,
        "mach": 1.4,
        "baro_rate_fpm": 9000.0,
        "inertial_rate_fpm": 9000.0,
        "selected_altitude_mcp_ft": 70000.0,
        "selected_altitude_fms_ft": 70000.0,
        "true_airspeed_kt": 800.0,
    }
    for name in INPUTS:
        values = rng.uniform(-spans[name], spans[name], n)
        if name in ("true_track_deg", "magnetic_heading_deg", "ground_speed_kt"):
            values = np.abs(values)
        values[rng.random(n) < 0.3] = np.nan
        raw[name] = values
    # Half of the rows consistent: the rate as a coordinated turn of the roll.
    calm = rng.random(n) < 0.5
    raw["ground_speed_kt"][calm] = rng.uniform(50.0, 500.0, calm.sum())
    raw["true_airspeed_kt"][calm] = raw["ground_speed_kt"][calm] + 20.0
    raw["roll_deg"][calm] = rng.uniform(-30.0, 30.0, calm.sum())
    speed = raw["ground_speed_kt"][calm] * 1852.0 / 3600.0
    rate = np.degrees(9.80665 * np.tan(np.radians(raw["roll_deg"][calm])) / speed)
    raw["track_angle_rate_deg_s"][calm] = rate + rng.normal(0.0, 1.5, calm.sum())
    return raw


@pytest.mark.parametrize("n", [1, 7, 60])
def test_compiled_daps_are_plot_daps_to_the_bit(n: int) -> None:
    rng = np.random.default_rng(100 + n)
    implausible_seen = 0
    for site in SITES:
        columns = _drawn(rng, n)
        columns[0] = rng.uniform(1_000.0, 400_000.0, n)
        converted, steps = convert_batch_plots(site, PLANE, *columns)
        raw = _raw_with_daps(rng, n)
        reference, implausible = plot_daps(
            raw, PLANE, converted.lat_deg, converted.lon_deg, converted.height_m
        )
        found = fill_daps(raw, converted.lat_deg, converted.height_m, steps)
        assert found is not None
        out, flags, compiled_implausible = found
        for k, name in enumerate(DAP_FIELDS):
            assert _same(reference[name], out[:, k]), name
        assert _same(reference["dap_flags"], flags)
        assert _same(implausible, compiled_implausible)
        implausible_seen += int(implausible.sum())
    assert implausible_seen > 0
    assert fill_daps(_absent(n), *_no_daps_inputs(n)) is None


def _absent(n: int) -> npt.NDArray[Any]:
    raw = np.zeros(n, RAW_DTYPE)
    for name in INPUTS:
        raw[name] = np.nan
    return raw


def _no_daps_inputs(n: int) -> tuple[Any, ...]:
    converted, steps = convert_batch_plots(SITES[0], PLANE, *_drawn(np.random.default_rng(0), n))
    return converted.lat_deg, converted.height_m, steps


def test_the_radar_stages_batches_are_the_numpy_conversions() -> None:
    """The recording's plots through ``convert_batch`` as the radar stage runs it and
    through ``convert_plots``: the same positions, covariances and Jacobians."""
    replay = open_replay(str(RECORDING))
    stage = build_radar_stage(replay.config)
    batches = 0
    for _name, datagram in replay.datagrams:
        raw = extract_plots(datagram.payload).plots
        if not len(raw) or batches >= 150:
            continue
        source = f"{raw['sac'][0]}/{raw['sic'][0]}"
        info = stage.infos[source]
        args = (info, stage.plane, PlotClock(), HeightModel(), datagram.time, 0, 0)
        _, table, c = convert_batch(raw, *args)
        rho = np.asarray(raw["rho"], np.float64) * 1852.0
        reference = convert_plots(
            info.site,
            stage.plane,
            rho,
            raw["theta"],
            table["height_m"],
            table["height_sigma_m"],
            np.where(raw["typ"] == 1, info.psr_sigma_range_m, info.sigma_range_m),
            np.where(raw["typ"] == 1, info.psr_sigma_azimuth_deg, info.sigma_azimuth_deg),
        )
        assert _same(np.ascontiguousarray(table["x"]), reference.x)
        assert _same(np.ascontiguousarray(table["R"]), reference.R)
        assert _same(np.ascontiguousarray(c[:, :, 2]), reference.polar_jacobian[:, :, 1])
        batches += 1
    assert batches == 150
