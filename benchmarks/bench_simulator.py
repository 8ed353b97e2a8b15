"""Simulator speed: wall and CPU time to simulate a scenario, against the simulated time.

Target (issue 3): the `scale` scenario (20 radars, 2,000 aircraft) for 10 minutes in less
than 10 minutes of wall time. The ratio simulated/wall is the figure to quote; the
machine is shared, so run it when it is quiet and quote the median of --repeats.

    python benchmarks/bench_simulator.py [--scenario config/scenarios/scale.toml]
        [--duration 600] [--repeats 1] [--suffix .mcap]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import tempfile
import time
from pathlib import Path

from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", default=str(REPO / "config/scenarios/scale.toml"))
    parser.add_argument("--duration", type=float, default=600.0)
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--suffix", default=".mcap", choices=[".mcap", ".pcap", ".raw"])
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    walls, cpus, reports = [], [], 0
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / f"bench{args.suffix}"
        for _ in range(args.repeats):
            wall, cpu = time.perf_counter(), time.process_time()
            summary = simulate(scenario, out, duration_s=args.duration)
            walls.append(time.perf_counter() - wall)
            cpus.append(time.process_time() - cpu)
            reports = sum(summary.plots.values())
        size = out.stat().st_size
    wall = statistics.median(walls)
    result = {
        "scenario": scenario.name,
        "simulated_s": args.duration,
        "radars": len(scenario.radars),
        "aircraft": summary.aircraft,
        "reports": reports,
        "datagrams": summary.datagrams,
        "output_bytes": size,
        "wall_s_median": round(wall, 1),
        "cpu_s_median": round(statistics.median(cpus), 1),
        "simulated_per_wall": round(args.duration / wall, 2),
        "reports_per_wall_s": round(reports / wall),
        "machine": f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
        f"Python {platform.python_version()}",
    }
    print(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
