"""What the service publishes, as pydantic models: JSON over Zenoh and MCAP channels.

Times are POSIX seconds (UTC); positions are WGS84 degrees and metres in the system
plane (x east, y north at the plane's centre only: away from it the plane's axes turn
from true north by the meridian convergence, so x_m/y_m/vx_mps/vy_mps are not east/north
components there, while CAT062 I185 is true north at the target); velocities are m/s in
the same plane. Each field's schema description gives its unit and frame.
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
    """The radar of the local track."""
    local_track: int
    """The local track's number in that radar's tracker."""
    age_s: Seconds
    """Time of the system track minus the time of this local track's last update."""
    plot_id: int | None = None
    """The plot that last updated the local track, when it was a detection."""


class LastPlot(_Message):
    """The last measured plot used to update the track."""

    radar: RadarKey
    """The radar that measured it."""
    time: float
    """Its time of measurement, POSIX s (UTC)."""
    lat: Latitude
    """Its position, bias-corrected, WGS84 latitude in degrees."""
    lon: Longitude
    """WGS84 longitude in degrees, east positive."""
    range_m: Annotated[float, Field(ge=0.0)] | None = None
    """Measured (bias-corrected) slant range and azimuth, when the plot was polar."""
    azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)] | None = None
    """Degrees clockwise from the radar's north (true north at the radar)."""


class SensorAges(_Message):
    """Seconds since the last detection of each sensor type used; None: never used."""

    psr: Seconds | None = None
    """Primary radar."""
    ssr: Seconds | None = None
    """Secondary radar, Mode A/C."""
    mode_s: Seconds | None = None
    """Mode S."""
    adsb: Seconds | None = None
    """ADS-B."""


DapName = Literal[
    "magnetic_heading_deg",
    "indicated_airspeed_kt",
    "mach",
    "selected_altitude_ft",
    "baro_rate_fpm",
    "inertial_rate_fpm",
    "roll_deg",
    "track_angle_rate_deg_s",
    "true_track_deg",
    "ground_speed_kt",
]
DAP_NAMES: tuple[str, ...] = DapName.__args__  # type: ignore[attr-defined]


