"""``tracker-service export``: the tracks of a service log as GeoJSON, KML, CSV or Parquet.

One feature (GeoJSON), placemark (KML) or set of rows (CSV, Parquet) per track, with
time, position (WGS84 degrees), level, speed and identity, read from the log's
``/system_tracks`` or ``/local_tracks/<SAC>_<SIC>`` channels in file order. The columns
of CSV and Parquet are the ones the ``traffic`` library reads (``timestamp``, ``icao24``,
``callsign``, ``latitude``, ``longitude``, ``altitude``, ``groundspeed``, ``track``,
``vertical_rate``, ``squawk``, in its units: ft, kt, deg, ft/min), then ``flight_id``
(one per track: ``traffic`` makes one ``Flight`` of each) and the track's own fields.

Streaming: CSV and Parquet rows go out as they are read (Parquet in row groups of
``ROW_GROUP`` rows); a GeoJSON feature or KML placemark is written when its track ends,
so that memory holds the points of the live tracks only, never the whole log.

A track number the fuser (or a radar) gives again after the track ended is a new track:
its ``flight_id`` carries a suffix (``system/12``, then ``system/12.2``).
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import sys
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, replace
from datetime import UTC, datetime
from pathlib import Path
from typing import IO, Any, Literal, Protocol
from xml.sax.saxutils import escape

from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.mcap_log import read_log_messages, read_log_metadata
from tracker_service.service.config import ConfigError, ServiceConfig

__all__ = ["COLUMNS", "FORMATS", "Point", "add_arguments", "export", "read_tracks", "run"]

FORMATS = ("geojson", "kml", "csv", "parquet")
TrackKind = Literal["system", "local"]
COLUMNS = (
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
    "flight_id",
    "track_number",
    "source",
    "status",
)
"""The ``traffic`` library's columns (its units: altitude ft, groundspeed kt, track deg,
vertical_rate ft/min), then this service's: the track, its source (the radar "SAC/SIC"
of a local track, "system" otherwise) and its status."""
ROW_GROUP = 65_536
_LOCAL_BATCH = 4096
_KT_PER_MPS = 3600.0 / 1852.0
_FT_PER_FL = 100.0
_METRES_PER_FL = 30.48
_CONFIG_METADATA = "service"  # service.replay.CONFIG_METADATA, without its imports


@dataclass(frozen=True)
class Point:
    """One update of a track, in the export's units."""

    flight_id: str
    track_number: int
    source: str
    time: float
    lat: float
    lon: float
    altitude_ft: float | None
    """Pressure altitude (flight level x 100), as ``traffic`` and ADS-B give it."""
    altitude_m: float | None
    """Above mean sea level where the log has it (QNH), else the pressure altitude."""
    groundspeed_kt: float
    track_deg: float
    vertical_rate_fpm: float | None
    squawk: str | None
    icao24: str | None
    callsign: str | None
    status: str
    last: bool
    """The track's last update (ended or deleted)."""
    repeat: bool = False
    """A last message with no new state: it only ends the track (see ``read_tracks``)."""

    def row(self) -> tuple[object, ...]:
        return (
            _iso(self.time),
            self.icao24,
            self.callsign,
            self.lat,
            self.lon,
            self.altitude_ft,
            self.groundspeed_kt,
            self.track_deg,
            self.vertical_rate_fpm,
            self.squawk,
            self.flight_id,
            self.track_number,
            self.source,
            self.status,
        )


