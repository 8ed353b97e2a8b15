"""ASTERIX over UDP (``outputs/asterix_udp.py``): a recording through the service, the
datagrams received with real sockets on 127.0.0.1 (unicast, and multicast on loopback
where the machine allows), decoded by this codec, and each record checked with
libasterix, an independent decoder, when its venv is there."""

from __future__ import annotations

import json
import math
import socket
import struct
import subprocess
import time
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from asterix.codec import Block, decode_blocks
from tests.asterix_oracle import differences
from tests.test_service_replay import ZenohChild, endpoint, simulate
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.asterix_udp import blocks_in_datagrams, parse_destination
from tracker_service.outputs.periodic import PeriodicPicture, extrapolate
from tracker_service.service.command import open_service
from tracker_service.service.config import AsterixUdpOutput, ServiceConfig, with_destinations
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay

REPO = Path(__file__).resolve().parents[1]
PEER = Path(__file__).with_name("peer_libasterix.py")
PEER_VENVS = (Path("/tmp/venv-libasterix"), REPO / "benchmarks" / ".venvs" / "libasterix")
GROUP = "239.255.62.1"


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return simulate(tmp_path_factory.mktemp("sim") / "three_sites.mcap", 40.0)


class Receiver:
    """A UDP socket on 127.0.0.1 (or joined to ``group`` on loopback) keeping what comes."""

    def __init__(self, group: str | None = None) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 8 * 1024 * 1024)
        if group is None:
            self.sock.bind(("127.0.0.1", 0))
        else:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self.sock.bind((group, 0))
            membership = struct.pack("4s4s", socket.inet_aton(group), socket.inet_aton("127.0.0.1"))
            self.sock.setsockopt(socket.IPPROTO_IP, socket.IP_ADD_MEMBERSHIP, membership)
        self.port: int = self.sock.getsockname()[1]
        self.sock.setblocking(False)

    def take(self) -> list[bytes]:
        out = []
        while True:
            try:
                out.append(self.sock.recv(65535))
            except BlockingIOError:
                return out

    def close(self) -> None:
        self.sock.close()


def run_service(
    recording: Path,
    outputs: list[AsterixUdpOutput],
    *,
    seconds: float = math.inf,
    silence_s: float = 0.0,
) -> TrackerService:
    """The recording's first ``seconds`` through the service, then ``silence_s`` of data
    time without data, then its end."""
    source = open_replay(str(recording), None, None)
    config = source.config.model_copy(update={"asterix_udp": outputs})
    service = TrackerService(config)
    first: float | None = None
    for name, datagram in source.datagrams:
        assert datagram.time is not None
        first = datagram.time if first is None else first
        if datagram.time - first > seconds:
            break
        service.process(name, datagram)
    if silence_s:
        service.advance(service.now + silence_s)
    service.close()
    return service


def records(datagrams: list[bytes]) -> list[tuple[int, dict[str, Any]]]:
    out = []
    for payload in datagrams:
        for event in decode_blocks(payload):
            assert isinstance(event, Block), event
            out.extend((event.cat, record) for record in event.records)
    return out


@pytest.fixture(scope="module")
def on_update(recording: Path) -> Iterator[tuple[TrackerService, list[bytes]]]:
    receiver = Receiver()
    try:
        output = AsterixUdpOutput(address="127.0.0.1", port=receiver.port)  # type: ignore[arg-type]
        service = run_service(recording, [output], silence_s=60.0)
        yield service, receiver.take()
    finally:
        receiver.close()


