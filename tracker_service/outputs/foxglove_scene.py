"""The air picture as Foxglove's Map panel shows it: one identity, label, colour and
trail per system track, and the radar sites with their ranges.

``MapScene`` follows the system-track messages and makes, in Foxglove's well-known
schemas (JSON encoding, JSON schemas as Foxglove publishes them):

- ``/foxglove/tracks``: a ``foxglove.LocationFix`` per update, ``frame_id`` the track
  ("track/1234"), coloured by status and sources, its identity, label, level and speed in
  ``metadata`` (what the map's tooltip lists);
- ``/foxglove/picture``: a ``foxglove.GeoJSON`` every ``picture_period_s`` of data time,
  the whole picture: per live track a point named by its label (callsign or Mode 3/A code,
  flight level, ground speed), its trail over the last ``trail_s`` and a one-minute speed
  vector, each styled with the track's colour (``properties.style``: ``color``,
  ``weight``, ``opacity``, ``fillColor``, ``fillOpacity``, as the map panel's GeoJSON
  layer reads them);
- ``/foxglove/radars``: a ``foxglove.GeoJSON`` of the radar sites and their range rings,
  every ``sites_period_s`` (a client that joins late, or a log file cut by rotation, has
  them within that time).

Memory is bounded: per live track the text of its features in the picture (made with its
latest update) and at most ``trail_s / trail_spacing_s + 1`` trail points; an ended track
is forgotten.

Colours, from the display conventions of ATC situation displays: a track fused from two
or more sources green, one source blue, coasting amber, a Mode S address that another
live track also carries red.
"""

from __future__ import annotations

import json
import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from json.encoder import encode_basestring_ascii
from typing import Any, NamedTuple

import numpy as np
import numpy.typing as npt
from pyproj import Geod

from tracker_service.mcap_format import JSON_SCHEMA_DIALECT
from tracker_service.outputs.messages import SystemTrackMessage
from tracker_service.outputs.updates import (
    STATUSES,
    SystemBatch,
    SystemValues,
    python_json_numbers,
)

__all__ = [
    "CHANNELS",
    "GEOJSON",
    "LOCATION_FIX",
    "PICTURE_TOPIC",
    "RADARS_TOPIC",
    "SCHEMAS",
    "TRACKS_TOPIC",
    "FoxgloveMessage",
    "MapRadar",
    "MapScene",
    "track_colour",
    "track_label",
]

TRACKS_TOPIC = "/foxglove/tracks"
PICTURE_TOPIC = "/foxglove/picture"
RADARS_TOPIC = "/foxglove/radars"
LOCATION_FIX = "foxglove.LocationFix"
GEOJSON = "foxglove.GeoJSON"
CHANNELS = {TRACKS_TOPIC: LOCATION_FIX, PICTURE_TOPIC: GEOJSON, RADARS_TOPIC: GEOJSON}
"""Every topic the scene writes, with its schema."""

_NS_PER_S = 1_000_000_000
_METRES_PER_NM = 1852.0
_METRES_PER_FL = 30.48
_KT_PER_MPS = 3600.0 / 1852.0
_SPEED_VECTOR_S = 60.0
_EARTH_RADIUS_M = 6_371_000.0
_RING_POINTS = 72
_WGS84 = Geod(ellps="WGS84")

