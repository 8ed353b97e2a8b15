"""CPU time per plot of every stage of the whole service, side by side in one run, and the
whole chain's plots per CPU-second (issue 12, "Speed, one process").

The recording is replayed through ``TrackerService`` as ``tracker-service replay --speed
max`` runs it in one process, every output on: a Zenoh session (peer mode, loopback only,
no scouting) and an MCAP log in a temporary directory. Each stage's entry point is wrapped
by a timer of the CPU time of the calling thread (``time.thread_time``); nested stages are
exclusive (the bias step's time excludes the fusion and reference calls it makes, the
message building excludes the sink calls). The sinks run in their output threads
(``outputs.sink.QueuedSink``): their time is their thread's own. "other" is the
process's CPU time (``time.process_time``, every thread, Zenoh's own threads included)
minus the stages: the service's glue, the duplicate filter, queues, Zenoh internals.
The recording is read into memory before the clock starts. A first, untimed run over its
first 12 s (``--warmup-seconds``) loads (or compiles) the numba kernels of the tracker
and the fuser.

    tracker-service simulate config/scenarios/scale.toml -o scale60.mcap --duration 60
    python benchmarks/bench_stages.py scale60.mcap [--seconds 30] [--repeats 1]
        [--no-mcap] [--no-zenoh] [--fusion-implementation compiled|numpy] [--json]
        [--profile FILE]

The stages and what each wraps:

| stage | wrapped |
|---|---|
| decode | ``extract_plots`` and the service messages' ``decode_blocks`` (radar stage) |
| ADS-B decode | ``CentralStage.decode_adsb``: CAT021 reports, once a datagram (the core's call) |
| clock + conversion | ``convert_batch`` (plot clock, geodesy), time sanity, fixed targets |
| local tracking | ``LocalTracker.process`` |
| central stage | ``CentralStage.process``, ``feed_adsb`` less the three below (its own work) |
| bias | ``CentralStage._estimate_biases`` (observations, the estimator's update) |
| bias references | ``SystemTracker.references`` (the fuser's references for the bias) |
| fusion | ``SystemTracker.process`` |
| messages | ``Outputs.batch``, ``publish_cat062`` and the periodic messages, less the rest |
| CAT062 | ``PeriodRecords.update`` and ``block`` (the records, the block), ``encode_cat065`` |
| MCAP | ``McapSink``'s calls (the log's writer thread) |
| Foxglove map | ``FoxgloveSink``'s calls less its ``McapSink`` calls (the map in the log) |
| Zenoh | ``ZenohSink``'s calls (the publisher's thread) |
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import functools
import gc
import json
import os
import statistics
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

import tracker_service
from asterix.containers import Datagram
from tracker_service import radar_stage as radar_stage_module
from tracker_service.central_stage import CentralStage
from tracker_service.fusion import SystemTracker
from tracker_service.outputs.cat062 import PeriodRecords
from tracker_service.outputs.foxglove_sink import FoxgloveSink
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.mcap_sink import McapSink
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_sink import ZenohSink
from tracker_service.radar_stage import RadarStage
from tracker_service.service import core as core_module
from tracker_service.service.core import Outputs, TrackerService
from tracker_service.service.replay import open_replay
from tracker_service.time_sanity import TimeSanity
from tracker_service.tracking import LocalTracker

STAGES = (
    "decode",
    "ADS-B decode",
    "clock + conversion",
    "local tracking",
    "central stage",
    "bias",
    "bias references",
    "fusion",
    "messages",
    "CAT062",
    "MCAP",
    "Foxglove map",
    "Zenoh",
)
SINK_CALLS = (
    "datagram",
    "system",
    "local",
    "system_updates",
    "local_updates",
    "asterix",
    "bias",
    "status",
    "close",
)


class StageClock:
    """Exclusive CPU seconds per stage, per thread: a stage called from within another is
    taken off the outer one."""

    def __init__(self) -> None:
        self.seconds = dict.fromkeys(STAGES, 0.0)
        self.calls = dict.fromkeys(STAGES, 0)
        self._lock = threading.Lock()
        self._local = threading.local()

    def wrap(self, stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        @functools.wraps(fn)
        def timed(*args: Any, **kwargs: Any) -> Any:
            stack: list[float] = self._local.__dict__.setdefault("stack", [])
            stack.append(0.0)  # time of the stages nested in this call
            started = time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                elapsed = time.thread_time() - started
                nested = stack.pop()
                if stack:
                    stack[-1] += elapsed
                with self._lock:
                    self.seconds[stage] += elapsed - nested
                    self.calls[stage] += 1

        return timed


@contextlib.contextmanager
def instrumented(clock: StageClock) -> Iterator[None]:
    """Every stage's entry point wrapped for the duration (restored afterwards)."""
    targets: list[tuple[object, str, str]] = [
        (radar_stage_module, "extract_plots", "decode"),
        (radar_stage_module, "decode_blocks", "decode"),
        (CentralStage, "decode_adsb", "ADS-B decode"),
        (radar_stage_module, "convert_batch", "clock + conversion"),
        (TimeSanity, "check", "clock + conversion"),
        (RadarStage, "_fixed_transponders", "clock + conversion"),
        (LocalTracker, "process", "local tracking"),
        (CentralStage, "process", "central stage"),
        (CentralStage, "feed_adsb", "central stage"),
        (CentralStage, "_estimate_biases", "bias"),
        (SystemTracker, "references", "bias references"),
        (SystemTracker, "process", "fusion"),
        (Outputs, "batch", "messages"),
        (Outputs, "publish_cat062", "messages"),
        (Outputs, "publish_bias", "messages"),
        (Outputs, "publish_status", "messages"),
        (Outputs, "close", "messages"),
        (PeriodRecords, "update", "CAT062"),
        (PeriodRecords, "block", "CAT062"),
        (core_module, "encode_cat065", "CAT062"),
    ]
    targets += [(McapSink, call, "MCAP") for call in SINK_CALLS]
    targets += [(FoxgloveSink, call, "Foxglove map") for call in SINK_CALLS]
    targets += [(ZenohSink, call, "Zenoh") for call in SINK_CALLS]
    saved = []
    for owner, name, stage in targets:
        original = getattr(owner, name, None)
        if original is None:
            # Another helper moved it: say so rather than time it as "other" silently.
            print(f"bench_stages: {owner.__name__}.{name} not found, not timed", file=sys.stderr)  # type: ignore[attr-defined]
            continue
        own = name in vars(owner)
        saved.append((owner, name, original, own))
        setattr(owner, name, clock.wrap(stage, original))
    try:
        yield
    finally:
        for owner, name, original, own in reversed(saved):
            if own:
                setattr(owner, name, original)
            else:
                delattr(owner, name)


