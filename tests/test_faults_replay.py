"""Issue 11: a replay with hostile datagrams interleaved gives the clean replay's tracks.

A three_sites recording written as a pcap capture twice, once as it is and once with
hostile datagrams (malformed, random, records without a source, unknown categories and
sources, truncated records, repeats of real datagrams) between its datagrams; both
replayed by ``tracker-service replay``; the system tracks of their MCAP logs compared."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from asterix.containers import write_pcap
from tests.fault_tools import EXAMPLE, hostile_datagrams
from tests.test_service_replay import endpoint, logged, simulate, system_tracks
from tracker_service.cli import main
from tracker_service.simulator.recording import read_recording

HOSTILE_SRC = ("10.66.6.6", 6666)


def _replay(capture: Path, out: Path) -> None:
    args = ["replay", str(capture), "--config", str(EXAMPLE), "--speed", "max"]
    assert main([*args, "--mcap-dir", str(out), "--zenoh-listen", endpoint()]) == 0


def _track(message: dict[str, Any]) -> tuple[Any, ...]:
    """What a system track says, but the plot numbers (hostile plots of unknown sources,
    tracked apart, take numbers too)."""
    return (
        message["number"],
        message["time"],
        round(message["lat"], 9),
        round(message["lon"], 9),
        message["flight_level"],
        message["address"],
        message["mode3a"],
        message["status"],
        tuple((s["radar"], s["local_track"]) for s in message["sources"]),
    )


def test_hostile_datagrams_interleaved_leave_the_tracks_unchanged(tmp_path: Path) -> None:
    recording = read_recording(simulate(tmp_path / "sim.mcap", 60.0))
    clean = [(d.time, d.src, d.dst, d.payload) for d in recording.datagrams()]
    rng = np.random.default_rng(17)
    hostile = hostile_datagrams(rng, clean[0][0] % 86400)
    mixed = []
    kinds: dict[str, int] = {}
    for k, (t, src, dst, payload) in enumerate(clean):
        mixed.append((t, src, dst, payload))
        if k % 3 == 0:
            kind, bad = next(hostile)
            kinds[kind] = kinds.get(kind, 0) + 1
            mixed.append((t, HOSTILE_SRC, dst, bad))
        if k % 7 == 0:
            # The same datagram again on its LAN, a moment later: a repeat.
            kinds["repeat"] = kinds.get("repeat", 0) + 1
            mixed.append((t + 1e-5, src, dst, payload))
    write_pcap(tmp_path / "clean.pcap", clean)
    write_pcap(tmp_path / "hostile.pcap", mixed)
    _replay(tmp_path / "clean.pcap", tmp_path / "clean")
    _replay(tmp_path / "hostile.pcap", tmp_path / "hostile")

    expected = [_track(m) for m in system_tracks(tmp_path / "clean")]
    got = [_track(m) for m in system_tracks(tmp_path / "hostile")]
    assert len(expected) > 500
    assert got == expected
    assert min(kinds.values()) >= 10, kinds

    # And the hostile ones are in the status, counted.
    status = [m.data for m in logged(tmp_path / "hostile") if m.topic == "/status"][-1]
    errors: dict[str, int] = {}
    for radar in status["radars"]:
        for kind, n in radar["errors"].items():
            errors[kind] = errors.get(kind, 0) + n
    for kind, n in status["unattributed"].items():
        errors[kind] = errors.get(kind, 0) + n
    assert errors.get("no_source", 0) >= kinds["no_i010"]
    assert errors.get("unknown_category", 0) >= kinds["unknown_category"]
    assert errors.get("not_asterix", 0) >= kinds["malformed"]
    assert errors.get("decode_error", 0) >= kinds["truncated_record"]
