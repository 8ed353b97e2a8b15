"""From captured or received datagrams to records: redundant-LAN duplicates and time.

Radar feeds send every datagram on two LANs; the copy is recognised by its content within
a short window. A capture without times (raw, hex) uses a window counted in datagrams.
Plots carry a time of day (CAT048 I140), a time of day modulo 512 s (CAT001 I141) or none:
``PlotClock`` turns each into a POSIX time of measurement and says where it came from.
"""

from __future__ import annotations

import hashlib
import math
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
    """No time item and no north marker (CAT034 or CAT002) yet: the datagram's reception
    time (late by the sector's buffering and the network)."""
    I141_SERVICE = 3
    """CAT001 I141 (the time of day modulo 512 s) unrolled on the radar's own time: its
    last north marker or sector message (CAT002 I030), advanced by the reception time
    since."""
    I141_RECEPTION = 4
    """CAT001 I141 unrolled on the reception time: no recent service message of the radar
    (exact unless the radar's clock and ours are more than 256 s apart)."""


TRUNCATED_PERIOD_S = 512.0
"""CAT001 I141 is the low 16 bits of the time of day in 1/128 s."""
MIN_PERIOD_S, MAX_PERIOD_S = 0.5, 20.0
"""Antenna periods of surveillance radars (1 s for some surface radars, 12 s en route)
with room: between two north markers outside it, one was lost or the clock jumped."""
SERVICE_REFERENCE_S = 64.0
"""How long a radar's last service message serves to unroll its I141: over a few turns,
the radar's clock and the reception's drift apart by no more than the network's jitter."""


def posix_from_time_of_day(
    time_of_day: npt.NDArray[np.float64], reference_posix: float
) -> npt.NDArray[np.float64]:
    """POSIX times of times of day, each on the day that puts it nearest the reference
    (the reception time): a plot stamped 23:59:59.9 and received at 00:00:00.2 belongs
    to the day before."""
    day = np.floor(reference_posix / DAY_S) * DAY_S
    posix = day + np.asarray(time_of_day, dtype=np.float64)
    return np.asarray(posix - DAY_S * np.round((posix - reference_posix) / DAY_S))


def unroll_truncated_time(
    truncated: npt.NDArray[np.float64], reference_posix: float
) -> npt.NDArray[np.float64]:
    """POSIX times of times of day known modulo 512 s (CAT001 I141): each the time of day
    of that residue nearest the reference, on its day or the one before or after. The time
    of day restarts at midnight, so the day's last 384 s carry residues 0-384 s only."""
    truncated = np.asarray(truncated, dtype=np.float64)
    day = np.floor(reference_posix / DAY_S) * DAY_S
    of_day = reference_posix - day
    best = np.full(truncated.shape, np.nan)
    best_gap = np.full(truncated.shape, np.inf)
    for day_shift in (-DAY_S, 0.0, DAY_S):
        reference = of_day - day_shift  # the reference counted on the candidate day
        below = reference - np.mod(reference - truncated, TRUNCATED_PERIOD_S)
        for candidate in (below, below + TRUNCATED_PERIOD_S):
            gap = np.abs(candidate - reference)
            better = (candidate >= 0.0) & (candidate < DAY_S) & (gap < best_gap)
            best = np.where(better, day + day_shift + candidate, best)
            best_gap = np.where(better, gap, best_gap)
    return best


@dataclass
class _Antenna:
    north_posix: float
    period_s: float


@dataclass
class _RadarTime:
    """A radar's own time (its last service message's I030) and when it was received."""

    posix: float
    received: float


