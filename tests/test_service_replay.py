"""``tracker-service replay`` through the whole service: a real Zenoh subscriber in another
process, the MCAP log read back, CAT062 decoded and compared with the JSON messages."""

from __future__ import annotations

import gc
import json
import re
import socket
import subprocess
import sys
import weakref
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from asterix.codec import Block, decode_blocks
from tracker_service.central_stage import BIAS_HISTORY_S
from tracker_service.cli import main
from tracker_service.evaluation.pipeline import run_pipeline
from tracker_service.outputs.mcap_log import LoggedMessage, read_log_messages
from tracker_service.service import command
from tracker_service.service.command import open_service
from tracker_service.service.config import load_service_config
from tracker_service.service.core import TrackerService, build_chain, config_from_recording
from tracker_service.service.replay import open_replay
from tracker_service.simulator.recording import read_recording

REPO = Path(__file__).resolve().parents[1]
SCENARIO = REPO / "config" / "scenarios" / "three_sites.toml"

# The other process: listens on an endpoint (the service connects to it) or connects to
# the service's, and prints every sample under the selector as a JSON line, until its stdin
# closes; or, with "get", asks the picture of a service listening on the endpoint and
# prints the replies.
CHILD = r"""
import json, select, sys, time, zenoh
role, endpoint, selector, out = sys.argv[1:5]
# A file, not stdout: a pipe nobody reads yet would block the callback and Zenoh drop.
out = open(out, "w")
config = zenoh.Config()
config.insert_json5("mode", '"peer"')
config.insert_json5("listen/endpoints" if role == "listen" else "connect/endpoints",
                    json.dumps([endpoint]))
config.insert_json5("scouting/multicast/enabled", "false")
session = zenoh.open(config)

def show(sample):
    data = sample.payload.to_bytes()
    print(json.dumps({"key": str(sample.key_expr), "kind": str(sample.kind),
                      "payload": data.hex()}), file=out, flush=True)

if role in ("listen", "connect"):
    subscriber = session.declare_subscriber(selector, show)
    print(json.dumps({"ready": True}), flush=True)
    select.select([sys.stdin], [], [], 120.0)
else:
    deadline = time.monotonic() + 5.0
    replies = []
    while not replies and time.monotonic() < deadline:
        replies = [r.ok for r in session.get(selector, timeout=1.0) if r.ok is not None]
    for sample in replies:
        show(sample)
session.close()
"""


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as sock:
        sock.bind(("127.0.0.1", 0))
        port: int = sock.getsockname()[1]
        return port


def endpoint() -> str:
    return f"tcp/127.0.0.1:{free_port()}"


@dataclass
class Sample:
    key: str
    kind: str
    payload: bytes

    def json(self) -> Any:
        return json.loads(self.payload)


