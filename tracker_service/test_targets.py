"""A radar's test-target check for status: its I020 TST = 1 plots, as last seen.

Radars inject test targets into their own plot stream (a primary one at a fixed range and
azimuth, an SSR test transponder with code 7776 at FL660, say) to show that detection and
extraction work. The chain keeps them out of traffic tracking (``PlotUse.TEST_TARGET``);
this keeps, per radar, how many were seen and where the latest one was, from the plot
tables the outputs receive, so that it works wherever the outputs run.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from tracker_service.chain import NM, PlotUse
from tracker_service.outputs.messages import RadarTestTarget

__all__ = ["SeenTestTargets"]

PSR_ONLY = 1  # I048/020 TYP
Kind = Literal["primary", "secondary"]


@dataclass
class _Latest:
    seen: int
    time: float
    range_nm: float
    azimuth_deg: float
    flight_level: float | None


class SeenTestTargets:
    """One radar's test targets, one per kind (primary, secondary) and Mode 3/A code."""

    def __init__(self) -> None:
        self._latest: dict[tuple[Kind, int], _Latest] = {}

    def update(self, plots: npt.NDArray[Any]) -> None:
        """A plot table (``chain.RAW_PLOT_DTYPE``) of the radar."""
        # ``.value``: numpy compares an IntEnum member through a slow path.
        tests = plots["use"] == PlotUse.TEST_TARGET.value
        if not tests.any():
            return
        rows = plots[tests]
        for row in rows[np.argsort(rows["time"], kind="stable")]:
            kind: Kind = "primary" if int(row["typ"]) == PSR_ONLY else "secondary"
            key = (kind, int(row["mode3a"]))
            previous = self._latest.get(key)
            if previous is not None and previous.time > float(row["time"]):
                previous.seen += 1
                continue
            level = float(row["flight_level"])
            self._latest[key] = _Latest(
                seen=1 if previous is None else previous.seen + 1,
                time=float(row["time"]),
                range_nm=float(row["rho_m"]) / NM,
                azimuth_deg=float(row["theta_deg"]) % 360.0,
                flight_level=level if math.isfinite(level) else None,
            )

    def checks(self) -> list[RadarTestTarget]:
        return [
            RadarTestTarget(
                kind=kind,
                mode3a=f"{code:04o}" if code >= 0 else None,
                seen=latest.seen,
                last_time=latest.time,
                range_nm=latest.range_nm,
                azimuth_deg=latest.azimuth_deg,
                flight_level=latest.flight_level,
            )
            for (kind, code), latest in sorted(self._latest.items())
        ]
