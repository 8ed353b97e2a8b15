"""Clock faults of real feeds through the service core, against the clean run.

    tracker-service simulate config/scenarios/three_sites.toml -o midnight.mcap \\
        --duration 80 --start 2026-06-01T23:59:58Z
    python benchmarks/clock_faults.py midnight.mcap [--radar 25_13]

Each fault of tests/test_time_sanity.py (one corrupt I140 in the radar's first plots after
midnight and in the middle of its stream, ten times of day above 86,400 s after the wrap
in a capture replayed 13 hours later, one datagram two hours ahead, the radar restarting
60 s fast and one hour slow, the whole capture replayed 6 h 40 min later, with and
without ``time_base = "reception"``) is applied to the recording's datagrams, which go
through ``TrackerService``. Printed per fault: distinct system-track numbers, the radar's
confirmed local tracks, its updates with a plot after 45 s past midnight of data time,
health and the reasons of the last status. Only the service's public interface is used,
so that the same script measures an older checkout (PYTHONPATH=that checkout).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime
import logging
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from asterix.codec import Block, decode_blocks, encode_block
from asterix.containers import Datagram
from asterix.plots import extract_plots
from tracker_service.chain import BatchOutput
from tracker_service.service.config import ConfigError, ServiceConfig, parse_service_config
from tracker_service.service.core import Outputs, TrackerService
from tracker_service.service.replay import open_replay

MIDNIGHT = datetime.datetime(2026, 6, 2, tzinfo=datetime.UTC).timestamp()
DAY_S = 86400.0
Fault = Callable[[str, Datagram], list[Datagram]]


def retimed(
    payload: bytes, change: Callable[[int, float], float], items: Sequence[str] = ("140", "030")
) -> bytes:
    """The datagram with the times of day in ``items`` (CAT048 I140, CAT034 I030) changed
    by ``change(index of the record in its category, time of day)``."""
    blocks, index = [], {48: 0, 34: 0}
    for event in decode_blocks(payload):
        assert isinstance(event, Block)
        records = []
        for record in event.records:
            item = {48: "140", 34: "030"}.get(event.cat)
            if item is not None and item in items and item in record:
                record = {**record, item: change(index[event.cat], float(record[item]))}
                index[event.cat] += 1
            records.append(record)
        blocks.append(encode_block(event.cat, records))
    return b"".join(blocks)


class Recorded(Outputs):
    def __init__(self, config: ServiceConfig) -> None:
        super().__init__(config)
        self.local: list[tuple[str, Any]] = []

    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None:
        super().batch(output, sources, received)
        self.local += [(output.source, u) for u in output.local]


def faults(radar: str) -> dict[str, tuple[Fault | None, Callable[[dict[str, Any]], None] | None]]:
    def with_mode_s(name: str, datagram: Datagram) -> bool:
        plots = extract_plots(datagram.payload).plots
        return name == radar and len(plots) >= 2 and bool(np.any(plots["address"] >= 0))

    def at(datagram: Datagram) -> float:
        assert datagram.time is not None
        return datagram.time

    def corrupt_once(after: float) -> Fault:
        done = [False]

        def fault(name: str, datagram: Datagram) -> list[Datagram]:
            if done[0] or not with_mode_s(name, datagram) or at(datagram) < after:
                return [datagram]
            done[0] = True
            plots = extract_plots(datagram.payload).plots
            first = int(np.flatnonzero((plots["address"] >= 0) & (plots["rab"] != 1))[0])
            payload = retimed(datagram.payload, lambda i, t: 19711.0 if i == first else t, ["140"])
            return [dataclasses.replace(datagram, payload=payload)]

        return fault

    def ahead() -> Fault:
        done = [False]

        def fault(name: str, datagram: Datagram) -> list[Datagram]:
            if done[0] or not with_mode_s(name, datagram) or at(datagram) < MIDNIGHT + 30:
                return [datagram]
            done[0] = True
            future = retimed(datagram.payload, lambda _i, t: (t + 7200.0) % DAY_S)
            return [datagram, dataclasses.replace(datagram, payload=future)]

        return fault

    def restart(offset: float) -> Fault:
        def fault(name: str, datagram: Datagram) -> list[Datagram]:
            if name != radar or at(datagram) < MIDNIGHT + 25:
                return [datagram]
            payload = retimed(datagram.payload, lambda _i, t: (t + offset) % DAY_S)
            return [dataclasses.replace(datagram, payload=payload)]

        return fault

    def replayed(shift: float, unwrap: bool = False) -> Fault:
        count = [0]

        def fault(name: str, datagram: Datagram) -> list[Datagram]:
            payload = datagram.payload
            late = at(datagram) > MIDNIGHT + 5
            if unwrap and count[0] < 10 and late and with_mode_s(name, datagram):

                def keep(i: int, tod: float) -> float:
                    if i == 0 and tod < 100.0:
                        count[0] += 1
                        return tod + DAY_S
                    return tod

                payload = retimed(payload, keep, ["140"])
            return [dataclasses.replace(datagram, payload=payload, time=at(datagram) + shift)]

        return fault

    def on_reception(doc: dict[str, Any]) -> None:
        for entry in doc["radars"]:
            entry["time_base"] = "reception"

    return {
        "clean": (None, None),
        "corrupt I140 in the first plots after midnight": (corrupt_once(MIDNIGHT), None),
        "corrupt I140 in the middle": (corrupt_once(MIDNIGHT + 40), None),
        "ToD > 86400 after the wrap, replayed 13 h later": (replayed(13 * 3600.0, True), None),
        "one datagram 2 h ahead": (ahead(), None),
        "restarts 60 s fast": (restart(60.0), None),
        "restarts 1 h slow": (restart(-3600.0), None),
        "capture replayed 6 h 40 min later": (replayed(24000.0), None),
        "the same, time_base = reception": (replayed(24000.0), on_reception),
    }


def run(
    path: str,
    key: str,
    fault: Fault | None,
    update: Callable[[dict[str, Any]], None] | None,
) -> str:
    source = open_replay(path)
    config = source.config
    if update is not None:
        doc = config.model_dump(mode="json", exclude_none=True)
        update(doc)
        config = parse_service_config(doc)
    outputs = Recorded(config)
    service = TrackerService(config, outputs=outputs)
    for name, datagram in source.datagrams:
        for faulted in fault(name, datagram) if fault is not None else [datagram]:
            service.process(name, faulted)
    status = service.status()
    service.close()
    mine = [u for r, u in outputs.local if r == key]
    confirmed = len({int(u["track_number"]) for u in mine if u["status"] == 1})
    later = sum(1 for u in mine if u["plot_id"] >= 0 and u["time"] > MIDNIGHT + 45)
    return (
        f"{len(service.counts.system_tracks):4d} system numbers, {key}: {confirmed:3d} "
        f"confirmed, {later:4d} later updates; {status.health}; "
        f"{getattr(status, 'reasons', [])}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--radar", default="25_13", help="the faulty radar's input name")
    args = parser.parse_args()
    logging.disable(logging.WARNING)
    key = args.radar.replace("_", "/")
    for label, (fault, update) in faults(args.radar).items():
        try:
            result = run(args.recording, key, fault, update)
        except ConfigError as exc:  # an older checkout without the setting
            result = f"not configurable: {str(exc).splitlines()[1].strip()}"
        print(f"{label:50s} {result}", flush=True)


if __name__ == "__main__":
    main()