# foxglove.LocationFix as Foxglove's own JSON schema states it.
_LOCATION_FIX_SCHEMA: dict[str, Any] = {
    "$schema": JSON_SCHEMA_DIALECT,
    "title": LOCATION_FIX,
    "description": "A navigation satellite fix for any Global Navigation Satellite System",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "title": "time",
            "properties": {
                "sec": {"type": "integer", "minimum": 0},
                "nsec": {"type": "integer", "minimum": 0, "maximum": 999999999},
            },
            "description": "Timestamp of the message",
        },
        "frame_id": {"type": "string", "description": "Frame for the sensor."},
        "latitude": {"type": "number", "description": "Latitude in degrees"},
        "longitude": {"type": "number", "description": "Longitude in degrees"},
        "altitude": {"type": "number", "description": "Altitude in meters"},
        "position_covariance": {
            "type": "array",
            "items": {"type": "number"},
            "minItems": 9,
            "maxItems": 9,
            "description": "Position covariance (m^2) defined relative to a tangential "
            "plane through the reported position. The components are East, North, and Up "
            "(ENU), in row-major order.",
        },
        "position_covariance_type": {
            "title": "foxglove.PositionCovarianceType",
            "description": "If `position_covariance` is available, "
            "`position_covariance_type` must be set to indicate the type of covariance.",
            "oneOf": [
                {"title": "UNKNOWN", "const": 0},
                {"title": "APPROXIMATED", "const": 1},
                {"title": "DIAGONAL_KNOWN", "const": 2},
                {"title": "KNOWN", "const": 3},
            ],
        },
        "color": {
            "title": "foxglove.Color",
            "description": "Color used to visualize the location",
            "type": "object",
            "properties": {c: {"type": "number"} for c in ("r", "g", "b", "a")},
            "required": ["r", "g", "b", "a"],
        },
        "metadata": {
            "type": "array",
            "items": {
                "title": "foxglove.KeyValuePair",
                "type": "object",
                "properties": {"key": {"type": "string"}, "value": {"type": "string"}},
                "required": ["key", "value"],
            },
            "description": "Additional metadata of the fix (identity, label). Keys are unique.",
        },
    },
}

# The two schemas the map panel reads, with the fields Foxglove's schema of that name
# defines (the panel recognises the schema by its name, the fields by theirs); the tests
# check them against the Foxglove SDK's own message classes.
SCHEMAS: dict[str, dict[str, Any]] = {
    LOCATION_FIX: _LOCATION_FIX_SCHEMA,
    GEOJSON: {
        "title": GEOJSON,
        "description": "GeoJSON data for annotating maps",
        "type": "object",
        "properties": {"geojson": {"type": "string"}},
        "required": ["geojson"],
    },
}
_COVARIANCE_KNOWN = 3
_FIX = (
    '{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"track/%d","latitude":%s,"longitude":%s,'
    '"altitude":%s,"position_covariance":[%s,%s,0.0,%s,%s,0.0,0.0,0.0,1000000.0],'
    f'"position_covariance_type":{_COVARIANCE_KNOWN},'
    '"color":{"r":%s,"g":%s,"b":%s,"a":1.0},"metadata":[%s]}'
)
"""A ``foxglove.LocationFix`` as ``json.dumps`` writes it (compact): the plane's axes are
east and north near its centre; the vertical is not estimated, so large rather than zero."""
_ENDED = STATUSES.index("ended")

Rgb = tuple[float, float, float]
FloatArray = npt.NDArray[np.float64]
_MULTI: Rgb = (0.18, 0.8, 0.25)
_SINGLE: Rgb = (0.12, 0.56, 1.0)
_COASTING: Rgb = (1.0, 0.69, 0.0)
_DUPLICATE: Rgb = (0.9, 0.1, 0.1)
_ENDED_COLOUR: Rgb = (0.5, 0.5, 0.5)
_COLOUR_TEXT = {
    rgb: tuple(map(repr, rgb)) for rgb in (_MULTI, _SINGLE, _COASTING, _DUPLICATE, _ENDED_COLOUR)
}
"""Each colour's components as ``json.dumps`` writes them."""


class FoxgloveMessage(NamedTuple):
    """One message for a Foxglove channel: its topic, schema name (a key of
    ``SCHEMAS``), JSON payload and data time (POSIX s). A tuple: one a track update,
    made at a third of a frozen dataclass's cost."""

    topic: str
    schema: str
    data: bytes
    time: float


@dataclass(frozen=True)
class MapRadar:
    """A radar as the map shows it: its site and the range of its coverage ring."""

    key: str
    """ "SAC/SIC"."""
    name: str
    lat: float
    lon: float
    range_nm: float


