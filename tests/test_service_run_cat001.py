"""``tracker-service run`` fed a CAT001/CAT002 radar over UDP on 127.0.0.1: the daemon in
another process, stopped with SIGTERM, its MCAP log read back."""

from __future__ import annotations

import datetime as dt
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

from tests.test_service_replay import endpoint, free_port, logged
from tracker_service.simulator.recording import read_recording
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario

SPEED = 6.0
STARTUP_S = 30.0


def _scenario(start: str) -> Scenario:
    return Scenario.model_validate(
        {
            "name": "old radar live",
            "seed": 5,
            "start": start,
            "duration_s": 48.0,
            "system_centre": {"lat": 48.0, "lon": 17.0},
            "radars": [
                {
                    "name": "old",
                    "sac": 7,
                    "sic": 9,
                    "lat": 48.0,
                    "lon": 17.0,
                    "alt_m": 300.0,
                    "antenna_period_s": 4.0,
                    "asterix": "cat001",
                }
            ],
            "traffic": {
                "count": 12,
                "area": {"lat_min": 47.5, "lat_max": 48.5, "lon_min": 16.3, "lon_max": 17.7},
            },
        }
    )


CONFIG = """
[system]
centre_lat = 48.0
centre_lon = 17.0
sac = 7
sic = 100
holding_window_s = 0.2

[[radars]]
name = "old"
sac = 7
sic = 9
lat = 48.0
lon = 17.0
alt_m = 300.0
antenna_period_s = 4.0
sigma_range_m = 50.0
sigma_azimuth_deg = 0.06
input = {{ address = "127.0.0.1", port = {port} }}

[mcap]
directory = "{logs}"
"""


def test_run_reads_a_cat001_radar(tmp_path: Path) -> None:
    # Starting now: the daemon stamps reception times with the wall clock.
    start = dt.datetime.now(dt.UTC).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    recording = tmp_path / "old.mcap"
    simulate(_scenario(start), recording, no_bias=True)
    port, logs = free_port(socket.SOCK_DGRAM), tmp_path / "logs"
    config = tmp_path / "tracker.toml"
    config.write_text(CONFIG.format(port=port, logs=logs), encoding="utf-8")
    command = ["run", "--config", str(config), "--zenoh-listen", endpoint()]
    process = subprocess.Popen(
        [sys.executable, "-m", "tracker_service.cli", *command],
        stderr=subprocess.PIPE,
        text=True,
    )
    lines: list[str] = []
    ready = threading.Event()

    def drain() -> None:
        assert process.stderr is not None
        for line in process.stderr:
            lines.append(line.rstrip())
            if "running: publishing" in line:
                ready.set()

    threading.Thread(target=drain, daemon=True).start()
    try:
        assert ready.wait(STARTUP_S), "\n".join(lines)
        sent = categories = 0
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
            wall0, first = time.monotonic(), None
            for datagram in read_recording(recording).datagrams():
                first = datagram.time if first is None else first
                time.sleep(max(wall0 + (datagram.time - first) / SPEED - time.monotonic(), 0))
                sock.sendto(datagram.payload, ("127.0.0.1", port))
                sent += 1
                categories |= 1 << datagram.payload[0]
        assert categories == (1 << 1) | (1 << 2)  # CAT001 plots, CAT002 service messages
        time.sleep(0.5)
        process.send_signal(signal.SIGTERM)
        assert process.wait(timeout=30) == 0, "\n".join(lines)
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    messages = logged(logs)
    assert len([m for m in messages if m.topic == "/datagrams/7_9"]) == sent
    local = [m.data for m in messages if m.topic == "/local_tracks/7_9"]
    assert len({m["number"] for m in local}) >= 8
    system = [m.data for m in messages if m.topic == "/system_tracks"]
    assert len({m["number"] for m in system}) >= 8
    status = [m.data for m in messages if m.topic == "/status"][-1]
    (radar,) = status["radars"]
    assert radar["radar"] == "7/9" and radar["decode_errors"] == 0