def test_on_update_sends_every_system_track_update_as_cat062(
    on_update: tuple[TrackerService, list[bytes]],
) -> None:
    service, datagrams = on_update
    assert datagrams and all(len(d) <= 1400 for d in datagrams)
    decoded = records(datagrams)
    cat062 = [r for cat, r in decoded if cat == 62]
    counts = service.counts
    assert len(cat062) == counts.system_updates
    assert {r["040"] for r in cat062} == counts.system_tracks
    system = service.config.system
    assert all(r["010"] == {"SAC": system.sac, "SIC": system.sic} for r in cat062)
    assert all(r["015"] == system.service_id for r in cat062)
    # Each track ends with TSE, and starts with TSB.
    ends = Counter(r["040"] for r in cat062 if r["080"]["TSE"])
    starts = Counter(r["040"] for r in cat062 if r["080"]["TSB"])
    assert set(ends) == set(starts) == counts.system_tracks
    assert max(ends.values()) == max(starts.values()) == 1


def test_status_brings_cat065_sdps_status_and_cat063_per_radar(
    on_update: tuple[TrackerService, list[bytes]],
) -> None:
    service, datagrams = on_update
    decoded = records(datagrams)
    sdps = [r for cat, r in decoded if cat == 65]
    assert sdps and all(r["000"] == 1 and "040" in r for r in sdps)
    sensors = [r for cat, r in decoded if cat == 63]
    feeds = {f"{r['050']['SAC']}/{r['050']['SIC']}" for r in sensors}
    assert feeds == {r.key for r in service.config.radars} | {a.key for a in service.config.adsb}
    # One CAT063 per feed at each status; the last set while data came, after 40 s of
    # traffic: every radar operational, its biases observable (three radars overlap) and
    # sent as estimated, near the last estimates.
    end = max(r["070"] for cat, r in decoded if cat == 62) + 1.0
    last = {f"{r['050']['SAC']}/{r['050']['SIC']}": r for r in sensors if r["030"] <= end}
    estimates = service.chain.bias_estimates()
    for radar in service.config.radars:
        record = last[radar.key]
        assert record["060"]["CON"] == 0
        assert "080" in record and "081" in record, record
        bias, _ = estimates[radar.key]
        assert record["081"] == pytest.approx(math.degrees(bias[2]), abs=0.02)
        assert record["080"]["SRB"] == pytest.approx(bias[0] / 1852.0, abs=0.05)


@pytest.fixture(scope="module")
def periodic(recording: Path) -> Iterator[tuple[TrackerService, list[bytes]]]:
    receiver = Receiver()
    try:
        output = AsterixUdpOutput(
            address="127.0.0.1",  # type: ignore[arg-type]
            port=receiver.port,
            on_update=False,
            period_s=4.0,
        )
        service = run_service(recording, [output])
        yield service, receiver.take()
    finally:
        receiver.close()


def test_periodic_output_is_the_picture_extrapolated_to_common_times(
    periodic: tuple[TrackerService, list[bytes]],
) -> None:
    service, datagrams = periodic
    decoded = records(datagrams)
    batches: list[list[dict[str, Any]]] = [[]]
    ends = []
    for cat, record in decoded:
        if cat == 62:
            batches[-1].append(record)
        elif cat == 65 and record["000"] == 2:
            ends.append(record)
            batches.append([])
    assert len(ends) >= 8
    assert [e["020"] for e in ends] == list(range(len(ends)))
    for end, batch in zip(ends, batches, strict=False):
        # Every track of a batch at the batch's time, a multiple of the period.
        assert end["030"] % 4.0 == 0.0
        assert {r["070"] for r in batch} <= {end["030"]}
        assert len({r["040"] for r in batch}) == len(batch)
    assert max(len(b) for b in batches) >= 20
    numbers = {r["040"] for b in batches for r in b}
    assert numbers <= service.counts.system_tracks


