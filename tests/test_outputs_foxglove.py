"""The Foxglove channels: checked against the JSON schemas and the Foxglove SDK's own
message classes, read back from a real service log with the mcap library, and received
live from the SDK's WebSocket server by a WebSocket client on 127.0.0.1."""

from __future__ import annotations

import asyncio
import json
import math
import re
import socket
import struct
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from mcap.reader import make_reader

from tracker_service.outputs.foxglove_scene import (
    GEOJSON,
    LOCATION_FIX,
    PICTURE_TOPIC,
    RADARS_TOPIC,
    SCHEMAS,
    TRACKS_TOPIC,
    FoxgloveMessage,
    MapRadar,
    MapScene,
    _ahead,
    _round5,
    track_colour,
    track_label,
)
from tracker_service.outputs.foxglove_sink import (
    FoxgloveListenError,
    check_listen,
    parse_listen,
)
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.messages import SystemTrackMessage, TrackSource
from tracker_service.outputs.updates import SystemValues
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay

jsonschema = pytest.importorskip("jsonschema", reason="jsonschema is in the [test] extra")

REPO = Path(__file__).resolve().parents[1]
RECORDING = REPO / "recordings" / "three_sites.mcap"
T0 = 1_780_300_000.5
LOG_S = 30.0
SITE = MapRadar("25/11", "Alpha", 48.2, 17.2, 200.0)


def track(
    number: int = 7,
    *,
    time: float = T0,
    lat: float = 48.5,
    lon: float = 17.5,
    radars: tuple[str, ...] = ("25/11", "25/12"),
    status: str = "confirmed",
    **identity: Any,
) -> SystemTrackMessage:
    return SystemTrackMessage.from_state(
        time=time,
        x_m=0.0,
        y_m=0.0,
        vx_mps=200.0,
        vy_mps=0.0,
        covariance=[[100.0, 1.0, 0, 0], [1.0, 80.0, 0, 0], [0, 0, 4, 0], [0, 0, 0, 4]],
        number=number,
        lat=lat,
        lon=lon,
        sources=[TrackSource(radar=r, local_track=1, age_s=0.0) for r in radars],
        status=status,
        **identity,
    )


def validate(message: FoxgloveMessage) -> dict[str, Any]:
    """The message against its JSON schema (draft 2020-12), and GeoJSON's content as
    RFC 7946 shapes; its decoded JSON."""
    data = json.loads(message.data)
    jsonschema.Draft202012Validator(SCHEMAS[message.schema]).validate(data)
    if message.schema == GEOJSON:
        check_geojson(json.loads(data["geojson"]))
    return dict(data)


def check_position(coordinates: list[float]) -> None:
    assert len(coordinates) in (2, 3)
    lon, lat = coordinates[:2]
    assert -180.0 <= lon <= 180.0 and -90.0 <= lat <= 90.0


def check_geojson(collection: dict[str, Any]) -> None:
    assert collection["type"] == "FeatureCollection"
    for feature in collection["features"]:
        assert feature["type"] == "Feature" and isinstance(feature["properties"], dict)
        geometry = feature["geometry"]
        kind, coordinates = geometry["type"], geometry["coordinates"]
        if kind == "Point":
            check_position(coordinates)
        elif kind == "LineString":
            assert len(coordinates) >= 2
            for position in coordinates:
                check_position(position)
        else:
            assert kind == "Polygon"
            for ring in coordinates:
                assert len(ring) >= 4 and ring[0] == ring[-1]
                for position in ring:
                    check_position(position)


try:
    import foxglove.messages as sdk
except ImportError:  # the [foxglove] extra
    sdk = None
needs_sdk = pytest.mark.skipif(
    sdk is None, reason="the Foxglove SDK is not installed (pip install -e '.[foxglove]')"
)


