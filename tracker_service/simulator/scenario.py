"""Scenario files: TOML validated by pydantic, with errors that name the field and the fix.

A scenario holds radars (sites, timing, accuracy, systematic errors, clutter and plot
pathologies), optional ADS-B ground stations, aircraft with flight plans of legs, and an
optional traffic generator. Units are in the names: ``_m``, ``_nm``, ``_deg``, ``_s``,
``_kt``, ``_fpm``, ``_fl``; altitudes of sites are metres above mean sea level.
"""

from __future__ import annotations

import tomllib
from datetime import UTC, datetime
from pathlib import Path
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from tracker_service.validation import describe_errors

NM = 1852.0


class _Strict(BaseModel):
    # Unknown keys are typos more often than not: refuse them, naming the field.
    model_config = ConfigDict(extra="forbid", frozen=True)


class Wandering(_Strict):
    """A systematic error: a constant plus a slow random walk (std growth per sqrt(hour))."""

    value: float = 0.0
    wander_per_sqrt_h: Annotated[float, Field(ge=0.0)] = 0.0


def _wandering(value: object) -> object:
    return {"value": value} if isinstance(value, int | float) else value


class SystematicErrors(_Strict):
    """Measured minus true: rho_m = (1 + g) rho + range_offset; theta_m = theta + azimuth
    offset; I140 = true time + time offset + drift * elapsed hours."""

    range_offset_m: Wandering = Wandering()
    range_gain_m_per_nm: Wandering = Wandering()
    azimuth_offset_deg: Wandering = Wandering()
    time_offset_s: Wandering = Wandering()
    time_drift_s_per_h: float = 0.0

    _coerce = field_validator(
        "range_offset_m",
        "range_gain_m_per_nm",
        "azimuth_offset_deg",
        "time_offset_s",
        mode="before",
    )(_wandering)


class Clutter(_Strict):
    persistent_per_scan: Annotated[int, Field(ge=0)] = 0
    random_per_scan: Annotated[float, Field(ge=0.0)] = 0.0


class Pathologies(_Strict):
    """Probabilities per plot, except where said."""

    reflection: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    split: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    garbled_mode_c: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    missing_mode_c: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    garbled_mode_3a: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    missing_mode_3a: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    missing_time: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    """Fraction of CAT048 records sent without I140."""


class FieldMonitor(_Strict):
    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    alt_m: float
    mode3a: str = "7777"
    address: str | None = None

    _code = field_validator("mode3a")(lambda v: _octal_code(v))


class FixedTransponder(FieldMonitor):
    """A stationary transponder that does not say so (RAB = 0 unless ``rab``), e.g. a
    site monitor on code 7777; ``reported_fl``: the test level it sends as Mode C (a
    site monitor's is often not its height), its true pressure altitude when unset."""

    rab: bool = False
    reported_fl: Annotated[float, Field(ge=-12.0, le=1270.0)] | None = None


class TestTarget(_Strict):
    """A test target the radar injects into its own plots, exactly at ``range_nm`` and
    ``azimuth_deg`` (no error), flagged I020 TST (or SIM with ``flag = "sim"``); without
    ``mode3a`` a primary test target, else an SSR one at ``fl``."""

    __test__ = False  # not a pytest class

    range_nm: Annotated[float, Field(gt=0.0, lt=256.0)] = 200.0
    azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)] = 45.0
    mode3a: str | None = "7776"
    fl: Annotated[float, Field(ge=-12.0, le=1270.0)] | None = 660.0
    flag: Literal["tst", "sim"] = "tst"

    _code = field_validator("mode3a")(lambda v: v if v is None else _octal_code(v))


class Output(_Strict):
    """Where the radar's datagrams go in a .pcap (and later a live feed)."""

    group: str = "232.1.1.1"
    port: Annotated[int, Field(ge=1, le=65535)] = 8600
    second_lan_group: str | None = None
    """With dual_lan, the group of the second LAN (the same group when unset)."""


