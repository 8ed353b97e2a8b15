"""The service's TOML configuration, validated by pydantic; errors name the field.

Sections: ``[[radars]]`` (sites, accuracy, UDP inputs), ``[[adsb]]`` (ADS-B feeds),
``[system]`` (the system plane and the tracker's own SAC/SIC), ``[tracker]`` (fields of
``tracking.TrackerConfig``), ``[fusion]``, ``[bias]`` and ``[time_sanity]`` (free tables),
``[fixed_targets]`` (fields of ``fixed_targets.FixedTargetConfig``), ``[atmosphere]``
(``geodesy.Atmosphere``: qnh_hpa, isa_deviation_k), ``[zenoh]``,
``[mcap]`` and ``[[asterix_udp]]``. Units are in the names, as in the scenario files.
"""

from __future__ import annotations

import dataclasses
import tomllib
from ipaddress import IPv4Address
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from tracker_service.fixed_targets import FixedTargetConfig
from tracker_service.fusion.config import FusionConfig
from tracker_service.geodesy import Atmosphere
from tracker_service.geodesy.plane import PlaneKind
from tracker_service.outputs.asterix_udp import parse_destination
from tracker_service.simulator.scenario import FieldMonitor
from tracker_service.tracking import TrackerConfig
from tracker_service.validation import dataclass_kwargs, describe_errors

ANY_ADDRESS = IPv4Address("0.0.0.0")
TRACKER_FIELDS = {f.name: f for f in dataclasses.fields(TrackerConfig)}

Sac = Annotated[int, Field(ge=0, le=255)]
Port = Annotated[int, Field(ge=1, le=65535)]


class ConfigError(ValueError):
    """A configuration file that cannot be used; the message names the field and the fix."""


class _Strict(BaseModel):
    # Unknown keys are typos more often than not: refuse them, naming the field.
    model_config = ConfigDict(extra="forbid", frozen=True)


class Lan(_Strict):
    """One UDP endpoint: a multicast group, a unicast address of this host, or 0.0.0.0."""

    address: IPv4Address
    port: Port
    interface: IPv4Address | None = None
    """The local address whose interface joins the multicast group (the default route's
    interface when unset)."""


class Input(Lan):
    """A feed's UDP input, with the optional redundant LAN whose copies are dropped."""

    second_lan: Lan | None = None
    duplicate_window_s: Annotated[float, Field(gt=0.0, le=60.0)] = 1.0
    """A datagram equal to one received this recently (on either LAN) is a duplicate."""

    def endpoints(self) -> list[Lan]:
        first = Lan(address=self.address, port=self.port, interface=self.interface)
        return [first] if self.second_lan is None else [first, self.second_lan]


class FixedTransponder(_Strict):
    """A stationary transponder the radar sees (a site monitor sending RAB = 0, say): never
    tracked; with its surveyed position, a field monitor for the radar's biases."""

    name: str = ""
    address: str | None = None
    """Mode S address, 6 hex digits."""
    mode3a: str | None = None
    """Mode 3/A code, 4 octal digits."""
    lat: Annotated[float, Field(ge=-90.0, le=90.0)] | None = None
    lon: Annotated[float, Field(ge=-180.0, le=180.0)] | None = None
    alt_m: float | None = None
    """Height above mean sea level of the transponder's antenna."""
    tolerance_m: Annotated[float, Field(gt=0.0, le=20_000.0)] = 1000.0
    """How far from the surveyed position (in range, and across) a plot of its identity is
    still taken as this transponder: the radar's biases and noise at that range."""

    @field_validator("address")
    @classmethod
    def _address(cls, value: str | None) -> str | None:
        if value is not None and (len(value) != 6 or set(value.upper()) - set("0123456789ABCDEF")):
            raise ValueError(f"address {value!r} must be 6 hex digits, e.g. '00020A'")
        return value

    @field_validator("mode3a")
    @classmethod
    def _mode3a(cls, value: str | None) -> str | None:
        if value is not None and (len(value) != 4 or set(value) - set("01234567")):
            raise ValueError(f"mode3a {value!r} must be 4 octal digits, e.g. '7777'")
        return value

    @model_validator(mode="after")
    def _complete(self) -> FixedTransponder:
        if self.address is None and self.mode3a is None:
            raise ValueError("a fixed transponder needs its address or its mode3a (or both)")
        position = (self.lat, self.lon, self.alt_m)
        if any(v is None for v in position) and any(v is not None for v in position):
            raise ValueError("a surveyed position needs lat, lon and alt_m together")
        return self


