"""The outputs alone on a recording's own traffic: every call the service core makes on its
outputs (``Outputs``: datagrams, batches, CAT062, bias, status, the close) recorded once
over the first seconds of a recording, then replayed into a fresh ``Outputs`` with every
output on (an MCAP log in a temporary directory with its Foxglove map channels, a Zenoh
peer session), as the output process (``command.OutputProcess``) makes them: the CPU time
of the whole (every thread: the callers', the sinks' own, Zenoh's), per plot, and a
sha256 over every message the log holds and over every Zenoh put and delete (key,
encoding, payload), so that two versions of the outputs (a ``git archive`` copy on
``PYTHONPATH`` against the worktree) are compared on the same inputs, for speed and for
identity, without the chain's minute per run and its noise (``bench_stages.py``).

    python benchmarks/bench_output_calls.py record scale60.mcap --seconds 20 -o calls.pkl
    python benchmarks/bench_output_calls.py replay calls.pkl [--repeats 3] [--profile FILE]
    python benchmarks/bench_output_calls.py calls calls.pkl [--speed 1] [--skip 30]

``calls`` times every call one by one instead (one pass, after the untimed one): the
core's calls on ``Outputs`` in the main thread, each output's calls on its thread, and
each Foxglove picture built (``MapScene.picture_geojson``), wall and CPU time
(``time.thread_time``) per call, their median, p99 and maximum; and, per batch, the
publication delay: from the start of the core's ``batch`` call to the end of the Zenoh
output's call that puts its system tracks, what the output process adds to a plot's
latency (the close's ends left out); each full collection of the cyclic collector is timed
too, as thread "gc" (the calls are frozen out of its scans, as the service's start-up
objects are, and the survivors of each full collection after them, as the output process
has them: ``command.freeze_survivors``); at the end, the objects in reference cycles are
counted with every generation unfrozen (what frozen survivors would leak). ``--speed``
paces the calls at their data time (1: real time, as the daemon gets them; 0: back to
back); ``--skip`` leaves the first seconds of data time (the picture filling) out of the
figures.

The calls are pickled as the output process receives them (``(method, args)``), to be read
back only from a file of one's own making; they are unpickled before the clock starts, and
a first pass is untimed (numba loads or compiles the kernels there).
The Zenoh digest is taken by a stand-in for the publisher's session that hashes each call
and then makes it: what the outputs hand to Zenoh, byte for byte (that a subscriber
receives what is put is ``tests/test_outputs_zenoh.py``'s).
"""

from __future__ import annotations

import argparse
import contextlib
import cProfile
import gc
import hashlib
import pickle
import statistics
import sys
import tempfile
import threading
import time
from collections import defaultdict
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import tracker_service
from tracker_service.outputs.foxglove_scene import MapScene
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.sink import QueuedSink
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.service import command
from tracker_service.service.core import Outputs, TrackerService

sys.path.insert(0, str(Path(__file__).parent))
from bench_stages import slice_of
from output_hash import log_digest


class _Recorder:
    """An ``OutputSink`` that keeps each call as the output process's pipe carries it."""

    def __init__(self) -> None:
        self.calls: list[bytes] = []

    def __getattr__(self, method: str) -> Any:
        def call(*args: object) -> None:
            self.calls.append(pickle.dumps((method, args), protocol=pickle.HIGHEST_PROTOCOL))

        return call


def record(path: str, seconds: float) -> tuple[Any, list[bytes]]:
    """The recording's configuration and the core's calls on its outputs, pickled."""
    replay, datagrams = slice_of(path, seconds)
    recorder = _Recorder()
    service = TrackerService(replay.config, outputs=recorder)  # type: ignore[arg-type]
    service.set_input_counters(replay.counters)
    for name, datagram in datagrams:
        service.process(name, datagram)
    service.close()
    return replay.config, recorder.calls


class _HashingSession:
    """The publisher's session, each put and delete hashed (key, encoding, payload) first."""

    def __init__(self, session: Any) -> None:
        self._session = session
        self.digest = hashlib.sha256()
        self.count = 0

    def put(self, key: str, payload: bytes, *, encoding: Any = None, **kwargs: Any) -> None:
        self._note(b"put", key, str(encoding).encode(), payload)
        self._session.put(key, payload, encoding=encoding, **kwargs)

    def delete(self, key: str, **kwargs: Any) -> None:
        self._note(b"delete", key, b"", b"")
        self._session.delete(key, **kwargs)

    def _note(self, kind: bytes, key: str, encoding: bytes, payload: bytes) -> None:
        for part in (kind, key.encode(), encoding, bytes(payload)):
            self.digest.update(len(part).to_bytes(8, "little"))
            self.digest.update(part)
        self.count += 1

    def __getattr__(self, name: str) -> Any:
        return getattr(self._session, name)


