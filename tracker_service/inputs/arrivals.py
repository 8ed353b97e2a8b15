"""One wake-up for a loop fed by several inputs: which of them have something to take.

The live loops (the daemon, the radar and fusion processes) used to ask every input in
turn whether it had a datagram and sleep a millisecond when none had: about 7 % of a
core per idle process, and under load tens of thousands of empty ``queue.get`` a second
over 48 inputs. Instead each input, once it has queued something, names itself here
(``notify``), and the loop waits on ``wait`` with a timeout that runs to its next duty,
then ``take``s the names and takes from those inputs only.

No wake-up is lost: a producer queues its item, then adds its name and sets the event
(both after the item is queued); the consumer clears the event, then swaps the set of
names out, then takes from those inputs. A name added before the swap is in what the
consumer takes, and its item, queued before the name was added, is there to take. A name
added after the swap is in the next set, and its event is set after the consumer's
clear (clear comes before swap, swap before that add, the add before that set): the
next ``wait`` returns at once. The cost is at most a spurious wake-up, whose inputs turn
out empty. A producer whose name is already in the set does not set the event again:
the producer that added the name sets it after its add, which came after the last swap,
so after the last clear; until the consumer swaps that name out, its event is set or
about to be, and the item of the second producer, queued before it looked, is taken
with the name.

Waiting on a ``threading.Event`` in the main thread is safe with the service's signal
handling (``service.signals``): a Python signal handler may run inside ``Event.wait``,
while the thread holds the event's internal lock, and ``StopSignal.handler`` only stores
two attributes, taking no lock, so it cannot wait for one its own thread holds. The
handler's flag is then seen when the wait returns, which the loops bound (``WAIT_CAP_S``).
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable

__all__ = ["WAIT_CAP_S", "Arrivals"]

WAIT_CAP_S = 0.05
"""The longest a live loop waits for data: how late it may see a stop request (a signal
sets a flag without waking the event)."""


class Arrivals:
    """The names of the inputs that have queued something since the consumer last took
    them, and an event set when a name is added (see the module docstring)."""

    def __init__(self, waited: Callable[[float], None] | None = None) -> None:
        self._lock = threading.Lock()
        self._ready: set[str] = set()
        self._event = threading.Event()
        self._waited = waited
        """Told how long each wait lasted: the consumer's loop is busy the rest of the
        time (``tracker_service.loop_load``)."""

    def notify(self, name: str) -> None:
        """From a producer thread, after its item is queued where the consumer takes it."""
        with self._lock:
            new = name not in self._ready
            self._ready.add(name)
        if new:
            self._event.set()

    def wait(self, timeout: float) -> bool:
        """Until a producer notifies (True) or ``timeout`` seconds pass (False)."""
        if self._waited is None:
            return self._event.wait(max(timeout, 0.0))
        began = time.monotonic()
        try:
            return self._event.wait(max(timeout, 0.0))
        finally:
            self._waited(time.monotonic() - began)

    def wait_until(self, *deadlines: float | None) -> bool:
        """Until a producer notifies (True) or the earliest of ``deadlines`` (POSIX s; None
        for none) comes, and at most ``WAIT_CAP_S`` (False)."""
        earliest = min((d for d in deadlines if d is not None), default=math.inf)
        return self.wait(min(earliest - time.time(), WAIT_CAP_S))

    def take(self) -> set[str]:
        """The names notified since the last call; the event cleared first, so that a
        notification racing with this call wakes the next ``wait``."""
        self._event.clear()
        with self._lock:
            ready, self._ready = self._ready, set()
        return ready