def _map_track(track: SystemTrackMessage | SystemValues) -> SystemValues:
    return track if isinstance(track, SystemValues) else SystemValues.of_message(track)


def track_colour(track: SystemTrackMessage | SystemValues) -> Rgb:
    """See the module docstring."""
    m = _map_track(track)
    return _colour(m.status, m.duplicate_address, len(set(m.sources)))


def _colour(status: str, duplicate_address: bool, radars: int) -> Rgb:
    if status == "ended":
        return _ENDED_COLOUR
    if duplicate_address:
        return _DUPLICATE
    if status == "coasting":
        return _COASTING
    return _MULTI if radars >= 2 else _SINGLE


def track_label(track: SystemTrackMessage | SystemValues) -> str:
    """What an ATC label shows: callsign, else Mode 3/A code, else the track number;
    flight level; ground speed in knots. E.g. "DLH65A FL350 452kt", "A7000 FL--- 120kt"."""
    m = _map_track(track)
    return _label(m.number, m.callsign, m.mode3a, m.flight_level, m.ground_speed_mps)


def _label(
    number: int,
    callsign: str | None,
    mode3a: str | None,
    flight_level: float | None,
    ground_speed_mps: float,
) -> str:
    identity = (callsign or "").strip() or (f"A{mode3a}" if mode3a else f"#{number}")
    level = "FL---" if flight_level is None else f"FL{round(flight_level):03d}"
    return f"{identity} {level} {round(ground_speed_mps * _KT_PER_MPS)}kt"


def _identity_texts(
    number: int,
    status: str,
    callsign: str | None,
    mode3a: str | None,
    address: str | None,
    flight_level: float | None,
    ground_speed_mps: float,
    track_angle_deg: float,
    sources: str,
) -> tuple[str, str, str]:
    """What the map's tooltip lists of a track, as ``json.dumps`` writes it (compact):
    its fix's ``metadata`` items (label first; an item the track has no value for left
    out), its label's JSON string and the same items but the label as its point's
    properties (",key:value" each). One call a row, each text written once for both:
    ``sources`` is the JSON string of its radars' names."""
    label = encode_basestring_ascii(
        _label(number, callsign, mode3a, flight_level, ground_speed_mps)
    )
    items = f'{{"key":"label","value":{label}}},{{"key":"track","value":"{number}"}},'
    items += f'{{"key":"status","value":"{status}"}}'
    properties = f',"track":"{number}","status":"{status}"'
    if callsign:
        text = encode_basestring_ascii(callsign.strip())
        items += f',{{"key":"callsign","value":{text}}}'
        properties += f',"callsign":{text}'
    if mode3a:
        items += f',{{"key":"mode3a","value":"{mode3a}"}}'
        properties += f',"mode3a":"{mode3a}"'
    if address:
        items += f',{{"key":"address","value":"{address}"}}'
        properties += f',"address":"{address}"'
    if flight_level is not None:
        items += f',{{"key":"flight_level","value":"{flight_level:.2f}"}}'
        properties += f',"flight_level":"{flight_level:.2f}"'
    speed = f"{ground_speed_mps * _KT_PER_MPS:.0f}"
    angle = f"{track_angle_deg:.0f}"
    items += (
        f',{{"key":"ground_speed_kt","value":"{speed}"}},'
        f'{{"key":"track_angle_deg","value":"{angle}"}},{{"key":"sources","value":{sources}}}'
    )
    properties += f',"ground_speed_kt":"{speed}","track_angle_deg":"{angle}","sources":{sources}'
    return items, label, properties


class _MapColumns(NamedTuple):
    number: list[int]
    colours: list[Rgb]
    metadata: list[str]
    """Each row's fix's ``metadata`` items (``_identity_texts``)."""
    labels: list[str]
    """Each row's label as a JSON string."""
    properties: list[str]
    """Each row's point's properties but its name."""


