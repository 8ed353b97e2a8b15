"""How busy a process's loop is, for the status: its headroom.

A process's share of a core (its CPU time) does not say how close its loop is to falling
behind on a host whose cores other processes share: a loop that waits for a core is no
less late for it. What does is the share of the wall clock the loop spends not waiting
for work (in its ``Arrivals.wait_until``, or the output process's poll of its pipe): at
1.0 it takes each item as soon as it is done with the previous one, and a burst or a
slower host second puts it behind. Measured at ``artas`` on two cores, the fusion
process's latency tail came in the seconds its loop was busy more than 0.8 of the time
(docs/benchmarks.md, "Session 24").

Each process counts its own (``LoopLoad``: cumulative seconds, so that a reader takes
the share over its own interval, and a lost heartbeat loses nothing); the status shows
each process's share since the last status (``LoadShares``).
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

__all__ = ["LoadShares", "LoopLoad", "LoopTotals"]


@dataclass(frozen=True)
class LoopTotals:
    """A loop's seconds of wall clock since it started, and those it was busy (not
    waiting for work)."""

    elapsed_s: float
    busy_s: float


class LoopLoad:
    """One loop's busy time: everything but its waits (``waited``)."""

    def __init__(self, clock: Callable[[], float] = time.monotonic) -> None:
        self._clock = clock
        self._start = clock()
        self._waited = 0.0

    def waited(self, seconds: float) -> None:
        """The loop waited this long for work."""
        self._waited += seconds

    def totals(self) -> LoopTotals:
        elapsed = self._clock() - self._start
        return LoopTotals(elapsed, max(elapsed - self._waited, 0.0))


class LoadShares:
    """Each loop's busy share of the wall clock between two readings of its totals (the
    status's ``busy``); a loop whose totals did not move since (a radar process whose
    heartbeats were lost) has none until they do, nor one that started again (its
    totals from zero) until its second reading."""

    def __init__(self) -> None:
        self._last: dict[str, LoopTotals] = {}

    def shares(self, totals: Mapping[str, LoopTotals]) -> dict[str, float]:
        out: dict[str, float] = {}
        for role, now in totals.items():
            before = self._last.get(role)
            if before is not None and now.elapsed_s == before.elapsed_s:
                continue  # nothing new from it
            self._last[role] = now
            if before is None or now.elapsed_s < before.elapsed_s:
                continue  # its first totals, or a restarted process's
            share = (now.busy_s - before.busy_s) / (now.elapsed_s - before.elapsed_s)
            out[role] = round(min(max(share, 0.0), 1.0), 3)
        return out
