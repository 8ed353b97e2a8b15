"""A radar's UDP feed: one or two LANs in, one bounded queue of datagrams out.

One thread per socket rather than asyncio: the reception time is taken the moment the
kernel hands the datagram over, whatever the consumer is busy with (a tracker step can
hold an event loop for milliseconds, which would both skew the reception times the plot
clock relies on and leave the socket undrained, where the kernel drops without telling).
Here the thread always drains the socket, and what the consumer cannot take in time is
dropped at the queue, and counted. ``recvmsg_into`` waits with the GIL released and without a
timeout, so the threads cost nothing while the feed is quiet; ``close`` shuts the sockets
down to end the wait.
"""

from __future__ import annotations

import contextlib
import errno
import ipaddress
import logging
import os
import socket
import struct
import threading
import time
from collections import deque
from dataclasses import dataclass, replace

from asterix.containers import Datagram
from tracker_service.closing import Closing
from tracker_service.ingest import DuplicateFilter, DuplicateWindow, Repetition
from tracker_service.inputs.arrivals import Arrivals
from tracker_service.ratelimit import RateLimitedLog

__all__ = [
    "EndpointError",
    "InputCounters",
    "UdpEndpoint",
    "UdpInput",
    "block_chain_error",
    "kernel_drop_table",
]

_log = logging.getLogger(__name__)

_MAX_DATAGRAM = 65535
_CLOSE_WAIT_S = 1.0
"""How long ``close`` waits for its reader threads once their sockets are shut down."""
_RECEIVE_BUFFER = 4 * 1024 * 1024
QUEUE_BYTES = 16 * 1024 * 1024
"""Default bound of an input's queue in bytes (beside its bound in datagrams): 1,024
datagrams of 64 KiB would otherwise be 64 MB per input."""
SO_RXQ_OVFL = getattr(socket, "SO_RXQ_OVFL", 40)
"""Linux: each datagram carries, as ancillary data, how many datagrams the kernel has
dropped on this socket so far (receive buffer full)."""
_ANCILLARY = socket.CMSG_SPACE(4)


class EndpointError(OSError):
    """A socket that cannot be opened as configured (the port in use, an address not of
    this host); ``endpoint`` says which, ``reason`` what to do, in words."""

    def __init__(self, endpoint: UdpEndpoint, error: OSError) -> None:
        self.endpoint = endpoint
        where = f"{endpoint.address}:{endpoint.port}"
        if error.errno == errno.EADDRINUSE:
            self.reason = (
                f"{where} is already bound by another process (a second tracker-service?); "
                f"stop it (`ss -ulpn 'sport = :{endpoint.port}'` names it) or choose a free port"
            )
        elif error.errno == errno.EADDRNOTAVAIL:
            self.reason = f"{where}: {endpoint.address} is not an address of this host"
        else:
            self.reason = f"{where}: {error.strerror or error}"
        super().__init__(error.errno, self.reason)


@dataclass(frozen=True, slots=True)
class UdpEndpoint:
    """Where one LAN's copy of a feed arrives.

    ``address`` is a multicast group to join, or a unicast address of this host to bind
    ("0.0.0.0" for all). ``interface`` is the local address of the interface on which to
    join the group (ignored for unicast).
    """

    address: str
    port: int
    interface: str = "0.0.0.0"

    @property
    def multicast(self) -> bool:
        return ipaddress.IPv4Address(self.address).is_multicast


@dataclass(slots=True)
class InputCounters:
    """What one input has seen since it started; every datagram lands in exactly one of
    ``delivered``, ``duplicates``, ``malformed`` and ``dropped``."""

    received: int = 0
    """Datagrams read from the sockets, both LANs."""
    delivered: int = 0
    """Put on the queue."""
    duplicates: int = 0
    """Copies of a datagram already received on the other LAN (the redundant LAN), dropped."""
    repeats: int = 0
    """Datagrams received twice on the same LAN within the duplicate window (a network or
    radar fault: processing them twice would count every plot twice), dropped."""
    malformed: int = 0
    """Not a chain of ASTERIX data blocks, dropped."""
    dropped: int = 0
    """Valid, but the queue was full (in datagrams or bytes): the consumer is behind."""
    held_dropped: int = 0
    """Dropped later, by the daemon's holding window when it was full (a burst): not
    part of the sum above, which ends at the queue."""
    kernel_drops: int = 0
    """Dropped by the kernel before this input could read them (receive buffer full),
    from SO_RXQ_OVFL: never seen, so not part of ``received`` either."""
    behind_dropped: int = 0
    """Dropped unprocessed later, when their turn came more than ``[system]
    max_behind_s`` behind the wall clock (the chain overloaded: it sheds load rather than
    fall further behind); not part of the sum above either."""
    warm_up_dropped: int = 0
    """The same for what arrived while the process warmed up (``service/warm_up.py``):
    late because of the start, not the chain."""
    bytes: int = 0
    last_reception: float | None = None
    """POSIX time of the last datagram received, valid or not."""