class ZenohChild:
    """A Zenoh session in another process: a subscriber that listens, or one query."""

    def __init__(self, role: str, where: str, selector: str, out: Path) -> None:
        self.out = out
        self.process = subprocess.Popen(
            [sys.executable, "-c", CHILD, role, where, selector, str(out)],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        if role != "get":
            assert self.process.stdout is not None
            assert json.loads(self.process.stdout.readline()) == {"ready": True}

    def samples(self) -> list[Sample]:
        """Everything received (closes the subscriber)."""
        self.process.communicate(timeout=30)
        text = self.out.read_text(encoding="utf-8")
        lines = [json.loads(line) for line in text.splitlines() if line.strip()]
        return [
            Sample(d["key"], d["kind"].removeprefix("SampleKind."), bytes.fromhex(d["payload"]))
            for d in lines
        ]


def simulate(out: Path, duration: float, start: str | None = None) -> Path:
    """A recording of the three_sites scenario; ``start`` replaces its start time."""
    scenario = SCENARIO
    if start is not None:
        text = SCENARIO.read_text(encoding="utf-8")
        scenario = out.with_suffix(".toml")
        scenario.write_text(re.sub(r"(?m)^start = .*$", f"start = {start}", text), "utf-8")
    assert main(["simulate", str(scenario), "-o", str(out), "--duration", str(duration)]) == 0
    return out


def log_files(directory: Path) -> list[Path]:
    return sorted(directory.glob("*.mcap"))


def logged(directory: Path) -> list[LoggedMessage]:
    return [m for path in log_files(directory) for m in read_log_messages(path)]


def system_tracks(directory: Path) -> list[dict[str, Any]]:
    return [m.data for m in logged(directory) if m.topic == "/system_tracks"]


def replay(recording: Path, log_dir: Path, *extra: str) -> None:
    args = ["replay", str(recording), "--speed", "max", "--mcap-dir", str(log_dir)]
    if not any(a.startswith("--zenoh") for a in extra):
        # Explicit endpoints keep the session from scouting for peers on the LAN.
        args += ["--zenoh-listen", endpoint()]
    assert main([*args, *extra]) == 0


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate(tmp_path_factory.mktemp("sim") / "three_sites.mcap", 60.0)


@dataclass
class Published:
    log_dir: Path
    samples: list[Sample]


@pytest.fixture(scope="module")
def published(recording: Path, tmp_path_factory: pytest.TempPathFactory) -> Published:
    """A paced replay with a subscriber in another process on every key of the service."""
    where = endpoint()
    log_dir = tmp_path_factory.mktemp("log")
    child = ZenohChild("listen", where, "tracker/**", log_dir.parent / "samples.jsonl")
    try:
        replay(recording, log_dir, "--speed", "30", "--zenoh-connect", where)
    finally:
        samples = child.samples()
    return Published(log_dir, samples)


def test_replay_publishes_system_tracks_over_zenoh(published: Published) -> None:
    tracks = [s for s in published.samples if s.key.startswith("tracker/system_tracks/")]
    puts = [s.json() for s in tracks if s.kind == "PUT"]
    assert len(puts) > 100
    # What the subscriber got is what the log holds, in the same order.
    logged_tracks = system_tracks(published.log_dir)
    positions = {json.dumps(m, sort_keys=True): i for i, m in enumerate(logged_tracks)}
    indices = [positions[json.dumps(m, sort_keys=True)] for m in puts]
    assert indices == sorted(indices)
    # Every track ends: its "ended" message, then the delete of its key.
    by_key: dict[str, list[Sample]] = defaultdict(list)
    for sample in tracks:
        by_key[sample.key].append(sample)
    for key, samples in by_key.items():
        assert samples[-1].kind == "DELETE", key
        assert samples[-2].json()["status"] == "ended", key
        assert all(s.json()["status"] != "ended" for s in samples[:-2]), key
    assert any(s.key.startswith("tracker/local_tracks/25_13/") for s in published.samples)
    bias = [s.json() for s in published.samples if s.key.startswith("tracker/bias/25_11")]
    assert bias
    # Mosnik has a field monitor and shares traffic with the other radars: its range
    # offset is observable, and the message says from what.
    offset = bias[-1]["range_offset_m"]
    assert offset["observable"]
    assert {"field_monitor", "other_radars"} & set(offset["observed_from"])
    status = [s.json() for s in published.samples if s.key == "tracker/status"]
    assert status and {r["radar"] for r in status[-1]["radars"]} >= {"25/11", "25/12", "25/13"}
    # LAN B's copies of Mosnik (25/11) were recognised as duplicates.
    mosnik = next(r for r in status[-1]["radars"] if r["radar"] == "25/11")
    assert mosnik["duplicates"] > 100


def test_log_holds_datagrams_tracks_status_and_map(published: Published, recording: Path) -> None:
    messages = logged(published.log_dir)
    topics = {m.topic for m in messages}
    assert {"/datagrams/25_11", "/datagrams/25_12", "/datagrams/25_13"} <= topics
    assert {"/system_tracks", "/status", "/cat062", "/foxglove/tracks"} <= topics
    datagrams = [m for m in messages if m.topic.startswith("/datagrams/")]
    source = open_replay(recording)
    expected = [(name, d.payload.hex()) for name, d in source.datagrams]
    assert [(m.data["input"], m.data["payload"]) for m in datagrams] == expected
    fixes = [m for m in messages if m.topic == "/foxglove/tracks"]
    assert fixes[0].schema == "foxglove.LocationFix"
    assert 45.0 < fixes[0].data["latitude"] < 52.0


def _cat062_records(payload: bytes) -> list[dict[str, Any]]:
    records: list[dict[str, Any]] = []
    for event in decode_blocks(payload):
        assert isinstance(event, Block), event
        if event.cat == 62:
            records.extend(event.records)
    return records


def test_cat062_content_matches_the_json_messages(published: Published) -> None:
    zenoh_cat062 = [s.payload for s in published.samples if s.key == "tracker/cat062"]
    messages = logged(published.log_dir)
    logged_cat062 = [bytes.fromhex(m.data["payload"]) for m in messages if m.topic == "/cat062"]
    # In the log's order; a CAT062 put is dropped, not blocked, under congestion (only a
    # track's end blocks: zenoh_out.py), and a loaded CI machine dropped one once.
    assert zenoh_cat062
    remaining = iter(enumerate(logged_cat062))  # each found after the one before it
    indices = [
        next((i for i, logged in remaining if logged == block), -1) for block in zenoh_cat062
    ]
    assert -1 not in indices
    assert len(zenoh_cat062) >= 0.95 * (indices[-1] + 1)
    latest: dict[int, dict[str, Any]] = {}
    compared = named = 0
    for message in messages:
        if message.topic == "/system_tracks":
            latest[message.data["number"]] = message.data
            continue
        if message.topic != "/cat062":
            continue
        for record in _cat062_records(bytes.fromhex(message.data["payload"])):
            track = latest[record["040"]]
            assert record["010"] == {"SAC": 25, "SIC": 100}
            assert record["070"] == pytest.approx(track["time"] % 86400, abs=1 / 128)
            assert record["105"]["LAT"] == pytest.approx(track["lat"], abs=180 / 2**25)
            assert record["105"]["LON"] == pytest.approx(track["lon"], abs=180 / 2**25)
            assert record["100"]["X"] == pytest.approx(track["x_m"], abs=0.5)
            assert record["100"]["Y"] == pytest.approx(track["y_m"], abs=0.5)
            assert record["080"]["TSE"] == int(track["status"] == "ended")
            assert record["080"]["CST"] == int(track["status"] == "coasting")
            assert record["080"]["MON"] == int(len(track["sources"]) == 1)
            if track["flight_level"] is not None:
                assert record["136"] == pytest.approx(track["flight_level"], abs=0.25)
            assert record.get("060", {}).get("MODE3A") == track["mode3a"]
            assert record.get("380", {}).get("ADR") == track["address"]
            if track["callsign"] is not None:
                assert record["245"]["CHR"].strip() == track["callsign"]
                named += 1
            if track["last_plot"] is not None:
                sac, sic = (int(p) for p in track["last_plot"]["radar"].split("/"))
                assert record["340"]["SID"] == {"SAC": sac, "SIC": sic}
            compared += 1
    assert compared > 100
    assert named > 50  # the Mode S aircraft's callsigns (I048/240) reach the system tracks


def test_replays_are_identical_and_so_is_the_replay_of_the_log(
    recording: Path, tmp_path: Path
) -> None:
    first, second, again = tmp_path / "first", tmp_path / "second", tmp_path / "again"
    replay(recording, first)
    replay(recording, second)
    tracks = system_tracks(first)
    assert len(tracks) > 500
    assert system_tracks(second) == tracks
    # The service's own log: its configuration and datagrams come from the file.
    replay(first, again)
    assert system_tracks(again) == tracks


def test_a_recording_across_midnight(tmp_path: Path) -> None:
    recording = simulate(tmp_path / "midnight.mcap", 60.0, start="2026-06-01T23:59:30Z")
    replay(recording, tmp_path / "log")
    tracks = system_tracks(tmp_path / "log")
    midnight = 1780358400.0  # 2026-06-02T00:00:00Z
    before = {m["number"] for m in tracks if m["time"] < midnight and m["status"] != "ended"}
    after = {m["number"] for m in tracks if m["time"] > midnight + 10 and m["status"] != "ended"}
    # Tracks go on through midnight under their numbers.
    assert len(before & after) >= 5
    ended = [m for m in tracks if m["status"] == "ended" and m["time"] < midnight + 25]
    assert len(ended) <= len(before) // 4, "tracks broke at midnight"
    times = [
        r["070"]
        for m in logged(tmp_path / "log")
        if m.topic == "/cat062"
        for r in _cat062_records(bytes.fromhex(m.data["payload"]))
    ]
    assert max(times) > 86390 and min(times) < 30


def test_a_radar_that_stops_and_resumes_is_tracked_again(recording: Path) -> None:
    source = open_replay(recording)
    service = TrackerService(source.config)
    start: float | None = None
    statuses: list[tuple[float, str]] = []
    resumed: list[set[str]] = []
    next_check = 0.0
    for name, datagram in source.datagrams:
        assert datagram.time is not None
        start = datagram.time if start is None else start
        elapsed = datagram.time - start
        if name == "25_13" and 20.0 < elapsed < 42.0:
            continue  # Koris-hegy (5 s antenna) silent for 22 s
        updated = service.counts.system_updates
        service.process(name, datagram)
        if elapsed > 50.0 and service.counts.system_updates > updated:
            resumed.append(_radars_of_live_tracks(service))
        if elapsed >= next_check:
            statuses.append((elapsed, service.status().health))
            next_check += 2.5
    service.close()
    assert any(h == "degraded" for t, h in statuses if 30.0 < t < 42.0)
    assert all(h == "ok" for t, h in statuses if t > 47.0)
    assert any("25/13" in radars for radars in resumed)


def _radars_of_live_tracks(service: TrackerService) -> set[str]:
    return {s.radar for track in service.picture().values() for s in track.sources}


def test_start_up_objects_are_out_of_the_collectors_sight() -> None:
    """``command.freeze_start_up``: once the service is built, what start-up made is in
    the permanent generation, so that a full collection scans only what came since."""
    config = load_service_config(REPO / "config" / "example.toml")
    gc.unfreeze()
    try:
        with open_service(config, None, zenoh=False) as service:
            assert gc.get_freeze_count() > 10_000
            assert service.chain.sources == ["25/11", "25/12", "25/13"]
    finally:
        gc.unfreeze()


def test_the_core_freezes_survivors_while_it_runs() -> None:
    """The core's process (``open_service``) has ``freeze_survivors`` as the output
    process has, for the service's life only."""
    config = load_service_config(REPO / "config" / "example.toml")
    gc.unfreeze()
    try:
        with open_service(config, None, zenoh=False):
            assert command._freeze_after_full_collection in gc.callbacks
        assert command._freeze_after_full_collection not in gc.callbacks
    finally:
        gc.unfreeze()


def test_the_core_switches_threads_often_while_it_runs() -> None:
    """The core's process (``open_service``) lets a waiting thread take the GIL after
    ``SWITCH_INTERVAL_S`` (1 ms, not Python's 5), for the service's life only."""
    config = load_service_config(REPO / "config" / "example.toml")
    before = sys.getswitchinterval()
    gc.unfreeze()
    try:
        with open_service(config, None, zenoh=False):
            assert sys.getswitchinterval() == pytest.approx(command.SWITCH_INTERVAL_S)
        assert sys.getswitchinterval() == before
    finally:
        gc.unfreeze()


def test_survivors_of_each_full_collection_leave_the_collectors_sight() -> None:
    """``command.freeze_survivors`` (the output process's): what survives a full
    collection is frozen at its end, the next scans only what came since; garbage is
    still collected, and a frozen object still freed when its last reference goes."""

    class Node:
        pass

    gc.unfreeze()
    command.freeze_survivors()
    command.freeze_survivors()
    try:
        assert gc.callbacks.count(command._freeze_after_full_collection) == 1
        kept = [Node() for _ in range(1000)]
        gc.collect()
        frozen = gc.get_freeze_count()
        assert frozen >= 1000
        assert not {id(node) for node in kept} & {id(o) for o in gc.get_objects()}
        # A cycle made since is the collector's as before.
        cycle = Node()
        cycle.self = cycle  # type: ignore[attr-defined]
        watch = weakref.ref(cycle)
        del cycle
        gc.collect(0)
        assert watch() is None
        # A frozen object goes with its last reference, out of the permanent generation.
        gone = weakref.ref(kept[0])
        del kept[0]
        assert gone() is None
        assert gc.get_freeze_count() < frozen
    finally:
        gc.callbacks.remove(command._freeze_after_full_collection)
        gc.unfreeze()


def test_only_an_evaluation_keeps_the_history_of_the_biases(recording: Path) -> None:
    """An evaluation's report plots each radar's bias over the run (an entry per radar
    every ``BIAS_HISTORY_S`` of data); the service runs for months, where that history
    would only grow: its chain keeps none."""
    data = read_recording(recording)
    service = build_chain(config_from_recording(data.metadata))
    for datagram in data.datagrams():
        service.feed(datagram.payload, datagram.time)
    assert service.bias is not None and service.bias_history == service.clock_history == []
    evaluated = run_pipeline(recording)
    by_radar = defaultdict(list)
    for time, source, _bias, _covariance in evaluated.bias_history:
        by_radar[source].append(time)
    assert sorted(by_radar) == sorted(evaluated.radars) != []
    for times in by_radar.values():
        assert len(times) >= 50.0 / BIAS_HISTORY_S
        assert min(np.diff(times)) >= BIAS_HISTORY_S
    assert len(evaluated.clock_history) == len(evaluated.bias_history)
