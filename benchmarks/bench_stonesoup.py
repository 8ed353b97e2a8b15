"""Our local tracker against Stone Soup 1.9.1 on the same plot stream, in the same run:
plots/s of each and the ratio (issue 12).

The stream is bench_tracking's synthetic radar (straight-flying traffic around one radar,
5 s period, 16 sectors, sigma 50 m / 0.06 deg, primary plots without identity), fed sector
by sector to both. Stone Soup (GNN + Kalman filter on a constant-velocity model, two-point
initiator, deletion after 2.5 periods without update: see stonesoup_peer.py) runs in its
own venv in a subprocess (``python -I``); ours is ``LocalTracker`` with its defaults (a
5-model IMM, k-d tree pre-selection, GNN, M-of-N confirmation, vertical filter idle on
these plots). Both time every batch, initiation included, in CPU seconds of their own
process (``time.process_time``: the machine is shared); repeats are interleaved so
machine noise hits both alike; medians are printed.

    bash benchmarks/setup_stonesoup.sh
    python benchmarks/bench_stonesoup.py [--aircraft 100] [--scans 20] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_tracking import PERIOD_S, sector_batches

from tracker_service.tracking import CONFIRMED, LocalTracker, TrackerConfig

HERE = Path(__file__).resolve().parent
PEER_PYTHON = HERE / ".venvs" / "stonesoup" / "bin" / "python"
PEER_SCRIPT = HERE / "stonesoup_peer.py"


def ours(batches: list[np.ndarray]) -> tuple[float, int]:
    """Seconds over every batch and the confirmed tracks at the end."""
    tracker = LocalTracker(TrackerConfig(scan_period_s=PERIOD_S))
    started = time.process_time()
    for batch in batches:
        tracker.process(batch)
    elapsed = time.process_time() - started
    return elapsed, int(np.count_nonzero(tracker.tracks["status"] == CONFIRMED))


def stonesoup(stream: Path) -> tuple[float, int]:
    done = subprocess.run(
        [str(PEER_PYTHON), "-I", str(PEER_SCRIPT), str(stream), str(PERIOD_S), "1"],
        check=True,
        capture_output=True,
        text=True,
    )
    report = json.loads(done.stdout)
    return float(report["seconds"][0]), int(report["tracks"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aircraft", type=int, default=100)
    parser.add_argument("--scans", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    if not PEER_PYTHON.exists():
        sys.exit(f"{PEER_PYTHON} missing: run bash benchmarks/setup_stonesoup.sh first")
    batches = sector_batches(args.aircraft, args.scans, seed=args.aircraft)
    plots = sum(len(b) for b in batches)
    ours([b.copy() for b in batches[: 5 * 16]])  # the compiled kernels loaded before the clock
    with tempfile.TemporaryDirectory(prefix="bench_stonesoup") as tmp:
        stream = Path(tmp) / "stream.npz"
        joined = np.concatenate(batches)
        np.savez(
            stream,
            time=joined["time"],
            x=joined["x"],
            y=joined["y"],
            R=joined["R"],
            batch=np.repeat(np.arange(len(batches)), [len(b) for b in batches]),
        )
        times: dict[str, list[float]] = {"ours": [], "stonesoup": []}
        tracks: dict[str, int] = {}
        for repeat in range(args.repeats):
            elapsed, tracks["ours"] = ours(batches)
            times["ours"].append(elapsed)
            elapsed, tracks["stonesoup"] = stonesoup(stream)
            times["stonesoup"].append(elapsed)
            print(
                f"repeat {repeat + 1}: ours {times['ours'][-1]:.2f} s,"
                f" stonesoup {times['stonesoup'][-1]:.2f} s",
                file=sys.stderr,
            )
    print(
        f"{args.aircraft} aircraft, {args.scans} scans, {plots:,} plots in"
        f" {len(batches)} sector batches; median of {args.repeats}"
    )
    print(f"{'tracker':<28} {'plots/s':>10} {'tracks at end':>14}")
    rate = {name: plots / statistics.median(t) for name, t in times.items()}
    print(f"{'ours (LocalTracker, IMM-5)':<28} {rate['ours']:>10,.0f} {tracks['ours']:>14}")
    print(
        f"{'Stone Soup 1.9.1 (GNN + KF)':<28} {rate['stonesoup']:>10,.0f} {tracks['stonesoup']:>14}"
    )
    print(f"ratio ours / Stone Soup: {rate['ours'] / rate['stonesoup']:.1f}x")


if __name__ == "__main__":
    main()
