"""ADS-B cover as coverage: the moments an aircraft is in some ADS-B ground station's
cover, from the recording's truth of the stations' reports (``/truth/plots`` records
of kind "adsb": the simulator's stations hear every equipped aircraft within range and
line of sight, so a report in an interval is the aircraft in cover in it).

``system_by_coverage`` gains "adsb_only" (in ADS-B cover and no radar's) and
"radar_and_adsb" (in both), on the system tracks' own intervals (``system_metrics``).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.metrics import Coverage
from tracker_service.simulator.recording import Recording

__all__ = ["AdsbCover", "adsb_cover_from_recording", "split_by_adsb"]


@dataclass(frozen=True)
class AdsbCover:
    """Every ADS-B report's aircraft and time of applicability (POSIX s)."""

    aircraft: npt.NDArray[np.int64]
    time: npt.NDArray[np.float64]

    def on_grid(self, grid: Coverage) -> Coverage:
        """The aircraft reporting in each interval of ``grid``."""
        index = np.floor((self.time - grid.times[0]) / grid.period_s).astype(np.int64)
        inside = (index >= 0) & (index < len(grid.times))
        sets: list[set[int]] = [set() for _ in grid.times]
        for k, a in zip(index[inside].tolist(), self.aircraft[inside].tolist(), strict=True):
            sets[k].add(a)
        return Coverage(grid.times, [frozenset(s) for s in sets], grid.period_s)


def adsb_cover_from_recording(recording: Recording) -> AdsbCover | None:
    """The recording's ADS-B reports (None: it has no ADS-B station)."""
    stations = set(dict(recording.metadata.get("adsb_stations", {})))
    if not stations or "/truth/plots" not in recording.topics:
        return None
    aircraft: list[int] = []
    times: list[float] = []
    for message in recording.messages("/truth/plots"):
        if str(message["source"]) not in stations:
            continue
        for record in message["records"]:
            if record.get("kind") == "adsb" and record.get("aircraft") is not None:
                aircraft.append(int(record["aircraft"]))
                times.append(float(record["detection_time"]))
    return AdsbCover(np.array(aircraft, dtype=np.int64), np.array(times, dtype=np.float64))


def split_by_adsb(radar: Coverage, adsb: Coverage) -> tuple[Coverage, Coverage]:
    """(ADS-B cover and no radar's, both) on the radar coverage's grid."""

    def of(sets: Sequence[frozenset[int]]) -> Coverage:
        return Coverage(radar.times, sets, radar.period_s)

    pairs = list(zip(adsb.aircraft, radar.aircraft, strict=True))
    return of([a - r for a, r in pairs]), of([a & r for a, r in pairs])
