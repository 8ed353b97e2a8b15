"""Stand-ins for numpy functions whose set-up costs more than their work on the few dozen
values of one radar's batch (``np.median``, ``np.isin``): the same results to the bit
(tests/test_small_arrays.py compares them with numpy's)."""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

__all__ = ["is_one_of", "median"]


def median(values: npt.ArrayLike) -> float:
    """``float(np.median(values))`` of a non-empty 1-D sequence: the middle value, the
    mean of the two middle ones for an even count, NaN when any is NaN."""
    ordered = np.sort(np.asarray(values, dtype=np.float64))
    if np.isnan(ordered[-1]):  # the sort puts NaN last
        return math.nan
    middle = len(ordered) // 2
    if len(ordered) % 2:
        return float(ordered[middle])
    return float((ordered[middle - 1] + ordered[middle]) / 2.0)


def is_one_of(values: IntArray, codes: IntArray) -> BoolArray:
    """``np.isin(values, codes)`` of a 1-D array and a few codes."""
    found: BoolArray = (values[:, None] == codes[None, :]).any(axis=1)
    return found
