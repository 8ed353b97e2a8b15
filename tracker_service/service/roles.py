"""``tracker-service run --role radar|fusion``: the chain's two stages in processes (or
hosts) of their own, over Zenoh (docs/deployment.md).

A radar process (``RadarRole``) takes the UDP inputs of the radars it is given, merges
them in reception order behind the holding window as the daemon does, runs their radar
stage, and publishes under ``<prefix>/stage/radars/<name>/`` (``name``: its radars,
"25_11-25_12"):

- ``batches``: a ``stage_messages.DatagramResult`` per datagram with plots, ordered by
  reception time in microseconds; and, when it has sent nothing for ``watermark_period``, one
  without batches whose order is a watermark (the process will send nothing older), every
  ``COUNTERS_S`` one with its inputs' counters (duplicates, drops by cause) for the fusion
  process's status;
- ``alive``: a liveliness token, gone when the process is (a SIGKILL closes its links:
  the fusion process learns it at once and stops waiting for it);
- ``live``: a queryable that answers with its radars' live local tracks (``LIVE_TRACKS``).

The fusion process (``FusionRole``) subscribes to every radar process's batches and
liveliness, merges the batches by reception time (order, then SAC/SIC), releasing one
once every live radar process's watermark has passed it, and runs the central stage and
the outputs (in a process of their own, as the daemon does). ADS-B inputs are its own.
Both shed load as the daemon does (``daemon.Lateness``): a datagram or a batch whose turn
comes more than ``[system] max_behind_s`` behind the wall clock is dropped unprocessed
and counted; the fusion process's status shows that count and the radar processes'
input counters per radar, and its lag is that of the batches it takes (reception at the
radar process to its turn in fusion). What its Zenoh callbacks receive waits in a
``StageInbox`` bounded in bytes, and the loop takes it at least every ``SLICE_S``.
At its start it asks every radar process for its live tracks, so that the picture is
back before the next antenna turn. A radar process that dies stops only its radars:
their system tracks coast and end as if the radars were silent; restarted, it resumes
them (its tracks new to the fuser: ``stage_messages.RadarBatch.incarnation``).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import logging
import threading
import time
from collections import Counter, deque
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path

import zenoh

from asterix.containers import Datagram
from tracker_service.chain import source_order
from tracker_service.inputs.arrivals import Arrivals
from tracker_service.inputs.udp import InputCounters, UdpInput, kernel_drop_table
from tracker_service.loop_load import LoopLoad, LoopTotals
from tracker_service.outputs.zenoh_session import open_session, zenoh_config
from tracker_service.radar_stage import RadarState, StageStats
from tracker_service.service.command import open_service, short_switch_interval
from tracker_service.service.config import ServiceConfig
from tracker_service.service.core import TrackerService, build_radar_stage, input_name
from tracker_service.service.daemon import (
    COUNTERS_S,
    QUIET_S,
    InputError,
    Lateness,
    Merger,
    input_counters,
    open_inputs,
    take_ready,
)
from tracker_service.service.memory import resident_mb
from tracker_service.service.signals import Stop
from tracker_service.service.warm_up import WarmUpStopped, core_warm_up, radar_warm_up
from tracker_service.sources import SourceCounts
from tracker_service.stage_messages import (
    DatagramResult,
    MessageKind,
    RadarBatch,
    StageMessageError,
    decode_message,
    encode_message,
)

__all__ = ["FusionRole", "RadarRole", "StageMerge", "stage_name"]

log = logging.getLogger(__name__)

WATERMARK_MAX_S = 0.1
WATERMARK_MIN_S = 0.005


def watermark_period(holding_window_s: float) -> float:
    """How long a radar process stays silent before it sends its watermark. Fusion holds a
    batch until every other radar process has passed its time, so with several of them
    each batch waited for the latest of their next watermarks: every 0.1 s, that was 67
    ms more on the median of three_sites in three radar processes (docs/benchmarks.md,
    session 23). A watermark now runs ``radar_watermark``'s half window ahead of the
    merger's release, so that one sent within the last half window has passed any batch
    another radar process can have published: no wait. Each costs ~0.25 ms of CPU at
    either end (Zenoh's wake-ups) and a busy process sends none (its batches carry the
    order): half the holding window, within 5 ms and 0.1 s."""
    return min(max(holding_window_s / 2, WATERMARK_MIN_S), WATERMARK_MAX_S)


def radar_watermark(oldest_held: float | None, taken: float, holding_window_s: float) -> float:
    """The reception time (POSIX s) before which a radar process will send nothing more:
    the oldest datagram its merger holds, else half a holding window before it last took
    its inputs' queues (``taken``). A datagram is stamped on reception and queued a few
    bytecodes later: one stamped before ``taken`` but queued after it is the only thing
    that could come older, and the half window is its margin, as the window itself is
    the one-process merger's. Not the merger's release (``taken`` less the whole window):
    that trails what another radar process publishes by the window, so every batch of
    theirs waited for this one's next watermark."""
    lead = taken - holding_window_s / 2
    return lead if oldest_held is None else min(oldest_held, lead)