def block_chain_error(payload: bytes) -> str | None:
    """Why ``payload`` is not a chain of ASTERIX data blocks, or None when it is one.

    Only the framing is checked (category, and block lengths that add up to the payload);
    the codec judges the records.
    """
    if not payload:
        return "empty datagram"
    pos, end = 0, len(payload)
    while pos < end:
        if pos + 3 > end:
            return f"{end - pos} trailing bytes at offset {pos}, too short for a block header"
        if payload[pos] == 0:
            return f"category 0 at offset {pos}"
        length = (payload[pos + 1] << 8) | payload[pos + 2]
        if length < 3:
            return f"block length {length} at offset {pos}"
        if pos + length > end:
            return f"block at offset {pos} claims {length} bytes, {end - pos} left"
        pos += length
    return None


def _open_socket(endpoint: UdpEndpoint) -> socket.socket:
    """A socket bound to ``endpoint``; EndpointError when it cannot be.

    Unicast sockets are bound exclusively (no SO_REUSEADDR): with it, any process of any
    user could bind the same port and take the feed, the kernel handing each datagram to
    one socket only, and a second instance of the service would start silently. UDP has
    no TIME_WAIT, so a restarted service loses nothing without it. Multicast sockets keep
    it: every receiver of a group on a host binds the group's port (the two LANs' groups
    on one port, another application watching the same radar), and each gets its own
    copy of every datagram, so sharing steals nothing."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    try:
        if endpoint.multicast:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RECEIVE_BUFFER)
        try:
            sock.setsockopt(socket.SOL_SOCKET, SO_RXQ_OVFL, 1)
        except OSError:
            _log.info("no SO_RXQ_OVFL here: kernel receive drops are not counted per input")
        try:
            # Multicast: bound to the group (Linux), so that datagrams of other groups on
            # the same port, which another radar may use, stay out.
            sock.bind((endpoint.address, endpoint.port))
        except OSError as exc:
            raise EndpointError(endpoint, exc) from None
        if endpoint.multicast:
            membership = struct.pack(
                "4s4s",
                socket.inet_aton(endpoint.address),
                socket.inet_aton(endpoint.interface),
            )
            try:
                sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
            except OSError as exc:
                raise EndpointError(endpoint, exc) from None
        # Blocking without a timeout whatever ``socket.setdefaulttimeout`` says: the
        # readers wait in recvmsg until a datagram or close's shutdown.
        sock.setblocking(True)
    except BaseException:
        sock.close()
        raise
    return sock


PROC_NET_UDP = "/proc/net/udp"


def kernel_drop_table() -> dict[int, int] | None:
    """Every UDP socket's kernel drop count (the same counter SO_RXQ_OVFL reports) from
    /proc/net/udp, by inode; None where that file is not (not Linux). Unlike the
    ancillary data, it is known without waiting for the next datagram. Read once for
    all of a process's inputs (``UdpInput.counters_with``): the table lists every
    socket of the host, and a radar process has dozens of inputs."""
    try:
        with open(PROC_NET_UDP, encoding="ascii") as table:
            lines = table.readlines()[1:]
    except OSError:
        return None
    by_inode = {}
    for line in lines:
        fields = line.split()
        if len(fields) >= 13:
            by_inode[int(fields[9])] = int(fields[-1])
    return by_inode


def _kernel_drops(ancillary: list[tuple[int, int, bytes]]) -> int | None:
    """The socket's drop count carried by one datagram (SO_RXQ_OVFL), if any."""
    for level, kind, data in ancillary:
        if level == socket.SOL_SOCKET and kind == SO_RXQ_OVFL and len(data) >= 4:
            drops: int = struct.unpack("=I", data[:4])[0]
            return drops
    return None