def sdk_fields(cls: type) -> set[str]:
    """The field names of one of the SDK's message classes (its keyword arguments)."""
    signature = cls.__text_signature__  # type: ignore[attr-defined]
    return set(re.findall(r"(\w+)=", signature))


def as_sdk_location_fix(data: dict[str, Any]) -> Any:
    """Our JSON as the SDK's ``LocationFix``: an unknown field or a wrong type raises."""
    fields = dict(data)
    fields["timestamp"] = sdk.Timestamp(**fields["timestamp"])
    fields["color"] = sdk.Color(**fields["color"])
    fields["metadata"] = [sdk.KeyValuePair(**pair) for pair in fields["metadata"]]
    fields["position_covariance_type"] = {
        0: sdk.LocationFixPositionCovarianceType.Unknown,
        1: sdk.LocationFixPositionCovarianceType.Approximated,
        2: sdk.LocationFixPositionCovarianceType.DiagonalKnown,
        3: sdk.LocationFixPositionCovarianceType.Known,
    }[fields["position_covariance_type"]]
    return sdk.LocationFix(**fields)


@needs_sdk
def test_schemas_name_the_fields_of_the_sdk_messages() -> None:
    assert set(SCHEMAS[LOCATION_FIX]["properties"]) <= sdk_fields(sdk.LocationFix)
    assert set(SCHEMAS[GEOJSON]["properties"]) == sdk_fields(sdk.GeoJson)
    assert sdk.LocationFix.get_schema().name == LOCATION_FIX
    assert sdk.GeoJson.get_schema().name == GEOJSON
    colour = SCHEMAS[LOCATION_FIX]["properties"]["color"]["properties"]
    assert set(colour) == sdk_fields(sdk.Color)


def test_a_track_update_is_a_location_fix_with_identity_and_colour() -> None:
    scene = MapScene([SITE])
    message = track(callsign="DLH65A", mode3a="1000", address="3C660C", flight_level=350.0)
    out = scene.update(message, T0)
    assert [m.topic for m in out] == [TRACKS_TOPIC, RADARS_TOPIC, PICTURE_TOPIC]
    fix = validate(out[0])
    assert set(fix) == set(SCHEMAS[LOCATION_FIX]["properties"])  # every field, none else
    assert fix["frame_id"] == "track/7"
    assert (fix["latitude"], fix["longitude"]) == (48.5, 17.5)
    assert fix["altitude"] == pytest.approx(350 * 30.48)
    assert fix["timestamp"] == {"sec": 1_780_300_000, "nsec": 500_000_000}
    metadata = {pair["key"]: pair["value"] for pair in fix["metadata"]}
    assert metadata["label"] == "DLH65A FL350 389kt"
    assert metadata["callsign"] == "DLH65A" and metadata["address"] == "3C660C"
    assert metadata["sources"] == "25/11,25/12"
    assert fix["color"] == {"r": 0.18, "g": 0.8, "b": 0.25, "a": 1.0}
    for message_out in out[1:]:
        geojson = validate(message_out)
        if sdk is not None:
            assert sdk.GeoJson(**geojson).encode()
    if sdk is not None:
        assert len(as_sdk_location_fix(fix).encode()) > 100


def test_labels_and_colours_follow_identity_status_and_sources() -> None:
    assert track_label(track(mode3a="7000")) == "A7000 FL--- 389kt"
    assert track_label(track(number=12)) == "#12 FL--- 389kt"
    assert track_label(track(callsign="AFR12   ", flight_level=99.6)) == "AFR12 FL100 389kt"
    multi, single = track_colour(track()), track_colour(track(radars=("25/11",)))
    coasting = track_colour(track(status="coasting"))
    duplicate = track_colour(track(duplicate_address=True, address="3C660C"))
    assert len({multi, single, coasting, duplicate}) == 4


def picture(scene: MapScene) -> dict[str, dict[str, Any]]:
    collection = json.loads(json.loads(scene.picture_geojson())["geojson"])
    check_geojson(collection)
    return {feature["id"]: feature for feature in collection["features"]}


