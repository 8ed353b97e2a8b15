"""What the service publishes, as pydantic models: JSON over Zenoh and MCAP channels.

Times are POSIX seconds (UTC); positions are WGS84 degrees and metres in the system
plane (x east, y north at the plane's centre); velocities are m/s in the same plane.
``python -m tracker_service.outputs.messages DIR`` writes one JSON schema per model into
DIR (the repository keeps them in ``docs/schemas``).
"""

from __future__ import annotations

import json
import math
import sys
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

SOURCE_KEY = r"^\d{1,3}/\d{1,3}$"
FEET_PER_METRE = 1.0 / 0.3048

RadarKey = Annotated[str, Field(pattern=SOURCE_KEY, description='"SAC/SIC", e.g. "25/11"')]
Address = Annotated[str, Field(pattern=r"^[0-9A-F]{6}$", description="Mode S address, hex")]
Mode3A = Annotated[str, Field(pattern=r"^[0-7]{4}$", description="Mode 3/A code, octal")]
Callsign = Annotated[str, Field(pattern=r"^[A-Z0-9 ]{1,8}$")]
Latitude = Annotated[float, Field(ge=-90.0, le=90.0)]
Longitude = Annotated[float, Field(ge=-180.0, le=180.0)]
Seconds = Annotated[float, Field(ge=0.0)]


class _Message(BaseModel):
    # The attribute docstrings become the schemas' descriptions: the published contract.
    model_config = ConfigDict(extra="forbid", frozen=True, use_attribute_docstrings=True)


class TrackSource(_Message):
    """A local track that contributes to a system track."""

    radar: RadarKey
    local_track: int
    age_s: Seconds
    """Time of the system track minus the time of this local track's last update."""
    plot_id: int | None = None
    """The plot that last updated the local track, when it was a detection."""


class LastPlot(_Message):
    """The last measured plot used to update the track."""

    radar: RadarKey
    time: float
    lat: Latitude
    lon: Longitude
    range_m: Annotated[float, Field(ge=0.0)] | None = None
    """Measured (bias-corrected) slant range and azimuth, when the plot was polar."""
    azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)] | None = None


class SensorAges(_Message):
    """Seconds since the last detection of each sensor type used; None: never used."""

    psr: Seconds | None = None
    ssr: Seconds | None = None
    mode_s: Seconds | None = None
    adsb: Seconds | None = None


Covariance = Annotated[
    list[list[float]],
    Field(
        min_length=4,
        max_length=4,
        description="4x4 state covariance of [x, y, vx, vy] in the system plane (m, m/s)",
    ),
]


class SystemTrackMessage(_Message):
    """One update of a fused (system) track; the last one of a track has status "ended"."""

    number: Annotated[int, Field(ge=0, le=65535)]
    time: float
    """Time of the track state (POSIX s)."""
    time_iso: str
    lat: Latitude
    lon: Longitude
    altitude_m: float | None = None
    """Barometric altitude above mean sea level (the flight level corrected with QNH)."""
    flight_level: float | None = None
    """Last measured flight level (Mode C, Mode S or ADS-B barometric), in FL (100 ft)."""
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    ground_speed_mps: Annotated[float, Field(ge=0.0)]
    track_angle_deg: Annotated[float, Field(ge=0.0, lt=360.0)]
    """Clockwise from the system plane's north."""
    climb_rate_fpm: float | None = None
    covariance: Covariance
    position_sigma_m: Annotated[float, Field(ge=0.0)]
    """Major semi-axis of the 1-sigma position error ellipse."""
    address: Address | None = None
    callsign: Callsign | None = None
    mode3a: Mode3A | None = None
    mode3a_changed: bool = False
    first: bool = False
    """The first message of this track number (CAT062 TSB)."""
    sources: list[TrackSource]
    status: Literal["confirmed", "coasting", "ended"]
    last_plot: LastPlot | None = None
    ages: SensorAges = SensorAges()
    duplicate_address: bool = False
    """Another live system track carries the same Mode S address."""

    @field_validator("covariance")
    @classmethod
    def _square(cls, value: list[list[float]]) -> list[list[float]]:
        if any(len(row) != 4 for row in value):
            raise ValueError("covariance must be 4x4 ([x, y, vx, vy])")
        return value

    @classmethod
    def from_state(
        cls,
        *,
        time: float,
        x_m: float,
        y_m: float,
        vx_mps: float,
        vy_mps: float,
        covariance: list[list[float]],
        climb_rate_fl_per_s: float | None = None,
        validate: bool = True,
        **identity: object,
    ) -> SystemTrackMessage:
        """A message with the fields that follow from the state filled in (time_iso,
        ground speed, track angle, position sigma, climb rate in ft/min); ``identity``
        gives the others (number, lat, lon, status, sources, ...).

        ``validate`` False skips pydantic's checks (a few tens of microseconds a message)
        for values whose types and ranges hold by construction, such as the service's own
        track rows; nested messages must then be models already."""
        fields: dict[str, Any] = {
            "time": time,
            "time_iso": iso_time(time),
            "x_m": x_m,
            "y_m": y_m,
            "vx_mps": vx_mps,
            "vy_mps": vy_mps,
            "ground_speed_mps": math.hypot(vx_mps, vy_mps),
            "track_angle_deg": track_angle_deg(vx_mps, vy_mps),
            "covariance": covariance,
            "position_sigma_m": position_sigma_m(covariance),
            "climb_rate_fpm": (
                None if climb_rate_fl_per_s is None else climb_rate_fl_per_s * 6000.0
            ),
            **identity,
        }
        return cls.model_validate(fields) if validate else cls.model_construct(**fields)


