"""``tracker-service run`` as a daemon in another process, fed real UDP datagrams on
127.0.0.1 (the simulator's recording, both LANs, paced), watched by Zenoh subscribers in
other processes, stopped with SIGTERM and SIGKILL; its MCAP log read back."""

from __future__ import annotations

import datetime as dt
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.test_service_replay import (
    REPO,
    Sample,
    ZenohChild,
    endpoint,
    free_port,
    logged,
    replay,
    simulate,
    system_tracks,
)
from tracker_service.cli import main
from tracker_service.simulator.recording import read_recording

SPEED = 4.0
STARTUP_S = 60.0  # a daemon and its output process, on a machine busy with other tests
MALFORMED = b"\x30\x00\x02garbage"


class Feeds:
    """Unicast UDP ports on 127.0.0.1 for each feed and LAN, and the config that uses them."""

    def __init__(self, tmp: Path) -> None:
        self.ports = {
            key: free_port(socket.SOCK_DGRAM)
            for key in [
                ("25/11", "A"),
                ("25/11", "B"),
                ("25/12", "A"),
                ("25/13", "A"),
                ("25/50", "A"),
            ]
        }
        text = (REPO / "config" / "example.toml").read_text(encoding="utf-8")
        inputs = iter(
            [
                f'input = {{ address = "127.0.0.1", port = {self.ports[("25/11", "A")]}, '
                f'second_lan = {{ address = "127.0.0.1", port = {self.ports[("25/11", "B")]} }} }}',
                f'input = {{ address = "127.0.0.1", port = {self.ports[("25/12", "A")]} }}',
                f'input = {{ address = "127.0.0.1", port = {self.ports[("25/13", "A")]} }}',
                f'input = {{ address = "127.0.0.1", port = {self.ports[("25/50", "A")]} }}',
            ]
        )
        text = re.sub(r"(?m)^input = .*$", lambda _: next(inputs), text)
        text = re.sub(r"(?m)^holding_window_s = .*$", "holding_window_s = 0.2", text)
        self.log_dir = tmp / "logs"
        text = re.sub(r"(?m)^directory = .*$", f'directory = "{self.log_dir}"', text)
        self.config = tmp / "tracker.toml"
        self.config.write_text(text, encoding="utf-8")

    def send(self, recording: Path, stop: threading.Event, malformed_after_s: float = 1.0) -> int:
        """The recording's datagrams (both LANs) paced at SPEED; one malformed datagram on
        Buchtuv kopec's port. Returns how many were sent."""
        sent = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            wall0 = time.monotonic()
            first: float | None = None
            malformed_sent = False
            for datagram in read_recording(recording).datagrams():
                first = datagram.time if first is None else first
                due = wall0 + (datagram.time - first) / SPEED
                if stop.wait(max(due - time.monotonic(), 0.0)):
                    break
                if not malformed_sent and time.monotonic() - wall0 > malformed_after_s:
                    sock.sendto(MALFORMED, ("127.0.0.1", self.ports[("25/12", "A")]))
                    malformed_sent = True
                sock.sendto(
                    datagram.payload, ("127.0.0.1", self.ports[(datagram.source, datagram.lan)])
                )
                sent += 1
        return sent


