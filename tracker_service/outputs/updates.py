"""Track updates as plain data with their JSON already written: the batch path of the
outputs, without a pydantic model per update.

``MessageMapper.local_updates`` and ``MessageMapper.system_updates`` (``mapping.py``) turn
the chain's rows into these, and the sinks carry a whole batch in one call
(``sink.BatchSink``). Each update's JSON is written here from its values (a plain dict,
by pydantic-core's JSON writer, which the models' own serialiser uses: measured 4-5 times
faster than formatting it in Python, and a model per update costs more still), in the
field order of its pydantic model (``LocalTrackMessage``, ``SystemTrackMessage``; a test
holds the writers to the models' fields and to their ``model_dump_json``, field by field);
the model itself is built only where a consumer asks for one (``message()``: the picture,
a sink without batch support).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

from pydantic_core import to_json

from tracker_service.outputs.messages import (
    DownlinkedParameter,
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
    "adsb_inconsistent",
    "daps",
)
"""The order ``system_json`` writes: ``SystemTrackMessage``'s (checked by a test)."""


def local_json(doc: Mapping[str, Any]) -> bytes:
    """A local-track update's values (keys in ``LOCAL_FIELDS`` order) as
    ``LocalTrackMessage.model_dump_json`` writes them: by pydantic-core's own JSON writer,
    non-finite numbers as null as the model's serialiser writes them."""
    return to_json(doc, inf_nan_mode="null")


def system_json(doc: Mapping[str, Any]) -> bytes:
    """As :func:`local_json`, for a system-track update (keys in ``SYSTEM_FIELDS`` order,
    nested values as ``model_dump()`` gives them)."""
    return to_json(doc, inf_nan_mode="null")


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
                "daps": [DownlinkedParameter.model_construct(**d) for d in doc["daps"]],
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