class _LiveRows(NamedTuple):
    """What the picture shows of a batch's live rows, made with their fixes: per row its
    position rounded (the trail's point) and that point's JSON, and its three features as
    JSON escaped into the picture's string (the trail's without its coordinates, which
    only the track's trail gives)."""

    here: list[tuple[float, float]]
    point: list[str]
    marker: Sequence[str]
    """The point feature, escaped."""
    trail_start: Sequence[str]
    """The trail feature up to its coordinates, escaped."""
    trail_end: Sequence[str]
    """The trail feature after its coordinates, escaped."""
    vector: Sequence[str]
    """The speed vector feature, escaped."""


def _map_columns(batch: SystemBatch, rows: npt.NDArray[np.int64]) -> _MapColumns:
    """What the map shows of rows ``rows`` of ``batch``: numbers, colours and the
    identity texts (``_identity_texts``), a row at a time from its columns' values."""
    names, radar_names = batch.names, batch.radar_names
    number = batch.number[rows].tolist()
    status = [STATUSES[code] for code in batch.status[rows].tolist()]
    # Each row's sources' radars (by id), their distinct names sorted: few sets a batch.
    keys = [
        tuple(row[:n])
        for row, n in zip(
            batch.source_radar[rows].tolist(), batch.n_sources[rows].tolist(), strict=True
        )
    ]
    radars = {key: sorted({radar_names[r] for r in key}) for key in set(keys)}
    sources = {key: encode_basestring_ascii(",".join(radar)) for key, radar in radars.items()}
    texts = list(
        map(
            _identity_texts,
            number,
            status,
            [None if i < 0 else names[i] for i in batch.callsign[rows].tolist()],
            [None if c < 0 else f"{c:04o}" for c in batch.mode3a[rows].tolist()],
            [None if a < 0 else f"{a:06X}" for a in batch.address[rows].tolist()],
            [None if f != f else f for f in batch.flight_level[rows].tolist()],
            batch.ground_speed[rows].tolist(),
            batch.track_angle[rows].tolist(),
            [sources[key] for key in keys],
        )
    )
    colours = [
        _colour(state, duplicate, len(radars[key]))
        for state, duplicate, key in zip(
            status, batch.duplicate_address[rows].tolist(), keys, strict=True
        )
    ]
    metadata, labels, properties = (list(column) for column in zip(*texts, strict=True))
    return _MapColumns(number, colours, metadata, labels, properties)


def _hex(rgb: Rgb) -> str:
    return "#" + "".join(f"{round(c * 255):02x}" for c in rgb)


_COLOUR_HEX = {rgb: _hex(rgb) for rgb in _COLOUR_TEXT}


def _timestamp(time: float) -> dict[str, int]:
    # The fractional part of a float is exact: split off first, no 128 ns rounding.
    sec = math.floor(time)
    nsec = min(round((time - sec) * _NS_PER_S), _NS_PER_S - 1)
    return {"sec": max(sec, 0), "nsec": nsec}


def _dumps(value: object) -> bytes:
    return json.dumps(value, separators=(",", ":")).encode()


def _geojson(features: list[dict[str, Any]]) -> bytes:
    collection = {"type": "FeatureCollection", "features": features}
    return _dumps({"geojson": json.dumps(collection, separators=(",", ":"))})


_Point = tuple[float, float, float]


@dataclass(slots=True)
class _Track:
    trail: deque[_Point] = field(default_factory=deque)
    """(time, lon, lat), oldest first."""
    trail_points: deque[str] = field(default_factory=deque)
    """Its trail's points as JSON ([lon, lat]), in the same order."""
    features: bytes = b""
    """Its features in the picture (point, trail, vector), as JSON escaped into a JSON
    string (the picture's ``geojson``, ASCII), made at its latest update."""


