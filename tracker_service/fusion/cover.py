"""Where the radars see targets, learnt from their plots: the cover that says whether a
second radar may need to join a primary-only aircraft's system track
(``fusion.psr_height``) and whether an ADS-B report can be checked against a radar before
it founds a system track (``fusion.adsb_source``).

The service is not configured with each radar's reach (range, PSR reach, terrain
shadows); the plots hold it. Per square cell of the system plane and per radar, the time
of the radar's latest plot there (of the plot types asked for); a position is covered by
a radar that has put a plot in its cell or a neighbouring one within ``memory_s`` (a
radar that went down covers nothing after that). Until a radar has reported for one
antenna period its cover is not known yet: ``known`` says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.arrays import is_member
from tracker_service.tracking.plots import BoolArray, FloatArray

__all__ = ["PSR_TYPES", "RadarCover"]

PSR_TYPES = (1, 3, 6, 7)
"""I048/020 TYP values with a primary detection (single PSR, SSR + PSR, Mode S + PSR)."""


class RadarCover:
    """See the module docstring. ``types``: the plot types (I048/020 TYP) that count,
    None for all."""

    def __init__(
        self, cell_m: float, memory_s: float, types: tuple[int, ...] | None = None
    ) -> None:
        self.cell_m = cell_m
        self.memory_s = memory_s
        self.types = None if types is None else np.array(types)
        self._seen: dict[tuple[int, int], dict[int, float]] = {}
        """Per cell (ix, iy), per radar, the time of its latest plot there."""
        self._first: dict[int, float] = {}
        """Per radar, the time of its first plot."""

    def _cells(self, x: FloatArray, y: FloatArray) -> zip[tuple[int, int]]:
        """The cell (ix, iy) of each position."""
        ix = np.floor(x / self.cell_m).astype(np.int64).tolist()
        iy = np.floor(y / self.cell_m).astype(np.int64).tolist()
        return zip(ix, iy, strict=True)

    def note(self, radar: int, plots: npt.NDArray[Any]) -> None:
        """A batch's plots (``PLOT_DTYPE`` rows) of ``radar``."""
        if not len(plots):
            return
        if radar not in self._first:
            self._first[radar] = float(plots["time"].min())
        # Column by column: the rows of a plot table are wide.
        x, y = plots["x"], plots["y"]
        counted = np.isfinite(x) & np.isfinite(y)
        if self.types is not None:
            counted &= is_member(plots["typ"], self.types)
        if not counted.any():
            return
        time = float(plots["time"][counted].max())
        # A set of the batch's few cells: ``np.unique(..., axis=0)`` sorts rows through a
        # structured view, ten times the cost (the order the cells are noted in is
        # immaterial: each is looked up by its indices).
        for cell in set(self._cells(x[counted], y[counted])):
            self._seen.setdefault(cell, {})[radar] = time

    def known(self, radars: dict[int, float], time: float) -> bool:
        """Whether every radar of ``radars`` (index: antenna period s) has reported for a
        full antenna period by ``time`` (before, a cell without its plots may simply not
        have been swept yet)."""
        return all(
            radar in self._first and time - self._first[radar] >= period
            for radar, period in radars.items()
        )

    def covered(self, x: FloatArray, y: FloatArray, time: float, besides: int = -1) -> BoolArray:
        """Per position, whether a radar other than ``besides`` has put a plot within a
        cell of it in the last ``memory_s``."""
        out = np.zeros(len(x), dtype=bool)
        for m, (ix, iy) in enumerate(self._cells(np.asarray(x), np.asarray(y))):
            out[m] = any(
                radar != besides and time - seen <= self.memory_s
                for dx in (-1, 0, 1)
                for dy in (-1, 0, 1)
                for radar, seen in self._seen.get((ix + dx, iy + dy), {}).items()
            )
        return out
