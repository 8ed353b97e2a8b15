"""``run --role radar`` and ``--role fusion`` as real processes with real Zenoh sessions on
127.0.0.1, fed real UDP datagrams (the simulator's recording, paced): a radar process
killed with SIGKILL stops only its radar while the others go on, and its restart resumes
it on the same system tracks; a fusion process restarted has its picture back from the
radar processes' live tracks within two antenna periods.

In three_sites every aircraft 25/13 sees at the kill is seen by another radar too, so
no system track ends here: one that only a silent radar fed ends by the fuser's silence
rule, as in one process (tests/test_service_replay.py, a radar that stops)."""

from __future__ import annotations

import datetime as dt
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
import zenoh

from tests.test_service_replay import endpoint, logged, simulate
from tests.test_service_run import SPEED, STARTUP_S, Feeds
from tracker_service.service.config import load_service_config
from tracker_service.service.roles import (
    radar_watermark,
    stage_session_config,
    watermark_period,
)
from tracker_service.simulator.recording import read_recording
from tracker_service.stage_messages import decode_message

PERIOD_S = 4.0
"""three_sites' longest antenna period (data time)."""


class Role:
    """One ``run --role`` process, its stderr collected; ready once it says so."""

    def __init__(self, feeds: Feeds, stage: str, *role: str, ready: str) -> None:
        self.lines: list[str] = []
        command = [sys.executable, "-m", "tracker_service.cli", "run", "--config"]
        command += [str(feeds.config), *role]
        if "fusion" in role:
            command += ["--stage-listen", stage, "--zenoh-listen", endpoint()]
        else:
            command += ["--stage-connect", stage]
        self.process = subprocess.Popen(command, stderr=subprocess.PIPE, text=True)
        self._ready = threading.Event()
        self._word = ready
        threading.Thread(target=self._drain, daemon=True).start()
        assert self._ready.wait(STARTUP_S), "\n".join(self.lines)

    def _drain(self) -> None:
        assert self.process.stderr is not None
        for line in self.process.stderr:
            self.lines.append(line.rstrip())
            if self._word in line:
                self._ready.set()

    def kill(self) -> None:
        self.process.send_signal(signal.SIGKILL)
        self.process.wait(timeout=10)

    def stop(self) -> int:
        self.process.send_signal(signal.SIGTERM)
        return self.process.wait(timeout=30)


@pytest.fixture
def recording(tmp_path: Path) -> Path:
    start = dt.datetime.now(dt.UTC).replace(microsecond=0).strftime("%Y-%m-%dT%H:%M:%SZ")
    return simulate(tmp_path / "live.mcap", 200.0, start=start)


@pytest.fixture
def roles(tmp_path: Path) -> Iterator[tuple[Feeds, str, list[Role]]]:
    feeds = Feeds(tmp_path)
    # Fed SPEED times faster than real time, the radars' data time runs away from
    # their reception: a radar process started late would be judged out of step with
    # the others (whose offsets are medians of a longer past) and kept out of fusion.
    text = feeds.config.read_text(encoding="utf-8")
    text = re.sub(r"(?m)^max_offset_s = .*$", "max_offset_s = 3600.0", text)
    feeds.config.write_text(text, encoding="utf-8")
    stage = endpoint()
    started: list[Role] = []
    try:
        yield feeds, stage, started
    finally:
        for role in started:
            if role.process.poll() is None:
                role.kill()