OUTPUT_STAGES = ("messages", "CAT062", "MCAP", "Foxglove map", "Zenoh")
FUSER_COUNTS = (
    "system_tracks_created",
    "system_tracks_ended",
    "system_tracks_merged",
    "numbers_reused_early",
    "numbers_exhausted",
)


class Windows:
    """``--windows S``: the replay's work by window of ``S`` seconds of data time (the
    datagrams' reception times from the first), each window a row: plots, CPU seconds
    of the process and of the stages, the slowest datagram (``TrackerService.process``,
    CPU of the main thread), the full collections of the cyclic collector (count, wall
    time), and the fuser's state at the window's end: live system tracks, local-track
    table rows (used, alive) and its counters' growth (tracks created, ended, merged;
    founders refused for want of a free number). A window that costs more than its
    neighbours for the same plots is the fuser's or the outputs' own doing, whatever the
    host does to a live run."""

    def __init__(self, seconds: float) -> None:
        self.seconds = seconds
        self.rows: list[dict[str, float]] = []
        self._full: list[float] = []
        self._full_started = 0.0

    def start(self, clock: StageClock, service: TrackerService, first: float | None) -> None:
        assert first is not None
        self._clock, self._service, self._first = clock, service, first
        self._end = first + self.seconds
        self._mark = self._snapshot()
        self._slowest = 0.0
        gc.callbacks.append(self._on_gc)

    def process(self, service: TrackerService, name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        while datagram.time >= self._end:
            self._close()
        started = time.thread_time()
        service.process(name, datagram)
        self._slowest = max(self._slowest, time.thread_time() - started)

    def end(self) -> None:
        self._close()
        gc.callbacks.remove(self._on_gc)

    def _on_gc(self, phase: str, info: dict[str, int]) -> None:
        if info["generation"] != 2:
            return
        if phase == "start":
            self._full_started = time.perf_counter()
        else:
            self._full.append(time.perf_counter() - self._full_started)

    def _snapshot(self) -> dict[str, float]:
        service = self._service
        stats = service.chain.stats
        counts: dict[str, float] = {
            "cpu": time.process_time(),
            "plots": stats.plots,
            "datagrams": stats.datagrams,
            **self._clock.seconds,
        }
        fuser = service.chain.fuser
        if fuser is not None:
            local = fuser.state.local
            counts["system tracks"] = fuser.system_tracks.size
            counts["local rows"] = local.n
            counts["local alive"] = int(np.count_nonzero(local.rows["alive"][: local.n]))
            counts.update({name: getattr(fuser.stats, name, 0) for name in FUSER_COUNTS})
        return counts

    def _close(self) -> None:
        now = self._snapshot()
        row = {k: now[k] - self._mark[k] for k in now}
        for name in ("system tracks", "local rows", "local alive"):
            if name in now:
                row[name] = now[name]
        row["start"] = self._end - self.seconds - self._first
        row["slowest"] = self._slowest
        row["full collections"] = len(self._full)
        row["full collection s"] = sum(self._full)
        self.rows.append(row)
        print(self._line(row), file=sys.stderr, flush=True)
        self._mark, self._slowest, self._full = now, 0.0, []
        self._end += self.seconds

    HEAD = (
        "| data s | plots | CPU ms/s | us/plot | fusion ms/s | central+bias ms/s | local ms/s "
        "| outputs ms/s | map ms/s | other ms/s | slowest ms | full GCs (ms) | system tracks "
        "| local rows (alive) | created / ended / merged / reused early / no number |"
    )

    def table(self) -> str:
        """The rows as a Markdown table: CPU ms per second of data, and per plot."""
        rule = "|" + " ---: |" * (self.HEAD.count("|") - 1)
        return "\n".join([self.HEAD, rule, *(self._line(r) for r in self.rows)])

    def _line(self, r: dict[str, float]) -> str:
        per_s = 1e3 / self.seconds
        outputs = sum(r[n] for n in OUTPUT_STAGES)
        central = r["central stage"] + r["bias"] + r["bias references"]
        local = r["decode"] + r["clock + conversion"] + r["local tracking"]
        other = r["cpu"] - sum(r[n] for n in STAGES)
        return (
            f"| {r['start']:.0f} | {r['plots']:.0f} | {r['cpu'] * per_s:.0f} | "
            f"{r['cpu'] / max(r['plots'], 1) * 1e6:.0f} | {r['fusion'] * per_s:.0f} | "
            f"{central * per_s:.0f} | {local * per_s:.0f} | {outputs * per_s:.0f} | "
            f"{r['Foxglove map'] * per_s:.0f} | "
            f"{other * per_s:.0f} | {r['slowest'] * 1e3:.0f} | "
            f"{r['full collections']:.0f} ({r['full collection s'] * 1e3:.0f}) | "
            f"{r.get('system tracks', 0):.0f} | "
            f"{r.get('local rows', 0):.0f} ({r.get('local alive', 0):.0f}) | "
            + " / ".join(f"{r.get(n, 0):.0f}" for n in FUSER_COUNTS)
            + " |"
        )


def slice_of(path: str, seconds: float) -> tuple[Any, list[tuple[str, Datagram]]]:
    """The recording's configuration and its first ``seconds`` of datagrams, in memory."""
    replay = open_replay(path)
    datagrams: list[tuple[str, Datagram]] = []
    first = None
    for name, datagram in replay.datagrams:
        assert datagram.time is not None
        first = datagram.time if first is None else first
        if datagram.time - first > seconds:
            break
        datagrams.append((name, datagram))
    return replay, datagrams


def run_once(
    path: str,
    seconds: float,
    mcap: bool,
    use_zenoh: bool,
    fusion_implementation: str,
    windows: Windows | None = None,
) -> tuple[dict[str, float], int, float, float]:
    """One replay of the slice: exclusive CPU seconds per stage (and "other"), plots,
    process CPU seconds and wall seconds; with ``windows``, the same by window of data
    time into it."""
    replay, datagrams = slice_of(path, seconds)
    if windows is not None:
        # The datagrams held for the replay out of the collector's scans (as the
        # daemon's start-up objects are, ``command.freeze_start_up``): a full collection
        # then walks what the chain holds, as in the service.
        gc.collect()
        gc.freeze()
    fusion = {**replay.config.fusion, "implementation": fusion_implementation}
    config = replay.config.model_copy(update={"fusion": fusion})
    clock = StageClock()
    with contextlib.ExitStack() as stack:
        publisher = None
        if use_zenoh:
            publisher = stack.enter_context(
                contextlib.closing(ZenohPublisher("bench", mode="peer", scouting=False))
            )
        log = None
        if mcap:
            directory = stack.enter_context(tempfile.TemporaryDirectory(prefix="bench_stages"))
            log = stack.enter_context(contextlib.closing(McapLog(directory)))
        with instrumented(clock):
            service = TrackerService(config, publisher, log)
            service.set_input_counters(replay.counters)
            threads_before = thread_seconds()
            cpu0, wall0 = time.process_time(), time.perf_counter()
            if windows is None:
                for name, datagram in datagrams:
                    service.process(name, datagram)
            else:
                windows.start(clock, service, datagrams[0][1].time)
                for name, datagram in datagrams:
                    windows.process(service, name, datagram)
                windows.end()
            service.local.drain()
            threads_after = thread_seconds()  # before close: the output threads end there
            service.close()
            service.local.drain()
            cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
            plots = service.chain.stats.plots
    gc.unfreeze()  # nothing frozen unless ``windows``
    stages = dict(clock.seconds)
    stages["other"] = cpu - sum(stages.values())
    if threads_before is not None and threads_after is not None:
        spent = {n: s - threads_before.get(n, 0.0) for n, s in threads_after.items()}
        print(
            "CPU s by thread (Linux):",
            ", ".join(f"{n} {s:.2f}" for n, s in sorted(spent.items(), key=lambda i: -i[1])),
            file=sys.stderr,
        )
    return stages, plots, cpu, wall


def thread_seconds() -> dict[str, float] | None:
    """User + system CPU seconds of this process's threads by name (comm), from /proc:
    what "other" is made of (the service's own threads, Zenoh's, numba's)."""
    tasks = Path("/proc/self/task")
    if not tasks.is_dir():
        return None
    tick = os.sysconf("SC_CLK_TCK")
    python_names = {t.native_id: t.name for t in threading.enumerate()}
    seconds: dict[str, float] = {}
    for task in tasks.iterdir():
        with contextlib.suppress(OSError, ValueError, IndexError):
            stat = (task / "stat").read_text()
            name = python_names.get(int(task.name)) or stat[stat.index("(") + 1 : stat.rindex(")")]
            fields = stat[stat.rindex(")") + 2 :].split()
            # utime and stime: fields 14 and 15 of stat(5), counted from the state (3).
            seconds[name] = seconds.get(name, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="a simulated recording (e.g. of scale)")
    parser.add_argument("--seconds", type=float, default=30.0, help="slice of the recording")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument(
        "--warmup-seconds", type=float, default=12.0, help="slice of the untimed first run"
    )
    parser.add_argument("--no-mcap", action="store_true")
    parser.add_argument("--no-zenoh", action="store_true")
    parser.add_argument(
        "--fusion-implementation", choices=("compiled", "numpy"), default="compiled"
    )
    parser.add_argument("--json", action="store_true", help="the figures as JSON on stdout")
    parser.add_argument(
        "--windows",
        type=float,
        metavar="S",
        help="also each run's work by window of S s of data time (a table; see Windows)",
    )
    parser.add_argument(
        "--profile",
        metavar="FILE",
        help="cProfile the timed runs' main thread into FILE (pstats), by its CPU time",
    )
    args = parser.parse_args()
    print(f"code: {tracker_service.__file__}", file=sys.stderr)
    options = (not args.no_mcap, not args.no_zenoh, args.fusion_implementation)
    # numba's kernels loaded (or compiled) before the clock starts: some are first called
    # only once system tracks are fed by two radars, after a few antenna periods.
    run_once(args.recording, min(args.warmup_seconds, args.seconds), *options)
    runs = []
    # The thread's CPU time, not cProfile's default wall clock: a call that releases the
    # GIL (a lock, a large numpy reduction) would otherwise be charged with the time the
    # output threads hold it.
    profiler = cProfile.Profile(time.thread_time) if args.profile else None
    for repeat in range(args.repeats):
        if profiler is not None:
            profiler.enable()
        windows = None if args.windows is None else Windows(args.windows)
        runs.append(
            run_once(
                args.recording,
                args.seconds,
                not args.no_mcap,
                not args.no_zenoh,
                args.fusion_implementation,
                windows,
            )
        )
        if profiler is not None:
            profiler.disable()
        if windows is not None:
            print(windows.table(), file=sys.stderr)
        _, plots, cpu, wall = runs[-1]
        print(
            f"run {repeat + 1}: {plots} plots, {cpu:.1f} CPU s, {wall:.1f} s wall,"
            f" {plots / cpu:,.0f} plots per CPU-second",
            file=sys.stderr,
        )
    if profiler is not None:
        profiler.dump_stats(args.profile)
    plots = runs[0][1]
    names = [*STAGES, "other"]
    median = {n: statistics.median(r[0][n] for r in runs) for n in names}
    cpu = statistics.median(r[2] for r in runs)
    wall = statistics.median(r[3] for r in runs)
    if args.json:
        report = {
            "recording": args.recording,
            "seconds": args.seconds,
            "repeats": args.repeats,
            "fusion_implementation": args.fusion_implementation,
            "plots": plots,
            "cpu_s": cpu,
            "wall_s": wall,
            "plots_per_cpu_s": plots / cpu,
            "stage_us_per_plot": {n: median[n] / plots * 1e6 for n in names},
        }
        json.dump(report, sys.stdout, indent=1)
        print()
        return
    print(f"{Path(args.recording).name}: first {args.seconds:g} s, {plots:,} plots,")
    print(
        f"median of {args.repeats} run(s); outputs: mcap={not args.no_mcap}"
        f" zenoh={not args.no_zenoh}; fusion {args.fusion_implementation}"
    )
    print(f"{'stage':<20} {'CPU s':>8} {'us/plot':>9} {'share':>7}")
    for n in names:
        print(f"{n:<20} {median[n]:>8.2f} {median[n] / plots * 1e6:>9.1f} {median[n] / cpu:>7.1%}")
    print(f"{'whole chain':<20} {cpu:>8.2f} {cpu / plots * 1e6:>9.1f} {1.0:>7.1%}")
    print(f"plots per CPU-second: {plots / cpu:,.0f} (wall {wall:.1f} s, target 20,000)")


if __name__ == "__main__":
    main()
