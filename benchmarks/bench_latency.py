"""Latency of the service: plot reception to system-track publication, at 2,000 plots/s.

The daemon (``tracker_service.service.daemon.Daemon``, what ``tracker-service run``
runs) in its own process, on unicast UDP inputs on 127.0.0.1, configured from the
recording's metadata as ``config_from_recording`` does. This process simulates the
scenario (starting now, so that the daemon dates the plots right), sends every radar's
datagrams (both LANs) over loopback paced at the recording's reception times divided by
the speed that gives the plot rate asked for, and subscribes to the system tracks over
Zenoh. A plot's latency is the time from the send of its datagram to the arrival of the
first system-track message whose last plot it is (the plot is known by its radar and
I140). Both clocks are this host's.

    python benchmarks/bench_latency.py [--scenario scale|three_sites|artas] [--rate 2000]
        [--speed 1] [--duration 180] [--holding-window 0.02] [--no-mcap] [--profile FILE]
        [--radar-processes N] [--samples FILE] [--statuses FILE] [--timeline FILE]
        [--sample-period S]

A long slice (``artas`` for 30 minutes: minutes of simulation) is simulated ahead, dated
in the future, then sent by a second run, so that the wait is not spent idle::

    python benchmarks/bench_latency.py --scenario artas --duration 1800 --lead 2400 \
        --write-recording /tmp/artas-future.mcap
    python benchmarks/bench_latency.py --speed 1 --recording /tmp/artas-future.mcap

``scale`` (20 radars, 2,000 aircraft, about 1,460 plots/s in real time, some 31 plots per
datagram) is the realistic load: its real time sped up about 1.37 times. ``three_sites``
(4.5 plots per datagram) compressed to the same plot rate is a per-datagram stress test
rather than a load a real system sees. ``artas`` (48 radars, 4,000 aircraft) is sent in
real time with ``--speed 1`` (which replaces ``--rate``): the ARTAS-class load.

Beside the latencies: the daemon's status over Zenoh (``tracker/status``: datagrams
dropped at its inputs, by cause, and its lag behind the wall clock) and the RSS of the
daemon and its output process. ``--timeline FILE`` writes, per ``--sample-period`` (2 s)
of the sending, what tells a lag's cause apart (``timeline_rows``): each process's share
of a core (from /proc/PID/stat: the daemon's processes, their children, this process),
the host's busy, iowait and steal time in cores (/proc/stat: steal is what the
hypervisor gave other machines), the CPU time of a fixed piece of work (``speed_probe``:
the host's speed), how late this process sent its datagrams against their schedule, the
daemon's lag and the plots' latency: a lag with one process's CPU up for the same plots
and the probe steady is the chain's work; with the probe slower (every process's CPU up
alike) or steal up, the host's; with the sender late, the benchmark's.

``--radar-processes N`` runs the daemon as the roles of docs/deployment.md: N ``run --role
radar`` processes (the radars dealt round robin) connected to one ``run --role fusion``
process (and its output process) over a stage session on 127.0.0.1; the CPU and RSS
figures are then of all of them.

The holding window (``system.holding_window_s``, 1 s in config/example.toml) adds itself
to every latency: it is what buys the deterministic order across radars. 20 ms here.
"""

from __future__ import annotations

import argparse
import cProfile
import datetime as dt
import gc
import itertools
import json
import logging
import math
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
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import numpy.typing as npt
import zenoh

from asterix.plots import extract_plots
from tracker_service.cli import main as cli
from tracker_service.service.command import stop_on_signals
from tracker_service.service.config import parse_service_config
from tracker_service.service.core import config_from_recording
from tracker_service.service.daemon import Daemon
from tracker_service.service.roles import FusionRole, RadarRole
from tracker_service.simulator.recording import read_recording

REPO = Path(__file__).resolve().parents[1]
DAY_S = 86400.0
LSB = 1 / 128
WARM_UP_S = 30.0
"""Plots sent in the first seconds, while 2,000 tracks are being initiated, are reported
apart."""