class Radar(_Strict):
    name: str
    sac: Sac
    sic: Sac
    lat: Annotated[float, Field(ge=-90.0, le=90.0)]
    lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    alt_m: float
    """Antenna height above mean sea level."""
    geoid_m: float = 0.0
    """Geoid undulation at the site (about 45 m in central Europe): see geodesy.RadarSite."""
    north_offset_deg: Annotated[float, Field(ge=-180.0, le=180.0)] = 0.0
    antenna_period_s: Annotated[float, Field(gt=0.5, le=60.0)]
    sigma_range_m: Annotated[float, Field(gt=0.0)]
    sigma_azimuth_deg: Annotated[float, Field(gt=0.0)]
    psr_sigma_range_m: Annotated[float, Field(gt=0.0)] | None = None
    psr_sigma_azimuth_deg: Annotated[float, Field(gt=0.0)] | None = None
    field_monitor: FieldMonitor | None = None
    fixed_transponders: list[FixedTransponder] = []
    """Stationary transponders, by address and/or code, surveyed or not: never tracked."""
    reference: bool = False
    """The radar's systematic errors are known (surveyed): the bias filters anchor on it."""
    time_base: Literal["data", "reception"] = "data"
    """Whose clock times its plots: "data", the radar's own (I140), checked against its
    reception (a feed far from it is reported in status); "reception", the radar's time
    re-based on the reception time (a replayed capture sent live, a radar whose clock is
    wrong): its plots keep their spacing, shifted by the measured offset."""
    input: Input | None = None
    """Where its datagrams arrive; a replay needs none."""

    @property
    def key(self) -> str:
        return f"{self.sac}/{self.sic}"


class AdsbFeed(_Strict):
    name: str = ""
    sac: Sac
    sic: Sac
    input: Input | None = None

    @property
    def key(self) -> str:
        return f"{self.sac}/{self.sic}"


class SystemConfig(_Strict):
    """The system plane and the tracker's identity as a data source (CAT062/065 I010)."""

    centre_lat: Annotated[float, Field(gt=-90.0, lt=90.0)]
    centre_lon: Annotated[float, Field(ge=-180.0, le=180.0)]
    projection: PlaneKind = "stereographic"
    sac: Sac
    sic: Sac
    service_id: Sac = 1
    """CAT062/065 I015: the service these tracks belong to."""
    holding_window_s: Annotated[float, Field(ge=0.0, le=30.0)] = 1.0
    """Data is merged across radars in time order once it is this old, so that late data
    up to this delay lands in the same order in every run (same input, same output)."""
    holding_window_max_datagrams: Annotated[int, Field(ge=100, le=10_000_000)] = 50_000
    holding_window_max_mb: Annotated[float, Field(gt=0.0, le=4096.0)] = 32.0
    """What the holding window may hold at most: a burst beyond is dropped and counted
    (``drops`` in status), not buffered in full."""
    max_behind_s: Annotated[float, Field(gt=0.0, le=3600.0)] = 10.0
    """Live (``run``): a datagram, or a radar process's batch, whose turn comes this many
    seconds behind the wall clock (beyond the holding window) is dropped unprocessed and
    counted (``drop_causes.behind`` in status). An overloaded chain so sheds load and
    keeps its picture at most this late, its memory bounded, rather than fall further
    behind with a backlog that grows without end."""
    max_output_restarts: Annotated[int, Field(ge=0, le=1000)] = 5
    """The daemon restarts its output process when it dies, up to this many times within
    10 minutes; one more death and it exits with status 1 (for systemd or Docker to
    restart it)."""
    max_unknown_sources: Annotated[int, Field(ge=0, le=256)] = 8
    """SAC/SICs not in the configuration that are still tracked (at an assumed site, out
    of fusion); plots of further unknown sources are dropped and counted."""
    warm_up: bool = True
    """Live (``run``, every role): each process, its inputs bound, first takes two
    minutes of generated traffic through throwaway copies of its stages, so that its
    compiled kernels are ready for the first live data (``service/warm_up.py``): a few
    seconds at each start, up to two minutes of compilation at the first after an
    installation, instead of a chain that falls behind and sheds its first minute."""


