"""``tracker-service subscribe``: the system tracks on a terminal, as JSON lines or a table.

It asks the service's queryable for the current picture first, then follows the updates.
Samples arrive on Zenoh's threads; they go through a queue to the main thread, which
alone prints, so lines never interleave.
"""

from __future__ import annotations

import argparse
import json
import queue
import signal
import sys
import threading
import time
from types import FrameType
from typing import Any, TextIO

import zenoh

from tracker_service.outputs.zenoh_out import DEFAULT_PREFIX
from tracker_service.outputs.zenoh_session import (
    PlaintextEndpointError,
    ZenohConfigError,
    zenoh_config,
    zenoh_error,
)

__all__ = ["add_arguments", "run", "subscribe"]

_REFRESH_S = 1.0
_QUERY_TIMEOUT_S = 3.0
_KT_PER_MPS = 3600 / 1852

# The message model's field names, with the spellings a column accepts.
_COLUMNS: tuple[tuple[str, int, tuple[str, ...]], ...] = (
    ("number", 6, ("number", "track_number")),
    ("callsign", 8, ("callsign",)),
    ("address", 7, ("address", "mode_s_address")),
    ("3/A", 4, ("mode3a", "mode_3a")),
    ("lat", 9, ("lat", "latitude")),
    ("lon", 10, ("lon", "longitude")),
    ("FL", 6, ("flight_level", "fl")),
    ("kt", 5, ("ground_speed_mps", "speed_mps")),
    ("status", 9, ("status",)),
    ("age", 5, ("time",)),
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--connect",
        action="append",
        default=[],
        metavar="ENDPOINT",
        help="Zenoh endpoint of the service, e.g. tls/127.0.0.1:7447 (repeatable); added "
        "to --zenoh-config's",
    )
    parser.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="Zenoh JSON5 configuration, e.g. the subscriber's certificate for mTLS "
        "(config/zenoh/subscriber.json5, docs/security.md)",
    )
    parser.add_argument(
        "--scouting",
        action="store_true",
        help="find the service by multicast and gossip scouting (off by default)",
    )
    parser.add_argument(
        "--allow-plaintext",
        action="store_true",
        help="allow a plaintext --connect beside a --zenoh-config that configures TLS",
    )
    parser.add_argument("--prefix", default=DEFAULT_PREFIX, help="the service's key prefix")
    parser.add_argument(
        "--key", help="key expression to follow (default: <prefix>/system_tracks/**)"
    )
    parser.add_argument("--json", action="store_true", help="one JSON line per message")


def _field(doc: dict[str, Any], names: tuple[str, ...]) -> Any:
    return next((doc[name] for name in names if doc.get(name) is not None), None)


def _cell(column: str, value: Any, now: float) -> str:
    if value is None:
        return "-"
    if column in ("lat", "lon"):
        return f"{value:.5f}"
    if column == "FL":
        return f"{value:.0f}"
    if column == "kt":
        return f"{value * _KT_PER_MPS:.0f}"
    if column == "age":
        return f"{now - value:.1f}"
    return str(value)


def _connected(session: zenoh.Session) -> bool:
    """Whether the session has a link to a peer or a router (the service, or a router
    on its way)."""
    info = session.info
    return any(True for _ in info.peers_zid()) or any(True for _ in info.routers_zid())


def _table(tracks: dict[str, dict[str, Any]], now: float) -> str:
    header = " ".join(f"{name:>{width}}" for name, width, _ in _COLUMNS)
    rows = [
        " ".join(
            f"{_cell(name, _field(doc, names), now):>{width}}" for name, width, names in _COLUMNS
        )
        for _, doc in sorted(tracks.items(), key=lambda item: _sort_key(item[0]))
    ]
    return "\n".join([header, *rows, f"{len(tracks)} tracks"])


def _sort_key(key: str) -> tuple[int, int, str]:
    # By track number; keys of another shape (a --key of the user's) after them.
    last = key.rsplit("/", 1)[-1]
    return (0, int(last), key) if last.isdigit() else (1, 0, key)


