"""``tracker-service replay``: a recording through the whole service, as the daemon runs it.

Three kinds of input, told apart by their content:

- a simulator recording (MCAP): the radars come from its metadata unless ``--config``
  gives them; both LANs' datagrams go through the duplicate filter, as live;
- a log of the service (MCAP, or a directory of them): the configuration comes from its
  metadata, the datagrams are fed in the order the service processed them (file order),
  so the replay gives the system tracks the service gave;
- pcap, pcapng, GPS, final format, raw and hex captures (``asterix.containers``): the
  radars need ``--config``; captures that hold times of day (GPS, final) or no times at
  all (raw, hex: the datagram's own I140/I030 stand in) need ``--date``.

Pacing follows the reception times divided by ``--speed``, or none with ``max``.
"""

from __future__ import annotations

import argparse
import datetime as dt
import itertools
import json
import math
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import TextIO

import numpy as np

from asterix.codec import Block, decode_blocks
from asterix.containers import ContainerError, Datagram, read_file
from asterix.plots import extract_plots
from tracker_service.chain import SERVICE_CATEGORIES, blocks_of
from tracker_service.ingest import DAY_S, DuplicateFilter
from tracker_service.inputs.udp import InputCounters
from tracker_service.outputs.mcap_log import read_log_messages, read_log_metadata
from tracker_service.service.config import (
    ConfigError,
    ServiceConfig,
    ZenohConfig,
    parse_service_config,
)
from tracker_service.service.core import config_from_recording, input_name
from tracker_service.simulator.recording import is_mcap, read_recording

__all__ = [
    "CONFIG_METADATA",
    "Replay",
    "open_replay",
    "parse_date",
    "parse_speed",
]

CONFIG_METADATA = "service"
"""The name of the metadata record that holds the service's configuration in its log
(key "config", the configuration as JSON)."""
DATAGRAM_PREFIX = "/datagrams/"


@dataclass
class Replay:
    """What a replay feeds the service: the configuration, and the datagrams in order
    with the name of their input."""

    config: ServiceConfig
    datagrams: Iterator[tuple[str, Datagram]]
    kind: str
    """"simulation", "service log" or the capture format."""
    span: tuple[float, float] | None = None
    """First and last reception time, when known beforehand (for the progress bar)."""
    counters: dict[str, InputCounters] = field(default_factory=dict)
    """Per input, what the duplicate filter and the container reader counted."""


def parse_speed(text: str) -> float:
    """``--speed``: a positive factor, or "max" (infinity: no pacing)."""
    if text == "max":
        return math.inf
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is neither a number nor 'max'") from None
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"speed {text!r} must be a positive number or 'max'")
    return value