class ZenohConfig(_Strict):
    mode: Literal["peer", "client", "router"] | None = None
    """None: the config_file's mode, else peer."""
    listen: list[str] = []
    connect: list[str] = []
    """Endpoints added to the config_file's (and the command line's to these)."""
    config_file: Path | None = None
    """A zenoh JSON5 configuration (TLS, access control, routers): docs/security.md."""
    scouting: bool = False
    """Multicast and gossip scouting (finding peers on the LAN), off unless asked for
    here, on the command line or in the config_file."""
    allow_plaintext: bool = False
    """Allow plaintext endpoints beside a config_file that configures TLS."""
    prefix: str = "tracker"
    period_s: Annotated[float, Field(gt=0.0, le=60.0)] | None = None
    """Every this many seconds of data time, the whole picture (every live system track
    extrapolated to one common time, a multiple of the period) on ``<prefix>/picture``
    (JSON list) and ``<prefix>/cat062/picture`` (CAT062 + CAT065 end of batch); none when
    unset. The updates go on as they are."""

    @field_validator("listen", "connect")
    @classmethod
    def _endpoints(cls, values: list[str]) -> list[str]:
        for value in values:
            protocol, _, address = value.partition("/")
            if not protocol or not address:
                raise ValueError(
                    f"{value!r} is not a zenoh endpoint: expected PROTOCOL/ADDRESS, "
                    "e.g. 'tcp/0.0.0.0:7447' or 'udp/224.0.0.224:7446'"
                )
        return values

    @field_validator("prefix")
    @classmethod
    def _prefix(cls, value: str) -> str:
        if not value or value.startswith("/") or value.endswith("/") or set(value) & set("*$?#"):
            raise ValueError(
                f"{value!r} is not a key prefix: non-empty, no leading or trailing '/', "
                "no wildcard characters (* $ ? #)"
            )
        return value


class McapConfig(_Strict):
    directory: Path | None = None
    """Where the log files go; no log when unset."""
    rotate_size_mb: Annotated[float, Field(gt=0.0)] = 256.0
    rotate_duration_s: Annotated[float, Field(gt=0.0)] = 3600.0
    chunk_size: Annotated[int, Field(ge=1024, le=64 * 1024 * 1024)] = 256 * 1024
    """A SIGKILL loses the chunk being written: at 2,000 plots/s the whole log (datagrams,
    plots, tracks as JSON) is about 0.5-1 MB/s, so 256 KiB is well under a second."""


class AsterixUdpOutput(_Strict):
    """One destination of ASTERIX over UDP (``[[asterix_udp]]``): CAT062 system tracks,
    CAT065 SDPS status and batch markers, CAT063 sensor status, sent as the SDPS
    ([system] sac, sic, service_id) to a multicast group or a unicast address."""

    address: IPv4Address
    port: Port
    interface: IPv4Address | None = None
    """Multicast only: the local address whose interface sends (the default route's when
    unset)."""
    ttl: Annotated[int, Field(ge=1, le=255)] = 1
    """Multicast only: how many routers the datagrams may cross (1: this LAN only)."""
    on_update: bool = True
    """Each system track as it is updated (CAT062 at the track's own time)."""
    period_s: Annotated[float, Field(gt=0.0, le=60.0)] | None = None
    """Every this many seconds of data time, every live system track extrapolated to one
    common time (a multiple of the period), followed by a CAT065 end of batch; none
    when unset."""
    status_period_s: Annotated[float, Field(gt=0.0, le=600.0)] | None = None
    """CAT065 SDPS status and CAT063 sensor status (per radar: connection, biases as
    estimated) at each status of the service (every 5 s) when unset, else at most this
    often."""
    service_id: Sac | None = None
    """I015 of this destination's records; [system] service_id when unset."""
    max_datagram_octets: Annotated[int, Field(ge=256, le=65_000)] = 1400
    """Data blocks are packed into datagrams of at most this size (one Ethernet frame)."""

    @model_validator(mode="after")
    def _something(self) -> AsterixUdpOutput:
        if not self.on_update and self.period_s is None:
            raise ValueError(
                "an asterix_udp output sends nothing with on_update = false and no "
                "period_s: set either"
            )
        if self.address == ANY_ADDRESS:
            raise ValueError("address 0.0.0.0 is no destination: give a group or a host")
        return self

    @property
    def destination(self) -> str:
        return f"{self.address}:{self.port}"


