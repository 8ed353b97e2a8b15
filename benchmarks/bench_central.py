"""The central stage alone on a recording's own traffic: every ``CentralStage`` call the
chain makes (``process`` of each radar batch, ``feed_adsb`` of each CAT021 datagram's
reports, with their arguments; the reports' decoding, ``decode_adsb``, is the core's)
recorded once over the first seconds of a recording, then replayed into a fresh central
stage: CPU time per plot of the whole stage (time consensus, bias correction, bias
observations and estimation, the fuser's references, fusion, and the stage's own glue),
split as ``bench_stages.py`` splits it, and a sha256 over every output (plots, local
updates, system rows, time reports) and the bias estimates at the end. Two versions (a
``git archive`` copy on ``PYTHONPATH`` against the worktree) are compared on the same
inputs, for speed and identity, in seconds rather than the minute of a whole-chain run;
what the main process of ``replay --workers N`` does, less the service's glue and the
outputs.

    python benchmarks/bench_central.py record scale60.mcap --seconds 20 -o central.pkl
    python benchmarks/bench_central.py replay central.pkl [--repeats 3] [--profile FILE]

The recording is made with the code in hand; the calls are pickled numpy arrays and
dataclasses, to be read back only from a file of one's own making. A replay's first pass
is untimed (numba loads or compiles the kernels there).
"""

from __future__ import annotations

import copy
import cProfile
import hashlib
import pickle
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

import tracker_service
from tracker_service.central_stage import BatchOutput, CentralStage
from tracker_service.fusion import SystemTracker

sys.path.insert(0, str(Path(__file__).parent))
from bench_fusion_calls import record_replay_parser, run_service
from bench_stages import StageClock

Call = tuple[Any, ...]
CALLS = ("process", "feed_adsb")
PARTS = ("bias", "bias references", "fusion")
"""The parts of the stage ``bench_stages.py`` names; the rest is the stage's own glue."""


def record(path: str, seconds: float) -> tuple[list[Call], int]:
    """The calls of the one central stage the service builds, in order: ("init", args,
    kwargs), then (name, args, kwargs), deep copies taken before the call (``process``
    renumbers its batch in place); and the chain's plot count, the per-plot figures'
    denominator (``bench_stages.py``'s)."""
    calls: list[Call] = []
    originals = {name: getattr(CentralStage, name) for name in ("__init__", *CALLS)}

    def recorder(name: str) -> Callable[..., Any]:
        method = originals[name]

        def call(self: CentralStage, *args: Any, **kwargs: Any) -> Any:
            calls.append((name, copy.deepcopy(args), copy.deepcopy(kwargs)))
            return method(self, *args, **kwargs)

        return call

    for name in originals:
        setattr(CentralStage, name, recorder(name))
    try:
        plots = run_service(path, seconds)
    finally:
        for name, method in originals.items():
            setattr(CentralStage, name, method)
    return calls, plots


def digest_output(digest: Any, output: BatchOutput) -> None:
    digest.update(output.source.encode())
    for array in (output.plots, output.local, output.system):
        digest.update(np.ascontiguousarray(array).tobytes())
    digest.update(repr(output.time).encode())


def replay(calls: list[Call]) -> tuple[float, str]:
    """The central stage's CPU seconds over the calls, and the sha256 of every output in
    order, then of its bias estimates at the end. The stage writes into its batches (plot
    ids): the calls are copies of the recorded ones."""
    digest = hashlib.sha256()
    stage: CentralStage | None = None
    cpu = 0.0
    for name, args, kwargs in calls:
        if name == "__init__":
            stage = CentralStage(*args, **kwargs)
            continue
        assert stage is not None
        started = time.process_time()
        result = getattr(stage, name)(*args, **kwargs)
        cpu += time.process_time() - started
        for output in result if isinstance(result, list) else [result]:
            digest_output(digest, output)
    assert stage is not None
    for source, (s, p) in stage.bias_estimates().items():
        digest.update(source.encode() + s.tobytes() + p.tobytes())
    return cpu, digest.hexdigest()


def instrument(clock: StageClock) -> list[tuple[type, str, Any]]:
    """``bench_stages.py``'s timers on the stage's parts (undone by ``restore``); the
    stage's own way to the fuser's references where it has one (a version without is
    timed all the same: a base copy)."""
    targets = [
        (CentralStage, "_estimate_biases", "bias"),
        (CentralStage, "_references", "bias references"),
        (SystemTracker, "references", "bias references"),
        (SystemTracker, "process", "fusion"),
    ]
    saved = []
    for owner, name, stage in targets:
        if name not in vars(owner):
            continue
        original = vars(owner)[name]
        saved.append((owner, name, original))
        setattr(owner, name, clock.wrap(stage, original))
    return saved


def restore(saved: list[tuple[type, str, Any]]) -> None:
    for owner, name, original in reversed(saved):
        setattr(owner, name, original)


def main() -> None:
    args = record_replay_parser(__doc__, "the central stage").parse_args()
    if args.command == "record":
        calls, plots = record(args.recording, args.seconds)
        with open(args.output, "wb") as out:
            pickle.dump((calls, plots), out)
        batches = sum(c[0] == "process" for c in calls)
        print(f"{len(calls)} calls, {batches} radar batches, {plots} plots")
        return
    with open(args.calls, "rb") as stream:
        calls, plots = pickle.load(stream)  # a file of one's own recording
    print(f"code: {tracker_service.__file__}")
    replay(copy.deepcopy(calls))  # untimed: numba loads (or compiles) the kernels
    profiler = cProfile.Profile(time.process_time) if args.profile else None
    totals: list[float] = []
    parts: dict[str, list[float]] = {p: [] for p in PARTS}
    for k in range(args.repeats):
        fresh = copy.deepcopy(calls)
        clock = StageClock()
        saved = instrument(clock)
        if profiler is not None:
            profiler.enable()
        try:
            cpu, digest = replay(fresh)
        finally:
            if profiler is not None:
                profiler.disable()
            restore(saved)
        totals.append(cpu)
        for part in PARTS:
            parts[part].append(clock.seconds[part])
        split = ", ".join(f"{p} {clock.seconds[p] / plots * 1e6:.1f}" for p in PARTS)
        glue = cpu - sum(clock.seconds[p] for p in PARTS)
        print(
            f"pass {k + 1}: {cpu:.3f} CPU s, {cpu / plots * 1e6:.1f} us per plot ({split},"
            f" glue {glue / plots * 1e6:.1f}), results sha256 {digest}"
        )
    median = statistics.median(totals)
    print(
        f"median: {median:.3f} CPU s, {median / plots * 1e6:.1f} us per plot over {plots}"
        f" plots ({plots / median:,.0f} plots per CPU-second); "
        + ", ".join(f"{p} {statistics.median(parts[p]) / plots * 1e6:.1f}" for p in PARTS)
    )
    if profiler is not None:
        profiler.dump_stats(args.profile)


if __name__ == "__main__":
    main()