class DaemonProcess:
    def __init__(self, feeds: Feeds, zenoh: str, health: Path) -> None:
        self.lines: list[str] = []
        self.process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "tracker_service.cli",
                "run",
                "--config",
                str(feeds.config),
                "--zenoh-listen",
                zenoh,
                "--health-file",
                str(health),
            ],
            stderr=subprocess.PIPE,
            text=True,
        )
        self._ready = threading.Event()
        threading.Thread(target=self._drain, daemon=True).start()
        if not self._ready.wait(STARTUP_S):
            # Its stacks first (tracker_service.cli registers SIGUSR1), to say where it hangs;
            # then not left running behind the failed test (sockets, output process).
            self.process.send_signal(signal.SIGUSR1)
            time.sleep(2.0)
            self.process.terminate()
            self.process.wait(timeout=30)
            raise AssertionError("\n".join(self.lines) or f"not ready within {STARTUP_S} s")

    def _drain(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.lines.append(line.rstrip())
            if "running: publishing" in line:
                self._ready.set()

    def stop(self, signum: int) -> int:
        self.process.send_signal(signum)
        return self.process.wait(timeout=30)


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    # Starting now: the daemon stamps reception times with the wall clock, and plots take
    # their day from them.
    start = dt.datetime.now(dt.UTC).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    return simulate(tmp_path / "live.mcap", 40.0, start=start)


@pytest.fixture
def daemon(tmp_path: Path) -> Iterator[tuple[Feeds, DaemonProcess, str]]:
    feeds = Feeds(tmp_path)
    zenoh = endpoint()
    process = DaemonProcess(feeds, zenoh, tmp_path / "health")
    try:
        yield feeds, process, zenoh
    finally:
        if process.process.poll() is None:
            process.process.kill()
            process.process.wait()


def test_run_tracks_live_feeds_and_stops_cleanly(
    daemon: tuple[Feeds, DaemonProcess, str], recording: Path, tmp_path: Path
) -> None:
    feeds, process, zenoh = daemon
    watcher = ZenohChild("connect", zenoh, "tracker/**", tmp_path / "watcher.jsonl")
    time.sleep(0.5)
    assert main(["health", "--file", str(tmp_path / "health")]) == 0
    sent = feeds.send(recording, threading.Event())
    time.sleep(0.5)
    # A subscriber that joins now gets the picture from the queryable.
    late = ZenohChild("get", zenoh, "tracker/system_tracks/**", tmp_path / "late.jsonl")
    picture = late.samples()
    assert len(picture) >= 10
    assert all(s.kind == "PUT" and s.json()["status"] != "ended" for s in picture)

    assert process.stop(signal.SIGTERM) == 0, "\n".join(process.lines)
    samples = watcher.samples()
    by_key: dict[str, list[Sample]] = defaultdict(list)
    for sample in samples:
        if sample.key.startswith("tracker/system_tracks/"):
            by_key[sample.key].append(sample)
    assert len(by_key) >= 10
    # SIGTERM ended every track: its "ended" message, then the delete.
    for key, track in by_key.items():
        assert [s.kind for s in track[-2:]] == ["PUT", "DELETE"], key
        assert track[-2].json()["status"] == "ended", key
    assert {s.key for s in picture} <= set(by_key)

    # The log was closed cleanly (summary and footer), and holds what came in.
    files = sorted(feeds.log_dir.glob("*.mcap"))
    assert files
    with files[-1].open("rb") as stream:
        assert make_reader(stream).get_summary() is not None
    messages = logged(feeds.log_dir)
    datagrams = [m for m in messages if m.topic.startswith("/datagrams/")]
    status = [m.data for m in messages if m.topic == "/status"][-1]
    radars = {r["radar"]: r for r in status["radars"]}
    duplicates = radars["25/11"]["duplicates"]
    # Every datagram is either logged or a counted duplicate of LAN B.
    assert duplicates > 50
    assert len(datagrams) + duplicates == sent
    assert radars["25/12"]["decode_errors"] == 1
    assert all(r["drops"] == 0 for r in radars.values())

    # The log replays to the same system tracks.
    replay(feeds.log_dir, tmp_path / "replayed")
    assert system_tracks(tmp_path / "replayed") == system_tracks(feeds.log_dir)


def test_sigkill_leaves_a_readable_log(
    daemon: tuple[Feeds, DaemonProcess, str], recording: Path
) -> None:
    feeds, process, _ = daemon
    stop = threading.Event()
    sender = threading.Thread(target=feeds.send, args=(recording, stop))
    sender.start()
    try:
        time.sleep(4.0)
        assert process.stop(signal.SIGKILL) == -signal.SIGKILL
    finally:
        stop.set()
        sender.join()
    messages = logged(feeds.log_dir)
    datagrams = [m for m in messages if m.topic.startswith("/datagrams/")]
    # Chunks are written out at least every second: little is lost.
    assert len(datagrams) > 50