class MapScene:
    """See the module docstring. ``update`` and ``tick`` return the messages that fall due;
    the scene's state follows only from the messages and times it is given."""

    def __init__(
        self,
        sites: Sequence[MapRadar],
        *,
        trail_s: float = 180.0,
        trail_spacing_s: float = 12.0,
        picture_period_s: float = 1.0,
        sites_period_s: float = 10.0,
    ) -> None:
        if trail_s < 0 or trail_spacing_s <= 0 or picture_period_s <= 0 or sites_period_s <= 0:
            raise ValueError("trail_s must be >= 0 and the periods and spacing positive")
        self.sites = list(sites)
        self.trail_s = trail_s
        self.trail_spacing_s = trail_spacing_s
        self.picture_period_s = picture_period_s
        self.sites_period_s = sites_period_s
        self._tracks: dict[int, _Track] = {}
        self._next_picture: float | None = None
        self._next_sites: float | None = None
        self._sites_payload: bytes | None = None

    @property
    def live_tracks(self) -> list[int]:
        return sorted(self._tracks)

    def update(
        self, update: SystemTrackMessage | SystemValues, time: float
    ) -> list[FoxgloveMessage]:
        """A system-track message at data time ``time``: its fix (none for "ended", whose
        track leaves the picture), then whatever periodic message falls due."""
        return self.updates(SystemBatch.of_values([_map_track(update)]), time)

    def updates(self, batch: SystemBatch, time: float) -> list[FoxgloveMessage]:
        """:meth:`update` of each row of ``batch`` in turn, all at data time ``time``; the
        fixes written for the whole batch at once."""
        fixes, shown = _location_fixes(batch)
        out: list[FoxgloveMessage] = []
        tracks = self._tracks
        rows = zip(
            batch.number.tolist(),
            (batch.status == _ENDED).tolist(),
            batch.time.tolist(),
            strict=True,
        )
        live = 0
        for k, (number, ended, at) in enumerate(rows):
            if ended:
                tracks.pop(number, None)
            else:
                track = tracks.get(number)
                if track is None:
                    track = tracks[number] = _Track()
                self._extend_trail(track, at, shown.here[live], shown.point[live])
                track.features = _track_features(track, shown, live)
                out.append(FoxgloveMessage(TRACKS_TOPIC, LOCATION_FIX, fixes[live], time))
                live += 1
            if k == 0:
                # Due once at most at this time: after the first update, as each update
                # at ``time`` would find it.
                out.extend(self.tick(time))
        return out

    def tick(self, time: float) -> list[FoxgloveMessage]:
        """Data time moves on to ``time``: the picture and the sites when due."""
        out = []
        due, self._next_sites = _due(self._next_sites, self.sites_period_s, time)
        if due:
            out.append(FoxgloveMessage(RADARS_TOPIC, GEOJSON, self.sites_geojson(), time))
        due, self._next_picture = _due(self._next_picture, self.picture_period_s, time)
        if due:
            out.append(FoxgloveMessage(PICTURE_TOPIC, GEOJSON, self.picture_geojson(), time))
        return out

    def _extend_trail(
        self, track: _Track, time: float, here: tuple[float, float], point: str
    ) -> None:
        """``here``: the update's position rounded as the picture's, ``point`` its JSON."""
        trail, points = track.trail, track.trail_points
        if not trail or time - trail[-1][0] >= self.trail_spacing_s:
            trail.append((time, *here))
            points.append(point)
        while trail and time - trail[0][0] > self.trail_s:
            trail.popleft()
            points.popleft()

    def location_fix(self, track: SystemTrackMessage | SystemValues) -> bytes:
        """The ``foxglove.LocationFix`` of one update (``location_fixes``)."""
        return self.location_fixes(SystemBatch.of_values([_map_track(track)]))[0]

    @staticmethod
    def location_fixes(batch: SystemBatch) -> list[bytes]:
        """The ``foxglove.LocationFix`` of each row of ``batch`` not ended, as
        ``json.dumps`` writes it (compact): ``frame_id`` the track, its colour, its
        identity and label in ``metadata``; the numbers of all of them written at once."""
        return _location_fixes(batch)[0]

    def picture_geojson(self) -> bytes:
        """Every live track's point, trail and vector, as one FeatureCollection: the
        features each track's latest update made, already escaped as the picture's string
        (``json.dumps`` escapes character by character: the escaped parts joined are the
        whole escaped), joined. Made with the updates rather than here: a picture of
        4,000 tracks is one join of bytes (4.8 MB copied once), not a spike of some 60 ms
        of formatting every period on the log's thread."""
        tracks = self._tracks
        # The features with a comma between each two, framed: one join.
        parts = [b","] * (2 * len(tracks) - 1)
        parts[::2] = [tracks[n].features for n in sorted(tracks)]
        return b"".join([_PICTURE_START, *parts, _PICTURE_END])

    def sites_geojson(self) -> bytes:
        if self._sites_payload is None:
            features: list[dict[str, Any]] = []
            for site in self.sites:
                name = f"{site.name} ({site.key})" if site.name else site.key
                features.append(
                    {
                        "type": "Feature",
                        "id": f"radar/{site.key}",
                        "geometry": {"type": "Point", "coordinates": [site.lon, site.lat]},
                        "properties": {
                            "name": name,
                            "radar": site.key,
                            "range_nm": site.range_nm,
                            "style": {"color": "#ffffff", "fillColor": "#ffffff", "weight": 2},
                        },
                    }
                )
                features.append(
                    {
                        "type": "Feature",
                        "id": f"range/{site.key}",
                        "geometry": {"type": "Polygon", "coordinates": [_ring(site)]},
                        "properties": {
                            "name": f"{name} {site.range_nm:g} NM",
                            "radar": site.key,
                            "style": {
                                "color": "#a0a0a0",
                                "weight": 1,
                                "opacity": 0.6,
                                "fillOpacity": 0.0,
                            },
                        },
                    }
                )
            self._sites_payload = _geojson(features)
        return self._sites_payload