def test_the_picture_holds_labels_trails_and_vectors_and_forgets_ended_tracks() -> None:
    scene = MapScene([SITE], trail_s=60.0, trail_spacing_s=4.0)
    for k in range(60):  # two minutes, an update every 2 s
        scene.update(track(time=T0 + 2 * k, lon=17.5 + 0.001 * k, callsign="DLH65A"), T0 + 2 * k)
    scene.update(track(8, time=T0 + 118, mode3a="7000", status="coasting"), T0 + 118)
    features = picture(scene)
    assert set(features) == {"track/7", "trail/7", "vector/7", "track/8", "vector/8"}
    point = features["track/7"]
    assert point["properties"]["name"] == "DLH65A FL--- 389kt"
    assert point["properties"]["style"]["color"] == "#2ecc40"
    assert features["track/8"]["properties"]["style"]["color"] == "#ffb000"
    trail = features["trail/7"]["geometry"]["coordinates"]
    # 60 s of trail at one point per 4 s, ending at the track's position.
    assert 15 <= len(trail) <= 17
    assert trail[-1] == [pytest.approx(17.5 + 0.059), 48.5]
    assert trail[0][0] == pytest.approx(17.5 + 0.001 * 30, abs=0.0025)
    vector = features["vector/7"]["geometry"]["coordinates"]
    assert vector[1][0] - vector[0][0] == pytest.approx(
        12_000 / (6_371_000 * 0.6626) * 57.2958, rel=0.01
    )
    # A track that moves after a picture is where it moved to in the next one.
    scene.update(track(8, time=T0 + 119, lon=17.7, mode3a="7000"), T0 + 119)
    moved = picture(scene)["track/8"]
    assert moved["geometry"]["coordinates"] == [17.7, 48.5]
    assert moved["properties"]["status"] == "confirmed"
    scene.update(track(time=T0 + 120, status="ended"), T0 + 120)
    assert set(picture(scene)) == {"track/8", "trail/8", "vector/8"}
    assert scene.live_tracks == [8]


def _canonical(text: bytes | str) -> str:
    """``text`` read and written back by ``json.dumps`` (compact): what the scene must
    write, every string escaped as ``json.dumps`` escapes it, every number its repr."""
    return json.dumps(json.loads(text), separators=(",", ":"))


def test_fixes_and_features_are_what_json_dumps_writes_of_awkward_identities() -> None:
    """Quotes, backslashes and non-ASCII characters in a callsign, a blank callsign, no
    identity at all, several radars: the fixes and the picture's features
    (written a row at a time, escaped in pieces) are ``json.dumps``'s own text."""
    scene = MapScene([SITE])
    odd = ("25/11", "7/3", "25/12")
    # The models hold callsigns to [A-Z0-9 ]; the map takes any text (``SystemValues``).
    messages = [
        SystemValues.of_message(track(3, radars=odd, mode3a="0017", flight_level=12.345))._replace(
            callsign='A"B\\C é\x01'
        ),
        SystemValues.of_message(
            track(4, radars=odd[1:], address="ABCDEF", status="coasting")
        )._replace(callsign="    "),
        SystemValues.of_message(track(5, radars=odd[:1], flight_level=-3.0)),
        SystemValues.of_message(track(6, duplicate_address=True, address="3C660C")),
    ]
    for k, message in enumerate(messages):
        for out in scene.update(message, T0 + k):
            assert out.data.decode() == _canonical(out.data)
            if out.topic == PICTURE_TOPIC:
                inner = json.loads(out.data)["geojson"]
                assert inner == _canonical(inner)
    features = picture(scene)
    assert features["track/3"]["properties"]["callsign"] == 'A"B\\C é\x01'
    assert features["track/3"]["properties"]["sources"] == ",".join(sorted(odd))
    assert features["vector/4"]["properties"]["name"] == "#4 FL--- 389kt 1 min"
    assert features["track/4"]["properties"]["callsign"] == ""
    assert "callsign" not in features["track/5"]["properties"]
    inner = json.loads(scene.picture_geojson())["geojson"]
    assert inner == _canonical(inner)


