"""The service's outputs behind one protocol, each isolated from the others.

A ``Sink`` carries messages already made (``mapping.py``) to one place: Zenoh
(``zenoh_sink.py``), the MCAP log (``mcap_sink.py``). ``IsolatedSink`` wraps one so that
its failure (a full disk, a closed session, a bug) stops only that output: the failing
call is counted as a dropped message, the output is marked failing with the reason and
the data time it began, its calls are dropped (and counted) until a retry falls due, and
the retries back off from 1 s to 30 s of wall clock. The first call after the backoff is
the retry: it either goes through (the output has recovered) or fails again. Only a call
that carries a message to the output counts as the retry: an empty batch is not made, and
a datagram is not offered to an output that does not keep them while it fails (its
``datagram`` may do nothing and so cannot fail). Each output's
``OutputState`` is plain data for the status message and the health.

Each output also runs on a thread of its own (``QueuedSink``) behind a bounded queue, so
that one that is slow or hangs (a stalled disk, a Zenoh put blocked by congestion) holds
up none of the others: what does not fit in its queue is dropped and counted, and the
status says so while the queue is full.

An output that holds a picture (Zenoh: subscribers and the queryable show each track's
latest state) gets, once it works again, the latest message of every system track whose
updates it missed, the "ended" ones included, so that no track it missed the end of stays
on a display. A log records what happened instead, gap included.
"""

from __future__ import annotations

import contextlib
import errno
import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from asterix.containers import Datagram
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
    iso_time,
)
from tracker_service.outputs.updates import LocalUpdate, SystemUpdate
from tracker_service.ratelimit import RateLimitedLog

__all__ = [
    "Backoff",
    "BatchSink",
    "IsolatedSink",
    "OutputState",
    "QueuedSink",
    "Sink",
    "describe_failure",
]

log = logging.getLogger(__name__)


class Sink(Protocol):
    """One output. ``time`` is the data time of the call (the log time in a file)."""

    name: str
    resends_tracks: bool
    """After an outage, it is sent the latest message of each system track it missed."""
    keeps_datagrams: bool
    """Whether ``datagram`` writes the datagram (a log). For the others it is at most a
    clock tick that may do nothing, so its success proves no recovery from an outage."""

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        """A datagram as an input received it (only a log keeps these)."""

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        """A system-track update; ``payload`` is ``message`` as JSON, serialised once for
        every output. The last message of a track has status "ended"."""

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None: ...

    def asterix(self, data: bytes, time: float) -> None:
        """A CAT062/CAT065 batch (ASTERIX data blocks)."""

    def bias(self, message: BiasMessage, time: float) -> None: ...

    def status(self, message: StatusMessage, time: float) -> None: ...

    def close(self) -> None: ...


class BatchSink(Sink, Protocol):
    """A ``Sink`` that also takes a batch's updates in one call (``updates.py``): the
    service's path. ``IsolatedSink`` gives a sink without these methods each update as a
    message, one call each."""

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None: ...

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None: ...


_REASONS = {
    errno.ENOSPC: "disk full",
    errno.EDQUOT: "disk quota exceeded",
    errno.EROFS: "read-only file system",
    errno.EIO: "I/O error",
}


def describe_failure(exc: BaseException) -> str:
    """What an operator reads in the status: "disk full", or the error in one line."""
    if isinstance(exc, OSError) and exc.errno is not None:
        return _REASONS.get(exc.errno) or exc.strerror or str(exc)
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {text[0]}" if text else type(exc).__name__


@dataclass
class Backoff:
    """Seconds between retries of a failing output: ``first``, doubled at each failed
    retry, at most ``longest``."""

    first: float = 1.0
    longest: float = 30.0

    def delay(self, failures: int) -> float:
        return min(self.first * 2.0 ** max(failures - 1, 0), self.longest)


@dataclass
class OutputState:
    """One output's state, as plain data."""

    name: str
    delivered: int = 0
    """Calls that went through since start."""
    dropped: int = 0
    """Messages not delivered since start: the failing calls and those skipped while the
    output was failing."""
    refused: int = 0
    """Messages the output refused (a value it cannot write), each alone: no outage."""
    outages: int = 0
    failing_since: float | None = None
    """Data time of the first failure of the current outage; None while it works."""
    reason: str = ""
    """Why it fails ("disk full", ...); the last reason once it works again."""
    failures: int = 0
    """Failed attempts in the current outage (the first call and the retries)."""
    dropped_in_outage: int = 0
    queued: int = 0
    """Messages waiting in its queue (``QueuedSink``), at the last one queued."""
    overflowed: int = 0
    """Messages dropped since start because its queue was full (the output too slow)."""
    full_since: float | None = None
    """Data time since which its queue has been full; None while there is room."""

    @property
    def ok(self) -> bool:
        return self.failing_since is None and self.full_since is None

    def reason_line(self) -> str | None:
        """The status line of a failing output (``StatusMessage.reasons``), else None."""
        if self.failing_since is not None:
            return (
                f"output {self.name}: {self.reason} since {iso_time(self.failing_since)}"
                f" ({self.dropped_in_outage} messages dropped, {self.failures} attempts)"
            )
        if self.full_since is not None:
            return (
                f"output {self.name}: too slow since {iso_time(self.full_since)}, its queue "
                f"full ({self.overflowed} messages dropped since start)"
            )
        return None


