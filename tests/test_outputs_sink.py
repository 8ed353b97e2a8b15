"""The isolation of one output (``IsolatedSink``): its state, the backoff of its retries,
the status line, and what an output that holds a picture is sent once it works again. The
destination here is a list that can be made to fail; the real outputs failing for real (a
full tmpfs, a closed Zenoh session) are in test_outputs_isolation.py."""

from __future__ import annotations

import errno
import logging
import math
import threading
from pathlib import Path

import pytest

from asterix.containers import Datagram
from tracker_service.outputs.foxglove_scene import TRACKS_TOPIC
from tracker_service.outputs.foxglove_sink import with_map_channels
from tracker_service.outputs.mcap_log import McapLog, read_log_messages
from tracker_service.outputs.mcap_sink import McapSink
from tracker_service.outputs.messages import (
    BiasMessage,
    LocalTrackMessage,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.sink import Backoff, IsolatedSink, QueuedSink, describe_failure


class Destination:
    """Keeps the system tracks it is sent, in order; raises while ``down``."""

    name = "picture"
    keeps_datagrams = True

    def __init__(self, resends_tracks: bool) -> None:
        self.resends_tracks = resends_tracks
        self.down = False
        self.received: list[tuple[int, str, float]] = []

    def _check(self) -> None:
        if self.down:
            raise OSError(errno.ENETUNREACH, "Network is unreachable")

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        self._check()

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self._check()
        self.received.append((message.number, message.status, message.time))

    def local(self, message: LocalTrackMessage, payload: bytes, time: float) -> None:
        self._check()

    def asterix(self, data: bytes, time: float) -> None:
        self._check()

    def bias(self, message: BiasMessage, time: float) -> None:
        self._check()

    def status(self, message: StatusMessage, time: float) -> None:
        self._check()

    def close(self) -> None:
        pass


def track(number: int, time: float, status: str = "confirmed") -> SystemTrackMessage:
    return SystemTrackMessage.from_state(
        time=time,
        x_m=0.0,
        y_m=0.0,
        vx_mps=100.0,
        vy_mps=0.0,
        covariance=[[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
        number=number,
        lat=45.0,
        lon=16.0,
        sources=[],
        status=status,
    )


class Clock:
    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


def test_backoff_doubles_to_its_longest() -> None:
    backoff = Backoff(1.0, 30.0)
    assert [backoff.delay(n) for n in range(1, 8)] == [1, 2, 4, 8, 16, 30, 30]


def test_failure_reasons_read_as_an_operator_would() -> None:
    assert describe_failure(OSError(errno.ENOSPC, "No space left on device")) == "disk full"
    assert describe_failure(RuntimeError("session closed\nmore")) == "RuntimeError: session closed"


@pytest.mark.parametrize("resends", [True, False])
def test_an_outage_is_reported_retried_and_what_was_missed_resent(
    resends: bool, caplog: pytest.LogCaptureFixture
) -> None:
    clock = Clock()
    destination = Destination(resends)
    sink = IsolatedSink(destination, Backoff(1.0, 4.0), clock)
    sink.system(track(1, 10.0), b"", 10.0)
    sink.system(track(2, 10.0), b"", 10.0)
    destination.down = True
    caplog.set_level(logging.INFO, logger="tracker_service.outputs.sink")
    for k in range(100):
        clock.now += 0.1
        sink.system(track(1, 11.0 + k), b"", 11.0 + k)
    sink.system(track(2, 111.0, "ended"), b"", 111.0)
    state = sink.state
    assert not state.ok and state.failing_since == 11.0
    assert state.reason == "Network is unreachable"
    assert state.dropped == 101 and state.outages == 1
    # The first call at 0.1 s, then retries 1, 2 and 4 s later: 10 s of calls, 4 attempts.
    assert state.failures == 4
    line = state.reason_line()
    assert line is not None and line.startswith("output picture: Network is unreachable since ")
    # One line at the start, then one per rate-limit interval at most: not one per call.
    assert len(caplog.records) <= 3
    destination.down = False
    clock.now += 5.0
    sink.system(track(3, 112.0), b"", 112.0)
    assert state.ok and state.reason_line() is None
    after = destination.received[2:]
    if resends:
        # The new track, then what was missed: the latest of track 1, the end of track 2.
        assert after == [(3, "confirmed", 112.0), (1, "confirmed", 110.0), (2, "ended", 111.0)]
    else:
        assert after == [(3, "confirmed", 112.0)]
    assert caplog.records[-1].getMessage().startswith("output picture: working again")


class Publisher(Destination):
    """A destination like Zenoh's: ``datagram`` does nothing, so it cannot fail."""

    keeps_datagrams = False

    def datagram(self, input_name: str, datagram: Datagram) -> None:
        pass


def test_only_a_call_that_carries_a_message_ends_an_outage() -> None:
    clock = Clock()
    destination = Publisher(resends_tracks=True)
    sink = IsolatedSink(destination, Backoff(1.0, 4.0), clock)
    destination.down = True
    sink.system(track(1, 10.0), b"", 10.0)
    # The backoff over: a datagram (nothing for this output) and an empty batch come first.
    clock.now += 2.0
    sink.datagram("radar", Datagram(b"\x30\x00\x03", 0, 11.0, None, None))
    sink.system_updates([], 11.0)
    state = sink.state
    assert not state.ok and state.failing_since == 10.0 and state.failures == 1
    # The next message is the retry: it fails, the outage goes on (one outage, not two).
    sink.system(track(1, 12.0), b"", 12.0)
    assert not state.ok and state.failures == 2 and state.outages == 1
    destination.down = False
    clock.now += 5.0
    sink.system(track(2, 13.0), b"", 13.0)
    assert state.ok and [n for n, _, _ in destination.received] == [2, 1]


def test_a_message_the_output_refuses_is_not_an_outage(tmp_path: Path) -> None:
    # A real log: a message whose time is not finite is refused by the log, alone.
    with McapLog(tmp_path) as log:
        sink = IsolatedSink(McapSink(log))
        bad = track(1, 10.0)
        sink.system(bad, bad.model_dump_json().encode(), math.nan)
        good = track(2, 11.0)
        sink.system(good, good.model_dump_json().encode(), 11.0)
    state = sink.state
    assert state.ok and state.refused == 1 and state.dropped == 1 and state.outages == 0
    logged = [
        m.data["number"] for m in read_log_messages(log.files[0]) if m.topic == "/system_tracks"
    ]
    assert logged == [2]


def test_a_position_that_is_not_finite_is_refused_by_the_map_alone(tmp_path: Path) -> None:
    # The log with its map channels: the JSON of /system_tracks goes in, the map refuses a
    # fix it cannot write as JSON (NaN), counted once, not an outage; the next is whole.
    with McapLog(tmp_path) as log:
        sink = IsolatedSink(with_map_channels(McapSink(log), log, []))
        bad = track(1, 10.0).model_copy(update={"lat": math.nan})
        sink.system(bad, bad.model_dump_json().encode(), 10.0)
        good = track(2, 11.0)
        sink.system(good, good.model_dump_json().encode(), 11.0)
    state = sink.state
    assert state.ok and state.refused == 1 and state.dropped == 1 and state.outages == 0
    messages = list(read_log_messages(log.files[0]))
    assert [m.data["number"] for m in messages if m.topic == "/system_tracks"] == [1, 2]
    fixes = [m.data for m in messages if m.topic == TRACKS_TOPIC]
    assert len(fixes) == 1 and math.isfinite(fixes[0]["latitude"])


class Hung(Destination):
    """A destination whose calls hang until ``release`` is set (a stalled disk)."""

    def __init__(self) -> None:
        super().__init__(resends_tracks=False)
        self.entered = threading.Event()
        self.release = threading.Event()

    def system(self, message: SystemTrackMessage, payload: bytes, time: float) -> None:
        self.entered.set()
        self.release.wait(30.0)
        super().system(message, payload, time)


def test_a_hung_output_holds_up_none_of_the_others(tmp_path: Path) -> None:
    hung = Hung()
    slow = QueuedSink(IsolatedSink(hung), capacity=10)
    with McapLog(tmp_path) as log:
        logged = QueuedSink(IsolatedSink(McapSink(log)), capacity=10)
        for k in range(100):
            message = track(k, 10.0 + k)
            payload = message.model_dump_json().encode()
            for sink in (slow, logged):
                sink.system(message, payload, 10.0 + k)
            if k == 0:
                assert hung.entered.wait(10.0)
            # The log keeps up (its thread writes while this one queues).
            assert logged.drain()
        logged.close()
    numbers = [
        m.data["number"] for m in read_log_messages(log.files[0]) if m.topic == "/system_tracks"
    ]
    assert numbers == list(range(100))
    assert logged.state.ok and logged.state.dropped == 0
    # The hung one: one call in progress, 10 queued, the rest dropped and counted.
    state = slow.state
    assert not state.ok and state.overflowed == 89 and state.full_since == 21.0
    line = state.reason_line()
    assert line is not None and line.startswith("output picture: too slow since ")
    hung.release.set()
    assert slow.drain()
    slow.close()
    assert len(hung.received) == 11
