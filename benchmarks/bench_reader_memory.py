"""Peak memory of the capture readers and the replay's input on large generated captures.

    python benchmarks/bench_reader_memory.py [--pcap-mb 200] [--hex-mb 20] [--json]

Writes, in a temporary directory, a pcap of about ``--pcap-mb`` MB (datagrams of 1,400
bytes, each a CAT048 block of radar 25/11, all different) and a hex dump of one line of
about ``--hex-mb`` MB, then reads each in a fresh process and reports the peak resident
memory above the process's baseline after its imports (VmHWM, reset through
/proc/self/clear_refs) and the peak of the Python heap (tracemalloc), as multiples of the
input size:

- ``read_file``: the container reader alone (``asterix.containers.read_file``);
- ``replay``: what ``tracker-service replay`` feeds the service (``open_replay(...).datagrams``,
  the duplicate filter and the counters included);
- ``decode``: ``tracker-service decode --summary`` (every record decoded).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))

from asterix.containers import write_pcap  # noqa: E402

MB = 1024 * 1024
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

MEASURE = r"""
import io, json, sys, time, tracemalloc
what, path, config = sys.argv[1:4]
from asterix.containers import read_file
from tracker_service.decode import run_decode
from tracker_service.service.config import parse_service_config
from tracker_service.service.replay import open_replay

def status(field):
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith(field + ":"))

with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
base = status("VmRSS")
tracemalloc.start()
start = time.perf_counter()
count = 0
if what == "read_file":
    for item in read_file(path):
        count += 1
elif what == "replay":
    for _ in open_replay(path, parse_service_config(json.loads(config), "bench")).datagrams:
        count += 1
else:
    out = io.StringIO()
    run_decode(__import__("pathlib").Path(path), True, out, io.StringIO())
    count = json.loads(out.getvalue())["datagrams"]
seconds = time.perf_counter() - start
heap = tracemalloc.get_traced_memory()[1]
print(json.dumps({"count": count, "rss": status("VmHWM") - base, "heap": heap,
                  "seconds": seconds}))
"""


def measure(what: str, path: Path) -> dict[str, float]:
    done = subprocess.run(
        [sys.executable, "-c", MEASURE, what, str(path), json.dumps(CONFIG)],
        capture_output=True,
        text=True,
        check=True,
        cwd=REPO,
    )
    result: dict[str, float] = json.loads(done.stdout)
    return result


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--pcap-mb", type=float, default=200.0)
    parser.add_argument("--hex-mb", type=float, default=20.0)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        pcap = Path(tmp) / "large.pcap"
        header = bytes((48, 1400 >> 8, 1400 & 0xFF, 0x80, 25, 11))
        frames = round(args.pcap_mb * MB / 1458)
        write_pcap(
            pcap,
            (
                (
                    1.78e9 + k * 0.001,
                    ("10.0.0.1", 5000),
                    ("232.1.1.1", 8600),
                    header + k.to_bytes(4) * 348 + bytes(2),
                )
                for k in range(frames)
            ),
        )
        hexdump = Path(tmp) / "long.hex"
        record = bytes(range(256)) * round(args.hex_mb * MB / 3 / 256)
        hexdump.write_text(" ".join(f"{b:02x}" for b in record) + "\n", encoding="ascii")
        for what, path in (
            ("read_file", pcap),
            ("replay", pcap),
            ("decode", pcap),
            ("read_file", hexdump),
        ):
            size = path.stat().st_size
            started = time.perf_counter()
            result = measure(what, path)
            rows.append(
                {
                    "input": path.name,
                    "reader": what,
                    "size_mb": size / MB,
                    "units": result["count"],
                    "peak_rss_mb": result["rss"] / MB,
                    "rss_per_input": result["rss"] / size,
                    "peak_heap_mb": result["heap"] / MB,
                    "heap_per_input": result["heap"] / size,
                    "seconds": time.perf_counter() - started,
                }
            )
    if args.json:
        print(json.dumps(rows, indent=2))
        return 0
    head = ("input", "reader", "MB", "units", "RSS MB", "x in", "heap MB", "x in", "s")
    print("{:12} {:10} {:>7} {:>8} {:>8} {:>6} {:>8} {:>6} {:>6}".format(*head))
    for r in rows:
        print(
            f"{r['input']:12} {r['reader']:10} {r['size_mb']:7.1f} {r['units']:8d} "
            f"{r['peak_rss_mb']:8.1f} {r['rss_per_input']:6.2f} {r['peak_heap_mb']:8.1f} "
            f"{r['heap_per_input']:6.2f} {r['seconds']:6.1f}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