STALLED_S = 2.0
"""A live radar process silent this long (no batch, no heartbeat) is not waited for."""
LIVE_QUERY_S = 2.0
SLICE_S = 0.05
"""The fusion process takes released batches for at most this long before it looks at
its inbox again: what waits is in the merge (decoded, ordered, shed when too late), not
in the inbox."""


def stage_name(radars: list[str]) -> str:
    """The key segment of a radar process: its radars, "25_11-25_12"."""
    return "-".join(input_name(r) for r in sorted(radars, key=source_order))


def reception_order(t: float) -> int:
    """A radar process's order of a datagram (and its watermarks): its reception time
    in microseconds."""
    return round(t * 1e6)


STAGE_LISTEN_FIX = "listen on another port (--stage-listen)"
"""Where the stage session's endpoints come from, for its errors."""


def stage_session_config(
    config: ServiceConfig, listen: list[str], connect: list[str]
) -> zenoh.Config:
    """The stage session's: ``[zenoh]``'s file, mode and scouting, the role's endpoints."""
    z = config.zenoh
    return zenoh_config(
        z.mode,
        listen,
        connect,
        z.config_file,
        scouting=z.scouting,
        allow_plaintext=z.allow_plaintext,
    )


def _session(config: ServiceConfig, listen: list[str], connect: list[str]) -> zenoh.Session:
    return open_session(stage_session_config(config, listen, connect), STAGE_LISTEN_FIX)


