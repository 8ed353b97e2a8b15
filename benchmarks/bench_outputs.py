"""The outputs' cost per plot, old path against new, in one run, on a `scale` slice.

The chain runs once over the recording (not timed) and what it hands the outputs is kept:
each radar batch's rows (``BatchOutput``) and the CAT062 cadence. Then each output stage
runs over those rows, the way it ran before issue 12's output work (one pydantic model per update,
``model_dump_json``, the generic codec, one sink call per message) and the way it runs
now (``MessageMapper.local_updates``/``system_updates``, ``encode_system_batch``, one
sink call per batch), interleaved, ``--repeats`` times; CPU time (``time.process_time``),
medians, ratios.

    python benchmarks/bench_outputs.py RECORDING [--repeats 5] [--calls FILE] [--json]

RECORDING: e.g. ``tracker-service simulate config/scenarios/scale.toml --duration 40
-o scale40.mcap``. ``--calls FILE`` keeps the chain's output in FILE (pickle) and reads it
from there on the next run: the chain on `scale` is slow.

Stages (each timed alone, over every batch of the slice):

- local messages: local-track rows to JSON payloads;
- system messages: system-track rows (with their plots) to JSON payloads;
- CAT062: each second's latest update per track to CAT062 blocks;
- MCAP: the payloads into a real MCAP log in
  a temporary directory, closed at the end;
- Zenoh: the payloads put on a real Zenoh session (peer, no endpoint, scouting off: the
  cost of the call, with no network behind it);
- all outputs, new: ``Outputs`` as the service runs it (mapper, CAT062, both sinks on
  their threads), drained; the old path as the sum of its stages.
"""

from __future__ import annotations

import argparse
import gc
import json
import pickle
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tracker_service.chain import BatchOutput
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.cat062 import encode_system_batch, encode_system_tracks_generic
from tracker_service.outputs.mapping import MessageMapper, ModelMapper
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.mcap_sink import SYSTEM_TRACKS_TOPIC, McapSink
from tracker_service.outputs.messages import LocalTrackMessage, SystemTrackMessage
from tracker_service.outputs.updates import SystemBatch
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_sink import ZenohSink
from tracker_service.service.config import ServiceConfig
from tracker_service.service.core import Outputs, TrackerService
from tracker_service.service.replay import open_replay


@dataclass
class Captured:
    """What the chain handed the outputs: ("batch", BatchOutput, sources) and ("cat062",)
    in order, with data time."""

    config: ServiceConfig
    calls: list[tuple[Any, ...]]

    @property
    def batches(self) -> list[tuple[BatchOutput, tuple[str, ...]]]:
        return [(c[1], c[2]) for c in self.calls if c[0] == "batch"]


class _Recorder:
    """An ``OutputSink`` that keeps the calls the stages under test take."""

    def __init__(self) -> None:
        self.calls: list[tuple[Any, ...]] = []
        self.now = 0.0

    def advance(self, time: float) -> None:
        self.now = max(self.now, time)

    def set_input_counters(self, counters: object) -> None: ...
    def set_core_state(self, state: object) -> None: ...

    def received(self, name: str, datagram: Any) -> None:
        self.advance(datagram.time)

    def error(self, *args: object) -> None: ...
    def count(self, *args: object) -> None: ...

    def batch(self, output: BatchOutput, sources: Any, received: float | None = None) -> None:
        if received is not None:
            self.advance(received)
        self.calls.append(("batch", output, tuple(sources), self.now))

    def publish_cat062(self) -> None:
        self.calls.append(("cat062", self.now))

    def publish_bias(self, *args: object) -> None: ...
    def publish_status(self) -> None: ...
    def close(self) -> None: ...


def capture(recording: Path, cache: Path | None) -> Captured:
    if cache is not None and cache.exists():
        with cache.open("rb") as f:
            loaded: Captured = pickle.load(f)
            return loaded
    replay = open_replay(recording)
    recorder = _Recorder()
    service = TrackerService(replay.config, outputs=recorder)
    start = time.process_time()
    for name, datagram in replay.datagrams:
        service.process(name, datagram)
    print(
        f"chain: {time.process_time() - start:.1f} CPU s (not part of the figures)", file=sys.stderr
    )
    captured = Captured(replay.config, recorder.calls)
    if cache is not None:
        with cache.open("wb") as f:
            pickle.dump(captured, f)
    return captured