class LocalTrackMessage(_Message):
    """One update of a radar's local track (before fusion)."""

    radar: RadarKey
    number: int
    time: float
    x_m: float
    y_m: float
    vx_mps: float
    vy_mps: float
    covariance: Covariance
    flight_level: float | None = None
    climb_rate_fpm: float | None = None
    status: Literal["tentative", "confirmed", "coasting", "deleted"]
    plot_id: int | None = None
    mode3a: Mode3A | None = None
    address: Address | None = None
    model_probabilities: list[float]
    """IMM model probabilities, in the order of the tracker's model set."""


BiasSource = Literal["other_radars", "reference_radar", "field_monitor", "adsb", "configuration"]
"""What makes a bias component observable: traffic shared with other radars (relative to
their estimates), traffic shared with a reference radar, the radar's field monitor, ADS-B,
or the configuration (a reference radar's bias is given)."""


class Estimate(_Message):
    estimate: float
    sigma: Annotated[float, Field(ge=0.0)]
    observable: bool
    """False while no source separates this error from the others: the estimate is then
    the prior's mean, and its sigma the prior's (a radar alone, without ADS-B or a field
    monitor, cannot tell its own biases from the aircraft's positions)."""
    observed_from: list[BiasSource] = Field(default_factory=list)
    """The sources the estimate is observable from (empty when not observable)."""


class BiasMessage(_Message):
    """A radar's systematic-error estimate (measured minus true)."""

    radar: RadarKey
    time: float
    range_offset_m: Estimate
    range_gain: Estimate
    """Dimensionless: rho_measured = (1 + gain) rho + offset."""
    azimuth_deg: Estimate
    time_s: Estimate


class RadarTestTarget(_Message):
    """A test target the radar injects (I020 TST = 1), as last seen: the radar's own check
    that its chain works. Kept out of traffic tracking."""

    kind: Literal["primary", "secondary"]
    """primary: a PSR-only test target; secondary: an SSR or Mode S test transponder."""
    mode3a: Mode3A | None = None
    seen: Annotated[int, Field(ge=1)]
    """Its plots since start."""
    last_time: float
    """Time of measurement of its latest plot, POSIX s."""
    range_nm: Annotated[float, Field(ge=0.0)]
    """Its latest plot's slant range (I040 RHO) and azimuth (THETA), as sent."""
    azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)]
    flight_level: float | None = None


