"""``replay --workers N``: the radar stages in worker processes over real Zenoh sessions
(loopback), fusion and the outputs in the main process: the same system tracks as one
process, and a worker killed with SIGKILL stops the replay with a one-line error."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from tracker_service.cli import main
from tracker_service.outputs.mcap_log import read_log_messages

SCENARIO = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "three_sites.toml"


def endpoint() -> str:
    """A free loopback endpoint for the outputs' session (explicit: no scouting)."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{probe.getsockname()[1]}"


def simulate(out: Path, duration: float) -> Path:
    assert main(["simulate", str(SCENARIO), "-o", str(out), "--duration", str(duration)]) == 0
    return out


def logged(directory: Path, prefix: str) -> list[tuple[str, dict[str, Any]]]:
    return [
        (m.topic, m.data)
        for path in sorted(directory.glob("*.mcap"))
        for m in read_log_messages(path)
        if m.topic.startswith(prefix)
    ]


def replay(recording: Path, log_dir: Path, *extra: str) -> int:
    return main(
        [
            "replay",
            str(recording),
            "--speed",
            "max",
            "--mcap-dir",
            str(log_dir),
            "--zenoh-listen",
            endpoint(),
            *extra,
        ]
    )


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate(tmp_path_factory.mktemp("sim") / "three_sites.mcap", 30.0)


@pytest.fixture(scope="module")
def one_process(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The log of the replay in one process."""
    log_dir = tmp_path_factory.mktemp("one")
    assert replay(recording, log_dir) == 0
    return log_dir


def test_two_workers_publish_exactly_the_system_tracks_of_one_process(
    recording: Path, one_process: Path, tmp_path: Path
) -> None:
    one, two = one_process, tmp_path / "two"
    assert replay(recording, two, "--workers", "2") == 0
    tracks = logged(one, "/system_tracks")
    assert len(tracks) > 200
    assert len({data["number"] for _, data in tracks}) > 10
    # The same messages, numbers and values; and so for local tracks, bias and status.
    assert logged(two, "/system_tracks") == tracks
    for prefix in ("/local_tracks", "/bias", "/status"):
        assert logged(two, prefix) == logged(one, prefix), prefix


def test_three_workers_for_three_radars_too(
    recording: Path, one_process: Path, tmp_path: Path
) -> None:
    three = tmp_path / "three"
    assert replay(recording, three, "--workers", "3") == 0
    assert logged(three, "/system_tracks") == logged(one_process, "/system_tracks")


def _workers_of(pid: int) -> list[int]:
    out = subprocess.run(
        ["ps", "-ww", "-o", "pid=,args=", "--ppid", str(pid)],
        capture_output=True,
        text=True,
        check=False,
    ).stdout
    return [int(line.split()[0]) for line in out.splitlines() if "spawn_main" in line]


def test_a_worker_killed_stops_the_replay_with_a_clear_error(
    recording: Path, tmp_path: Path
) -> None:
    """A replay must give the one-process picture or none: a dead worker is an error,
    not a gap (the live roles coast its radars instead: test_distribution_roles)."""
    command = [
        sys.executable,
        "-m",
        "tracker_service.cli",
        "replay",
        str(recording),
        "--speed",
        "2",
        "--workers",
        "2",
        "--zenoh-listen",
        endpoint(),
    ]
    # A session of its own: a replay that fails to stop is killed with its workers, so
    # that no orphan slows the tests after this one.
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, start_new_session=True)
    stderr: list[str] = []
    reader = threading.Thread(target=lambda: stderr.extend(process.stderr or []), daemon=True)
    reader.start()
    deadline = time.monotonic() + 30
    workers: list[int] = []
    while time.monotonic() < deadline and len(workers) < 2 and process.poll() is None:
        workers = _workers_of(process.pid)
        time.sleep(0.2)
    assert len(workers) == 2, f"the worker processes did not start: {''.join(stderr)}"
    time.sleep(3.0)  # well into the replay (at twice real time, 15 s long)
    os.kill(workers[0], signal.SIGKILL)
    try:
        code = process.wait(timeout=60)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGUSR1)  # its stacks into stderr (tracker_service.cli)
        time.sleep(2.0)
        os.killpg(process.pid, signal.SIGKILL)
        reader.join(timeout=5)
        raise AssertionError(f"the replay did not stop: {''.join(stderr)}") from None
    assert code == 1
    reader.join(timeout=5)
    text = "".join(stderr)
    assert "radar worker" in text and "exited with code -9" in text, text