class _Station(_Strict):
    """A source of ASTERIX data at a surveyed site, known by its SAC/SIC."""

    name: str
    sac: Annotated[int, Field(ge=0, le=255)]
    sic: Annotated[int, Field(ge=0, le=255)]
    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    alt_m: float

    @property
    def key(self) -> str:
        return f"{self.sac}/{self.sic}"


class Radar(_Station):
    antenna_period_s: Annotated[float, Field(gt=0.5, le=60.0)]
    rotation: Literal["clockwise", "counterclockwise"] = "clockwise"
    initial_azimuth_deg: Annotated[float, Field(ge=0.0, lt=360.0)] = 0.0
    sectors: Annotated[int, Field(ge=1, le=256)] = 16
    min_range_nm: Annotated[float, Field(ge=0.0)] = 0.5
    max_range_nm: Annotated[float, Field(gt=0.0, le=512.0)] = 250.0
    cone_of_silence_deg: Annotated[float, Field(gt=0.0, le=90.0)] = 45.0
    """Targets above this elevation are not seen."""
    psr: bool = True
    ssr: bool = True
    mode_s: bool = True
    pd_psr: Annotated[float, Field(ge=0.0, le=1.0)] = 0.9
    pd_ssr: Annotated[float, Field(ge=0.0, le=1.0)] = 0.97
    pd_mode_s: Annotated[float, Field(ge=0.0, le=1.0)] = 0.99
    psr_max_range_nm: Annotated[float, Field(gt=0.0)] = 80.0
    sigma_range_m: Annotated[float, Field(ge=0.0)] = 50.0
    sigma_azimuth_deg: Annotated[float, Field(ge=0.0)] = 0.06
    psr_sigma_range_m: Annotated[float, Field(ge=0.0)] | None = None
    psr_sigma_azimuth_deg: Annotated[float, Field(ge=0.0)] | None = None
    bias: SystematicErrors = SystematicErrors()
    psr_bias: SystematicErrors | None = None
    """PSR-only plots' range and azimuth errors; the SSR ones when unset. Its time fields
    are not used: the station has one clock, ``bias``'s, for every plot it sends."""
    clutter: Clutter = Clutter()
    pathologies: Pathologies = Pathologies()
    field_monitor: FieldMonitor | None = None
    fixed_transponders: list[FixedTransponder] = []
    test_targets: list[TestTarget] = []
    ehs_registers: Literal["rotating", "every_scan"] = "rotating"
    """Mode S Comm-B registers in I048/250: one of BDS 4,0, 5,0, 6,0 per plot in turn
    ("rotating"), or all three every scan, as enhanced-surveillance radars extract them."""
    dap_max_age_s: Annotated[float, Field(ge=0.0, le=10.0)] = 0.0
    """Register contents are the aircraft's of a moment drawn uniformly up to this long
    before the detection (transponders refresh BDS 5,0/6,0 every 1.3 s at most)."""
    dual_lan: bool = False
    output: Output = Output()
    asterix: Literal["cat048", "cat001"] = "cat048"
    """What the radar sends: CAT048 plots with CAT034 service messages, or, as older
    radars do, CAT001 plots (no Mode S items, the truncated I141) with CAT002."""

    @model_validator(mode="after")
    def _ranges(self) -> Radar:
        if self.min_range_nm >= self.max_range_nm:
            raise ValueError(
                f"min_range_nm ({self.min_range_nm}) must be below max_range_nm "
                f"({self.max_range_nm})"
            )
        if not (self.psr or self.ssr or self.mode_s):
            raise ValueError("a radar needs at least one of psr, ssr, mode_s set to true")
        return self


class AdsbStation(_Station):
    range_nm: Annotated[float, Field(gt=0.0)] = 200.0
    report_interval_s: Annotated[float, Field(gt=0.0)] = 1.0
    latency_s: Annotated[float, Field(ge=0.0)] = 0.3
    """Delay between the time of applicability (I073) and the datagram's reception."""
    output: Output = Output(group="232.1.2.1", port=8621)


