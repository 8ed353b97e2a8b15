"""Issue 11 findings 8 and 9: repeated datagrams detected, and counters that miss nothing.

Real sockets on 127.0.0.1; a real daemon frozen with SIGSTOP while its port is flooded
(the kernel drops, SO_RXQ_OVFL counts), fed a burst larger than its holding window, and
a flood of malformed datagrams (its log rate-limited)."""

from __future__ import annotations

import signal
import socket
import time
from pathlib import Path
from typing import Any

import numpy as np

from asterix.containers import Datagram
from tests.fault_tools import (
    DaemonProcess,
    hostile_datagrams,
    plot_block,
    send,
    stop_process,
    write_config,
)
from tracker_service.ingest import _MAX_REMEMBERED, DuplicateFilter, DuplicateWindow, Repetition
from tracker_service.inputs.udp import UdpEndpoint, UdpInput
from tracker_service.service.config import load_service_config
from tracker_service.service.core import TrackerService
from tracker_service.service.daemon import Merger

T0 = 1780300800.0


def wait_received(feed: UdpInput, n: int) -> None:
    deadline = time.monotonic() + 5.0
    while feed.counters.received < n:
        assert time.monotonic() < deadline, feed.counters
        time.sleep(0.01)


def test_a_datagram_repeated_on_a_single_lan_is_dropped_and_counted() -> None:
    with (
        UdpInput("r1", UdpEndpoint("127.0.0.1", 0)) as feed,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out,
    ):
        port = feed.endpoints[0][1]
        for n in range(10):
            payload = plot_block(25, 11, 100.0 + n)
            out.sendto(payload, ("127.0.0.1", port))
            out.sendto(payload, ("127.0.0.1", port))
        wait_received(feed, 20)
        counters = feed.counters
    assert (counters.delivered, counters.repeats, counters.duplicates) == (10, 10, 0)


def test_a_copy_on_the_other_lan_is_a_duplicate_a_second_one_a_repeat() -> None:
    with (
        UdpInput("r1", UdpEndpoint("127.0.0.1", 0), UdpEndpoint("127.0.0.1", 0)) as feed,
        socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as out,
    ):
        lan_a, lan_b = (("127.0.0.1", port) for _, port in feed.endpoints)
        payload = plot_block(25, 11, 100.0)
        out.sendto(payload, lan_a)
        wait_received(feed, 1)
        out.sendto(payload, lan_b)
        wait_received(feed, 2)
        out.sendto(payload, lan_a)
        wait_received(feed, 3)
        counters = feed.counters
    assert (counters.delivered, counters.duplicates, counters.repeats) == (1, 1, 1)


def test_the_duplicate_filter_has_bounded_memory() -> None:
    dedup = DuplicateFilter(DuplicateWindow(seconds=60.0))
    for n in range(100_000):  # all within the window: a flood of distinct datagrams
        assert dedup.classify(n.to_bytes(8), T0) is Repetition.NEW
    assert len(dedup._seen) <= _MAX_REMEMBERED
    assert dedup.classify((99_999).to_bytes(8), T0) is Repetition.REPEAT


def test_a_burst_beyond_the_holding_window_is_dropped_and_counted() -> None:
    merger = Merger(1.0, max_datagrams=1000, max_bytes=1024 * 1024)
    big = bytes([99, 0xEA, 0x60]) + bytes(59997)
    accepted = sum(merger.push("r1", Datagram(big, n, T0, None, None)) for n in range(100))
    assert accepted == 17  # 17 x 60 kB under 1 MiB
    assert merger.dropped["r1"] == 83
    assert merger.bytes == 17 * 60000
    assert len(merger.release(T0 + 1.0)) == 17 and merger.bytes == 0


def test_every_hostile_datagram_moves_a_counter() -> None:
    """255 of 1,276 hostile datagrams once left no trace (decode errors inside valid
    framing, unknown categories)."""
    core = TrackerService(load_service_config(Path("config/example.toml")))
    rng = np.random.default_rng(3)
    hostile = hostile_datagrams(rng, T0 % 86400)

    def counted() -> int:
        status = core.status()
        errors = sum(sum(r.errors.values()) for r in status.radars)
        return errors + sum(status.unattributed.values()) + core.counts.plots

    for k in range(300):
        kind, payload = next(hostile)
        before = counted()
        core.process("25_13", Datagram(payload, k, T0 + 0.01 * k, None, None))
        assert counted() > before, f"datagram {k} ({kind}) left no trace"


def _radar(daemon: DaemonProcess, key: str) -> dict[str, Any]:
    return next(r for r in daemon.status()["radars"] if r["radar"] == key)


def test_kernel_drops_bursts_and_floods_are_counted(tmp_path: Path) -> None:
    config, ports = write_config(
        tmp_path,
        log=False,
        holding_window_s=2.0,
        system={"holding_window_max_mb": 1.0},
    )
    daemon = DaemonProcess(config, tmp_path / "health")
    try:
        filler = bytes(30_000 - 3)
        # 1. Frozen (SIGSTOP: no thread reads its socket), its port flooded: the kernel
        # drops what the receive buffer cannot hold.
        stop_process(daemon.process.pid)
        flood = [
            bytes([99]) + (30_000).to_bytes(2) + n.to_bytes(4) + filler[4:] for n in range(300)
        ]
        send(ports["25/12"], flood)
        daemon.process.send_signal(signal.SIGCONT)
        # No datagram after the drops carries their count (SO_RXQ_OVFL): /proc/net/udp
        # has it.
        status = daemon.wait_status(lambda s: _counted(s, "25/12") >= 300, timeout=30.0)
        radar = next(r for r in status["radars"] if r["radar"] == "25/12")
        assert radar["drop_causes"].get("kernel", 0) > 0, radar
        # Nothing lost that was not counted: each datagram was an unknown category,
        # or a drop.
        assert _counted(status, "25/12") == 300, radar

        # 2. A burst of 64 kB datagrams larger than the holding window's 1 MB.
        rss = daemon.rss_mb()
        burst = [
            bytes([99]) + (65000).to_bytes(2) + n.to_bytes(4) + bytes(64993) for n in range(300)
        ]
        send(ports["25/13"], burst, pause_every=20, pause_s=0.01)
        status = daemon.wait_status(lambda s: _counted(s, "25/13") >= 300, timeout=30.0)
        radar = next(r for r in status["radars"] if r["radar"] == "25/13")
        assert radar["drop_causes"].get("holding_window", 0) > 0, radar
        assert _counted(status, "25/13") == 300, radar
        assert daemon.rss_mb() - rss < 40.0  # 300 x 65 kB held in full would be 20 MB

        # 3. 2,000 malformed datagrams: counted, and a few log lines, not 2,000.
        send(ports["25/11"], [b"\x30\x00\x02garbage"] * 2000, pause_every=100, pause_s=0.005)
        status = daemon.wait_status(lambda s: _counted(s, "25/11") >= 2000, timeout=30.0)
        assert _counted(status, "25/11") == 2000
        assert daemon.stop() == 0
        lines = [line for line in daemon.lines if "not ASTERIX" in line]
        assert 1 <= len(lines) <= 3, lines
    finally:
        daemon.close()


def _counted(status: dict[str, Any], key: str) -> int:
    """What the status accounts for of the datagrams sent to one radar's input: decode
    errors (the malformed at the input included) and drops."""
    radar = next(r for r in status["radars"] if r["radar"] == key)
    return int(radar["decode_errors"]) + int(radar["drops"])
