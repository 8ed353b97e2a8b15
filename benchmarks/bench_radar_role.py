"""CPU of the radar process (``tracker-service run --role radar``) live: every radar of a
recording sent over loopback UDP (both LANs) in real time to one radar process, which
receives, decodes, tracks and publishes its batches over Zenoh to this process (issue 12).

``bench_radar_stage.py`` times the radar stage's feed alone; the process also runs a
reader thread per LAN, the holding window, the stage messages' encoding and the Zenoh
puts (with the session's own threads). This measures all of it: the process's CPU
(user + system, /proc) over the sending, split by thread (main, the UDP readers, the
rest: Zenoh's), per plot and per datagram sent.

The recording's plots are dated when it was simulated: the radar process runs with its
clock (``time.time``) moved back by the difference (sent on its stdin), so
that each datagram arrives at the time its plots say, as they would live. The
subscriber here counts the messages and their bytes only.

    python benchmarks/bench_radar_role.py /tmp/s17/artas150.mcap --skip 30 --seconds 60

To compare two trees, run this script with ``PYTHONPATH=COPY`` (the radar process
inherits it), alternated.
"""

from __future__ import annotations

import argparse
import json
import logging
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import zenoh

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_latency import daemon_config, free_port  # noqa: E402

from asterix.plots import extract_plots  # noqa: E402
from tracker_service.simulator.recording import read_recording  # noqa: E402

START_S = 3.0
"""Between the radar process's imports and the first datagram's send: its start-up."""
WARM_UP_S = 10.0
"""Sent before the measured slice, untimed: the numba caches are loaded at first use."""


def serve(config_path: str, stage: str) -> int:
    """The radar process (``--serve``): every configured radar, its clock behind this
    host's by the seconds read from stdin once its modules are imported."""
    import tracker_service
    from tracker_service.service.command import stop_on_signals
    from tracker_service.service.config import parse_service_config
    from tracker_service.service.roles import RadarRole

    print("imported", file=sys.stderr, flush=True)
    shift = float(sys.stdin.readline())
    wall = time.time
    time.time = lambda: wall() - shift
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    logging.info("tracker_service from %s", tracker_service.__file__)
    config = parse_service_config(json.loads(Path(config_path).read_text("utf-8")))
    radars = [r.key for r in config.radars if r.input is not None]
    with stop_on_signals() as stop:
        return RadarRole(config, radars, [], [stage]).run(stop)