def _plane(config: ServiceConfig) -> SystemPlane:
    s = config.system
    return SystemPlane(s.centre_lat, s.centre_lon, s.projection)


# --- the stages, old and new ------------------------------------------------------------


def local_old(c: Captured) -> None:
    mapper = ModelMapper(_plane(c.config))
    for output, _ in c.batches:
        for message in mapper.local(output.source, output.local):
            message.model_dump_json().encode()


def local_new(c: Captured) -> None:
    mapper = MessageMapper(_plane(c.config))
    for output, _ in c.batches:
        mapper.local_updates(output.source, output.local)


def _system_old(c: Captured) -> list[list[SystemTrackMessage]]:
    mapper = ModelMapper(_plane(c.config))
    out = []
    for output, sources in c.batches:
        mapper.local(output.source, output.local)  # the sources' ages need their times
        messages = mapper.system(output.system, output.plots, sources) if len(output.system) else []
        for m in messages:
            m.model_dump_json().encode()
        out.append(messages)
    return out


def _system_new(c: Captured) -> list[list[Any]]:
    mapper = MessageMapper(_plane(c.config))
    out = []
    for output, sources in c.batches:
        mapper.local_updates(output.source, output.local)
        out.append(
            mapper.system_updates(output.system, output.plots, sources)
            if len(output.system)
            else []
        )
    return out


def _cat062_batches(
    c: Captured, per_batch: list[list[Any]], key: Callable[[Any], int]
) -> list[list[Any]]:
    """Each CAT062 call's pending updates (the latest per track, by number)."""
    batches, pending, i = [], {}, 0
    for call in c.calls:
        if call[0] == "batch":
            for u in per_batch[i]:
                pending[key(u)] = u
            i += 1
        else:
            batches.append([pending[n] for n in sorted(pending)])
            pending = {}
    return batches


