"""Track updates as plain data with their JSON already written: the batch path of the
outputs, without a pydantic model per update.

``MessageMapper.local_updates`` and ``MessageMapper.system_updates`` (``mapping.py``) turn
the chain's rows into these, and the sinks carry a whole batch in one call
(``sink.BatchSink``). Each update's JSON is written here, straight from its values, in the
field order of its pydantic model (``LocalTrackMessage``, ``SystemTrackMessage``; a test
holds the writers to the models' fields and to their ``model_dump_json``, field by field);
the model itself is built only where a consumer asks for one (``message()``: the picture,
a sink without batch support), validated.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from tracker_service.outputs.messages import LocalTrackMessage, SystemTrackMessage

__all__ = [
    "LOCAL_FIELDS",
    "SYSTEM_FIELDS",
    "LocalUpdate",
    "LocationFix",
    "SystemUpdate",
    "local_json",
    "location_of",
    "system_json",
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


def _number(value: float | None) -> str:
    """A JSON number; None and the non-finite (which JSON lacks) as null, as pydantic."""
    if value is None or not math.isfinite(value):
        return "null"
    return repr(value)


def _integer(value: int | None) -> str:
    return "null" if value is None else str(value)


def _string(value: str | None) -> str:
    return "null" if value is None else json.dumps(value)


def _bool(value: bool) -> str:
    return "true" if value else "false"


def _covariance(p: Sequence[float]) -> str:
    """The flattened 4x4 as JSON rows."""
    f = [_number(v) for v in p]
    return (
        f"[[{','.join(f[0:4])}],[{','.join(f[4:8])}],[{','.join(f[8:12])}],[{','.join(f[12:16])}]]"
    )


def local_json(doc: Mapping[str, Any], p: Sequence[float]) -> bytes:
    """A local-track update as ``LocalTrackMessage.model_dump_json`` writes it, up to
    number formatting; ``p`` is the covariance flattened."""
    probabilities = ",".join(_number(v) for v in doc["model_probabilities"])
    return (
        f'{{"radar":{_string(doc["radar"])},"number":{doc["number"]},'
        f'"time":{_number(doc["time"])},"x_m":{_number(doc["x_m"])},'
        f'"y_m":{_number(doc["y_m"])},"vx_mps":{_number(doc["vx_mps"])},'
        f'"vy_mps":{_number(doc["vy_mps"])},"covariance":{_covariance(p)},'
        f'"flight_level":{_number(doc["flight_level"])},'
        f'"climb_rate_fpm":{_number(doc["climb_rate_fpm"])},'
        f'"status":"{doc["status"]}","plot_id":{_integer(doc["plot_id"])},'
        f'"mode3a":{_string(doc["mode3a"])},"address":{_string(doc["address"])},'
        f'"model_probabilities":[{probabilities}]}}'
    ).encode()


def _source(s: Mapping[str, Any]) -> str:
    return (
        f'{{"radar":{_string(s["radar"])},"local_track":{s["local_track"]},'
        f'"age_s":{_number(s["age_s"])},"plot_id":{_integer(s["plot_id"])}}}'
    )


def _last_plot(plot: Mapping[str, Any] | None) -> str:
    if plot is None:
        return "null"
    return (
        f'{{"radar":{_string(plot["radar"])},"time":{_number(plot["time"])},'
        f'"lat":{_number(plot["lat"])},"lon":{_number(plot["lon"])},'
        f'"range_m":{_number(plot["range_m"])},"azimuth_deg":{_number(plot["azimuth_deg"])}}}'
    )


def _ages(ages: Mapping[str, float | None]) -> str:
    return (
        f'{{"psr":{_number(ages["psr"])},"ssr":{_number(ages["ssr"])},'
        f'"mode_s":{_number(ages["mode_s"])},"adsb":{_number(ages["adsb"])}}}'
    )


def system_json(doc: Mapping[str, Any], p: Sequence[float]) -> bytes:
    """A system-track update as ``SystemTrackMessage.model_dump_json`` writes it, up to
    number formatting; ``p`` is the covariance flattened."""
    sources = ",".join(_source(s) for s in doc["sources"])
    return (
        f'{{"number":{doc["number"]},"time":{_number(doc["time"])},'
        f'"time_iso":"{doc["time_iso"]}","lat":{_number(doc["lat"])},'
        f'"lon":{_number(doc["lon"])},"altitude_m":{_number(doc["altitude_m"])},'
        f'"flight_level":{_number(doc["flight_level"])},"x_m":{_number(doc["x_m"])},'
        f'"y_m":{_number(doc["y_m"])},"vx_mps":{_number(doc["vx_mps"])},'
        f'"vy_mps":{_number(doc["vy_mps"])},'
        f'"ground_speed_mps":{_number(doc["ground_speed_mps"])},'
        f'"track_angle_deg":{_number(doc["track_angle_deg"])},'
        f'"climb_rate_fpm":{_number(doc["climb_rate_fpm"])},'
        f'"covariance":{_covariance(p)},'
        f'"position_sigma_m":{_number(doc["position_sigma_m"])},'
        f'"address":{_string(doc["address"])},"callsign":{_string(doc["callsign"])},'
        f'"mode3a":{_string(doc["mode3a"])},"mode3a_changed":{_bool(doc["mode3a_changed"])},'
        f'"first":{_bool(doc["first"])},"sources":[{sources}],"status":"{doc["status"]}",'
        f'"last_plot":{_last_plot(doc["last_plot"])},"ages":{_ages(doc["ages"])},'
        f'"duplicate_address":{_bool(doc["duplicate_address"])}}}'
    ).encode()


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
        return SystemTrackMessage.model_validate(self.doc)

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
