"""Local tracking speed: plots/s on one core, and how the cost per plot grows with traffic.

Targets (issue 12): at least 50,000 plots/s per core for a dense terminal area (`tma`),
fed as the radar sends them (one sector per batch), and a cost per plot that grows by
less than 1.5x from 200 to 4,000 aircraft. Synthetic straight-flying traffic around one
radar (5 s period, 16 sectors, sigma 50 m / 0.06 deg); the first 5 scans (initiation)
are not timed. Each size and each ``--implementations`` (``TrackerConfig.implementation``:
the compiled kernels and the numpy reference) is timed --repeats times, interleaved;
medians are printed with the ratio to the smallest size.

    python benchmarks/bench_tracking.py [--sizes 200 1000 4000] [--scans 25] [--repeats 3]

With --recording, it times the trackers on a simulated recording instead (for the `tma`
target: `tracker-service simulate config/scenarios/tma.toml -o tma.mcap --no-bias`): the
batches each radar's tracker receives through the evaluation pipeline are collected once,
then fed to fresh trackers of each implementation, --repeats times interleaved; only
`process` is timed.

    python benchmarks/bench_tracking.py --recording tma.mcap

--associations (``TrackerConfig.association``, default gnn) times the associators side by
side the same way (issue 13: JPDA at most 2x and MHT at most 5x GNN's cost per plot on
`tma`, still flat with traffic); with several, a last table gives each one's cost per
plot over GNN's, on the recording and each size in one run (docs/association.md, "Cost
of the associators, session 8"):

    python benchmarks/bench_tracking.py --recording tma.mcap --sizes 200 2000 \
        --implementations compiled --associations gnn jpda mht --repeats 5

--compare feeds the recording's batches to a compiled and a numpy tracker of each
association instead, and prints how their outputs differ (integer fields: rows that
differ; floats: the largest difference relative to max(1, |value|)).
"""

from __future__ import annotations

import argparse
import statistics
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from tracker_service.evaluation.pipeline import run_pipeline
from tracker_service.geodesy import polar_covariance
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig

PERIOD_S = 5.0
SECTORS = 16
SIGMA_RHO_M = 50.0
SIGMA_THETA_DEG = 0.06


