"""The daemon behind ``tracker-service run``: live UDP feeds into the service core.

Each feed has its input (``inputs.udp.UdpInput``: a thread per LAN, the duplicate filter,
a bounded queue whose overflow is counted), which tells one ``inputs.arrivals.Arrivals``
when it has queued something. One thread, this one, merges the inputs, waiting for data
(or its next duty) rather than polling them: a datagram waits until
``system.holding_window_s`` has passed since its reception, so that the datagrams of
every radar reach the core in reception-time order (ties by input name) even when a
thread ran late; the core logs them in that order, and the replay of the log feeds them
the same way. The window holds at most a configured number of datagrams
and bytes: a burst beyond is dropped and counted. An exception in the processing of one
datagram is logged (at a bounded rate) and counted; the daemon goes on.

The chain runs here; the outputs (messages, Zenoh, CAT062, MCAP) in a second process
(``command.OutputProcess``, restarted when it dies), fed the chain's rows in order, so
that the chain has a core of its own and the messages are those of a single process.
The daemon measures how far the chain is behind the wall clock (``lag_s`` in status); a
datagram whose turn comes more than ``system.max_behind_s`` behind is dropped unprocessed
and counted (``Lateness``): an overloaded daemon sheds load, its picture at most that late.
"""

from __future__ import annotations

import errno
import heapq
import logging
import math
import time
from collections import Counter
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

from asterix.containers import Datagram
from tracker_service.ingest import DuplicateWindow
from tracker_service.inputs.arrivals import Arrivals
from tracker_service.inputs.udp import (
    EndpointError,
    InputCounters,
    UdpEndpoint,
    UdpInput,
    kernel_drop_table,
)
from tracker_service.loop_load import LoopLoad
from tracker_service.ratelimit import RateLimitedLog
from tracker_service.service.command import OutputProcessFailed, open_service
from tracker_service.service.config import AdsbFeed, Lan, Radar, ServiceConfig
from tracker_service.service.core import TrackerService, input_name
from tracker_service.service.signals import Stop
from tracker_service.service.warm_up import WarmUpStopped, core_warm_up

__all__ = [
    "Daemon",
    "InputError",
    "Lateness",
    "Merger",
    "input_counters",
    "open_inputs",
    "take_ready",
]

log = logging.getLogger(__name__)

COUNTERS_S = 0.5
"""How often the inputs' counters are copied for the status messages (wall clock)."""
STOP_DRAIN_S = 2.0
"""At a stop, the datagrams the holding window holds are processed for at most this long;
the rest (a backlog of an overloaded core) are dropped and counted, so that a stop is
prompt whatever the load."""
ADVANCE_S = 0.1
"""While every feed is quiet, data time follows the wall clock in steps this long (each
step is a call to the output process, and a wake-up of the loop)."""
QUIET_S = 1.0
"""After this long without a datagram, data time follows the wall clock (status goes on)."""


def take_ready(inputs: list[UdpInput], ready: set[str]) -> Iterator[tuple[str, Datagram]]:
    """Every datagram queued by the inputs named in ``ready`` (from ``Arrivals.take``),
    input by input in the order of ``inputs`` (that of the configuration), so that the
    order of what is pushed does not depend on the order of a set."""
    for udp in inputs:
        if udp.name in ready:
            for datagram in udp.take():
                yield udp.name, datagram


class InputError(ValueError):
    """An input that cannot be opened as configured; the message names the field, the
    address and port, and the fix, on one line."""


def _endpoint(lan: Lan) -> UdpEndpoint:
    interface = "0.0.0.0" if lan.interface is None else str(lan.interface)
    return UdpEndpoint(str(lan.address), lan.port, interface)


def _feeds(config: ServiceConfig) -> list[tuple[str, Radar | AdsbFeed]]:
    """Each feed with the name of its table in the configuration (``radars[0]``)."""
    return [(f"radars[{i}]", r) for i, r in enumerate(config.radars)] + [
        (f"adsb[{i}]", a) for i, a in enumerate(config.adsb)
    ]


def open_inputs(
    config: ServiceConfig, queue_size: int = 1024, arrivals: Arrivals | None = None
) -> list[UdpInput]:
    """One input per configured feed (radars and ADS-B) that has an ``input`` table,
    each telling ``arrivals`` when it has queued a datagram; InputError when one cannot be
    bound."""
    inputs: list[UdpInput] = []
    try:
        for table, feed in _feeds(config):
            if feed.input is None:
                continue
            second = feed.input.second_lan
            lan_a = _endpoint(feed.input)
            lan_b = None if second is None else _endpoint(second)
            try:
                inputs.append(
                    UdpInput(
                        input_name(feed.key),
                        lan_a,
                        lan_b,
                        queue_size=queue_size,
                        duplicate_window=DuplicateWindow(seconds=feed.input.duplicate_window_s),
                        arrivals=arrivals,
                    )
                )
            except EndpointError as exc:
                field = f"{table}.input" if exc.endpoint == lan_a else f"{table}.input.second_lan"
                attribute = "address" if exc.errno == errno.EADDRNOTAVAIL else "port"
                raise InputError(
                    f"{field}.{attribute} ({feed.key} {feed.name!r}): {exc.reason}"
                ) from None
    except BaseException:
        for opened in inputs:
            opened.close()
        raise
    return inputs