def _location_fixes(batch: SystemBatch) -> tuple[list[bytes], _LiveRows]:
    """``MapScene.location_fixes``, and what the picture shows of the live rows."""
    live = np.flatnonzero(batch.status != _ENDED)
    if not live.size:
        return [], _LiveRows([], [], [], [], [], [])
    p = batch.covariance[live]
    level, altitude_m = batch.flight_level[live], batch.altitude_m[live]
    lat, lon = batch.lat[live], batch.lon[live]
    values = np.empty((live.size, 7))
    values[:, 0], values[:, 1] = lat, lon
    # The altitude the message gives, else its flight level's, else 0.
    values[:, 2] = np.where(
        np.isnan(altitude_m),
        np.where(np.isnan(level), 0.0, level * _METRES_PER_FL),
        altitude_m,
    )
    values[:, 3:5], values[:, 5:7] = p[:, 0:2], p[:, 4:6]
    if not np.isfinite(values).all():
        # Refused whole (``IsolatedSink`` counts it): a fix that is not JSON for the map.
        raise ValueError("a location must be finite")
    numbers = python_json_numbers(values.ravel().tolist())
    time = batch.time[live]
    sec = np.floor(time)
    # ``_timestamp``: the fraction split off first, no 128 ns rounding.
    nsec = np.minimum(np.rint((time - sec) * _NS_PER_S), _NS_PER_S - 1).astype(np.int64)
    shown = _map_columns(batch, live)
    fixes = [
        (
            _FIX
            % (
                second,
                nanosecond,
                n,
                *numbers[7 * k : 7 * k + 7],
                *_COLOUR_TEXT[colour],
                metadata,
            )
        ).encode()
        for k, (n, second, nanosecond, colour, metadata) in enumerate(
            zip(
                shown.number,
                np.maximum(sec, 0).astype(np.int64).tolist(),
                nsec.tolist(),
                shown.colours,
                shown.metadata,
                strict=True,
            )
        )
    ]
    return fixes, _live_rows(lon, lat, batch.vx[live], batch.vy[live], shown)


_PICTURE_START = (
    '{"geojson":"' + encode_basestring_ascii('{"type":"FeatureCollection","features":[')[1:-1]
).encode()
_PICTURE_END = b']}"}'


