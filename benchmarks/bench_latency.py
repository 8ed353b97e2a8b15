"""Latency of the service: plot reception to system-track publication, at 2,000 plots/s.

`tracker-service run` in its own process, on unicast UDP inputs on 127.0.0.1; this
process sends a simulated recording's datagrams (both LANs) paced to the plot rate asked
for (the recording's reception times compressed: the scenario starts now, so that the
daemon dates the plots right), and subscribes to the system tracks over Zenoh. A plot's
latency is the time from the send of its datagram to the arrival of the first
system-track message whose last plot it is (the plot is known by its radar and I140).
Both clocks are this host's.

    python benchmarks/bench_latency.py [--rate 2000] [--duration 300] [--holding-window 0.02]

The holding window (``system.holding_window_s``, 1 s in config/example.toml) adds itself
to every latency: it is what buys the deterministic order across radars.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np
import zenoh

from asterix.plots import extract_plots
from tracker_service.cli import main as cli
from tracker_service.simulator.recording import read_recording

REPO = Path(__file__).resolve().parents[1]
DAY_S = 86400.0
LSB = 1 / 128


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def config_text(ports: dict[tuple[str, str], int], holding_window: float) -> str:
    """config/example.toml with unicast inputs on 127.0.0.1 and no MCAP log."""
    text = (REPO / "config" / "example.toml").read_text(encoding="utf-8")
    lines = iter(
        [
            f'input = {{ address = "127.0.0.1", port = {ports["25/11", "A"]}, second_lan = '
            f'{{ address = "127.0.0.1", port = {ports["25/11", "B"]} }} }}',
            f'input = {{ address = "127.0.0.1", port = {ports["25/12", "A"]} }}',
            f'input = {{ address = "127.0.0.1", port = {ports["25/13", "A"]} }}',
            f'input = {{ address = "127.0.0.1", port = {ports["25/50", "A"]} }}',
        ]
    )
    text = re.sub(r"(?m)^input = .*$", lambda _: next(lines), text)
    text = re.sub(r"(?m)^holding_window_s = .*$", f"holding_window_s = {holding_window}", text)
    return re.sub(r"(?m)^directory = .*$", "", text)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rate", type=float, default=2000.0, help="plots per second")
    parser.add_argument("--duration", type=float, default=300.0, help="scenario seconds")
    parser.add_argument("--holding-window", type=float, default=0.02)
    args = parser.parse_args()

    work = Path(tempfile.mkdtemp(prefix="bench_latency_"))
    scenario = work / "three_sites.toml"
    start = dt.datetime.now(dt.UTC).replace(microsecond=0) + dt.timedelta(seconds=10)
    text = (REPO / "config" / "scenarios" / "three_sites.toml").read_text(encoding="utf-8")
    scenario.write_text(
        re.sub(r"(?m)^start = .*$", f"start = {start:%Y-%m-%dT%H:%M:%SZ}", text), "utf-8"
    )
    recording = work / "three_sites.mcap"
    cli(["simulate", str(scenario), "-o", str(recording), "--duration", str(args.duration)])
    datagrams = list(read_recording(recording).datagrams())
    plots = sum(len(extract_plots(d.payload).plots) for d in datagrams if d.lan == "A")
    span = datagrams[-1].time - datagrams[0].time
    speed = args.rate / (plots / span)

    keys = [("25/11", "A"), ("25/11", "B"), ("25/12", "A"), ("25/13", "A"), ("25/50", "A")]
    ports = {key: free_port(socket.SOCK_DGRAM) for key in keys}
    config = work / "tracker.toml"
    config.write_text(config_text(ports, args.holding_window), encoding="utf-8")
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    daemon = subprocess.Popen(
        [
            *(sys.executable, "-m", "tracker_service.cli", "run"),
            *("--config", str(config), "--zenoh-listen", endpoint),
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert daemon.stderr is not None
    for line in daemon.stderr:
        if "running: publishing" in line:
            break
    threading.Thread(target=daemon.stderr.read, daemon=True).start()

    arrivals: list[tuple[float, bytes]] = []
    zconfig = zenoh.Config()
    zconfig.insert_json5("connect/endpoints", json.dumps([endpoint]))
    zconfig.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(zconfig)
    subscriber = session.declare_subscriber(
        "tracker/system_tracks/*",
        lambda s: arrivals.append((time.time(), s.payload.to_bytes())),
    )
    time.sleep(1.0)

    sent: dict[tuple[str, int], float] = {}
    cpu0 = _cpu(daemon.pid)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        wall0 = time.monotonic() + 0.1
        first = datagrams[0].time
        for d in datagrams:
            delay = wall0 + (d.time - first) / speed - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            sock.sendto(d.payload, ("127.0.0.1", ports[d.source, d.lan]))
            now = time.time()
            if d.lan == "A":
                for tod in extract_plots(d.payload).plots["time_of_day"].tolist():
                    if np.isfinite(tod):
                        sent.setdefault((d.source, round(tod / LSB)), now)
    wall = time.monotonic() - wall0
    time.sleep(2.0 + args.holding_window)
    cpu = _cpu(daemon.pid) - cpu0
    daemon.send_signal(signal.SIGTERM)
    daemon.wait(timeout=60)
    subscriber.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]

    latencies = []
    seen: set[tuple[str, int]] = set()
    for arrived, payload in arrivals:
        if not payload:
            continue  # the delete that follows a track's end
        plot = json.loads(payload).get("last_plot")
        if plot is None:
            continue
        key = (plot["radar"], round((plot["time"] % DAY_S) / LSB))
        if key in seen or key not in sent:
            continue
        seen.add(key)
        latencies.append(arrived - sent[key])
    print(f"{len(arrivals)} system-track samples, {len(sent)} plots sent", file=sys.stderr)
    if not latencies:
        print("no system track carried a plot sent here: did the subscriber connect?")
        return 1
    latencies.sort()
    ms = [1000 * x for x in latencies]
    print(
        f"{plots} plots in {wall:.1f} s ({plots / wall:.0f} plots/s, speed x{speed:.0f}), "
        f"holding window {args.holding_window * 1000:.0f} ms, daemon CPU {cpu / wall:.0%} "
        f"of a core"
    )
    print(
        f"plot reception to system-track publication, {len(ms)} plots: "
        f"p50 {statistics.median(ms):.1f} ms, p99 {ms[int(0.99 * (len(ms) - 1))]:.1f} ms, "
        f"max {ms[-1]:.1f} ms"
    )
    return 0


def _cpu(pid: int) -> float:
    """User + system CPU seconds of a process so far (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    ticks = int(fields[11]) + int(fields[12])
    return ticks / 100.0


if __name__ == "__main__":
    sys.exit(main())
