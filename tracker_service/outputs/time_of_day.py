"""ASTERIX time of day: seconds since UTC midnight at the 1/128 s LSB of I030/I070."""

from __future__ import annotations

__all__ = ["SECONDS_PER_DAY", "TIME_LSB", "time_of_day"]

SECONDS_PER_DAY = 86_400
TIME_LSB = 1.0 / 128.0


def time_of_day(posix: float) -> float:
    """``posix`` as a time of day rounded to the LSB, 0 again at midnight (a value that
    rounds up to 86,400 s would overflow the item)."""
    return (round(posix / TIME_LSB) % (SECONDS_PER_DAY * 128)) * TIME_LSB
