"""``tracker-service play``: a capture's datagrams sent to the configured radar inputs, as
the radars send them.

Any recording the replay reads (a simulator recording, the service's own log, pcap,
pcapng, GPS, final format, raw, hex: ``service.replay.open_replay``), its second-LAN
copies dropped by content, each datagram sent to the UDP input of the feed its first
record names (I010), on every LAN the configuration gives that feed (multicast or
unicast), paced by its reception times divided by ``speed``. A datagram of a feed the
configuration has no input for is not sent, and counted.

With ``now``, times are re-based on the present: the pacing starts now, and the times
inside the datagrams move by the same whole number of seconds (CAT048 I140, CAT034 and
CAT002 I030, CAT001's truncated I141, CAT021's times of applicability, reception and
transmission), so that the daemon sees a feed of today, as ``simulate --start now``
makes one. The blocks are re-encoded by the codec (which re-encodes every block it
decodes to its bytes); a datagram it cannot decode is sent as it is.
"""

from __future__ import annotations

import argparse
import math
import socket
import sys
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from asterix.codec import Block, decode_blocks, encode_block
from tracker_service.ingest import DAY_S
from tracker_service.service.config import (
    AdsbFeed,
    ConfigError,
    Lan,
    Radar,
    ServiceConfig,
    load_service_config,
)
from tracker_service.service.core import radar_key
from tracker_service.service.replay import open_replay, parse_date, parse_speed
from tracker_service.service.signals import stop_on_signals

__all__ = ["PlaySummary", "add_arguments", "play", "run", "shift_times"]

TRUNCATED_DAY_S = 512.0
"""CAT001 I141: the time of day modulo 512 s."""
_TIME_ITEMS: dict[int, tuple[tuple[str, float], ...]] = {
    48: (("140", DAY_S),),
    34: (("030", DAY_S),),
    2: (("030", DAY_S),),
    1: (("141", TRUNCATED_DAY_S),),
    21: tuple((item, DAY_S) for item in ("071", "072", "073", "075", "077")),
}
"""Per category, its time-of-day items and their modulus. CAT021's high-precision items
(074, 076) are fractions of the second: a shift by whole seconds leaves them right."""


def shift_times(payload: bytes, seconds: int) -> bytes:
    """``payload`` with every time of day of its records moved by ``seconds`` (whole
    seconds, so that every LSB and fraction stays exact); blocks of other categories, and
    a datagram that does not decode, are left as they are."""
    if seconds == 0:
        return payload
    out = []
    pos = 0
    for event in decode_blocks(payload):
        if not isinstance(event, Block):
            return payload
        size = int.from_bytes(payload[pos + 1 : pos + 3])
        original = payload[pos : pos + size]
        pos += size
        items = _TIME_ITEMS.get(event.cat)
        if items is None or not event.supported:
            out.append(original)
            continue
        records: list[dict[str, Any]] = []
        for record in event.records:
            moved = dict(record)
            for item, modulus in items:
                if item in moved:
                    moved[item] = (moved[item] + seconds) % modulus
            records.append(moved)
        out.append(encode_block(event.cat, records))
    if pos != len(payload):
        return payload
    return b"".join(out)


@dataclass
class PlaySummary:
    sent: int = 0
    """Datagrams sent (a datagram sent on two LANs counts once)."""
    skipped: Counter[str] = field(default_factory=Counter)
    """Per SAC/SIC, datagrams of a feed with no configured input, not sent."""
    shift_s: int = 0
    """How far the times were moved (``now``)."""
    seconds: float = 0.0
    """Wall-clock time the play took."""


class _Sender:
    """One socket sending to the configured LANs of every feed."""

    def __init__(self, config: ServiceConfig, interface: str | None, ttl: int) -> None:
        feeds: list[Radar | AdsbFeed] = [*config.radars, *config.adsb]
        self.lans: dict[str, list[Lan]] = {
            feed.key: feed.input.endpoints() for feed in feeds if feed.input is not None
        }
        self.socket = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.socket.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_TTL, ttl)
        self.socket.setsockopt(socket.IPPROTO_IP, socket.IP_MULTICAST_LOOP, 1)
        self._interface = interface

    def send(self, key: str, payload: bytes) -> bool:
        lans = self.lans.get(key)
        if not lans:
            return False
        for lan in lans:
            address = str(lan.address)
            if lan.address.is_multicast:
                # The configured interface of the input is where the daemon listens.
                interface = self._interface or (
                    None if lan.interface is None else str(lan.interface)
                )
                if interface is not None:
                    self.socket.setsockopt(
                        socket.IPPROTO_IP, socket.IP_MULTICAST_IF, socket.inet_aton(interface)
                    )
            elif address == "0.0.0.0":
                address = "127.0.0.1"
            self.socket.sendto(payload, (address, lan.port))
        return True

    def close(self) -> None:
        self.socket.close()


