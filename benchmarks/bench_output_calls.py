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
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import tracker_service
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.sink import QueuedSink
from tracker_service.outputs.zenoh_out import ZenohPublisher
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
    plots = plots_of(calls)
    # An untimed pass first: numba loads (or compiles) the kernels there.
    replay(config, calls, hashed=False)
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
