"""The tracker's input: one radar's plots, already in the system plane."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.tracking.config import SHARED_MODE3A_CODES

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

PLOT_DTYPE = np.dtype(
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
"""Structured-array form of the input, one row per plot (see ``PlotArrays``)."""


@dataclass(frozen=True)
class PlotArrays:
    """Plots as columns: time (POSIX s, of measurement), x, y (m, east/north), R (N, 2, 2),
    flight_level (NaN absent), fl_valid, mode3a (-1 absent), mode3a_valid, address (24 bit,
    -1 absent), typ (I048/020 TYP), plot_id."""

    time: FloatArray
    x: FloatArray
    y: FloatArray
    R: FloatArray
    flight_level: FloatArray
    fl_valid: BoolArray
    mode3a: IntArray
    mode3a_valid: BoolArray
    address: IntArray
    typ: IntArray
    plot_id: IntArray

    def __len__(self) -> int:
        return int(self.time.shape[0])

    def columns(self) -> tuple[Any, ...]:
        """The fields in declaration order. Spelt out rather than built with
        ``dataclasses.fields``: this runs several times per batch, and the reflection cost
        more than the indexing of a small batch."""
        return (
            self.time,
            self.x,
            self.y,
            self.R,
            self.flight_level,
            self.fl_valid,
            self.mode3a,
            self.mode3a_valid,
            self.address,
            self.typ,
            self.plot_id,
        )

    def take(self, index: npt.NDArray[Any]) -> PlotArrays:
        return PlotArrays(*(column[index] for column in self.columns()))

    def select(self, mask: BoolArray) -> PlotArrays:
        """The rows where ``mask`` is true; ``self`` itself when it keeps every row (the
        usual case, and columns are never written in place, so sharing them is safe)."""
        return self if mask.all() else self.take(mask)

    @staticmethod
    def concat(a: PlotArrays, b: PlotArrays) -> PlotArrays:
        if len(b) == 0:
            return a  # the columns are never written in place, so sharing them is safe
        if len(a) == 0:
            return b
        return PlotArrays(
            *(np.concatenate([ca, cb]) for ca, cb in zip(a.columns(), b.columns(), strict=True))
        )

    @staticmethod
    def empty() -> PlotArrays:
        return PlotArrays(*(column[:0] for column in _EMPTY.columns()))


def as_plot_arrays(plots: PlotArrays | npt.NDArray[Any]) -> PlotArrays:
    """Columns of known dtypes from a ``PlotArrays`` or a structured array with these fields."""

    def col(name: str, dtype: type[Any]) -> Any:
        values = getattr(plots, name) if isinstance(plots, PlotArrays) else plots[name]
        return np.ascontiguousarray(values, dtype=dtype)

    if isinstance(plots, PlotArrays) and _has_column_dtypes(plots):
        return plots  # already columns of the right dtypes: no copy per batch
    time = col("time", np.float64)
    r = col("R", np.float64).reshape(time.shape[0], 2, 2)
    return PlotArrays(
        time=time,
        x=col("x", np.float64),
        y=col("y", np.float64),
        R=r,
        flight_level=col("flight_level", np.float64),
        fl_valid=col("fl_valid", np.bool_),
        mode3a=col("mode3a", np.int64),
        mode3a_valid=col("mode3a_valid", np.bool_),
        address=col("address", np.int64),
        typ=col("typ", np.int64),
        plot_id=col("plot_id", np.int64),
    )


def is_shared_code(code: IntArray) -> BoolArray:
    """``np.isin(code, SHARED_MODE3A_CODES)`` without its set-up cost on a few elements."""
    shared = np.zeros(code.shape, dtype=bool)
    for value in SHARED_MODE3A_CODES:
        shared |= code == value
    return shared


_COLUMN_DTYPES = tuple(
    np.dtype(t)
    for t in (
        np.float64,
        np.float64,
        np.float64,
        np.float64,
        np.float64,
        np.bool_,
        np.int64,
        np.bool_,
        np.int64,
        np.int64,
        np.int64,
    )
)


def _has_column_dtypes(plots: PlotArrays) -> bool:
    return plots.R.ndim == 3 and all(
        column.dtype == dtype and column.flags.c_contiguous
        for column, dtype in zip(plots.columns(), _COLUMN_DTYPES, strict=True)
    )


_EMPTY = as_plot_arrays(np.zeros(0, dtype=PLOT_DTYPE))