def thread_cpu(pid: int) -> dict[str, float]:
    """CPU seconds (user + system) so far of each of a process's threads, grouped: "main",
    "udp readers" (the other Python threads: Python does not name them for the OS), and
    "zenoh" (its runtime's threads, named by it)."""
    out = {"main": 0.0, "udp readers": 0.0, "zenoh": 0.0}
    comm = Path(f"/proc/{pid}/comm").read_text().strip()
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            head, tail = (task / "stat").read_text().rsplit(")", 1)
        except OSError:
            continue
        fields = tail.split()
        seconds = (int(fields[11]) + int(fields[12])) / 100.0
        name = head.split("(", 1)[1]
        if int(task.name) == pid:
            out["main"] += seconds
        else:
            out["udp readers" if name == comm else "zenoh"] += seconds
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", nargs="?")
    parser.add_argument("--skip", type=float, default=30.0, help="seconds of the recording skipped")
    parser.add_argument("--seconds", type=float, default=60.0, help="seconds sent")
    parser.add_argument("--holding-window", type=float, default=0.02)
    parser.add_argument("--json", action="store_true", help="the figures as JSON on stdout")
    parser.add_argument("--serve", help=argparse.SUPPRESS)
    parser.add_argument("--stage", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.serve is not None:
        return serve(args.serve, args.stage)

    recording = read_recording(Path(args.recording))
    everything = list(recording.datagrams())
    start = everything[0].time + args.skip
    datagrams = [d for d in everything if start <= d.time < start + args.seconds]
    plots = sum(len(extract_plots(d.payload).plots) for d in datagrams if d.lan == "A")
    ports = {(d.source, d.lan): 0 for d in everything}
    ports = {key: free_port(socket.SOCK_DGRAM) for key in ports}
    stage = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    work = Path(tempfile.mkdtemp(prefix="bench_radar_role_"))
    config = work / "tracker.json"
    doc = daemon_config(recording.metadata, ports, args.holding_window, stage, None)
    config.write_text(json.dumps(doc), encoding="utf-8")

    zconfig = zenoh.Config()
    zconfig.insert_json5("listen/endpoints", json.dumps([stage]))
    zconfig.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(zconfig)
    received = {"messages": 0, "bytes": 0}

    def count(sample: zenoh.Sample) -> None:
        received["messages"] += 1
        received["bytes"] += len(sample.payload)

    subscriber = session.declare_subscriber("tracker/stage/radars/*/batches", count)
    process = subprocess.Popen(
        [sys.executable, __file__, "--serve", str(config), "--stage", stage],
        stdin=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stdin is not None and process.stderr is not None
    origin = ""
    for line in process.stderr:
        if "imported" in line:
            break
    # The radar process's clock: the first datagram's time at its send.
    sent = [d for d in everything if start - WARM_UP_S <= d.time < start + args.seconds]
    first = sent[0].time
    wall0 = time.time() + START_S
    process.stdin.write(f"{wall0 - first!r}\n")
    process.stdin.flush()
    for line in process.stderr:
        if "tracker_service from" in line:
            origin = line.rsplit(" ", 1)[1].strip()
        if "publishing under" in line:
            break
    log_tail: list[str] = []
    threading.Thread(target=lambda: log_tail.extend(process.stderr or ()), daemon=True).start()
    begin = time.monotonic() + (wall0 - time.time())
    late = 0.0
    cpu0: dict[str, float] | None = None
    messages0 = dict(received)
    cpu_wall0 = time.monotonic()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        for d in sent:
            due = begin + (d.time - first)
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            elif cpu0 is not None:
                late = max(late, -delay)
            if cpu0 is None and d.time >= start:
                cpu0 = thread_cpu(process.pid)
                messages0 = dict(received)
                cpu_wall0 = time.monotonic()
            sock.sendto(d.payload, ("127.0.0.1", ports[d.source, d.lan]))
    time.sleep(0.5)
    assert cpu0 is not None
    cpu1 = thread_cpu(process.pid)
    cpu_wall = time.monotonic() - cpu_wall0
    process.terminate()
    process.wait(timeout=30)
    subscriber.undeclare()  # type: ignore[no-untyped-call]
    session.close()  # type: ignore[no-untyped-call]
    shutil.rmtree(work, ignore_errors=True)
    if received["messages"] == messages0["messages"]:
        print("".join(log_tail[-20:]), file=sys.stderr)
    cpu = {group: cpu1[group] - cpu0[group] for group in cpu0}
    total = sum(cpu.values())
    report = {
        "tracker_service": origin,
        "recording": args.recording,
        "skip_s": args.skip,
        "seconds": args.seconds,
        "plots": plots,
        "datagrams": len(datagrams),
        "messages": received["messages"] - messages0["messages"],
        "message_bytes": received["bytes"] - messages0["bytes"],
        "cpu_s": cpu,
        "cpu_total_s": total,
        "share_of_core": total / cpu_wall,
        "us_per_plot": total / plots * 1e6,
        "us_per_datagram": total / len(datagrams) * 1e6,
        "sender_late_max_s": late,
    }
    if args.json:
        json.dump(report, sys.stdout)
        print()
        return 0
    print(
        f"{Path(args.recording).name} [{args.skip:g}, {args.skip + args.seconds:g}) s: "
        f"{plots:,} plots in {len(datagrams):,} datagrams (both LANs), "
        f"{report['messages']:,} messages ({report['message_bytes'] / 1e6:.1f} MB) from {origin}"
    )
    print(
        f"radar process CPU {total:.2f} s ({total / cpu_wall:.0%} of a core): "
        + ", ".join(f"{g} {s:.2f}" for g, s in cpu.items())
    )
    print(
        f"{report['us_per_plot']:.1f} us per plot, {report['us_per_datagram']:.1f} us per "
        f"datagram; sender late at most {late * 1000:.1f} ms"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