class UdpInput(Closing):
    """One radar's feed: LAN A, optionally LAN B whose copies of A's datagrams are
    dropped, into a queue of :class:`Datagram` bounded in datagrams and in bytes
    (reception time from ``time.time()``, sender address as source, the endpoint as
    destination). A datagram repeated on the same LAN within the duplicate window is
    dropped too, and counted apart (``repeats``).

    ``Datagram.offset`` is the datagram's number in this input (from 0, both LANs), the
    nearest thing a live feed has to an offset in its input.

    ``arrivals``: told this input's name each time a datagram is queued, so that a loop
    over many inputs waits for data and takes from those that have some (``take``).
    """

    def __init__(
        self,
        name: str,
        lan_a: UdpEndpoint,
        lan_b: UdpEndpoint | None = None,
        *,
        queue_size: int = 1024,
        queue_bytes: int = QUEUE_BYTES,
        duplicate_window: DuplicateWindow | None = None,
        arrivals: Arrivals | None = None,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, not {queue_size}")
        self.name = name
        self._queue: deque[Datagram] = deque()
        self._queue_size = queue_size
        self._queue_bytes = queue_bytes
        self._queued_bytes = 0
        self._arrivals = arrivals
        # On one LAN too: a datagram received twice within the window (a switch loop, a
        # radar that resends) would have every plot processed twice.
        self._duplicates = DuplicateFilter(duplicate_window)
        self._counters = InputCounters()
        self._socket_drops: list[int] = []
        self._rate_limited = RateLimitedLog(_log)
        # One lock for the filter, the counters, the datagram numbers and the queue: the
        # two LAN threads and the consumer share them.
        self._lock = threading.Lock()
        self._queued = threading.Condition(self._lock)
        self._stop = threading.Event()
        endpoints = [lan_a] if lan_b is None else [lan_a, lan_b]
        self._sockets: list[socket.socket] = []
        try:
            for endpoint in endpoints:
                self._sockets.append(_open_socket(endpoint))
        except BaseException:
            self._close_sockets()
            raise
        self._endpoints = [
            (endpoint.address, sock.getsockname()[1])
            for endpoint, sock in zip(endpoints, self._sockets, strict=True)
        ]
        self._socket_drops = [0] * len(self._sockets)
        self._inodes = [os.fstat(sock.fileno()).st_ino for sock in self._sockets]
        self._threads = [
            threading.Thread(
                target=self._receive,
                args=(sock, destination, lan),
                name=f"udp-{name}-{'AB'[lan]}",
                daemon=True,
            )
            for lan, (sock, destination) in enumerate(
                zip(self._sockets, self._endpoints, strict=True)
            )
        ]
        for thread in self._threads:
            thread.start()

    @property
    def endpoints(self) -> list[tuple[str, int]]:
        """(address, port) per LAN as bound; the port is the one the kernel chose when 0
        was asked for."""
        return list(self._endpoints)

    @property
    def counters(self) -> InputCounters:
        """A consistent snapshot of the counters."""
        return self.counters_with(kernel_drop_table())

    def counters_with(self, drop_table: dict[int, int] | None) -> InputCounters:
        """``counters``, the kernel's drop counts read from ``drop_table``
        (``kernel_drop_table``, None: not known)."""
        drops = None if drop_table is None else [drop_table.get(i, 0) for i in self._inodes]
        with self._lock:
            if drops is not None:
                self._socket_drops = [
                    max(a, b) for a, b in zip(self._socket_drops, drops, strict=True)
                ]
                self._counters.kernel_drops = sum(self._socket_drops)
            return replace(self._counters)

    def get(self, timeout: float | None = None) -> Datagram | None:
        """The next datagram, or None when none came within ``timeout`` seconds."""
        with self._queued:
            if not self._queued.wait_for(lambda: self._queue, timeout):
                return None
            datagram = self._queue.popleft()
            self._queued_bytes -= len(datagram.payload)
        return datagram

    def take(self) -> list[Datagram]:
        """Every datagram queued, in order; none waited for."""
        with self._lock:
            datagrams = list(self._queue)
            self._queue.clear()
            self._queued_bytes = 0
        return datagrams

    def _receive(self, sock: socket.socket, destination: tuple[str, int], lan: int) -> None:
        # Received into one buffer and copied out at its size: ``recvmsg`` allocates the
        # largest datagram's 64 KiB for each and shrinks it after, which left the
        # malloc arenas of these threads fragmented, growing by a megabyte a minute
        # under ``artas``'s 370 datagrams a second (docs/benchmarks.md, session 19).
        buffer = bytearray(_MAX_DATAGRAM)
        view = memoryview(buffer)
        while not self._stop.is_set():
            try:
                # Blocking, no timeout: one system call per datagram, none while the feed
                # is quiet (a timeout polls first, and woke every idle thread five times
                # a second); ``close`` shuts the socket down to end the wait.
                size, ancillary, _, sender = sock.recvmsg_into((buffer,), _ANCILLARY)
                payload = bytes(view[:size])
            except OSError:
                if self._stop.is_set():
                    return
                # A transient error (ICMP feedback, buffer pressure) must not end the feed.
                self._rate_limited.exception(
                    "receive", "%s: receive error on %s:%d", self.name, *destination
                )
                continue
            received_at = time.time()
            if self._stop.is_set():
                return  # woken by close's shutdown (or a last datagram: dropped)
            drops = _kernel_drops(ancillary)
            queued = self._accept(
                payload, received_at, (sender[0], sender[1]), destination, lan, drops
            )
            if queued and self._arrivals is not None:
                # After the datagram is queued (and outside this input's lock): see
                # inputs.arrivals for why no wake-up is lost.
                self._arrivals.notify(self.name)

    def _accept(
        self,
        payload: bytes,
        received_at: float,
        source: tuple[str, int],
        destination: tuple[str, int],
        lan: int = 0,
        socket_drops: int | None = None,
    ) -> bool:
        """Whether the datagram was queued."""
        with self._lock:
            counters = self._counters
            if socket_drops is not None and socket_drops != self._socket_drops[lan]:
                self._socket_drops[lan] = socket_drops
                counters.kernel_drops = sum(self._socket_drops)
                self._rate_limited.warning(
                    "kernel",
                    "%s: the kernel dropped datagrams on %s:%d (receive buffer full): "
                    "%d so far on this input",
                    self.name,
                    *destination,
                    counters.kernel_drops,
                )
            number = counters.received
            counters.received += 1
            counters.bytes += len(payload)
            counters.last_reception = received_at
            reason = block_chain_error(payload)
            if reason is not None:
                counters.malformed += 1
                self._rate_limited.warning(
                    "malformed",
                    "%s: not ASTERIX from %s:%d (%d bytes): %s",
                    self.name,
                    *source,
                    len(payload),
                    reason,
                )
                return False
            repetition = self._duplicates.classify(payload, received_at, lan)
            if repetition is Repetition.COPY:
                counters.duplicates += 1
                return False
            if repetition is Repetition.REPEAT:
                counters.repeats += 1
                self._rate_limited.warning(
                    "repeat",
                    "%s: a datagram repeated on LAN %s within %g s, dropped",
                    self.name,
                    "AB"[lan],
                    self._duplicates.window.seconds,
                )
                return False
            if (
                len(self._queue) >= self._queue_size
                or self._queued_bytes + len(payload) > self._queue_bytes
            ):
                counters.dropped += 1
                self._rate_limited.warning(
                    "queue", "%s: queue full (the core is behind): datagram dropped", self.name
                )
                return False
            self._queue.append(Datagram(payload, number, received_at, source, destination))
            self._queued_bytes += len(payload)
            counters.delivered += 1
            self._queued.notify()
            return True

    def close(self) -> None:
        """Stops the threads and closes the sockets; what is queued stays readable."""
        self._stop.set()
        for sock in self._sockets:
            # Wakes a thread waiting in recvmsg (Linux: even on an unconnected UDP
            # socket, which says ENOTCONN all the same).
            with contextlib.suppress(OSError):
                sock.shutdown(socket.SHUT_RD)
        deadline = time.monotonic() + _CLOSE_WAIT_S  # one wait for all the threads
        for thread in self._threads:
            thread.join(max(deadline - time.monotonic(), 0.0))
            if thread.is_alive():
                _log.warning("%s: %s still waiting on its socket at close", self.name, thread.name)
        self._close_sockets()

    def _close_sockets(self) -> None:
        for sock in self._sockets:
            sock.close()
