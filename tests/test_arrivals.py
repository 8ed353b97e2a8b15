"""The live loops' wake-up (``inputs.arrivals.Arrivals``): no lost wake-up with real
threads racing, the wait bounded by its deadlines and its cap, and real UDP inputs that
announce what they queue; the fusion merge's own deadline."""

from __future__ import annotations

import socket
import threading
import time
from collections import deque

import pytest

from asterix.containers import Datagram
from tracker_service.inputs.arrivals import WAIT_CAP_S, Arrivals
from tracker_service.inputs.udp import UdpEndpoint, UdpInput
from tracker_service.service.roles import LOCAL, STALLED_S, StageMerge

ROUNDS = 3000
PRODUCERS = 2
LOST_S = 5.0
"""A wait this long with items queued and announced is a lost wake-up (a round takes
microseconds)."""


def test_no_wake_up_is_lost_while_producers_race_the_consumer() -> None:
    """In each round two producers queue a few items each and notify, at the same time
    as the consumer clears, takes and drains: the consumer must see every item of the
    round without a wait that times out. A lost wake-up leaves the last items of a round
    queued while the consumer waits for a notification that never comes."""
    arrivals = Arrivals()
    queues = {f"p{i}": deque[int]() for i in range(PRODUCERS)}
    start = threading.Barrier(PRODUCERS + 1)
    per_round = [1 + (r % 3) for r in range(ROUNDS)]

    def produce(name: str) -> None:
        items = queues[name]
        for r in range(ROUNDS):
            try:
                start.wait()
            except threading.BrokenBarrierError:  # the consumer failed
                return
            for k in range(per_round[r]):
                items.append(r * 10 + k)
                arrivals.notify(name)

    threads = [threading.Thread(target=produce, args=(name,)) for name in queues]
    for thread in threads:
        thread.start()
    try:
        for r in range(ROUNDS):
            expected = PRODUCERS * per_round[r]
            seen = 0
            start.wait()
            while seen < expected:
                names = arrivals.take()
                taken = 0
                for name in names:
                    while queues[name]:
                        assert queues[name].popleft() // 10 == r
                        taken += 1
                seen += taken
                if seen < expected:
                    assert arrivals.wait(LOST_S), f"round {r}: lost wake-up, {seen}/{expected}"
    finally:
        start.abort()
        for thread in threads:
            thread.join()
    assert all(not items for items in queues.values())


def test_a_notification_before_the_wait_is_not_lost() -> None:
    arrivals = Arrivals()
    arrivals.notify("a")
    arrivals.notify("a")
    arrivals.notify("b")
    assert arrivals.wait(0.0)
    assert arrivals.take() == {"a", "b"}
    assert not arrivals.wait(0.0)
    assert arrivals.take() == set()


def test_wait_until_ends_at_the_earliest_deadline_or_the_cap() -> None:
    arrivals = Arrivals()
    started = time.monotonic()
    assert not arrivals.wait_until(None, time.time() + 0.02, time.time() + 10.0)
    took = time.monotonic() - started
    assert 0.015 <= took < WAIT_CAP_S
    started = time.monotonic()
    assert not arrivals.wait_until(None)
    took = time.monotonic() - started
    assert WAIT_CAP_S * 0.9 <= took < WAIT_CAP_S + 1.0
    # A deadline already past: no wait.
    started = time.monotonic()
    assert not arrivals.wait_until(time.time() - 1.0)
    assert time.monotonic() - started < WAIT_CAP_S * 0.9


def test_a_datagram_wakes_the_waiter_and_only_its_input_is_named() -> None:
    arrivals = Arrivals()
    with (
        UdpInput("r1", UdpEndpoint("127.0.0.1", 0), arrivals=arrivals) as first,
        UdpInput("r2", UdpEndpoint("127.0.0.1", 0), arrivals=arrivals) as second,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sender,
    ):
        assert not arrivals.wait(0.05)
        payloads = [bytes([48, 0, 4, n]) for n in range(3)]
        for payload in payloads:
            sender.sendto(payload, ("127.0.0.1", second.endpoints[0][1]))
        taken: list[bytes] = []
        deadline = time.monotonic() + LOST_S
        while len(taken) < len(payloads):
            assert arrivals.wait(deadline - time.monotonic()), f"only {taken} woke the waiter"
            assert arrivals.take() == {"r2"}
            taken += [datagram.payload for datagram in second.take()]
        assert taken == payloads
        assert first.take() == [] and second.take() == []
        # A malformed datagram is counted, not queued: no wake-up for it.
        sender.sendto(b"\x00\x00\x03", ("127.0.0.1", first.endpoints[0][1]))
        assert not arrivals.wait(0.2)
        assert first.counters.malformed == 1


def test_the_fusion_merge_says_when_its_oldest_item_may_go() -> None:
    """``StageMerge.next_release``: what the fusion loop waits for when nothing arrives.
    A radar process behind the oldest item (here a datagram of the fusion process's own)
    holds it until it stalls; the own inputs (clocked) until the wall clock, less their
    lag, passes it."""
    merge = StageMerge()
    now = 1000.0
    assert merge.next_release(now, LOCAL, 0.2) is None
    datagram = Datagram(b"\x15\x00\x03", 0, 999.5, None, None)
    merge.push_datagram("25_50", datagram)
    merge.note("west", 999_400_000, now - 0.5)  # behind the batch, heard 0.5 s ago
    merge.note("east", 999_600_000, now)  # past it
    merge.note(LOCAL, 999_300_000, now)  # behind it too
    assert merge.next_release(now, LOCAL, 0.2) == pytest.approx(999.5 + 0.2)
    merge.note(LOCAL, 999_800_000, now)
    assert merge.next_release(now, LOCAL, 0.2) == pytest.approx(now - 0.5 + STALLED_S)
    assert list(merge.release(now)) == []
    # Stalled: no longer waited for, the batch goes at once.
    later = now - 0.5 + STALLED_S
    assert merge.next_release(later, LOCAL, 0.2) == later
    assert list(merge.release(later)) == [("25_50", datagram)]
    assert merge.next_release(later, LOCAL, 0.2) is None
