"""The fuser's per-batch table work with its tables packed (one structured array each, as
before) and column by column (``fusion.table.Columns``, as now), interleaved in one run.

A state of ``--aircraft`` live system tracks, each fed by ``--radars`` local tracks (21
radars' sensitivities, as on `scale` with ADS-B), is built once and copied into the packed
layout; each batch of ``--batch`` system tracks then runs what every radar batch runs over
the whole tables: the silent tracks' end, the open tracks, the gate's pre-selection, the
orphans' end, the slots of the fed tracks and merging. CPU time, median of the repeats.

    python benchmarks/bench_fusion_tables.py [--aircraft 2000] [--radars 10] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import FusionConfig, associate, lifecycle
from tracker_service.fusion.estimator import SystemEstimator, make_system_estimator
from tracker_service.fusion.state import FusionState
from tracker_service.fusion.table import KEY_SHIFT, Columns
from tracker_service.tracking import LocalTracker
from tracker_service.tracking.models import ModelSet

SOURCES = 21


def build(aircraft: int, radars: int, seed: int = 1) -> FusionState:
    rng = np.random.default_rng(seed)
    config = FusionConfig()
    state = FusionState(config, SOURCES, ModelSet.from_config(config.plot_filter))
    sys, n = state.sys, np.arange(1, aircraft + 1)
    sys["alive"][n] = True
    sys["t"][n] = sys["t_plot"][n] = rng.uniform(0.0, 4.0, n.size)
    sys["mx"][n, :, :2] = rng.uniform(-4e5, 4e5, (n.size, 1, 2))
    sys["mx"][n, :, 2:] = rng.uniform(-250.0, 250.0, (n.size, 1, 2))
    sys["mP"][n] = sys["P"][n] = np.eye(4) * 100.0
    sys["mu"][n] = 1.0 / state.models.n_models
    sys["x"][n] = sys["mx"][n, 0]
    sys["M"][n] = rng.normal(0.0, 0.3, (n.size, SOURCES, 4, 2))
    sys["B"][n] = np.eye(2) * 50.0
    sys["address"][n] = sys["mode3a"][n] = n
    for radar in range(radars):
        u = np.zeros(aircraft, dtype=LocalTracker().output_dtype)
        u["track_number"] = n
        u["plot_id"] = -1
        rows = state.local.find(radar, u)
        loc = state.local.rows
        loc["system"][rows] = n
        loc["status"][rows] = 1
        loc["t"][rows] = loc["t_plot"][rows] = sys["t"][n]
        loc["x"][rows] = sys["x"][n]
        loc["P"][rows] = np.eye(4) * 100.0
    state.now = 4.0
    return state


def packed(table: Columns) -> npt.NDArray[Any]:
    """The same table as one structured array (the layout before ``Columns``)."""
    rows = np.zeros(len(table), dtype=table.dtype)
    for name in table.dtype.names or ():
        rows[name] = table[name]
    return rows


def batch(state: FusionState, estimator: SystemEstimator, numbers: npt.NDArray[Any]) -> None:
    lifecycle.expire(state, 0)
    candidates = associate.open_systems(state, 0)
    free = state.local._lookup((np.int64(3) << KEY_SHIFT) | numbers)
    associate._near(state, estimator, free, candidates)
    lifecycle.orphan(state, 0, numbers)
    state.local.slots(numbers, state.config.max_sources)
    lifecycle.merge(state, 0, numbers)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--aircraft", type=int, default=2000)
    parser.add_argument("--radars", type=int, default=10, help="local tracks per aircraft")
    parser.add_argument("--batch", type=int, default=30)
    parser.add_argument("--batches", type=int, default=40, help="per repeat")
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    estimator = make_system_estimator("plots")
    old, new = build(args.aircraft, args.radars), build(args.aircraft, args.radars)
    old.sys = packed(old.sys)  # type: ignore[assignment]
    old.local.rows = packed(old.local.rows)  # type: ignore[assignment]
    every = np.arange(1, args.aircraft + 1)
    times: dict[str, list[float]] = {"packed": [], "columns": []}
    for repeat in range(args.repeats + 1):  # the first: numba's kernels loaded, not counted
        for name, state in (("packed", old), ("columns", new)):
            rng = np.random.default_rng(repeat)
            started = time.process_time()
            for _ in range(args.batches):
                batch(state, estimator, np.sort(rng.choice(every, args.batch, replace=False)))
            if repeat:
                times[name].append((time.process_time() - started) / args.batches)
    ratios = [a / b for a, b in zip(times["packed"], times["columns"], strict=True)]
    for name, values in times.items():
        print(f"{name:8} {statistics.median(values) * 1e3:7.2f} ms per batch")
    print(
        f"packed / columns: median {statistics.median(ratios):.2f}"
        f" (min {min(ratios):.2f}, max {max(ratios):.2f}), {args.repeats} repeats"
    )


if __name__ == "__main__":
    main()
