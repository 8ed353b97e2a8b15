"""The processing chain: datagrams of radars in, plots, local tracks and system tracks out.

One ``Chain`` is the in-process composition of the two stages: the radar stage
(``radar_stage.RadarStage``: source admission, plot clock, time sanity, conversion, test
targets and fixed transponders, one local tracker per radar) and the central stage
(``central_stage.CentralStage``: the radars' time against each other, bias correction and
estimation, fusion), which talk through ``stage_messages.RadarBatch`` as they do over Zenoh
(``distribution``). The evaluation, the replay and the daemon all feed it datagrams in
the order they have them; it keeps nothing of theirs. Each radar is identified by the
SAC/SIC its plots carry, not by the socket they came from: a datagram that mixes radars
is split. A replay with workers gives the chain a ``radar_stage`` whose radars run in
other processes (``distribution.RemoteRadarStages``): the rest is the same code.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from tracker_service.adsb import AdsbReference, AdsbReports
from tracker_service.bias import BiasConfig, BiasEstimator, ObservedFrom
from tracker_service.central_stage import BatchOutput, CentralStage
from tracker_service.fixed_targets import FixedTargetConfig
from tracker_service.fusion import FusionConfig, SystemTracker
from tracker_service.geodesy import Atmosphere, RadarSite, SystemPlane
from tracker_service.radar_stage import (
    CAT001,
    CAT002,
    CAT021,
    CAT034,
    CAT048,
    KIND_UNKNOWN,
    NM,
    PLOT_CATEGORIES,
    RAW_PLOT_DTYPE,
    SERVICE_CATEGORIES,
    FieldMonitor,
    PlotUse,
    RadarInfo,
    RadarStage,
    RadarState,
    StageStats,
    blocks_of,
    convert_batch,
    rejections,
    source_order,
)
from tracker_service.sources import DEFAULT_MAX_UNKNOWN, SourceCounts
from tracker_service.stage_messages import RadarBatch
from tracker_service.time_sanity import TimeSanity, TimeSanityConfig
from tracker_service.tracking import LocalTracker, TrackerConfig

__all__ = [
    "CAT001",
    "CAT002",
    "CAT021",
    "CAT034",
    "CAT048",
    "KIND_UNKNOWN",
    "NM",
    "PLOT_CATEGORIES",
    "RAW_PLOT_DTYPE",
    "SERVICE_CATEGORIES",
    "BatchOutput",
    "Chain",
    "ChainStats",
    "FieldMonitor",
    "PlotUse",
    "RadarInfo",
    "RadarStageFailed",
    "RadarStages",
    "RadarState",
    "blocks_of",
    "convert_batch",
    "radar_infos",
    "recording_atmosphere",
    "rejections",
    "source_order",
    "system_plane",
]

log = logging.getLogger(__name__)

FloatArray = npt.NDArray[np.float64]
ChainStats = StageStats
"""The chain's counts are its radar stage's."""


class RadarStageFailed(RuntimeError):
    """The radar side is gone (a worker process died): no datagram's fault, so the
    service does not count and skip it but stops."""


class Admission(Protocol):
    """What the service reads of source admission (``SourceAdmission``)."""

    @property
    def counts(self) -> SourceCounts: ...


class RadarStages(Protocol):
    """What the chain needs of its radar side: one ``RadarStage``, or stages in other
    processes behind a proxy."""

    stats: StageStats
    radars: dict[str, RadarState]

    @property
    def admission(self) -> Admission: ...

    def feed(self, payload: bytes, received: float, order: int) -> list[RadarBatch]: ...


class Chain:
    """See the module docstring. ``tracker``: ``TrackerConfig`` fields for every radar
    (``scan_period_s`` comes from each radar's period unless given); ``fusion``: the
    fuser's configuration (None: local tracks only); ``make_tracker(source, config)``
    builds each radar's tracker (a benchmark passes one that times it);
    ``max_unknown_sources``: radars not in ``radars`` tracked at most (``sources``);
    ``radar_stage``: the radar side when it is not a ``RadarStage`` of this process;
    ``atmosphere``: QNH and ISA deviation of the Mode C conversion (ISA when None);
    ``bias_history``: keep the biases' history (``CentralStage``), as an evaluation does."""

    def __init__(
        self,
        radars: Mapping[str, RadarInfo],
        plane: SystemPlane,
        tracker: Mapping[str, Any] | None = None,
        make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
        fusion: FusionConfig | None = None,
        bias: BiasConfig | None = None,
        time_sanity: TimeSanityConfig | None = None,
        fixed_targets: FixedTargetConfig | None = None,
        max_unknown_sources: int = DEFAULT_MAX_UNKNOWN,
        radar_stage: RadarStages | None = None,
        atmosphere: Atmosphere | None = None,
        bias_history: bool = False,
    ) -> None:
        self.infos = dict(radars)
        self.plane = plane
        self.fixed_targets = fixed_targets or FixedTargetConfig()
        self.radar_stage: RadarStages = radar_stage or RadarStage(
            radars,
            plane,
            tracker,
            make_tracker,
            time_sanity,
            self.fixed_targets,
            max_unknown_sources,
            atmosphere=atmosphere,
        )
        self.central = CentralStage(radars, plane, fusion, bias, time_sanity, bias_history)
        self.sources = self.central.fusion_sources
        """The fuser's sources by index: the radars in SAC/SIC order, then ADS-B when fused."""
        self._order = 0

    @property
    def stats(self) -> StageStats:
        return self.radar_stage.stats

    @property
    def admission(self) -> Admission:
        return self.radar_stage.admission

    @property
    def radars(self) -> dict[str, RadarState]:
        """The radars of a radar stage in this process (empty when they run elsewhere)."""
        return self.radar_stage.radars

    @property
    def time_sanity(self) -> TimeSanity:
        stage = self.radar_stage
        if not isinstance(stage, RadarStage):
            raise RuntimeError("the radar stages run in other processes")
        return stage.time_sanity

    @property
    def fuser(self) -> SystemTracker | None:
        return self.central.fuser

    @property
    def bias(self) -> BiasEstimator | None:
        return self.central.bias

    @property
    def adsb(self) -> AdsbReference | None:
        return self.central.adsb

    @property
    def bias_history(self) -> list[tuple[float, str, FloatArray, FloatArray]]:
        return self.central.bias_history

    @property
    def clock_history(self) -> list[tuple[float, str, FloatArray, FloatArray]]:
        return self.central.clock_history

    def clock_estimates(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Each fused radar's clock drift (and drift rate) and covariance (``BiasConfig
        .clock_states``); empty without bias estimation."""
        return self.central.clock_estimates()

    def decode_adsb(self, payload: bytes, received: float) -> list[AdsbReports]:
        """The reports of each CAT021 block of a datagram (``CentralStage.decode_adsb``)."""
        return self.central.decode_adsb(payload, received)

    def feed(
        self, payload: bytes, received: float, adsb: list[AdsbReports] | None = None
    ) -> list[BatchOutput]:
        """Process one datagram received at ``received`` (POSIX s); ``adsb``: its CAT021
        reports when the caller has decoded them already (``decode_adsb``)."""
        order = self._order
        self._order += 1
        if adsb is None:
            adsb = self.decode_adsb(payload, received) if self.central.takes_adsb else []
        return self.central.feed_adsb(adsb) + [
            self.central.process(batch) for batch in self.radar_stage.feed(payload, received, order)
        ]

    def bias_estimates(self) -> dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]:
        """Each fused radar's current bias [range offset m, gain, azimuth rad, time s] (then
        its clock's drift and drift rate, ``BiasConfig.clock_states``) and its covariance;
        empty without bias estimation."""
        return self.central.bias_estimates()

    def bias_observed_from(self) -> dict[str, ObservedFrom]:
        """Each fused radar's sources of each bias component; empty without bias
        estimation."""
        return self.central.bias_observed_from()


def _finite(value: Any, default: float) -> float:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else default


def radar_infos(
    metadata: Mapping[str, Any],
    overrides: Mapping[str, Mapping[str, float]] | None = None,
    geoid_m: float = 0.0,
) -> dict[str, RadarInfo]:
    """The radars of a recording's metadata (the simulator's scenario radars), with
    ``overrides`` per "SAC/SIC" of any ``RadarInfo``/``RadarSite`` field (lat_deg, lon_deg,
    alt_m, geoid_m, north_offset_deg, period_s, sigma_*). Only what a radar operator would
    know is read: site, period, sigmas and the field monitor's survey, never the truth of
    its errors."""
    overrides = overrides or {}
    infos: dict[str, RadarInfo] = {}
    for source, radar in dict(metadata.get("radars", {})).items():
        override = dict(overrides.get(source, {}))
        site = RadarSite(
            lat_deg=float(override.pop("lat_deg", radar["lat"])),
            lon_deg=float(override.pop("lon_deg", radar["lon"])),
            alt_m=float(override.pop("alt_m", radar["alt_m"])),
            geoid_m=float(override.pop("geoid_m", geoid_m)),
            north_offset_deg=float(override.pop("north_offset_deg", 0.0)),
        )
        sigma_range = float(
            override.pop("sigma_range_m", _finite(radar.get("sigma_range_m"), 50.0))
        )
        sigma_azimuth = float(
            override.pop("sigma_azimuth_deg", _finite(radar.get("sigma_azimuth_deg"), 0.07))
        )
        # Without PSR sigmas, PSR-only plots are taken as accurate as the others.
        psr_range = _finite(radar.get("psr_sigma_range_m"), sigma_range)
        psr_azimuth = _finite(radar.get("psr_sigma_azimuth_deg"), sigma_azimuth)
        monitor = radar.get("field_monitor")
        infos[source] = RadarInfo(
            source=source,
            site=site,
            period_s=float(override.pop("period_s", _finite(radar.get("antenna_period_s"), 5.0))),
            sigma_range_m=sigma_range,
            sigma_azimuth_deg=sigma_azimuth,
            psr_sigma_range_m=float(override.pop("psr_sigma_range_m", psr_range)),
            psr_sigma_azimuth_deg=float(override.pop("psr_sigma_azimuth_deg", psr_azimuth)),
            field_monitor=(
                FieldMonitor(float(monitor["lat"]), float(monitor["lon"]), float(monitor["alt_m"]))
                if isinstance(monitor, dict)
                else None
            ),
        )
        if override:
            raise ValueError(f'[radars."{source}"]: unknown fields {sorted(override)}')
    for source in overrides:
        if source not in infos:
            log.warning("configured radar %s is not in the recording's metadata", source)
    return infos


def system_plane(metadata: Mapping[str, Any], infos: Mapping[str, RadarInfo]) -> SystemPlane:
    """The scenario's system centre, or the mean of the sites when it gives none."""
    centre = dict(metadata.get("scenario", {})).get("system_centre")
    if isinstance(centre, dict) and "lat" in centre and "lon" in centre:
        return SystemPlane(float(centre["lat"]), float(centre["lon"]))
    if not infos:
        raise ValueError("the recording names no radar and no system centre")
    lat = float(np.mean([i.site.lat_deg for i in infos.values()]))
    lon = float(np.mean([i.site.lon_deg for i in infos.values()]))
    return SystemPlane(lat, lon)


def recording_atmosphere(metadata: Mapping[str, Any]) -> Atmosphere:
    """The scenario's atmosphere (QNH, temperature offset from ISA): the met report an
    operator would configure for the Mode C conversion; ISA when it gives none."""
    atmosphere = dict(metadata.get("scenario", {})).get("atmosphere")
    if not isinstance(atmosphere, dict):
        return Atmosphere()
    return Atmosphere(
        qnh_hpa=float(atmosphere.get("qnh_hpa", 1013.25)),
        isa_deviation_k=float(atmosphere.get("temperature_offset_k", 0.0)),
    )