class Merger:
    """Datagrams of several inputs, released in (reception time, input name, number)
    order once ``window`` seconds old; holding at most ``max_datagrams`` and
    ``max_bytes``: beyond, a datagram is refused (``push`` says False) and its input's
    ``dropped`` count grows, so that a burst is dropped and counted, not held in full."""

    def __init__(
        self, window: float, max_datagrams: int = 50_000, max_bytes: int = 32 * 1024 * 1024
    ) -> None:
        self.window = window
        self.max_datagrams = max_datagrams
        self.max_bytes = max_bytes
        self.bytes = 0
        self.dropped: Counter[str] = Counter()
        self._heap: list[tuple[float, str, int, Datagram]] = []

    def __len__(self) -> int:
        return len(self._heap)

    def push(self, name: str, datagram: Datagram) -> bool:
        assert datagram.time is not None
        size = len(datagram.payload)
        if len(self._heap) >= self.max_datagrams or self.bytes + size > self.max_bytes:
            self.dropped[name] += 1
            return False
        heapq.heappush(self._heap, (datagram.time, name, datagram.offset, datagram))
        self.bytes += size
        return True

    def oldest(self) -> float | None:
        """The reception time (POSIX s) of the oldest datagram held; None when empty."""
        return self._heap[0][0] if self._heap else None

    def due(self) -> float | None:
        """When the oldest datagram held is ``window`` old (POSIX s); None when empty."""
        oldest = self.oldest()
        return None if oldest is None else oldest + self.window

    def release(self, now: float) -> list[tuple[str, Datagram]]:
        """What is at least ``window`` old at ``now`` (everything when ``now`` is inf)."""
        out = []
        while self._heap and self._heap[0][0] <= now - self.window:
            _, name, _, datagram = heapq.heappop(self._heap)
            self.bytes -= len(datagram.payload)
            out.append((name, datagram))
        return out


class Lateness:
    """How far behind the wall clock the data is when its turn comes (``lag_s`` in
    status), beyond the holding window ``window``; and the shedding of what is too late:
    more than ``max_behind`` seconds behind, an item is dropped unprocessed and counted
    by input name (``drop_causes.behind``). Skipping costs next to nothing, so an
    overloaded chain catches up to ``max_behind`` at once and stays there, its backlog
    (and memory) bounded, instead of falling ever further behind.

    What was received before ``started`` (the process's warm-up, ``service/warm_up.py``:
    its inputs bound, their data waiting) is late because of the start, not the chain:
    shed all the same when too late, but counted apart (``drop_causes.warm_up``) and left
    out of the lag."""

    def __init__(self, window: float, max_behind: float) -> None:
        self.window = window
        self.max_behind = max_behind
        self.dropped: Counter[str] = Counter()
        self.warm_up_dropped: Counter[str] = Counter()
        self.started = -math.inf
        """When the process began to take its inputs' data (POSIX s)."""
        self._lag = 0.0

    def admit(self, name: str, received: float) -> bool:
        """Whether the item of input ``name`` received at ``received`` (POSIX s) is to
        be processed now; False: it is dropped, and counted."""
        behind = time.time() - received - self.window
        waited = received < self.started
        if not waited:
            self._lag = max(self._lag, behind)
        if behind > self.max_behind:
            (self.warm_up_dropped if waited else self.dropped)[name] += 1
            return False
        return True

    def take_lag(self) -> float:
        """The most any item was behind since the last call."""
        lag, self._lag = self._lag, 0.0
        return lag


def input_counters(
    inputs: list[UdpInput], merger: Merger, lateness: Lateness
) -> dict[str, InputCounters]:
    """Each input's counters by name, with what the holding window and the shedding
    dropped of its datagrams later (the daemon's status; a radar process's watermark)."""
    drop_table = kernel_drop_table()
    return {
        udp.name: replace(
            udp.counters_with(drop_table),
            held_dropped=merger.dropped[udp.name],
            behind_dropped=lateness.dropped[udp.name],
            warm_up_dropped=lateness.warm_up_dropped[udp.name],
        )
        for udp in inputs
    }


