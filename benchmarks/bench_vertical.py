"""CPU per update of the compiled vertical step: the IMM (``kernels.vertical_update``)
against the 2-state filter it replaced, from a copy of main's kernels module.

    git show main:tracker_service/tracking/kernels.py > /tmp/old_kernels.py
    .venv/bin/python benchmarks/bench_vertical.py --old /tmp/old_kernels.py
"""

from __future__ import annotations

import argparse
import importlib.util
import time
from pathlib import Path
from types import ModuleType

import numpy as np

from tracker_service.tracking import TrackerConfig, kernels

TRACKS, BATCH = 200, 20


def load(path: Path) -> ModuleType:
    spec = importlib.util.spec_from_file_location("old_kernels", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def two_state(old: ModuleType, calls: int) -> float:
    rng = np.random.default_rng(0)
    fl = rng.uniform(100, 400, TRACKS)
    rate, pv = np.zeros(TRACKS), np.tile(np.eye(2) * 0.01, (TRACKS, 1, 1))
    t_fl, ok, rejects = np.zeros(TRACKS), np.ones(TRACKS, bool), np.zeros(TRACKS, np.int64)
    rows, z, var = np.arange(BATCH), fl[:BATCH].copy(), np.full(BATCH, 0.0052)
    start = time.process_time()
    for k in range(calls):
        t = np.full(BATCH, 5.0 * (k + 1))
        old.vertical_update(rows, t, z, var, fl, rate, pv, t_fl, ok, rejects, 0.02, 16.0, 2, 1.0)
    return (time.process_time() - start) / (calls * BATCH)


def imm(calls: int) -> float:
    cfg = TrackerConfig()
    rng = np.random.default_rng(0)
    xv = np.zeros((TRACKS, 3, 2))
    xv[:, :, 0] = rng.uniform(100, 400, (TRACKS, 1))
    pvm = np.tile(np.eye(2) * 0.01, (TRACKS, 3, 1, 1))
    muv = np.full((TRACKS, 3), 1 / 3)
    fl, rate, pv = xv[:, 0, 0].copy(), np.zeros(TRACKS), np.zeros((TRACKS, 2, 2))
    t_fl, ok, rejects = np.zeros(TRACKS), np.ones(TRACKS, bool), np.zeros(TRACKS, np.int64)
    rows, z, var = np.arange(BATCH), fl[:BATCH].copy(), np.full(BATCH, 0.0052)
    nan = np.full(BATCH, np.nan)
    constants = (
        np.array(cfg.vertical_q), np.array(cfg.vertical_sojourn_s),
        np.array(cfg.vertical_initial_probabilities), cfg.fl_gate, cfg.fl_max_rejects,
        cfg.initial_climb_variance, cfg.level_rate_variance,
    )  # fmt: skip
    start = time.process_time()
    for k in range(calls):
        t = np.full(BATCH, 5.0 * (k + 1))
        kernels.vertical_update(
            rows, t, z, var, nan, nan, nan, xv, pvm, muv, fl, rate, pv, t_fl, ok, rejects,
            *constants,
        )  # fmt: skip
    return (time.process_time() - start) / (calls * BATCH)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--old", type=Path, required=True, help="a copy of main's kernels.py")
    parser.add_argument("--calls", type=int, default=20000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    old = load(args.old)
    two_state(old, 10), imm(10)  # compiled (or loaded) before timing
    for _ in range(args.repeats):
        a, b = two_state(old, args.calls), imm(args.calls)
        print(f"2-state {a * 1e6:.3f} us/update, IMM {b * 1e6:.3f} us/update, ratio {b / a:.2f}")


if __name__ == "__main__":
    main()
