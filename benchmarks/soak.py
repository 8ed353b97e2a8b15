"""Soak: the daemon fed the three_sites scenario live on loopback for a long time, with
faults injected, against a clean replay of the same recording.

    .venv/bin/python benchmarks/soak.py                      # 30 minutes
    .venv/bin/python benchmarks/soak.py --minutes 3 --out /tmp/soak

What it does:

1. simulates three_sites for the soak's duration, starting a little in the future, so
   that every plot's I140 matches the wall clock when its datagram is sent (the daemon
   stamps receptions with the wall clock);
2. starts ``tracker-service run`` (a real daemon, config/example.toml with unicast
   inputs on free 127.0.0.1 ports, Mosnik on two LANs) and sends the recording paced in
   real time, both LANs;
3. injects faults all along: ``--fault-rate`` hostile datagrams a second on the radars'
   ports (malformed, random 65,507-byte, records without I010, unknown categories,
   truncated records, plots of ever new unknown SAC/SICs), every real datagram of
   Buchtuv kopec sent twice (repeats on a single LAN), and every ``--burst-every`` s a
   burst of 64 kB datagrams larger than the holding window;
4. samples every ``--sample-s`` s the RSS of the core and of the output process and the
   status the daemon writes into its health file (drops, errors, health, lag);
5. stops it with SIGTERM, then replays the clean recording (``tracker-service replay
   --speed max``) and compares: system tracks per aircraft (distinct track numbers per
   Mode S address) in both, and, per input, datagrams sent = logged + counted
   (duplicates, repeats, malformed, drops): nothing lost that was not counted.

Output in ``--out`` (default a new temporary directory): ``samples.jsonl`` (one JSON
object per sample: ``elapsed_s``, ``core_rss_mb``, ``outputs_rss_mb``, ``health``,
``reasons``, ``drops``, ``decode_errors``, ``duplicates``, ``repeats``, ``lag_s``),
``summary.json`` (the figures below) and ``summary.md``, a Markdown table for
docs/reliability.md, also printed. The daemon's log is ``daemon.log``; its MCAP log is
under ``logs/``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import re
import signal
import socket
import sys
import tempfile
import threading
import time
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.fault_tools import (  # noqa: E402
    CONFIGURED,
    MALFORMED,
    NO_I010,
    DaemonProcess,
    free_port,
    plot_block,
    write_config,
)
from tests.test_service_replay import logged  # noqa: E402
from tracker_service.cli import main as cli  # noqa: E402
from tracker_service.simulator.recording import read_recording  # noqa: E402

SCENARIO = REPO / "config" / "scenarios" / "three_sites.toml"
SIM_S_PER_MINUTE = 4.0
"""Wall seconds the simulator takes per simulated minute, with room (2.3 measured on a
shared machine): the recording starts this far in the future; what the simulation ends
too late to send on time is skipped (and said in the summary)."""


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    except OSError:
        return None
    return None


def simulate(out: Path, seconds: float, start: dt.datetime) -> Path:
    text = SCENARIO.read_text(encoding="utf-8")
    stamp = start.strftime("%Y-%m-%dT%H:%M:%SZ")
    scenario = out / "three_sites_now.toml"
    scenario.write_text(re.sub(r"(?m)^start = .*$", f"start = {stamp}", text), "utf-8")
    recording = out / "three_sites.mcap"
    code = cli(["simulate", str(scenario), "-o", str(recording), "--duration", str(seconds)])
    if code != 0:
        raise SystemExit(f"simulate failed ({code})")
    return recording


class Sender:
    """The recording's datagrams in real time (both LANs), and the faults."""

    def __init__(self, recording: Path, ports: dict[str, int], args: argparse.Namespace) -> None:
        self.datagrams = list(read_recording(recording).datagrams())
        self.ports = ports
        self.args = args
        self.sent: Counter[str] = Counter()
        """Datagrams sent per input name (both LANs of an input together)."""
        self.faults: Counter[str] = Counter()
        self.stop = threading.Event()
        self.skipped = 0
        self._rng = np.random.default_rng(args.seed)
        self._unknown = iter(
            (sac, sic) for sac in range(256) for sic in range(256) if (sac, sic) not in CONFIGURED
        )

    def _port(self, source: str, lan: str) -> int:
        return self.ports[f"{source} B"] if lan == "B" else self.ports[source]

    def run(self) -> None:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDBUF, 4 * 1024 * 1024)
            next_fault = time.time()
            next_burst = time.time() + self.args.burst_every
            for datagram in self.datagrams:
                delay = datagram.time - time.time()
                if delay < -1.0:
                    self.skipped += 1  # the simulation ended after the recording began
                    continue
                while delay > 0:
                    if self.stop.wait(min(delay, 0.05)):
                        return
                    now = time.time()
                    if now >= next_fault:
                        self._fault(sock, now)
                        next_fault += 1.0 / self.args.fault_rate
                    if now >= next_burst:
                        self._burst(sock)
                        next_burst += self.args.burst_every
                    delay = datagram.time - time.time()
                port = self._port(datagram.source, datagram.lan)
                name = datagram.source.replace("/", "_")
                sock.sendto(datagram.payload, ("127.0.0.1", port))
                self.sent[name] += 1
                if datagram.source == "25/12":
                    sock.sendto(datagram.payload, ("127.0.0.1", port))  # a repeat
                    self.sent[name] += 1
                    self.faults["repeat"] += 1

    def _send_fault(self, sock: socket.socket, kind: str, key: str, payload: bytes) -> None:
        sock.sendto(payload, ("127.0.0.1", self.ports[key]))
        self.sent[key.replace("/", "_")] += 1
        self.faults[kind] += 1

    def _fault(self, sock: socket.socket, now: float) -> None:
        rng = self._rng
        key = ["25/11", "25/12", "25/13"][int(rng.integers(3))]
        kind = ["malformed", "random", "no_i010", "unknown_category", "truncated", "unknown"][
            int(rng.integers(6))
        ]
        if kind == "malformed":
            payload = MALFORMED
        elif kind == "random":
            payload = rng.bytes(65507)
        elif kind == "no_i010":
            payload = NO_I010
        elif kind == "unknown_category":
            payload = bytes([99, 0, 8]) + rng.bytes(5)
        elif kind == "truncated":
            payload = bytes([48, 0, 6, 0xF0, 25, 99])
        else:
            sac, sic = next(self._unknown, (0, 0))
            payload = plot_block(sac, sic, now % 86400)
        self._send_fault(sock, kind, key, payload)

    def _burst(self, sock: socket.socket) -> None:
        padding = bytes(64993)
        for n in range(self.args.burst_datagrams):
            payload = bytes([99]) + (65000).to_bytes(2) + n.to_bytes(4) + padding
            self._send_fault(sock, "burst", "25/13", payload)