def test_sites_are_points_and_range_rings_of_their_range() -> None:
    sites = json.loads(json.loads(MapScene([SITE]).sites_geojson())["geojson"])
    check_geojson(sites)
    point, ring = sites["features"]
    assert point["geometry"]["coordinates"] == [17.2, 48.2]
    assert point["properties"]["name"] == "Alpha (25/11)"
    from pyproj import Geod

    geod = Geod(ellps="WGS84")
    for lon, lat in ring["geometry"]["coordinates"][0]:
        _, _, distance = geod.inv(17.2, 48.2, lon, lat)
        assert distance == pytest.approx(200 * 1852.0, rel=1e-6)


def test_periodic_messages_follow_data_time() -> None:
    scene = MapScene([SITE], picture_period_s=1.0, sites_period_s=10.0)
    topics = [m.topic for t in (0.0, 0.5, 1.0, 1.2, 2.1, 10.0) for m in scene.tick(T0 + t)]
    assert topics.count(PICTURE_TOPIC) == 4  # at 0, 1.0, 2.1, 10.0
    assert topics.count(RADARS_TOPIC) == 2  # at 0 and 10.0


@needs_sdk
def test_listen_errors_name_the_option_the_port_and_the_fix() -> None:
    assert parse_listen("127.0.0.1:8765") == ("127.0.0.1", 8765)
    with pytest.raises(FoxgloveListenError, match="expected HOST:PORT"):
        parse_listen("8765")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(FoxgloveListenError, match=rf"127.0.0.1:{port}: .*another port"):
            check_listen(f"127.0.0.1:{port}")