def subscribe(
    config: zenoh.Config,
    key: str,
    as_json: bool,
    out: TextIO = sys.stdout,
    where: str = "the service",
) -> int:
    """Follows ``key`` on a session of ``config`` until SIGINT or SIGTERM; returns the
    exit status."""
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    for signum in (signal.SIGINT, signal.SIGTERM):
        signal.signal(signum, on_signal)
    samples: queue.Queue[tuple[str, bytes | None]] = queue.Queue()

    def on_sample(sample: zenoh.Sample) -> None:
        deleted = sample.kind == zenoh.SampleKind.DELETE
        samples.put((str(sample.key_expr), None if deleted else sample.payload.to_bytes()))

    session = zenoh.open(config)
    try:
        # Subscribed before asking, so that nothing falls between the picture and updates.
        subscriber = session.declare_subscriber(key, on_sample)
        for reply in session.get(key, timeout=_QUERY_TIMEOUT_S):
            if reply.ok is not None:
                on_sample(reply.ok)
        tracks: dict[str, dict[str, Any]] = {}
        next_draw = 0.0
        connected: bool | None = None
        not_connected = f"not connected to {where}: retrying (is the service running?)"
        while not stop.is_set():
            if as_json and time.monotonic() >= next_draw:
                # JSON lines stay JSON: the link's state goes to stderr when it changes.
                now_connected = _connected(session)
                if now_connected != connected:
                    print(
                        f"connected to {where}" if now_connected else not_connected,
                        file=sys.stderr,
                        flush=True,
                    )
                    connected = now_connected
                next_draw = time.monotonic() + _REFRESH_S
            try:
                sample_key, payload = samples.get(timeout=0.1)
            except queue.Empty:
                sample_key, payload = "", None
            if sample_key and payload is None:
                tracks.pop(sample_key, None)
            elif payload is not None:
                if as_json:
                    out.write(payload.decode(errors="replace").strip() + "\n")
                    out.flush()
                else:
                    try:
                        tracks[sample_key] = json.loads(payload)
                    except ValueError:
                        print(f"{sample_key}: not JSON", file=sys.stderr)
            if not as_json and time.monotonic() >= next_draw:
                # Ages in data time, from the newest track: a replay of an old recording
                # is not months old.
                now = max((float(doc.get("time", 0.0)) for doc in tracks.values()), default=0.0)
                # Clear the screen and home the cursor, then draw.
                table = _table(tracks, now)
                if not _connected(session):
                    table += f"\n{not_connected}"
                out.write("\x1b[2J\x1b[H" + table + "\n")
                out.flush()
                next_draw = time.monotonic() + _REFRESH_S
        subscriber.undeclare()  # type: ignore[no-untyped-call]
    finally:
        session.close()  # type: ignore[no-untyped-call]
    return 0


def run(args: argparse.Namespace) -> int:
    key = args.key or f"{args.prefix}/system_tracks/**"
    try:
        config = zenoh_config(
            connect=args.connect,
            config_file=args.zenoh_config,
            scouting=args.scouting,
            allow_plaintext=args.allow_plaintext,
        )
    except PlaintextEndpointError as exc:
        print(
            f"tracker-service subscribe: {exc.describe('--connect', 'give --allow-plaintext')}",
            file=sys.stderr,
        )
        return 2
    except ZenohConfigError as exc:
        print(f"tracker-service subscribe: {exc}", file=sys.stderr)
        return 2
    if config.get_json("connect/endpoints") == "[]" and not args.scouting:
        print(
            "tracker-service subscribe: nowhere to find the service: give --connect ENDPOINT "
            "(or a --zenoh-config with connect endpoints, or --scouting)",
            file=sys.stderr,
        )
        return 2
    try:
        where = ", ".join(args.connect) or "the service"
        return subscribe(config, key, args.json, where=where)
    except zenoh.ZError as exc:
        # Typically no link: the service is down, or refused this subscriber's TLS.
        print(f"tracker-service subscribe: {zenoh_error(exc)}", file=sys.stderr)
        return 1
    except BrokenPipeError:
        # `subscribe --json | head` closes the pipe early; that is not an error.
        sys.stderr.close()
        return 0
