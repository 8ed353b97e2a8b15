"""``tracker-service export``: a real service log exported and read back (json, xml.etree,
csv, pyarrow), compared with the log's own messages."""

from __future__ import annotations

import csv
import json
import xml.etree.ElementTree as ET
from collections import defaultdict
from collections.abc import Iterator
from datetime import datetime
from pathlib import Path
from typing import Any

import pytest
from pyproj import Geod

from tracker_service.cli import main
from tracker_service.export import COLUMNS, Point, by_track, read_tracks
from tracker_service.outputs.mcap_log import McapLog, read_log_messages
from tracker_service.outputs.messages import SystemTrackMessage, TrackSource
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import CONFIG_METADATA, open_replay

REPO = Path(__file__).resolve().parents[1]
RECORDING = REPO / "recordings" / "three_sites.mcap"
LOG_S = 40.0
TRAFFIC_COLUMNS = (
    "timestamp",
    "icao24",
    "callsign",
    "latitude",
    "longitude",
    "altitude",
    "groundspeed",
    "track",
    "vertical_rate",
    "squawk",
)
GEOD = Geod(ellps="WGS84")
KML = {"kml": "http://www.opengis.net/kml/2.2", "gx": "http://www.google.com/kml/ext/2.2"}


@pytest.fixture(scope="module")
def log_dir(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The first ``LOG_S`` of the bundled recording through the service, logged."""
    directory = tmp_path_factory.mktemp("log")
    source = open_replay(RECORDING)
    metadata = {CONFIG_METADATA: {"config": source.config.model_dump_json()}}
    with McapLog(directory, metadata=metadata) as log:
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


def logged(directory: Path, topic_prefix: str) -> list[dict[str, Any]]:
    return [
        m.data
        for path in sorted(directory.glob("*.mcap"))
        for m in read_log_messages(path)
        if m.topic.startswith(topic_prefix)
    ]


def updates_by_number(directory: Path) -> dict[int, list[dict[str, Any]]]:
    """The logged system-track messages per number, "ended" repeats left out."""
    tracks: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for data in logged(directory, "/system_tracks"):
        seen = tracks[data["number"]]
        if data["status"] == "ended" and seen and seen[-1]["time"] == data["time"]:
            continue
        seen.append(data)
    return tracks


def export(log_dir: Path, out: Path, fmt: str, *extra: str) -> str:
    assert main(["export", str(log_dir), "--format", fmt, "-o", str(out), *extra]) == 0
    return out.read_text(encoding="utf-8") if fmt != "parquet" else ""


def test_geojson_one_feature_per_track(log_dir: Path, tmp_path: Path) -> None:
    tracks = updates_by_number(log_dir)
    collection = json.loads(export(log_dir, tmp_path / "tracks.geojson", "geojson"))
    assert collection["type"] == "FeatureCollection"
    features = collection["features"]
    assert len(features) == len(tracks) > 10
    for feature in features:
        properties, geometry = feature["properties"], feature["geometry"]
        updates = tracks[properties["track_number"]]
        coordinates = geometry["coordinates"]
        if len(updates) == 1:
            assert geometry["type"] == "Point"
            coordinates = [coordinates]
        else:
            assert geometry["type"] == "LineString"
        assert len(coordinates) == len(updates) == len(properties["times"])
        for position, update in zip(coordinates, updates, strict=True):
            assert position[0] == pytest.approx(update["lon"], abs=1e-6)
            assert position[1] == pytest.approx(update["lat"], abs=1e-6)
            assert -180 <= position[0] <= 180 and -90 <= position[1] <= 90
        assert properties["flight_id"] == f"system/{properties['track_number']}"
        last = updates[-1]
        assert properties["icao24"] == (last["address"] and last["address"].lower())
        assert properties["squawk"] == last["mode3a"]
        assert properties["groundspeeds_kt"][-1] == pytest.approx(
            last["ground_speed_mps"] * 3600 / 1852, abs=0.06
        )
    assert any(f["properties"]["callsign"] for f in features)


def test_kml_one_placemark_per_track(log_dir: Path, tmp_path: Path) -> None:
    tracks = updates_by_number(log_dir)
    root = ET.fromstring(export(log_dir, tmp_path / "tracks.kml", "kml"))
    schema = root.find("kml:Document/kml:Schema", KML)
    assert schema is not None and schema.get("id") == "track_data"
    arrays = {f.get("name") for f in schema.findall("gx:SimpleArrayField", KML)}
    placemarks = root.findall("kml:Document/kml:Placemark", KML)
    assert len(placemarks) == len(tracks)
    for placemark in placemarks:
        data = {
            d.get("name"): d.findtext("kml:value", namespaces=KML)
            for d in placemark.iter(f"{{{KML['kml']}}}Data")
        }
        updates = tracks[int(data["track_number"] or -1)]
        track = placemark.find("gx:Track", KML)
        assert track is not None
        whens = [w.text for w in track.findall("kml:when", KML)]
        coords = [c.text.split() for c in track.findall("gx:coord", KML) if c.text]
        assert len(whens) == len(coords) == len(updates)
        lon, lat, _ = map(float, coords[0])
        assert (lon, lat) == (pytest.approx(updates[0]["lon"]), pytest.approx(updates[0]["lat"]))
        assert placemark.findtext("kml:name", namespaces=KML) == (
            data.get("callsign")
            or (data.get("squawk") and f"A{data['squawk']}")
            or data["flight_id"]
        )
        data_of = track.find("kml:ExtendedData/kml:SchemaData", KML)
        assert data_of is not None and data_of.get("schemaUrl") == "#track_data"
        values = data_of.findall("gx:SimpleArrayData", KML)
        assert {v.get("name") for v in values} == arrays
        assert all(len(list(v)) == len(updates) for v in values)


def test_csv_rows_in_traffic_columns(log_dir: Path, tmp_path: Path) -> None:
    tracks = updates_by_number(log_dir)
    rows = list(csv.DictReader(export(log_dir, tmp_path / "tracks.csv", "csv").splitlines()))
    assert tuple(rows[0]) == COLUMNS
    assert len(rows) == sum(map(len, tracks.values()))
    first = tracks[int(rows[0]["track_number"])][0]
    assert rows[0]["timestamp"] == first["time_iso"]
    assert float(rows[0]["latitude"]) == pytest.approx(first["lat"], abs=1e-6)
    if first["flight_level"] is not None:
        assert float(rows[0]["altitude"]) == pytest.approx(first["flight_level"] * 100)
    assert float(rows[0]["track"]) == pytest.approx(first["track_angle_deg"], abs=0.01)


def test_parquet_reads_back_with_traffic_columns(log_dir: Path, tmp_path: Path) -> None:
    pa = pytest.importorskip("pyarrow", reason="pyarrow is the [export] extra")
    import pyarrow.parquet as pq

    out = tmp_path / "tracks.parquet"
    export(log_dir, out, "parquet")
    table = pq.read_table(out)
    assert tuple(table.column_names[: len(TRAFFIC_COLUMNS)]) == TRAFFIC_COLUMNS
    assert table.schema.field("timestamp").type == pa.timestamp("us", tz="UTC")
    tracks = updates_by_number(log_dir)
    assert table.num_rows == sum(map(len, tracks.values()))
    rows = table.to_pylist()
    assert len({r["flight_id"] for r in rows}) == len(tracks)
    for row in rows[:50]:
        when = row["timestamp"].timestamp()
        update = min(tracks[row["track_number"]], key=lambda u: abs(u["time"] - when))
        assert update["time"] == pytest.approx(when, abs=2e-6)
        assert row["latitude"] == pytest.approx(update["lat"], abs=1e-6)
        assert row["groundspeed"] == pytest.approx(update["ground_speed_mps"] * 1.943844, abs=0.01)
        assert row["squawk"] == update["mode3a"]
        assert row["icao24"] == (update["address"] and update["address"].lower())


def test_local_tracks_of_every_radar(log_dir: Path, tmp_path: Path) -> None:
    messages = logged(log_dir, "/local_tracks/")
    rows = list(
        csv.DictReader(
            export(log_dir, tmp_path / "local.csv", "csv", "--tracks", "local").splitlines()
        )
    )
    assert (
        {r["source"] for r in rows}
        == {m["radar"] for m in messages}
        == {
            "25/11",
            "25/12",
            "25/13",
        }
    )
    assert len(rows) <= len(messages)
    assert {r["flight_id"].split("/")[0] for r in rows} == {"25_11", "25_12", "25_13"}
    # Converted from the log's system plane: a confirmed local track lies where a system
    # track is at about the same time: most within tens of metres (a wrong plane or an
    # axis swap gives tens of km); a few are not fused (a false or unseen track).
    by_second: dict[int, list[dict[str, Any]]] = defaultdict(list)
    for data in logged(log_dir, "/system_tracks"):
        by_second[int(data["time"])].append(data)
    distances = []
    for row in rows:
        if row["status"] != "confirmed":
            continue
        when = datetime.fromisoformat(row["timestamp"]).timestamp()
        near = [
            u
            for second in range(int(when) - 2, int(when) + 3)
            for u in by_second[second]
            if abs(u["time"] - when) <= 2.0
        ]
        if not near:
            continue
        distance = min(
            GEOD.inv(u["lon"], u["lat"], float(row["longitude"]), float(row["latitude"]))[2]
            for u in near
        )
        distances.append(distance)
    assert len(distances) > 100
    assert sorted(distances)[int(0.95 * len(distances))] < 2_000.0


def system_message(number: int, time: float, status: str = "confirmed") -> SystemTrackMessage:
    return SystemTrackMessage.from_state(
        time=time,
        x_m=0.0,
        y_m=0.0,
        vx_mps=100.0,
        vy_mps=0.0,
        covariance=[[1.0, 0, 0, 0], [0, 1.0, 0, 0], [0, 0, 1.0, 0], [0, 0, 0, 1.0]],
        number=number,
        lat=48.0,
        lon=17.0 + (time - 1e9) * 1e-3,
        sources=[TrackSource(radar="25/11", local_track=1, age_s=0.0)],
        status=status,
        mode3a="1234",
    )


def test_a_number_given_again_is_another_track(tmp_path: Path) -> None:
    with McapLog(tmp_path / "log") as log:
        for time, status in ((1e9, "confirmed"), (1e9 + 4, "confirmed"), (1e9 + 4, "ended")):
            log.log("/system_tracks", system_message(5, time, status), time)
        log.log("/system_tracks", system_message(5, 1e9 + 30), 1e9 + 30)
    points = list(read_tracks(tmp_path / "log"))
    assert [(p.flight_id, p.repeat, p.last) for p in points] == [
        ("system/5", False, False),
        ("system/5", False, False),
        ("system/5", True, True),
        ("system/5.2", False, False),
    ]
    assert [len(t) for t in by_track(points)] == [2, 1]


def test_a_track_is_written_when_it_ends_not_at_the_end_of_the_log(tmp_path: Path) -> None:
    read: list[float] = []

    def points() -> Iterator[Point]:
        for k in range(3):
            point = Point(
                "system/1",
                1,
                "system",
                float(k),
                48.0,
                17.0,
                None,
                None,
                1.0,
                0.0,
                None,
                None,
                None,
                None,
                "confirmed",
                last=k == 2,
            )
            read.append(point.time)
            yield point
        read.append(-1.0)  # the rest of the log

    tracks = by_track(points())
    assert len(next(tracks)) == 3
    assert read == [0.0, 1.0, 2.0]


def test_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    missing = tmp_path / "none.mcap"
    assert main(["export", str(missing), "--format", "csv", "-o", str(tmp_path / "o")]) == 2
    assert (
        capsys.readouterr().err.strip()
        == f"tracker-service export: {missing}: no such file or directory"
    )
    assert not (tmp_path / "o").exists()
    with McapLog(tmp_path / "bare", metadata={}) as log:
        log.log("/system_tracks", system_message(1, 1e9), 1e9)
    code = main(
        ["export", str(tmp_path / "bare"), "--format", "csv", "--tracks", "local", "-o", "x.csv"]
    )
    assert code == 2
    assert "not a log of tracker-service" in capsys.readouterr().err


def test_summary_line(log_dir: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "t.geojson"
    export(log_dir, out, "geojson")
    tracks = updates_by_number(log_dir)
    points = sum(map(len, tracks.values()))
    assert (
        capsys.readouterr().err
        == f"{out}: {len(tracks)} system tracks, {points} points (geojson)\n"
    )
