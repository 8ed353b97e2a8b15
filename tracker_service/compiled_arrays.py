"""numpy's semantics for the compiled kernels of the radar stage: ``np.maximum`` and
``np.minimum`` of two floats (NaN when either is: Python's ``max`` and ``min`` are not) and
``small_arrays.median`` (numpy's median), as numba functions (``cache=True``)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba

__all__ = ["maximum", "median", "minimum"]


@numba.njit(cache=True, error_model="numpy", inline="always")
def maximum(a: float, b: float) -> float:  # pragma: no cover - compiled
    """``np.maximum`` of two floats: NaN when either is."""
    if a != a or b != b:
        return a + b
    return a if a >= b else b


@numba.njit(cache=True, error_model="numpy", inline="always")
def minimum(a: float, b: float) -> float:  # pragma: no cover - compiled
    """``np.minimum`` of two floats: NaN when either is."""
    if a != a or b != b:
        return a + b
    return a if a <= b else b


@numba.njit(cache=True, error_model="numpy")
def median(values: npt.NDArray[np.float64]) -> float:  # pragma: no cover - compiled
    """``small_arrays.median`` of a non-empty array: the middle value, the mean of the two
    middle ones for an even count, NaN when any is NaN."""
    ordered = np.sort(values)
    if np.isnan(ordered[-1]):
        return math.nan
    middle = ordered.shape[0] // 2
    if ordered.shape[0] % 2:
        return float(ordered[middle])
    return float((ordered[middle - 1] + ordered[middle]) / 2.0)
