"""Issue 11 finding 6: SIGTERM never deadlocks the daemon.

The handler used to call ``Event.set()`` while the main thread could be inside
``Event.wait()`` holding the same lock. Real processes, real signals at random moments:
first the stop request alone under a loop that waits as the daemon does (where the
deadlock showed in 8 of 20 runs), then real daemons fed datagrams."""

from __future__ import annotations

import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.fault_tools import REPO, DaemonProcess, plot_block, send, write_config

EXIT_S = 10.0
"""Bound on the time from SIGTERM to the stop request's return."""
DAEMON_EXIT_S = 20.0
"""Bound on the time from SIGTERM to a daemon's exit: the output process may still be
starting (seconds on a loaded machine), then at most ``daemon.STOP_DRAIN_S`` of backlog,
the tracks ended and the log closed."""

ROUNDS = 24
# The stop request the commands use, entered again and again, each time in a loop that
# spends nearly all its time inside wait(): where a handler taking the wait's lock
# deadlocked (8 of 20 runs).
WAITER = r"""
import sys
from tracker_service.service.command import stop_on_signals
for _ in range(int(sys.argv[1])):
    with stop_on_signals() as stop:
        print("ready", flush=True)
        while not stop.is_set():
            stop.wait(0)
    print("stopped", flush=True)
"""


def test_sigterm_at_random_moments_never_hangs_the_stop_request() -> None:
    rng = random.Random(7)
    process = subprocess.Popen(
        [sys.executable, "-c", WAITER, str(ROUNDS)],
        stdout=subprocess.PIPE,
        text=True,
        cwd=REPO,
    )
    assert process.stdout is not None
    lines = process.stdout
    try:
        for round_ in range(ROUNDS):
            assert lines.readline().strip() == "ready"
            time.sleep(rng.uniform(0.0, 0.05))
            for _ in range(rng.randint(1, 3)):
                process.send_signal(signal.SIGTERM)
                time.sleep(rng.uniform(0.0, 0.002))
            answer: list[str] = []
            reader = threading.Thread(target=lambda a=answer: a.append(lines.readline()))
            reader.start()
            reader.join(EXIT_S)
            assert answer and answer[0].strip() == "stopped", f"round {round_}: hung"
        assert process.wait(timeout=EXIT_S) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()


def _daemon_run(directory: Path, seed: int) -> tuple[int | None, float, str]:
    """A daemon fed datagrams, SIGTERMed 1-4 times at a random moment: (exit code, seconds
    from the first signal to the exit, its log)."""
    rng = random.Random(seed)
    config, ports = write_config(directory, log=seed % 2 == 0)
    # Waits only for the inputs: the signal may come while the output process starts,
    # or while datagrams are processed.
    daemon = DaemonProcess(config, directory / "health", wait="listening on")
    stop = threading.Event()

    def feed() -> None:
        n = 0
        while not stop.is_set():
            send(ports["25/12"], [plot_block(25, 12, 36000.0 + n, 30.0 + n % 50)])
            n += 1
            time.sleep(0.001)

    sender = threading.Thread(target=feed)
    sender.start()
    code = None
    sent_at = time.monotonic()
    try:
        time.sleep(rng.uniform(0.0, 4.0))
        sent_at = time.monotonic()
        for _ in range(rng.randint(1, 4)):
            daemon.process.send_signal(signal.SIGTERM)
            time.sleep(rng.uniform(0.0, 0.05))
        code = daemon.process.wait(timeout=30.0)
    except subprocess.TimeoutExpired:
        pass
    finally:
        took = time.monotonic() - sent_at
        stop.set()
        sender.join()
        daemon.close()
    return code, took, daemon.log()


@pytest.mark.slow
def test_daemons_fed_datagrams_exit_cleanly_on_sigterm_at_random_moments(
    tmp_path: Path,
) -> None:
    results: dict[int, tuple[int | None, float, str]] = {}
    threads = [
        threading.Thread(
            target=lambda s=seed: results.__setitem__(s, _daemon_run(tmp_path / f"d{s}", s))
        )
        for seed in range(3)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    for seed, (code, took, log) in sorted(results.items()):
        assert code == 0, f"daemon {seed}: exit code {code}\n{log}"
        assert took < DAEMON_EXIT_S, f"daemon {seed}: {took:.1f} s to exit\n{log}"
