"""The tracker's input: one radar's plots, already in the system plane."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.small_arrays import concatenate_rows, row_bytes, take_rows
from tracker_service.tracking.config import SHARED_MODE3A_CODES

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

DAP_FIELDS = (
    "roll_deg",
    "true_track_deg",
    "ground_speed_kt",
    "track_angle_rate_deg_s",
    "magnetic_heading_deg",
    "indicated_airspeed_kt",
    "mach",
    "baro_rate_fpm",
    "inertial_rate_fpm",
    "selected_altitude_ft",
    "dap_vx",
    "dap_vy",
    "dap_turn_rate_rad_s",
)
"""Mode S DAPs of each plot (``tracking.daps.plot_daps``), floats, NaN when absent or
implausible: BDS 5,0 roll (deg, right wing down positive), true track angle (deg),
ground speed (kt), track angle rate (deg/s, clockwise); BDS 6,0 magnetic heading (deg),
IAS (kt), Mach, barometric and inertial vertical rates (ft/min); BDS 4,0 selected
altitude (ft, MCP/FCU, else FMS); and what the tracker uses of BDS 5,0: the velocity in
the plane ``dap_vx``, ``dap_vy`` (m/s) and the turn rate in the plane
``dap_turn_rate_rad_s`` (counter-clockwise positive, as the IMM's turn models).

``dap_flags`` says which DAPs the tracker may use (``DAP_VELOCITY``, ``DAP_TURN_RATE``,
``DAP_VERTICAL_RATE``: either vertical rate, ``DAP_SELECTED_ALTITUDE`` bits): rows made
with ``np.zeros`` have 0 there, so a zero velocity, climb rate or selected altitude is
never taken for a measurement. Make new rows with ``empty_plots`` (DAPs NaN)."""
DAP_VELOCITY = 1
DAP_TURN_RATE = 2
DAP_VERTICAL_RATE = 4
DAP_SELECTED_ALTITUDE = 8
PUBLISHED_DAP_FIELDS = (
    "magnetic_heading_deg",
    "indicated_airspeed_kt",
    "mach",
    "selected_altitude_ft",
    "baro_rate_fpm",
    "inertial_rate_fpm",
    "roll_deg",
    "track_angle_rate_deg_s",
    "true_track_deg",
    "ground_speed_kt",
)
"""The DAPs the plot table carries on to the system-track messages and CAT062 I380
(``outputs.messages.DapName``, in this order)."""

BASE_PLOT_DTYPE = np.dtype(
    [
        ("time", np.float64),
        ("x", np.float64),
        ("y", np.float64),
        ("R", np.float64, (2, 2)),
        ("flight_level", np.float64),
        ("fl_valid", np.bool_),
        ("mode3a", np.int64),
        ("mode3a_valid", np.bool_),
        ("address", np.int64),
        ("typ", np.int64),
        ("plot_id", np.int64),
    ]
)
"""The columns before the DAPs: rows built from these (``as_plot_arrays``) get the DAPs
absent."""

PLOT_DTYPE = np.dtype(
    [
        *((name, BASE_PLOT_DTYPE.fields[name][0]) for name in BASE_PLOT_DTYPE.names or ()),  # type: ignore[index]
        *((name, np.float64) for name in DAP_FIELDS),
        ("dap_flags", np.uint8),
    ]
)
"""Structured-array form of the input, one row per plot (see ``PlotArrays``)."""


class PlotArrays:
    """Plots as columns: time (POSIX s, of measurement), x, y (m, east/north), R (N, 2, 2),
    flight_level (NaN absent), fl_valid, mode3a (-1 absent), mode3a_valid, address (24 bit,
    -1 absent), typ (I048/020 TYP), plot_id.

    The columns are views of one ``PLOT_DTYPE`` array, ``rows``, so that taking,
    selecting or joining plots is one copy of whole rows instead of one per column (the
    tracker does this several times per sector of a few plots). The rows are never
    written in place, so plots may share them."""

    __slots__ = ("rows",)

    def __init__(self, rows: npt.NDArray[Any]) -> None:
        self.rows = rows

    @property
    def time(self) -> FloatArray:
        column: FloatArray = self.rows["time"]
        return column

    @property
    def x(self) -> FloatArray:
        column: FloatArray = self.rows["x"]
        return column

    @property
    def y(self) -> FloatArray:
        column: FloatArray = self.rows["y"]
        return column

    @property
    def R(self) -> FloatArray:
        column: FloatArray = self.rows["R"]
        return column

    @property
    def flight_level(self) -> FloatArray:
        column: FloatArray = self.rows["flight_level"]
        return column

    @property
    def fl_valid(self) -> BoolArray:
        column: BoolArray = self.rows["fl_valid"]
        return column

    @property
    def mode3a(self) -> IntArray:
        column: IntArray = self.rows["mode3a"]
        return column

    @property
    def mode3a_valid(self) -> BoolArray:
        column: BoolArray = self.rows["mode3a_valid"]
        return column

    @property
    def address(self) -> IntArray:
        column: IntArray = self.rows["address"]
        return column

    @property
    def typ(self) -> IntArray:
        column: IntArray = self.rows["typ"]
        return column

    @property
    def plot_id(self) -> IntArray:
        column: IntArray = self.rows["plot_id"]
        return column

    def __len__(self) -> int:
        return int(self.rows.shape[0])

    def take(self, index: npt.NDArray[Any]) -> PlotArrays:
        """The rows at ``index`` (integers or a mask), always a copy."""
        return PlotArrays(take_rows(self.rows, index))

    def select(self, mask: BoolArray) -> PlotArrays:
        """The rows where ``mask`` is true; ``self`` itself when it keeps every row (the
        usual case)."""
        return self if mask.all() else self.take(mask)

    @staticmethod
    def concat(a: PlotArrays, b: PlotArrays) -> PlotArrays:
        if len(b) == 0:
            return a
        if len(a) == 0:
            return b
        return PlotArrays(concatenate_rows([a.rows, b.rows]))

    @staticmethod
    def empty() -> PlotArrays:
        return _EMPTY


def as_plot_arrays(plots: PlotArrays | npt.NDArray[Any]) -> PlotArrays:
    """``PlotArrays`` from a ``PlotArrays`` or a structured array with these fields. A
    contiguous ``PLOT_DTYPE`` array is wrapped, not copied: callers that keep plots
    beyond the batch keep copies (``take``)."""
    if isinstance(plots, PlotArrays):
        return plots
    if plots.dtype == PLOT_DTYPE and plots.flags.c_contiguous:
        return PlotArrays(plots)
    rows = empty_plots(plots.shape[0])
    for name in PLOT_DTYPE.names or ():
        if name in (plots.dtype.names or ()):
            rows[name] = plots[name].reshape(rows[name].shape)
    return PlotArrays(rows)


def _empty_row() -> npt.NDArray[Any]:
    row = np.zeros(1, dtype=PLOT_DTYPE)
    for name in DAP_FIELDS:
        row[name] = np.nan
    return row_bytes(row)


_EMPTY_ROW = _empty_row()
"""One empty row as opaque bytes: repeated, ``empty_plots`` in one copy (a sector's
batch paid a column assignment per DAP field)."""


def empty_plots(n: int) -> npt.NDArray[Any]:
    """``n`` zeroed ``PLOT_DTYPE`` rows with the DAP columns absent (NaN)."""
    return np.repeat(_EMPTY_ROW, n).view(PLOT_DTYPE)


def is_shared_code(code: IntArray) -> BoolArray:
    """``np.isin(code, SHARED_MODE3A_CODES)`` without its set-up cost on a few elements."""
    shared = np.zeros(code.shape, dtype=bool)
    for value in SHARED_MODE3A_CODES:
        shared |= code == value
    return shared


_EMPTY = PlotArrays(np.zeros(0, dtype=PLOT_DTYPE))