def _sleep(delay: float) -> bool:
    time.sleep(delay)
    return False


def play(
    path: str | Path,
    config: ServiceConfig,
    *,
    speed: float = 1.0,
    now: bool = False,
    day_posix: float | None = None,
    interface: str | None = None,
    ttl: int = 1,
    stop: Callable[[float], bool] | None = None,
    clock: Callable[[], float] = time.time,
) -> PlaySummary:
    """Sends ``path`` to the inputs of ``config``; see the module docstring. ``stop(delay)``
    waits up to ``delay`` s and says whether to stop (a signal), else ``time.sleep``."""
    source = open_replay(path, config, day_posix)
    wait = stop or _sleep
    summary = PlaySummary()
    sender = _Sender(config, interface, ttl)
    wall0 = time.monotonic()
    first: float | None = None
    try:
        for name, datagram in source.datagrams:
            assert datagram.time is not None
            if first is None:
                first = datagram.time
                if now:
                    summary.shift_s = round(clock() - first)
            if math.isfinite(speed):
                delay = wall0 + (datagram.time - first) / speed - time.monotonic()
                if delay > 0 and wait(delay):
                    break
            # The feed the replay reader names by its first record's I010.
            key = radar_key(name)
            if sender.send(key, shift_times(datagram.payload, summary.shift_s)):
                summary.sent += 1
            else:
                summary.skipped[key] += 1
    finally:
        sender.close()
        summary.seconds = time.monotonic() - wall0
    return summary


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "capture",
        help="a simulator recording, a log of the service, or a pcap/pcapng/GPS/final/raw/hex "
        "capture",
    )
    parser.add_argument(
        "--config", required=True, help="service configuration whose radar inputs receive it"
    )
    parser.add_argument(
        "--speed",
        type=parse_speed,
        default=1.0,
        metavar="1|N|max",
        help="pace: reception times divided by N, or 'max' (default 1, real time)",
    )
    parser.add_argument(
        "--now",
        action="store_true",
        help="re-base the times on the present: the datagrams' own times (I140, I030, ...) "
        "move by as many whole seconds as the capture's start is from now",
    )
    parser.add_argument(
        "--date",
        type=parse_date,
        metavar="YYYY-MM-DD",
        help="the UTC day of a capture that holds times of day only (GPS, final, raw, hex)",
    )
    parser.add_argument(
        "--interface",
        metavar="ADDRESS",
        help="local address whose interface sends to multicast groups (e.g. 127.0.0.1); "
        "default: each input's configured interface, else the default route's",
    )
    parser.add_argument(
        "--ttl", type=int, default=1, help="multicast TTL (default 1: this LAN only)"
    )


def run(args: argparse.Namespace) -> int:
    try:
        config = load_service_config(args.config)
    except ConfigError as exc:
        print(f"tracker-service play: {exc}", file=sys.stderr)
        return 2
    with stop_on_signals() as stop:
        try:
            summary = play(
                args.capture,
                config,
                speed=args.speed,
                now=args.now,
                day_posix=args.date,
                interface=args.interface,
                ttl=args.ttl,
                stop=stop.wait,
            )
        except (ConfigError, ValueError, OSError) as exc:
            print(f"tracker-service play: {exc}", file=sys.stderr)
            return 2
    skipped = ", ".join(f"{key}: {n}" for key, n in sorted(summary.skipped.items()))
    shift = f", times moved by {summary.shift_s:+d} s" if args.now else ""
    print(
        f"sent {summary.sent} datagrams in {summary.seconds:.1f} s{shift}"
        + (f"; not sent (no input configured): {{{skipped}}}" if skipped else ""),
        file=sys.stderr,
    )
    return 0
