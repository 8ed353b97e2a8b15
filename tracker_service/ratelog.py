"""Log lines that a fault repeating thousands of times a second cannot multiply.

``RateLimitedLog.log(key, level, message, *args)`` writes at most one line per key per
``interval_s`` (wall clock); the lines kept back are counted, and the next line written
for that key says how many there were.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable

__all__ = ["RateLimitedLog"]


class RateLimitedLog:
    def __init__(
        self,
        logger: logging.Logger,
        interval_s: float = 10.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if interval_s <= 0:
            raise ValueError(f"interval_s {interval_s} must be positive")
        self.logger = logger
        self.interval_s = interval_s
        self._clock = clock
        self._last: dict[str, float] = {}
        self.suppressed: dict[str, int] = {}
        """Per key, the lines kept back since the last one written."""

    def log(self, key: str, level: int, message: str, *args: object) -> bool:
        """Writes the line unless one of ``key`` went out less than ``interval_s`` ago;
        returns whether it was written."""
        now = self._clock()
        last = self._last.get(key)
        if last is not None and now - last < self.interval_s:
            self.suppressed[key] = self.suppressed.get(key, 0) + 1
            return False
        self._last[key] = now
        held = self.suppressed.pop(key, 0)
        if held:
            message += " (%d similar lines suppressed in the last %.0f s)"
            args = (*args, held, now - last if last is not None else 0.0)
        self.logger.log(level, message, *args)
        return True
