"""What the status counts of an ADS-B feed: its CAT021 reports and their latest time.

A radar's counters come from its plots in the chain; an ADS-B ground station sends no
plots, so its reports are counted here from the datagram itself: every CAT021 record,
and the latest of its times of applicability (I071, else I073 reception of position),
put on the day nearest the reception time. ``plots_per_second`` of an ADS-B feed in the
status is then its report rate, and ``last_plot_time``, ``plot_delay_s`` its latest
report's.
"""

from __future__ import annotations

from asterix.codec import Block, decode_blocks
from tracker_service.ingest import DAY_S

__all__ = ["adsb_reports"]

CAT021 = 21


def _on_day_of(time_of_day: float, received: float) -> float:
    """The POSIX time nearest ``received`` whose time of day is ``time_of_day``."""
    shift = (time_of_day - received % DAY_S + DAY_S / 2) % DAY_S - DAY_S / 2
    return received + shift


def adsb_reports(payload: bytes, received: float) -> tuple[int, float | None]:
    """(CAT021 records of the datagram, the latest time among them as POSIX s or None)."""
    count = 0
    latest: float | None = None
    pos = 0
    while pos + 3 <= len(payload):
        size = max(int.from_bytes(payload[pos + 1 : pos + 3]), 3)
        if payload[pos] == CAT021:
            for event in decode_blocks(payload[pos : pos + size]):
                if not isinstance(event, Block):
                    continue
                for record in event.records:
                    count += 1
                    tod = record.get("071", record.get("073"))
                    if isinstance(tod, float | int):
                        t = _on_day_of(float(tod), received)
                        latest = t if latest is None else max(latest, t)
        pos += size
    return count, latest
