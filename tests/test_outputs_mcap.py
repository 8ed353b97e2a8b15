"""The MCAP log read back with the mcap library: closed, rotated and killed files."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import pytest
from mcap.reader import make_reader
from pydantic import BaseModel

from asterix.containers import Datagram
from tracker_service.outputs.foxglove_scene import LOCATION_FIX, SCHEMAS
from tracker_service.outputs.mcap_log import LoggedDatagram, McapLog, read_log_messages

T0 = 1_700_000_000.25


_FIX = {
    "timestamp": {"sec": 1_700_000_001, "nsec": 250_000_000},
    "frame_id": "track/4",
    "latitude": 48.5,
    "longitude": 2.25,
    "altitude": 3000.0,
}
"""A ``foxglove.LocationFix``, as the map's channel carries it (a well-known schema's
message already encoded: ``log_encoded``)."""
_FIX_JSON = json.dumps(_FIX, separators=(",", ":")).encode()


class Track(BaseModel):
    number: int
    lat: float


def test_read_back_with_make_reader(tmp_path: Path) -> None:
    datagram = Datagram(b"\x30\x00\x04\x00", 0, T0, ("10.0.0.1", 5000), ("232.1.1.1", 8600))
    with McapLog(tmp_path) as log:
        log.log_datagram(datagram, "r1")
        log.log("/system_tracks", Track(number=4, lat=48.5), T0 + 1)
        log.log_encoded(
            "/foxglove/tracks", LOCATION_FIX, lambda: SCHEMAS[LOCATION_FIX], _FIX_JSON, T0 + 1
        )
    assert len(log.files) == 1
    with log.files[0].open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None
        got = [
            (channel.topic, schema and schema.name, message.log_time, json.loads(message.data))
            for schema, channel, message in reader.iter_messages(log_time_order=True)
        ]
    assert {s.name: s.encoding for s in summary.schemas.values()} == {
        "tracker_service.LoggedDatagram": "jsonschema",
        "tracker_service.Track": "jsonschema",
        "foxglove.LocationFix": "jsonschema",
    }
    assert {c.topic for c in summary.channels.values()} == {
        "/datagrams/r1",
        "/system_tracks",
        "/foxglove/tracks",
    }
    assert all(c.message_encoding == "json" for c in summary.channels.values())
    track_schema = next(s for s in summary.schemas.values() if s.name.endswith("Track"))
    assert json.loads(track_schema.data)["properties"]["lat"]["type"] == "number"
    assert got[0] == (
        "/datagrams/r1",
        "tracker_service.LoggedDatagram",
        1_700_000_000_250_000_000,
        {
            "input": "r1",
            "time": T0,
            "src": "10.0.0.1:5000",
            "dst": "232.1.1.1:8600",
            "payload": "30000400",
        },
    )
    assert got[1][3] == {"number": 4, "lat": 48.5}
    assert got[2][1:] == ("foxglove.LocationFix", 1_700_000_001_250_000_000, _FIX)
    assert (
        json.loads(next(s for s in summary.schemas.values() if s.name == LOCATION_FIX).data)
        == (SCHEMAS[LOCATION_FIX])
    )
    # The robust reader agrees with the indexed one on a closed file.
    assert [(m.topic, m.data) for m in read_log_messages(log.files[0])] == [
        (topic, data) for topic, _, _, data in got
    ]


@pytest.mark.parametrize(
    ("size_mb", "duration_s", "files"),
    [
        # 60 s of log times in files of 25 s: from 0, 25 and 50 s.
        (100.0, 25.0, [0, 250, 500]),
        # A few kB: every finished chunk or two starts a new file.
        (0.002, 3600.0, None),
    ],
)
def test_rotation(
    tmp_path: Path, size_mb: float, duration_s: float, files: list[int] | None
) -> None:
    with McapLog(tmp_path, size_mb, duration_s, chunk_size=2048) as log:
        for n in range(600):
            log.log("/tracks", Track(number=n, lat=float(n)), T0 + n * 0.1)
    assert log.files == sorted(tmp_path.glob("tracker_*.mcap"))
    firsts = []
    numbers = []
    for path in log.files:
        with path.open("rb") as stream:
            found = [
                json.loads(m.data)["number"] for _, _, m in make_reader(stream).iter_messages()
            ]
        firsts.append(found[0])
        numbers += found
    assert numbers == list(range(600))
    if files is None:
        assert len(log.files) >= 3
    else:
        assert firsts == files
    assert log.files[0].name == "tracker_20231114T221320250Z_0000.mcap"


CHILD = r"""
import sys
from pydantic import BaseModel
from tracker_service.outputs.mcap_log import McapLog

class Track(BaseModel):
    number: int
    lat: float

log = McapLog(sys.argv[1], chunk_size=1024, flush_interval_s=3600.0)
n = 0
while True:
    log.log("/tracks", Track(number=n, lat=48.0 + n * 1e-6), 1_700_000_000.0 + n)
    n += 1
    if n % 100 == 0:
        print(n, flush=True)
"""


def test_sigkill_leaves_readable_chunks(tmp_path: Path) -> None:
    proc = subprocess.Popen(
        [sys.executable, "-c", CHILD, str(tmp_path)], stdout=subprocess.PIPE, text=True
    )
    assert proc.stdout is not None
    try:
        for line in proc.stdout:
            if int(line) >= 2000:
                break
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait()
    assert proc.returncode == -signal.SIGKILL
    (path,) = tmp_path.glob("*.mcap")
    numbers = [m.data["number"] for m in read_log_messages(path)]
    # Every message up to the last complete chunk (about 40 to a chunk of 1 kB), in order.
    assert numbers == list(range(len(numbers)))
    assert len(numbers) >= 2000 - 100


@pytest.mark.parametrize(
    ("time", "source", "destination"),
    [
        (T0, ("10.0.0.1", 5000), ("232.1.1.1", 8600)),
        (T0 + 1e-7, None, None),
        (0.0, None, ("::1", 1)),
    ],
)
def test_a_datagram_is_loggeddatagrams_json(
    tmp_path: Path, time: float, source: tuple[str, int] | None, destination: tuple[str, int] | None
) -> None:
    """Written without a validated model per datagram, byte for byte the model's JSON."""
    datagram = Datagram(bytes(range(256)) * 3, 0, time, source, destination)
    with McapLog(tmp_path) as log:
        log.log_datagram(datagram, "25_11")
    ((_, data),) = [(m.topic, m.data) for m in _raw(log.files[0])]
    endpoint = [None if e is None else f"{e[0]}:{e[1]}" for e in (source, destination)]
    model = LoggedDatagram(
        input="25_11", time=time, src=endpoint[0], dst=endpoint[1], payload=datagram.payload.hex()
    )
    assert data == model.model_dump_json().encode()


@pytest.mark.parametrize("time", [-1.0, float("nan"), float("inf")])
def test_a_datagram_with_an_impossible_time_is_refused_as_before(
    tmp_path: Path, time: float
) -> None:
    with McapLog(tmp_path) as log, pytest.raises(ValueError, match="time"):
        log.log_datagram(Datagram(b"\x30\x00\x03", 0, time, None, None), "25_11")


class _Raw(NamedTuple):
    topic: str
    data: bytes


def _raw(path: Path) -> list[_Raw]:
    with path.open("rb") as stream:
        return [
            _Raw(channel.topic, message.data)
            for _, channel, message in make_reader(stream).iter_messages(log_time_order=False)
        ]