def test_multicast_on_loopback(recording: Path) -> None:
    try:
        receiver = Receiver(GROUP)
    except OSError as exc:
        pytest.skip(f"cannot join {GROUP} on loopback here: {exc}")
    try:
        output = AsterixUdpOutput(
            address=GROUP,  # type: ignore[arg-type]
            port=receiver.port,
            interface="127.0.0.1",  # type: ignore[arg-type]
        )
        try:
            service = run_service(recording, [output], seconds=10.0)
        except OSError as exc:
            pytest.skip(f"cannot send to {GROUP} over loopback here: {exc}")
        datagrams = receiver.take()
    finally:
        receiver.close()
    if not datagrams:
        pytest.skip("multicast on loopback is not delivered on this machine")
    cat062 = [r for cat, r in records(datagrams) if cat == 62]
    assert len(cat062) == service.counts.system_updates


def _peer_python() -> Path:
    for venv in PEER_VENVS:
        python = venv / "bin" / "python"
        if python.exists():
            return python
    pytest.skip(
        "libasterix not installed in a separate venv: python3 -m venv /tmp/venv-libasterix "
        "&& /tmp/venv-libasterix/bin/pip install libasterix==0.36.3"
    )


def test_every_record_is_valid_for_libasterix(
    on_update: tuple[TrackerService, list[bytes]],
    periodic: tuple[TrackerService, list[bytes]],
    tmp_path: Path,
) -> None:
    python = _peer_python()
    # A sample (libasterix takes about 10 ms a record): every status, some tracks.
    datagrams = [d for d in on_update[1] if d[0] != 62][:20] + on_update[1][::5] + periodic[1][::3]
    hex_file = tmp_path / "datagrams.hex"
    hex_file.write_text("".join(d.hex() + "\n" for d in datagrams), encoding="ascii")
    done = subprocess.run(
        [str(python), "-I", str(PEER), str(hex_file)],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    theirs = [json.loads(line) for line in done.stdout.splitlines()]
    assert not [t for t in theirs if "error" in t]
    ours = records(datagrams)
    assert {c for c, _ in ours} == {62, 63, 65}
    assert len(theirs) == len(ours)
    for their, (cat, mine) in zip(theirs, ours, strict=True):
        assert their["cat"] == cat
        assert not differences(their["items"], mine), (cat, differences(their["items"], mine))


def test_a_silent_radar_is_not_connected_in_cat063(
    on_update: tuple[TrackerService, list[bytes]],
) -> None:
    """After the recording, a minute without data: every feed silent, CON "not currently
    connected" and the no-plot warning, the SDPS degraded."""
    _, datagrams = on_update
    decoded = records(datagrams)
    sensors = [r for cat, r in decoded if cat == 63]
    last = {f"{r['050']['SAC']}/{r['050']['SIC']}": r for r in sensors}
    assert len(last) == 4
    for record in last.values():
        assert record["060"]["CON"] == 3
        assert record["060"]["NPW"] == 1
    sdps = [r for cat, r in decoded if cat == 65 and r["000"] == 1]
    assert sdps[0]["040"]["NOGO"] == 0
    assert sdps[-1]["040"]["NOGO"] == 1


def test_extrapolation_moves_the_state_and_grows_its_covariance(
    on_update: tuple[TrackerService, list[bytes]],
) -> None:
    service, _ = on_update
    plane = service.plane
    picture = PeriodicPicture(plane, 5.0)
    assert picture.due(1000.2) is None and picture.due(1004.9) is None
    assert picture.due(1005.1) == 1005.0 and picture.due(1009.0) is None
    assert picture.due(1042.0) == 1040.0  # a silence gives one picture, not a burst
    message = _a_message(plane)
    moved = extrapolate(message, message.time + 10.0, plane)
    assert moved.x_m == pytest.approx(message.x_m + 10.0 * message.vx_mps)
    assert moved.y_m == pytest.approx(message.y_m + 10.0 * message.vy_mps)
    lat, lon = plane.to_geodetic(np.array([moved.x_m]), np.array([moved.y_m]))
    assert (moved.lat, moved.lon) == pytest.approx((lat[0], lon[0]))
    # Position variance: P_xx + 2 dt P_xv + dt² P_vv + q dt³/3.
    p = np.asarray(message.covariance)
    expected = p[0, 0] + 2 * 10 * p[0, 2] + 100 * p[2, 2] + 1000 / 3
    assert moved.covariance[0][0] == pytest.approx(expected)
    assert moved.flight_level == pytest.approx(350.0 + 1000 / 6000 * 10)
    assert moved.time == message.time + 10.0


def _a_message(plane: SystemPlane) -> Any:
    from tracker_service.outputs.messages import SystemTrackMessage

    lat, lon = plane.to_geodetic(np.array([20_000.0]), np.array([-5_000.0]))
    p = np.diag([100.0, 150.0, 4.0, 9.0])
    p[0, 2] = p[2, 0] = 5.0
    return SystemTrackMessage.from_state(
        time=1_780_000_000.0,
        x_m=20_000.0,
        y_m=-5_000.0,
        vx_mps=200.0,
        vy_mps=-30.0,
        covariance=p.tolist(),
        climb_rate_fl_per_s=1000 / 6000,
        number=7,
        lat=float(lat[0]),
        lon=float(lon[0]),
        flight_level=350.0,
        sources=[],
        status="confirmed",
    )


def test_destinations_from_the_command_line(recording: Path) -> None:
    config: ServiceConfig = open_replay(str(recording), None, None).config
    assert parse_destination("239.1.62.1:8600") == ("239.1.62.1", 8600)
    added = with_destinations(config, ["239.1.62.1:8600", "127.0.0.1:9000"])
    assert [o.destination for o in added.asterix_udp] == ["239.1.62.1:8600", "127.0.0.1:9000"]
    assert all(o.on_update and o.period_s is None for o in added.asterix_udp)
    for bad in ("localhost", "1.2.3.4:0", "1.2.3.4:port", "radar:8600"):
        with pytest.raises(ValueError, match=r"--asterix-udp|HOST:PORT"):
            with_destinations(config, [bad])
    with pytest.raises(ValueError, match="on_update"):
        AsterixUdpOutput(address="127.0.0.1", port=9, on_update=False)  # type: ignore[arg-type]


def test_blocks_are_packed_whole_into_datagrams() -> None:
    blocks = [bytes([62]) + (n).to_bytes(2) + bytes(n - 3) for n in (500, 600, 700, 1500, 10)]
    data = b"".join(blocks)
    payloads = list(blocks_in_datagrams(data, 1400))
    assert b"".join(payloads) == data
    assert [len(p) for p in payloads] == [1100, 700, 1500, 10]


def test_the_periodic_picture_over_zenoh(recording: Path, tmp_path: Path) -> None:
    """``[zenoh] period_s``: the same pictures on Zenoh, to a subscriber in another
    process, as JSON lists and as CAT062 + CAT065."""
    where = endpoint()
    child = ZenohChild("listen", where, "tracker/**", tmp_path / "z.jsonl")
    source = open_replay(str(recording), None, None)
    zenoh = source.config.zenoh.model_copy(update={"connect": [where], "period_s": 4.0})
    config = source.config.model_copy(update={"zenoh": zenoh})
    try:
        with open_service(config, None) as service:
            time.sleep(1.0)  # the subscriber's interest reaches the publisher
            for name, datagram in source.datagrams:
                service.process(name, datagram)
    finally:
        samples = child.samples()
    pictures = [s.json() for s in samples if s.key == "tracker/picture"]
    blocks = [s.payload for s in samples if s.key == "tracker/cat062/picture"]
    assert len(pictures) >= 8 and len(blocks) == len(pictures)
    for picture, data in zip(pictures, blocks, strict=True):
        times = {m["time"] for m in picture}
        assert len(times) <= 1 and all(t % 4.0 == 0.0 for t in times)
        decoded = records([data])
        assert [r["040"] for c, r in decoded if c == 62] == [m["number"] for m in picture]
        assert decoded[-1][0] == 65 and decoded[-1][1]["000"] == 2
    assert max(len(p) for p in pictures) >= 20
