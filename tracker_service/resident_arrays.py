"""Tables preallocated for their largest use, resident from the start.

``np.zeros`` of a large array maps its pages lazily (calloc gives zero pages that cost
memory only when first written). A table sized for its largest use, such as the system
tracks by number (``fusion.table``: about 20 kB a number on ``artas``, 8,192 numbers) or
a radar's clutter cells, then grows the process's resident memory for as long as new
rows are first written: on ``artas`` the fusion process's grew for the whole half hour of
a run as system numbers were first used, which reads as a leak and hides what the host
must have. Written at once, the memory a service needs shows from its start and stays
flat; the write costs a few tens of milliseconds at start and a doubling table's new
rows once.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

__all__ = ["resident_zeros"]


def resident_zeros(
    shape: int | tuple[int, ...], dtype: npt.DTypeLike = np.float64
) -> npt.NDArray[Any]:
    """Zeros of ``shape`` and ``dtype``, every page written (``np.full`` writes them)."""
    return np.full(shape, 0, dtype=dtype)