def _iso(time: float) -> str:
    return datetime.fromtimestamp(time, UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def log_files(path: Path) -> list[Path]:
    """A log file, or the files of a log directory in name (= time) order."""
    if path.is_dir():
        files = sorted(path.glob("*.mcap"))
        if not files:
            raise ValueError(f"{path}: a directory without .mcap files")
        return files
    if not path.is_file():
        raise ValueError(f"{path}: no such file or directory")
    return [path]


def _plane(path: Path) -> SystemPlane:
    """The system plane of the service that wrote ``path`` (its configuration metadata)."""
    text = read_log_metadata(path).get(_CONFIG_METADATA, {}).get("config")
    if text is None:
        raise ValueError(
            f"{path}: no service configuration in its metadata: not a log of tracker-service"
        )
    system = ServiceConfig.model_validate_json(text).system
    return SystemPlane(system.centre_lat, system.centre_lon, system.projection)


class _Numbering:
    """A flight_id per track: a number given again after its track ended is a new one."""

    def __init__(self, prefix: str) -> None:
        self.prefix = prefix
        self._live: dict[int, str] = {}
        self._used: dict[int, int] = {}

    def id_of(self, number: int) -> str:
        live = self._live.get(number)
        if live is None:
            count = self._used[number] = self._used.get(number, 0) + 1
            live = f"{self.prefix}/{number}" + ("" if count == 1 else f".{count}")
            self._live[number] = live
        return live

    def end(self, number: int) -> None:
        self._live.pop(number, None)


def _system_point(data: dict[str, Any], numbering: _Numbering) -> Point:
    number = int(data["number"])
    flight_id = numbering.id_of(number)
    last = data["status"] == "ended"
    if last:
        numbering.end(number)
    level = data.get("flight_level")
    altitude_m = data.get("altitude_m")
    address = data.get("address")
    callsign = data.get("callsign")
    return Point(
        flight_id=flight_id,
        track_number=number,
        source="system",
        time=float(data["time"]),
        lat=round(float(data["lat"]), 7),
        lon=round(float(data["lon"]), 7),
        altitude_ft=None if level is None else level * _FT_PER_FL,
        altitude_m=altitude_m if altitude_m is not None else _level_m(level),
        groundspeed_kt=round(float(data["ground_speed_mps"]) * _KT_PER_MPS, 2),
        track_deg=round(float(data["track_angle_deg"]), 2),
        vertical_rate_fpm=data.get("climb_rate_fpm"),
        squawk=data.get("mode3a"),
        icao24=None if address is None else address.lower(),
        callsign=None if callsign is None else callsign.strip() or None,
        status=data["status"],
        last=last,
    )


def _level_m(level: float | None) -> float | None:
    return None if level is None else level * _METRES_PER_FL


def _local_points(
    batch: list[dict[str, Any]], plane: SystemPlane, numberings: dict[str, _Numbering]
) -> Iterator[Point]:
    lat, lon = plane.to_geodetic([d["x_m"] for d in batch], [d["y_m"] for d in batch])
    for k, data in enumerate(batch):
        radar = data["radar"]
        numbering = numberings.get(radar)
        if numbering is None:
            numbering = numberings[radar] = _Numbering(radar.replace("/", "_"))
        number = int(data["number"])
        flight_id = numbering.id_of(number)
        last = data["status"] == "deleted"
        if last:
            numbering.end(number)
        vx, vy = float(data["vx_mps"]), float(data["vy_mps"])
        level = data.get("flight_level")
        address = data.get("address")
        yield Point(
            flight_id=flight_id,
            track_number=number,
            source=radar,
            time=float(data["time"]),
            lat=round(float(lat[k]), 7),
            lon=round((float(lon[k]) + 180.0) % 360.0 - 180.0, 7),
            altitude_ft=None if level is None else level * _FT_PER_FL,
            altitude_m=_level_m(level),
            groundspeed_kt=round(math.hypot(vx, vy) * _KT_PER_MPS, 2),
            # Clockwise from the system plane's north, as the system tracks' track angle.
            track_deg=round(math.degrees(math.atan2(vx, vy)) % 360.0, 2),
            vertical_rate_fpm=data.get("climb_rate_fpm"),
            squawk=data.get("mode3a"),
            icao24=None if address is None else address.lower(),
            callsign=None,
            status=data["status"],
            last=last,
        )


def read_tracks(path: Path, tracks: TrackKind = "system") -> Iterator[Point]:
    """Every update of the log's system (or local) tracks, in file order. A last message
    ("ended", "deleted") that only repeats its track's latest state comes with
    ``repeat`` set: it ends the track, and the writers give it no point of its own."""
    latest: dict[str, float] = {}
    for point in _read_points(path, tracks):
        before = latest.pop(point.flight_id, None) if point.last else None
        if not point.last:
            latest[point.flight_id] = point.time
        yield replace(point, repeat=True) if before == point.time else point


def _read_points(path: Path, tracks: TrackKind) -> Iterator[Point]:
    if tracks == "system":
        numbering = _Numbering("system")
        for file in log_files(path):
            for message in read_log_messages(file):
                if message.topic == "/system_tracks":
                    yield _system_point(message.data, numbering)
        return
    numberings: dict[str, _Numbering] = {}
    for file in log_files(path):
        plane = _plane(file)
        batch: list[dict[str, Any]] = []
        for message in read_log_messages(file):
            if message.topic.startswith("/local_tracks/"):
                batch.append(message.data)
                if len(batch) >= _LOCAL_BATCH:
                    yield from _local_points(batch, plane, numberings)
                    batch = []
        if batch:
            yield from _local_points(batch, plane, numberings)


@dataclass
class _Track:
    points: list[Point] = field(default_factory=list)


def by_track(points: Iterable[Point]) -> Iterator[list[Point]]:
    """The points of each track, once it ends (the live ones at the end of the log, in
    the order they began)."""
    live: dict[str, _Track] = {}
    for point in points:
        track = live.get(point.flight_id)
        if track is None:
            track = live[point.flight_id] = _Track()
        if not point.repeat:
            track.points.append(point)
        if point.last:
            del live[point.flight_id]
            if track.points:
                yield track.points
    for track in live.values():
        if track.points:
            yield track.points


class _Writer(Protocol):
    def __call__(self, points: Iterable[Point], out: Path) -> tuple[int, int]: ...


def _identity(first: Point, points: list[Point]) -> dict[str, Any]:
    """A track's identity: the latest callsign, code and address it had."""
    callsign = next((p.callsign for p in reversed(points) if p.callsign), None)
    squawk = next((p.squawk for p in reversed(points) if p.squawk), None)
    icao24 = next((p.icao24 for p in reversed(points) if p.icao24), None)
    return {
        "flight_id": first.flight_id,
        "track_number": first.track_number,
        "source": first.source,
        "callsign": callsign,
        "squawk": squawk,
        "icao24": icao24,
        "start": _iso(first.time),
        "stop": _iso(points[-1].time),
    }


def _name(identity: dict[str, Any]) -> str:
    return (
        str(identity["callsign"] or (identity["squawk"] and f"A{identity['squawk']}") or "")
        or (identity["flight_id"])
    )


def _text(value: object) -> str:
    return "" if value is None else str(value)


def _coordinate(p: Point) -> list[float]:
    return [p.lon, p.lat] if p.altitude_m is None else [p.lon, p.lat, p.altitude_m]


def write_geojson(points: Iterable[Point], out: Path) -> tuple[int, int]:
    """A FeatureCollection, one feature per track: a LineString (a Point for a track of
    one update) in lon, lat, altitude (m), with its identity and, per coordinate, its
    time (``times``), ground speed, flight level and vertical rate."""
    tracks = n = 0
    with out.open("w", encoding="utf-8") as stream:
        stream.write('{"type":"FeatureCollection","features":[\n')
        for track in by_track(points):
            first = track[0]
            coordinates = [_coordinate(p) for p in track]
            geometry = (
                {"type": "Point", "coordinates": coordinates[0]}
                if len(track) == 1
                else {"type": "LineString", "coordinates": coordinates}
            )
            identity = _identity(first, track)
            properties = {
                **identity,
                "name": _name(identity),
                "times": [_iso(p.time) for p in track],
                "flight_levels": [
                    None if p.altitude_ft is None else p.altitude_ft / _FT_PER_FL for p in track
                ],
                "groundspeeds_kt": [round(p.groundspeed_kt, 1) for p in track],
                "vertical_rates_fpm": [p.vertical_rate_fpm for p in track],
            }
            feature = {"type": "Feature", "geometry": geometry, "properties": properties}
            stream.write(("," if tracks else "") + json.dumps(feature, separators=(",", ":")))
            stream.write("\n")
            tracks += 1
            n += len(track)
        stream.write("]}\n")
    return tracks, n


_KML_ARRAYS = (
    ("flight_level", "FL"),
    ("groundspeed_kt", "GS (kt)"),
    ("vertical_rate_fpm", "VS (ft/min)"),
)
_KML_SCHEMA = (
    '<Schema id="track_data">\n'
    + "".join(
        f'<gx:SimpleArrayField name="{name}" type="float">'
        f"<displayName>{escape(shown)}</displayName></gx:SimpleArrayField>\n"
        for name, shown in _KML_ARRAYS
    )
    + "</Schema>\n"
)
_KML_HEAD = """<?xml version="1.0" encoding="UTF-8"?>
<kml xmlns="http://www.opengis.net/kml/2.2" xmlns:gx="http://www.google.com/kml/ext/2.2">
<Document>
<name>{name}</name>
{schema}"""


def write_kml(points: Iterable[Point], out: Path) -> tuple[int, int]:
    """One Placemark per track: a ``gx:Track`` (a time and a coordinate per update,
    absolute altitude in m) named by its callsign or code, its identity, level and speed
    per update in ``ExtendedData``."""
    tracks = n = 0
    with out.open("w", encoding="utf-8") as stream:
        stream.write(_KML_HEAD.format(name=escape(out.stem), schema=_KML_SCHEMA))
        for track in by_track(points):
            identity = _identity(track[0], track)
            stream.write(f"<Placemark><name>{escape(_name(identity))}</name>\n")
            stream.write(
                f"<TimeSpan><begin>{identity['start']}</begin><end>{identity['stop']}</end>"
                "</TimeSpan>\n<ExtendedData>\n"
            )
            for key, value in identity.items():
                if value is not None:
                    stream.write(f'<Data name="{key}"><value>{escape(str(value))}</value></Data>\n')
            stream.write("</ExtendedData>\n<gx:Track><altitudeMode>absolute</altitudeMode>\n")
            for p in track:
                stream.write(f"<when>{_iso(p.time)}</when>\n")
            for p in track:
                stream.write(f"<gx:coord>{p.lon} {p.lat} {p.altitude_m or 0.0}</gx:coord>\n")
            stream.write('<ExtendedData><SchemaData schemaUrl="#track_data">\n')
            for name, values in (
                ("flight_level", [p.altitude_ft and p.altitude_ft / _FT_PER_FL for p in track]),
                ("groundspeed_kt", [round(p.groundspeed_kt, 1) for p in track]),
                ("vertical_rate_fpm", [p.vertical_rate_fpm for p in track]),
            ):
                stream.write(f'<gx:SimpleArrayData name="{name}">')
                stream.write(
                    "".join(f"<gx:value>{'' if v is None else v}</gx:value>" for v in values)
                )
                stream.write("</gx:SimpleArrayData>\n")
            stream.write("</SchemaData></ExtendedData>\n</gx:Track></Placemark>\n")
            tracks += 1
            n += len(track)
        stream.write("</Document>\n</kml>\n")
    return tracks, n


def write_csv(points: Iterable[Point], out: Path) -> tuple[int, int]:
    """A header of ``COLUMNS``, a row per update; empty where a value is unknown."""
    seen: set[str] = set()
    n = 0
    with out.open("w", encoding="utf-8", newline="") as stream:
        writer = csv.writer(stream)
        writer.writerow(COLUMNS)
        for p in points:
            if p.repeat:
                continue
            writer.writerow(["" if v is None else v for v in p.row()])
            seen.add(p.flight_id)
            n += 1
    return len(seen), n


def write_parquet(points: Iterable[Point], out: Path) -> tuple[int, int]:
    """``COLUMNS`` with ``timestamp`` a UTC timestamp (µs), the rest typed; row groups of
    ``ROW_GROUP`` rows. Needs pyarrow (``pip install 'tracker-service[export]'``)."""
    try:
        import pyarrow as pa
        import pyarrow.parquet as pq
    except ImportError:
        raise ValueError(
            "--format parquet needs pyarrow: pip install 'tracker-service[export]'"
        ) from None
    schema = pa.schema(
        [
            ("timestamp", pa.timestamp("us", tz="UTC")),
            ("icao24", pa.string()),
            ("callsign", pa.string()),
            ("latitude", pa.float64()),
            ("longitude", pa.float64()),
            ("altitude", pa.float64()),
            ("groundspeed", pa.float64()),
            ("track", pa.float64()),
            ("vertical_rate", pa.float64()),
            ("squawk", pa.string()),
            ("flight_id", pa.string()),
            ("track_number", pa.int32()),
            ("source", pa.string()),
            ("status", pa.string()),
        ]
    )
    seen: set[str] = set()
    n = 0
    columns: list[list[Any]] = [[] for _ in COLUMNS]

    def flush(writer: Any) -> None:
        columns[0] = [round(t * 1e6) for t in columns[0]]
        writer.write_table(pa.Table.from_arrays(columns, schema=schema))
        for column in columns:
            column.clear()

    with pq.ParquetWriter(out, schema) as writer:
        for p in points:
            if p.repeat:
                continue
            for column, value in zip(columns, (p.time, *p.row()[1:]), strict=True):
                column.append(value)
            seen.add(p.flight_id)
            n += 1
            if len(columns[0]) >= ROW_GROUP:
                flush(writer)
        if columns[0] or n == 0:
            flush(writer)
    return len(seen), n


WRITERS: dict[str, _Writer] = {
    "geojson": write_geojson,
    "kml": write_kml,
    "csv": write_csv,
    "parquet": write_parquet,
}


def export(log: Path, out: Path, fmt: str, tracks: TrackKind = "system") -> tuple[int, int]:
    """Writes the log's tracks into ``out``; (tracks, points) written."""
    files = log_files(log)  # a missing log is an error before ``out`` is created
    if tracks == "local":
        _plane(files[0])
    return WRITERS[fmt](read_tracks(log, tracks), out)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("log", help="a log of the service (.mcap, or a directory of logs)")
    parser.add_argument("--format", required=True, choices=FORMATS, help="output format")
    parser.add_argument(
        "--tracks",
        choices=("system", "local"),
        default="system",
        help="the fused system tracks (default) or every radar's local tracks",
    )
    parser.add_argument("-o", "--output", required=True, help="the file to write")


def run(args: argparse.Namespace, stderr: IO[str] | None = None) -> int:
    stderr = stderr or sys.stderr
    out = Path(args.output)
    try:
        tracks, points = export(Path(args.log), out, args.format, args.tracks)
    except (ValueError, ConfigError, OSError) as exc:
        print(f"tracker-service export: {exc}", file=stderr)
        return 2
    print(f"{out}: {tracks} {args.tracks} tracks, {points} points ({args.format})", file=stderr)
    return 0
