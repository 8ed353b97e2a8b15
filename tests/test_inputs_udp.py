"""The UDP input on loopback, with real sockets."""

from __future__ import annotations

import socket
import time
from collections.abc import Iterator

import pytest

from asterix.containers import Datagram
from tracker_service.inputs.udp import UdpEndpoint, UdpInput, block_chain_error

TIMEOUT_S = 2.0


def block(n: int, size: int = 12) -> bytes:
    """A CAT048 data block of ``size`` bytes whose content says ``n``."""
    body = n.to_bytes(4, "big") + bytes(size - 7)
    return bytes([48]) + size.to_bytes(2, "big") + body


@pytest.fixture
def sender() -> Iterator[socket.socket]:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    yield sock
    sock.close()


def wait_counters(feed: UdpInput, received: int) -> None:
    deadline = time.monotonic() + TIMEOUT_S
    while feed.counters.received < received:
        assert time.monotonic() < deadline, f"only {feed.counters} after {TIMEOUT_S} s"
        time.sleep(0.005)


def test_block_chain_error() -> None:
    assert block_chain_error(block(1) + block(2, 20)) is None
    assert block_chain_error(b"") == "empty datagram"
    assert "category 0" in str(block_chain_error(b"\x00\x00\x05ab"))
    assert "claims 12 bytes" in str(block_chain_error(block(1)[:-1]))
    assert "trailing" in str(block_chain_error(block(1) + b"\x30\x00"))
    assert "block length 2" in str(block_chain_error(b"\x30\x00\x02"))


def test_unicast_delivery(sender: socket.socket) -> None:
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0)) as feed:
        port = feed.endpoints[0][1]
        before = time.time()
        sender.sendto(block(1), ("127.0.0.1", port))
        got = feed.get(TIMEOUT_S)
        after = time.time()
    assert isinstance(got, Datagram)
    assert got.payload == block(1)
    assert got.source == sender.getsockname()
    assert got.destination == ("127.0.0.1", port)
    assert got.time is not None and before <= got.time <= after
    assert feed.counters.delivered == 1 and feed.counters.received == 1


def test_payloads_are_their_own_bytes(sender: socket.socket) -> None:
    """The reader receives into one buffer and copies each datagram out at its size: a
    large datagram, then smaller ones, each delivered whole and alone, and unchanged by
    the receptions after it (a view of the buffer would be overwritten)."""
    sizes = [65_000, 12, 3_000, 12, 40_000]
    sent = [block(n, size) for n, size in enumerate(sizes)]
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0)) as feed:
        port = feed.endpoints[0][1]
        for payload in sent:
            sender.sendto(payload, ("127.0.0.1", port))
        wait_counters(feed, len(sent))
        got = [feed.get(TIMEOUT_S) for _ in sent]
    assert [type(d.payload) for d in got if d is not None] == [bytes] * len(sent)
    assert [d.payload for d in got if d is not None] == sent
    assert feed.counters.bytes == sum(sizes)


def test_second_lan_duplicate_dropped_and_counted(sender: socket.socket) -> None:
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0), UdpEndpoint("127.0.0.1", 0)) as feed:
        (_, port_a), (_, port_b) = feed.endpoints
        sender.sendto(block(1), ("127.0.0.1", port_a))
        sender.sendto(block(1), ("127.0.0.1", port_b))
        sender.sendto(block(2), ("127.0.0.1", port_b))
        wait_counters(feed, 3)
        got = [feed.get(TIMEOUT_S) for _ in range(2)]
        assert feed.get(0.05) is None
    assert sorted(d.payload for d in got if d is not None) == [block(1), block(2)]
    counters = feed.counters
    assert (counters.delivered, counters.duplicates) == (2, 1)


def test_malformed_counted_and_next_arrives(sender: socket.socket) -> None:
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0)) as feed:
        port = feed.endpoints[0][1]
        sender.sendto(b"hello, not asterix", ("127.0.0.1", port))
        sender.sendto(block(7), ("127.0.0.1", port))
        got = feed.get(TIMEOUT_S)
    assert got is not None and got.payload == block(7)
    assert feed.counters.malformed == 1
    assert feed.counters.delivered == 1


def test_queue_overflow_counted(sender: socket.socket) -> None:
    with UdpInput("r1", UdpEndpoint("127.0.0.1", 0), queue_size=3) as feed:
        port = feed.endpoints[0][1]
        for n in range(10):
            sender.sendto(block(n), ("127.0.0.1", port))
        wait_counters(feed, 10)
        got = [feed.get(0.05) for _ in range(4)]
    assert [d.payload for d in got if d is not None] == [block(0), block(1), block(2)]
    counters = feed.counters
    assert (counters.delivered, counters.dropped) == (3, 7)


def test_multicast_on_loopback() -> None:
    group = "239.255.71.13"
    try:
        feed = UdpInput("r1", UdpEndpoint(group, 0, interface="127.0.0.1"))
    except OSError as exc:
        pytest.skip(f"cannot join {group} on loopback: {exc}")
    with feed, socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out:
        out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton("127.0.0.1"))
        out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        out.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, 0)
        port = feed.endpoints[0][1]
        try:
            out.sendto(block(3), (group, port))
        except OSError as exc:
            pytest.skip(f"cannot send to {group} on loopback: {exc}")
        got = feed.get(TIMEOUT_S)
    if got is None:
        pytest.skip("the kernel does not loop multicast back on lo (no MULTICAST flag?)")
    assert got.payload == block(3)
    assert got.destination == (group, port)
