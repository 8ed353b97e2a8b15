"""``daps.plot_daps`` (the numpy reference) as one compiled pass over a batch, writing
straight into the tracker's batch and the plot table: the same values to the bit.

The plausibility limits, the wind and turn-rate checks, the turn rate and the velocity in
the plane run in ``plot_daps``'s order of operations; its one ``tan`` stays a numpy
call (numpy's SIMD ``tan`` and the C library's differ in the last bit), made before the
pass, and the plane's Jacobian comes from the conversion's projections
(``geodesy.compiled``). ``tests/test_plot_daps.py`` holds the two to it.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.compiled import PlaneSteps, plane_jacobian_at
from tracker_service.numba_symbols import numba
from tracker_service.tracking.config import KNOT_M_S
from tracker_service.tracking.daps import (
    _LIMITS,
    G0,
    MAX_RATE_ROLL_DISAGREEMENT_DEG_S,
    MAX_WIND_KT,
    MIN_TURN_SPEED_KT,
)
from tracker_service.tracking.plots import (
    DAP_FIELDS,
    DAP_SELECTED_ALTITUDE,
    DAP_TURN_RATE,
    DAP_VELOCITY,
    DAP_VERTICAL_RATE,
    PUBLISHED_DAP_FIELDS,
    BoolArray,
    FloatArray,
)

__all__ = ["INPUTS", "PUBLISHED", "fill_daps"]

INPUTS = (
    *DAP_FIELDS[:9],
    "selected_altitude_mcp_ft",
    "selected_altitude_fms_ft",
    "true_airspeed_kt",
)
"""The decoded register columns (``asterix.daps``) the pass reads, in its order: the
first nine are ``DAP_FIELDS``' first nine, copied."""
ROLL, TRACK, GS, RATE, HEADING, IAS, MACH, BARO, INERTIAL, MCP, FMS, TAS = range(len(INPUTS))
SELECTED, VX, VY, TURN = 9, 10, 11, 12
"""Columns of the pass's output (``DAP_FIELDS`` order): the first nine as the inputs'."""
_LIMIT = np.array([_LIMITS.get(name, np.inf) for name in DAP_FIELDS[:10]])
"""The plausible bound of each of the first ten ``DAP_FIELDS`` (the copied registers and
the selected altitude; the angles have none)."""
PUBLISHED = np.array([DAP_FIELDS.index(name) for name in PUBLISHED_DAP_FIELDS], np.intp)
"""The columns of ``PUBLISHED_DAP_FIELDS`` among the pass's output."""
_DISAGREEMENT_RAD = float(np.radians(MAX_RATE_ROLL_DISAGREEMENT_DEG_S))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _roll_rate(gs_kt: float, tan_roll: float) -> float:  # pragma: no cover - compiled
    """``daps._turn_rates``' coordinated-turn rate from tan(roll) (given)."""
    if gs_kt >= MIN_TURN_SPEED_KT:
        return -G0 * tan_roll / (gs_kt * KNOT_M_S)
    return np.nan


@numba.njit(cache=True, error_model="numpy")
def _daps(
    registers: tuple[FloatArray, ...],
    tan_roll: FloatArray,
    limits: FloatArray,
    lat: FloatArray,
    height: FloatArray,
    steps: PlaneSteps,
    out: FloatArray,
    flags: npt.NDArray[np.uint8],
    implausible: BoolArray,
) -> bool:  # pragma: no cover - compiled
    """``plot_daps`` of the registers (``INPUTS``' columns) into ``out`` (n,
    ``DAP_FIELDS``), ``flags`` and ``implausible``; False (and nothing written) when no
    plot has any register."""
    n = out.shape[0]
    found = False
    for column in registers:
        for i in range(n):
            found = found or np.isfinite(column[i])
    if not found:
        return False
    r = np.empty(len(INPUTS))
    for i in range(n):
        for c, column in enumerate(registers):
            r[c] = column[i]
        o = out[i]
        for c in range(9):
            o[c] = r[c]
        o[SELECTED] = r[MCP] if np.isfinite(r[MCP]) else r[FMS]
        bad = False
        for c in range(10):
            if abs(o[c]) > limits[c]:
                o[c] = np.nan
                bad = True
        windy = abs(o[GS] - r[TAS]) > MAX_WIND_KT
        rate = -np.radians(o[RATE])
        roll_rate = _roll_rate(o[GS], tan_roll[i] if o[ROLL] == o[ROLL] else np.nan)
        disagree = abs(rate - roll_rate) > _DISAGREEMENT_RAD
        if windy:
            o[GS] = np.nan
        if disagree:
            o[ROLL] = np.nan
            o[RATE] = np.nan
        implausible[i] = bad or windy or disagree
        rate = -np.radians(o[RATE])
        roll_rate = _roll_rate(o[GS], tan_roll[i] if o[ROLL] == o[ROLL] else np.nan)
        o[TURN] = rate if np.isfinite(rate) else roll_rate
        o[VX] = np.nan
        o[VY] = np.nan
        if np.isfinite(o[GS]) and np.isfinite(o[TRACK]):
            speed = o[GS] * KNOT_M_S
            psi = np.radians(o[TRACK])
            east = speed * np.sin(psi)
            north = speed * np.cos(psi)
            j00, j01, j10, j11 = plane_jacobian_at(i, lat, height[i], steps)
            o[VX] = j00 * east + j01 * north
            o[VY] = j10 * east + j11 * north
        bits = DAP_VELOCITY if np.isfinite(o[VX]) else 0
        bits |= DAP_TURN_RATE if np.isfinite(o[TURN]) else 0
        vertical = np.isfinite(o[BARO]) or np.isfinite(o[INERTIAL])
        bits |= DAP_VERTICAL_RATE if vertical else 0
        bits |= DAP_SELECTED_ALTITUDE if np.isfinite(o[SELECTED]) else 0
        flags[i] = bits
    return True


def fill_daps(
    raw: npt.NDArray[Any],
    lat: FloatArray,
    height: FloatArray,
    steps: PlaneSteps,
) -> tuple[FloatArray, npt.NDArray[np.uint8], BoolArray] | None:
    """``plot_daps`` of a batch's plot rows (``asterix.plots`` rows), given the
    conversion's latitudes, heights above MSL and projections: (the ``DAP_FIELDS``
    columns (n, 13), ``dap_flags``, which plots had an implausible DAP); None when no
    plot has any register."""
    n = len(raw)
    out = np.empty((n, len(DAP_FIELDS)))
    flags = np.empty(n, np.uint8)
    implausible = np.empty(n, np.bool_)
    tan_roll = np.tan(np.radians(raw["roll_deg"]))
    registers = tuple(raw[name] for name in INPUTS)
    if not _daps(registers, tan_roll, _LIMIT, lat, height, steps, out, flags, implausible):
        return None
    return out, flags, implausible
