"""Track updates as plain data with their JSON already written: the batch path of the
outputs, without a pydantic model per update.

``MessageMapper.local_updates`` and ``MessageMapper.system_updates`` (``mapping.py``) turn
the chain's rows into these, and the sinks carry a whole batch in one call
(``sink.BatchSink``). Each update's JSON is written here, straight from its values, in the
field order of its pydantic model (``LocalTrackMessage``, ``SystemTrackMessage``; a test
holds the writers to the models' fields and to their ``model_dump_json``, field by field);
the model itself is built only where a consumer asks for one (``message()``: the picture,
a sink without batch support).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from tracker_service.outputs.messages import (
    LastPlot,
    LocalTrackMessage,
    SensorAges,
    SystemTrackMessage,
    TrackSource,
)

__all__ = [
    "LOCAL_FIELDS",
    "SYSTEM_FIELDS",
    "LocalUpdate",
    "LocationFix",
    "SystemUpdate",
    "local_json",
    "location_of",
    "system_json",
    "system_model",
]

_METRES_PER_FL = 30.48

LOCAL_FIELDS = (
    "radar",
    "number",
    "time",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "covariance",
    "flight_level",
    "climb_rate_fpm",
    "status",
    "plot_id",
    "mode3a",
    "address",
    "model_probabilities",
)
"""The order ``local_json`` writes: ``LocalTrackMessage``'s (checked by a test)."""

SYSTEM_FIELDS = (
    "number",
    "time",
    "time_iso",
    "lat",
    "lon",
    "altitude_m",
    "flight_level",
    "x_m",
    "y_m",
    "vx_mps",
    "vy_mps",
    "ground_speed_mps",
    "track_angle_deg",
    "climb_rate_fpm",
    "covariance",
    "position_sigma_m",
    "address",
    "callsign",
    "mode3a",
    "mode3a_changed",
    "first",
    "sources",
    "status",
    "last_plot",
    "ages",
    "duplicate_address",
)
"""The order ``system_json`` writes: ``SystemTrackMessage``'s (checked by a test)."""


def _optional(value: float | int | None) -> str:
    return "null" if value is None else repr(value)


def _number(value: float | None) -> str:
    """A JSON number; None and the non-finite (which JSON lacks) as null, as pydantic."""
    return "null" if value is None or not math.isfinite(value) else repr(value)


def _quoted(value: str | None) -> str:
    """A string of the messages' own character sets (radar keys, hex, octal): no escapes."""
    return "null" if value is None else f'"{value}"'


@lru_cache(maxsize=65536)
def _callsign(value: str | None) -> str:
    return "null" if value is None else json.dumps(value)


_COVARIANCE = "[[%r,%r,%r,%r],[%r,%r,%r,%r],[%r,%r,%r,%r],[%r,%r,%r,%r]]"
_LOCAL = (
    '{"radar":"%s","number":%d,"time":%r,"x_m":%r,"y_m":%r,"vx_mps":%r,"vy_mps":%r,'
    f'"covariance":{_COVARIANCE},'
    '"flight_level":%s,"climb_rate_fpm":%s,"status":"%s","plot_id":%s,"mode3a":%s,'
    '"address":%s,"model_probabilities":[%s]}'
)


def local_json(
    radar: str,
    number: int,
    state: Sequence[float],
    p: Sequence[float],
    flight_level: float | None,
    climb_rate_fpm: float | None,
    status: str,
    plot_id: int | None,
    mode3a: str | None,
    address: str | None,
    model_probabilities: Sequence[float],
) -> bytes:
    """A local-track update as ``LocalTrackMessage.model_dump_json`` writes it, up to
    number formatting: ``state`` is (time, x, y, vx, vy), ``p`` the covariance
    flattened; every float finite (the caller sends the others through the model, which
    writes them as null)."""
    return (
        _LOCAL
        % (
            radar,
            number,
            *state,
            *p,
            _optional(flight_level),
            _optional(climb_rate_fpm),
            status,
            _optional(plot_id),
            _quoted(mode3a),
            _quoted(address),
            ",".join(map(repr, model_probabilities)),
        )
    ).encode()


_SOURCE = '{"radar":"%s","local_track":%d,"age_s":%r,"plot_id":%s}'
_LAST_PLOT = '{"radar":"%s","time":%r,"lat":%r,"lon":%r,"range_m":%s,"azimuth_deg":%s}'
_AGES = '{"psr":%s,"ssr":%s,"mode_s":%s,"adsb":%s}'
_SYSTEM = (
    '{"number":%d,"time":%r,"time_iso":"%s","lat":%r,"lon":%r,"altitude_m":%s,'
    '"flight_level":%s,"x_m":%r,"y_m":%r,"vx_mps":%r,"vy_mps":%r,"ground_speed_mps":%r,'
    '"track_angle_deg":%r,"climb_rate_fpm":%s,'
    f'"covariance":{_COVARIANCE},'
    '"position_sigma_m":%r,"address":%s,"callsign":%s,"mode3a":%s,"mode3a_changed":%s,'
    '"first":%s,"sources":[%s],"status":"%s","last_plot":%s,"ages":%s,'
    '"duplicate_address":%s}'
)
_BOOL = ("false", "true")


