"""From captured or received datagrams to records: redundant-LAN duplicates and time.

Radar feeds send every datagram on two LANs; the copy is recognised by its content within
a short window. A capture without times (raw, hex) uses a window counted in datagrams.
Plots carry a time of day (I140) or none: ``PlotClock`` turns both into POSIX times of
measurement and says where each came from.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

_MAX_REMEMBERED = 16_384
"""Payloads remembered at most per filter, whatever the window says (a clock that stands
still, a flood of distinct datagrams): about 2 MB. A feed sends tens to hundreds of
datagrams per second, so a one-second window never comes near it."""


@dataclass(frozen=True, slots=True)
class DuplicateWindow:
    seconds: float = 1.0
    datagrams: int = 64


class Repetition(IntEnum):
    """What a payload is to a :class:`DuplicateFilter`."""

    NEW = 0
    COPY = 1
    """Seen within the window on another LAN only: the redundant LAN's copy."""
    REPEAT = 2
    """Seen within the window on the same LAN: the network or the radar sent it twice."""


class DuplicateFilter:
    """Says whether a payload repeats one seen within the window (by content: a 128-bit
    hash, so memory per payload is fixed), and on which LAN it was seen."""

    def __init__(self, window: DuplicateWindow | None = None) -> None:
        self.window = window or DuplicateWindow()
        self._seen: OrderedDict[bytes, tuple[int, float | None, int]] = OrderedDict()
        self._count = 0
        self.duplicates = 0

    def is_duplicate(self, payload: bytes, time: float | None) -> bool:
        return self.classify(payload, time) is not Repetition.NEW

    def classify(self, payload: bytes, time: float | None, lan: int = 0) -> Repetition:
        """NEW, COPY (seen on another LAN only) or REPEAT (seen on ``lan`` already)."""
        self._count += 1
        key = hashlib.blake2b(payload, digest_size=16).digest()
        self._expire(time)
        previous = self._seen.get(key)
        bit = 1 << lan
        if previous is None:
            self._seen[key] = (self._count, time, bit)
            return Repetition.NEW
        self.duplicates += 1
        count, seen_at, lans = previous
        self._seen[key] = (count, seen_at, lans | bit)
        return Repetition.REPEAT if lans & bit else Repetition.COPY

    def _expire(self, time: float | None) -> None:
        while self._seen:
            count, seen_at, _ = next(iter(self._seen.values()))
            if time is not None and seen_at is not None:
                # Either way: a copy may be stamped a little before the original, and a
                # jump back (midnight, a new capture) must end the window too.
                expired = abs(time - seen_at) > self.window.seconds
            else:
                expired = self._count - count >= self.window.datagrams
            if not expired and len(self._seen) < _MAX_REMEMBERED:
                return
            self._seen.popitem(last=False)


# --- plot times ---------------------------------------------------------------------------

DAY_S = 86400.0


class TimeSource(IntEnum):
    """Where a plot's time of measurement comes from."""

    I140 = 0
    """The radar's own time of day."""
    AZIMUTH = 1
    """No I140: the last north marker plus the beam's travel to the plot's azimuth."""
    RECEPTION = 2
    """No I140 and no CAT034 yet: the datagram's reception time (late by the sector's
    buffering and the network)."""


def posix_from_time_of_day(
    time_of_day: npt.NDArray[np.float64], reference_posix: float
) -> npt.NDArray[np.float64]:
    """POSIX times of times of day, each on the day that puts it nearest the reference
    (the reception time): a plot stamped 23:59:59.9 and received at 00:00:00.2 belongs
    to the day before."""
    day = np.floor(reference_posix / DAY_S) * DAY_S
    posix = day + np.asarray(time_of_day, dtype=np.float64)
    return np.asarray(posix - DAY_S * np.round((posix - reference_posix) / DAY_S))


@dataclass
class _Antenna:
    north_posix: float
    period_s: float


class PlotClock:
    """Gives every CAT048 plot a POSIX time of measurement, per radar (SAC/SIC).

    Keeps each radar's last north marker (CAT034 I000 = 1, its I030 and I041) to time the
    plots that come without I140, from their azimuth; says for each plot where its time
    came from (``TimeSource``).
    """

    def __init__(self) -> None:
        self._antennas: dict[tuple[int, int], _Antenna] = {}

    def service_message(self, items: dict[str, Any], reception_posix: float) -> None:
        """Take note of a CAT034 record (north markers carry the antenna period)."""
        source, kind, tod = items.get("010"), items.get("000"), items.get("030")
        if kind != 1 or not isinstance(source, dict) or not isinstance(tod, float):
            return
        key = (source["SAC"], source["SIC"])
        period = items.get("041")
        if not isinstance(period, float) or period <= 0.0:
            known = self._antennas.get(key)
            if known is None:
                return
            period = known.period_s
        north = float(posix_from_time_of_day(np.array([tod]), reception_posix)[0])
        self._antennas[key] = _Antenna(north, period)

    def times(
        self, plots: npt.NDArray[Any], reception_posix: float
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
        """(POSIX time, TimeSource) of each plot of one datagram."""
        times = np.full(len(plots), reception_posix)
        sources = np.full(len(plots), TimeSource.RECEPTION, dtype=np.int8)
        stamped = np.isfinite(plots["time_of_day"])
        times[stamped] = posix_from_time_of_day(plots["time_of_day"][stamped], reception_posix)
        sources[stamped] = TimeSource.I140
        for row in np.flatnonzero(~stamped):
            antenna = self._antennas.get((int(plots["sac"][row]), int(plots["sic"][row])))
            theta = plots["theta"][row]
            if antenna is None or not np.isfinite(theta):
                continue
            # Clockwise rotation, as nearly every ATC radar turns; the plot was seen in the
            # last turn that ends before the datagram arrived.
            when = antenna.north_posix + theta / 360.0 * antenna.period_s
            turns = np.floor((reception_posix - when) / antenna.period_s)
            times[row] = when + turns * antenna.period_s
            sources[row] = TimeSource.AZIMUTH
        return times, sources
