"""Log lines that a flood of bad input cannot multiply: one line per kind of event per
interval, the next one saying how many were suppressed meanwhile.

A hostile or broken feed can send thousands of bad datagrams a second; one warning each
(15 MB of log in 10 s, seen) fills the disk and buries what matters. The counters in
``status`` say how many; the log says what, by example.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

__all__ = ["RateLimitedLog"]

MAX_KINDS = 256
"""Kinds remembered at most (a kind is a short fixed text, but a caller's bug must not
make this a leak): the oldest is forgotten first."""


class RateLimitedLog:
    """``warning(kind, message, *args)``: logged at most once per ``interval_s`` for each
    ``kind``; the first line after a quiet spell carries the count suppressed before it."""

    def __init__(
        self,
        logger: logging.Logger,
        interval_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.logger = logger
        self.interval_s = interval_s
        self._clock = clock
        self._next: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}

    def warning(self, kind: str, message: str, *args: object) -> None:
        self.log(logging.WARNING, kind, message, *args)

    def error(self, kind: str, message: str, *args: object) -> None:
        self.log(logging.ERROR, kind, message, *args)

    def exception(self, kind: str, message: str, *args: object) -> None:
        """As ``error``, with the traceback of the exception being handled."""
        self.log(logging.ERROR, kind, message, *args, exc_info=True)

    def log(
        self, level: int, kind: str, message: str, *args: object, exc_info: bool = False
    ) -> None:
        now = self._clock()
        if now < self._next.get(kind, -float("inf")):
            self._suppressed[kind] = self._suppressed.get(kind, 0) + 1
            return
        suppressed = self._suppressed.pop(kind, 0)
        self._next.pop(kind, None)
        if len(self._next) >= MAX_KINDS:
            forgotten = next(iter(self._next))
            del self._next[forgotten]
            self._suppressed.pop(forgotten, None)
        self._next[kind] = now + self.interval_s
        if suppressed:
            message += f" ({suppressed} more like it suppressed since the last such line)"
        self.logger.log(level, message, *args, exc_info=exc_info)