def _live_rows(
    lon: FloatArray, lat: FloatArray, vx: FloatArray, vy: FloatArray, shown: _MapColumns
) -> _LiveRows:
    """Each row's point (its identity as properties), the start and end of its trail and
    its one-minute vector, as ``json.dumps`` writes them (compact), escaped into the
    picture's string; the coordinates of all of them written at once."""
    values = np.empty((len(lon), 4))
    values[:, 0], values[:, 1] = lon, lat
    values[:, 2], values[:, 3] = _ahead(lon, lat, vx, vy)
    # Coordinates to 1e-5 degrees (about 1 m): the picture's size, not the log's
    # precision (/system_tracks has the full values). One call for the four columns.
    values = _round5(values)
    here_lon, here_lat = values[:, 0], values[:, 1]
    numbers = python_json_numbers(values.ravel().tolist())
    point = [f"[{x},{y}]" for x, y in zip(numbers[0::4], numbers[1::4], strict=True)]
    features = list(
        map(
            _features,
            shown.number,
            point,
            numbers[2::4],
            numbers[3::4],
            shown.labels,
            shown.properties,
            [_COLOUR_HEX[c] for c in shown.colours],
        )
    )
    marker, trail_start, trail_end, vector = zip(*features, strict=True)
    return _LiveRows(
        list(zip(here_lon.tolist(), here_lat.tolist(), strict=True)),
        point,
        marker,
        trail_start,
        trail_end,
        vector,
    )


def _escaped(text: str) -> str:
    """``text`` escaped into a JSON string, without the quotes."""
    return encode_basestring_ascii(text)[1:-1]


# A row's features, escaped into the picture's string once at import (``%s``: what each
# row gives, escaped itself where it is text).
_MARKER = _escaped(
    '{"type":"Feature","id":"track/%s","geometry":{"type":"Point","coordinates":%s},'
    '"properties":{"name":%s%s,"style":{"color":"%s","fillColor":"%s","fillOpacity":1.0}}}'
)
_TRAIL_START = _escaped(
    '{"type":"Feature","id":"trail/%s","geometry":{"type":"LineString","coordinates":['
)
_TRAIL_END = _escaped(
    ']},"properties":{"name":%s trail","style":{"color":"%s","weight":2,"opacity":0.5}}}'
)
_VECTOR = _escaped(
    '{"type":"Feature","id":"vector/%s","geometry":{"type":"LineString",'
    '"coordinates":[%s,[%s,%s]]},"properties":{"name":%s 1 min",'
    '"style":{"color":"%s","weight":1,"opacity":0.9}}}'
)


def _features(
    number: int, point: str, ahead_lon: str, ahead_lat: str, name: str, properties: str, colour: str
) -> tuple[str, str, str, str]:
    """A row's point (``name``: its label's JSON string), the start and end of its trail
    and its vector, each escaped into the picture's string (``json.dumps`` escapes
    character by character: the escaped parts joined are the whole escaped, so the
    templates are escaped once and each row's texts, name and properties, alone; numbers,
    brackets and colours need none). With " trail" or " 1 min" added before its closing
    quote, a label's JSON string is the longer name's: the escaped name without its
    escaped closing quote (two characters)."""
    label = _escaped(name)
    opened = label[:-2]
    return (
        _MARKER % (number, point, label, _escaped(properties), colour, colour),
        _TRAIL_START % number,
        _TRAIL_END % (opened, colour),
        _VECTOR % (number, point, ahead_lon, ahead_lat, opened, colour),
    )


def _track_features(track: _Track, shown: _LiveRows, k: int) -> bytes:
    """A track's features in the picture after its update, row ``k`` of ``shown``: its
    point, its trail (with the point when the trail does not end there yet; none under
    two points) and its vector, escaped. The trail's points need no escaping (numbers,
    brackets, commas)."""
    trail, points = track.trail_points, len(track.trail_points)
    # Float by float: a tuple's == takes the same object (the one the trail just stored)
    # as equal even when it is a NaN, which the float's == does not.
    lon, lat = shown.here[k]
    if points and track.trail[-1][1] == lon and track.trail[-1][2] == lat:
        line = ",".join(trail)
    else:
        line = ",".join([*trail, shown.point[k]])
        points += 1
    if points < 2:
        return f"{shown.marker[k]},{shown.vector[k]}".encode()
    return (
        f"{shown.marker[k]},{shown.trail_start[k]}{line}{shown.trail_end[k]},{shown.vector[k]}"
    ).encode()


