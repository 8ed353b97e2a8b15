"""The fuser alone on a recording's own traffic: every ``SystemTracker`` call the chain
makes (``references`` and ``process``, with their arguments) recorded once over the first
seconds of a recording, then replayed into a fresh fuser: CPU time of each kind of call,
and a sha256 over every result (the system rows and the references), so that two
versions of the fuser (a ``git archive`` copy on ``PYTHONPATH`` against the worktree)
are compared on the same inputs, for speed and for identity, in seconds rather than the
minute of a whole-chain run (``bench_stages.py``).

    python benchmarks/bench_fusion_calls.py record scale60.mcap --seconds 20 -o calls.pkl
    python benchmarks/bench_fusion_calls.py replay calls.pkl [--repeats 3] [--profile FILE]
        [--split S]

``--split S``: also the distribution of ``process``'s CPU time per batch (p50, p99, max)
and its CPU per local-track update, over the batches whose latest update is before and
after S seconds from the first (the founding burst and the steady state after): the
largest batches set a fusion role's latency tail.

The recording is made with the code in hand; the calls are pickled numpy arrays, to be
read back only from a file of one's own making. A replay's first pass is untimed (numba
loads or compiles the kernels there).
"""

from __future__ import annotations

import argparse
import copy
import cProfile
import dataclasses
import hashlib
import pickle
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

import tracker_service
from tracker_service.fusion import SystemTracker
from tracker_service.service.core import TrackerService

sys.path.insert(0, str(Path(__file__).parent))
from bench_stages import slice_of

Call = tuple[Any, ...]


def record(path: str, seconds: float) -> list[Call]:
    """The calls of the one fuser the service builds, in order: ("init", n_radars,
    config), then ("process" | "references", args, kwargs), deep copies."""
    calls: list[Call] = []
    init, process, references = (
        SystemTracker.__init__,
        SystemTracker.process,
        SystemTracker.references,
    )

    def recording_init(self: SystemTracker, n_radars: int, config: Any = None) -> None:
        calls.append(("init", n_radars, copy.deepcopy(config)))
        init(self, n_radars, config)

    def recorder(kind: str, method: Any) -> Any:
        def call(self: SystemTracker, *args: Any, **kwargs: Any) -> Any:
            calls.append((kind, copy.deepcopy(args), copy.deepcopy(kwargs)))
            return method(self, *args, **kwargs)

        return call

    SystemTracker.__init__ = recording_init
    SystemTracker.process = recorder("process", process)
    SystemTracker.references = recorder("references", references)
    try:
        run_service(path, seconds)
    finally:
        SystemTracker.__init__ = init
        SystemTracker.process = process
        SystemTracker.references = references
    return calls


def run_service(path: str, seconds: float) -> int:
    """The recording's first ``seconds`` through a service without outputs (while a
    benchmark records its calls); the plots its chain took."""
    replay, datagrams = slice_of(path, seconds)
    service = TrackerService(replay.config, None, None)
    for name, datagram in datagrams:
        service.process(name, datagram)
    service.local.drain()
    plots = service.chain.stats.plots
    service.close()
    return plots


Batch = tuple[float, int, float]
"""A ``process`` call's latest update time, updates and CPU seconds."""


def replay(calls: list[Call], batches: list[Batch] | None = None) -> tuple[dict[str, float], str]:
    """CPU seconds of each kind of call, and the sha256 of every result in order; each
    ``process`` call with updates appended to ``batches`` if given."""
    digest = hashlib.sha256()
    cpu = {"process": 0.0, "references": 0.0}
    fuser: SystemTracker | None = None
    for call in calls:
        if call[0] == "init":
            fuser = SystemTracker(call[1], call[2])
            continue
        assert fuser is not None
        kind, args, kwargs = call
        started = time.process_time()
        result = getattr(fuser, kind)(*args, **kwargs)
        elapsed = time.process_time() - started
        cpu[kind] += elapsed
        if kind == "process":
            digest.update(result.tobytes())
            updates = args[1]
            if batches is not None and len(updates):
                batches.append((float(updates["time"].max()), len(updates), elapsed))
        else:
            for field in dataclasses.fields(result):
                digest.update(np.ascontiguousarray(getattr(result, field.name)).tobytes())
    return cpu, digest.hexdigest()


def batch_distribution(batches: list[Batch], split: float) -> str:
    """``process``'s CPU per update and per batch (p50, p99, max), before and after
    ``split`` seconds from the first batch."""
    t, updates, cpu = (np.array(column, dtype=np.float64) for column in zip(*batches, strict=True))
    after = t - t.min() >= split
    lines = []
    for name, part in ((f"first {split:g} s", ~after), ("after", after), ("all", after | ~after)):
        if not part.any():
            continue
        ms = cpu[part] * 1e3
        lines.append(
            f"  {name}: {int(part.sum())} batches, {int(updates[part].sum())} updates, "
            f"{cpu[part].sum() / updates[part].sum() * 1e6:.1f} us per update; per batch "
            f"p50 {np.percentile(ms, 50):.2f} ms, p99 {np.percentile(ms, 99):.2f} ms, "
            f"max {ms.max():.2f} ms"
        )
    return "\n".join(lines)


def record_replay_parser(
    doc: str, calls_of: str, batch_split: bool = False
) -> argparse.ArgumentParser:
    """The command line of a benchmark that records ``calls_of``'s calls once and
    replays them (this one, ``bench_central.py``)."""
    parser = argparse.ArgumentParser(description=doc.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help=f"record {calls_of}'s calls over a recording's start")
    rec.add_argument("recording")
    rec.add_argument("--seconds", type=float, default=20.0)
    rec.add_argument("-o", "--output", required=True)
    rep = sub.add_parser("replay", help=f"replay recorded calls into a fresh {calls_of}")
    rep.add_argument("calls")
    rep.add_argument("--repeats", type=int, default=3)
    rep.add_argument("--profile", help="cProfile (CPU time) of the timed passes into FILE")
    if batch_split:
        rep.add_argument(
            "--split", type=float, help="per-batch CPU before and after S s (see above)"
        )
    return parser


def main() -> None:
    args = record_replay_parser(__doc__, "the fuser", batch_split=True).parse_args()
    if args.command == "record":
        calls = record(args.recording, args.seconds)
        with open(args.output, "wb") as out:
            pickle.dump(calls, out)
        print(f"{len(calls)} calls, {sum(c[0] == 'process' for c in calls)} batches")
        return
    with open(args.calls, "rb") as stream:
        calls = pickle.load(stream)  # a file of one's own recording
    print(f"code: {tracker_service.__file__}")
    replay(calls)  # untimed: numba loads (or compiles) the kernels
    profiler = cProfile.Profile(time.process_time) if args.profile else None
    if profiler is not None:
        profiler.enable()
    for k in range(args.repeats):
        batches: list[Batch] = []
        cpu, digest = replay(calls, batches)
        print(
            f"pass {k + 1}: process {cpu['process']:.3f} CPU s, references "
            f"{cpu['references']:.3f} CPU s, results sha256 {digest}"
        )
        if args.split is not None and batches:
            print(batch_distribution(batches, args.split))
    if profiler is not None:
        profiler.disable()
        profiler.dump_stats(args.profile)


if __name__ == "__main__":
    main()
