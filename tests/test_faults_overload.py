"""An overloaded chain sheds what comes too late, says so, and keeps its memory bounded.

Real processes and sockets on 127.0.0.1. The chain is made to fall behind by freezing
its output process (SIGSTOP): the chain's calls to it block once their pipe is full,
while its input threads go on reading and dating datagrams. When the output process
runs again (SIGCONT), what waited more than ``[system] max_behind_s`` is dropped
unprocessed and counted (``drop_causes.behind``), the status says the chain is
overloaded, and the chain is current again at once. Before, the daemon worked through
its whole backlog, and the fusion process of ``run --role fusion`` held an unbounded
queue of radar batches while its status said ``lag 0`` and ``health ok``.
"""

from __future__ import annotations

import os
import signal
import socket
import time
from pathlib import Path
from typing import Any

from tests.fault_tools import (
    DaemonProcess,
    free_port,
    plot_block,
    send,
    stop_process,
    write_config,
)

MAX_BEHIND_S = 1.0
FROZEN_S = 6.0
"""Long enough for the plots sent to fill the 1 MB pipe to the output process well before
the thaw, so that what waits behind it is more than ``MAX_BEHIND_S`` late: about 1 kB a
one-plot datagram's calls since the dtypes cross once (session 14; 3 kB before, when
3 s sufficed)."""


def _radar(status: dict[str, Any], key: str) -> dict[str, Any]:
    return next(r for r in status["radars"] if r["radar"] == key)


def _behind(status: dict[str, Any], key: str) -> int:
    return int(_radar(status, key)["drop_causes"].get("behind", 0))


def _plots(n: int, start: int = 0) -> list[bytes]:
    """``n`` distinct plots of 25/11, dated now (a sane clock)."""
    now = time.time() % 86400.0
    return [plot_block(25, 11, now, rho_nm=20.0 + 0.01 * (start + k)) for k in range(n)]


def _freeze_outputs_and_feed(chain: DaemonProcess, port: int) -> int:
    """The chain's output process frozen while ``FROZEN_S`` of plots reach ``port``;
    then thawed. How many were sent."""
    output = chain.output_process()
    stop_process(output)
    try:
        sent = 0
        deadline = time.monotonic() + FROZEN_S
        while time.monotonic() < deadline:
            send(port, _plots(10, sent))
            sent += 10
            time.sleep(0.02)
    finally:
        os.kill(output, signal.SIGCONT)
    return sent


def _settled_behind(chain: DaemonProcess, key: str, quiet_s: float = 2.0) -> int:
    """``key``'s shed count once the chain is current and the count has held still for
    ``quiet_s``: the thawed output process still works through the calls that filled its
    pipe, and on a loaded host the chain can block on it again and shed a last late batch
    after its first status with a small lag."""
    deadline = time.monotonic() + 30.0
    shed = _behind(chain.wait_status(lambda s: (s["lag_s"] or 0.0) < MAX_BEHIND_S), key)
    while time.monotonic() < deadline:
        time.sleep(quiet_s)
        now = _behind(chain.wait_status(lambda s: (s["lag_s"] or 0.0) < MAX_BEHIND_S), key)
        if now == shed:
            return shed
        shed = now
    raise AssertionError(f"{key}'s shed count still moving after 30 s: {shed}")


def _check_shed_and_current(chain: DaemonProcess, port: int, sent: int) -> dict[str, Any]:
    overloaded = chain.wait_status(
        lambda s: any("overloaded" in line for line in s["reasons"]), timeout=30.0
    )
    assert _behind(overloaded, "25/11") > 0, _radar(overloaded, "25/11")
    assert _behind(overloaded, "25/11") <= sent
    # Current again: what comes now is processed, not shed, and the lag is small.
    shed = _settled_behind(chain, "25/11")
    send(port, _plots(20, sent), pause_every=1, pause_s=0.05)
    time.sleep(2.0)
    status = chain.status()
    assert _behind(status, "25/11") == shed, _radar(status, "25/11")
    assert (status["lag_s"] or 0.0) < MAX_BEHIND_S, status["lag_s"]
    return overloaded


def test_an_overloaded_daemon_sheds_what_is_too_late_and_says_so(tmp_path: Path) -> None:
    config, ports = write_config(tmp_path, log=False, system={"max_behind_s": MAX_BEHIND_S})
    daemon = DaemonProcess(config, tmp_path / "health")
    try:
        sent = _freeze_outputs_and_feed(daemon, ports["25/11"])
        _check_shed_and_current(daemon, ports["25/11"], sent)
        assert daemon.stop() == 0
    finally:
        daemon.close()


def test_the_fusion_process_sheds_too_and_shows_the_radar_processes_counters(
    tmp_path: Path,
) -> None:
    config, ports = write_config(
        tmp_path, log=False, second_lan=True, system={"max_behind_s": MAX_BEHIND_S}
    )
    stage = f"tcp/127.0.0.1:{free_port(socket.SOCK_STREAM)}"
    fusion = DaemonProcess(
        config,
        tmp_path / "health",
        wait="fusion: taking",
        role=("--role", "fusion", "--stage-listen", stage),
    )
    radar = None
    try:
        radar = DaemonProcess(
            config,
            tmp_path / "none",
            wait="publishing",
            role=("--role", "radar", "--radars", "25/11,25/12", "--stage-connect", stage),
        )
        # A copy on LAN B: a duplicate, counted by the radar process, shown by fusion.
        copies = _plots(5, 10_000)
        send(ports["25/11"], copies)
        send(ports["25/11 B"], copies)
        fusion.wait_status(lambda s: _radar(s, "25/11")["duplicates"] == 5, timeout=30.0)
        sent = _freeze_outputs_and_feed(fusion, ports["25/11"])
        status = _check_shed_and_current(fusion, ports["25/11"], sent)
        assert _radar(status, "25/11")["duplicates"] == 5
        assert fusion.stop() == 0, fusion.log()
        assert radar.stop() == 0, radar.log()
    finally:
        fusion.close()
        if radar is not None:
            radar.close()