@contextlib.contextmanager
def in_callers_thread(enabled: bool) -> Iterator[None]:
    """Each output's calls made at once in the caller's thread rather than queued to its
    own (``QueuedSink``): what a profile of one thread needs to see them."""
    if not enabled:
        yield
        return
    queued = QueuedSink._put

    def direct(self: QueuedSink, time: float, call: Any, args: Any, messages: int = 1) -> None:
        call(*args)

    QueuedSink._put = direct  # type: ignore[method-assign]
    try:
        yield
    finally:
        QueuedSink._put = queued  # type: ignore[method-assign]


@contextlib.contextmanager
def sink_threads_timed() -> Iterator[dict[str, float]]:
    """The CPU seconds of each output's thread (``QueuedSink``) by its name, at its end:
    the recorded calls end with the core's ``close``, which ends the threads."""
    seconds: dict[str, float] = {}
    work = QueuedSink._work

    def timed(self: QueuedSink) -> None:
        try:
            work(self)
        finally:
            seconds[self.name] = time.thread_time()

    QueuedSink._work = timed  # type: ignore[method-assign]
    try:
        yield seconds
    finally:
        QueuedSink._work = work  # type: ignore[method-assign]


def replay(
    config: Any,
    calls: list[tuple[str, tuple[Any, ...]]],
    hashed: bool,
    profiler: cProfile.Profile | None = None,
) -> tuple[float, dict[str, float], tuple[int, str], tuple[int, str]]:
    """One pass: CPU seconds of the process (every thread), CPU seconds by thread, the
    log's (messages, sha256) and Zenoh's (calls, sha256; empty unless ``hashed``)."""
    with tempfile.TemporaryDirectory(prefix="bench_output_calls") as tmp:
        directory = Path(tmp) / "log"
        with (
            contextlib.closing(ZenohPublisher("tracker", mode="peer", scouting=False)) as publisher,
            contextlib.closing(McapLog(directory)) as log,
        ):
            session = None
            if hashed:
                session = _HashingSession(publisher._session)
                publisher._session = session  # type: ignore[assignment]
            with sink_threads_timed() as by_thread:
                outputs = Outputs(config, publisher, log)
                gc.collect()
                started = time.process_time()
                main_started = time.thread_time()
                if profiler is not None:
                    profiler.enable()
                for method, args in calls:
                    getattr(outputs, method)(*args)
                outputs.stop()
                if profiler is not None:
                    profiler.disable()
                cpu = time.process_time() - started
                by_thread["main"] = time.thread_time() - main_started
            if session is not None:
                publisher._session = session._session  # type: ignore[assignment]
        count, digest, _ = log_digest(directory)
    zenoh = (0, "") if session is None else (session.count, session.digest.hexdigest())
    return cpu, by_thread, (count, digest), zenoh


class _CallTimes:
    """Each timed call: (thread, method, data time, wall start, wall s, CPU s, the wall
    start of the core's call it came from); ``origin`` is the core's call in progress
    (None for any but ``batch``: the publication delay is a batch's), and each collection
    of the oldest generation is a call of thread "gc"."""

    def __init__(self) -> None:
        self.rows: list[tuple[str, str, float, float, float, float, float | None]] = []
        self.origin: float | None = None
        self.data_time = 0.0
        self.lock = threading.Lock()
        self._collection: tuple[float, float] | None = None

    def collection(self, phase: str, info: dict[str, int]) -> None:
        """A ``gc.callbacks`` entry."""
        if info["generation"] != 2:
            return
        if phase == "start":
            self._collection = (time.perf_counter(), time.thread_time())
        elif self._collection is not None:
            wall, cpu = self._collection
            row = (
                "gc",
                "full collection",
                self.data_time,
                wall,
                time.perf_counter() - wall,
                time.thread_time() - cpu,
                None,
            )
            self.rows.append(row)

    def timed(self, thread: str, method: str, call: Callable[..., Any]) -> Callable[..., None]:
        origin, data_time = self.origin, self.data_time

        def run(*args: object) -> None:
            wall, cpu = time.perf_counter(), time.thread_time()
            call(*args)
            cpu = time.thread_time() - cpu
            end = time.perf_counter()
            with self.lock:
                self.rows.append((thread, method, data_time, wall, end - wall, cpu, origin))

        return run


