"""ZenohPublisher against a real subscriber in another process, over tcp/127.0.0.1."""

from __future__ import annotations

import itertools
import json
import select
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from mcap.reader import make_reader
from pydantic import BaseModel

from tests.test_outputs_updates import (
    NOON,
    PLANE,
    SOURCES,
    _local_rows,
    _plots,
    _system_rows,
)
from tracker_service.outputs.mapping import MessageMapper
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.mcap_sink import McapSink
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_sink import ZenohSink

TIMEOUT_S = 10.0

# The other process: "listen" prints every sample of tracker/** as a JSON line; "get"
# asks the picture (retrying until the link is up) and prints the replies, then exits.
CHILD = r"""
import json, select, sys, time, zenoh
endpoint, action, selector = sys.argv[1:4]
config = zenoh.Config()
config.insert_json5("mode", '"peer"')
config.insert_json5("connect/endpoints", json.dumps([endpoint]))
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)

def show(sample):
    text = sample.payload.to_bytes().decode()
    print(json.dumps({"key": str(sample.key_expr), "kind": str(sample.kind), "payload": text,
                      "encoding": str(sample.encoding)}), flush=True)

if action == "listen":
    subscriber = session.declare_subscriber(selector, show)
    print(json.dumps({"ready": True}), flush=True)
    # Until the test closes stdin, or ends on its own so that a lost sample fails the
    # test rather than hanging it: longer than the test's own bounded waits after "ready"
    # together (the probes up to 10 s, then the puts), which a loaded machine can spend
    # (the fresh-clone CI ran a 10 s bound out while the test still published).
    select.select([sys.stdin], [], [], 60.0)
else:
    deadline = time.monotonic() + 5.0
    replies = []
    while not replies and time.monotonic() < deadline:
        replies = [r.ok for r in session.get(selector, timeout=1.0) if r.ok is not None]
    for sample in replies:
        show(sample)
session.close()
"""


class Track(BaseModel):
    number: int
    status: str
    lat: float


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


@pytest.fixture
def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@pytest.fixture
def publisher(endpoint: str) -> Iterator[ZenohPublisher]:
    with ZenohPublisher(listen=[endpoint]) as pub:
        yield pub


def child(endpoint: str, action: str, selector: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, "-c", CHILD, endpoint, action, selector],
        stdin=subprocess.PIPE,
        stdout=subprocess.PIPE,
        text=True,
    )


def read_line(proc: subprocess.Popen[str]) -> dict[str, Any]:
    assert proc.stdout is not None
    line = proc.stdout.readline()
    assert line, f"the subscriber ended (exit {proc.poll()})"
    doc: dict[str, Any] = json.loads(line)
    return doc


def get_picture(endpoint: str, selector: str) -> dict[str, dict[str, Any]]:
    proc = child(endpoint, "get", selector)
    out, _ = proc.communicate(timeout=TIMEOUT_S)
    assert proc.returncode == 0
    replies = [json.loads(line) for line in out.splitlines()]
    return {reply["key"]: json.loads(reply["payload"]) for reply in replies}


def test_subscriber_in_another_process_receives(publisher: ZenohPublisher, endpoint: str) -> None:
    proc = child(endpoint, "listen", "tracker/**")
    try:
        assert read_line(proc) == {"ready": True}
        # The subscription reaches the publisher some time after it is declared: probe
        # with status messages until one arrives.
        deadline = time.monotonic() + TIMEOUT_S
        assert proc.stdout is not None
        while not select.select([proc.stdout], [], [], 0.05)[0]:
            assert time.monotonic() < deadline, "no probe reached the subscriber"
            publisher.put_status(Track(number=0, status="probe", lat=0.0))
        publisher.put_system_track(7, Track(number=7, status="confirmed", lat=48.5))
        publisher.put_local_track((25, 11), 301, Track(number=301, status="tentative", lat=1))
        publisher.put_bias((25, 11), Track(number=0, status="bias", lat=0.0))
        publisher.put_cat062(b'{"not": "really cat062"}')
        publisher.end_system_track(7, Track(number=7, status="ended", lat=48.6))
        # Probes still in flight arrive before the rest.
        samples = (read_line(proc) for _ in itertools.count())
        got = list(itertools.islice((s for s in samples if s["key"] != "tracker/status"), 6))
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait(timeout=TIMEOUT_S)
    assert [(g["key"], g["kind"]) for g in got] == [
        ("tracker/system_tracks/7", "SampleKind.PUT"),
        ("tracker/local_tracks/25_11/301", "SampleKind.PUT"),
        ("tracker/bias/25_11", "SampleKind.PUT"),
        ("tracker/cat062", "SampleKind.PUT"),
        ("tracker/system_tracks/7", "SampleKind.PUT"),
        ("tracker/system_tracks/7", "SampleKind.DELETE"),
    ]
    assert json.loads(got[0]["payload"]) == {"number": 7, "status": "confirmed", "lat": 48.5}
    assert json.loads(got[4]["payload"])["status"] == "ended"