class IsolatedSink:
    """A ``Sink`` whose failures stay inside it; see the module docstring."""

    def __init__(
        self,
        sink: Sink,
        backoff: Backoff | None = None,
        clock: Callable[[], float] = time.monotonic,
        limited_log: RateLimitedLog | None = None,
    ) -> None:
        self.sink = sink
        self.name = sink.name
        self.state = OutputState(sink.name)
        self.backoff = backoff or Backoff()
        self._clock = clock
        self._retry_at = 0.0
        self._log = limited_log or RateLimitedLog(log, 60.0, clock)
        self._missed: dict[int, tuple[SystemTrackMessage | SystemUpdate, bytes, float]] = {}
        """Per system track whose updates were dropped, the latest (for resends_tracks);
        at most one per track number."""

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        if self.state.failing_since is not None and not self.sink.keeps_datagrams:
            return
        self._run(datagram.time, self.sink.datagram, input_name, datagram)

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        if self._run(time, self.sink.system, message, payload, time):
            self._missed.pop(message.number, None)
        elif self.sink.resends_tracks and self.state.failing_since is not None:
            # Dropped by the outage (a message refused for itself is not sent again).
            self._missed[message.number] = (message, payload, time)
        self._resend()

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self._run(time, self.sink.local, message, payload, time)
        self._resend()

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None:
        """A batch's system-track updates in one call of the sink (one failure, counted
        as that many messages dropped), or one ``system`` call each for a sink that takes
        no batches."""
        if not updates:
            return
        batch = getattr(self.sink, "system_updates", None)
        if batch is None:
            for update in updates:
                self.system(update.message(), update.payload, time)
            return
        if self._run(time, batch, updates, time, messages=len(updates)):
            if self._missed:
                for update in updates:
                    self._missed.pop(update.number, None)
        elif self.sink.resends_tracks and self.state.failing_since is not None:
            for update in updates:
                self._missed[update.number] = (update, update.payload, time)
        self._resend()

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None:
        """As :meth:`system_updates`, for one radar's local-track updates."""
        if not updates:
            return
        batch = getattr(self.sink, "local_updates", None)
        if batch is None:
            for update in updates:
                self.local(update.message(), update.payload, time)
            return
        self._run(time, batch, radar, updates, time, messages=len(updates))
        self._resend()

    def asterix(self, data: bytes, time: float) -> None:
        self._run(time, self.sink.asterix, data, time)
        self._resend()

    def bias(self, message: BiasMessage, time: float) -> None:
        self._run(time, self.sink.bias, message, time)
        self._resend()

    def status(self, message: StatusMessage, time: float) -> None:
        self._run(time, self.sink.status, message, time)
        self._resend()

    def close(self) -> None:
        try:
            self.sink.close()
        except Exception as exc:
            log.error("output %s: closing failed: %s", self.name, describe_failure(exc))

    def _resend(self) -> None:
        """Once the output works again, what it missed of each track, in number order."""
        if not self._missed or self.state.failing_since is not None:
            return
        batch = getattr(self.sink, "system_updates", None)
        for number in sorted(self._missed):
            message, payload, time = self._missed.pop(number)
            if isinstance(message, SystemUpdate):
                if batch is not None:
                    delivered = self._run(time, batch, [message], time)
                else:
                    delivered = self._run(time, self.sink.system, message.message(), payload, time)
            else:
                delivered = self._run(time, self.sink.system, message, payload, time)
            if not delivered and self.state.failing_since is not None:
                # Down again: this one and the rest wait for the next recovery.
                self._missed[number] = (message, payload, time)
                return

    def _run(
        self, time: float, call: Callable[..., None], *args: object, messages: int = 1
    ) -> bool:
        """Whether the call (of ``messages`` messages) went through."""
        state = self.state
        if state.failing_since is not None and self._clock() < self._retry_at:
            state.dropped += messages
            state.dropped_in_outage += messages
            return False
        try:
            call(*args)
        except (ValueError, TypeError) as exc:
            # The message, not the output: this one is refused, the next goes through.
            state.dropped += messages
            state.refused += messages
            self._log.error(
                f"{self.name} refused",
                "output %s: a %s message refused (%s); %d refused since start",
                self.name,
                getattr(call, "__name__", "?"),
                describe_failure(exc),
                state.refused,
            )
            return False
        except Exception as exc:
            self._failed(time, exc, messages)
            return False
        if state.failing_since is not None:
            log.warning(
                "output %s: working again after %s; %d messages dropped",
                self.name,
                state.reason,
                state.dropped_in_outage,
            )
            state.failing_since = None
            state.failures = 0
            state.dropped_in_outage = 0
        state.delivered += 1
        return True

    def _failed(self, time: float, exc: Exception, messages: int = 1) -> None:
        state = self.state
        state.dropped += messages
        state.dropped_in_outage += messages
        state.failures += 1
        state.reason = describe_failure(exc)
        delay = self.backoff.delay(state.failures)
        self._retry_at = self._clock() + delay
        expected = isinstance(exc, OSError)
        if state.failing_since is None:
            state.failing_since = time
            state.outages += 1
            # The first failure of an outage: its traceback too when it is not the
            # environment's doing (a full disk) but possibly a bug.
            log.error(
                "output %s: %s; its messages are dropped, the other outputs go on; retry in %.1f s",
                self.name,
                state.reason,
                delay,
                exc_info=None if expected else exc,
            )
            return
        self._log.warning(
            self.name,
            "output %s: still failing (%s) after %d attempts, %d messages dropped; retry in %.1f s",
            self.name,
            state.reason,
            state.failures,
            state.dropped_in_outage,
            delay,
        )