def _due(next_time: float | None, period: float, time: float) -> tuple[bool, float | None]:
    """Whether a periodic message is due at ``time``, and when the next one is: on a grid
    of ``period`` from the first (a quiet spell makes no burst, a late call no drift)."""
    if next_time is None:
        return True, time + period
    if time < next_time:
        return False, next_time
    return True, next_time + period * (math.floor((time - next_time) / period) + 1)


_RADIANS_PER_DEGREE = math.pi / 180.0
"""``math.radians``' factor (CPython multiplies by it)."""
_DEGREES_PER_RADIAN = 180.0 / math.pi
"""``math.degrees``' factor."""


def _ahead(
    lon: FloatArray, lat: FloatArray, vx_mps: FloatArray, vy_mps: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Where each track is in one minute at its velocity (the plane's axes taken as east
    and north: a display's speed vector, not a prediction), unrounded: the
    values of the scalar formula in Python floats (``math``), operation for operation
    (numpy's arithmetic is IEEE's, as Python's; the cosine is ``math.cos``, numpy's may
    differ in its last bit)."""
    d_north = vy_mps * _SPEED_VECTOR_S
    d_east = vx_mps * _SPEED_VECTOR_S
    cosines = np.fromiter(
        map(math.cos, (lat * _RADIANS_PER_DEGREE).tolist()), dtype=np.float64, count=len(lat)
    )
    cos_lat = np.maximum(cosines, 1e-6)
    ahead_lon = lon + d_east / (_EARTH_RADIUS_M * cos_lat) * _DEGREES_PER_RADIAN
    ahead_lat = lat + d_north / _EARTH_RADIUS_M * _DEGREES_PER_RADIAN
    with np.errstate(invalid="ignore"):
        wrapped = np.remainder(ahead_lon + 180.0, 360.0) - 180.0
    return wrapped, np.maximum(np.minimum(ahead_lat, 90.0), -90.0)


_TIE_MARGIN = 1e-6
"""How near a half ``_round5`` leaves a scaled value to Python: its product with 1e5 is
off the exact one by at most 2**-23 below 2**30."""


def _round5(values: FloatArray) -> FloatArray:
    """``round(v, 5)`` of each value, the same float: Python rounds the exact binary value
    to 5 decimals (half to even) and reads the decimal back; the nearest integer of
    ``v * 1e5`` divided by 1e5 is that float wherever the product cannot be on the other
    side of a half from the exact one, and Python rounds the rest (non-finite values, huge
    ones, and those within ``_TIE_MARGIN`` of a half)."""
    scaled = values * 1e5
    rounded = np.rint(scaled) / 1e5
    with np.errstate(invalid="ignore"):
        safe = (np.abs(scaled) < 2.0**30) & (np.abs(scaled - np.floor(scaled) - 0.5) > _TIE_MARGIN)
    if not safe.all():
        # Flat indices: any shape and layout of array (``flat`` writes through).
        for i in np.flatnonzero(~safe).tolist():
            rounded.flat[i] = round(float(values.flat[i]), 5)
    return rounded


def _ring(site: MapRadar) -> list[list[float]]:
    """The geodesic circle of the site's range, closed, counter-clockwise (RFC 7946)."""
    azimuths = [360.0 - 360.0 * k / _RING_POINTS for k in range(_RING_POINTS)]
    lons, lats, _ = _WGS84.fwd(
        [site.lon] * _RING_POINTS,
        [site.lat] * _RING_POINTS,
        azimuths,
        [site.range_nm * _METRES_PER_NM] * _RING_POINTS,
    )
    ring = [[float(lon), float(lat)] for lon, lat in zip(lons, lats, strict=True)]
    return [*ring, ring[0]]
