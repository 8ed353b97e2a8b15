"""The radar stages in other processes, over Zenoh: ``tracker-service replay --workers N``.

The main process runs the service as in one process (the central stage, the outputs,
their schedule), with a ``RemoteRadarStages`` as its chain's radar side. Each of the N
worker processes reads the same input, numbers its datagrams as the main process does
(every datagram the service would feed the chain counts), and runs a ``RadarStage`` over
the datagrams of the radars assigned to it (``assign``: the configured radars in SAC/SIC
order, round robin; an unconfigured source by a hash of its SAC/SIC). For each of them it
publishes a ``stage_messages.DatagramResult`` on ``<prefix>/stage/replay/<k>/result``.

The main process takes, for each datagram in input order, the next result of the worker
that owns it, and checks that it is that datagram's (``order``): the central stage sees
the same batches in the same order as in one process, so the system tracks are the same
messages with the same numbers and values, whatever the timing of the network.

Flow control: a worker runs ahead of the main process by at most ``WINDOW`` of its
results. The main process says how many of worker k's results it has consumed, every
``credit_step(window)`` of them, on ``<prefix>/stage/replay/<k>/consumed`` (a u64
little-endian count); the worker, once ``WINDOW`` ahead of the last count it heard, waits
for the next one. The main process's queues so hold at most ``WINDOW`` results per worker
however slow its central stage and outputs are (docs/benchmarks.md, session 12), and no
Zenoh callback ever blocks: the main process's only puts the payload in a queue, the
worker's only raises a count under a lock.

Sessions as everywhere in the service (``outputs.zenoh_session``): peers, scouting off,
explicit endpoints only; the main process listens on 127.0.0.1 on a free port, the
workers connect to it, and nothing else can join by accident.
"""

from __future__ import annotations

import contextlib
import json
import logging
import multiprocessing
import os
import queue
import socket
import struct
import threading
import time
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from multiprocessing.synchronize import Event
from pathlib import Path
from typing import Any, Self

import zenoh

from tracker_service.chain import RadarStageFailed, RadarState, source_order
from tracker_service.inputs.udp import block_chain_error
from tracker_service.outputs.zenoh_session import zenoh_config
from tracker_service.radar_stage import StageStats
from tracker_service.service.config import ServiceConfig, parse_service_config
from tracker_service.service.core import build_radar_stage
from tracker_service.service.replay import first_source, open_replay
from tracker_service.sources import SourceCounts
from tracker_service.stage_messages import (
    DatagramResult,
    MessageKind,
    RadarBatch,
    decode_message,
    encode_message,
)

__all__ = ["RemoteRadarStages", "WorkerFailed", "assign", "owner"]

log = logging.getLogger(__name__)

READY_TIMEOUT_S = 30.0
"""A worker that has not reached the main process's session in this long gives up."""
RESULT_TIMEOUT_S = 1.0
"""How long the main process waits for a result before it checks its worker still runs."""
WINDOW = 1024
"""How many results a worker may have published beyond what the main process has consumed
of its results. Large enough that a worker never starves the main process: when the main
process is the slower, its queue holds a full window and a credit comes back every
``WINDOW // 8`` results, within milliseconds on loopback, long before the 7/8 left run
out (1024 results are 9 s of the 20-radar ``scale`` scenario, 3.5 s of ``artas``: more
than a worker is ever descheduled); when the worker is the slower, its window never
fills. Small enough to bound the main process's memory: an encoded result is 14 kB on
average on ``scale``, 9 kB on ``artas``, 47 kB at most (the plots, Jacobians and
local-track updates of one datagram), and the largest 1024 consecutive results are 15 MB
on ``scale``, 10 MB on ``artas``: so much per worker waits in the main process's queue
at most (47 MB were every result the largest seen), where unbounded a slow main process
held every result of the recording it had not reached (docs/benchmarks.md, session 12)."""
CREDIT_WAIT_S = 1.0
"""How long a worker at the end of its window waits for a credit before it looks whether
the main process is done (a replay stopped early) and waits again (a main process that
died is noticed by ``_exit_when_orphaned`` meanwhile)."""
_COUNT = struct.Struct("<Q")
"""A credit: how many of a worker's results the main process has consumed."""


