"""``tracker-service run`` (the daemon, its outputs in their own process) logging onto a
2 MiB tmpfs that fills up and is freed again while real UDP feeds arrive on 127.0.0.1: a
Zenoh subscriber in another process keeps receiving the system tracks, the published
status names the full disk, and the log goes on in a new file."""

from __future__ import annotations

import datetime as dt
import signal
import subprocess
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tests.test_outputs_isolation import fill
from tests.test_service_replay import ZenohChild, endpoint, simulate
from tests.test_service_run import SPEED, DaemonProcess, Feeds
from tracker_service.simulator.recording import read_recording


def test_run_on_a_disk_that_fills_up(tmp_path: Path) -> None:
    start = dt.datetime.now(dt.UTC).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    recording = simulate(tmp_path / "live.mcap", 40.0, start=start)
    feeds = Feeds(tmp_path)
    feeds.log_dir.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", str(feeds.log_dir)],
        capture_output=True,
        text=True,
        check=False,
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs (root needed): {mounted.stderr.strip()}")
    try:
        zenoh = endpoint()
        process = DaemonProcess(feeds, zenoh, tmp_path / "health")
        try:
            watcher = ZenohChild("connect", zenoh, "tracker/**", tmp_path / "watcher.jsonl")
            time.sleep(0.5)
            stop = threading.Event()
            sender = threading.Thread(target=feeds.send, args=(recording, stop))
            sent_at = time.time()
            sender.start()
            time.sleep(2.0)
            filler = fill(feeds.log_dir)
            full_from = time.time()
            time.sleep(6.0)
            full_to = time.time()
            filler.unlink()
            sender.join()
            assert process.stop(signal.SIGTERM) == 0, "\n".join(process.lines)
            samples = watcher.samples()
        finally:
            if process.process.poll() is None:
                process.process.kill()
                process.process.wait()
        files = sorted(feeds.log_dir.glob("*.mcap"))
        counts = []
        for path in files:
            with path.open("rb") as stream:
                counts.append(sum(1 for _ in make_reader(stream).iter_messages()))
    finally:
        subprocess.run(["umount", "-l", str(feeds.log_dir)], check=False)

    tracks = [
        s.json() for s in samples if s.key.startswith("tracker/system_tracks/") and s.kind == "PUT"
    ]
    # Track times are the recording's, sent SPEED times faster than they passed.
    first = next(read_recording(recording).datagrams()).time

    def sent(t: float) -> float:
        return sent_at + (t - first) / SPEED

    during = [t for t in tracks if full_from + 1.0 <= sent(t["time"]) <= full_to]
    assert len(during) > 0.4 * len(tracks), (len(tracks), len(during))
    statuses = [s.json() for s in samples if s.key == "tracker/status"]
    full = [s for s in statuses if any("output mcap: disk full since" in r for r in s["reasons"])]
    assert full and all(s["health"] == "degraded" for s in full)
    assert not any("output mcap" in r for r in statuses[-1]["reasons"]), statuses[-1]
    # The file cut by the full disk and the one after it: complete MCAP, read back.
    assert len(files) >= 2 and all(counts), (files, counts)
    lines = [line for line in process.lines if "output mcap" in line]
    assert 1 <= len(lines) <= 10, lines
    assert not any("Traceback" in line for line in process.lines), "\n".join(process.lines)
