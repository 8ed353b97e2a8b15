"""Stand-ins for numpy functions whose set-up costs more than their work on the few dozen
values of one radar's batch (``np.median``, ``np.isin``; the copy, take and concatenation
of structured rows): the same results to the bit (tests/test_small_arrays.py compares
them with numpy's)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

__all__ = ["concatenate_rows", "copy_rows", "is_one_of", "median", "row_bytes", "take_rows"]


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


_ROW_BYTES: dict[int, np.dtype[np.void]] = {}
"""Per row size, its opaque bytes' dtype (a dtype costs to build: made once)."""


def row_bytes(rows: npt.NDArray[Any]) -> npt.NDArray[np.void]:
    """A 1-D structured array's rows as opaque fixed-size bytes (a view). numpy copies
    structured rows field by field, setting up a transfer per field at each call: 15 us
    to copy 20 rows of the 36 fields of a radar's plots, 80 us to join two such arrays,
    where whole rows of bytes copy in 2-3 us. ``.view(rows.dtype)`` turns them back."""
    size = rows.dtype.itemsize
    opaque = _ROW_BYTES.get(size)
    if opaque is None:
        opaque = _ROW_BYTES[size] = np.dtype((np.void, size))
    return rows.view(opaque)


def copy_rows(rows: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """``rows.copy()`` of a 1-D structured array (see ``row_bytes``)."""
    return row_bytes(rows).copy().view(rows.dtype)


def take_rows(rows: npt.NDArray[Any], index: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """``rows[index]`` of a 1-D structured array, ``index`` integers or a mask."""
    taken: npt.NDArray[Any] = row_bytes(rows)[index]
    return taken.view(rows.dtype)


def concatenate_rows(parts: Sequence[npt.NDArray[Any]]) -> npt.NDArray[Any]:
    """``np.concatenate(parts)`` of 1-D structured arrays of one dtype."""
    joined: npt.NDArray[Any] = np.concatenate([row_bytes(p) for p in parts])
    return joined.view(parts[0].dtype)