class Leg(_Strict):
    """A piece of a flight plan: for ``duration_s``, turn at ``turn_rate_deg_s`` (positive
    right, a coordinated turn), climb or descend at ``climb_fpm`` until ``target_fl``, and
    change speed at ``accel_kt_s`` towards ``target_speed_kt``. Zero/unset = keep as is."""

    duration_s: Annotated[float, Field(gt=0.0)]
    turn_rate_deg_s: Annotated[float, Field(ge=-6.0, le=6.0)] = 0.0
    climb_fpm: Annotated[float, Field(ge=-8000.0, le=8000.0)] = 0.0
    target_fl: Annotated[float, Field(ge=-10.0, le=600.0)] | None = None
    target_speed_kt: Annotated[float, Field(ge=0.0, le=1200.0)] | None = None
    accel_kt_s: Annotated[float, Field(gt=0.0, le=20.0)] = 1.0

    @model_validator(mode="after")
    def _climb(self) -> Leg:
        if self.climb_fpm and self.target_fl is None:
            raise ValueError("climb_fpm needs target_fl, the flight level where it levels off")
        return self


class CodeChange(_Strict):
    at_s: Annotated[float, Field(ge=0.0)]
    mode3a: str

    _code = field_validator("mode3a")(lambda v: _octal_code(v))


class Aircraft(_Strict):
    callsign: str = ""
    address: str | None = None
    """ICAO 24-bit address, 6 hex digits; required for Mode S and ADS-B."""
    mode3a: str | None = "2000"
    transponder: Literal["mode_s", "mode_ac", "none"] = "mode_s"
    adsb: bool = False
    nacp: Annotated[int, Field(ge=0, le=11)] = 9
    adsb_offset_nm: Annotated[float, Field(ge=0.0, le=100.0)] = 0.0
    """A spoofed or faulty ADS-B position: its reports this far from the true position
    (the radars see it where it is), towards ``adsb_offset_bearing_deg``."""
    adsb_offset_bearing_deg: Annotated[float, Field(ge=0.0, lt=360.0)] = 90.0
    start_s: Annotated[float, Field(ge=0.0)] = 0.0
    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    fl: Annotated[float, Field(ge=-10.0, le=600.0)]
    speed_kt: Annotated[float, Field(ge=0.0, le=1200.0)]
    heading_deg: Annotated[float, Field(ge=0.0, le=360.0)]
    legs: list[Leg] = []
    code_changes: list[CodeChange] = []

    _code = field_validator("mode3a")(lambda v: None if v is None else _octal_code(v))

    @field_validator("address")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is None:
            return None
        try:
            number = int(value, 16)
        except ValueError:
            number = -1
        if not 0 <= number <= 0xFFFFFF or len(value) != 6:
            raise ValueError(f"address {value!r} must be 6 hex digits, e.g. '3C660C'")
        return value.upper()

    @field_validator("callsign")
    @classmethod
    def _callsign(cls, value: str) -> str:
        allowed = set("ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789 ")
        if len(value) > 8 or not set(value.upper()) <= allowed:
            raise ValueError(f"callsign {value!r}: at most 8 of A-Z, 0-9 and space")
        return value.upper()

    @model_validator(mode="after")
    def _identity(self) -> Aircraft:
        if (self.transponder == "mode_s" or self.adsb) and self.address is None:
            raise ValueError("a Mode S or ADS-B aircraft needs an address (6 hex digits)")
        return self


class Area(_Strict):
    lat_min: Annotated[float, Field(ge=-90.0, le=90.0)]
    lat_max: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon_min: Annotated[float, Field(ge=-180.0, le=180.0)]
    lon_max: Annotated[float, Field(ge=-180.0, le=180.0)]

    @model_validator(mode="after")
    def _order(self) -> Area:
        if self.lat_min >= self.lat_max or self.lon_min >= self.lon_max:
            raise ValueError("the area needs lat_min < lat_max and lon_min < lon_max")
        return self


