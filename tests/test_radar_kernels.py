"""``radar_kernels.plot_columns`` against the plain numpy reference of the same columns
(what ``radar_stage.convert_batch`` computed before it): the same values to the bit, on
drawn rows of every kind (levels invalid, garbled, absent and off the decoder's grid, a
field monitor, surveyed transponders, primary plots, test, simulated and track reports,
no position, no I140)."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from asterix.plots import PLOT_DTYPE as RAW_DTYPE
from tracker_service.geodesy import Atmosphere, HeightModel
from tracker_service.ingest import PlotClock
from tracker_service.radar_kernels import level_table, plot_columns
from tracker_service.radar_stage import PlotUse

SIGMAS = np.array([40.0, 0.07, 70.0, 0.12])
RECEIVED = 1_780_000_123.25


def _rows(rng: np.random.Generator, n: int, off_grid: bool) -> npt.NDArray[Any]:
    raw = np.zeros(n, RAW_DTYPE)
    raw["time_of_day"] = rng.uniform(0.0, 86_400.0, n)
    raw["flight_level"] = rng.integers(-40, 1_800, n) / 4.0
    if off_grid:
        raw["flight_level"][0] = 312.3
    raw["flight_level"][rng.random(n) < 0.2] = np.nan
    for name in ("flight_level_invalid", "flight_level_garbled", "rab", "sim", "tst"):
        raw[name] = rng.random(n) < 0.1
    raw["track_report"] = np.where(rng.random(n) < 0.1, 1, rng.choice([0, -1], n))
    raw["typ"] = rng.integers(0, 4, n)
    raw["rho"] = rng.uniform(0.0, 250.0, n)
    raw["theta"] = rng.uniform(0.0, 360.0, n)
    raw["rho"][rng.random(n) < 0.05] = np.nan
    raw["theta"][rng.random(n) < 0.05] = np.nan
    raw["mode3a"] = np.where(rng.random(n) < 0.2, -1, rng.integers(0, 4096, n))
    raw["mode3a_invalid"] = rng.random(n) < 0.1
    raw["mode3a_garbled"] = rng.random(n) < 0.1
    return raw


def _reference(
    raw: npt.NDArray[Any],
    heights: HeightModel,
    monitor_alt_m: float | None,
    surveyed: npt.NDArray[np.float64] | None,
) -> dict[str, npt.NDArray[Any]]:
    """The columns as ``convert_batch`` computed them with numpy."""
    times, sources = PlotClock().times(raw, RECEIVED)
    fl = np.asarray(raw["flight_level"], dtype=np.float64)
    fl_ok = (
        np.isfinite(fl) & (raw["flight_level_invalid"] != 1) & (raw["flight_level_garbled"] != 1)
    )
    fl_clean = np.where(fl_ok, fl, np.nan)
    height, height_sigma = heights.heights(fl_clean)
    rab = np.asarray(raw["rab"]) == 1
    if monitor_alt_m is not None:
        height = np.where(rab, monitor_alt_m, height)
        height_sigma = np.where(rab, 0.0, height_sigma)
    if surveyed is not None:
        known = np.isfinite(surveyed)
        height = np.where(known, surveyed, height)
        height_sigma = np.where(known, 0.0, height_sigma)
    rho_m = np.asarray(raw["rho"], dtype=np.float64) * 1852.0
    unknown = ~fl_ok & np.isfinite(rho_m)
    if monitor_alt_m is not None:
        unknown &= ~rab
    if surveyed is not None:
        unknown &= ~np.isfinite(surveyed)
    psr_only = raw["typ"] == 1
    mode3a = np.asarray(raw["mode3a"], np.int64)
    use = np.zeros(len(raw), np.int8)
    use[np.asarray(raw["sim"]) == 1] = PlotUse.SIMULATED
    use[np.asarray(raw["tst"]) == 1] = PlotUse.TEST_TARGET
    use[rab] = PlotUse.FIELD_MONITOR
    use[raw["track_report"] == 1] = PlotUse.RADAR_TRACK
    use[~(np.isfinite(raw["rho"]) & np.isfinite(raw["theta"]))] = PlotUse.NO_POSITION
    return {
        "times": times,
        "time_sources": sources,
        "fl_ok": fl_ok,
        "fl_clean": fl_clean,
        "height": height,
        "height_sigma": height_sigma,
        "rho_m": rho_m,
        "sigma_rho": np.where(psr_only, SIGMAS[2], SIGMAS[0]),
        "sigma_theta": np.where(psr_only, SIGMAS[3], SIGMAS[1]),
        "unknown": unknown,
        "mode3a_valid": (mode3a >= 0) & (raw["mode3a_invalid"] != 1) & (raw["mode3a_garbled"] != 1),
        "rab": rab,
        "use": use,
    }


@pytest.mark.parametrize("n", [1, 5, 40])
@pytest.mark.parametrize("off_grid", [False, True])
@pytest.mark.parametrize("atmosphere", [Atmosphere(), Atmosphere(1003.0, -7.0)])
def test_plot_columns_are_the_numpy_columns(n: int, off_grid: bool, atmosphere: Atmosphere) -> None:
    rng = np.random.default_rng(n + 10 * off_grid)
    heights = HeightModel(atmosphere=atmosphere)
    for monitor, with_surveyed in ((None, False), (512.0, True)):
        raw = _rows(rng, n, off_grid)
        surveyed = None
        if with_surveyed:
            surveyed = np.where(rng.random(n) < 0.2, 350.0, np.nan)
        got = plot_columns(raw, RECEIVED, heights, SIGMAS, monitor, surveyed)
        want = _reference(raw, heights, monitor, surveyed)
        assert got.stamped
        assert got.any_unknown == bool(want["unknown"].any())
        for name, values in want.items():
            column = getattr(got, name)
            assert column.tobytes() == values.astype(column.dtype).tobytes(), name


def test_plots_without_i140_are_left_to_the_plot_clock() -> None:
    raw = _rows(np.random.default_rng(3), 6, False)
    raw["time_of_day"][2] = np.nan
    assert not plot_columns(raw, RECEIVED, HeightModel(), SIGMAS, None, None).stamped


def test_the_level_table_is_the_atmospheres_heights() -> None:
    atmosphere = Atmosphere(1021.0, 9.0)
    table = level_table(atmosphere)
    codes = np.array([-8192, -1, 0, 1, 1400, 8191])
    assert table[codes + 8192].tobytes() == atmosphere.flight_level_height_m(codes / 4).tobytes()
