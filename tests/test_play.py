"""``tracker-service play``: a capture sent to a running ``run`` daemon's inputs over real
UDP on 127.0.0.1, its times re-based on the present (``--now``), and tracked."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from asterix.codec import Block, decode_blocks, encode_block
from tests.test_service_replay import endpoint, logged, simulate
from tests.test_service_run import DaemonProcess, Feeds
from tracker_service.play import shift_times
from tracker_service.simulator.cat001 import cat001_plot
from tracker_service.simulator.recording import read_recording

DAY = 86_400.0


@pytest.fixture(scope="module")
def old_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The scenario's own start: a day that is not today."""
    return simulate(tmp_path_factory.mktemp("sim") / "old.mcap", 30.0)


def _times(payload: bytes) -> list[tuple[int, str, float]]:
    items = {48: ("140",), 34: ("030",), 21: ("071", "073", "075", "077")}
    out = []
    for event in decode_blocks(payload):
        assert isinstance(event, Block)
        for record in event.records:
            out.extend((event.cat, k, record[k]) for k in items.get(event.cat, ()) if k in record)
    return out


def test_shift_moves_every_time_of_day_and_nothing_else(old_recording: Path) -> None:
    seen = set()
    for recorded in list(read_recording(old_recording).datagrams())[:400]:
        moved = shift_times(recorded.payload, 3600 * 20 + 7)
        before, after = _times(recorded.payload), _times(moved)
        assert len(before) == len(after)
        for (cat, item, t0), (_, _, t1) in zip(before, after, strict=True):
            assert t1 == pytest.approx((t0 + 72_007) % DAY)
            seen.add((cat, item))
        # Only the times changed: everything else re-encodes to itself.
        assert shift_times(moved, -(3600 * 20 + 7)) == recorded.payload
    assert {(48, "140"), (34, "030")} <= seen
    assert any(cat == 21 for cat, _ in seen)
    assert shift_times(b"\x30\x00\x05ab", 5) == b"\x30\x00\x05ab"  # malformed: as it is


def test_play_feeds_a_running_daemon(tmp_path: Path) -> None:
    """In real time (a faster pace would put the data ahead of the wall clock)."""
    old_recording = simulate(tmp_path / "old.mcap", 16.0)
    feeds = Feeds(tmp_path)
    # The daemon's ASTERIX output too, received here.
    receiver = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    receiver.bind(("127.0.0.1", 0))
    receiver.setblocking(False)
    with feeds.config.open("a", encoding="utf-8") as text:
        port = receiver.getsockname()[1]
        text.write(f'\n[[asterix_udp]]\naddress = "127.0.0.1"\nport = {port}\n')
    process = DaemonProcess(feeds, endpoint(), tmp_path / "health")
    try:
        started = time.time()
        done = subprocess.run(
            [
                sys.executable,
                "-m",
                "tracker_service.cli",
                "play",
                str(old_recording),
                "--config",
                str(feeds.config),
                "--now",
            ],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode == 0, done.stderr
        assert "sent " in done.stderr and "times moved by" in done.stderr, done.stderr
        time.sleep(1.0)
        assert process.stop(signal.SIGTERM) == 0, "\n".join(process.lines)
    finally:
        if process.process.poll() is None:
            process.process.kill()
            process.process.wait()
    sent = []
    with receiver:
        while True:
            try:
                sent.append(receiver.recv(65535))
            except BlockingIOError:
                break
    categories = [
        (e.cat, r)
        for d in sent
        for e in decode_blocks(d)
        if isinstance(e, Block)
        for r in e.records
    ]
    assert {cat for cat, _ in categories} == {62, 63, 65}
    assert all(r["010"] == {"SAC": 25, "SIC": 100} for _, r in categories)
    messages = logged(feeds.log_dir)
    datagrams = [m for m in messages if m.topic.startswith("/datagrams/")]
    assert len(datagrams) > 100
    # The datagrams' own times are today's: I140 within a few seconds of reception.
    for message in datagrams[::20]:
        received = float(message.data["time"])
        assert received >= started
        for cat, _, t in _times(bytes.fromhex(message.data["payload"])):
            if cat == 48:
                lag = (received - t) % DAY
                assert min(lag, DAY - lag) < 10.0
    tracks = {m.data["number"] for m in messages if m.topic == "/system_tracks"}
    assert len(tracks) >= 10
    assert {r["040"] for cat, r in categories if cat == 62} == tracks
    status = [m.data for m in messages if m.topic == "/status"][-1]
    radars = {r["radar"]: r for r in status["radars"]}
    for key in ("25/11", "25/12", "25/13"):
        assert abs(radars[key]["time_offset_s"]) < 2.0, radars[key]
        assert radars[key]["time_sane"], radars[key]
    assert radars["25/11"]["duplicates"] > 0  # both LANs of 25/11 were sent


def test_shift_wraps_cat001_truncated_time_at_512_s(old_recording: Path) -> None:
    """CAT001 I141 is the time of day modulo 512 s: shifted, it wraps there."""
    for recorded in read_recording(old_recording).datagrams():
        plots = [
            cat001_plot(r)
            for e in decode_blocks(recorded.payload)
            if isinstance(e, Block) and e.cat == 48
            for r in e.records
        ]
        if plots:
            break
    payload = encode_block(1, plots)
    moved = next(e for e in decode_blocks(shift_times(payload, 500)) if isinstance(e, Block))
    for before, after in zip(plots, moved.records, strict=True):
        assert after["141"] == pytest.approx((before["141"] + 500) % 512.0)
        assert {k: v for k, v in after.items() if k != "141"} == {
            k: v for k, v in before.items() if k != "141"
        }
