"""System-track identity from the plots that updated it (issue 13): two aircraft that
share a Mode S address never trade callsigns, and a system track keeps its aircraft
through a swap of Mode 3/A codes announced by the plots."""

from __future__ import annotations

import dataclasses
from collections import Counter, defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.test_fusion import AIRCRAFT, RADARS, T0, Aircraft, build
from tests.test_service_replay import _cat062_records, endpoint
from tracker_service.cli import main
from tracker_service.fusion import ENDED, SystemTracker
from tracker_service.outputs.mcap_log import LoggedMessage, read_log_messages
from tracker_service.tracking import LocalTracker, TrackerConfig

REPO = Path(__file__).resolve().parents[1]
DEMO = REPO / "recordings" / "three_sites.mcap"
SHARED_ADDRESS = "C1DDBD"
"""The address two of the bundled recording's aircraft share (QRY455 and KOM5518:
``shared_address_pairs = 1`` in three_sites.toml)."""


@pytest.fixture(scope="module")
def logged(tmp_path_factory: pytest.TempPathFactory) -> list[LoggedMessage]:
    log_dir = tmp_path_factory.mktemp("log")
    args = ["replay", str(DEMO), "--speed", "max", "--mcap-dir", str(log_dir)]
    assert main([*args, "--zenoh-listen", endpoint()]) == 0
    return [m for path in sorted(log_dir.glob("*.mcap")) for m in read_log_messages(path)]


def test_aircraft_sharing_an_address_keep_their_callsigns(logged: list[LoggedMessage]) -> None:
    """Each system track carries one callsign, in its JSON messages and in CAT062 I245;
    the two tracks of the shared address carry different ones. Before: system track 5
    (code 1754, QRY455) carried KOM5518 in 40 of its 72 updates."""
    callsigns: dict[int, Counter[str | None]] = defaultdict(Counter)
    latest: dict[int, dict[str, Any]] = {}
    in_cat062: dict[int, set[str]] = defaultdict(set)
    for message in logged:
        if message.topic == "/system_tracks":
            latest[message.data["number"]] = message.data
            callsigns[message.data["number"]][message.data["callsign"]] += 1
        elif message.topic == "/cat062":
            for record in _cat062_records(bytes.fromhex(message.data["payload"])):
                if "245" in record:
                    in_cat062[record["040"]].add(record["245"]["CHR"].strip())
    shared = sorted(n for n, m in latest.items() if m["address"] == SHARED_ADDRESS)
    assert len(shared) == 2
    named = {n: {c for c in callsigns[n] if c is not None} for n in shared}
    assert all(len(names) == 1 for names in named.values()), named
    assert named[shared[0]] != named[shared[1]]
    for number, names in callsigns.items():
        assert len(names.keys() - {None}) <= 1, (number, names)
        assert in_cat062[number] <= names.keys(), (number, in_cat062[number], names)


def test_a_code_swap_keeps_each_system_track_on_its_aircraft() -> None:
    """Two Mode A/C aircraft (no address) swap their Mode 3/A codes at t = 150 s, as ATC
    may reassign them: each system track keeps its aircraft (by its plots) and takes the
    new code the plots announce, once."""
    swap_s = 150.0
    a, b = (dataclasses.replace(AIRCRAFT[i], address=-1) for i in (0, 2))
    scenario = build([a, b], RADARS)
    for _, plots in scenario.batches:
        late = plots["time"] >= T0 + swap_s
        plots["mode3a"][late] = np.where(plots["mode3a"][late] == a.mode3a, b.mode3a, a.mode3a)
    trackers = [LocalTracker(TrackerConfig(scan_period_s=r.period)) for r in RADARS]
    fuser = SystemTracker(len(RADARS))
    rows = []
    for radar, plots in scenario.batches:
        out = fuser.process(radar, trackers[radar].process(plots), plots)
        rows.append(out[out["status"] != ENDED])
    system = np.concatenate(rows)
    fresh = system[system["plot_id"] >= 0]
    owners: dict[int, set[int]] = defaultdict(set)
    for number, plot_id in zip(fresh["system_number"], fresh["plot_id"], strict=True):
        owners[int(number)].add(scenario.owner[int(plot_id)])
    assert sorted(owners) == sorted(set(owners)) and len(owners) == 2, owners
    assert all(len(o) == 1 for o in owners.values()), owners
    for number, (owner,) in owners.items():
        aircraft: Aircraft = (a, b)[owner]
        other = (b, a)[owner]
        track = fresh[fresh["system_number"] == number]
        codes = track["mode3a"]
        before = track["time"] < T0 + swap_s - 1.0
        after = track["time"] > T0 + swap_s + 12.0
        assert (codes[before] == aircraft.mode3a).all()
        assert (codes[after] == other.mode3a).all()
        assert np.count_nonzero(np.diff(codes) != 0) == 1
