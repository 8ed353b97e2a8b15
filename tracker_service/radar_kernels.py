"""The radar stage's per-plot columns before the conversion in one compiled pass: the plot
clock of I140 times, the Mode C height and its sigma (or the stand-in), the field
monitor's and the surveyed transponders' heights, the range in metres, the sigmas by
plot type, the validity of the codes and each plot's use (``PlotUse``): what
``radar_stage.convert_batch`` computed in some 40 numpy calls per batch, with the same
operations, so the same values.

The Mode C height comes from ``Atmosphere.flight_level_height_m`` computed once for every
flight level the plot path can decode (a quarter FL, 14 bits signed: ``level_table``), as
numpy computes each element alike however it is called; a level off that grid (never
from the decoder) makes the caller compute the batch's heights with numpy itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy import Atmosphere, HeightModel
from tracker_service.ingest import DAY_S, TimeSource
from tracker_service.numba_symbols import numba

__all__ = ["LEVEL_STEPS", "PlotColumns", "level_table", "plot_columns"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
LEVEL_STEPS = 4
"""Flight-level codes per FL (CAT048 I090 and CAT001 HGT: 1/4 FL)."""
LEVEL_CODES = 1 << 14
"""14 bits, signed: codes -8192 to 8191."""
_I140 = int(TimeSource.I140)
# PlotUse values (radar_stage.PlotUse, not imported: it imports this module).
FIELD_MONITOR, RADAR_TRACK, TEST_TARGET, SIMULATED, NO_POSITION = 1, 2, 4, 5, 7
NM = 1852.0


@cache
def level_table(atmosphere: Atmosphere) -> FloatArray:
    """The geometric height (m above MSL) of every decodable flight level, by code + 8192."""
    codes = np.arange(-LEVEL_CODES // 2, LEVEL_CODES // 2, dtype=np.float64)
    table: FloatArray = atmosphere.flight_level_height_m(codes / LEVEL_STEPS)
    table.flags.writeable = False
    return table


@numba.njit(cache=True, error_model="numpy")
def _columns(
    time_of_day: FloatArray,
    received: float,
    fl: FloatArray,
    fl_invalid: npt.NDArray[np.int32],
    fl_garbled: npt.NDArray[np.int32],
    rab: npt.NDArray[np.int32],
    rho: FloatArray,
    theta: FloatArray,
    typ: npt.NDArray[np.int32],
    sim: npt.NDArray[np.int32],
    tst: npt.NDArray[np.int32],
    track_report: npt.NDArray[np.int32],
    mode3a: npt.NDArray[np.int32],
    mode3a_invalid: npt.NDArray[np.int32],
    mode3a_garbled: npt.NDArray[np.int32],
    surveyed: FloatArray,
    levels: FloatArray,
    mode_c: FloatArray,
    use_mode_c: bool,
    mode_c_sigma_m: float,
    mode_c_relative_sigma: float,
    assumed_height_m: float,
    assumed_sigma_m: float,
    monitor_alt_m: float,
    has_monitor: bool,
    sigmas: FloatArray,
    times: FloatArray,
    sources: npt.NDArray[np.int8],
    fl_ok: npt.NDArray[np.bool_],
    fl_clean: FloatArray,
    height: FloatArray,
    height_sigma: FloatArray,
    rho_m: FloatArray,
    sigma_rho: FloatArray,
    sigma_theta: FloatArray,
    unknown: npt.NDArray[np.bool_],
    mode3a_valid: npt.NDArray[np.bool_],
    is_rab: npt.NDArray[np.bool_],
    use: npt.NDArray[np.int8],
) -> tuple[bool, bool, bool]:  # pragma: no cover - compiled
    """Every column (the outputs after ``sigmas`` = ssr range, ssr azimuth, psr range, psr
    azimuth); returns (every plot had an I140, a level was off the table, a height is
    unknown)."""
    n = fl.shape[0]
    stamped = True
    for i in range(n):
        if not np.isfinite(time_of_day[i]):
            stamped = False
    if stamped:
        # ingest.posix_from_time_of_day
        day = math.floor(received / DAY_S) * DAY_S
        for i in range(n):
            posix = day + time_of_day[i]
            times[i] = posix - DAY_S * np.round((posix - received) / DAY_S)
            sources[i] = _I140
    off_table = False
    any_unknown = False
    half = levels.shape[0] // 2
    for i in range(n):
        level = fl[i]
        ok = np.isfinite(level) and fl_invalid[i] != 1 and fl_garbled[i] != 1
        fl_ok[i] = ok
        fl_clean[i] = level if ok else np.nan
        # HeightModel.heights: Mode C, or the stand-in.
        if ok:
            if use_mode_c:
                h = mode_c[i]
            else:
                code = level * 4.0
                slot = int(code) + half if -half <= code < half else -1
                if slot < 0 or code != math.floor(code):
                    off_table = True
                    h = np.nan
                else:
                    h = levels[slot]
            height[i] = h
            height_sigma[i] = np.hypot(mode_c_sigma_m, mode_c_relative_sigma * h)
        else:
            height[i] = assumed_height_m
            height_sigma[i] = assumed_sigma_m
        monitor = rab[i] == 1
        is_rab[i] = monitor
        if has_monitor and monitor:
            # The test transponder's height is surveyed: better than its Mode C.
            height[i] = monitor_alt_m
            height_sigma[i] = 0.0
        known = np.isfinite(surveyed[i])
        if known:
            height[i] = surveyed[i]
            height_sigma[i] = 0.0
        r = rho[i] * NM
        rho_m[i] = r
        lost = not ok and np.isfinite(r) and not (has_monitor and monitor) and not known
        unknown[i] = lost
        any_unknown |= lost
        psr_only = typ[i] == 1
        sigma_rho[i] = sigmas[2] if psr_only else sigmas[0]
        sigma_theta[i] = sigmas[3] if psr_only else sigmas[1]
        mode3a_valid[i] = mode3a[i] >= 0 and mode3a_invalid[i] != 1 and mode3a_garbled[i] != 1
        # PlotUse by precedence: no position, a radar's track, a field monitor, a test
        # target, a simulated one.
        u = 0
        if sim[i] == 1:
            u = SIMULATED
        if tst[i] == 1:
            u = TEST_TARGET
        if monitor:
            u = FIELD_MONITOR
        if track_report[i] == 1:
            u = RADAR_TRACK
        if not (np.isfinite(rho[i]) and np.isfinite(theta[i])):
            u = NO_POSITION
        use[i] = u
    return stamped, off_table, any_unknown


@dataclass(frozen=True)
class PlotColumns:
    """One batch's columns (``plot_columns``); ``times`` and ``time_sources`` are set only
    when ``stamped`` (every plot had an I140)."""

    times: FloatArray
    time_sources: npt.NDArray[np.int8]
    fl_ok: BoolArray
    fl_clean: FloatArray
    height: FloatArray
    height_sigma: FloatArray
    rho_m: FloatArray
    sigma_rho: FloatArray
    sigma_theta: FloatArray
    unknown: BoolArray
    mode3a_valid: BoolArray
    rab: BoolArray
    use: npt.NDArray[np.int8]
    stamped: bool = False
    any_unknown: bool = False


def plot_columns(
    raw: npt.NDArray[np.void],
    received: float,
    heights: HeightModel,
    sigmas: FloatArray,
    monitor_alt_m: float | None,
    surveyed: FloatArray | None,
) -> PlotColumns:
    """The per-plot columns of one batch of ``asterix.plots`` rows (see the module
    docstring); ``sigmas``: the radar's range and azimuth sigmas, then its primary ones;
    ``monitor_alt_m``: its field monitor's surveyed height; ``surveyed``: per plot, the
    surveyed height of the fixed transponder it is (NaN for others)."""
    n = len(raw)
    f, b = np.float64, np.bool_
    out: list[npt.NDArray[Any]] = [
        np.empty(n, t) for t in (f, np.int8, b, f, f, f, f, f, f, b, b, b, np.int8)
    ]
    fl = raw["flight_level"]
    levels = level_table(heights.atmosphere)
    mode_c = levels[:0]
    if surveyed is None:
        surveyed = np.full(n, np.nan)
    for use_mode_c in (False, True):
        stamped, off_table, any_unknown = _columns(
            raw["time_of_day"], received, fl, raw["flight_level_invalid"],
            raw["flight_level_garbled"], raw["rab"], raw["rho"], raw["theta"], raw["typ"],
            raw["sim"], raw["tst"], raw["track_report"], raw["mode3a"], raw["mode3a_invalid"],
            raw["mode3a_garbled"], surveyed, levels, mode_c, use_mode_c, heights.mode_c_sigma_m,
            heights.mode_c_relative_sigma, heights.assumed_height_m, heights.assumed_sigma_m,
            0.0 if monitor_alt_m is None else monitor_alt_m, monitor_alt_m is not None, sigmas,
            *out,
        )  # fmt: skip
        if not off_table:
            break
        # A level off the decoder's grid: numpy's heights of the batch, element by element.
        mode_c = heights.atmosphere.flight_level_height_m(np.asarray(fl, np.float64))
    times, sources, fl_ok, fl_clean, height, sigma, rho_m, sr, st, unknown, valid, rab, use = out
    return PlotColumns(
        times, sources, fl_ok, fl_clean, height, sigma, rho_m, sr, st, unknown, valid, rab, use,
        stamped, any_unknown,
    )  # fmt: skip