def free_port(kind: int) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def simulate(scenario: str, duration: float, work: Path, lead_s: float = 0.0) -> Path:
    """The scenario's recording, its start moved to now (the daemon dates each plot's
    I140 on the day nearest its reception)."""
    text = (REPO / "config" / "scenarios" / f"{scenario}.toml").read_text(encoding="utf-8")
    start = (dt.datetime.now(dt.UTC) + dt.timedelta(seconds=lead_s)).replace(microsecond=0)
    path = work / f"{scenario}.toml"
    path.write_text(
        re.sub(r"(?m)^start = .*$", f'start = "{start:%Y-%m-%dT%H:%M:%SZ}"', text), "utf-8"
    )
    recording = work / f"{scenario}.mcap"
    cli(["simulate", str(path), "-o", str(recording), "--duration", str(duration)])
    return recording


def daemon_config(
    metadata: dict[str, Any],
    ports: dict[tuple[str, str], int],
    holding_window: float,
    endpoint: str,
    mcap_dir: Path | None,
) -> dict[str, Any]:
    """``config_from_recording`` with a unicast 127.0.0.1 input per feed (LAN B, where
    the recording has one, as the second LAN), the holding window, the Zenoh endpoint
    and the MCAP log."""
    doc = config_from_recording(metadata).model_dump(mode="json", exclude_none=True)
    for feed in [*doc["radars"], *doc["adsb"]]:
        key = f"{feed['sac']}/{feed['sic']}"
        if (key, "A") not in ports:
            continue
        feed["input"] = {"address": "127.0.0.1", "port": ports[key, "A"]}
        if (key, "B") in ports:
            feed["input"]["second_lan"] = {"address": "127.0.0.1", "port": ports[key, "B"]}
    doc["system"]["holding_window_s"] = holding_window
    doc["zenoh"] = {"listen": [endpoint]}
    doc["mcap"] = {} if mcap_dir is None else {"directory": str(mcap_dir)}
    return doc


def serve(config_path: str, profile: str | None, role: str | None, stage: str | None) -> int:
    """The daemon side (``--serve``): the daemon on the configuration, until SIGTERM; with
    ``role`` one of its roles (``run --role``): "fusion" listening on the stage endpoint,
    or "radar:25/11,25/12" connecting to it."""
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    config = parse_service_config(json.loads(Path(config_path).read_text("utf-8")))
    service: Daemon | FusionRole | RadarRole
    if role == "fusion":
        service = FusionRole(config, [stage or ""], [])
    elif role is not None:
        service = RadarRole(config, role.removeprefix("radar:").split(","), [], [stage or ""])
    else:
        service = Daemon(config)
    with stop_on_signals() as stop:
        if profile is None:
            return service.run(stop)
        profiler = cProfile.Profile()
        code: int = profiler.runcall(service.run, stop)
        profiler.dump_stats(profile)
        return code


class LogTail:
    """The last lines of a service process's log, read on by a thread to its end: a
    30-minute run's log is too long to keep whole, and a process that died during a run
    left nothing to say why without them."""

    LINES = 30

    def __init__(self, stream: IO[str], ready: str) -> None:
        """Reads ``stream`` up to the line that has ``ready`` (or its end), then starts the
        thread that reads the rest."""
        self._lines: deque[str] = deque(maxlen=self.LINES)
        for line in stream:
            self._lines.append(line)
            if ready in line:
                break
        self._reader = threading.Thread(target=self._lines.extend, args=(stream,), daemon=True)
        self._reader.start()

    def text(self) -> str:
        """The last lines, once the log has ended (its process gone: a few seconds)."""
        self._reader.join(timeout=5.0)
        return "".join(list(self._lines))


