"""A radar's UDP feed: one or two LANs in, one bounded queue of datagrams out.

One thread per socket rather than asyncio: the reception time is taken the moment the
kernel hands the datagram over, whatever the consumer is busy with (a tracker step can
hold an event loop for milliseconds, which would both skew the reception times the plot
clock relies on and leave the socket undrained, where the kernel drops without telling).
Here the thread always drains the socket, and what the consumer cannot take in time is
dropped at the queue, and counted. ``recvfrom`` releases the GIL, so the threads cost
nothing while the feed is quiet.
"""

from __future__ import annotations

import ipaddress
import logging
import queue
import socket
import struct
import threading
import time
from dataclasses import dataclass, replace

from asterix.containers import Datagram
from tracker_service.closing import Closing
from tracker_service.ingest import DuplicateFilter, DuplicateWindow

__all__ = ["InputCounters", "UdpEndpoint", "UdpInput", "block_chain_error"]

_log = logging.getLogger(__name__)

_MAX_DATAGRAM = 65535
# Long enough to add nothing measurable to idle CPU, short enough that close() returns
# promptly without having to shut the socket down from another thread.
_POLL_S = 0.2
_RECEIVE_BUFFER = 4 * 1024 * 1024


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
    """Copies of a datagram already received (the redundant LAN), dropped."""
    malformed: int = 0
    """Not a chain of ASTERIX data blocks, dropped."""
    dropped: int = 0
    """Valid, but the queue was full: the consumer is behind."""
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
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM, socket.IPPROTO_UDP)
    try:
        # Both LANs may carry the same group and port on two interfaces; a restarted
        # service must not wait for the old socket.
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, _RECEIVE_BUFFER)
        if endpoint.multicast:
            # Bound to the group (Linux): datagrams of other groups on the same port, which
            # another radar may use, stay out.
            sock.bind((endpoint.address, endpoint.port))
            membership = struct.pack(
                "4s4s",
                socket.inet_aton(endpoint.address),
                socket.inet_aton(endpoint.interface),
            )
            sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
        else:
            sock.bind((endpoint.address, endpoint.port))
        sock.settimeout(_POLL_S)
    except BaseException:
        sock.close()
        raise
    return sock


class UdpInput(Closing):
    """One radar's feed: LAN A, optionally LAN B whose copies of A's datagrams are
    dropped, into a bounded queue of :class:`Datagram` (reception time from
    ``time.time()``, sender address as source, the endpoint as destination).

    ``Datagram.offset`` is the datagram's number in this input (from 0, both LANs), the
    nearest thing a live feed has to an offset in its input.
    """

    def __init__(
        self,
        name: str,
        lan_a: UdpEndpoint,
        lan_b: UdpEndpoint | None = None,
        *,
        queue_size: int = 1024,
        duplicate_window: DuplicateWindow | None = None,
    ) -> None:
        if queue_size < 1:
            raise ValueError(f"queue_size must be at least 1, not {queue_size}")
        self.name = name
        self._queue: queue.Queue[Datagram] = queue.Queue(maxsize=queue_size)
        # Only a second LAN makes copies expected; on a single LAN two equal datagrams
        # are the radar's own business.
        self._duplicates = None if lan_b is None else DuplicateFilter(duplicate_window)
        self._counters = InputCounters()
        # One lock for the filter, the counters and the datagram numbers: the two LAN
        # threads share them.
        self._lock = threading.Lock()
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
        self._threads = [
            threading.Thread(
                target=self._receive,
                args=(sock, destination),
                name=f"udp-{name}-{lan}",
                daemon=True,
            )
            for sock, destination, lan in zip(self._sockets, self._endpoints, "AB", strict=False)
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
        with self._lock:
            return replace(self._counters)

    def get(self, timeout: float | None = None) -> Datagram | None:
        """The next datagram, or None when none came within ``timeout`` seconds."""
        try:
            return self._queue.get(timeout=timeout)
        except queue.Empty:
            return None

    def _receive(self, sock: socket.socket, destination: tuple[str, int]) -> None:
        while not self._stop.is_set():
            try:
                payload, sender = sock.recvfrom(_MAX_DATAGRAM)
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                # A transient error (ICMP feedback, buffer pressure) must not end the feed.
                _log.exception("%s: receive error on %s:%d", self.name, *destination)
                continue
            received_at = time.time()
            self._accept(payload, received_at, (sender[0], sender[1]), destination)

    def _accept(
        self,
        payload: bytes,
        received_at: float,
        source: tuple[str, int],
        destination: tuple[str, int],
    ) -> None:
        with self._lock:
            counters = self._counters
            number = counters.received
            counters.received += 1
            counters.bytes += len(payload)
            counters.last_reception = received_at
            reason = block_chain_error(payload)
            if reason is not None:
                counters.malformed += 1
                _log.warning(
                    "%s: not ASTERIX from %s:%d (%d bytes): %s",
                    self.name,
                    *source,
                    len(payload),
                    reason,
                )
                return
            if self._duplicates is not None and self._duplicates.is_duplicate(payload, received_at):
                counters.duplicates += 1
                return
            try:
                self._queue.put_nowait(Datagram(payload, number, received_at, source, destination))
            except queue.Full:
                counters.dropped += 1
                return
            counters.delivered += 1

    def close(self) -> None:
        """Stops the threads and closes the sockets; what is queued stays readable."""
        self._stop.set()
        for thread in self._threads:
            thread.join()
        self._close_sockets()

    def _close_sockets(self) -> None:
        for sock in self._sockets:
            sock.close()