def _last_plot(plot: Mapping[str, Any] | None) -> str:
    if plot is None:
        return "null"
    return _LAST_PLOT % (
        plot["radar"],
        plot["time"],
        plot["lat"],
        plot["lon"],
        # A plot without a polar position (NaN) has neither.
        _number(plot["range_m"]),
        _number(plot["azimuth_deg"]),
    )


def system_json(doc: Mapping[str, Any], p: Sequence[float]) -> bytes:
    """A system-track update as ``SystemTrackMessage.model_dump_json`` writes it, up to
    number formatting; ``p`` is the covariance flattened. Its floats must be finite, as
    for ``local_json``."""
    ages = doc["ages"]
    sources = ",".join(
        _SOURCE % (s["radar"], s["local_track"], s["age_s"], _optional(s["plot_id"]))
        for s in doc["sources"]
    )
    return (
        _SYSTEM
        % (
            doc["number"],
            doc["time"],
            doc["time_iso"],
            doc["lat"],
            doc["lon"],
            _optional(doc["altitude_m"]),
            _optional(doc["flight_level"]),
            doc["x_m"],
            doc["y_m"],
            doc["vx_mps"],
            doc["vy_mps"],
            doc["ground_speed_mps"],
            doc["track_angle_deg"],
            _optional(doc["climb_rate_fpm"]),
            *p,
            doc["position_sigma_m"],
            _quoted(doc["address"]),
            _callsign(doc["callsign"]),
            _quoted(doc["mode3a"]),
            _BOOL[doc["mode3a_changed"]],
            _BOOL[doc["first"]],
            sources,
            doc["status"],
            _last_plot(doc["last_plot"]),
            _AGES
            % (
                _optional(ages["psr"]),
                _optional(ages["ssr"]),
                _optional(ages["mode_s"]),
                _optional(ages["adsb"]),
            ),
            _BOOL[doc["duplicate_address"]],
        )
    ).encode()


def system_model(doc: Mapping[str, Any]) -> SystemTrackMessage:
    """The model of a system update's values, unvalidated (values that hold no bound, such
    as a non-finite one, serialised as pydantic writes them)."""
    plot = doc["last_plot"]
    return SystemTrackMessage.model_construct(
        **(
            dict(doc)
            | {
                "sources": [TrackSource.model_construct(**s) for s in doc["sources"]],
                "last_plot": None if plot is None else LastPlot.model_construct(**plot),
                "ages": SensorAges.model_construct(**doc["ages"]),
            }
        )
    )


@dataclass(frozen=True, slots=True)
class LocalUpdate:
    """One local-track update: its number and its JSON (``LocalTrackMessage``)."""

    number: int
    deleted: bool
    payload: bytes

    def message(self) -> LocalTrackMessage:
        return LocalTrackMessage.model_validate_json(self.payload)


@dataclass(frozen=True, slots=True)
class SystemUpdate:
    """One system-track update: what the sinks need of it, its JSON
    (``SystemTrackMessage``) and its values (``doc``: ``model_dump()``'s shape, for
    CAT062 and the picture)."""

    number: int
    doc: dict[str, Any]
    payload: bytes

    @property
    def ended(self) -> bool:
        return bool(self.doc["status"] == "ended")

    def message(self) -> SystemTrackMessage:
        """The model, unvalidated, as the pydantic path builds it from the rows."""
        return system_model(self.doc)

    def location(self) -> LocationFix:
        d = self.doc
        return location_of(d["time"], d["lat"], d["lon"], d["flight_level"], d["covariance"])


@dataclass(frozen=True)
class LocationFix:
    """A system track's position as a map shows it (``foxglove.LocationFix``)."""

    time: float
    lat: float
    lon: float
    altitude_m: float
    covariance: tuple[float, ...]
    """3x3 ENU position covariance (m², row-major)."""


def location_of(
    time: float,
    lat: float,
    lon: float,
    flight_level: float | None,
    covariance: Sequence[Sequence[float]],
) -> LocationFix:
    p = covariance
    # ENU position covariance: the plane's axes are east and north near the centre; the
    # vertical is unknown, so left large rather than zero.
    enu = (p[0][0], p[0][1], 0.0, p[1][0], p[1][1], 0.0, 0.0, 0.0, 1e6)
    altitude = 0.0 if flight_level is None else flight_level * _METRES_PER_FL
    return LocationFix(time, lat, lon, altitude, enu)