@pytest.fixture(scope="module")
def service_log(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first ``LOG_S`` of the bundled recording through the service, logged."""
    directory = tmp_path_factory.mktemp("log")
    source = open_replay(RECORDING)
    with McapLog(directory) as log:
        service = TrackerService(source.config, log_file=log)
        first = None
        for name, datagram in source.datagrams:
            assert datagram.time is not None
            first = datagram.time if first is None else first
            if datagram.time > first + LOG_S:
                break
            service.process(name, datagram)
        service.close()
    return directory


def test_the_log_holds_the_channels_in_foxglove_schemas(service_log: Path) -> None:
    [path] = sorted(service_log.glob("*.mcap"))
    with path.open("rb") as stream:
        reader = make_reader(stream)
        seen: dict[str, int] = {}
        labelled = set()
        for schema, channel, message in reader.iter_messages():
            if not channel.topic.startswith("/foxglove/"):
                continue
            assert schema is not None and schema.encoding == "jsonschema"
            assert channel.message_encoding == "json"
            # Each message against the schema the file itself carries.
            written = FoxgloveMessage(channel.topic, schema.name, message.data, 0.0)
            assert json.loads(schema.data) == SCHEMAS[schema.name]
            data = validate(written)
            seen[channel.topic] = seen.get(channel.topic, 0) + 1
            if channel.topic == TRACKS_TOPIC:
                if sdk is not None:
                    as_sdk_location_fix(data).encode()
                labelled.add(data["frame_id"])
    assert seen[TRACKS_TOPIC] > 200
    assert LOG_S / 4 - 1 <= seen[PICTURE_TOPIC] <= LOG_S / 4 + 1  # one a scan (4 s)
    assert seen[RADARS_TOPIC] == LOG_S // 10  # every 10 s
    assert len(labelled) > 10


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


async def receive_live(port: int, deadline: float) -> tuple[str, list[dict[str, Any]], Any]:
    """As the Foxglove app does: connect, read the advertised channels, subscribe to the
    tracks and receive one message (binary opcode 1: subscription id, log time, payload)."""
    websockets = pytest.importorskip("websockets", reason="websockets is in the [test] extra")

    while True:
        try:
            connection = await websockets.connect(
                f"ws://127.0.0.1:{port}", subprotocols=["foxglove.sdk.v1", "foxglove.websocket.v1"]
            )
            break
        except ConnectionRefusedError:  # not listening yet
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.2)
    async with connection as ws:
        subprotocol = str(ws.subprotocol)
        channels: dict[str, dict[str, Any]] = {}
        subscribed = False
        while time.monotonic() < deadline:
            frame = await asyncio.wait_for(ws.recv(), deadline - time.monotonic())
            if isinstance(frame, str):
                op = json.loads(frame)
                if op["op"] == "advertise":
                    channels.update({c["topic"]: c for c in op["channels"]})
                if TRACKS_TOPIC in channels and not subscribed:
                    request = {"id": 1, "channelId": channels[TRACKS_TOPIC]["id"]}
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": [request]}))
                    subscribed = True
                continue
            assert frame[0] == 1
            subscription, log_time = struct.unpack_from("<IQ", frame, 1)
            assert subscription == 1 and log_time > 1_700_000_000 * 10**9
            return subprotocol, list(channels.values()), json.loads(frame[13:])
    raise TimeoutError("no message from the live server")


@needs_sdk
def test_live_view_over_websocket(tmp_path: Path) -> None:
    port = free_port()
    process = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "tracker_service.cli",
            "replay",
            str(RECORDING),
            "--speed",
            "10",
            "--zenoh-listen",
            f"tcp/127.0.0.1:{free_port()}",
            "--foxglove-listen",
            f"127.0.0.1:{port}",
        ],
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        subprotocol, channels, fix = asyncio.run(receive_live(port, time.monotonic() + 60.0))
    except Exception as exc:
        process.terminate()
        raise AssertionError(f"the service said: {process.communicate(timeout=30)[1]}") from exc
    process.terminate()
    _, stderr = process.communicate(timeout=30)
    assert f"open ws://127.0.0.1:{port} in the Foxglove app" in stderr
    assert subprotocol == "foxglove.sdk.v1"
    by_topic = {c["topic"]: c for c in channels}
    assert by_topic[TRACKS_TOPIC]["schemaName"] == LOCATION_FIX
    assert by_topic[TRACKS_TOPIC]["schemaEncoding"] == "jsonschema"
    assert json.loads(by_topic[TRACKS_TOPIC]["schema"]) == SCHEMAS[LOCATION_FIX]
    assert by_topic[RADARS_TOPIC]["schemaName"] == GEOJSON
    validate(FoxgloveMessage(TRACKS_TOPIC, LOCATION_FIX, json.dumps(fix).encode(), 0.0))
    assert fix["frame_id"].startswith("track/")


def test_layout_opens_on_the_map_of_the_example_configuration() -> None:
    layout = json.loads((REPO / "config" / "foxglove" / "layout.json").read_text())
    panels = layout["configById"]
    first = layout["layout"]["first"]
    assert first.startswith("map!") and first in panels
    assert panels[first]["layer"] == "map"
    assert panels[first]["center"] == {"lat": 48.6, "lon": 18.6}
    # The uncoloured topic of earlier versions' logs is off; the scene's topics are on.
    assert "/map/system_tracks" in panels[first]["disabledTopics"]
    assert not {TRACKS_TOPIC, PICTURE_TOPIC, RADARS_TOPIC} & set(panels[first]["disabledTopics"])
    rest = [layout["layout"]["second"]["first"], layout["layout"]["second"]["second"]]
    assert all(name in panels for name in rest)


def test_scene_from_values_is_the_scene_from_models() -> None:
    """The batch path's ``SystemValues`` (an update's plain values) gives the scene's
    messages the model gives, byte for byte: fixes, labels, colours, pictures."""
    messages = [
        track(3, radars=("25/11",), callsign="AFR12   ", flight_level=99.6),
        track(4, status="coasting", mode3a="7000"),
        track(5, duplicate_address=True, address="3C660C"),
        track(3, time=T0 + 13.0, lat=48.51, radars=("25/11", "25/12", "25/13")),
        track(4, time=T0 + 14.0, status="ended"),
    ]
    from_models, from_values = MapScene([SITE]), MapScene([SITE])
    for m in messages:
        assert from_values.update(SystemValues.of_message(m), m.time) == (
            from_models.update(m, m.time)
        )
    assert from_values.picture_geojson() == from_models.picture_geojson()


def _ahead_reference(lon: float, lat: float, vx: float, vy: float) -> tuple[float, float]:
    """The speed vector's end in Python floats, the textbook way: the picture's values."""
    cos_lat = max(math.cos(math.radians(lat)), 1e-6)
    lon = lon + math.degrees(vx * 60.0 / (6_371_000.0 * cos_lat))
    lat = lat + math.degrees(vy * 60.0 / 6_371_000.0)
    return (round((lon + 180.0) % 360.0 - 180.0, 5), round(max(min(lat, 90.0), -90.0), 5))


def _bits(values: list[float]) -> list[int]:
    bits: list[int] = np.array(values, dtype=np.float64).view(np.int64).tolist()
    return bits


def test_picture_coordinates_are_pythons_round_and_math_to_the_bit() -> None:
    """The picture's coordinates, rounded and moved over arrays, are the floats Python's
    ``round(v, 5)`` and ``math`` give, bit for bit: anywhere, on the halves of the fifth
    decimal and next to them, at the wrap of longitude and the poles, non-finite."""
    rng = np.random.default_rng(12)
    n = 100_000
    lon, lat = rng.uniform(-180.0, 180.0, n), rng.uniform(-89.9, 89.9, n)
    halves = (rng.integers(-18_000_000, 18_000_000, 10_000) + 0.5) / 1e5
    edges = np.array(
        [0.0, -0.0, 1 / 64, -1 / 64, 179.999995, -179.999995, 90.0, 1e12, np.nan, np.inf, -np.inf]
    )
    samples: list[npt.NDArray[np.float64]] = [
        lon,
        lat,
        halves,
        np.nextafter(halves, np.inf),
        np.nextafter(halves, -np.inf),
        edges,
    ]
    for values in samples:
        assert _bits(_round5(values).tolist()) == _bits([round(v, 5) for v in values.tolist()])
    # Columns at once, as the picture rounds them: the same, Python's rounds in place.
    columns = np.column_stack((halves, np.nextafter(halves, np.inf), lon[: len(halves)]))
    columns[::7, 2] = np.nan
    rounded = _round5(columns)
    assert rounded.shape == columns.shape
    assert _bits(rounded.ravel().tolist()) == _bits([round(v, 5) for v in columns.ravel().tolist()])
    # In any layout: a Fortran-ordered copy rounds to the same values.
    fortran = _round5(np.asfortranarray(columns))
    assert _bits(fortran.ravel().tolist()) == _bits(rounded.ravel().tolist())
    lon = np.concatenate([lon, rng.uniform(179.9, 180.0, 1000), np.full(1000, -179.99999)])
    lat = np.concatenate([lat, rng.uniform(89.99, 90.0, 1000), rng.uniform(-90.0, -89.99, 1000)])
    vx, vy = rng.normal(0.0, 300.0, len(lon)), rng.normal(0.0, 300.0, len(lon))
    ahead_lon, ahead_lat = _round5(np.column_stack(_ahead(lon, lat, vx, vy))).T
    expected = list(map(_ahead_reference, lon.tolist(), lat.tolist(), vx.tolist(), vy.tolist()))
    assert _bits(ahead_lon.tolist()) == _bits([e[0] for e in expected])
    assert _bits(ahead_lat.tolist()) == _bits([e[1] for e in expected])