def send(feeds: Feeds, recording: Path, running: threading.Event) -> None:
    """The recording's datagrams to the feeds' ports, paced at SPEED, waiting while
    ``running`` is clear (the pause shifts the rest)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as sock:
        wall0 = time.monotonic()
        first: float | None = None
        for datagram in read_recording(recording).datagrams():
            first = datagram.time if first is None else first
            if not running.is_set():
                pause = time.monotonic()
                running.wait()
                wall0 += time.monotonic() - pause
            time.sleep(max(wall0 + (datagram.time - first) / SPEED - time.monotonic(), 0.0))
            sock.sendto(
                datagram.payload, ("127.0.0.1", feeds.ports[(datagram.source, datagram.lan)])
            )


def _tracks(messages: list[Any]) -> list[dict[str, Any]]:
    return [m.data for m in messages if m.topic == "/system_tracks"]


def test_a_radar_process_killed_and_a_fusion_process_restarted(
    roles: tuple[Feeds, str, list[Role]], recording: Path, tmp_path: Path
) -> None:
    feeds, stage, started = roles
    fusion = Role(feeds, stage, "--role", "fusion", ready="fusion: taking")
    started.append(fusion)
    west = Role(feeds, stage, "--role", "radar", "--radars", "25/11,25/12", ready="publishing")
    east = Role(feeds, stage, "--role", "radar", "--radars", "25/13", ready="publishing")
    started += [west, east]
    running = threading.Event()
    running.set()
    sender = threading.Thread(target=send, args=(feeds, recording, running), daemon=True)
    first = next(iter(read_recording(recording).datagrams())).time
    t0 = time.monotonic()
    paused = [0.0]
    sender.start()

    def at(wall_s: float) -> float:
        """Waits until ``wall_s`` into the feed; the data time of then."""
        time.sleep(max(t0 + wall_s - time.monotonic(), 0.0))
        return now()

    def now() -> float:
        return first + (time.monotonic() - t0 - paused[0]) * SPEED

    killed_at = at(8.0)  # 32 s of data: tracks confirmed on every radar
    # The status's time is reception's (the wall clock's); the tracks' is the recording's,
    # which started when it was simulated, before the processes started and warmed up.
    killed_wall = time.time()
    east.kill()
    restarted_at = at(16.0)  # 32 s of data without 25/13
    east = Role(feeds, stage, "--role", "radar", "--radars", "25/13", ready="publishing")
    started.append(east)
    east_back_at = now()
    fusion_killed_at = at(32.0)
    # The feed waits while the new fusion process starts (10-20 s on a loaded 2-core
    # machine): what is measured is how soon its picture is back once it runs.
    running.clear()
    pause = time.monotonic()
    fusion.kill()
    fusion = Role(feeds, stage, "--role", "fusion", ready="fusion: taking")
    started.append(fusion)
    paused[0] += time.monotonic() - pause
    fusion_back_at = now()
    running.set()
    sender.join(timeout=120)
    time.sleep(1.0)
    assert fusion.stop() == 0, "\n".join(fusion.lines)
    for role in (west, east):
        assert role.stop() == 0, "\n".join(role.lines)

    tracks = _tracks(logged(feeds.log_dir))
    print("\n".join(fusion.lines))
    assert len({t["number"] for t in tracks}) > 10

    def radars_between(start: float, end: float) -> set[str]:
        return {
            s["radar"]
            for t in tracks
            if start <= t["time"] < end and t["status"] != "ended"
            for s in t["sources"]
            if s["age_s"] < 1.5 * PERIOD_S  # fed lately, not coasting on its last update
        }

    lag = 2.0 * SPEED  # holding windows, heartbeats, pacing (data seconds)
    assert "25/13" in radars_between(killed_at - 2 * PERIOD_S, killed_at)
    # Killed: 25/13 feeds nothing; the others go on.
    silent = radars_between(killed_at + lag, restarted_at)
    assert "25/13" not in silent and {"25/11", "25/12"} <= silent
    # Restarted: 25/13 is back, on the system tracks the others keep (its old local
    # tracks ended in the fuser), not beside them as duplicates.
    assert "25/13" in radars_between(east_back_at + lag, fusion_killed_at)
    live_before = {t["number"] for t in tracks if killed_at - PERIOD_S <= t["time"] < killed_at}
    live_after = {
        t["number"] for t in tracks if fusion_killed_at - PERIOD_S <= t["time"] < fusion_killed_at
    }
    assert len(live_after) <= 1.2 * len(live_before), (len(live_before), len(live_after))
    # The new fusion process: its picture back within two antenna periods.
    before = {
        t["number"] for t in tracks if fusion_killed_at - PERIOD_S <= t["time"] < fusion_killed_at
    }
    soon = fusion_back_at + 2 * PERIOD_S
    after = {t["number"] for t in tracks if fusion_back_at - PERIOD_S <= t["time"] < soon}
    assert len(after) >= 0.8 * len(before), (len(before), len(after))
    # The fusion process's status says the memory of each process of the layout: its
    # own, its output process's and each radar process's, as its heartbeat last said.
    statuses = [m.data for m in logged(feeds.log_dir) if m.topic == "/status"]
    roles_mb = [s["memory_mb"] for s in statuses if s["time"] < killed_wall]
    everyone = {"core", "outputs", "radar 25_11-25_12", "radar 25_13"}
    assert any(set(m) == everyone for m in roles_mb), roles_mb
    assert all(mb > 20.0 for m in roles_mb for mb in m.values()), roles_mb
    # And how busy each one's loop was since the last status (the radar processes' as
    # their heartbeats said): from a process's second status on (its first totals are
    # the base of its share), so seen over the run, each one's restarts included.
    roles_busy = [s["busy"] for s in statuses]
    assert set().union(*roles_busy) == everyone, roles_busy


def test_the_watermark_period_is_half_the_holding_window_within_bounds() -> None:
    assert watermark_period(0.02) == pytest.approx(0.01)
    assert watermark_period(0.0) == pytest.approx(0.005)
    assert watermark_period(1.0) == pytest.approx(0.1)


def test_a_radar_watermark_is_half_a_window_ahead_of_the_release_unless_a_datagram_is_held() -> (
    None
):
    # Nothing held: half the window before the inputs were last taken, half a window
    # ahead of what the merger releases (taken less the window).
    assert radar_watermark(None, 100.0, 0.02) == pytest.approx(99.99)
    # The oldest datagram held is what the process still has to send.
    assert radar_watermark(99.985, 100.0, 0.02) == pytest.approx(99.985)
    assert radar_watermark(99.995, 100.0, 0.02) == pytest.approx(99.99)
    assert radar_watermark(None, 100.0, 0.0) == pytest.approx(100.0)


def test_an_idle_radar_process_sends_its_watermark_every_half_holding_window(
    roles: tuple[Feeds, str, list[Role]],
) -> None:
    """Fusion releases a batch once every other radar process has passed its time, so an
    idle radar process's watermark period is added to every other radar's latency: at a
    holding window of 20 ms, each 10 ms (it was 0.1 s whatever the window: 67 ms more on
    three_sites' median in three radar processes). Heard here as fusion hears it, on a
    stage session listening where the radar process connects; nothing is sent to it."""
    feeds, stage, started = roles
    text = feeds.config.read_text(encoding="utf-8")
    feeds.config.write_text(
        re.sub(r"(?m)^holding_window_s = .*$", "holding_window_s = 0.02", text), "utf-8"
    )
    config = load_service_config(feeds.config)
    heard: list[tuple[float, int]] = []
    session = zenoh.open(stage_session_config(config, [stage], []))
    try:
        session.declare_subscriber(
            f"{config.zenoh.prefix}/stage/radars/*/batches",
            lambda s: heard.append((time.time(), decode_message(s.payload.to_bytes()).order)),
        )
        radar = Role(feeds, stage, "--role", "radar", "--radars", "25/11", ready="publishing")
        started.append(radar)
        time.sleep(1.0)  # the session's links up
        first = len(heard)
        time.sleep(2.0)
        beats = heard[first:]
        assert radar.stop() == 0, "\n".join(radar.lines)
    finally:
        session.close()  # type: ignore[no-untyped-call]
    orders = [order for _, order in beats]
    assert orders == sorted(orders)
    # 200 at 10 ms; at the old 0.1 s, 20. Loose for a loaded machine.
    assert len(beats) > 60, len(beats)
    # Half the window behind their reception here (and the link's delay), where the
    # release is the whole window behind: another radar process's batch, published once
    # a window old, finds this one's last watermark past it.
    behind = sorted(heard_at - order / 1e6 for heard_at, order in beats)
    assert behind[len(behind) // 2] < 0.018, behind[len(behind) // 2]