def run(c: Captured, repeats: int) -> dict[str, Any]:
    config = c.config
    plots = sum(len(o.plots) for o, _ in c.batches)
    locals_ = sum(len(o.local) for o, _ in c.batches)
    old_system = _system_old(c)
    new_system = _system_new(c)
    systems = sum(len(s) for s in new_system)
    old_cat = _cat062_batches(c, old_system, lambda m: m.number)
    new_cat = [
        SystemBatch.gather([(u.batch, u.index) for u in b])
        for b in _cat062_batches(c, new_system, lambda u: u.number)
        if b
    ]
    old_cat = [b for b in old_cat if b]
    assert all(
        encode_system_tracks_generic(o, config.system) == encode_system_batch(n, config.system)
        for o, n in zip(old_cat[:3], new_cat[:3], strict=True)
    ), "the two CAT062 paths differ"
    old_local = [
        (o.source, ModelMapper(_plane(config)).local(o.source, o.local)) for o, _ in c.batches
    ]
    new_local_mapper = MessageMapper(_plane(config))
    new_local = [
        (o.source, new_local_mapper.local_updates(o.source, o.local)) for o, _ in c.batches
    ]
    times = [call[-1] for call in c.calls if call[0] == "batch"]
    tmp = Path(tempfile.mkdtemp(prefix="bench_outputs_"))
    publisher = ZenohPublisher(mode="peer")

    def mcap_old() -> None:
        with McapLog(tmp / f"old{time.monotonic_ns()}", name="old") as log:
            for (radar, messages), system, now in zip(old_local, old_system, times, strict=True):
                topic = f"/local_tracks/{radar.replace('/', '_')}"
                for m in messages:
                    log.log_json(topic, LocalTrackMessage, m.model_dump_json().encode(), now)
                for s in system:
                    log.log_json(
                        SYSTEM_TRACKS_TOPIC, SystemTrackMessage, s.model_dump_json().encode(), now
                    )

    def mcap_new() -> None:
        with McapLog(tmp / f"new{time.monotonic_ns()}", name="new") as log:
            sink = McapSink(log)
            for (radar, updates), system, now in zip(new_local, new_system, times, strict=True):
                sink.local_updates(radar, updates, now)
                if system:
                    sink.system_updates(system, now)

    def zenoh_old() -> None:
        for (radar, messages), system in zip(old_local, old_system, strict=True):
            sac_sic = tuple(int(p) for p in radar.split("/"))
            for m in messages:
                publisher.put_local_track(sac_sic, m.number, m.model_dump_json().encode())  # type: ignore[arg-type]
            for s in system:
                if s.status == "ended":
                    publisher.end_system_track(s.number, s.model_dump_json().encode())
                else:
                    publisher.put_system_track(s.number, s.model_dump_json().encode())

    def zenoh_new() -> None:
        sink = ZenohSink(publisher)
        for (radar, updates), system, now in zip(new_local, new_system, times, strict=True):
            sink.local_updates(radar, updates, now)
            sink.system_updates(system, now)

    def all_new() -> None:
        with McapLog(tmp / f"all{time.monotonic_ns()}", name="all") as log:
            outputs = Outputs(config, publisher, log)
            for call in c.calls:
                outputs.advance(call[-1])
                if call[0] == "batch":
                    outputs.batch(call[1], call[2])
                else:
                    outputs.publish_cat062()
            outputs.drain()
            outputs.stop()

    # The old path's serialisation is inside its MCAP and Zenoh stages (as the service
    # serialised once for both, each stage here pays it: the payload part is subtracted
    # below with the serialise-only timing).
    def serialise_old() -> None:
        for (_, messages), system in zip(old_local, old_system, strict=True):
            for m in messages:
                m.model_dump_json().encode()
            for s in system:
                s.model_dump_json().encode()

    stages: dict[str, tuple[Callable[[], Any], Callable[[], Any]]] = {
        "local messages": (lambda: local_old(c), lambda: local_new(c)),
        "system messages": (lambda: _system_old(c), lambda: _system_new(c)),
        "CAT062": (
            lambda: [encode_system_tracks_generic(b, config.system) for b in old_cat],
            lambda: [encode_system_batch(b, config.system) for b in new_cat],
        ),
        "MCAP": (mcap_old, mcap_new),
        "Zenoh": (zenoh_old, zenoh_new),
        "serialise (old, inside MCAP and Zenoh)": (serialise_old, lambda: None),
    }
    samples: dict[str, dict[str, list[float]]] = {k: {"old": [], "new": []} for k in stages}
    samples["all outputs"] = {"old": [], "new": []}
    try:
        for _ in range(repeats):
            for name, (old, new) in stages.items():
                for label, fn in (("old", old), ("new", new)):
                    gc.collect()
                    start = time.process_time()
                    fn()
                    samples[name][label].append(time.process_time() - start)
            gc.collect()
            start = time.process_time()
            all_new()
            samples["all outputs"]["new"].append(time.process_time() - start)
    finally:
        # Zenoh's threads would keep a failed run alive.
        publisher.close()
    # The system stage's old and new each also map the local rows (the sources' ages
    # need them): subtract that, so each stage is its own.
    report: dict[str, Any] = {
        "plots": plots,
        "local_updates": locals_,
        "system_updates": systems,
        "cat062_batches": len(new_cat),
        "repeats": repeats,
        "stages": {},
    }
    med = {k: {lab: statistics.median(v) for lab, v in d.items() if v} for k, d in samples.items()}
    med["system messages"] = {
        lab: med["system messages"][lab] - med["local messages"][lab] for lab in ("old", "new")
    }
    ser = med.pop("serialise (old, inside MCAP and Zenoh)")["old"]
    for k in ("MCAP", "Zenoh"):
        med[k]["old"] -= ser
    med["all outputs"]["old"] = sum(
        med[k]["old"] for k in ("local messages", "system messages", "CAT062", "MCAP", "Zenoh")
    )
    for name, m in med.items():
        report["stages"][name] = {
            "old_s": m["old"],
            "new_s": m["new"],
            "old_us_per_plot": 1e6 * m["old"] / plots,
            "new_us_per_plot": 1e6 * m["new"] / plots,
            "ratio": m["old"] / m["new"] if m["new"] > 0 else float("inf"),
        }
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--calls", type=Path, default=None)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    report = run(capture(args.recording, args.calls), args.repeats)
    if args.json:
        json.dump(report, sys.stdout, indent=2)
        print()
        return
    print(
        f"{report['plots']} plots, {report['local_updates']} local and "
        f"{report['system_updates']} system updates, {report['cat062_batches']} CAT062 "
        f"batches; medians of {report['repeats']} runs, CPU time"
    )
    print(f"{'stage':<18} {'old us/plot':>12} {'new us/plot':>12} {'old/new':>8}")
    for name, s in report["stages"].items():
        print(
            f"{name:<18} {s['old_us_per_plot']:>12.2f} {s['new_us_per_plot']:>12.2f} "
            f"{s['ratio']:>8.1f}"
        )


if __name__ == "__main__":
    main()