@contextlib.contextmanager
def calls_timed(times: _CallTimes) -> Iterator[None]:
    """Every call queued to an output's thread timed on that thread (``QueuedSink``), and
    every Foxglove picture built timed on its own, as thread "picture"."""
    put, picture = QueuedSink._put, MapScene.picture_geojson

    def timed_put(
        self: QueuedSink,
        time: float,
        call: Callable[..., None],
        args: tuple[object, ...],
        messages: int = 1,
    ) -> None:
        put(self, time, times.timed(self.name, call.__name__, call), args, messages)

    def timed_picture(self: MapScene) -> bytes:
        out: list[bytes] = []
        times.timed("picture", "picture_geojson", lambda: out.append(picture(self)))()
        return out[0]

    QueuedSink._put = timed_put  # type: ignore[method-assign]
    MapScene.picture_geojson = timed_picture  # type: ignore[method-assign]
    gc.callbacks.append(times.collection)
    try:
        yield
    finally:
        gc.callbacks.remove(times.collection)
        QueuedSink._put = put  # type: ignore[method-assign]
        MapScene.picture_geojson = picture  # type: ignore[method-assign]


def _data_time(method: str, args: tuple[Any, ...]) -> float | None:
    if method == "advance":
        return float(args[0])
    if method == "received":
        return float(args[1].time)
    return None


def per_call(config: Any, calls: list[tuple[str, tuple[Any, ...]]], speed: float) -> _CallTimes:
    """One pass with every call timed (``calls_timed``), paced at ``speed`` times the
    calls' data time (0: back to back)."""
    times = _CallTimes()
    with (
        tempfile.TemporaryDirectory(prefix="bench_output_calls") as tmp,
        contextlib.closing(ZenohPublisher("tracker", mode="peer", scouting=False)) as publisher,
        contextlib.closing(McapLog(Path(tmp) / "log")) as log,
        calls_timed(times),
    ):
        outputs = Outputs(config, publisher, log)
        gc.collect()
        first: tuple[float, float] | None = None
        for method, args in calls:
            at = _data_time(method, args)
            if at is not None:
                times.data_time = at
                if first is None:
                    first = (at, time.perf_counter())
                elif speed > 0:
                    ahead = first[1] + (at - first[0]) / speed - time.perf_counter()
                    if ahead > 0:
                        time.sleep(ahead)
            times.origin = time.perf_counter() if method == "batch" else None
            times.timed("main", method, getattr(outputs, method))(*args)
        outputs.stop()
        sizes = ", ".join(f"{path.stat().st_size / 1e6:.0f}" for path in log.files)
        print(f"log files (MB): {sizes}")
    return times


def _ms(values: list[float]) -> str:
    ordered = sorted(values)
    p99 = ordered[min(len(ordered) - 1, int(0.99 * len(ordered)))]
    return f"{1e3 * statistics.median(ordered):8.2f} {1e3 * p99:8.2f} {1e3 * ordered[-1]:8.2f}"


def report_calls(times: _CallTimes, skip: float) -> None:
    """Per thread and method: calls, wall and CPU ms (median, p99, max); the publication
    delay of the system tracks; the slowest calls."""
    start = min(row[2] for row in times.rows if row[2] > 0) + skip
    rows = [row for row in times.rows if row[2] >= start]
    groups: dict[tuple[str, str], list[tuple[float, float]]] = defaultdict(list)
    for thread, method, _, _, wall, cpu, _ in rows:
        groups[thread, method].append((wall, cpu))
    print(
        f"{'thread':>10} {'call':<18} {'n':>6}   wall ms: p50      p99      max"
        "    CPU ms: p50      p99      max"
    )
    for (thread, method), values in sorted(groups.items()):
        walls, cpus = [v[0] for v in values], [v[1] for v in values]
        print(f"{thread:>10} {method:<18} {len(values):6d} {_ms(walls)} {_ms(cpus)}")
    delays = [
        start_wall + wall - origin
        for thread, method, _, start_wall, wall, _, origin in rows
        if thread == "zenoh" and method == "system_updates" and origin is not None
    ]
    if delays:
        print(
            f"publication delay (core's batch call to Zenoh put done), ms: p50 p99 max "
            f"{_ms(delays)}"
        )
    print("slowest calls (data time, thread, call, wall ms, CPU ms):")
    for thread, method, at, _, wall, cpu, _ in sorted(rows, key=lambda r: -r[5])[:12]:
        print(
            f"  {at - start + skip:8.3f} {thread:>10} {method:<18} {1e3 * wall:8.2f} "
            f"{1e3 * cpu:8.2f}"
        )