class FoxgloveConfig(_Strict):
    """The Foxglove channels (the log's, the live view's): ``outputs/foxglove_scene.py``."""

    listen: str | None = None
    """HOST:PORT of the live view's WebSocket server (the Foxglove SDK); none when unset."""
    trail_s: Annotated[float, Field(ge=0.0, le=3600.0)] = 180.0
    """How much of each track's past the map shows as its trail."""
    picture_period_s: Annotated[float, Field(ge=0.1, le=60.0)] = 1.0
    """Data seconds between two pictures of the live view (GeoJSON of every track)."""
    log_picture_period_s: Annotated[float, Field(ge=0.1, le=60.0)] = 4.0
    """The same in the log, where the picture (about 1.2 kB a track before compression)
    is the biggest channel: one a scan; every update is on ``/foxglove/tracks``."""
    range_nm: Annotated[float, Field(gt=0.0, le=500.0)] = 250.0
    """The range ring drawn around each radar site."""
    ranges_nm: dict[str, Annotated[float, Field(gt=0.0, le=500.0)]] = {}
    """Per radar ("SAC/SIC") a range ring of its own instead of ``range_nm``."""


class ServiceConfig(_Strict):
    radars: Annotated[list[Radar], Field(min_length=1)]
    adsb: list[AdsbFeed] = []
    system: SystemConfig
    tracker: dict[str, Any] = {}
    fusion: dict[str, Any] = {}
    bias: dict[str, Any] = {}
    time_sanity: dict[str, Any] = {}
    """Fields of ``time_sanity.TimeSanityConfig`` (tolerances of the plots' times)."""
    fixed_targets: dict[str, Any] = {}
    atmosphere: dict[str, Any] = {}
    """QNH and ISA deviation of the Mode C conversion (``geodesy.Atmosphere``: qnh_hpa,
    isa_deviation_k); ISA when empty."""
    zenoh: ZenohConfig = ZenohConfig()
    mcap: McapConfig = McapConfig()
    asterix_udp: list[AsterixUdpOutput] = []
    """ASTERIX over UDP destinations (CAT062, CAT063, CAT065): outputs/asterix_udp.py."""
    foxglove: FoxgloveConfig = FoxgloveConfig()

    @field_validator("tracker")
    @classmethod
    def _tracker_fields(cls, table: dict[str, Any]) -> dict[str, Any]:
        unknown = sorted(table.keys() - TRACKER_FIELDS.keys())
        if unknown:
            raise ValueError(
                f"unknown tracker setting(s) {unknown}; allowed: {sorted(TRACKER_FIELDS)}"
            )
        return table

    @field_validator("fusion")
    @classmethod
    def _fusion(cls, table: dict[str, Any]) -> dict[str, Any]:
        # FusionConfig's checks raise ValueError naming the setting (``[fusion] adsb``).
        FusionConfig(**dataclass_kwargs("fusion", table, FusionConfig))
        return table

    @field_validator("fixed_targets")
    @classmethod
    def _fixed_targets(cls, table: dict[str, Any]) -> dict[str, Any]:
        # Its checks raise ValueError naming the setting; pydantic adds the table's name.
        FixedTargetConfig(**dataclass_kwargs("fixed_targets", table, FixedTargetConfig))
        return table

    @field_validator("atmosphere")
    @classmethod
    def _atmosphere(cls, table: dict[str, Any]) -> dict[str, Any]:
        Atmosphere(**dataclass_kwargs("atmosphere", table, Atmosphere))
        return table

    def atmosphere_config(self) -> Atmosphere:
        """What turns Mode C into geometric heights: the ``[atmosphere]`` table."""
        return Atmosphere(**dataclass_kwargs("atmosphere", self.atmosphere, Atmosphere))

    def fixed_target_config(self) -> FixedTargetConfig:
        """How the chain detects stationary transponders: the ``[fixed_targets]`` table."""
        return FixedTargetConfig(
            **dataclass_kwargs("fixed_targets", self.fixed_targets, FixedTargetConfig)
        )

    @model_validator(mode="after")
    def _unique(self) -> ServiceConfig:
        feeds: list[Radar | AdsbFeed] = [*self.radars, *self.adsb]
        keys = [f.key for f in feeds] + [f"{self.system.sac}/{self.system.sic}"]
        duplicated = sorted({k for k in keys if keys.count(k) > 1})
        if duplicated:
            raise ValueError(
                f"SAC/SIC used twice: {duplicated}; every radar, ADS-B feed and the "
                "system itself ([system] sac/sic) needs its own"
            )
        endpoints = [
            (feed.key, lan)
            for feed in feeds
            if feed.input is not None
            for lan in feed.input.endpoints()
        ]
        for i, (key_a, a) in enumerate(endpoints):
            for key_b, b in endpoints[i + 1 :]:
                if _clash(a, b):
                    raise ValueError(
                        f"inputs of {key_a} and {key_b} both listen on "
                        f"{a.address}:{a.port} / {b.address}:{b.port}; each input needs its "
                        "own group or port (0.0.0.0 takes the whole port)"
                    )
        return self

    def tracker_config(self) -> TrackerConfig:
        """The local tracker's settings: defaults overridden by the ``[tracker]`` table."""
        # TOML has no tuples: the tuple-valued fields arrive as lists.
        values: dict[str, Any] = {
            k: tuple(v) if isinstance(v, list) else v for k, v in self.tracker.items()
        }
        return dataclasses.replace(TrackerConfig(), **values)


