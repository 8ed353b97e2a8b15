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
        [--prefix 15]

The wall time of a whole replay holds each process's start-up (imports, numba's cached
kernels, the Zenoh session: some 1.5 CPU-s a process, three of them in the pipeline) and
the founding of the picture, which a daemon pays once, not per hour. ``--prefix S`` also
replays, in each round and layout, a copy of the recording cut after its first S seconds
of datagrams (``cut_recording``: the same messages up to then), and prints the
throughput of the rest: the wall time of the whole less that of the prefix, layout
against layout, what the pipeline sustains once running.
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


def cut_recording(recording: Path, seconds: float, out: Path) -> None:
    """A copy of a simulator recording with every message logged up to ``seconds`` after
    its first datagram (``/asterix/*``), metadata and channels alike."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with recording.open("rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        asterix = [k for k, c in summary.channels.items() if c.topic.startswith("/asterix/")]
        first = min(
            m.log_time for _, _, m in reader.iter_messages(topics=None) if m.channel_id in asterix
        )
        end = first + int(seconds * 1e9)
        with out.open("wb") as g:
            writer = Writer(g)
            writer.start(profile=reader.get_header().profile, library="bench_pipeline")
            for record in reader.iter_metadata():
                writer.add_metadata(record.name, record.metadata)
            schemas = {0: 0}
            for key, schema in summary.schemas.items():
                schemas[key] = writer.register_schema(schema.name, schema.encoding, schema.data)
            ids = {
                key: writer.register_channel(
                    channel.topic,
                    channel.message_encoding,
                    schemas[channel.schema_id],
                    channel.metadata,
                )
                for key, channel in summary.channels.items()
            }
            for _, channel, message in reader.iter_messages(log_time_order=True):
                if message.log_time > end:
                    break
                writer.add_message(
                    ids[channel.id],
                    message.log_time,
                    message.data,
                    message.publish_time,
                    message.sequence,
                )
            writer.finish()


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
    parser.add_argument(
        "--prefix",
        type=float,
        help="also replay the recording's first S seconds, and print the throughput of the "
        "rest (start-up and founding left out)",
    )
    args = parser.parse_args()
    layouts: list[str] = args.layouts
    print(f"load average before: {load()} ({os.cpu_count()} cores)")
    walls: dict[str, list[float]] = {layout: [] for layout in layouts}
    cpus: dict[str, list[list[float]]] = {layout: [] for layout in layouts}
    rests: dict[str, list[float]] = {layout: [] for layout in layouts}
    with tempfile.TemporaryDirectory() as work:
        prefix = Path(work) / "prefix.mcap"
        if args.prefix is not None:
            cut_recording(args.recording, args.prefix, prefix)
        for round_ in range(args.rounds):
            for layout in layouts:
                wall, cpu = run(args.recording, layout)
                walls[layout].append(wall)
                cpus[layout].append(cpu)
                print(f"round {round_ + 1} {layout:>3}: {wall:6.1f} s wall, cpu {cpu}", flush=True)
                if args.prefix is not None:
                    head, _ = run(prefix, layout)
                    rests[layout].append(wall - head)
                    print(f"          prefix: {head:6.1f} s wall, the rest {wall - head:.1f} s")
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
    if args.prefix is not None:
        print(f"past the first {args.prefix:g} s: the rest's wall (median), one/layout [min-max]")
        for layout in layouts:
            ratios = [one / mine for one, mine in zip(rests["one"], rests[layout], strict=True)]
            name = "one" if layout == "one" else f"workers {layout}"
            print(
                f"{name:<10} {statistics.median(rests[layout]):7.1f} s     "
                f"{statistics.median(ratios):5.2f}x [{min(ratios):.2f}-{max(ratios):.2f}]"
            )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
