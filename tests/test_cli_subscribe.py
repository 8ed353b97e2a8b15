"""``tracker-service subscribe --json`` in a subprocess against a publisher in this one."""

from __future__ import annotations

import json
import select
import signal
import socket
import subprocess
import sys
import time

from pydantic import BaseModel

from tracker_service.outputs.zenoh_out import ZenohPublisher

TIMEOUT_S = 10.0


class Track(BaseModel):
    number: int
    callsign: str
    status: str


def free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def test_subscribe_prints_picture_then_updates_and_ends_on_sigterm() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    with ZenohPublisher(listen=[endpoint]) as publisher:
        publisher.put_system_track(1, Track(number=1, callsign="AFR1", status="confirmed"))
        publisher.put_system_track(2, Track(number=2, callsign="BAW2", status="coasting"))
        command = [sys.executable, "-m", "tracker_service.cli", "subscribe", "--json"]
        proc = subprocess.Popen(
            [*command, "--connect", endpoint],
            stdout=subprocess.PIPE,
            text=True,
        )
        assert proc.stdout is not None
        try:
            picture = [json.loads(proc.stdout.readline()) for _ in range(2)]
            # Updates reach the subscriber once its subscription has reached us: publish
            # until one is printed.
            deadline = time.monotonic() + TIMEOUT_S
            update = Track(number=3, callsign="DLH3", status="tentative")
            while not select.select([proc.stdout], [], [], 0.05)[0]:
                assert time.monotonic() < deadline, "no update reached the subscriber"
                publisher.put_system_track(3, update)
            assert json.loads(proc.stdout.readline()) == update.model_dump()
        finally:
            proc.send_signal(signal.SIGTERM)
            proc.wait(timeout=TIMEOUT_S)
    assert sorted(doc["callsign"] for doc in picture) == ["AFR1", "BAW2"]
    assert proc.returncode == 0
