"""Load: does ``tracker-service replay RECORDING --speed 1`` keep up with real time?

The replay (every output on: the MCAP log, CAT062 in it, Zenoh publication) runs as a
subprocess; this process subscribes to its system tracks over Zenoh on 127.0.0.1 and,
every ``--sample-s`` seconds, reads the replay's CPU time and RSS (with its children)
from /proc. A system-track message's lag is how late it arrives against the schedule
the replay paces itself by: wall time since the replay started minus data time since
the recording's first datagram (the holding window, 1 s by default, is in it). A replay
that keeps up shows a flat lag; one that does not, a lag growing with the data time.

    python benchmarks/bench_load.py simulate [--scenario artas] [--duration 120]
        [--out /tmp/artas-slice.mcap]       # the slice, once (minutes for artas)
    python benchmarks/bench_load.py replay /tmp/artas-slice.mcap [--speed 1]
        [--sample-s 5] [--samples FILE.jsonl] [--max-wall 600] [--workers N]

``--max-wall``: a replay that falls far behind is stopped (SIGTERM, a clean stop) after
that many seconds; the figures are then of what it did by then (data seconds replayed
per wall second, plots per CPU-second from its own count).

Recordings go to /tmp (never into the repository). A replay has no sockets, so it drops
nothing: what it cannot do in time shows as lag. Datagrams dropped at the UDP inputs are
the daemon's business: ``bench_latency.py --scenario artas``.
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import zenoh
from bench_latency import cpu_per_process, free_port, rss_mb

from asterix.plots import extract_plots
from tracker_service.cli import main as cli
from tracker_service.simulator.recording import read_recording

REPO = Path(__file__).resolve().parents[1]


def simulate(args: argparse.Namespace) -> int:
    scenario = REPO / "config" / "scenarios" / f"{args.scenario}.toml"
    started = time.perf_counter()
    cpu0 = time.process_time()
    code = cli(["simulate", str(scenario), "-o", args.out, "--duration", str(args.duration)])
    print(
        f"simulated {args.duration:.0f} s of {args.scenario} in {time.perf_counter() - started:.0f}"
        f" s wall, {time.process_time() - cpu0:.0f} s CPU: {args.out}"
    )
    return code


def replay(args: argparse.Namespace) -> int:
    recording = read_recording(args.recording)
    times = [d.time for d in recording.datagrams()]
    first, span = times[0], times[-1] - times[0]
    plots = sum(len(extract_plots(d.payload).plots) for d in recording.datagrams() if d.lan == "A")
    work = Path(tempfile.mkdtemp(prefix="bench_load_"))
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    command = [sys.executable, "-m", "tracker_service.cli", "replay", args.recording]
    command += ["--speed", str(args.speed), "--mcap-dir", str(work / "log")]
    command += ["--zenoh-listen", endpoint]
    if args.workers:
        command += ["--workers", str(args.workers)]
    # The subscriber is ready before the replay starts: connect retries until it listens.
    arrivals: list[tuple[float, float]] = []
    config = zenoh.Config()
    config.insert_json5("connect/endpoints", json.dumps([endpoint]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("connect/timeout_ms", "-1")

    def on_sample(sample: Any) -> None:
        payload = sample.payload.to_bytes()
        if payload:  # an empty one is the delete after a track's end
            arrivals.append((time.monotonic(), json.loads(payload)["time"]))

    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None
    for line in process.stderr:
        if "watch with" in line:
            break
    wall0 = time.monotonic()
    log_lines: list[str] = []
    threading.Thread(target=lambda: log_lines.extend(process.stderr or []), daemon=True).start()
    session = zenoh.open(config)
    subscriber = session.declare_subscriber("tracker/system_tracks/*", on_sample)
    samples: list[dict[str, Any]] = []
    cpu_before = 0.0
    while process.poll() is None:
        time.sleep(args.sample_s)
        if time.monotonic() - wall0 > args.max_wall and process.poll() is None:
            print(f"stopped after {args.max_wall:.0f} s (SIGTERM)", file=sys.stderr)
            process.send_signal(signal.SIGTERM)
        elapsed = time.monotonic() - wall0
        cpu = sum(cpu_per_process(process.pid).values())
        recent = [a - wall0 - (t - first) for a, t in arrivals[-2000:] if a > wall0 + elapsed - 5]
        samples.append(
            {
                "elapsed_s": round(elapsed, 1),
                "cpu_share": round((cpu - cpu_before) / args.sample_s, 3),
                "cpu_s": cpu,
                "rss_mb": round(rss_mb(process.pid), 1),
                # The median: an ended track's last message carries its last update's
                # time, tens of seconds old, so the maximum says little of the pace.
                "lag_s": round(statistics.median(recent), 3) if recent else None,
                "lag_max_s": round(max(recent), 3) if recent else None,
                "messages": len(arrivals),
            }
        )
        cpu_before = cpu
        print(json.dumps(samples[-1]), file=sys.stderr)
    wall = time.monotonic() - wall0
    time.sleep(1.0)  # the last lines of its log
    subscriber.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    shutil.rmtree(work, ignore_errors=True)  # the replay's MCAP log
    if args.samples:
        Path(args.samples).write_text("".join(json.dumps(s) + "\n" for s in samples), "utf-8")
    print("".join(log_lines[-3:]), end="", file=sys.stderr)
    if process.returncode != 0 or not arrivals:
        print(f"replay exited {process.returncode} with {len(arrivals)} system-track messages")
        return 1
    lags = [a - wall0 - (t - first) for a, t in arrivals]
    tenth = max(1, len(lags) // 10)
    cpu_total = max((s["cpu_s"] for s in samples), default=0.0)
    rss = [s["rss_mb"] for s in samples if s["rss_mb"]]
    # The replay's own count: "replayed N datagrams (...): P plots, ..."
    done = re.search(r"replayed (\d+) datagrams.*?: (\d+) plots", "".join(log_lines))
    datagrams_done, plots_done = (int(done[1]), int(done[2])) if done else (0, 0)
    data_s = max(t for _, t in arrivals) - first
    print(
        f"{Path(args.recording).name}: {len(times)} datagrams, {plots} radar plots over "
        f"{span:.0f} s ({plots / span:.0f} plots/s), replayed at x{args.speed:g}: "
        f"{datagrams_done} datagrams, {plots_done} plots, {data_s:.0f} s of data in {wall:.0f} s "
        f"wall ({data_s / wall:.2f} data seconds per wall second)"
    )
    print(
        f"CPU {cpu_total:.0f} s ({cpu_total / wall:.0%} of a core on average, "
        f"{plots_done / max(cpu_total, 1e-9):.0f} plots per CPU-second); RSS "
        f"{min(rss, default=0):.0f}-{max(rss, default=0):.0f} MB"
    )
    print(
        f"system-track lag: first tenth p50 {statistics.median(lags[:tenth]):.2f} s, last tenth "
        f"p50 {statistics.median(lags[-tenth:]):.2f} s, max {max(lags):.2f} s "
        f"({len(arrivals)} messages)"
    )
    return 0


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser("simulate", help="write the slice to replay")
    sim.add_argument("--scenario", default="artas")
    sim.add_argument("--duration", type=float, default=120.0, help="scenario seconds")
    sim.add_argument("--out", default="/tmp/artas-slice.mcap")
    rep = sub.add_parser("replay", help="replay it at --speed and measure")
    rep.add_argument("recording")
    rep.add_argument("--speed", type=float, default=1.0)
    rep.add_argument("--sample-s", type=float, default=5.0)
    rep.add_argument("--samples", help="write the samples here (JSON lines)")
    rep.add_argument("--max-wall", type=float, default=600.0, help="stop it after (s)")
    rep.add_argument(
        "--workers", type=int, default=0, help="radar worker processes (replay --workers)"
    )
    args = parser.parse_args()
    return simulate(args) if args.command == "simulate" else replay(args)


if __name__ == "__main__":
    sys.exit(main())