class Traffic(_Strict):
    """Random aircraft over an area: straight, turning or climbing, at the given mix."""

    count: Annotated[int, Field(ge=0, le=100_000)] | None = None
    density_per_km2: Annotated[float, Field(gt=0.0)] | None = None
    """Instead of count: aircraft per km^2 (1.336e-3 is a Mode S station's average)."""
    area: Area
    fl_min: Annotated[float, Field(ge=0.0, le=600.0)] = 50.0
    fl_max: Annotated[float, Field(ge=0.0, le=600.0)] = 400.0
    speed_min_kt: Annotated[float, Field(gt=0.0)] = 250.0
    speed_max_kt: Annotated[float, Field(gt=0.0)] = 480.0
    turning_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.2
    climbing_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.15
    mode_s_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.9
    psr_only_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.0
    adsb_fraction: Annotated[float, Field(ge=0.0, le=1.0)] = 0.6
    shared_address_pairs: Annotated[int, Field(ge=0)] = 0
    """Pairs of aircraft given the same Mode S address, as happens now and then."""
    code_changes: Annotated[int, Field(ge=0)] = 0
    """Aircraft whose Mode 3/A code changes in flight."""
    mean_flight_s: Annotated[float, Field(ge=60.0)] | None = None
    """With it, traffic enters and leaves: ``count`` stays the number in the air while
    each aircraft flies for 0.5-1.5 times this mean (those in the air at the start part-way
    through), then leaves, and another enters at a random point of the area. Unset: the
    same aircraft for the whole scenario."""

    @model_validator(mode="after")
    def _how_many(self) -> Traffic:
        if (self.count is None) == (self.density_per_km2 is None):
            raise ValueError("give exactly one of count or density_per_km2")
        if self.fl_min > self.fl_max or self.speed_min_kt > self.speed_max_kt:
            raise ValueError("fl_min/speed_min_kt must not exceed fl_max/speed_max_kt")
        return self


class Atmosphere(_Strict):
    """Mode C is pressure altitude: with QNH and temperature off standard, it differs from
    the geometric height of the aircraft."""

    qnh_hpa: Annotated[float, Field(ge=900.0, le=1100.0)] = 1013.25
    temperature_offset_k: Annotated[float, Field(ge=-40.0, le=40.0)] = 0.0


class Centre(_Strict):
    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]


class Scenario(_Strict):
    name: str
    description: str = ""
    seed: int = 1
    start: datetime = datetime(2026, 1, 1, 12, 0, 0, tzinfo=UTC)
    duration_s: Annotated[float, Field(gt=0.0, le=86_400.0)] = 600.0
    system_centre: Centre
    atmosphere: Atmosphere = Atmosphere()
    truth_rate_hz: Annotated[float, Field(gt=0.0, le=50.0)] = 1.0
    radars: list[Radar]
    adsb_stations: list[AdsbStation] = []
    aircraft: list[Aircraft] = []
    traffic: Traffic | None = None

    @field_validator("start")
    @classmethod
    def _utc(cls, value: datetime) -> datetime:
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)

    @model_validator(mode="after")
    def _unique_sources(self) -> Scenario:
        keys = [(r.sac, r.sic) for r in self.radars] + [(s.sac, s.sic) for s in self.adsb_stations]
        duplicated = {k for k in keys if keys.count(k) > 1}
        if duplicated:
            raise ValueError(f"SAC/SIC used twice: {sorted(duplicated)}; each source needs its own")
        if not self.radars:
            raise ValueError("a scenario needs at least one radar")
        return self


def _octal_code(value: str) -> str:
    if len(value) != 4 or any(c not in "01234567" for c in value):
        raise ValueError(f"Mode 3/A code {value!r} must be 4 octal digits, e.g. '7000'")
    return value


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message names the field and the fix."""


def load_scenario(path: str | Path) -> Scenario:
    file = Path(path)
    try:
        data = tomllib.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ScenarioError(f"{file}: no such scenario file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{file}: not valid TOML: {exc}") from None
    try:
        return Scenario.model_validate(data)
    except ValidationError as exc:
        raise ScenarioError(f"{file}: {describe_errors(exc)}") from None