def plots_of(calls: list[tuple[str, tuple[Any, ...]]]) -> int:
    return sum(len(args[0].plots) for method, args in calls if method == "batch")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    rec = sub.add_parser("record", help="record the outputs' calls over a recording's start")
    rec.add_argument("recording")
    rec.add_argument("--seconds", type=float, default=20.0)
    rec.add_argument("-o", "--output", required=True)
    rep = sub.add_parser("replay", help="replay recorded calls into fresh outputs")
    rep.add_argument("calls")
    rep.add_argument("--repeats", type=int, default=3)
    rep.add_argument(
        "--profile",
        help="cProfile (CPU time) of the timed passes into FILE, every output's calls made "
        "in the main thread",
    )
    rep.add_argument(
        "--no-hash", action="store_true", help="time only (the Zenoh digest costs a little)"
    )
    timed = sub.add_parser("calls", help="time each call of recorded calls, one pass")
    timed.add_argument("calls")
    timed.add_argument("--speed", type=float, default=1.0, help="0: back to back")
    timed.add_argument("--skip", type=float, default=0.0, help="data seconds left out")
    timed.add_argument(
        "--log-picture-period",
        type=float,
        help="[foxglove] log_picture_period_s instead of the recording's (60: the picture "
        "all but off, to see what it costs)",
    )
    args = parser.parse_args()
    if args.command == "record":
        config, recorded = record(args.recording, args.seconds)
        with open(args.output, "wb") as out:
            pickle.dump((config, recorded), out)
        print(f"{len(recorded)} calls")
        return
    with open(args.calls, "rb") as stream:
        config, recorded = pickle.load(stream)
    print(f"tracker_service: {tracker_service.__file__}", file=sys.stderr)
    calls = [pickle.loads(item) for item in recorded]
    # Out of the collector's scans, as the service's start-up objects are
    # (``command.freeze_start_up``): what the outputs keep is what is scanned; and the
    # survivors of each full collection after it, as the output process has them
    # (``command.freeze_survivors``; a base copy from before it has not).
    gc.freeze()
    freeze_survivors = getattr(command, "freeze_survivors", None)
    if freeze_survivors is not None:
        freeze_survivors()
    plots = plots_of(calls)
    # An untimed pass first: numba loads (or compiles) the kernels there.
    replay(config, calls, hashed=False)
    if args.command == "calls":
        if args.log_picture_period is not None:
            foxglove = config.foxglove.model_copy(
                update={"log_picture_period_s": args.log_picture_period}
            )
            config = config.model_copy(update={"foxglove": foxglove})
        report_calls(per_call(config, calls, args.speed), args.skip)
        gc.unfreeze()
        print(
            f"objects in reference cycles, all generations unfrozen at the end: {gc.collect()} "
            "(what frozen survivors would leak, with the calls' own)"
        )
        return
    profiler = cProfile.Profile(time.thread_time) if args.profile else None
    seconds = []
    for repeat in range(args.repeats):
        with in_callers_thread(profiler is not None):
            cpu, by_thread, log, zenoh = replay(config, calls, not args.no_hash, profiler)
        seconds.append(cpu)
        threads = ", ".join(
            f"{n} {s:.2f}" for n, s in sorted(by_thread.items(), key=lambda i: -i[1])
        )
        print(
            f"run {repeat + 1}: {cpu:.2f} CPU s, {1e6 * cpu / plots:.1f} us per plot "
            f"({threads}); log {log[0]} {log[1]}; zenoh {zenoh[0]} {zenoh[1]}"
        )
    if profiler is not None:
        profiler.dump_stats(args.profile)
    median = statistics.median(seconds)
    print(
        f"{plots} plots, {len(calls)} calls: median {median:.2f} CPU s, "
        f"{1e6 * median / plots:.1f} us per plot"
    )


if __name__ == "__main__":
    main()