class Daemon:
    def __init__(self, config: ServiceConfig, health_file: Path | None = None) -> None:
        self.config = config
        self.health_file = health_file
        self.failures = 0
        self._warn = RateLimitedLog(log)
        system = config.system
        self.lateness = Lateness(system.holding_window_s, system.max_behind_s)
        self.load = LoopLoad()
        """Its loop's: the status's ``busy["core"]``."""

    def run(self, stop: Stop) -> int:
        """Until ``stop`` is set; then what the merger holds is processed (for at most
        ``STOP_DRAIN_S``), every live track ended and the log closed."""
        config = self.config
        arrivals = Arrivals(self.load.waited)
        # Bound first, so that a UDP port in use is the one line it should be at once; what
        # arrives while the process warms up waits in the inputs' bounded queues (their
        # overflow counted), and what is then too late is shed as any late data is.
        inputs = open_inputs(config, arrivals=arrivals)
        if not inputs:
            log.warning("no radar has an [input]: nothing will arrive")
        for udp in inputs:
            log.info("%s: listening on %s", udp.name, udp.endpoints)
        system = config.system
        merger = Merger(
            system.holding_window_s,
            system.holding_window_max_datagrams,
            int(system.holding_window_max_mb * 1024 * 1024),
        )
        try:
            try:
                warm_up = core_warm_up(config, stop)
            except WarmUpStopped:
                warm_up = None
            if stop.is_set():  # told to stop while it warmed up
                return 0
            self.lateness.started = time.time()
            with open_service(
                config,
                config.mcap.directory,
                output_process=True,
                health_file=self.health_file,
                warm_up=warm_up,
            ) as service:
                # Data time starts now, and with it the status (and the health file).
                service.advance(time.time() - system.holding_window_s)
                log.info("running: publishing under %s/", config.zenoh.prefix)
                last_datagram = time.time()
                next_counters = 0.0
                next_advance = 0.0
                while not stop.is_set():
                    received = self._collect(inputs, arrivals.take(), merger)
                    now = time.time()
                    if received:
                        last_datagram = now
                    released = merger.release(now)
                    for k, (name, datagram) in enumerate(released):
                        if stop.is_set():
                            # Back into the window, for the bounded drain below.
                            for later in released[k:]:
                                merger.push(*later)
                            break
                        self._process(service, name, datagram)
                    if now >= next_counters:
                        self._update_counters(service, inputs, merger)
                        next_counters = now + COUNTERS_S
                    if now - last_datagram > QUIET_S and not merger and now >= next_advance:
                        service.advance(now - config.system.holding_window_s)
                        next_advance = now + ADVANCE_S
                    # Until data comes or the next duty: the oldest datagram held due (so
                    # that it is released as late as it was at a 1 ms poll, or less), the
                    # counters, data time's advance while quiet.
                    advance_at = None if merger else max(last_datagram + QUIET_S, next_advance)
                    arrivals.wait_until(merger.due(), next_counters, advance_at)
                for udp in inputs:
                    udp.close()
                self._collect(inputs, {udp.name for udp in inputs}, merger)
                # What the window holds goes through, for as long as a stop may take.
                deadline = time.monotonic() + STOP_DRAIN_S
                for name, datagram in merger.release(float("inf")):
                    if time.monotonic() < deadline:
                        self._process(service, name, datagram)
                    else:
                        merger.dropped[name] += 1
                self._update_counters(service, inputs, merger)
                log.info(
                    "stopping: %d datagrams through the chain, %d failures; ending every "
                    "live track",
                    service.chain.stats.datagrams,
                    self.failures,
                )
        finally:
            for udp in inputs:
                udp.close()
        return 0

    def _update_counters(
        self, service: TrackerService, inputs: list[UdpInput], merger: Merger
    ) -> None:
        service.set_input_counters(input_counters(inputs, merger, self.lateness))
        service.note_live(self.lateness.take_lag(), loops={"core": self.load.totals()})

    @staticmethod
    def _collect(inputs: list[UdpInput], ready: set[str], merger: Merger) -> bool:
        """What the inputs named ``ready`` hold into the window; whether there was any."""
        received = False
        for name, datagram in take_ready(inputs, ready):
            merger.push(name, datagram)
            received = True
        return received

    def _process(self, service: TrackerService, name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        if not self.lateness.admit(name, datagram.time):
            return
        try:
            service.process(name, datagram)
        except OutputProcessFailed:
            raise
        except Exception:
            # The core catches what bad data does; this is the rest (a full disk, a
            # closed session): counted, and the daemon goes on.
            self.failures += 1
            self._warn.exception(
                "process", "%s: datagram %d could not be handled", name, datagram.offset
            )
