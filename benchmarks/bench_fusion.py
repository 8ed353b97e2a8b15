"""Fusion speed: local-track updates per CPU-second, and how the cost per update grows
with traffic (issue 12: at least 20,000 updates/s, less than 1.5x from 200 to 4,000
aircraft), with the bias stage's fuser references timed beside it.

Synthetic traffic over a `scale`-like region: 20 radars on a 5 x 4 grid 150 km apart
(periods 4-12 s, 16 sectors each, range 250 km), aircraft flying straight at random
positions, headings and speeds; each radar sends, per sector, one confirmed local-track
update per aircraft it sees, with its plot (50 m noise), as the chain gives the fuser.
The fuser gets exactly what ``Chain`` gives it per batch: ``references`` (the bias
observations' reference), then ``process`` with a residual-bias covariance per update.
The first two periods of the longest radar (system tracks being created) are not timed.

Each size is run --repeats times, interleaved, with each ``FusionConfig.implementation``
asked for ("compiled": fusion/kernels.py; "numpy": the reference); medians are printed with
the ratio of the cost per update to the smallest size, and the speed-up of the compiled
fuser over the numpy one. The first run of each is a warm-up (numba loads or compiles its
kernels), not timed. --baseline REV times the fuser of git revision REV
(its fusion/tracker.py, e.g. the monolithic one before the split) on the same batches,
side by side, for an old/new ratio.

    python benchmarks/bench_fusion.py [--sizes 200 1000 4000] [--duration 60] [--repeats 3]
        [--method plots] [--implementations compiled numpy] [--baseline 06133d7]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.tracking import PLOT_DTYPE, LocalTracker

REPO = Path(__file__).resolve().parents[1]
GRID = (5, 4)
SPACING_M = 150e3
RANGE_M = 250e3
SECTORS = 16
SIGMA_M = 50.0
T0 = 1.78e9


@dataclass
class Batch:
    radar: int
    updates: npt.NDArray[Any]
    plots: npt.NDArray[Any]
    extra: npt.NDArray[np.float64]


def traffic(n_aircraft: int, duration_s: float, seed: int) -> list[Batch]:
    """Every radar's sector batches in the order of their last plot's time."""
    rng = np.random.default_rng(seed)
    gx, gy = GRID
    sites = np.array(
        [
            ((i - (gx - 1) / 2) * SPACING_M, (j - (gy - 1) / 2) * SPACING_M)
            for i in range(gx)
            for j in range(gy)
        ]
    )
    periods = rng.choice([4.0, 5.0, 6.0, 8.0, 10.0, 12.0], len(sites))
    half = np.array([gx, gy]) * SPACING_M / 2
    start = rng.uniform(-half, half, (n_aircraft, 2))
    heading = rng.uniform(0, 2 * np.pi, n_aircraft)
    speed = rng.uniform(120.0, 250.0, n_aircraft)
    velocity = np.column_stack([speed * np.sin(heading), speed * np.cos(heading)])
    address = rng.choice(0xFFFFFE, n_aircraft, replace=False) + 1
    code = rng.choice(4096, n_aircraft, replace=n_aircraft > 4096)
    dtype = LocalTracker().output_dtype
    p_local = np.diag([SIGMA_M**2, SIGMA_M**2, 25.0, 25.0]).reshape(16)
    timed: list[tuple[float, Batch]] = []
    plot_id = 0
    for radar, (site, period) in enumerate(zip(sites, periods, strict=True)):
        phase = rng.uniform(0, period)
        for scan in range(int(duration_s / period)):
            t_scan = phase + scan * period
            pos = start + velocity * t_scan
            d = pos - site
            seen = np.flatnonzero(np.hypot(d[:, 0], d[:, 1]) < RANGE_M)
            azimuth = np.arctan2(d[seen, 0], d[seen, 1]) % (2 * np.pi)
            t = t_scan + azimuth / (2 * np.pi) * period
            sector = np.floor(azimuth / (2 * np.pi) * SECTORS).astype(np.int64)
            for s in range(SECTORS):
                pick = sector == s
                ac, tk = seen[pick], t[pick]
                if ac.size == 0:
                    continue
                truth = start[ac] + velocity[ac] * tk[:, None]
                plots = np.zeros(ac.size, dtype=PLOT_DTYPE)
                plots["time"] = T0 + tk
                noisy = truth + rng.normal(0.0, SIGMA_M, truth.shape)
                plots["x"], plots["y"] = noisy.T
                plots["R"] = np.eye(2) * SIGMA_M**2
                plots["flight_level"], plots["fl_valid"] = 300.0, True
                plots["mode3a"], plots["mode3a_valid"] = code[ac], True
                plots["address"], plots["typ"] = address[ac], 5
                plots["plot_id"] = plot_id + np.arange(ac.size)
                plot_id += ac.size
                updates = np.zeros(ac.size, dtype=dtype)
                updates["track_number"] = ac + 1
                updates["time"] = plots["time"]
                updates["x"], updates["y"] = (noisy + rng.normal(0.0, 0.5 * SIGMA_M, truth.shape)).T
                updates["vx"], updates["vy"] = (velocity[ac] + rng.normal(0.0, 3.0, truth.shape)).T
                updates["P"] = p_local
                updates["flight_level"] = 300.0
                updates["status"] = 1  # confirmed
                updates["plot_id"] = plots["plot_id"]
                updates["mode3a"], updates["address"] = code[ac], address[ac]
                updates["model_probabilities"] = 1.0 / dtype["model_probabilities"].shape[0]
                extra = np.broadcast_to(np.eye(2) * 30.0**2, (ac.size, 2, 2)).copy()
                timed.append((float(tk.max()), Batch(radar, updates, plots, extra)))
    timed.sort(key=lambda b: b[0])
    return [b for _, b in timed]


def load_baseline(revision: str) -> type[SystemTracker]:
    """``SystemTracker`` of fusion/tracker.py at ``revision`` (its other modules: today's)."""
    source = subprocess.run(
        ["git", "-C", str(REPO), "show", f"{revision}:tracker_service/fusion/tracker.py"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    path = Path(tempfile.mkdtemp()) / "baseline_tracker.py"
    path.write_text(source, encoding="utf-8")
    spec = importlib.util.spec_from_file_location("baseline_tracker", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["baseline_tracker"] = module
    spec.loader.exec_module(module)
    cls: type[SystemTracker] = module.SystemTracker
    return cls


@dataclass
class Timing:
    updates: int
    process_s: float
    references_s: float
    system_tracks: int


def time_fuser(cls: type[SystemTracker], batches: list[Batch], config: FusionConfig) -> Timing:
    fuser = cls(20, config)
    warm_until = batches[0].plots["time"].min() + 2 * config.longest_period_s
    n = 0
    t_process = t_refs = 0.0
    for b in batches:
        timed = b.plots["time"].min() >= warm_until
        c0 = time.process_time()
        fuser.references(b.radar, b.updates, b.plots)
        c1 = time.process_time()
        fuser.process(b.radar, b.updates, b.plots, b.extra)
        c2 = time.process_time()
        if timed:
            n += len(b.updates)
            t_refs += c1 - c0
            t_process += c2 - c1
    return Timing(n, t_process, t_refs, int(fuser.system_tracks.size))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[200, 1000, 4000])
    parser.add_argument("--duration", type=float, default=60.0)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--method", choices=("plots", "tracks"), default="plots")
    parser.add_argument(
        "--implementations", nargs="+", choices=("compiled", "numpy"), default=["compiled", "numpy"]
    )
    parser.add_argument("--baseline", help="git revision whose fusion/tracker.py to compare")
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    fusers: dict[str, tuple[type[SystemTracker], FusionConfig]] = {
        impl: (
            SystemTracker,
            FusionConfig(method=args.method, longest_period_s=12.0, implementation=impl),
        )
        for impl in args.implementations
    }
    if args.baseline:
        old = (
            load_baseline(args.baseline),
            FusionConfig(method=args.method, longest_period_s=12.0),
        )
        fusers = {f"old ({args.baseline})": old, **fusers}
    data = {n: traffic(n, args.duration, args.seed) for n in args.sizes}
    for cls, config in fusers.values():  # warm-up: numba's kernels loaded (or compiled)
        time_fuser(cls, traffic(50, 30.0, args.seed), config)
    results: dict[tuple[str, int], list[Timing]] = {}
    for _ in range(args.repeats):
        for n in args.sizes:
            for name, (cls, config) in fusers.items():
                results.setdefault((name, n), []).append(time_fuser(cls, data[n], config))
    print(
        f"method {args.method}, {args.duration:.0f} s of traffic, {args.repeats} repeats (medians)"
    )
    print(
        "fuser            aircraft  sys.tracks  updates  process upd/s  refs us/upd"
        "  both upd/s  us/upd ratio"
    )
    base: dict[str, float] = {}
    for name in fusers:
        for n in args.sizes:
            runs = results[(name, n)]
            upd = runs[0].updates
            proc = statistics.median(r.process_s for r in runs)
            refs = statistics.median(r.references_s for r in runs)
            both = statistics.median(r.process_s + r.references_s for r in runs)
            per = both / upd * 1e6
            base.setdefault(name, per)
            print(
                f"{name:16s} {n:8d} {runs[0].system_tracks:11d} {upd:8d} {upd / proc:14,.0f}"
                f" {refs / upd * 1e6:12.1f} {upd / both:11,.0f} {per:7.1f} {per / base[name]:5.2f}"
            )
    for n in args.sizes if "compiled" in fusers else []:
        cost = {
            name: statistics.median(r.process_s + r.references_s for r in results[(name, n)])
            for name in fusers
        }
        for name in (other for other in fusers if other != "compiled"):
            speed_up = cost[name] / cost["compiled"]
            print(f"speed-up compiled/{name} at {n} aircraft: {speed_up:.2f}x")


if __name__ == "__main__":
    main()