class RadarRole:
    """See the module docstring. ``radars``: "SAC/SIC" of configured radars with an
    ``[input]``; ``listen``/``connect``: the stage session's endpoints."""

    def __init__(
        self, config: ServiceConfig, radars: list[str], listen: list[str], connect: list[str]
    ) -> None:
        known = {radar.key for radar in config.radars}
        unknown = [r for r in radars if r not in known]
        if unknown or not radars:
            raise InputError(
                f"--radars {','.join(radars)}: {', '.join(unknown) or 'none given'} not among "
                f"the configured radars ({', '.join(sorted(known, key=source_order))})"
            )
        self.config = config
        self.radars = radars
        self.listen, self.connect = listen, connect
        self.name = stage_name(radars)

    def run(self, stop: Stop) -> int:
        with short_switch_interval():
            return self._run(stop)

    def _run(self, stop: Stop) -> int:
        config = self.config
        mine = [r for r in config.radars if r.key in self.radars]
        load = LoopLoad()
        arrivals = Arrivals(load.waited)
        inputs = open_inputs(
            config.model_copy(update={"radars": mine, "adsb": []}), arrivals=arrivals
        )
        with contextlib.suppress(WarmUpStopped):  # the inputs bound: see ``Daemon.run``
            radar_warm_up(config, stop)
        if stop.is_set():
            for udp in inputs:
                udp.close()
            return 0
        started = time.time()
        stage = build_radar_stage(config, incarnation=time.time_ns() // 1_000_000)
        lock = threading.Lock()
        system = config.system
        merger = Merger(
            system.holding_window_s,
            system.holding_window_max_datagrams,
            int(system.holding_window_max_mb * 1024 * 1024),
        )
        lateness = Lateness(system.holding_window_s, system.max_behind_s)
        lateness.started = started
        period = watermark_period(system.holding_window_s)
        base = f"{config.zenoh.prefix}/stage/radars/{self.name}"
        watermark = reception_order(time.time() - system.holding_window_s)
        session = _session(config, self.listen, self.connect)

        def answer(query: zenoh.Query) -> None:
            with lock:
                batches = stage.live_tracks(watermark, watermark / 1e6)
            result = DatagramResult(
                watermark, watermark / 1e6, batches, kind=MessageKind.LIVE_TRACKS
            )
            query.reply(f"{base}/live", encode_message(result))

        try:
            publisher = session.declare_publisher(
                f"{base}/batches",
                congestion_control=zenoh.CongestionControl.BLOCK,
                encoding=zenoh.Encoding.APPLICATION_OCTET_STREAM,
            )
            token = session.liveliness().declare_token(f"{base}/alive")
            queryable = session.declare_queryable(f"{base}/live", answer)
            log.info("radar stage %s: publishing under %s/", ", ".join(self.radars), base)
            last_sent = next_counters = 0.0
            while not stop.is_set():
                taken = time.time()
                for name, datagram in take_ready(inputs, arrivals.take()):
                    merger.push(name, datagram)
                now = time.time()
                for name, datagram in merger.release(now):
                    assert datagram.time is not None
                    if not lateness.admit(name, datagram.time):
                        continue
                    order = reception_order(datagram.time)
                    with lock:
                        batches = stage.feed(datagram.payload, datagram.time, order)
                    if batches:
                        publisher.put(
                            encode_message(
                                DatagramResult(
                                    order,
                                    datagram.time,
                                    batches,
                                    stage.stats.decode_errors,
                                    stage.admission.counts,
                                )
                            )
                        )
                        # The live tracks' order too (``answer``): a busy process sends
                        # no watermarks, and its tracks are of this datagram by now.
                        watermark = order
                        last_sent = now
                if now - last_sent >= period or now >= next_counters:
                    watermark = reception_order(
                        radar_watermark(merger.oldest(), taken, system.holding_window_s)
                    )
                    beat = DatagramResult(watermark, watermark / 1e6)
                    if now >= next_counters:
                        beat.inputs = input_counters(inputs, merger, lateness)
                        beat.resident_mb = resident_mb()
                        beat.loop = load.totals()
                        next_counters = now + COUNTERS_S
                    publisher.put(encode_message(beat))
                    last_sent = now
                # Until data comes, the oldest datagram held is due, or the next watermark.
                arrivals.wait_until(merger.due(), last_sent + period)
            queryable.undeclare()  # type: ignore[no-untyped-call]
            token.undeclare()  # type: ignore[no-untyped-call]
        finally:
            for udp in inputs:
                udp.close()
            session.close()  # type: ignore[no-untyped-call]
        return 0


class NoRadarStages:
    """The fusion process's chain has no radar stage of its own: its datagrams (ADS-B)
    go to the central stage only."""

    def __init__(self) -> None:
        self.stats = StageStats()
        self.radars: dict[str, RadarState] = {}

    @property
    def admission(self) -> NoRadarStages:
        return self

    @property
    def counts(self) -> SourceCounts:
        return SourceCounts()

    def feed(self, payload: bytes, received: float, order: int) -> list[RadarBatch]:
        return []


@dataclass
class _Producer:
    watermark: int = -1
    heard: float = 0.0
    alive: bool = True


class StageMerge:
    """Radar batches (and the fusion process's own datagrams) of several producers,
    released in (order, SAC/SIC) order once every live producer has passed them."""

    def __init__(self) -> None:
        self.producers: dict[str, _Producer] = {}
        self._heap: list[tuple[int, tuple[int, ...], int, RadarBatch | tuple[str, Datagram]]] = []
        self._seq = itertools.count()

    def __len__(self) -> int:
        return len(self._heap)

    def note(self, producer: str, watermark: int, now: float) -> None:
        entry = self.producers.setdefault(producer, _Producer())
        entry.watermark = max(entry.watermark, watermark)
        entry.heard = now
        entry.alive = True

    def gone(self, producer: str) -> None:
        entry = self.producers.get(producer)
        if entry is not None:
            entry.alive = False

    def push_batch(self, batch: RadarBatch) -> None:
        key = source_order(batch.source)
        heapq.heappush(self._heap, (batch.order, key, next(self._seq), batch))

    def push_datagram(self, name: str, datagram: Datagram) -> None:
        assert datagram.time is not None
        heapq.heappush(
            self._heap, (reception_order(datagram.time), (), next(self._seq), (name, datagram))
        )

    def release(self, now: float) -> Iterator[RadarBatch | tuple[str, Datagram]]:
        """What every live producer has passed at ``now``, in order, taken one at a time:
        what the caller does not take stays for the next call."""
        waited = [
            p.watermark for p in self.producers.values() if p.alive and now - p.heard < STALLED_S
        ]
        limit = min(waited) if waited else None
        while self._heap and (limit is None or self._heap[0][0] <= limit):
            yield heapq.heappop(self._heap)[3]

    def next_release(self, now: float, clocked: str, lag: float) -> float | None:
        """When (POSIX s) the oldest item held may be released though nothing more
        arrives; None when nothing is held. Each live producer whose watermark holds it
        back lets it go when it stalls (``STALLED_S`` after it was last heard), except
        ``clocked``, whose watermark follows the wall clock ``lag`` s behind (the fusion
        process's own inputs): it passes the item ``lag`` after the item's time. With
        nothing holding it back (the caller stopped taking), that is ``now``."""
        if not self._heap:
            return None
        oldest = self._heap[0][0]
        times = [
            oldest / 1e6 + lag if name == clocked else p.heard + STALLED_S
            for name, p in self.producers.items()
            if p.alive and now - p.heard < STALLED_S and p.watermark < oldest
        ]
        return min(times, default=now)


INBOX = "stage inbox"
"""The fusion process's inbox among the names its ``Arrivals`` hears (no input's name:
those are SAC_SIC)."""
LOCAL = "local"
"""The fusion process's own inputs as a producer of its ``StageMerge``."""


class StageInbox:
    """What the fusion process's Zenoh callbacks received and its loop has not yet
    taken: bounded in bytes, so that a loop that cannot even decode at the rate the
    radar processes send drops and counts (by producer) rather than hold it all. What it
    holds is announced to ``arrivals`` under ``INBOX``, as an input's datagrams are."""

    def __init__(self, max_bytes: int, arrivals: Arrivals | None = None) -> None:
        self.max_bytes = max_bytes
        self.arrivals = arrivals
        self.size = 0
        """Bytes held."""
        self.dropped: Counter[str] = Counter()
        self._items: deque[tuple[str, str, bytes]] = deque()
        self._lock = threading.Lock()

    def put(self, kind: str, producer: str, payload: bytes) -> None:
        """From a Zenoh callback (any thread); never blocks."""
        with self._lock:
            if self.size + len(payload) > self.max_bytes:
                self.dropped[producer] += 1
                return
            self._items.append((kind, producer, payload))
            self.size += len(payload)
        if self.arrivals is not None:
            self.arrivals.notify(INBOX)

    def take(self) -> list[tuple[str, str, bytes]]:
        """Everything received so far, in arrival order."""
        with self._lock:
            items = list(self._items)
            self._items.clear()
            self.size = 0
        return items


class FusionRole:
    """See the module docstring."""

    def __init__(
        self,
        config: ServiceConfig,
        listen: list[str],
        connect: list[str],
        health_file: Path | None = None,
    ) -> None:
        self.config = config
        self.listen, self.connect = listen, connect
        self.health_file = health_file
        system = config.system
        self.lateness = Lateness(system.holding_window_s, system.max_behind_s)
        self.load = LoopLoad()
        """Its loop's: the status's ``busy["core"]``."""
        self.arrivals = Arrivals(self.load.waited)
        """Heard by the Zenoh callbacks (through the inbox) and by the own inputs."""
        self.inbox = StageInbox(int(system.holding_window_max_mb * 1024 * 1024), self.arrivals)
        self.remote_inputs: dict[str, dict[str, InputCounters]] = {}
        """Per radar process, its inputs' counters (from its watermarks)."""
        self.remote_memory: dict[str, float] = {}
        """Per live radar process, its resident memory, MB (from its watermarks)."""
        self.remote_loops: dict[str, LoopTotals] = {}
        """Per live radar process, its loop's totals (from its watermarks)."""
        self._inbox_counted = 0

    def run(self, stop: Stop) -> int:
        config = self.config
        prefix = f"{config.zenoh.prefix}/stage/radars"
        window = config.system.holding_window_s
        inputs = open_inputs(config.model_copy(update={"radars": []}), arrivals=self.arrivals)
        try:
            warm_up = core_warm_up(config, stop, remote_radars=True)
        except WarmUpStopped:
            warm_up = None
        if stop.is_set():
            for udp in inputs:
                udp.close()
            return 0
        self.lateness.started = time.time()
        inbox = self.inbox

        def producer_of(key: zenoh.KeyExpr) -> str:
            return str(key).removeprefix(prefix + "/").split("/")[0]

        session = _session(config, self.listen, self.connect)
        try:
            with open_service(
                config,
                config.mcap.directory,
                output_process=True,
                health_file=self.health_file,
                radar_stage=NoRadarStages(),
                warm_up=warm_up,
            ) as service:
                service.advance(time.time() - window)
                session.declare_subscriber(
                    f"{prefix}/*/batches",
                    lambda s: inbox.put("batch", producer_of(s.key_expr), s.payload.to_bytes()),
                )
                session.liveliness().declare_subscriber(
                    f"{prefix}/*/alive",
                    lambda s: inbox.put(str(s.kind), producer_of(s.key_expr), b""),
                    history=True,
                )
                merge = StageMerge()
                self._rebuild(session, prefix, merge)
                log.info("fusion: taking the radar stages under %s/", prefix)
                self._loop(service, inputs, merge, stop)
        finally:
            for udp in inputs:
                udp.close()
            session.close()  # type: ignore[no-untyped-call]
        return 0

    @staticmethod
    def _rebuild(session: zenoh.Session, prefix: str, merge: StageMerge) -> None:
        """Every radar process's live tracks, before their next batches."""
        for reply in session.get(f"{prefix}/*/live", timeout=LIVE_QUERY_S):
            if reply.ok is None:
                continue
            try:
                result = decode_message(reply.ok.payload.to_bytes())
            except StageMessageError as exc:
                log.warning("live tracks from %s refused: %s", reply.ok.key_expr, exc)
                continue
            for batch in result.batches:
                merge.push_batch(batch)
            log.info(
                "live tracks of %s: %d",
                reply.ok.key_expr,
                sum(len(b.local) for b in result.batches),
            )

    def _take_inbox(self, merge: StageMerge, now: float) -> None:
        """The inbox into the merge."""
        for kind, producer, payload in self.inbox.take():
            if kind == "batch":
                try:
                    result = decode_message(payload)
                except StageMessageError as exc:
                    log.warning("a batch from %s refused: %s", producer, exc)
                    continue
                merge.note(producer, result.order, now)
                for batch in result.batches:
                    merge.push_batch(batch)
                if result.inputs:
                    self.remote_inputs[producer] = result.inputs
                if result.resident_mb is not None:
                    self.remote_memory[producer] = result.resident_mb
                if result.loop is not None:
                    self.remote_loops[producer] = result.loop
            elif kind.endswith("DELETE"):
                log.warning("radar stage %s gone: its radars coast", producer)
                merge.gone(producer)
                self.remote_memory.pop(producer, None)
                self.remote_loops.pop(producer, None)
            else:
                merge.note(producer, -1, now)

    def _loop(
        self, service: TrackerService, inputs: list[UdpInput], merge: StageMerge, stop: Stop
    ) -> None:
        window = self.config.system.holding_window_s
        lateness = self.lateness
        arrivals = self.arrivals
        last_data = time.time()
        next_counters = 0.0
        while not stop.is_set():
            now = time.time()
            ready = arrivals.take()
            if INBOX in ready:
                self._take_inbox(merge, now)
            for name, datagram in take_ready(inputs, ready):
                merge.push_datagram(name, datagram)
            if inputs:
                merge.note(LOCAL, reception_order(now - window), now)
            deadline = now + SLICE_S
            for item in merge.release(now):
                last_data = now
                if isinstance(item, RadarBatch):
                    if lateness.admit(input_name(item.source), item.received):
                        service.process_batch(item)
                else:
                    name, datagram = item
                    assert datagram.time is not None
                    if lateness.admit(name, datagram.time):
                        service.process(name, datagram)
                if time.time() >= deadline:
                    break
            if now >= next_counters:
                self._update_counters(service, inputs)
                next_counters = now + COUNTERS_S
            if now - last_data > QUIET_S and not merge:
                service.advance(now - window)
                last_data = now - QUIET_S + 0.1
            # Until a message or a datagram comes, or the next duty: what the merge holds
            # releasable (at once when the slice above ended it), the counters, data
            # time's advance while quiet.
            arrivals.wait_until(
                merge.next_release(now, LOCAL, window),
                next_counters,
                None if merge else last_data + QUIET_S,
            )
        self._update_counters(service, inputs)

    def _update_counters(self, service: TrackerService, inputs: list[UdpInput]) -> None:
        """The status's input counters: the radar processes' (as they last sent them) and
        this process's own inputs', with what this process shed; and its lag."""
        counters: dict[str, InputCounters] = {}
        for remote in self.remote_inputs.values():
            counters.update({name: replace(c) for name, c in remote.items()})
        drop_table = kernel_drop_table()
        for udp in inputs:
            counters[udp.name] = udp.counters_with(drop_table)
        for name, n in self.lateness.dropped.items():
            entry = counters.setdefault(name, InputCounters())
            entry.behind_dropped += n
        for name, n in self.lateness.warm_up_dropped.items():
            entry = counters.setdefault(name, InputCounters())
            entry.warm_up_dropped += n
        service.set_input_counters(counters)
        lost = sum(self.inbox.dropped.values())
        if lost > self._inbox_counted:
            service.outputs.count("stage", "stage_inbox_full", lost - self._inbox_counted)
            self._inbox_counted = lost
        loops = {"core": self.load.totals()}
        loops.update((f"radar {name}", t) for name, t in sorted(self.remote_loops.items()))
        service.note_live(
            self.lateness.take_lag(),
            {f"radar {name}": mb for name, mb in sorted(self.remote_memory.items())},
            loops,
        )