class DownlinkedParameter(_Message):
    """A Mode S downlinked aircraft parameter (DAP) of the track's aircraft, as its last
    Mode S plot carrying it gave it (BDS 4,0, 5,0 or 6,0 in I048/250; plausible values
    only, ``tracking.daps``)."""

    name: DapName
    """BDS 6,0 magnetic heading (deg), IAS (kt), Mach, barometric and inertial vertical
    rates (ft/min); BDS 4,0 selected altitude (ft); BDS 5,0 roll (deg, right wing down
    positive), track angle rate (deg/s, clockwise), true track angle (deg), ground speed
    (kt)."""
    value: float
    """In the unit its name says."""
    age_s: Seconds
    """Seconds since the plot that carried it (CAT062 I295)."""


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
    """System track number (CAT062 I040), stable over the track's life."""
    time: float
    """Time of the track state (POSIX s)."""
    time_iso: str
    """``time`` as ISO 8601 UTC."""
    lat: Latitude
    """WGS84 latitude of the track position, degrees."""
    lon: Longitude
    """WGS84 longitude, degrees east."""
    altitude_m: float | None = None
    """Barometric altitude above mean sea level (the flight level corrected with QNH)."""
    flight_level: float | None = None
    """Last measured flight level (Mode C, Mode S or ADS-B barometric), in FL (100 ft)."""
    x_m: float
    """Position, m, in the system plane ([system] centre_lat/centre_lon, stereographic or tangent):
    x east and y north at the plane's centre only, turned from true north elsewhere by the
    meridian convergence (up to a few degrees; CAT062 I185 is true north at the target)."""
    y_m: float
    """Position, m, in the system plane (see x_m)."""
    vx_mps: float
    """Velocity, m/s, along the system plane's x axis: not true east away from the plane's centre
    (see x_m)."""
    vy_mps: float
    """Velocity, m/s, along the system plane's y axis: not true north away from the plane's centre
    (see x_m)."""
    ground_speed_mps: Annotated[float, Field(ge=0.0)]
    """Horizontal speed, m/s (the same in any frame)."""
    track_angle_deg: Annotated[float, Field(ge=0.0, lt=360.0)]
    """Clockwise from the system plane's north."""
    climb_rate_fpm: float | None = None
    """Rate of climb (positive) or descent, ft/min."""
    covariance: Covariance
    """4x4 covariance of [x_m, y_m, vx_mps, vy_mps] in the system plane (m², m²/s, m²/s²)."""
    position_sigma_m: Annotated[float, Field(ge=0.0)]
    """Major semi-axis of the 1-sigma position error ellipse."""
    address: Address | None = None
    """Mode S (ICAO 24-bit) aircraft address, 6 hex digits."""
    callsign: Callsign | None = None
    """Aircraft identification the aircraft downlinked (Mode S BDS 2,0 / I048/240)."""
    mode3a: Mode3A | None = None
    """Mode 3/A code, 4 octal digits."""
    mode3a_changed: bool = False
    """The Mode 3/A code differs from the track's previous message."""
    first: bool = False
    """The first message of this track number (CAT062 TSB)."""
    sources: list[TrackSource]
    """The local tracks fused into it."""
    status: Literal["confirmed", "coasting", "ended"]
    """coasting: no radar updated it at its last scan; ended: the track's last message."""
    last_plot: LastPlot | None = None
    """The plot that last updated it."""
    ages: SensorAges = SensorAges()
    """Seconds since each sensor type last updated it."""
    duplicate_address: bool = False
    """Another live system track carries the same Mode S address."""
    adsb_inconsistent: bool = False
    """The ADS-B reports of its address disagree with its radars beyond the gate (a
    spoofed or faulty transponder, a wrong address): not fused (CAT062 I080 AFF)."""
    daps: list[DownlinkedParameter] = []
    """The aircraft's Mode S DAPs with their ages, in ``DAP_NAMES`` order (CAT062 I380
    and I295)."""

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
    """The radar whose tracker holds it."""
    number: int
    """Track number in that radar's tracker."""
    time: float
    """Time of the track state, POSIX s (UTC)."""
    x_m: float
    """Position, m, in the system plane (x east and y north at its centre only: see
    SystemTrackMessage.x_m)."""
    y_m: float
    """Position, m, in the system plane."""
    vx_mps: float
    """Velocity, m/s, along the system plane's x axis."""
    vy_mps: float
    """Velocity, m/s, along the system plane's y axis."""
    covariance: Covariance
    """4x4 covariance of [x_m, y_m, vx_mps, vy_mps] in the system plane (m², m²/s, m²/s²)."""
    flight_level: float | None = None
    """Flight level (100 ft, pressure altitude) from Mode C or Mode S."""
    climb_rate_fpm: float | None = None
    """Rate of climb (positive) or descent, ft/min."""
    status: Literal["tentative", "confirmed", "coasting", "deleted"]
    """tentative until M of N plots confirm it; deleted: its last message."""
    plot_id: int | None = None
    """The plot that updated it (None when coasting)."""
    mode3a: Mode3A | None = None
    """Mode 3/A code, 4 octal digits."""
    address: Address | None = None
    """Mode S aircraft address, 6 hex digits."""
    model_probabilities: list[float]
    """IMM model probabilities, in the order of the tracker's model set."""


BiasSource = Literal["other_radars", "reference_radar", "field_monitor", "adsb", "configuration"]
"""What makes a bias component observable: traffic shared with other radars (relative to
their estimates), traffic shared with a reference radar, the radar's field monitor, ADS-B,
or the configuration (a reference radar's bias is given)."""


class Estimate(_Message):
    estimate: float
    """The estimate, in the unit its field's name gives (m, dimensionless, deg, s)."""
    sigma: Annotated[float, Field(ge=0.0)]
    """Its standard deviation, same unit."""
    observable: bool
    """False while no source separates this error from the others: the estimate is then
    the prior's mean, and its sigma the prior's (a radar alone, without ADS-B or a field
    monitor, cannot tell its own biases from the aircraft's positions)."""
    observed_from: list[BiasSource] = Field(default_factory=list)
    """The sources the estimate is observable from (empty when not observable)."""


class BiasMessage(_Message):
    """A radar's systematic-error estimate (measured minus true)."""

    radar: RadarKey
    """The radar whose systematic errors these are."""
    time: float
    """Data time of the estimate, POSIX s (UTC)."""
    range_offset_m: Estimate
    """Range offset, m: rho_measured = (1 + gain) rho + offset."""
    range_gain: Estimate
    """Dimensionless: rho_measured = (1 + gain) rho + offset."""
    azimuth_deg: Estimate
    """Azimuth offset, degrees: theta_measured = theta + offset."""
    time_s: Estimate
    """Time-stamping offset, s: the radar's time of measurement minus the true time."""
    time_drift_s_per_h: Estimate | None = None
    """The clock's drift, s/h: how fast ``time_s`` grows (with ``[bias] clock_states`` 2 or
    3; absent with the offset alone). Observable with the time offset."""
    time_drift_rate_s_per_h2: Estimate | None = None
    """The drift's rate, s/h^2 (``clock_states`` 3)."""


