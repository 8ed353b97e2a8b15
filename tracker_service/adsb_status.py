"""What the status counts of an ADS-B feed: its CAT021 reports and their latest time.

A radar's counters come from its plots in the chain; an ADS-B ground station sends no
plots, so its reports are counted from the datagram's decoding, the one the central stage
takes (``Chain.decode_adsb``): every CAT021 record, and the latest of their times of
applicability (I071, else I073 reception of position), put on the day nearest the
reception time (``AdsbReports.latest``). ``plots_per_second`` of an ADS-B feed in the
status is then its report rate, and ``last_plot_time``, ``plot_delay_s`` its latest
report's. The core hands the count to the outputs with the datagram: a plain message,
which crosses to an output process as the datagram does.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from tracker_service.adsb import AdsbReports

__all__ = ["AdsbCount", "adsb_count"]


@dataclass(frozen=True)
class AdsbCount:
    """A datagram's CAT021 records, and the latest time among them (POSIX s, None
    without one)."""

    records: int
    latest: float | None


def adsb_count(reports: Sequence[AdsbReports]) -> AdsbCount | None:
    """The count of a datagram's decoded CAT021 blocks; None when it has none."""
    if not reports:
        return None
    times = [r.latest for r in reports if r.latest is not None]
    return AdsbCount(sum(r.records for r in reports), max(times) if times else None)