def parse_date(text: str) -> float:
    """``--date YYYY-MM-DD``: the POSIX time of that day's UTC midnight."""
    try:
        day = dt.date.fromisoformat(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a date YYYY-MM-DD") from None
    return dt.datetime(day.year, day.month, day.day, tzinfo=dt.UTC).timestamp()


def open_replay(
    path: str | Path, config: ServiceConfig | None = None, day_posix: float | None = None
) -> Replay:
    """The replay of ``path``; ValueError (or ConfigError) says what is missing."""
    file = Path(path)
    logs = sorted(file.glob("*.mcap")) if file.is_dir() else [file]
    if not logs:
        raise ValueError(f"{file}: a directory without .mcap files")
    if is_mcap(logs[0]):
        metadata = read_log_metadata(logs[0])
        if CONFIG_METADATA in metadata:
            return _service_log(logs, metadata[CONFIG_METADATA], config)
        if file.is_dir():
            raise ValueError(f"{file}: only a directory of the service's logs can be replayed")
        return _simulation(file, config)
    if config is None:
        raise ConfigError(
            f"{file}: a capture says nothing of the radars' sites; give --config FILE"
        )
    return _capture(file, config, day_posix)


def _service_log(
    files: list[Path], metadata: dict[str, str], config: ServiceConfig | None
) -> Replay:
    if config is None:
        logged = parse_service_config(json.loads(metadata["config"]), f"{files[0]} metadata")
        # Where the logging service listened is not where its replay should: the command
        # line says that.
        zenoh = ZenohConfig(mode=logged.zenoh.mode, prefix=logged.zenoh.prefix)
        config = logged.model_copy(update={"zenoh": zenoh})

    def datagrams() -> Iterator[tuple[str, Datagram]]:
        number = 0
        for path in files:
            for message in read_log_messages(path):
                if not message.topic.startswith(DATAGRAM_PREFIX):
                    continue
                doc = message.data
                # The logged time is the reception time exactly: the log time in ns is
                # only its rounding.
                yield (
                    doc["input"],
                    Datagram(
                        bytes.fromhex(doc["payload"]),
                        number,
                        float(doc["time"]),
                        _endpoint(doc["src"]),
                        _endpoint(doc["dst"]),
                    ),
                )
                number += 1

    return Replay(config, datagrams(), "service log")


def _endpoint(text: str | None) -> tuple[str, int] | None:
    if text is None:
        return None
    host, _, port = text.rpartition(":")
    return host, int(port)


def _simulation(path: Path, config: ServiceConfig | None) -> Replay:
    recording = read_recording(path)
    config = config or config_from_recording(recording.metadata)
    replay = Replay(config, iter(()), "simulation")
    start = recording.metadata.get("start_posix")
    duration = recording.metadata.get("duration_s")
    if isinstance(start, int | float) and isinstance(duration, int | float):
        replay.span = (float(start), float(start) + float(duration))

    def datagrams() -> Iterator[tuple[str, Datagram]]:
        filters: dict[str, DuplicateFilter] = {}
        for number, recorded in enumerate(recording.datagrams()):
            name = input_name(recorded.source)
            if _duplicate(replay, filters, name, recorded.payload, recorded.time):
                continue
            yield (
                name,
                Datagram(recorded.payload, number, recorded.time, recorded.src, recorded.dst),
            )

    replay.datagrams = datagrams()
    return replay


def _duplicate(
    replay: Replay,
    filters: dict[str, DuplicateFilter],
    name: str,
    payload: bytes,
    time: float,
) -> bool:
    """The input stage of the daemon: counts, and drops the redundant LAN's copies."""
    counters = replay.counters.setdefault(name, InputCounters())
    counters.received += 1
    counters.bytes += len(payload)
    counters.last_reception = time
    if filters.setdefault(name, DuplicateFilter()).is_duplicate(payload, time):
        counters.duplicates += 1
        return True
    counters.delivered += 1
    return False


def first_source(payload: bytes) -> str | None:
    """SAC/SIC of the datagram's first record: I010 leads the UAP of CAT021, 034 and 048."""
    pos = 3
    if len(payload) <= pos:
        return None
    first = payload[pos]
    while pos < len(payload) and payload[pos] & 1:
        pos += 1
    pos += 1
    if not first & 0x80 or pos + 2 > len(payload):
        return None
    return f"{payload[pos]}/{payload[pos + 1]}"


def _own_time_of_day(payload: bytes) -> float | None:
    """The latest time of day the datagram itself carries: its plots' I140, or the I030
    of its CAT034 or CAT002 messages (CAT001's I141 is only the time modulo 512 s)."""
    found = extract_plots(payload).plots["time_of_day"]
    found = found[np.isfinite(found)]
    if len(found):
        return float(found.max())
    for category in SERVICE_CATEGORIES:
        for block in blocks_of(payload, category):
            for event in decode_blocks(block):
                if isinstance(event, Block):
                    times = [r["030"] for r in event.records if "030" in r]
                    if times:
                        return float(max(times))
    return None


_PEEK_UNITS = 10_000
"""Units of a capture read ahead for a reception time that says whether its times are
POSIX or times of day; a capture with none in that many has none (raw, hex)."""


def _capture(path: Path, config: ServiceConfig, day_posix: float | None) -> Replay:
    # Streamed: only the units before the first one with a time are held, at most
    # _PEEK_UNITS of them.
    units = read_file(path)
    head: list[Datagram | ContainerError] = []
    first_time: float | None = None
    for unit in units:
        head.append(unit)
        if isinstance(unit, Datagram) and unit.time is not None:
            first_time = unit.time
            break
        if len(head) >= _PEEK_UNITS:
            break
    items = itertools.chain(head, units)
    replay = Replay(config, iter(()), "capture")
    posix = first_time is not None and first_time > DAY_S
    if not posix and day_posix is None:
        raise ValueError(
            f"{path}: its times are times of day (or it has none); give the day with "
            "--date YYYY-MM-DD"
        )

    def datagrams() -> Iterator[tuple[str, Datagram]]:
        filters: dict[str, DuplicateFilter] = {}
        day = day_posix or 0.0
        previous: float | None = None
        for item in items:
            if isinstance(item, ContainerError):
                print(f"{path}: offset {item.offset}: {item.reason}", file=sys.stderr)
                continue
            name = input_name(first_source(item.payload) or "0/0")
            t = item.time
            if t is None:
                t = _own_time_of_day(item.payload)
                if t is None:
                    t = previous
            if t is None:
                continue
            if not posix:
                # Times of day: one that goes back by more than half a day is the next day.
                if previous is not None and t < previous - DAY_S / 2:
                    day += DAY_S
                previous = t
                t += day
            else:
                previous = t
            if _duplicate(replay, filters, name, item.payload, t):
                continue
            yield name, Datagram(item.payload, item.offset, t, item.source, item.destination)

    replay.datagrams = datagrams()
    return replay


class Progress:
    """A one-line progress bar on a terminal (nothing otherwise)."""

    WIDTH = 30

    def __init__(self, span: tuple[float, float] | None, out: TextIO = sys.stderr) -> None:
        self.span = span
        self.out = out
        self.enabled = out.isatty()
        self._last_draw = 0.0

    def update(self, now: float, datagrams: int, tracks: int | None, force: bool = False) -> None:
        """``tracks`` None: unknown here (the outputs run in a process of their own)."""
        if not self.enabled:
            return
        wall = time.monotonic()
        if not force and wall - self._last_draw < 0.2:
            return
        self._last_draw = wall
        stamp = dt.datetime.fromtimestamp(now, dt.UTC).strftime("%H:%M:%S")
        bar = ""
        if self.span is not None and self.span[1] > self.span[0]:
            done = min(max((now - self.span[0]) / (self.span[1] - self.span[0]), 0.0), 1.0)
            filled = round(done * self.WIDTH)
            bar = f"[{'#' * filled}{'.' * (self.WIDTH - filled)}] {done:4.0%} "
        live = "" if tracks is None else f", {tracks} live tracks"
        self.out.write(f"\r{bar}{stamp} {datagrams} datagrams{live} ")
        self.out.flush()

    def finish(self) -> None:
        if self.enabled:
            self.out.write("\n")
            self.out.flush()
