"""``replay --workers N``: the radar stages in worker processes over real Zenoh sessions
(loopback), the central stage in the main process, the outputs in a process of their own
(``--output-process``, the default with workers): the same messages as one process; a
worker or the output process killed with SIGKILL stops the replay with a one-line error;
and a main process slower than its workers holds no more than a window of their results."""

from __future__ import annotations

import contextlib
import multiprocessing
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
from tracker_service.distribution import RemoteRadarStages
from tracker_service.inputs.udp import block_chain_error
from tracker_service.outputs.mcap_log import read_log_messages
from tracker_service.service.replay import open_replay

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


@pytest.mark.parametrize(
    "layout",
    [("--workers", "2"), ("--workers", "2", "--no-output-process"), ("--output-process",)],
    ids=["workers and output process", "workers alone", "output process alone"],
)
def test_the_processes_publish_exactly_the_messages_of_one_process(
    recording: Path, one_process: Path, tmp_path: Path, layout: tuple[str, ...]
) -> None:
    one, apart = one_process, tmp_path / "apart"
    assert replay(recording, apart, *layout) == 0
    tracks = logged(one, "/system_tracks")
    assert len(tracks) > 200
    assert len({data["number"] for _, data in tracks}) > 10
    # The same messages, numbers and values; and so for every other topic (local tracks,
    # bias, status with its input counters, CAT062, the Foxglove map, the datagrams).
    assert logged(apart, "/system_tracks") == tracks
    topics = {topic for topic, _ in logged(one, "/")}
    kinds = {topic.split("/")[1] for topic in topics}
    assert {"status", "bias", "cat062", "foxglove", "datagrams"} <= kinds, kinds
    for topic in topics:
        assert logged(apart, topic) == logged(one, topic), topic


def test_three_workers_for_three_radars_too(
    recording: Path, one_process: Path, tmp_path: Path
) -> None:
    three = tmp_path / "three"
    assert replay(recording, three, "--workers", "3") == 0
    assert logged(three, "/system_tracks") == logged(one_process, "/system_tracks")


def _children_of(pid: int) -> list[int]:
    """The processes ``pid`` spawned (multiprocessing's), its resource tracker aside."""
    out = subprocess.run(
        ["ps", "-ww", "-o", "pid=,args=", "--ppid", str(pid)],
        capture_output=True,
        text=True,
        check=False,
    ).stdout
    return [int(line.split()[0]) for line in out.splitlines() if "spawn_main" in line]


def _holds_file_in(pid: int, directory: Path) -> bool:
    """Whether ``pid`` has a file of ``directory`` open: the output process its log."""
    with contextlib.suppress(OSError):
        for fd in Path(f"/proc/{pid}/fd").iterdir():
            with contextlib.suppress(OSError):
                if Path(os.readlink(fd)).parent == directory:
                    return True
    return False


@pytest.mark.parametrize("victim", ["radar worker", "output process"])
def test_a_process_killed_stops_the_replay_with_a_clear_error(
    recording: Path, tmp_path: Path, victim: str
) -> None:
    """A replay must give the one-process picture or none: a dead worker is an error,
    not a gap (the live roles coast its radars instead: test_distribution_roles), and a
    dead output process is one too, not restarted as the daemon's is: a new one would
    start a second log without the picture of the first (every track "first" again)."""
    log_dir = tmp_path / "log"
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
        "--mcap-dir",
        str(log_dir),
    ]
    # A session of its own: a replay that fails to stop is killed with its workers, so
    # that no orphan slows the tests after this one.
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True, start_new_session=True)
    stderr: list[str] = []
    reader = threading.Thread(target=lambda: stderr.extend(process.stderr or []), daemon=True)
    reader.start()
    deadline = time.monotonic() + 30
    outputs: list[int] = []
    children: list[int] = []
    while time.monotonic() < deadline and not outputs and process.poll() is None:
        children = _children_of(process.pid)
        outputs = [child for child in children if _holds_file_in(child, log_dir.resolve())]
        time.sleep(0.2)
    workers = [child for child in children if child not in outputs]
    assert len(outputs) == 1 and len(workers) == 2, f"not started: {''.join(stderr)}"
    time.sleep(3.0)  # well into the replay (at twice real time, 15 s long)
    os.kill((workers if victim == "radar worker" else outputs)[0], signal.SIGKILL)
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
    assert f"{victim} " in text and "exited with code -9" in text, text
    assert len(text.strip().splitlines()[-1]) < 200  # one line says it, no traceback
    assert "Traceback" not in text, text


def _wait_for_full_windows(stages: RemoteRadarStages) -> None:
    """Until each worker has sent its window of results (at most 30 s: numba may compile
    on a cold cache), nothing consumed."""
    deadline = time.monotonic() + 30.0
    while min(stages.backlog) < stages.window and time.monotonic() < deadline:
        time.sleep(0.05)


def test_a_slow_main_process_holds_no_more_than_a_window_of_each_workers_results(
    recording: Path,
) -> None:
    """Flow control: a worker stops ``window`` results ahead of what the main process has
    consumed of its results, so that a main process slower than its workers (the central
    stage and the outputs are, on a long recording) holds a bounded number of results,
    not the rest of the recording. Driven here from ``RemoteRadarStages`` itself: nothing
    consumed at first, then every result taken slowly, then the rest at once, in input
    order across the two workers (which must not deadlock at any window)."""
    source = open_replay(recording)
    inputs = [
        (datagram.payload, datagram.time)
        for _, datagram in source.datagrams
        if datagram.time is not None and block_chain_error(datagram.payload) is None
    ]
    window = 16
    assert len(inputs) > 20 * window
    # A deadlock would leave feed() waiting for ever on live workers: killed after a
    # minute, they make it raise WorkerFailed instead.
    watchdog = threading.Timer(
        60.0, lambda: [child.kill() for child in multiprocessing.active_children()]
    )
    watchdog.start()
    try:
        with RemoteRadarStages(recording, source.config, None, 2, window=window) as stages:
            # Nothing consumed: each worker stops at the window (without flow control,
            # each ran through its whole share of the recording into this queue).
            _wait_for_full_windows(stages)
            time.sleep(1.0)  # time to go further, were they not held
            assert stages.backlog == [window, window]
            peak = [0, 0]
            for order, (payload, received) in enumerate(inputs):
                stages.feed(payload, received, order)
                if order < 8 * window:
                    time.sleep(0.002)  # the slow central stage: the workers wait
                peak = [max(p, b) for p, b in zip(peak, stages.backlog, strict=True)]
            # At most the window, and the worker's end of input beyond it.
            assert max(peak) <= window + 1, peak
            assert stages.stats.datagrams == len(inputs)
    finally:
        watchdog.cancel()


def test_workers_held_by_their_window_end_at_once_when_the_replay_stops(
    recording: Path,
) -> None:
    """A replay stopped early (^C) leaves its workers waiting for credits that will not
    come: they end as soon as the main process says it is done, each with its CPU
    seconds reported, rather than killed once the main process tires of waiting."""
    source = open_replay(recording)
    with RemoteRadarStages(recording, source.config, None, 2, window=16) as stages:
        _wait_for_full_windows(stages)
        assert stages.backlog == [16, 16]
        closing = time.monotonic()
    # Killed, a worker would not report its CPU seconds, and the main process kills a
    # worker after waiting 5 s for it.
    assert min(stages.cpu_s) > 0.0, stages.cpu_s
    assert time.monotonic() - closing < 5.0
