"""Plot extraction (``asterix.plots.extract_plots``) on real CAT048 and CAT001 feeds.

    python benchmarks/bench_plots.py [--repeats R] [--json]

Two ways for each recording of shared/data/asterix: datagram by datagram, as the chain
calls it (real CAT001 radars send one plot a datagram, so the per-call cost counts), and
on the whole recording's data blocks joined into one buffer (the array path at its best).
Prints plots/s and microseconds per datagram, medians over R runs.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))

from asterix.containers import Datagram, read_file  # noqa: E402
from asterix.plots import extract_plots  # noqa: E402

DATA = Path(os.environ.get("TRACKER_SHARED_DIR", REPO.parent / "shared")) / "data/asterix"
RECORDINGS = {
    "CAT048 068test_bds30.gps": "reader_network/068test_bds30.gps",
    "CAT048 cat_034_048.pcap": "croatiacontrol/cat_034_048.pcap",
    "CAT001 canalA.gps": "reader_network/canalA.gps",
}


def _seconds(payloads: list[bytes], repeats: int) -> tuple[int, float]:
    runs = []
    plots = 0
    for _ in range(repeats):
        start = time.perf_counter()
        plots = sum(len(extract_plots(p).plots) for p in payloads)
        runs.append(time.perf_counter() - start)
    return plots, statistics.median(runs)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    results = {}
    for label, relative in RECORDINGS.items():
        path = DATA / relative
        if not path.is_file():
            print(f"{label}: {path} is absent, skipped", file=sys.stderr)
            continue
        payloads = [u.payload for u in read_file(path) if isinstance(u, Datagram)]
        extract_plots(b"".join(payloads[:200]))  # warm-up: walkers and plans
        plots, per_datagram = _seconds(payloads, args.repeats)
        _, joined = _seconds([b"".join(payloads)], args.repeats)
        results[label] = {
            "datagrams": len(payloads),
            "plots": plots,
            "per_datagram_plots_per_s": plots / per_datagram,
            "per_datagram_us": per_datagram / len(payloads) * 1e6,
            "joined_plots_per_s": plots / joined,
        }
    if args.json:
        print(json.dumps(results, indent=2))
        return 0
    for label, r in results.items():
        print(
            f"{label:<26} {r['datagrams']:>6} datagrams {r['plots']:>6} plots: "
            f"by datagram {r['per_datagram_plots_per_s']:>9,.0f} plots/s "
            f"({r['per_datagram_us']:.0f} us each), joined {r['joined_plots_per_s']:>9,.0f} plots/s"
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