class RadarTestTarget(_Message):
    """A test target the radar injects (I020 TST = 1), as last seen: the radar's own check
    that its chain works. Kept out of traffic tracking."""

    kind: Literal["primary", "secondary"]
    """primary: a PSR-only test target; secondary: an SSR or Mode S test transponder."""
    mode3a: Mode3A | None = None
    """Its Mode 3/A code (a secondary one)."""
    seen: Annotated[int, Field(ge=1)]
    """Its plots since start."""
    last_time: float
    """Time of measurement of its latest plot, POSIX s."""
    range_nm: Annotated[float, Field(ge=0.0)]
    """Its latest plot's slant range (I040 RHO) and azimuth (THETA), as sent."""
    azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)]
    """Degrees clockwise from the radar's north."""
    flight_level: float | None = None
    """Its Mode C, FL (100 ft)."""


class RadarStatus(_Message):
    radar: RadarKey
    """The feed (radar or ADS-B station)."""
    last_plot_time: float | None = None
    """Time of measurement of its latest plot (an ADS-B feed: its latest report's time of
    applicability), POSIX s."""
    plots_per_second: Annotated[float, Field(ge=0.0)]
    """Plots (an ADS-B feed: reports) per second since the last status."""
    decode_errors: Annotated[int, Field(ge=0)]
    """Datagrams or records dropped since start as malformed or unusable (by kind: ``errors``)."""
    duplicates: Annotated[int, Field(ge=0)]
    """Datagrams since start dropped as the second LAN's copies."""
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
    beyond its bound), kernel (the socket's receive buffer full, SO_RXQ_OVFL), behind
    (the chain overloaded: dropped unprocessed, their turn more than ``[system]
    max_behind_s`` behind the wall clock), warm_up (the same for what arrived while the
    process warmed up at its start)."""
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
    """zenoh, mcap, asterix_udp HOST:PORT, output_process, ..."""
    ok: bool
    """Working (not failing, its queue not full)."""
    failures: Annotated[int, Field(ge=0)] = 0
    """Failed calls since start."""
    last_error: str | None = None
    """Why it last failed, in one line."""
    restarts: Annotated[int, Field(ge=0)] = 0
    """For the output process: times it was restarted after it died."""


class StatusMessage(_Message):
    time: float
    """Data time of the status, POSIX s (UTC)."""
    uptime_s: Seconds
    """Data time since the service's first datagram (or start), s."""
    health: Literal["ok", "degraded"]
    """degraded while any reason below holds."""
    reasons: list[str] = Field(default_factory=list)
    """Why health is not "ok", one line each, naming the radar or output concerned."""
    radars: list[RadarStatus]
    """Every configured feed, and the unknown sources tracked."""
    outputs: list[OutputStatus] = Field(default_factory=list)
    """Each output's state."""
    lag_s: float | None = None
    """How far the chain is behind the wall clock beyond the holding window (the daemon)."""
    unattributed: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    """Counts that belong to no radar of the list: errors of inputs the configuration does
    not name (a replayed capture), unknown_sources_dropped (distinct SAC/SICs whose plots
    were dropped beyond [system] max_unknown_sources)."""
    memory_mb: dict[str, Annotated[float, Field(ge=0.0)]] = Field(default_factory=dict)
    """Resident memory (RSS, MB) of a live service's processes: "core" (the chain: the
    radar stages and fusion, or fusion alone in a `--role fusion` process), "outputs"
    (the output process, when the outputs run in one), "radar <name>" (each radar process
    of a fusion process, as it last said); empty in a replay (whose status is
    a function of its recording) and where the platform does not tell (Linux /proc
    does)."""
    busy: dict[str, Annotated[float, Field(ge=0.0, le=1.0)]] = Field(default_factory=dict)
    """How busy each of a live service's process loops was since the last status: the
    share of the wall clock it spent not waiting for work, by the roles of ``memory_mb``.
    Its headroom, which a share of a core does not show on a host whose cores other
    processes share: near 1 a loop takes each item as soon as it is done with the last,
    and a burst or a slower second puts it behind (at ``artas`` on two cores, the
    latency's tail came in the seconds the fusion process's loop was busy more than 0.8
    of the time). Empty in a replay and in the first status."""


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
    return ellipse_sigma_m(covariance[0][0], covariance[0][1], covariance[1][1])


def ellipse_sigma_m(sxx: float, sxy: float, syy: float) -> float:
    """:func:`position_sigma_m` of the position block's variances and covariance."""
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
