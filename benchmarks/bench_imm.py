"""The IMM step alone (prediction, gate test, update with the combination: what the local
tracker runs per track-plot pair), numpy reference against the compiled kernels, in CPU
microseconds per pair for batches of k pairs (a sector brings about 10). Issue 12
measured 27 us per track update for the numpy IMM and 2.6-2.9 us as a compiled loop.

    python benchmarks/bench_imm.py [--sizes 1 10 100 1000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

from tracker_service.tracking import TrackerConfig
from tracker_service.tracking.imm import ImmFilter, make_imm
from tracker_service.tracking.models import ModelSet


def pairs(k: int, models: ModelSet, seed: int) -> tuple[np.ndarray, ...]:
    rng = np.random.default_rng(seed)
    m = models.n_models
    x = np.empty((k, m, 4))
    x[..., :2] = rng.uniform(-2e5, 2e5, (k, 1, 2)) + rng.normal(0, 100, (k, m, 2))
    x[..., 2:] = rng.uniform(-250, 250, (k, 1, 2)) + rng.normal(0, 5, (k, m, 2))
    p = np.broadcast_to(np.diag([2500.0, 2500.0, 100.0, 100.0]), (k, m, 4, 4)).copy()
    mu = rng.dirichlet(np.ones(m), k)
    dt = rng.uniform(3.0, 5.0, k)
    z = x[:, 0, :2] + rng.normal(0, 50, (k, 2))
    r = np.broadcast_to(np.eye(2) * 2500.0, (k, 2, 2)).copy()
    return x, p, mu, dt, z, r


def step_seconds(imm: ImmFilter, data: tuple[np.ndarray, ...], loops: int) -> float:
    x, p, mu, dt, z, r = data
    started = time.process_time()
    for _ in range(loops):
        pred = imm.predict(x, p, mu, dt)
        imm.innovation_test(pred, z, r)
        imm.update(pred, z, r)
    return (time.process_time() - started) / loops


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[1, 10, 100, 1000])
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    models = ModelSet.from_config(TrackerConfig())
    filters = {name: make_imm(name, models) for name in ("numpy", "compiled")}
    data = {k: pairs(k, models, k) for k in args.sizes}
    for imm in filters.values():
        step_seconds(imm, data[args.sizes[0]], 1)  # the kernels loaded before the clock
    seconds: dict[tuple[str, int], list[float]] = {}
    for _ in range(args.repeats):
        for k in args.sizes:
            loops = max(1, 2000 // k)
            for name, imm in filters.items():
                seconds.setdefault((name, k), []).append(step_seconds(imm, data[k], loops))
    print(f"IMM step ({models.n_models} models), CPU us per pair, median of {args.repeats}")
    print(f"{'pairs':>7} {'numpy':>9} {'compiled':>9} {'ratio':>6}")
    for k in args.sizes:
        numpy_us = statistics.median(seconds["numpy", k]) / k * 1e6
        compiled_us = statistics.median(seconds["compiled", k]) / k * 1e6
        print(f"{k:>7} {numpy_us:>9.2f} {compiled_us:>9.2f} {numpy_us / compiled_us:>6.1f}")


if __name__ == "__main__":
    main()
