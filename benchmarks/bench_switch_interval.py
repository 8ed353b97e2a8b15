"""What Python's GIL switch interval costs a thread that wakes while another computes: the
service's hops (a UDP reader, a Zenoh callback, the output process's reader of the
core's calls, a sink's thread) each wake and need the GIL from a thread that is
computing the chain.

In this process the main thread computes (pure Python arithmetic, which holds the GIL
as the chain's numpy and numba calls do), and a reader thread blocks on a pipe. A
writer process writes a time stamp into the pipe every few milliseconds; the reader
notes how long after the write it got the GIL back (its wake-up delay). Rounds with the
service's interval (``command.SWITCH_INTERVAL_S``) and Python's default alternate; each
round also counts the main thread's work per second, to see what the switches cost it.

    python benchmarks/bench_switch_interval.py [--rounds 6] [--seconds 5]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import threading
import time

import numpy as np

from tracker_service.service.command import SWITCH_INTERVAL_S

DEFAULT_INTERVAL_S = sys.getswitchinterval()
"""Python's own (5 ms), as this process starts."""
WRITE_PERIOD_S = 0.003
STAMP = 8


WRITER = """
import os, sys, time
fd, stamp = int(sys.argv[1]), int(sys.argv[2])
seconds, period = float(sys.argv[3]), float(sys.argv[4])
end = time.monotonic() + seconds
while time.monotonic() < end:
    os.write(fd, time.monotonic_ns().to_bytes(stamp, "little"))
    time.sleep(period)
os.write(fd, bytes(stamp))
"""
"""The writer process: every ``WRITE_PERIOD_S`` the monotonic clock's time into the pipe
(the clock is the host's: the reader compares it with its own), then a zero."""


def one_round(interval: float, seconds: float) -> tuple[np.ndarray, float]:
    """The reader's wake-up delays (ms) and the main thread's loops per second."""
    sys.setswitchinterval(interval)
    read_fd, write_fd = os.pipe()
    delays: list[float] = []

    def read() -> None:
        while True:
            data = os.read(read_fd, STAMP)
            now = time.monotonic_ns()
            sent = int.from_bytes(data, "little")
            if sent == 0:
                return
            delays.append((now - sent) / 1e6)

    reader = threading.Thread(target=read)
    reader.start()
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, *map(str, (write_fd, STAMP, seconds, WRITE_PERIOD_S))],
        pass_fds=(write_fd,),
    )
    loops, x = 0, 0.0
    started = time.monotonic()
    while reader.is_alive():
        for k in range(1000):
            x += k * 0.5
        loops += 1
    spent = time.monotonic() - started
    writer.wait()
    os.close(read_fd)
    os.close(write_fd)
    return np.array(delays[10:]), loops / spent


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--rounds", type=int, default=6)
    parser.add_argument("--seconds", type=float, default=5.0)
    args = parser.parse_args()
    figures: dict[float, list[tuple[float, float, float]]] = {
        SWITCH_INTERVAL_S: [],
        DEFAULT_INTERVAL_S: [],
    }
    for k in range(args.rounds):
        order = [SWITCH_INTERVAL_S, DEFAULT_INTERVAL_S]
        for interval in order if k % 2 == 0 else order[::-1]:
            delays, rate = one_round(interval, args.seconds)
            p50, p99 = np.percentile(delays, [50, 99])
            figures[interval].append((p50, p99, rate))
            print(
                f"round {k} interval {interval * 1e3:.0f} ms: wake-up p50 {p50:.2f} ms, "
                f"p99 {p99:.2f}, max {delays.max():.2f}; main thread {rate:,.0f} loops/s",
                flush=True,
            )
    print("medians of the rounds:")
    base = statistics.median(r for *_, r in figures[DEFAULT_INTERVAL_S])
    for interval, rows in figures.items():
        p50 = statistics.median(r[0] for r in rows)
        p99 = statistics.median(r[1] for r in rows)
        rate = statistics.median(r[2] for r in rows)
        print(
            f"  interval {interval * 1e3:.0f} ms: wake-up p50 {p50:.2f} ms, p99 {p99:.2f} ms; "
            f"main thread {rate / base:.3f} x the default's work"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
