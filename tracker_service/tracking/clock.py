"""A data clock that no single time stamp can move.

The local tracker, its initiator and the fuser all need "now": the time up to which the
data has come, from which missed scans, silences and pairing windows are counted. Taken
as the latest time ever seen, one corrupt stamp two hours ahead ends every track and
makes every later plot "late"; a radar that restarts with its clock an hour slow is then
never heard again. ``DataClock`` moves only with batches that agree with it: a batch
whose times lie beyond ``max_ahead_s`` or ``max_behind_s`` of the clock is held back
(out of line), and only ``resync_batches`` out-of-line batches in a row, each jumping the
same way by about as much and together spanning ``resync_span_s`` of their own time,
re-synchronise the clock to them (a burst of old datagrams replayed is no restart). Any
batch in line ends such a run, so a single stamp, or one radar among several in step,
can never move it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba

__all__ = ["ClockStep", "DataClock"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class ClockStep:
    """What one batch did to the clock: which of its times it accepts, whether the batch
    as a whole was out of line (one more piece of evidence of a jump, held back), and the
    jump (new now - old now) when it re-synchronised the clock (0.0 otherwise)."""

    accepted: BoolArray
    out_of_line: int = 0
    """0 for a batch in line, else its place (1, 2, ...) in the run of batches that
    jump alike (1: a new run, the earlier ones were no jump)."""
    jump_s: float = 0.0

    @property
    def resynchronised(self) -> bool:
        return self.jump_s != 0.0


@dataclass
class DataClock:
    """See the module docstring. ``now`` is -inf until the first batch."""

    max_ahead_s: float
    max_behind_s: float
    resync_batches: int = 3
    resync_span_s: float = 0.0
    now: float = -math.inf
    resyncs: int = 0
    """Times the clock was re-synchronised to a jumped stream."""
    _run: int = field(default=0, repr=False)
    _run_jump: float = field(default=math.nan, repr=False)
    _run_start: float = field(default=math.nan, repr=False)

    def __post_init__(self) -> None:
        if not (self.max_ahead_s > 0 and self.max_behind_s > 0 and self.resync_batches >= 1):
            raise ValueError("max_ahead_s, max_behind_s and resync_batches must be positive")

    def step(self, times: FloatArray) -> ClockStep:
        """Judge one batch's (finite) times; the clock moves to the latest accepted one."""
        times = np.asarray(times, dtype=np.float64)
        if times.size == 0:
            return ClockStep(np.zeros(0, dtype=bool))
        # A time of the batch (the upper middle one), never the mean of two that
        # disagree; the times within reach of the clock (of that one for the first
        # batch: its own median is all the evidence there is), and the latest of them.
        centre, accepted, latest = _judge(times, self.now, self.max_ahead_s, self.max_behind_s)
        if not math.isfinite(self.now):
            self.now = latest
            return ClockStep(accepted)
        jump = centre - self.now
        if -self.max_behind_s <= jump <= self.max_ahead_s:
            self._run = 0
            self.now = max(self.now, latest)
            return ClockStep(accepted)
        # Most of the batch is out of line: evidence of a jump if the previous batches
        # jumped the same way by about as much.
        tolerance = max(self.max_ahead_s, self.max_behind_s)
        if self._run and abs(jump - self._run_jump) <= tolerance:
            self._run += 1
        else:
            self._run = 1
            self._run_start = centre
        self._run_jump = jump
        if self._run < self.resync_batches or centre - self._run_start < self.resync_span_s:
            self.now = max(self.now, latest)
            return ClockStep(accepted, out_of_line=self._run)
        old = self.now
        accepted = self._near(times, centre)
        self.now = float(times[accepted].max())
        self._run = 0
        self.resyncs += 1
        return ClockStep(accepted, jump_s=(self.now - old) or math.ulp(old))

    def _near(self, times: FloatArray, centre: float) -> BoolArray:
        return np.asarray(
            (times <= centre + self.max_ahead_s) & (times >= centre - self.max_behind_s),
            dtype=bool,
        )


@numba.njit(cache=True)
def _judge(
    times: FloatArray, now: float, max_ahead_s: float, max_behind_s: float
) -> tuple[float, BoolArray, float]:  # pragma: no cover - compiled
    """``DataClock.step``'s look at a batch in one pass: its upper middle time (what
    ``np.partition`` puts at n // 2), which times lie within ``max_ahead_s`` and
    ``max_behind_s`` of ``now`` (of that middle time while ``now`` is not finite), and
    the latest of those (-inf without any)."""
    centre = np.sort(times)[times.size // 2]
    around = now if math.isfinite(now) else centre
    ahead = around + max_ahead_s
    behind = around - max_behind_s
    accepted = np.empty(times.size, np.bool_)
    latest = -np.inf
    for k in range(times.size):
        accepted[k] = times[k] <= ahead and times[k] >= behind
        if accepted[k]:
            latest = max(latest, times[k])
    return centre, accepted, latest