def start_service(
    config: Path, args: argparse.Namespace, ready: str, role: list[str] | None = None
) -> tuple[subprocess.Popen[str], LogTail]:
    """A ``--serve`` process, returned once its log says ``ready``, and its log's tail."""
    command = [sys.executable, __file__, "--serve", str(config), *(role or [])]
    if args.profile is not None and (role is None or "fusion" in role):
        command += ["--profile", args.profile]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None
    return process, LogTail(process.stderr, ready)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scenario", choices=("scale", "three_sites", "artas"), default="scale")
    parser.add_argument("--rate", type=float, default=2000.0, help="plots per second")
    parser.add_argument("--speed", type=float, help="real time times this (instead of --rate)")
    parser.add_argument(
        "--lead",
        type=float,
        default=0.0,
        help="start the scenario this many s from now, and send from then: longer than the "
        "simulation takes, so that plots are not older than their reception (artas: minutes)",
    )
    parser.add_argument("--duration", type=float, default=180.0, help="scenario seconds")
    parser.add_argument("--holding-window", type=float, default=0.02, help="seconds")
    parser.add_argument("--no-mcap", action="store_true", help="run the daemon without log")
    parser.add_argument(
        "--no-warm-up",
        action="store_true",
        help="[system] warm_up = false: each process compiles (or loads) its kernels on the "
        "first data instead of before it listens (with NUMBA_CACHE_DIR set to an empty "
        "directory: the first start after an installation)",
    )
    parser.add_argument("--profile", help="cProfile the daemon into this file")
    parser.add_argument("--samples", help="write each plot's send time (s) and latency (ms)")
    parser.add_argument(
        "--statuses",
        help="write each status the daemon published (JSON lines): its lag, drops by cause",
    )
    parser.add_argument(
        "--timeline",
        help="write, per sample period of the sending, each process's CPU, the host's steal, "
        "the sender's lateness, the daemon's lag and the latencies (tab-separated)",
    )
    parser.add_argument(
        "--sample-period", type=float, default=2.0, help="seconds between CPU samples"
    )
    parser.add_argument(
        "--radar-processes",
        type=int,
        default=0,
        help="run the daemon as this many `run --role radar` processes (the radars dealt "
        "round robin) and one `run --role fusion`, over a stage session on 127.0.0.1",
    )
    parser.add_argument(
        "--write-recording",
        metavar="PATH",
        help="only simulate the scenario (starting --lead s from now) into PATH: a long "
        "slice is then simulated ahead of the run that sends it (--recording)",
    )
    parser.add_argument(
        "--recording",
        metavar="PATH",
        help="send this recording (from --write-recording, starting in the future) instead "
        "of simulating one",
    )
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    parser.add_argument("--role", help=argparse.SUPPRESS)
    parser.add_argument("--stage", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve is not None:
        return serve(args.serve, args.profile, args.role, args.stage)

    work = Path(tempfile.mkdtemp(prefix="bench_latency_"))
    if args.write_recording is not None:
        simulated = simulate(args.scenario, args.duration, work, args.lead)
        shutil.move(simulated, args.write_recording)
        shutil.rmtree(work, ignore_errors=True)
        return 0
    if args.recording is not None:
        recording = read_recording(Path(args.recording))
    else:
        recording = read_recording(simulate(args.scenario, args.duration, work, args.lead))
    datagrams = list(recording.datagrams())
    if args.recording is not None and datagrams[0].time < time.time():
        print(
            f"the recording starts {time.time() - datagrams[0].time:.0f} s in the past: its "
            "plots would be older than their reception; simulate it with a longer --lead",
            file=sys.stderr,
        )
        return 2
    # Everything the send loop needs, worked out before it starts: its own CPU would
    # otherwise compete with the daemon's.
    keys_of = []
    for d in datagrams:
        tods = extract_plots(d.payload).plots["time_of_day"].tolist() if d.lan == "A" else []
        keys_of.append([(d.source, round(t / LSB)) for t in tods if np.isfinite(t)])
    plots = sum(len(keys) for keys in keys_of)
    span = datagrams[-1].time - datagrams[0].time
    speed = args.rate / (plots / span) if args.speed is None else args.speed

    ports = {(d.source, d.lan): 0 for d in datagrams}
    ports = {key: free_port(socket.SOCK_DGRAM) for key in ports}
    endpoint = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    mcap_dir = None if args.no_mcap else work / "log"
    config = work / "tracker.json"
    doc = daemon_config(recording.metadata, ports, args.holding_window, endpoint, mcap_dir)
    doc["system"]["warm_up"] = not args.no_warm_up
    config.write_text(json.dumps(doc), encoding="utf-8")
    radar_processes: list[subprocess.Popen[str]] = []
    logs: dict[str, LogTail] = {}
    if args.radar_processes:
        stage = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
        fusion = ["--role", "fusion", "--stage", stage]
        daemon, logs["daemon"] = start_service(config, args, "fusion: taking", fusion)
        radars = [f"{r['sac']}/{r['sic']}" for r in doc["radars"] if "input" in r]
        for k in range(args.radar_processes):
            mine = ",".join(radars[k :: args.radar_processes])
            role = ["--role", f"radar:{mine}", "--stage", stage]
            radar_process, logs[f"radar process {k}"] = start_service(
                config, args, "publishing under", role
            )
            radar_processes.append(radar_process)
    else:
        daemon, logs["daemon"] = start_service(config, args, "running: publishing")

    arrivals: list[tuple[float, bytes]] = []
    zconfig = zenoh.Config()
    zconfig.insert_json5("connect/endpoints", json.dumps([endpoint]))
    zconfig.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(zconfig)
    subscriber = session.declare_subscriber(
        "tracker/system_tracks/*",
        lambda s: arrivals.append((time.time(), s.payload.to_bytes())),
    )
    statuses: list[dict[str, Any]] = []
    status_subscriber = session.declare_subscriber(
        "tracker/status", lambda s: statuses.append(json.loads(s.payload.to_bytes()))
    )
    roles = {daemon.pid: "fusion" if radar_processes else "main"}
    roles.update({p.pid: f"radar process {k}" for k, p in enumerate(radar_processes)})
    samples_taken: list[Sample] = []
    sampling = threading.Event()

    def sample() -> None:
        samples_taken.append(take_sample(roles))
        while not sampling.wait(args.sample_period):
            samples_taken.append(take_sample(roles))

    threading.Thread(target=sample, daemon=True).start()
    time.sleep(1.0)

    # Each datagram's send (POSIX s) and how late it left against its schedule (s): into
    # arrays made beforehand, so that the loop allocates nothing. A dictionary of each
    # plot's send time filled in the loop stalled the sender whenever it grew (0.3 s at
    # 0.7 million plots, 0.8 s at 1.4, 2.9 s at 2.8 in a 30-minute run of `artas`).
    send_times = np.full(len(datagrams), np.nan)
    lateness = np.full(len(datagrams), np.nan)
    # Millions of arrivals held, and no cycle among them: the collector's full passes
    # over them paused the sender for seconds in a 30-minute run (then a burst: the
    # radars' clocks judged 17 s behind), so it is off while sending.
    gc.disable()
    # At the scenario's start (with --lead), else at once: the plots' times are real.
    start_in = datagrams[0].time - time.time()
    wall0 = time.monotonic() + max(0.1, start_in)
    # The CPU shares are of the sending time only, not of the lead's idle wait.
    time.sleep(max(0.0, wall0 - time.monotonic() - 0.05))
    cpu0 = {k: v for p in [daemon, *radar_processes] for k, v in cpu_per_process(p.pid).items()}
    own0 = time.process_time()
    cpu_wall0 = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        first = datagrams[0].time
        for i, d in enumerate(datagrams):
            due = wall0 + (d.time - first) / speed
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            sock.sendto(d.payload, ("127.0.0.1", ports[d.source, d.lan]))
            send_times[i] = time.time()
            lateness[i] = time.monotonic() - due
    wall = time.monotonic() - wall0
    time.sleep(2.0 + args.holding_window)
    cpu1 = {k: v for p in [daemon, *radar_processes] for k, v in cpu_per_process(p.pid).items()}
    own = time.process_time() - own0
    cpu_wall = time.monotonic() - cpu_wall0
    sampling.set()
    # A process gone before its stop is a failed run, whatever the samples say (a
    # one-process daemon that died of a segfault in its first second left only "no
    # system track" to go by).
    died = {
        name: process.returncode
        for name, process in [("daemon", daemon)]
        + [(f"radar process {k}", p) for k, p in enumerate(radar_processes)]
        if process.poll() is not None
    }
    for radar_process in radar_processes:
        radar_process.terminate()
        radar_process.wait(timeout=60)
    daemon.terminate()
    try:
        daemon.wait(timeout=60)
    except subprocess.TimeoutExpired:
        # Still working through a backlog: what it has not published by now is late anyway.
        print("the daemon did not stop within 60 s: killed", file=sys.stderr)
        daemon.kill()
        daemon.wait()
    subscriber.undeclare()  # type: ignore[no-untyped-call]
    status_subscriber.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    shutil.rmtree(work, ignore_errors=True)  # the recording and the daemon's log

    sent: dict[tuple[str, int], float] = {}
    for keys, at in zip(keys_of, send_times.tolist(), strict=True):
        for key in keys:
            sent.setdefault(key, at)
    start = min(sent.values())
    latencies: tuple[list[float], list[float]] = ([], [])
    seen: set[tuple[str, int]] = set()
    samples: list[tuple[float, float]] = []
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
        samples.append((sent[key] - start, 1000 * (arrived - sent[key])))
        latencies[samples[-1][0] >= WARM_UP_S].append(samples[-1][1])
    if args.samples is not None:
        np.savetxt(args.samples, sorted(samples), fmt="%.3f", header="sent_s latency_ms")
    print(f"{len(arrivals)} system-track samples, {len(sent)} plots sent", file=sys.stderr)
    for name, code in died.items():
        cause = f"signal {signal.Signals(-code).name}" if code < 0 else f"exit status {code}"
        print(f"the {name} ended during the run ({cause}): the run is void", file=sys.stderr)
        print(f"its log's last lines:\n{logs[name].text()}", file=sys.stderr)
    if died:
        return 1
    if not seen:
        print("no system track carried a plot sent here: did the subscriber connect?")
        return 1
    cpu = {pid: cpu1[pid] - cpu0.get(pid, 0.0) for pid in cpu1}
    name = Path(args.recording).name if args.recording else args.scenario
    print(
        f"{name}: {plots} plots in {len(datagrams)} datagrams, sent in {wall:.1f} s "
        f"({plots / wall:.0f} plots/s, {len(datagrams) / wall:.0f} datagrams/s, speed "
        f"x{speed:.2f}), holding window {args.holding_window * 1000:.0f} ms, MCAP log "
        f"{'off' if mcap_dir is None else 'on'}"
    )
    if args.timeline is not None:
        # The timeline's clock: seconds from the first datagram's send, as the samples'.
        rows = timeline_rows(
            samples_taken,
            wall0,
            (send_times - start, lateness),
            [(s["time"] - start, s["lag_s"]) for s in statuses if s.get("lag_s") is not None],
            np.array(samples, dtype=np.float64).reshape(-1, 2),
        )
        write_timeline(args.timeline, rows)
        print(attribute_lag(rows))
    print(
        "CPU, share of a core: daemon "
        + ", ".join(
            # The children: the output process, and multiprocessing's resource tracker.
            f"{roles.get(pid, f'child {pid}')} {s / cpu_wall:.0%}"
            for pid, s in cpu.items()
            if s / cpu_wall >= 0.01
        )
        + f"; this process (sender, subscriber) {own / cpu_wall:.0%}"
    )
    if args.statuses is not None:
        with open(args.statuses, "w", encoding="utf-8") as out:
            out.writelines(json.dumps(status) + "\n" for status in statuses)
    if statuses:
        last = statuses[-1]
        causes: dict[str, int] = {}
        for radar in last["radars"]:
            for cause, count in radar.get("drop_causes", {}).items():
                causes[cause] = causes.get(cause, 0) + count
        lags = [s["lag_s"] for s in statuses if s.get("lag_s") is not None]
        print(
            f"daemon status ({len(statuses)}): drops {sum(r['drops'] for r in last['radars'])} "
            f"{causes or ''}, lag max {max(lags, default=0.0):.2f} s, last "
            f"{lags[-1] if lags else 0.0:.2f} s, health {last['health']}"
            + "".join(f"; {reason}" for reason in last.get("reasons", []))
        )
        busy: dict[str, list[float]] = {}
        for status in statuses:
            for role, share in status.get("busy", {}).items():
                busy.setdefault(role, []).append(share)
        if busy:
            print(
                "busy share of each process's loop, per status (median, max): "
                + ", ".join(
                    f"{role} {statistics.median(v):.2f} {max(v):.2f}"
                    for role, v in sorted(busy.items())
                )
            )
    rss = [(s.at - wall0, s.rss_mb) for s in samples_taken]
    if rss:
        print(
            "RSS of the daemon's processes, from the start of sending: "
            + ", ".join(f"{t:.0f} s {mb:.0f} MB" for t, mb in rss[:: max(1, len(rss) // 8)])
            + f", last {rss[-1][1]:.0f} MB"
        )
    for label, ms in (("first 30 s", latencies[0]), ("after 30 s", latencies[1])):
        if ms:
            ms.sort()
            print(
                f"plot reception to system-track publication, {label}, {len(ms)} plots: "
                f"p50 {statistics.median(ms):.1f} ms, p99 {ms[int(0.99 * (len(ms) - 1))]:.1f} "
                f"ms, max {ms[-1]:.1f} ms"
            )
    return 0


def rss_mb(pid: int) -> float:
    """Resident set size of a process and its children, MB (Linux /proc)."""
    total, pending = 0.0, [pid]
    while pending:
        current = pending.pop()
        try:
            pages = int(Path(f"/proc/{current}/statm").read_text().split()[1])
            children = Path(f"/proc/{current}/task/{current}/children").read_text().split()
        except OSError:
            continue
        total += pages * 4096 / 2**20
        pending.extend(int(child) for child in children)
    return total


def cpu_per_process(pid: int) -> dict[int, float]:
    """User + system CPU seconds so far of a process and of its children (Linux /proc)."""
    out = {}
    pending = [pid]
    while pending:
        current = pending.pop()
        try:
            fields = Path(f"/proc/{current}/stat").read_text().rsplit(")", 1)[1].split()
            children = Path(f"/proc/{current}/task/{current}/children").read_text().split()
        except OSError:
            continue
        out[current] = (int(fields[11]) + int(fields[12])) / 100.0
        pending.extend(int(child) for child in children)
    return out


HOST_FIELDS = ("user", "nice", "system", "idle", "iowait", "irq", "softirq", "steal")
"""The first fields of /proc/stat's ``cpu`` line (proc(5)), clock ticks of all cores."""
TICK_S = 0.01
"""A clock tick (``SC_CLK_TCK`` 100 on Linux), as ``cpu_per_process`` counts."""


@dataclass
class Sample:
    """One look at the host and the daemon's processes (``take_sample``)."""

    at: float
    """``time.monotonic()``."""
    host: dict[str, int]
    """/proc/stat's CPU ticks by kind, all cores."""
    cpu: dict[str, float]
    """CPU seconds by process: the daemon's roles by name, their children as "<name>+",
    and "bench" (this process: the sender and the subscriber)."""
    rss_mb: float
    """RSS of the daemon's processes and their children."""
    probe_s: float
    """``speed_probe``'s CPU seconds."""


PROBE_LOOPS = 50_000


def speed_probe() -> float:
    """CPU seconds of this thread (``time.thread_time``: waits and steal left out) for a
    fixed piece of Python work, a few milliseconds: the host's speed for the same work.
    A virtual machine's neighbours (their caches, memory bandwidth, a shared core) slow
    every process alike without any steal shown; each process's CPU then rises for the
    same plots, which this tells apart from the chain's own work."""
    started = time.thread_time()
    total = 0
    for k in range(PROBE_LOOPS):
        total += k % 7
    assert total >= 0
    return time.thread_time() - started


def take_sample(roles: dict[int, str]) -> Sample:
    """The host's CPU ticks and the CPU and RSS of the processes ``roles`` names (pid:
    name) and of this one, now."""
    line = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    assert line[0] == "cpu"
    cpu: dict[str, float] = {}
    for pid, name in roles.items():
        for member, seconds in cpu_per_process(pid).items():
            key = name if member == pid else f"{name}+"
            cpu[key] = cpu.get(key, 0.0) + seconds
    # Its own threads only: the daemon's processes are its children.
    cpu["bench"] = time.process_time()
    return Sample(
        at=time.monotonic(),
        host=dict(zip(HOST_FIELDS, map(int, line[1:]), strict=False)),
        cpu=cpu,
        rss_mb=sum(rss_mb(pid) for pid in roles),
        probe_s=speed_probe(),
    )


def timeline_rows(
    samples: list[Sample],
    wall0: float,
    sends: tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]],
    lags: list[tuple[float, float]],
    latencies: npt.NDArray[np.float64],
) -> list[dict[str, float]]:
    """One row per pair of consecutive samples within the sending (times in s from the
    first send; ``wall0``, the schedule's start in monotonic s, is that send within a
    millisecond):
    each process's share of a core; the host's busy, iowait and steal time in cores,
    and ``speed_probe``'s milliseconds at the window's end;
    the datagrams sent, the latest of them against its schedule (ms) and their p99; the
    daemon's largest lag among the statuses of the window's data; the p50 and p99 of
    the latencies (ms) of the plots sent in it. ``sends``: each datagram's send (s from
    the first) and lateness (s); ``lags``: (data time from the first send, ``lag_s``);
    ``latencies``: (sent, ms) rows."""
    sent, late = sends
    last_send = float(np.nanmax(sent)) if sent.size else 0.0
    lag_t = np.array([t for t, _ in lags], dtype=np.float64)
    lag_s = np.array([lag for _, lag in lags], dtype=np.float64)
    rows = []
    for before, after in itertools.pairwise(samples):
        t0, t1 = before.at - wall0, after.at - wall0
        if t1 <= 0.0 or t0 >= last_send:
            continue
        span = t1 - t0
        row: dict[str, float] = {"t0": t0, "t1": t1}
        for name in after.cpu:
            row[f"cpu {name}"] = (after.cpu[name] - before.cpu.get(name, 0.0)) / span
        ticks = {k: after.host[k] - before.host.get(k, 0) for k in after.host}
        busy = sum(ticks[k] for k in ("user", "nice", "system", "irq", "softirq") if k in ticks)
        row["host busy"] = busy * TICK_S / span
        row["host iowait"] = ticks.get("iowait", 0) * TICK_S / span
        row["host steal"] = ticks.get("steal", 0) * TICK_S / span
        row["probe ms"] = after.probe_s * 1e3
        inside = (sent >= t0) & (sent < t1)
        row["datagrams"] = float(np.count_nonzero(inside))
        row["late max ms"] = float(late[inside].max() * 1e3) if inside.any() else math.nan
        row["late p99 ms"] = (
            float(np.percentile(late[inside], 99) * 1e3) if inside.any() else math.nan
        )
        statuses = (lag_t >= t0) & (lag_t < t1)
        row["lag max s"] = float(lag_s[statuses].max()) if statuses.any() else math.nan
        plots = latencies[(latencies[:, 0] >= t0) & (latencies[:, 0] < t1), 1]
        row["latency p50 ms"] = float(np.percentile(plots, 50)) if plots.size else math.nan
        row["latency p99 ms"] = float(np.percentile(plots, 99)) if plots.size else math.nan
        rows.append(row)
    return rows


def write_timeline(path: str, rows: list[dict[str, float]]) -> None:
    """The rows tab-separated, a header line of their names first."""
    names = list(dict.fromkeys(name for row in rows for name in row))
    with open(path, "w", encoding="utf-8") as out:
        out.write("\t".join(names) + "\n")
        for row in rows:
            out.write("\t".join(f"{row.get(name, math.nan):.4g}" for name in names) + "\n")


def attribute_lag(rows: list[dict[str, float]], lagging_s: float = 1.0) -> str:
    """The timeline's windows where the daemon lagged ``lagging_s`` or more against the
    others: the mean of each process's share of a core, of the host's steal, and the
    sender's worst lateness, side by side."""
    lagging = [r for r in rows if r.get("lag max s", 0.0) >= lagging_s]
    others = [r for r in rows if not r.get("lag max s", 0.0) >= lagging_s]
    names = [n for n in dict.fromkeys(n for r in rows for n in r) if n.startswith("cpu ")]
    names += ["host busy", "host steal", "host iowait", "probe ms", "late max ms", "datagrams"]

    def mean(part: list[dict[str, float]], name: str) -> str:
        values = [r[name] for r in part if name in r and math.isfinite(r[name])]
        return f"{statistics.fmean(values):.3g}" if values else "-"

    return (
        f"timeline: {len(lagging)} of {len(rows)} windows with a lag of {lagging_s:g} s or "
        "more; mean of each, lagging / others: "
        + ", ".join(f"{n} {mean(lagging, n)} / {mean(others, n)}" for n in names)
    )


if __name__ == "__main__":
    sys.exit(main())