def test_late_joiner_gets_live_tracks_only(publisher: ZenohPublisher, endpoint: str) -> None:
    for number in (1, 2, 3):
        publisher.put_system_track(number, Track(number=number, status="tentative", lat=1.0))
    publisher.put_system_track(3, Track(number=3, status="confirmed", lat=3.5))
    publisher.end_system_track(2, Track(number=2, status="ended", lat=2.0))
    assert publisher.live_tracks == [1, 3]
    picture = get_picture(endpoint, "tracker/system_tracks/**")
    assert picture == {
        "tracker/system_tracks/1": {"number": 1, "status": "tentative", "lat": 1.0},
        "tracker/system_tracks/3": {"number": 3, "status": "confirmed", "lat": 3.5},
    }
    assert list(get_picture(endpoint, "tracker/system_tracks/3")) == ["tracker/system_tracks/3"]


def test_bad_arguments_refused() -> None:
    with pytest.raises(ValueError, match="prefix"):
        ZenohPublisher("tracker/**")


def test_subscribers_receive_what_the_log_holds(
    publisher: ZenohPublisher, endpoint: str, tmp_path: Path
) -> None:
    """Batches of updates (the batch path's JSON) through the Zenoh and the MCAP sinks:
    a subscriber in another process receives, key by key and in order, the bytes the log
    holds (themselves the models' own JSON: tests/test_outputs_updates.py), as JSON, and
    each track's end followed by its key's deletion."""
    rng = np.random.default_rng(5)
    mapper, zenoh = MessageMapper(PLANE), ZenohSink(publisher)
    # The batches are made and logged before the subscriber starts: its wait for samples
    # is bounded, and the mapper's kernels may take seconds to load on a loaded machine.
    batches = []
    with McapLog(tmp_path) as log:
        sink = McapSink(log)
        for step in range(4):
            t = NOON + 5.0 * step
            plots = _plots(rng, 20, t, 20 * step)
            local = mapper.local_updates("40/2", _local_rows(rng, 12, t))
            system = mapper.system_updates(_system_rows(rng, 20, t, plots), plots, SOURCES)
            sink.local_updates("40/2", local, t)
            sink.system_updates(system, t)
            batches.append((t, local, system))
        ended = mapper.end_all_updates()
        sink.system_updates(ended, t)
    expected = _published(log.files[0])
    proc = child(endpoint, "listen", "tracker/**")
    try:
        assert read_line(proc) == {"ready": True}
        _wait_for_subscriber(publisher, proc)
        for t, local, system in batches:
            zenoh.local_updates("40/2", local, t)
            zenoh.system_updates(system, t)
        zenoh.system_updates(ended, t)
        # Probes still in flight arrive before the rest.
        samples = (read_line(proc) for _ in itertools.count())
        got = list(itertools.islice((s for s in samples if s["key"] != _PROBE), len(expected)))
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait(timeout=TIMEOUT_S)
    assert [(g["key"], g["kind"]) for g in got] == [(key, kind) for key, kind, _ in expected]
    for sample, (_, kind, payload) in zip(got, expected, strict=True):
        if kind == "SampleKind.PUT":
            assert sample["payload"].encode() == payload
            assert sample["encoding"] == "application/json"


_PROBE = "tracker/system_tracks/65535"


def _wait_for_subscriber(publisher: ZenohPublisher, proc: subprocess.Popen[str]) -> None:
    """Probes on a track key (ended: put and deleted) until one reaches the subscriber;
    those still in flight are for the reader to skip."""
    assert proc.stdout is not None
    deadline = time.monotonic() + TIMEOUT_S
    while not select.select([proc.stdout], [], [], 0.05)[0]:
        assert time.monotonic() < deadline, "no probe reached the subscriber"
        publisher.end_system_track(65535, b"{}")


def _published(path: Path) -> list[tuple[str, str, bytes]]:
    """What Zenoh publishes of a log's track messages: (key, kind, JSON), a deletion after
    each system track's end."""
    out = []
    with path.open("rb") as stream:
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            doc = json.loads(message.data)
            if channel.topic == "/system_tracks":
                key = f"tracker/system_tracks/{doc['number']}"
            elif channel.topic.startswith("/local_tracks/"):
                key = f"tracker/local_tracks/{channel.topic.rsplit('/', 1)[1]}/{doc['number']}"
            else:
                continue
            out.append((key, "SampleKind.PUT", message.data))
            if channel.topic == "/system_tracks" and doc["status"] == "ended":
                out.append((key, "SampleKind.DELETE", b""))
    return out
