"""The tracker's input: one radar's plots, already in the system plane."""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

import numpy as np
import numpy.typing as npt

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

    def take(self, index: npt.NDArray[Any]) -> PlotArrays:
        return PlotArrays(**{f.name: getattr(self, f.name)[index] for f in fields(self)})

    @staticmethod
    def concat(a: PlotArrays, b: PlotArrays) -> PlotArrays:
        return PlotArrays(
            **{f.name: np.concatenate([getattr(a, f.name), getattr(b, f.name)]) for f in fields(a)}
        )

    @staticmethod
    def empty() -> PlotArrays:
        return as_plot_arrays(np.zeros(0, dtype=PLOT_DTYPE))


def as_plot_arrays(plots: PlotArrays | npt.NDArray[Any]) -> PlotArrays:
    """Columns of known dtypes from a ``PlotArrays`` or a structured array with these fields."""

    def col(name: str, dtype: type[Any]) -> Any:
        values = getattr(plots, name) if isinstance(plots, PlotArrays) else plots[name]
        return np.ascontiguousarray(values, dtype=dtype)

    n = col("time", np.float64).shape[0]
    r = col("R", np.float64).reshape(n, 2, 2)
    return PlotArrays(
        time=col("time", np.float64),
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