def tracks_per_aircraft(messages: list[dict[str, Any]]) -> dict[str, int]:
    """Distinct system track numbers per Mode S address."""
    numbers: dict[str, set[int]] = defaultdict(set)
    for m in messages:
        if m.get("address"):
            numbers[m["address"]].add(m["number"])
    return {address: len(n) for address, n in sorted(numbers.items())}


def accounting(log_dir: Path, status: dict[str, Any], sent: Counter[str]) -> dict[str, Any]:
    """Per input: sent, and what the daemon logged or counted of them."""
    logged_per_input: Counter[str] = Counter()
    for message in logged(log_dir):
        if message.topic.startswith("/datagrams/"):
            logged_per_input[message.topic.removeprefix("/datagrams/")] += 1
    out = {}
    for radar in status["radars"]:
        name = radar["radar"].replace("/", "_")
        malformed = radar["decode_errors"] - sum(radar["errors"].values())
        counted = radar["duplicates"] + radar["repeats"] + malformed + radar["drops"]
        out[name] = {
            "sent": sent[name],
            "logged": logged_per_input[name],
            "counted": counted,
            "uncounted": sent[name] - logged_per_input[name] - counted,
            "drop_causes": radar["drop_causes"],
        }
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=30.0)
    parser.add_argument("--out", type=Path)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--fault-rate", type=float, default=5.0, help="hostile datagrams/s")
    parser.add_argument("--burst-every", type=float, default=60.0, help="seconds")
    parser.add_argument("--burst-datagrams", type=int, default=200, help="64 kB each")
    parser.add_argument("--sample-s", type=float, default=10.0)
    args = parser.parse_args()
    out = args.out or Path(tempfile.mkdtemp(prefix="soak-"))
    out.mkdir(parents=True, exist_ok=True)
    seconds = args.minutes * 60.0

    lead = 30.0 + SIM_S_PER_MINUTE * args.minutes
    start = dt.datetime.now(dt.UTC).replace(microsecond=0) + dt.timedelta(seconds=lead)
    print(f"simulating {args.minutes:g} min of three_sites starting {start:%H:%M:%S}Z", flush=True)
    recording = simulate(out, seconds, start)

    config, ports = write_config(out, second_lan=True, log=True)
    daemon = DaemonProcess(config, out / "health")
    sender = Sender(recording, ports, args)
    feeding = threading.Thread(target=sender.run)
    samples = []
    wall0 = time.time()
    feeding.start()
    try:
        with (out / "samples.jsonl").open("w", encoding="utf-8") as stream:
            while feeding.is_alive():
                feeding.join(args.sample_s)
                sample = _sample(daemon, wall0)
                samples.append(sample)
                stream.write(json.dumps(sample) + "\n")
                stream.flush()
                print(
                    f"{sample['elapsed_s']:7.0f} s  core {sample['core_rss_mb']:.0f} MB  "
                    f"outputs {sample['outputs_rss_mb'] or 0:.0f} MB  {sample['health']}  "
                    f"drops {sample['drops']}  errors {sample['decode_errors']}",
                    flush=True,
                )
        time.sleep(3.0)  # the holding window goes by
        code = daemon.stop(timeout=120.0)
        final = daemon.status()  # the last one, written as it stopped
    finally:
        sender.stop.set()
        feeding.join()
        (out / "daemon.log").write_text(daemon.log() + "\n", encoding="utf-8")
        daemon.close()

    faulted_tracks = [m.data for m in logged(out / "logs") if m.topic == "/system_tracks"]
    clean_dir = out / "clean"
    zenoh = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    replay = ["replay", str(recording), "--speed", "max", "--mcap-dir", str(clean_dir)]
    cli([*replay, "--zenoh-listen", zenoh])
    clean_tracks = [m.data for m in logged(clean_dir) if m.topic == "/system_tracks"]
    faulted = tracks_per_aircraft(faulted_tracks)
    clean = tracks_per_aircraft(clean_tracks)
    summary = _summary(args, samples, final, code, sender, faulted, clean, out)
    (out / "summary.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    table = _markdown(summary)
    (out / "summary.md").write_text(table, encoding="utf-8")
    print(table)
    print(f"output in {out}")
    return 0 if code == 0 and summary["uncounted"] == 0 else 1


def _sample(daemon: DaemonProcess, wall0: float) -> dict[str, Any]:
    try:
        status = daemon.status()
    except (OSError, ValueError):
        status = {"radars": [], "health": "unknown", "reasons": [], "lag_s": None}
    try:
        outputs_pid: int | None = daemon.output_process()
    except (AssertionError, OSError):
        outputs_pid = None
    radars = status["radars"]
    return {
        "elapsed_s": round(time.time() - wall0, 1),
        "core_rss_mb": rss_mb(daemon.process.pid),
        "outputs_rss_mb": None if outputs_pid is None else rss_mb(outputs_pid),
        "health": status["health"],
        "reasons": status["reasons"],
        "drops": sum(r["drops"] for r in radars),
        "decode_errors": sum(r["decode_errors"] for r in radars),
        "duplicates": sum(r["duplicates"] for r in radars),
        "repeats": sum(r["repeats"] for r in radars),
        "lag_s": status.get("lag_s"),
    }


def _rss_trend(samples: list[dict[str, Any]], key: str) -> dict[str, float | None]:
    """First, last and largest RSS, and its trend (least squares) over the samples after
    the first quarter of the run (start-up: imports, the first tracks, caches)."""
    points = [(s["elapsed_s"], s[key]) for s in samples if s[key] is not None]
    if len(points) < 4:
        return {"first_mb": None, "last_mb": None, "max_mb": None, "slope_mb_per_h": None}
    t, rss = np.array(points).T
    settled = t >= t[0] + 0.25 * (t[-1] - t[0])
    slope = float(np.polyfit(t[settled], rss[settled], 1)[0]) * 3600.0
    return {
        "first_mb": round(float(rss[0]), 1),
        "last_mb": round(float(rss[-1]), 1),
        "max_mb": round(float(rss.max()), 1),
        "slope_mb_per_h": round(slope, 1),
    }


def _summary(
    args: argparse.Namespace,
    samples: list[dict[str, Any]],
    final: dict[str, Any],
    code: int,
    sender: Sender,
    faulted: dict[str, int],
    clean: dict[str, int],
    out: Path,
) -> dict[str, Any]:
    accounts = accounting(out / "logs", final, sender.sent)
    common = sorted(set(faulted) & set(clean))
    return {
        "minutes": args.minutes,
        "fault_rate_per_s": args.fault_rate,
        "exit_code": code,
        "core_rss": _rss_trend(samples, "core_rss_mb"),
        "outputs_rss": _rss_trend(samples, "outputs_rss_mb"),
        "faults_sent": dict(sender.faults),
        "datagrams_sent": sum(sender.sent.values()),
        "skipped_late": sender.skipped,
        "inputs": accounts,
        "uncounted": sum(a["uncounted"] for a in accounts.values()),
        "aircraft": len(common),
        "tracks_per_aircraft_faulted": round(float(np.mean([faulted[a] for a in common])), 3)
        if common
        else None,
        "tracks_per_aircraft_clean": round(float(np.mean([clean[a] for a in common])), 3)
        if common
        else None,
        "aircraft_with_other_track_count": sum(faulted[a] != clean[a] for a in common),
        "unknown_sources_dropped": final.get("unattributed", {}).get("unknown_sources_dropped"),
        "final_health": final["health"],
        "final_reasons": final["reasons"],
    }


def _markdown(s: dict[str, Any]) -> str:
    core, outputs = s["core_rss"], s["outputs_rss"]
    rows = [
        ("duration", f"{s['minutes']:g} min, {s['datagrams_sent']} datagrams sent"),
        ("faults", ", ".join(f"{k} {v}" for k, v in sorted(s["faults_sent"].items()))),
        (
            "core RSS",
            f"{core['first_mb']} -> {core['last_mb']} MB (max {core['max_mb']}, "
            f"trend after the first quarter {core['slope_mb_per_h']} MB/h)",
        ),
        (
            "output process RSS",
            f"{outputs['first_mb']} -> {outputs['last_mb']} MB (max {outputs['max_mb']}, "
            f"trend {outputs['slope_mb_per_h']} MB/h)",
        ),
        (
            "drops (counted)",
            "; ".join(f"{k}: {v['drop_causes'] or 0}" for k, v in s["inputs"].items() if v["sent"]),
        ),
        ("sent but neither logged nor counted", str(s["uncounted"])),
        (
            "system tracks per aircraft",
            f"{s['tracks_per_aircraft_faulted']} faulted, {s['tracks_per_aircraft_clean']} "
            f"clean ({s['aircraft']} aircraft by Mode S address; "
            f"{s['aircraft_with_other_track_count']} with another count)",
        ),
        ("unknown sources dropped", str(s["unknown_sources_dropped"])),
        ("exit on SIGTERM", str(s["exit_code"])),
    ]
    lines = ["| what | figure |", "| --- | --- |"]
    lines += [f"| {what} | {figure} |" for what, figure in rows]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)
    raise SystemExit(main())
