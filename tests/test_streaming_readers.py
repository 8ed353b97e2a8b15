"""Captures are read in bounded memory, whatever their size: the hex reader, the other
container readers and the replay stream (peak memory measured in a subprocess, with the
input generated); a service log cut short decodes to what it holds, without a traceback."""

from __future__ import annotations

import io
import json
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from asterix.containers import Datagram, write_pcap
from tracker_service.decode import run_decode
from tracker_service.outputs.mcap_log import McapLog, read_log_messages
from tracker_service.service.config import parse_service_config
from tracker_service.service.replay import CONFIG_METADATA, open_replay

MB = 1024 * 1024

# Reads a capture in another process and prints its peak memory beside the baseline, in
# bytes. Memory is capped (address space: baseline + 400 MB) so that a reader that would
# not stream fails with MemoryError instead of taking the machine's memory.
MEASURE = r"""
import json, resource, sys, tracemalloc
what, path = sys.argv[1:3]
from asterix.containers import read_file
from tracker_service.service.config import parse_service_config
from tracker_service.service.replay import CONFIG_METADATA, open_replay
from tracker_service.service.config import parse_service_config

def status(field):
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith(field + ":"))

resource.setrlimit(resource.RLIMIT_AS, (status("VmSize") + 400 * 2**20, resource.RLIM_INFINITY))
# The peak RSS from here on: clear_refs 5 resets the high-water mark (Linux >= 4.0).
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
base = status("VmRSS")
tracemalloc.start()
count = size = 0
if what == "file":
    items = read_file(path)
else:
    config = parse_service_config(json.loads(sys.argv[3]), "test")
    items = (d for _name, d in open_replay(path, config).datagrams)
for item in items:
    count += 1
    size += len(getattr(item, "payload", b""))
heap = tracemalloc.get_traced_memory()[1]
peak = status("VmHWM")
print(json.dumps({"count": count, "bytes": size, "rss": peak - base, "heap": heap}))
"""

CONFIG = {
    "radars": [
        {
            "name": "a",
            "sac": 25,
            "sic": 11,
            "lat": 45.0,
            "lon": 16.0,
            "alt_m": 100.0,
            "antenna_period_s": 4.0,
            "sigma_range_m": 50.0,
            "sigma_azimuth_deg": 0.08,
        }
    ],
    "system": {"centre_lat": 45.0, "centre_lon": 16.0, "sac": 25, "sic": 100},
}


def measure(*args: str) -> dict[str, int]:
    done = subprocess.run(
        [sys.executable, "-c", MEASURE, *args], capture_output=True, text=True, timeout=120
    )
    assert done.returncode == 0, done.stderr[-2000:]
    result: dict[str, int] = json.loads(done.stdout)
    return result


def test_a_long_hex_line_is_read_in_a_small_multiple_of_its_size(tmp_path: Path) -> None:
    # One 20 MB line: a dump of one huge "datagram" (3 characters a byte).
    path = tmp_path / "long.hex"
    record = bytes(range(256)) * 26_000
    path.write_text(" ".join(f"{b:02x}" for b in record) + "\n", encoding="ascii")
    size = path.stat().st_size
    assert size > 19 * MB
    result = measure("file", str(path))
    assert result == result | {"count": 1, "bytes": len(record)}
    # The line, its text and the payload: a few times the line, not 110 times.
    assert result["rss"] < 4 * size, result
    assert result["heap"] < 3 * size, result


def test_replay_of_a_large_capture_streams(tmp_path: Path) -> None:
    # 20 MB of pcap: 15,000 datagrams of 1,400 bytes, each a CAT048 block of radar 25/11.
    path = tmp_path / "large.pcap"
    header = bytes((48, 1400 >> 8, 1400 & 0xFF, 0x80, 25, 11))
    start = 1.78e9
    count = write_pcap(
        path,
        (
            # Each one different: the replay drops a second LAN's copies.
            (
                start + k * 0.01,
                ("10.0.0.1", 5000),
                ("232.1.1.1", 8600),
                header + k.to_bytes(4) * 348 + bytes(2),
            )
            for k in range(15_000)
        ),
    )
    size = path.stat().st_size
    assert size > 20 * MB
    result = measure("replay", str(path), json.dumps(CONFIG))
    assert result["count"] == count
    # Neither the file nor its datagrams held at once: a window of pages and a datagram.
    assert result["rss"] < size // 2, result
    assert result["heap"] < size // 10, result


# Logs datagrams with the service's MCAP log until killed; says "ready" once 2,000 are in.
WRITER = r"""
import sys
from asterix.containers import Datagram
from tracker_service.outputs.mcap_log import McapLog
log = McapLog(sys.argv[1], chunk_size=4096)
k = 0
while True:
    payload = bytes((48, 0, 12, 0x80, 25, 11)) + k.to_bytes(6)
    log.log_datagram(Datagram(payload, k, 1.78e9 + k * 0.01, None, None), "25_11")
    k += 1
    if k == 2000:
        print("ready", flush=True)
"""


def decode(path: Path) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    out, err = io.StringIO(), io.StringIO()
    assert run_decode(path, True, out, err) == 0
    events = [json.loads(line) for line in err.getvalue().splitlines()]
    # The payloads are not meant to decode: only the container's errors count here.
    return json.loads(out.getvalue()), [e for e in events if e["error"] == "container"]


def test_decode_and_replay_of_a_log_killed_while_writing(tmp_path: Path) -> None:
    writer = subprocess.Popen(
        [sys.executable, "-c", WRITER, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    assert writer.stdout is not None and writer.stdout.readline().strip() == "ready"
    writer.send_signal(signal.SIGKILL)
    writer.wait(timeout=10)
    (path,) = tmp_path.glob("*.mcap")
    summary, errors = decode(path)
    assert summary["datagrams"] >= 1500
    assert len(errors) <= 1
    assert all("cut short" in e["reason"] for e in errors)
    logged = list(read_log_messages(path))
    assert len(logged) == summary["datagrams"]


def test_decode_of_a_log_cut_anywhere_reads_what_it_holds(tmp_path: Path) -> None:
    config = parse_service_config(CONFIG, "test")
    metadata = {CONFIG_METADATA: {"config": config.model_dump_json()}}
    with McapLog(tmp_path / "log", chunk_size=2048, metadata=metadata) as log:
        for k in range(3000):
            payload = bytes((48, 0, 12, 0x80, 25, 11)) + k.to_bytes(6)
            log.log_datagram(Datagram(payload, k, 1.78e9 + k * 0.01, None, None), "25_11")
    data = log.files[0].read_bytes()
    # Inside the magic and the header, then all through the file.
    cuts = [*range(0, 120, 7), *range(120, len(data), len(data) // 20), len(data)]
    previous = 0
    for cut in cuts:
        path = tmp_path / f"cut_{cut}.mcap"
        path.write_bytes(data[:cut])
        summary, errors = decode(path)
        assert summary["datagrams"] >= previous, cut
        previous = summary["datagrams"]
        assert len(errors) == (0 if cut in (0, len(data)) else 1), (cut, errors)
        if cut >= 8:
            # A replay reads the same datagrams, or, cut before the configuration it
            # logged, says in one line why it cannot.
            try:
                replay = open_replay(path)
            except ValueError as exc:
                assert summary["datagrams"] == 0 and "MCAP" in str(exc), (cut, exc)
            else:
                assert sum(1 for _ in replay.datagrams) == summary["datagrams"]
    assert previous == 3000
