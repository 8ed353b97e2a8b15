"""Fixed-transponder detection speed: plots/s of ``FixedTargets.classify`` on one core.

Synthetic Mode S traffic flying straight around one radar (5 s period, 16 sectors, one
sector per batch, sigma 100 m), with 5 stationary site monitors on 7777; the first 5
scans are not timed. Each size is timed --repeats times; medians are printed, with the
cost per plot against the smallest size (the stage must stay a small share of the local
tracker's, whose target is 20,000 plots/s).

    python benchmarks/bench_fixed_targets.py [--sizes 100 500 2000] [--scans 25] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.chain import RAW_PLOT_DTYPE
from tracker_service.fixed_targets import FixedTargets
from tracker_service.geodesy import RadarSite, SystemPlane

PERIOD_S = 5.0
SECTORS = 16
SIGMA_M = 100.0
MONITORS = 5


def sector_tables(targets: int, scans: int, seed: int) -> list[npt.NDArray[Any]]:
    rng = np.random.default_rng(seed)
    n = targets + MONITORS
    radius = rng.uniform(10e3, 300e3, n)
    bearing = rng.uniform(0.0, 2 * np.pi, n)
    start = np.stack([radius * np.sin(bearing), radius * np.cos(bearing)], axis=1)
    speed = np.concatenate([rng.uniform(60.0, 250.0, targets), np.zeros(MONITORS)])
    course = rng.uniform(0.0, 2 * np.pi, n)
    velocity = np.stack([speed * np.sin(course), speed * np.cos(course)], axis=1)
    address = np.arange(n, dtype=np.int64) + 0x300000
    code = np.concatenate([rng.integers(0o1000, 0o6777, targets), np.full(MONITORS, 0o7777)])
    tables = []
    for scan in range(scans):
        position = start + velocity * (scan * PERIOD_S)
        position += rng.normal(0.0, SIGMA_M, position.shape)
        theta = np.degrees(np.arctan2(position[:, 0], position[:, 1])) % 360.0
        sector = (theta // (360.0 / SECTORS)).astype(int)
        for s in range(SECTORS):
            rows = np.flatnonzero(sector == s)
            table = np.zeros(len(rows), RAW_PLOT_DTYPE)
            table["time"] = scan * PERIOD_S + theta[rows] / 360.0 * PERIOD_S
            table["x"], table["y"] = position[rows, 0], position[rows, 1]
            table["R"] = np.eye(2) * SIGMA_M**2
            table["address"], table["mode3a"] = address[rows], code[rows]
            table["rho_m"] = np.hypot(position[rows, 0], position[rows, 1])
            table["theta_deg"] = theta[rows]
            tables.append(table)
    return tables


def time_once(tables: list[npt.NDArray[Any]]) -> tuple[float, int, int]:
    stage = FixedTargets(RadarSite(48.0, 17.0, 0.0), SystemPlane(48.0, 17.0), PERIOD_S)
    warm = 5 * SECTORS
    fixed = 0
    for table in tables[:warm]:
        stage.classify(table, np.ones(len(table), bool), np.ones(len(table), bool))
    plots = sum(len(t) for t in tables[warm:])
    started = time.perf_counter()
    for table in tables[warm:]:
        found = stage.classify(table, np.ones(len(table), bool), np.ones(len(table), bool))
        fixed += int(found.fixed.sum())
    return time.perf_counter() - started, plots, fixed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[100, 500, 2000])
    parser.add_argument("--scans", type=int, default=25)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    base: float | None = None
    for size in args.sizes:
        tables = sector_tables(size, args.scans, seed=size)
        runs = [time_once(tables) for _ in range(args.repeats)]
        seconds = statistics.median(r[0] for r in runs)
        plots, fixed = runs[0][1], runs[0][2]
        per_plot = seconds / plots
        base = per_plot if base is None else base
        print(
            f"{size:5d} aircraft: {plots / seconds:10,.0f} plots/s, "
            f"{per_plot * 1e6:6.2f} us/plot ({per_plot / base:4.2f}x), "
            f"{fixed} plots fixed (site monitors: {MONITORS * (args.scans - 5)})"
        )


if __name__ == "__main__":
    main()
