"""A process loop's busy share (``tracker_service.loop_load``): the wall clock less its
waits, and the share between two readings as the status shows it; the waits as the live
loops' ``Arrivals`` count them, with a real thread's wake-up."""

from __future__ import annotations

import threading
import time

import pytest

from tracker_service.inputs.arrivals import Arrivals
from tracker_service.loop_load import LoadShares, LoopLoad, LoopTotals


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_a_loop_is_busy_the_time_it_does_not_wait() -> None:
    clock = Clock()
    load = LoopLoad(clock)
    clock.now += 2.0
    load.waited(0.5)
    assert load.totals() == LoopTotals(2.0, 1.5)
    clock.now += 1.0
    load.waited(1.0)
    assert load.totals() == LoopTotals(3.0, 1.5)


def test_the_status_shows_each_loop_share_since_its_last_totals() -> None:
    shares = LoadShares()
    # The first totals of each are a base: no share yet.
    assert shares.shares({"core": LoopTotals(10.0, 4.0), "outputs": LoopTotals(9.0, 1.0)}) == {}
    first = shares.shares({"core": LoopTotals(15.0, 8.0), "outputs": LoopTotals(14.0, 1.5)})
    assert first == {"core": pytest.approx(0.8), "outputs": pytest.approx(0.1)}
    # A radar process whose heartbeats did not come since: none, until they do; its
    # share is then over the whole time since its last totals.
    second = shares.shares({"core": LoopTotals(20.0, 9.0), "radar a": LoopTotals(5.0, 1.0)})
    assert second == {"core": pytest.approx(0.2)}
    assert shares.shares({"radar a": LoopTotals(5.0, 1.0)}) == {}
    assert shares.shares({"radar a": LoopTotals(10.0, 4.0)}) == {"radar a": pytest.approx(0.6)}
    # Restarted (its totals from zero): a new base, not a negative share.
    assert shares.shares({"radar a": LoopTotals(1.0, 0.9)}) == {}
    assert shares.shares({"radar a": LoopTotals(3.0, 1.4)}) == {"radar a": pytest.approx(0.25)}


def test_the_waits_of_a_live_loop_are_counted_until_its_wake_up() -> None:
    clock_waits: list[float] = []
    arrivals = Arrivals(clock_waits.append)
    assert arrivals.wait(0.05) is False  # nothing comes: the whole timeout
    waker = threading.Timer(0.1, arrivals.notify, args=("25_11",))
    waker.start()
    began = time.monotonic()
    assert arrivals.wait(5.0) is True  # woken by the input, long before the timeout
    woke = time.monotonic() - began
    waker.join()
    assert arrivals.take() == {"25_11"}
    assert clock_waits[0] == pytest.approx(0.05, abs=0.04)
    assert 0.09 <= clock_waits[1] <= woke
