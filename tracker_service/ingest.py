"""From captured or received datagrams to records: redundant-LAN duplicates and time.

Radar feeds send every datagram on two LANs; the copy is recognised by its content within
a short window. A capture without times (raw, hex) uses a window counted in datagrams.
"""

from __future__ import annotations

import hashlib
from collections import OrderedDict
from dataclasses import dataclass

_MAX_REMEMBERED = 100_000


@dataclass(frozen=True, slots=True)
class DuplicateWindow:
    seconds: float = 1.0
    datagrams: int = 64


class DuplicateFilter:
    """Says whether a payload repeats one seen within the window."""

    def __init__(self, window: DuplicateWindow | None = None) -> None:
        self.window = window or DuplicateWindow()
        self._seen: OrderedDict[bytes, tuple[int, float | None]] = OrderedDict()
        self._count = 0
        self.duplicates = 0

    def is_duplicate(self, payload: bytes, time: float | None) -> bool:
        self._count += 1
        key = hashlib.blake2b(payload, digest_size=16).digest()
        self._expire(time)
        previous = self._seen.get(key)
        if previous is not None:
            self.duplicates += 1
            return True
        self._seen[key] = (self._count, time)
        return False

    def _expire(self, time: float | None) -> None:
        while self._seen:
            count, seen_at = next(iter(self._seen.values()))
            if time is not None and seen_at is not None:
                # Either way: a copy may be stamped a little before the original, and a
                # jump back (midnight, a new capture) must end the window too.
                expired = abs(time - seen_at) > self.window.seconds
            else:
                expired = self._count - count >= self.window.datagrams
            # A bound on memory whatever the times say (a clock that stands still).
            if not expired and len(self._seen) < _MAX_REMEMBERED:
                return
            self._seen.popitem(last=False)
