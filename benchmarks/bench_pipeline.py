"""Throughput of ``replay`` in one process against the pipeline of processes (issue 12,
"two processes give at least 1.6x the throughput of one"), side by side in one run.

Each round replays the recording (``--speed max``, an MCAP log in a temporary directory,
Zenoh on a free loopback port) once per layout, in turn, so that a drift of the
machine's speed hits every layout alike:

- ``one``: everything in one process;
- ``workers 1`` / ``workers 2``: the radar stages in 1 or 2 worker processes, the central
  stage (bias, fusion) in the main one, the outputs in a process of their own.

It prints, per layout, the median wall time and its ratio to ``one`` pair by pair
(one / layout: above 1 is faster), and the CPU seconds of each process as the replay
reports them (``cpu seconds: ...``): their total over 2 cores against the largest
process says how well the pipeline balances. The wall time on 2 quiet cores is at least
the larger of the two, so "2-core bound" (one-process CPU / that, pair by pair) is the
ratio a quiet 2-core machine could give at most; on a shared machine the pipeline, which
needs both cores at once, loses more than the one process does. The load average before
and after says how shared the machine was.

    tracker-service simulate config/scenarios/scale.toml -o scale60.mcap --duration 60
    python benchmarks/bench_pipeline.py scale60.mcap [--rounds 3] [--layouts one,1,2]
"""

from __future__ import annotations

import argparse
import os
import re
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

CPU_LINE = re.compile(r"^cpu seconds: (.*)$", re.MULTILINE)
NUMBER = re.compile(r"\d+\.\d+")


def free_endpoint() -> str:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{probe.getsockname()[1]}"


def run(recording: Path, layout: str) -> tuple[float, list[float]]:
    """Wall seconds of one replay, and each process's CPU seconds (one process: its own,
    from the operating system's accounting of the child)."""
    executable = Path(sys.executable).with_name("tracker-service")
    extra = [] if layout == "one" else ["--workers", layout]
    with tempfile.TemporaryDirectory() as log_dir:
        command = [
            str(executable),
            "replay",
            str(recording),
            "--speed",
            "max",
            "--mcap-dir",
            log_dir,
            "--zenoh-listen",
            free_endpoint(),
            *extra,
        ]
        before = os.times()
        start = time.monotonic()
        done = subprocess.run(command, capture_output=True, text=True, check=False)
        wall = time.monotonic() - start
        after = os.times()
    if done.returncode != 0:
        raise SystemExit(f"{' '.join(command)}: exit {done.returncode}\n{done.stderr}")
    found = CPU_LINE.search(done.stderr)
    if found is None:
        own = (after.children_user - before.children_user) + (
            after.children_system - before.children_system
        )
        return wall, [own]
    # "this process 48.0, outputs 28.6, radar workers 11.0 + 13.2"
    return wall, [float(n) for n in NUMBER.findall(found.group(1))]


def load() -> str:
    return " ".join(f"{x:.2f}" for x in os.getloadavg())


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument(
        "--layouts",
        type=lambda text: text.split(","),
        default=["one", "1", "2"],
        help="'one' and worker counts, comma-separated (default one,1,2)",
    )
    args = parser.parse_args()
    layouts: list[str] = args.layouts
    print(f"load average before: {load()} ({os.cpu_count()} cores)")
    walls: dict[str, list[float]] = {layout: [] for layout in layouts}
    cpus: dict[str, list[list[float]]] = {layout: [] for layout in layouts}
    for round_ in range(args.rounds):
        for layout in layouts:
            wall, cpu = run(args.recording, layout)
            walls[layout].append(wall)
            cpus[layout].append(cpu)
            print(f"round {round_ + 1} {layout:>3}: {wall:6.1f} s wall, cpu {cpu}", flush=True)
    print(f"load average after: {load()}")
    print("layout     wall (median)  one/layout [min-max]  2-core bound  cpu per process (median)")
    one_cpu = [sum(cpu) for cpu in cpus["one"]]
    for layout in layouts:
        ratios = [one / mine for one, mine in zip(walls["one"], walls[layout], strict=True)]
        bounds = [
            one / max(max(cpu), sum(cpu) / 2)
            for one, cpu in zip(one_cpu, cpus[layout], strict=True)
        ]
        per_process = [statistics.median(column) for column in zip(*cpus[layout], strict=True)]
        total = sum(per_process)
        name = "one" if layout == "one" else f"workers {layout}"
        balance = (
            ""
            if len(per_process) == 1
            else f"  total {total:.1f}, total/2 {total / 2:.1f}, largest {max(per_process):.1f}"
        )
        print(
            f"{name:<10} {statistics.median(walls[layout]):7.1f} s     "
            f"{statistics.median(ratios):5.2f}x [{min(ratios):.2f}-{max(ratios):.2f}]  "
            f"{statistics.median(bounds):5.2f}x       "
            f"{', '.join(f'{c:.1f}' for c in per_process)}{balance}"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
