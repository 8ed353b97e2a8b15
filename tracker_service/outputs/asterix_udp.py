"""ASTERIX over UDP as a ``Sink``: what an ATC system takes from an SDPS.

To one destination (a multicast group or a unicast address, ``[[asterix_udp]]``), as the
SDPS of ``[system]`` (I010 SAC/SIC, I015 service identification):

- on update: each system-track update as CAT062 (I070 its own time; the track's end with
  TSE), the updates of one batch of the chain packed together, sent at the next call of
  any kind (the next datagram received: the latency of the chain);
- periodically (``period_s``): at every multiple of the period in data time, every live
  system track extrapolated to that time (``periodic.PeriodicPicture``), then a CAT065
  end of batch with the batch number (modulo 256);
- with the service's status (every 5 s, or ``status_period_s``): a CAT065 SDPS status
  (I040 NOGO "degraded" while the status is, OVL while an output overflows) and one
  CAT063 record per radar and ADS-B feed (``cat063``: connection, time source, biases).

Data blocks are packed into datagrams of at most ``max_datagram_octets``, whole blocks
only (CAT062 blocks are cut at ``cat062.MAX_BLOCK_OCTETS``). A send that fails (no route,
a full buffer) raises: ``IsolatedSink`` reports the output as failing and retries.
"""

from __future__ import annotations

import math
import socket
from collections.abc import Iterator
from ipaddress import IPv4Address
from typing import Any, Protocol

from asterix.codec import encode_block
from asterix.containers import Datagram
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.cat062 import MAX_BLOCK_OCTETS, encode_cat065, encode_system_tracks
from tracker_service.outputs.cat063 import CAT063, sensor_records
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.periodic import PeriodicPicture
from tracker_service.outputs.sdps import Sdps, SdpsIdentity

__all__ = [
    "AsterixUdpSink",
    "UdpDestination",
    "blocks_in_datagrams",
    "parse_destination",
]


def parse_destination(text: str) -> tuple[str, int]:
    """``HOST:PORT`` of ``--asterix-udp`` (an IPv4 address, multicast or unicast)."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ValueError(f"{text!r} is not HOST:PORT, e.g. 239.1.62.1:8600 or 127.0.0.1:8600")
    return host, int(port)


def blocks_in_datagrams(data: bytes, limit: int) -> Iterator[bytes]:
    """Whole data blocks of ``data``, packed into payloads of at most ``limit`` octets
    (a block longer than ``limit`` alone in its payload)."""
    start = pos = 0
    while pos + 3 <= len(data):
        end = pos + max(int.from_bytes(data[pos + 1 : pos + 3]), 3)
        if end - start > limit and pos > start:
            yield data[start:pos]
            start = pos
        pos = end
    if pos > start:
        yield data[start:pos]


class UdpDestination(Protocol):
    """One destination's settings (``service.config.AsterixUdpOutput`` is one)."""

    @property
    def address(self) -> IPv4Address: ...

    @property
    def port(self) -> int: ...

    @property
    def destination(self) -> str: ...

    @property
    def interface(self) -> IPv4Address | None: ...

    @property
    def ttl(self) -> int: ...

    @property
    def on_update(self) -> bool: ...

    @property
    def period_s(self) -> float | None: ...

    @property
    def status_period_s(self) -> float | None: ...

    @property
    def service_id(self) -> int | None: ...

    @property
    def max_datagram_octets(self) -> int: ...


class AsterixUdpSink:
    """See the module docstring. ``plane`` is the system plane (for the extrapolation)."""

    resends_tracks = False

    keeps_datagrams = False

    def __init__(self, output: UdpDestination, system: SdpsIdentity, plane: SystemPlane) -> None:
        self.name = f"asterix_udp {output.destination}"
        self.output = output
        self.sdps = Sdps.of(system, output.service_id)
        """The SDPS identity of its records (I010, I015) and the plane of I100."""
        self.destination = (str(output.address), output.port)
        self.periodic = None if output.period_s is None else PeriodicPicture(plane, output.period_s)
        self.sent_datagrams = 0
        self._pending: list[SystemTrackMessage] = []
        self._pending_time = -math.inf
        self._batch = 0
        self._biases: dict[str, BiasMessage] = {}
        self._next_status = -math.inf
        self._socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            if output.address.is_multicast:
                self._socket.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, output.ttl)
                self._socket.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
                if output.interface is not None:
                    self._socket.setsockopt(
                        socket.IPPROTO_IP,
                        socket.IP_MULTICAST_IF,
                        socket.inet_aton(str(output.interface)),
                    )
        except BaseException:
            self._socket.close()
            raise

    # --- the Sink protocol ---------------------------------------------------------------

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        self._tick(datagram.time)

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self._tick(time)
        if self.periodic is not None:
            self.periodic.update(message)
        if self.output.on_update:
            self._pending.append(message)
            self._pending_time = time

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self._tick(time)

    def asterix(self, data: bytes, time: float) -> None:
        """The core's own batches (Zenoh's, the log's): this output makes its own."""
        self._tick(time)

    def bias(self, message: BiasMessage, time: float) -> None:
        self._tick(time)
        self._biases[message.radar] = message

    def status(self, message: StatusMessage, time: float) -> None:
        self._tick(time)
        period = self.output.status_period_s
        if period is not None and time < self._next_status:
            return
        self._next_status = time + (period or 0.0)
        overflow = any(o.name == self.name and not o.ok for o in message.outputs)
        data = encode_cat065(
            "sdps_status",
            message.time,
            self._batch,
            self.sdps,
            degraded=message.health != "ok",
            overload=overflow,
        )
        data += self._sensor_status(message)
        self._send(data)

    def close(self) -> None:
        try:
            self._flush()
        finally:
            self._socket.close()

    # --- what it sends ---------------------------------------------------------------------

    def _tick(self, time: float) -> None:
        """Before any call at ``time``: the updates of an earlier time go out, and a
        periodic picture that fell due."""
        if self._pending and time != self._pending_time:
            self._flush()
        if self.periodic is None:
            return
        due = self.periodic.due(time)
        if due is None:
            return
        self._flush()
        picture = self.periodic.at(due)
        data = encode_system_tracks(picture, self.sdps, MAX_BLOCK_OCTETS)
        data += encode_cat065("end_of_batch", due, self._batch, self.sdps)
        self._batch += 1
        self._send(data)

    def _flush(self) -> None:
        if not self._pending:
            return
        messages, self._pending = self._pending, []
        self._send(encode_system_tracks(messages, self.sdps, MAX_BLOCK_OCTETS))

    def _sensor_status(self, message: StatusMessage) -> bytes:
        sdps = self.sdps
        records: list[dict[str, Any]] = sensor_records(
            message.radars, message.time, sdps.sac, sdps.sic, sdps.service_id, self._biases
        )
        # A block per a few dozen sensors keeps each within one datagram.
        return b"".join(
            encode_block(CAT063, records[i : i + 32]) for i in range(0, len(records), 32)
        )

    def _send(self, data: bytes) -> None:
        for payload in blocks_in_datagrams(data, self.output.max_datagram_octets):
            self._socket.sendto(payload, self.destination)
            self.sent_datagrams += 1