def _clash(a: Lan, b: Lan) -> bool:
    """Two endpoints that would receive each other's datagrams (bound on one port)."""
    if a.port != b.port:
        return False
    if ANY_ADDRESS in (a.address, b.address):
        return True
    return a.address == b.address and a.interface == b.interface


def load_service_config(path: str | Path) -> ServiceConfig:
    file = Path(path)
    try:
        data = tomllib.loads(file.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{file}: no such configuration file") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{file}: not valid TOML: {exc}") from None
    return parse_service_config(data, str(file))


def parse_service_config(data: dict[str, Any], origin: str = "configuration") -> ServiceConfig:
    """A parsed TOML document (or any dict) as a configuration; ``origin`` heads errors."""
    try:
        return ServiceConfig.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{origin}: {describe_errors(exc, ServiceConfig)}") from None


def with_destinations(config: ServiceConfig, destinations: list[str]) -> ServiceConfig:
    """The configuration with an ``[[asterix_udp]]`` on update per ``HOST:PORT`` of the
    command line (``--asterix-udp``) added; ValueError naming a malformed one."""
    added = []
    for text in destinations:
        host, port = parse_destination(text)
        try:
            added.append(AsterixUdpOutput(address=host, port=port))  # type: ignore[arg-type]
        except ValueError as exc:
            raise ValueError(f"--asterix-udp {text}: {_first_error(exc)}") from None
    if not added:
        return config
    return config.model_copy(update={"asterix_udp": [*config.asterix_udp, *added]})


def _first_error(exc: ValueError) -> str:
    errors = getattr(exc, "errors", None)
    if callable(errors):
        first = errors()[0]
        return f"{first['msg']} (got {first.get('input')!r})"
    return str(exc)
