"""The service's commands: ``replay``, ``run`` and ``health``; what they share."""

from __future__ import annotations

import argparse
import logging
import math
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType

from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.service.config import ConfigError, ServiceConfig, load_service_config
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import (
    CONFIG_METADATA,
    Progress,
    open_replay,
    parse_date,
    parse_speed,
)

__all__ = [
    "add_health_arguments",
    "add_replay_arguments",
    "add_run_arguments",
    "health",
    "open_service",
    "replay",
    "stop_on_signals",
]

log = logging.getLogger(__name__)


def _add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--zenoh-listen",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint to listen on, e.g. tcp/127.0.0.1:7447 (repeatable)",
    )
    parser.add_argument(
        "--zenoh-connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint (router or peer) to connect to (repeatable)",
    )
    parser.add_argument(
        "--zenoh-config", metavar="FILE", help="Zenoh JSON5 configuration (routers, TLS, ACL)"
    )


def add_replay_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        help="a simulator recording or a log of the service (.mcap, or a directory of "
        "logs), or a pcap/pcapng/GPS/final/raw/hex capture",
    )
    parser.add_argument(
        "--speed",
        type=parse_speed,
        default=1.0,
        metavar="1|N|max",
        help="pace: reception times divided by N, or 'max' for as fast as possible "
        "(default 1, real time)",
    )
    parser.add_argument(
        "--config",
        help="service configuration (radars, system plane, settings); "
        "default: the recording's metadata",
    )
    parser.add_argument(
        "--date",
        type=parse_date,
        metavar="YYYY-MM-DD",
        help="the UTC day of a capture that holds times of day only (GPS, final, raw, hex)",
    )
    parser.add_argument("--mcap-dir", help="write the service's MCAP log into this directory")
    _add_zenoh_arguments(parser)


def add_run_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, help="service configuration (TOML)")
    parser.add_argument(
        "--health-file",
        help="a file the daemon touches at each status message (for a container's "
        "health check: `tracker-service health --file FILE`)",
    )
    _add_zenoh_arguments(parser)


def add_health_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--file", required=True, help="the daemon's --health-file")
    parser.add_argument(
        "--max-age",
        type=float,
        default=30.0,
        help="seconds since the last status beyond which the daemon is unhealthy",
    )


def _with_cli(config: ServiceConfig, args: argparse.Namespace) -> ServiceConfig:
    """The configuration with the command line's Zenoh settings on top."""
    zenoh = config.zenoh
    updates: dict[str, object] = {}
    if args.zenoh_listen:
        updates["listen"] = list(args.zenoh_listen)
    if args.zenoh_connect:
        updates["connect"] = list(args.zenoh_connect)
    if args.zenoh_config:
        updates["config_file"] = Path(args.zenoh_config)
    return config.model_copy(update={"zenoh": zenoh.model_copy(update=updates)})


@contextmanager
def open_service(
    config: ServiceConfig, mcap_dir: Path | None, *, zenoh: bool = True
) -> Iterator[TrackerService]:
    """The core with its Zenoh session and MCAP log; on the way out every live track is
    ended, then the session and the log are closed, whatever happened."""
    publisher = None
    mcap = None
    try:
        if zenoh:
            z = config.zenoh
            publisher = ZenohPublisher(
                z.prefix,
                mode=z.mode,
                listen=z.listen,
                connect=z.connect,
                config_file=z.config_file,
                # Explicit endpoints: no scouting for strangers on the LAN.
                multicast_scouting=False if (z.listen or z.connect) else None,
            )
        if mcap_dir is not None:
            m = config.mcap
            mcap = McapLog(
                mcap_dir,
                m.rotate_size_mb,
                m.rotate_duration_s,
                m.chunk_size,
                metadata={CONFIG_METADATA: {"config": config.model_dump_json()}},
            )
        service = TrackerService(config, publisher, mcap)
        try:
            yield service
        finally:
            service.close()
    finally:
        if publisher is not None:
            publisher.close()
        if mcap is not None:
            mcap.close()


@contextmanager
def stop_on_signals() -> Iterator[threading.Event]:
    """An event set by SIGTERM or SIGINT (the previous handlers come back afterwards)."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGTERM, signal.SIGINT)}
    try:
        yield stop
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _watch_hint(config: ServiceConfig) -> str:
    z = config.zenoh
    endpoints = [e.replace("0.0.0.0", "127.0.0.1") for e in z.listen]
    connect = " ".join(f"--connect {e}" for e in endpoints[:1])
    prefix = "" if z.prefix == "tracker" else f" --prefix {z.prefix}"
    return f"tracker-service subscribe {connect}{prefix}".replace("  ", " ").strip()


def replay(args: argparse.Namespace) -> int:
    try:
        config = None if args.config is None else load_service_config(args.config)
        source = open_replay(args.recording, config, args.date)
        config = _with_cli(source.config, args)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"tracker-service replay: {exc}", file=sys.stderr)
        return 2
    mcap_dir = None if args.mcap_dir is None else Path(args.mcap_dir)
    speed: float = args.speed
    print(f"{args.recording}: {source.kind}; watch with: {_watch_hint(config)}", file=sys.stderr)
    progress = Progress(source.span)
    with stop_on_signals() as stop, open_service(config, mcap_dir) as service:
        service.input_counters = source.counters
        first: float | None = None
        wall0 = time.monotonic()
        for name, datagram in source.datagrams:
            if stop.is_set():
                break
            assert datagram.time is not None
            if first is None:
                first = datagram.time
            if math.isfinite(speed):
                delay = wall0 + (datagram.time - first) / speed - time.monotonic()
                if delay > 0 and stop.wait(delay):
                    break
            service.process(name, datagram)
            progress.update(service.now, service.counts.datagrams, len(service.live_tracks))
        progress.update(service.now, service.counts.datagrams, len(service.live_tracks), True)
        progress.finish()
        log_files = [] if service.log is None else list(service.log.files)
    counts = service.counts
    duplicates = sum(c.duplicates for c in source.counters.values())
    print(
        f"replayed {counts.datagrams} datagrams ({duplicates} duplicates dropped): "
        f"{counts.plots} plots, {len(counts.system_tracks)} system tracks "
        f"({counts.system_updates} updates), {counts.errors} errors",
        file=sys.stderr,
    )
    for path in log_files:
        print(f"log: {path}", file=sys.stderr)
    return 0


def health(args: argparse.Namespace) -> int:
    """0 when the daemon wrote a status within ``--max-age`` seconds, else 1."""
    try:
        age = time.time() - Path(args.file).stat().st_mtime
    except OSError as exc:
        print(f"unhealthy: {exc}", file=sys.stderr)
        return 1
    if age > args.max_age:
        print(f"unhealthy: last status {age:.0f} s ago", file=sys.stderr)
        return 1
    print(f"healthy: last status {age:.1f} s ago")
    return 0


def run(args: argparse.Namespace) -> int:
    from tracker_service.service.daemon import Daemon

    try:
        config = _with_cli(load_service_config(args.config), args)
    except ConfigError as exc:
        print(f"tracker-service run: {exc}", file=sys.stderr)
        return 2
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(message)s")
    health_file = None if args.health_file is None else Path(args.health_file)
    with stop_on_signals() as stop:
        return Daemon(config, health_file).run(stop)