class RadarStatus(_Message):
    radar: RadarKey
    last_plot_time: float | None = None
    plots_per_second: Annotated[float, Field(ge=0.0)]
    decode_errors: Annotated[int, Field(ge=0)]
    duplicates: Annotated[int, Field(ge=0)]
    drops: Annotated[int, Field(ge=0)]
    """Plots or datagrams dropped under overload (counted, also in the MCAP log)."""
    rejected: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    """Plots since start kept out of traffic tracking, by reason (field_monitor,
    time_implausible, out_of_line: refused by its tracker's clock, ...)."""
    time_offset_s: float | None = None
    """Its data time minus its reception time (median of recent datagrams and north
    markers); None until measured. Beyond a few seconds: a replayed capture or a wrong
    clock (see ``reasons``)."""
    test_targets: list[RadarTestTarget] = Field(default_factory=list)
    """The radar's test targets, one per kind and code."""
    errors: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    """What ``decode_errors`` counts, by kind: not_asterix (framing), decode_error (a
    record inside valid framing), unknown_category, no_source (plots without I010),
    unknown_source (plots of unknown SAC/SICs beyond the limit), processing_failed."""
    repeats: Annotated[int, Field(ge=0)] = 0
    """Datagrams received twice on the same LAN within the duplicate window, dropped."""
    drop_causes: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    """What ``drops`` counts, by cause: queue (the core behind), holding_window (a burst
    beyond its bound), kernel (the socket's receive buffer full, SO_RXQ_OVFL)."""
    last_reception_time: float | None = None
    """Data time of the last datagram from this radar (reception, not plot time)."""
    plot_delay_s: float | None = None
    """Reception time minus the time of measurement of the radar's latest plot."""
    receiving: bool = True
    """Data arrived within the last few antenna periods (or nothing was expected yet)."""
    tracking: bool = True
    """Its tracked plots update local tracks (no tracker stall)."""
    time_sane: bool = True
    """Its plots' times of measurement lie within bounds of their reception times."""


class OutputStatus(_Message):
    """One output of the service (Zenoh publishing, MCAP logging, the output process)."""

    name: str
    ok: bool
    failures: Annotated[int, Field(ge=0)] = 0
    """Failed calls since start."""
    last_error: str | None = None
    restarts: Annotated[int, Field(ge=0)] = 0
    """For the output process: times it was restarted after it died."""


class StatusMessage(_Message):
    time: float
    uptime_s: Seconds
    health: Literal["ok", "degraded"]
    reasons: list[str] = Field(default_factory=list)
    """Why health is not "ok", one line each, naming the radar or output concerned."""
    radars: list[RadarStatus]
    outputs: list[OutputStatus] = Field(default_factory=list)
    lag_s: float | None = None
    """How far the chain is behind the wall clock beyond the holding window (the daemon)."""
    unattributed: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    """Counts that belong to no radar of the list: errors of inputs the configuration does
    not name (a replayed capture), unknown_sources_dropped (distinct SAC/SICs whose plots
    were dropped beyond [system] max_unknown_sources)."""


MODELS: tuple[type[BaseModel], ...] = (
    SystemTrackMessage,
    LocalTrackMessage,
    BiasMessage,
    StatusMessage,
)


def iso_time(posix: float) -> str:
    """ISO 8601 UTC with microseconds, e.g. 2026-06-01T10:00:00.500000Z."""
    return datetime.fromtimestamp(posix, UTC).strftime("%Y-%m-%dT%H:%M:%S.%fZ")


def wrap_degrees(angle: float) -> float:
    """``angle`` in [0, 360): a tiny negative angle is 0, not the 360.0 that ``% 360.0``
    rounds it to (outside the schemas' bounds)."""
    wrapped = angle % 360.0
    return 0.0 if wrapped >= 360.0 else wrapped


def track_angle_deg(vx_mps: float, vy_mps: float) -> float:
    """Clockwise from north, in [0, 360)."""
    return wrap_degrees(math.degrees(math.atan2(vx_mps, vy_mps)))


def position_sigma_m(covariance: list[list[float]]) -> float:
    """Major semi-axis of the position error ellipse: sqrt of the larger eigenvalue of
    the 2x2 position block."""
    sxx, sxy, syy = covariance[0][0], covariance[0][1], covariance[1][1]
    half_trace = 0.5 * (sxx + syy)
    spread = math.hypot(0.5 * (sxx - syy), sxy)
    return math.sqrt(max(half_trace + spread, 0.0))


def schemas() -> dict[str, str]:
    """File name -> JSON schema text of every published model."""
    return {
        f"{model.__name__}.schema.json": json.dumps(model.model_json_schema(), indent=2) + "\n"
        for model in MODELS
    }


def write_schemas(directory: str | Path) -> list[Path]:
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    written = []
    for name, text in schemas().items():
        path = out / name
        path.write_text(text, encoding="utf-8")
        written.append(path)
    return written


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: python -m tracker_service.outputs.messages DIRECTORY")
    for path in write_schemas(sys.argv[1]):
        print(path)
