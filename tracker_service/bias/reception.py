"""CAT034 (and CAT002) time stamps beside their reception time: clock evidence per radar.

A radar's service messages (north markers, sector crossings) carry its clock's time of
the beam crossing a boundary (I030) and leave the station a fixed processing time later.
The receiving host's clock (NTP or GNSS-disciplined in an ATC centre; the capture's in a
recording) is the reference: reception - I030 = delay - clock offset, whose slope is the
radar clock's drift (``bias.clock``, ``BiasConfig.reception_clock``). The radar stage keeps
each radar's evidence until its next plot batch carries it to the central stage
(``RadarBatch.clock_evidence``).

Plots are not used: a plot waits in the station until its sector is complete, a delay that
depends on its azimuth within the sector. Stamps further than ``max_offset_s`` (the time
sanity's bound, ``TimeSanityConfig.max_offset_s``) from their reception (a replayed
capture, a radar whose clock is off by hours) are no evidence: such a feed is
``time_sanity``'s business first.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from tracker_service.ingest import posix_from_time_of_day
from tracker_service.time_sanity import TimeSanityConfig
from tracker_service.tracking.plots import FloatArray

SERVICE_KINDS = (1, 2)
"""I000 message types stamped at a boundary: north marker, sector crossing."""


def no_evidence() -> FloatArray:
    """An empty evidence array (0, 2): [radar time s, reception s] per message."""
    return np.zeros((0, 2))


class ReceptionEvidence:
    """Per radar ("SAC/SIC"), the service messages' (radar time, reception time) since the
    radar's last batch; stamps beyond ``max_offset_s`` of their reception are dropped."""

    def __init__(self, max_offset_s: float = TimeSanityConfig.max_offset_s) -> None:
        self.max_offset_s = max_offset_s
        self._pending: dict[str, list[tuple[float, float]]] = {}

    def service_message(self, items: dict[str, Any], received: float) -> None:
        """A decoded CAT034/CAT002 record received at ``received`` (POSIX s)."""
        source, kind, tod = items.get("010"), items.get("000"), items.get("030")
        if kind not in SERVICE_KINDS or not isinstance(source, dict) or not isinstance(tod, float):
            return
        stamp = float(posix_from_time_of_day(np.array([tod]), received)[0])
        if abs(stamp - received) <= self.max_offset_s:
            key = f"{source['SAC']}/{source['SIC']}"
            self._pending.setdefault(key, []).append((stamp, received))

    def take(self, source: str) -> FloatArray:
        """The radar's evidence since the last call (rows [radar time, reception])."""
        pending = self._pending.pop(source, None)
        return np.array(pending, dtype=np.float64) if pending else no_evidence()