_Call = tuple[Callable[..., None], tuple[object, ...]]


class QueuedSink:
    """An ``IsolatedSink`` on a thread of its own behind a queue of ``capacity`` calls;
    see the module docstring. ``drain`` waits until the queue is empty; ``close`` makes
    the calls queued, then stops the thread (the sink's own ``close`` after them)."""

    def __init__(self, sink: IsolatedSink, capacity: int = 10_000) -> None:
        if capacity < 1:
            raise ValueError(f"capacity {capacity} must be at least 1")
        self.sink = sink
        self.name = sink.name
        self.state = sink.state
        self.capacity = capacity
        self._queue: queue.Queue[_Call | None] = queue.Queue(capacity)
        self._log = RateLimitedLog(log, 60.0)
        self._closed = False
        self._thread = threading.Thread(target=self._work, name=f"output-{self.name}", daemon=True)
        self._thread.start()

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        self._put(datagram.time, self.sink.datagram, (input_name, datagram))

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self._put(time, self.sink.system, (message, payload, time))

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self._put(time, self.sink.local, (message, payload, time))

    def system_updates(self, updates: Sequence[SystemUpdate], time: float) -> None:
        """A batch in one queued call: one queue operation for the batch."""
        self._put(time, self.sink.system_updates, (updates, time), len(updates))

    def local_updates(self, radar: str, updates: Sequence[LocalUpdate], time: float) -> None:
        self._put(time, self.sink.local_updates, (radar, updates, time), len(updates))

    def asterix(self, data: bytes, time: float) -> None:
        self._put(time, self.sink.asterix, (data, time))

    def bias(self, message: BiasMessage, time: float) -> None:
        self._put(time, self.sink.bias, (message, time))

    def status(self, message: StatusMessage, time: float) -> None:
        self._put(time, self.sink.status, (message, time))

    def drain(self, timeout: float = 10.0) -> bool:
        """Waits until every queued call is made (at most ``timeout`` s); whether it was."""
        deadline = time.monotonic() + timeout
        while self._queue.unfinished_tasks:
            if time.monotonic() > deadline:
                return False
            time.sleep(0.001)
        return True

    def close(self, timeout: float = 10.0) -> None:
        if self._closed:
            return
        self._closed = True
        with contextlib.suppress(queue.Full):
            self._queue.put(None, timeout=timeout)
        self._thread.join(timeout)
        if self._thread.is_alive():
            log.error(
                "output %s: still busy after %.0f s; %d calls not made",
                self.name,
                timeout,
                self._queue.qsize(),
            )
            return
        self.sink.close()

    def _put(
        self,
        time: float,
        call: Callable[..., None],
        args: tuple[object, ...],
        messages: int = 1,
    ) -> None:
        state = self.state
        if self._closed:
            raise ValueError(f"output {self.name} is closed")
        try:
            self._queue.put_nowait((call, args))
        except queue.Full:
            state.overflowed += messages
            state.dropped += messages
            if state.full_since is None:
                state.full_since = time
            self._log.warning(
                self.name,
                "output %s: too slow, its queue of %d is full; %d messages dropped since start",
                self.name,
                self.capacity,
                state.overflowed,
            )
            return
        state.queued = self._queue.qsize()
        if state.full_since is not None and state.queued <= self.capacity // 2:
            state.full_since = None

    def _work(self) -> None:
        while True:
            item = self._queue.get()
            try:
                if item is None:
                    return
                call, args = item
                # IsolatedSink's calls raise nothing (they count and report instead).
                call(*args)
            finally:
                self._queue.task_done()