class WorkerFailed(RadarStageFailed):
    """A worker process died or sent what the main process did not expect."""


def assign(sources: Sequence[str], workers: int) -> dict[str, int]:
    """Which worker runs each configured radar: SAC/SIC order, round robin."""
    return {source: k % workers for k, source in enumerate(sorted(sources, key=source_order))}


def owner(payload: bytes, assignment: dict[str, int], workers: int) -> int:
    """The worker of a datagram: its first record's source's (a datagram that mixes
    radars goes whole to one worker, as it goes whole to the one-process chain)."""
    source = first_source(payload) or "0/0"
    found = assignment.get(source)
    return found if found is not None else zlib.crc32(source.encode()) % workers


def result_key(prefix: str, worker: int) -> str:
    return f"{prefix}/stage/replay/{worker}/result"


def consumed_key(prefix: str, worker: int) -> str:
    return f"{prefix}/stage/replay/{worker}/consumed"


def credit_step(window: int) -> int:
    """Every how many consumed results the main process sends a worker its count: an
    eighth of the window, so that a credit is one message per many results and a worker
    that keeps up never finds its window shut."""
    return max(1, window // 8)


def ready_key(prefix: str) -> str:
    return f"{prefix}/stage/replay/ready"


def free_loopback_port() -> int:
    """A TCP port free on 127.0.0.1 now (the main process listens on it at once)."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


@dataclass
class _WorkerArgs:
    recording: str
    config_json: str
    day_posix: float | None
    worker: int
    workers: int
    endpoint: str
    prefix: str
    window: int


class _Credit:
    """In a worker, how many of its results the main process has consumed, as it last
    said; fed by the worker's subscriber, waited on by the worker's loop."""

    def __init__(self) -> None:
        self._consumed = 0
        self._changed = threading.Condition()

    def heard(self, sample: zenoh.Sample) -> None:
        """The subscriber's callback: a count, kept if it is the highest yet (it never
        waits for more than the lock, held only between the loop's checks)."""
        (consumed,) = _COUNT.unpack(sample.payload.to_bytes())
        with self._changed:
            if consumed > self._consumed:
                self._consumed = consumed
                self._changed.notify_all()

    def wait_for_room(self, published: int, window: int, done: Event) -> bool:
        """Until the main process has consumed enough that one more result keeps
        ``published`` within ``window`` of it (True), or has said it reads no more
        (``done``: a replay stopped early; False)."""
        with self._changed:
            while published - self._consumed >= window:
                if done.is_set():
                    return False
                self._changed.wait(CREDIT_WAIT_S)
        return True


def _wait_ready(session: zenoh.Session, prefix: str) -> None:
    """Until the main process answers: its subscriber is declared by then, so that no
    result is published before anyone hears it."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    while time.monotonic() < deadline:
        for reply in session.get(ready_key(prefix), timeout=1.0):
            if reply.ok is not None:
                return
        time.sleep(0.05)
    raise WorkerFailed(f"no answer from the main process on {ready_key(prefix)}")


def _exit_when_orphaned(parent: int) -> None:
    """A worker whose main process died (killed, say) ends too: nobody reads its results,
    and an orphan would hold its core and its session for good."""
    while True:
        time.sleep(1.0)
        if os.getppid() != parent:
            os._exit(1)


def _run_worker(
    args: _WorkerArgs, done: Event, cpu: multiprocessing.Queue[tuple[int, float]], parent: int
) -> None:
    """A worker process: its radars' stage over the input, each result published; its
    CPU seconds into ``cpu`` at the end."""
    threading.Thread(target=_exit_when_orphaned, args=(parent,), daemon=True).start()
    logging.basicConfig(level=logging.WARNING)
    config = parse_service_config(json.loads(args.config_json), "replay worker")
    source = open_replay(args.recording, config, args.day_posix)
    stage = build_radar_stage(config)
    assignment = assign([radar.key for radar in config.radars], args.workers)
    session = zenoh.open(zenoh_config("peer", connect=[args.endpoint]))
    credit = _Credit()
    try:
        publisher = session.declare_publisher(
            result_key(args.prefix, args.worker),
            congestion_control=zenoh.CongestionControl.BLOCK,
            encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM,
        )
        # Declared before the ready query: the main process has heard of it before it
        # answers, so no credit it sends later goes unheard.
        session.declare_subscriber(consumed_key(args.prefix, args.worker), credit.heard)
        _wait_ready(session, args.prefix)
        order = 0
        published = 0
        for _name, datagram in source.datagrams:
            payload = datagram.payload
            if datagram.time is None or block_chain_error(payload) is not None:
                continue  # the service does not feed these to the chain
            if owner(payload, assignment, args.workers) == args.worker:
                batches = stage.feed(payload, datagram.time, order)
                result = DatagramResult(
                    order, datagram.time, batches, stage.stats.decode_errors, stage.admission.counts
                )
                # No deadlock: the main process consumes this worker's results in the
                # order they are published, so the one it waits for from this worker is
                # its oldest not consumed. When that is this one (number ``published``,
                # all before it consumed), the count the main process last sent is at
                # most ``credit_step - 1`` below ``published`` (it sends on every
                # multiple of the step, and again whenever it has waited a second for a
                # result), and ``credit_step <= window``: the wait ends. Other workers'
                # windows play no part: each worker's results are waited for on their own.
                if not credit.wait_for_room(published, args.window, done):
                    break  # the main process stopped early: it reads no more
                publisher.put(encode_message(result))
                published += 1
            order += 1
        else:
            end = DatagramResult(order, 0.0, kind=MessageKind.END_OF_INPUT)
            publisher.put(encode_message(end))
        cpu.put((args.worker, time.process_time()))
        # Until the main process has what it needs: closing at once could drop the tail.
        done.wait()
    finally:
        session.close()  # type: ignore[no-untyped-call]


@dataclass
class _RemoteAdmission:
    """The workers' source admission counts, summed."""

    per_worker: list[SourceCounts] = field(default_factory=list)

    @property
    def counts(self) -> SourceCounts:
        return SourceCounts(
            sum(c.no_source for c in self.per_worker),
            sum(c.unknown_dropped for c in self.per_worker),
            sum(c.unknown_sources_dropped for c in self.per_worker),
        )


class RemoteRadarStages:
    """The chain's radar side in ``workers`` processes (see the module docstring), which
    replay ``recording`` with ``config`` (``day_posix`` as ``open_replay``'s). A context
    manager: leaving it ends the workers and closes the session."""

    def __init__(
        self,
        recording: str | Path,
        config: ServiceConfig,
        day_posix: float | None,
        workers: int,
        prefix: str = "tracker",
        window: int = WINDOW,
    ) -> None:
        if workers < 1:
            raise ValueError(f"--workers {workers}: give 1 or more")
        if window < 1:
            raise ValueError(f"window {window}: give 1 or more")
        self.workers = workers
        self.window = window
        self.stats = StageStats()
        self.radars: dict[str, RadarState] = {}
        self.admission = _RemoteAdmission([SourceCounts() for _ in range(workers)])
        self._assignment = assign([radar.key for radar in config.radars], workers)
        self._decode_errors = [0] * workers
        # Unbounded as queues, bounded by the credits: each holds at most ``window``
        # results (and the worker's end of input), and the callback never blocks.
        self._queues: list[queue.Queue[bytes]] = [queue.Queue() for _ in range(workers)]
        self._consumed = [0] * workers
        self._credit_step = credit_step(window)
        endpoint = f"tcp/127.0.0.1:{free_loopback_port()}"
        self._session = zenoh.open(zenoh_config("peer", listen=[endpoint]))
        # BLOCK, not the default DROP: a credit dropped on a congested link would hold
        # its worker until the main process's next one (safe: the worker's callback that
        # takes it never waits).
        self._credits = [
            self._session.declare_publisher(
                consumed_key(prefix, k),
                congestion_control=zenoh.CongestionControl.BLOCK,
                encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM,
            )
            for k in range(workers)
        ]
        self._subscriber = self._session.declare_subscriber(
            f"{prefix}/stage/replay/*/result", self._received
        )
        self._queryable = self._session.declare_queryable(
            ready_key(prefix), lambda query: query.reply(ready_key(prefix), b"")
        )
        context = multiprocessing.get_context("spawn")
        self._done = context.Event()
        self._cpu: multiprocessing.Queue[tuple[int, float]] = context.Queue()
        self.cpu_s = [0.0] * workers
        """Each worker's CPU seconds (``time.process_time``), known once it has ended."""
        self._processes = [
            context.Process(
                target=_run_worker,
                args=(
                    _WorkerArgs(
                        str(recording),
                        config.model_dump_json(),
                        day_posix,
                        k,
                        workers,
                        endpoint,
                        prefix,
                        window,
                    ),
                    self._done,
                    self._cpu,
                    os.getpid(),
                ),
                name=f"tracker-radar-worker-{k}",
            )
            for k in range(workers)
        ]
        for process in self._processes:
            process.start()

    def _received(self, sample: zenoh.Sample) -> None:
        worker = int(str(sample.key_expr).split("/")[-2])
        self._queues[worker].put(sample.payload.to_bytes())

    @property
    def backlog(self) -> list[int]:
        """Per worker, the results received and not yet consumed (at most ``window``)."""
        return [q.qsize() for q in self._queues]

    def _send_credit(self, worker: int) -> None:
        self._credits[worker].put(_COUNT.pack(self._consumed[worker]))

    def _next(self, worker: int) -> DatagramResult:
        while True:
            try:
                return decode_message(self._queues[worker].get(timeout=RESULT_TIMEOUT_S))
            except queue.Empty:
                # Its exact count again: a worker waiting for a credit lost on the way
                # (none should be: the link is reliable) would wait no longer than this.
                self._send_credit(worker)
                process = self._processes[worker]
                if not process.is_alive():
                    raise WorkerFailed(
                        f"radar worker {worker} exited with code {process.exitcode}"
                    ) from None

    def feed(self, payload: bytes, received: float, order: int) -> list[RadarBatch]:
        """The batches of one datagram, from the worker that owns it."""
        worker = owner(payload, self._assignment, self.workers)
        result = self._next(worker)
        if result.kind != MessageKind.DATAGRAM_RESULT or result.order != order:
            raise WorkerFailed(
                f"radar worker {worker}: expected datagram {order}, got {result.kind.name} "
                f"{result.order} (do the workers read the same input?)"
            )
        self._consumed[worker] += 1
        if self._consumed[worker] % self._credit_step == 0:
            self._send_credit(worker)
        self.stats.datagrams += 1
        self.stats.decode_errors += result.decode_errors - self._decode_errors[worker]
        self._decode_errors[worker] = result.decode_errors
        self.admission.per_worker[worker] = result.sources
        for batch in result.batches:
            self.stats.plots += len(batch.plots)
            self.stats.field_monitor_plots += int(batch.plots["rab"].sum())
        return result.batches

    def close(self) -> None:
        """Ends the workers (they wait for this once their input is read) and the session."""
        # A worker killed while it waited on the event may hold the event's lock for good
        # (set() would then block): with one dead, the others are ended instead.
        dead = [
            (k, p.exitcode) for k, p in enumerate(self._processes) if p.exitcode not in (None, 0)
        ]
        if not dead:
            self._done.set()
        else:
            for process in self._processes:
                if process.is_alive():
                    process.terminate()
        for process in self._processes:
            process.join(timeout=5.0)
            if process.is_alive():
                process.kill()
                process.join()
        with contextlib.suppress(queue.Empty):
            while True:
                worker, seconds = self._cpu.get(timeout=0.1)
                self.cpu_s[worker] = seconds
        with contextlib.suppress(zenoh.ZError):
            for publisher in self._credits:
                publisher.undeclare()  # type: ignore[no-untyped-call]
            self._queryable.undeclare()  # type: ignore[no-untyped-call]
            self._subscriber.undeclare()  # type: ignore[no-untyped-call]
            self._session.close()  # type: ignore[no-untyped-call]
        if dead:
            # Its results may all have arrived, but a replay that lost a worker is no
            # replay to trust: said, as when the loss is seen earlier.
            worker, code = dead[0]
            raise WorkerFailed(f"radar worker {worker} exited with code {code}")

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