class PlotClock:
    """Gives every CAT048 and CAT001 plot a POSIX time of measurement, per radar (SAC/SIC).

    Keeps each radar's last north marker (CAT034 or CAT002 I000 = 1, its I030 and I041) to
    time the plots that come without I140, from their azimuth, and its last north marker
    or sector message (I000 = 1 or 2) to unroll CAT001's truncated I141; says for each
    plot where its time came from (``TimeSource``).
    """

    def __init__(self) -> None:
        self._antennas: dict[tuple[int, int], _Antenna] = {}
        self._radar_times: dict[tuple[int, int], _RadarTime] = {}

    def service_message(self, items: dict[str, Any], reception_posix: float) -> None:
        """Take note of a CAT034 or CAT002 record (the two name their items alike: I000
        message type, I010 source, I030 time of day, I041 antenna period)."""
        source, kind, tod = items.get("010"), items.get("000"), items.get("030")
        if kind not in (1, 2) or not isinstance(source, dict) or not isinstance(tod, float):
            return
        key = (source["SAC"], source["SIC"])
        posix = float(posix_from_time_of_day(np.array([tod]), reception_posix)[0])
        self._radar_times[key] = _RadarTime(posix, reception_posix)
        if kind != 1:
            return
        period = items.get("041")
        known = self._antennas.get(key)
        if not isinstance(period, float) or period <= 0.0:
            if known is None:
                # Without I041 (many CAT002 radars), the next north marker gives the period.
                self._antennas[key] = _Antenna(posix, math.nan)
                return
            # A lost north marker makes one turn look twice as long: shorter ones win.
            turn = posix - known.north_posix
            plausible = MIN_PERIOD_S <= turn <= MAX_PERIOD_S
            longer = math.isfinite(known.period_s) and turn > 1.5 * known.period_s
            period = turn if plausible and not longer else known.period_s
        self._antennas[key] = _Antenna(posix, period)

    def antenna_period(self, sac: int, sic: int) -> float | None:
        """The radar's antenna period (I041, or between its last north markers)."""
        known = self._antennas.get((sac, sic))
        return None if known is None or not math.isfinite(known.period_s) else known.period_s

    def _unroll(
        self, plots: npt.NDArray[Any], rows: npt.NDArray[np.intp], reception_posix: float
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
        """Times and sources of the plots ``rows`` that carry a truncated I141 only."""
        times = np.empty(len(rows))
        sources = np.empty(len(rows), dtype=np.int8)
        keys = plots["sac"][rows].astype(np.int64) * 256 + plots["sic"][rows]
        for key in np.unique(keys).tolist():
            mine = keys == key
            known = self._radar_times.get((key >> 8, key & 255))
            if known is not None and 0.0 <= reception_posix - known.received < SERVICE_REFERENCE_S:
                reference = known.posix + (reception_posix - known.received)
                sources[mine] = TimeSource.I141_SERVICE
            else:
                reference = reception_posix
                sources[mine] = TimeSource.I141_RECEPTION
            times[mine] = unroll_truncated_time(plots["truncated_time"][rows[mine]], reference)
        return times, sources

    def times(
        self, plots: npt.NDArray[Any], reception_posix: float
    ) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.int8]]:
        """(POSIX time, TimeSource) of each plot of one datagram."""
        times = np.full(len(plots), reception_posix)
        sources = np.full(len(plots), TimeSource.RECEPTION, dtype=np.int8)
        stamped = np.isfinite(plots["time_of_day"])
        times[stamped] = posix_from_time_of_day(plots["time_of_day"][stamped], reception_posix)
        sources[stamped] = TimeSource.I140
        truncated = ~stamped & np.isfinite(plots["truncated_time"])
        if truncated.any():
            rows = np.flatnonzero(truncated)
            times[rows], sources[rows] = self._unroll(plots, rows, reception_posix)
            stamped |= truncated
        for row in np.flatnonzero(~stamped):
            antenna = self._antennas.get((int(plots["sac"][row]), int(plots["sic"][row])))
            theta = plots["theta"][row]
            if antenna is None or not np.isfinite(theta) or not math.isfinite(antenna.period_s):
                continue
            # Clockwise rotation, as nearly every ATC radar turns; the plot was seen in the
            # last turn that ends before the datagram arrived.
            when = antenna.north_posix + theta / 360.0 * antenna.period_s
            turns = np.floor((reception_posix - when) / antenna.period_s)
            times[row] = when + turns * antenna.period_s
            sources[row] = TimeSource.AZIMUTH
        return times, sources