def sector_batches(targets: int, scans: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    radius = rng.uniform(10e3, 300e3, targets)
    bearing = rng.uniform(0.0, 2 * np.pi, targets)
    start = np.stack([radius * np.sin(bearing), radius * np.cos(bearing)], axis=1)
    speed = rng.uniform(120.0, 250.0, targets)
    course = rng.uniform(0.0, 2 * np.pi, targets)
    velocity = np.stack([speed * np.sin(course), speed * np.cos(course)], axis=1)
    batches = []
    for scan in range(scans):
        # Detection time: when the beam (clockwise from north) crosses each target.
        position = start + velocity * (scan * PERIOD_S)
        theta = np.degrees(np.arctan2(position[:, 0], position[:, 1])) % 360.0
        t = scan * PERIOD_S + theta / 360.0 * PERIOD_S
        position = start + velocity * t[:, None]
        rho = np.hypot(position[:, 0], position[:, 1])
        theta = np.degrees(np.arctan2(position[:, 0], position[:, 1])) % 360.0
        rho_m = rho + rng.normal(0.0, SIGMA_RHO_M, targets)
        theta_m = theta + rng.normal(0.0, SIGMA_THETA_DEG, targets)
        plots = np.zeros(targets, dtype=PLOT_DTYPE)
        plots["time"] = 1.78e9 + t
        plots["x"] = rho_m * np.sin(np.radians(theta_m))
        plots["y"] = rho_m * np.cos(np.radians(theta_m))
        plots["R"] = polar_covariance(rho_m, theta_m, SIGMA_RHO_M, SIGMA_THETA_DEG)
        plots["flight_level"] = np.nan
        plots["mode3a"] = -1
        plots["address"] = -1
        plots["typ"] = 2
        plots["plot_id"] = scan * targets + np.arange(targets)
        sector = (theta // (360.0 / SECTORS)).astype(int)
        for s in range(SECTORS):
            chosen = plots[sector == s]
            batches.append(chosen[np.argsort(chosen["time"])])
    return batches


def run_once(
    batches: list[np.ndarray], warm_up: int, implementation: str, association: str = "gnn"
) -> tuple[float, int]:
    config = TrackerConfig(
        scan_period_s=PERIOD_S, implementation=implementation, association=association
    )
    tracker = LocalTracker(config)
    for batch in batches[:warm_up]:
        tracker.process(batch)
    timed = batches[warm_up:]
    started = time.process_time()
    for batch in timed:
        tracker.process(batch)
    return time.process_time() - started, sum(len(b) for b in timed)


class RecordingTracker(LocalTracker):
    """A LocalTracker that keeps a copy of every batch it is given."""

    def __init__(self, config: TrackerConfig) -> None:
        super().__init__(config)
        self.batches: list[np.ndarray] = []

    def process(self, plots: np.ndarray) -> np.ndarray:  # type: ignore[override]
        self.batches.append(np.array(plots, copy=True))
        return super().process(plots)


def recorded_batches(path: str) -> tuple[dict[str, RecordingTracker], dict[str, float]]:
    """The trackers of the recording's radars, holding the batches each was given, and
    each radar's period."""
    trackers: dict[str, RecordingTracker] = {}

    def make(source: str, config: TrackerConfig) -> LocalTracker:
        trackers[source] = RecordingTracker(config)
        return trackers[source]

    result = run_pipeline(path, make_tracker=make)
    return trackers, {source: run.info.period_s for source, run in result.radars.items()}


def bench_recording(
    path: str, implementations: list[str], repeats: int, associations: list[str]
) -> dict[str, float]:
    """Prints the recording's table; returns each variant's seconds per plot."""
    trackers, periods = recorded_batches(path)
    seconds: dict[tuple[str, str], list[float]] = {}
    variants = [f"{i}/{a}" for i in implementations for a in associations]
    for _ in range(repeats):
        for variant in variants:
            implementation, association = variant.split("/")
            for source, recorded in trackers.items():
                config = replace(
                    recorded.config, implementation=implementation, association=association
                )
                tracker = LocalTracker(config)
                started = time.process_time()
                for batch in recorded.batches:
                    tracker.process(batch)
                elapsed = time.process_time() - started
                seconds.setdefault((variant, source), []).append(elapsed)
    print(f"{path}: median of {repeats}")
    print(
        f"{'implementation':>18} {'radar':>7} {'period s':>9} {'plots':>8} {'plots/batch':>12}"
        f" {'us/batch':>9} {'plots/s':>10}"
    )
    per_plot = {}
    for variant in variants:
        total_plots, total_seconds = 0, 0.0
        for source, period in periods.items():
            batches = trackers[source].batches
            plots = sum(len(b) for b in batches)
            elapsed = statistics.median(seconds[variant, source])
            total_plots += plots
            total_seconds += elapsed
            print(
                f"{variant:>18} {source:>7} {period:>9.1f} {plots:>8} "
                f"{plots / len(batches):>12.1f} {elapsed / len(batches) * 1e6:>9.0f} "
                f"{plots / elapsed:>10,.0f}"
            )
        print(
            f"{variant:>18} {'all':>7} {'':>9} {total_plots:>8} {'':>12} {'':>9}"
            f" {total_plots / total_seconds:>10,.0f}"
            f" ({total_seconds / total_plots * 1e6:.1f} us/plot)"
        )
        per_plot[variant] = total_seconds / total_plots
    return per_plot


def compare_recording(path: str, associations: list[str]) -> None:
    """The compiled and the numpy tracker of each association on the recording's batches,
    batch by batch: rows whose integer fields differ, the largest float difference."""
    trackers, _ = recorded_batches(path)
    integers = ("track_number", "status", "plot_id", "address", "mode3a")
    floats = ("x", "y", "vx", "vy", "P", "model_probabilities")
    for association in associations:
        differing, worst, rows = 0, 0.0, 0
        for recorded in trackers.values():
            pair = [
                LocalTracker(replace(recorded.config, implementation=i, association=association))
                for i in ("numpy", "compiled")
            ]
            for batch in recorded.batches:
                a, b = (tracker.process(batch) for tracker in pair)
                rows += len(a)
                if len(a) != len(b):
                    differing += max(len(a), len(b))
                    continue
                same = np.ones(len(a), dtype=bool)
                for field in integers:
                    same &= a[field] == b[field]
                differing += int(np.count_nonzero(~same))
                for field in floats:
                    x, y = a[field][same], b[field][same]
                    if x.size:
                        gap = np.abs(x - y) / np.maximum(1.0, np.abs(x))
                        worst = max(worst, float(np.nanmax(gap, initial=0.0)))
        print(
            f"{association}: {rows} rows, {differing} with other integers, largest float"
            f" difference {worst:.1e} (relative to max(1, |value|))"
        )


def print_ratios(per_plot: dict[str, dict[str, float]], associations: list[str]) -> None:
    """Each association's cost per plot over GNN's, for each data set and implementation."""
    print("cost per plot over GNN's (medians)")
    print(f"{'data':>13} {'implementation':>15} " + " ".join(f"{a:>12}" for a in associations))
    for data, by_variant in per_plot.items():
        for implementation in sorted({v.split("/")[0] for v in by_variant}):
            cost = [by_variant[f"{implementation}/{a}"] for a in associations]
            gnn = by_variant[f"{implementation}/gnn"]
            cells = " ".join(f"{c / gnn:>6.2f} ({c * 1e6:>3.0f})" for c in cost)
            print(f"{data:>13} {implementation:>15} {cells}")
    print("(in brackets: us per plot)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--sizes",
        type=int,
        nargs="+",
        help="aircraft (default 200 1000 4000, none with --recording)",
    )
    parser.add_argument("--scans", type=int, default=25)
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--recording", help="time the trackers on this simulated recording")
    parser.add_argument(
        "--implementations", nargs="+", default=["compiled", "numpy"], help="TrackerConfig"
    )
    parser.add_argument("--associations", nargs="+", default=["gnn"], help="TrackerConfig")
    parser.add_argument(
        "--compare", action="store_true", help="compiled against numpy on --recording"
    )
    args = parser.parse_args()
    if args.compare:
        if not args.recording:
            parser.error("--compare needs --recording")
        compare_recording(args.recording, args.associations)
        return
    # Loads (or compiles, after an install) the kernels before any clock runs.
    for association in args.associations:
        run_once(sector_batches(20, 8, seed=0), 0, "compiled", association)
    per_plot: dict[str, dict[str, float]] = {}
    if args.recording:
        per_plot[Path(args.recording).stem] = bench_recording(
            args.recording, args.implementations, args.repeats, args.associations
        )
    sizes = args.sizes or ([] if args.recording else [200, 1000, 4000])
    if sizes:
        per_plot.update(
            bench_sizes(sizes, args.scans, args.repeats, args.implementations, args.associations)
        )
    if "gnn" in args.associations and len(args.associations) > 1:
        print_ratios(per_plot, args.associations)


def bench_sizes(
    sizes: list[int],
    scans: int,
    repeats: int,
    implementations: list[str],
    associations: list[str],
) -> dict[str, dict[str, float]]:
    """Prints the synthetic traffic's table; returns each size's seconds per plot by
    variant."""
    data = {n: sector_batches(n, scans, seed=n) for n in sizes}
    seconds: dict[tuple[str, int], list[float]] = {}
    plots: dict[int, int] = {}
    variants = [f"{i}/{a}" for i in implementations for a in associations]
    for _ in range(repeats):
        for variant in variants:
            implementation, association = variant.split("/")
            for n in sizes:
                elapsed, count = run_once(data[n], 5 * SECTORS, implementation, association)
                seconds.setdefault((variant, n), []).append(elapsed)
                plots[n] = count
    print(f"median of {repeats}")
    print(
        f"{'implementation':>18} {'aircraft':>9} {'plots/s':>10} {'us/plot':>9} {'cost ratio':>11}"
    )
    per_plot: dict[str, dict[str, float]] = {f"{n} aircraft": {} for n in sizes}
    for variant in variants:
        base = None
        for n in sizes:
            cost = statistics.median(seconds[variant, n]) / plots[n]
            per_plot[f"{n} aircraft"][variant] = cost
            base = base or cost
            print(
                f"{variant:>18} {n:>9} {1 / cost:>10,.0f} {cost * 1e6:>9.1f} {cost / base:>11.2f}"
            )
    return per_plot


if __name__ == "__main__":
    main()
