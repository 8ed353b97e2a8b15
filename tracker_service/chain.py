"""The processing chain: datagrams of radars in, plots, local tracks and system tracks out.

One ``Chain`` holds every stage after the codec: the plot clock (``ingest.PlotClock``, fed
with the CAT034 and CAT002 service messages), the conversion to the system plane (``geodesy``), one
``LocalTracker`` per radar, and, once configured, the bias estimator and the fuser. The
evaluation, the replay and the daemon all feed it datagrams in the order they have them;
it keeps nothing of theirs. Each radar is identified by the SAC/SIC its plots carry, not
by the socket they came from: a datagram that mixes radars is split.

A radar that the configuration does not know is still tracked (with a warning), in a
plane of its own centred on an assumed site (the system centre): its local tracks are
shaped right, but without a surveyed site they are placed wrong, so they are kept out of
fusion and bias estimation. Field-monitor plots (I020 RAB = 1) are a radar's test
transponder at a surveyed position: never tracked, they are a reference for its biases.
Test targets (I020 TST) and simulated reports (SIM) are never tracked either, nor fixed
transponders (``fixed_targets``: configured or detected), the surveyed ones of which are
bias references like field monitors.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from asterix.plots import extract_plots
from tracker_service.adsb import AdsbReference
from tracker_service.bias import (
    BiasConfig,
    BiasEstimator,
    BiasObservations,
    ObservationKind,
    ObservedFrom,
    concatenate,
    make_bias_estimator,
    make_observations,
)
from tracker_service.fixed_targets import FixedTargetConfig, FixedTargets, FixedTransponder
from tracker_service.fusion import SYSTEM_UPDATE_DTYPE, FusionConfig, References, SystemTracker
from tracker_service.geodesy import HeightModel, RadarSite, SystemPlane, convert_plots
from tracker_service.ingest import PlotClock
from tracker_service.sources import DEFAULT_MAX_UNKNOWN, SourceAdmission
from tracker_service.time_sanity import TimeBase, TimeReport, TimeSanity, TimeSanityConfig
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig

__all__ = [
    "KIND_UNKNOWN",
    "RAW_PLOT_DTYPE",
    "BatchOutput",
    "Chain",
    "FieldMonitor",
    "PlotUse",
    "RadarInfo",
    "blocks_of",
    "convert_batch",
    "radar_infos",
    "rejections",
    "source_order",
    "system_plane",
]

log = logging.getLogger(__name__)

NM = 1852.0
CAT001 = 1
CAT002 = 2
CAT021 = 21
CAT034 = 34
CAT048 = 48
PLOT_CATEGORIES = (CAT048, CAT001)
SERVICE_CATEGORIES = (CAT034, CAT002)
"""Radar service messages (north markers, sector crossings) of CAT048 and CAT001 radars."""
MONITOR_SURVEY_VARIANCE_M2 = 1.0
"""A field monitor's surveyed position: metre-level, against plots of tens of metres."""
BIAS_HISTORY_S = 10.0
ABSOLUTE_ENOUGH = 100
"""ADS-B observations of a radar after which other radars' tracks no longer serve as its
reference."""

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
_NO_SYSTEM_ROWS = np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)
KIND_UNKNOWN = -1

RAW_PLOT_DTYPE = np.dtype(
    [
        ("plot_id", np.int64),
        ("sequence", np.int64),  # datagram number of the source (LAN A in a recording)
        ("record", np.int64),  # CAT048 record index within that datagram
        ("time", np.float64),  # POSIX time of measurement the tracker used
        ("time_source", np.int8),  # ingest.TimeSource
        ("x", np.float64),
        ("y", np.float64),
        ("R", np.float64, (2, 2)),
        ("rho_m", np.float64),
        ("theta_deg", np.float64),
        ("flight_level", np.float64),  # NaN when absent, invalid or garbled
        ("typ", np.int64),
        ("rab", np.bool_),  # field monitor
        ("address", np.int64),  # Mode S address, -1 when absent
        ("mode3a", np.int64),  # Mode 3/A code as an integer, -1 when absent
        ("callsign", "U8"),  # I048/240, "" when absent
        ("kind", np.int8),  # what the plot truly is, when an evaluation knows (KIND_*)
        ("aircraft", np.int64),  # origin aircraft index, -1 when none or unknown
        ("detection_time", np.float64),  # true time of detection, NaN when unknown
        ("use", np.int8),  # PlotUse: what the chain did with the plot
    ]
)
"""One converted plot of one radar, as received (before any bias correction), with room
for its truth origin."""


class PlotUse(IntEnum):
    """What the chain did with a plot: tracked, or kept out of traffic tracking and why.
    Every plot of a radar's table carries one; status counts the others per radar by
    their lower-case name."""

    TRACKED = 0
    FIELD_MONITOR = 1
    """I020 RAB = 1: a radar's test transponder, a bias reference, never tracked."""
    RADAR_TRACK = 2
    """A CAT001 track report (I020 TYP = 1): the radar's own smoothed track, not a plot."""
    TIME_IMPLAUSIBLE = 3
    """Its time does not fit its radar's timeline (``time_sanity``)."""
    TEST_TARGET = 4
    """I020 TST = 1: a test target the radar injects (its check is in status)."""
    SIMULATED = 5
    """I020 SIM = 1: a simulated target report."""
    FIXED_TRANSPONDER = 6
    """A stationary transponder, configured or detected (``fixed_targets``); a bias
    reference where its position is surveyed."""
    NO_POSITION = 7
    """No measured position (RHO or THETA absent: a CAT048 TYP 0 "no detection" record)."""


def rejections(use: npt.NDArray[np.int8]) -> dict[str, int]:
    """Counts of a table's plots kept out of tracking, by reason (``PlotUse`` names)."""
    codes, counts = np.unique(use[use != PlotUse.TRACKED], return_counts=True)
    return {PlotUse(code).name.lower(): int(n) for code, n in zip(codes, counts, strict=True)}


@dataclass(frozen=True)
class FieldMonitor:
    """A radar's fixed test transponder at a surveyed position (height above MSL)."""

    lat_deg: float
    lon_deg: float
    alt_m: float


@dataclass(frozen=True)
class RadarInfo:
    """What the chain needs to know of one radar."""

    source: str
    site: RadarSite
    period_s: float
    sigma_range_m: float
    sigma_azimuth_deg: float
    psr_sigma_range_m: float
    psr_sigma_azimuth_deg: float
    field_monitor: FieldMonitor | None = None
    fixed_transponders: tuple[FixedTransponder, ...] = ()
    surveyed: bool = True
    """False for a radar the configuration does not know (an assumed site)."""
    time_base: TimeBase = "data"
    """"reception": its plots' times re-based on reception (``time_sanity``)."""


def source_order(source: str) -> tuple[int, ...]:
    """Sort key of "SAC/SIC" texts: by number, not as text."""
    return tuple(int(part) for part in source.split("/"))


def blocks_of(payload: bytes, category: int) -> Iterator[bytes]:
    """The data blocks of one category in a datagram, by their headers alone (cheap: the
    plot path needs the service messages decoded, not every block)."""
    pos = 0
    while pos + 3 <= len(payload):
        length = int.from_bytes(payload[pos + 1 : pos + 3])
        if length < 3 or pos + length > len(payload):
            return
        if payload[pos] == category:
            yield payload[pos : pos + length]
        pos += length


def convert_batch(
    raw: npt.NDArray[Any],
    info: RadarInfo,
    plane: SystemPlane,
    clock: PlotClock,
    heights: HeightModel,
    received: float,
    first_id: int,
    sequence: int,
    bias: FloatArray | None = None,
    surveyed_height: FloatArray | None = None,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any], FloatArray | None]:
    """One datagram's plots of one radar (``asterix.plots`` rows): timed, converted to the
    system plane, as the tracker's batch (``tracking.PLOT_DTYPE``), as a
    ``RAW_PLOT_DTYPE`` table (origins unknown) with plot ids from ``first_id``, and, when
    ``bias`` is given, the bias Jacobian C (N, 2, 4) of each plot's plane position (its
    time column, which needs the aircraft's velocity, left 0).

    ``bias``: the radar's estimated systematic errors [range offset m, range gain,
    azimuth rad, time s], removed from the batch (not from the table, which keeps the
    plots as the radar sent them). ``surveyed_height``: per plot, the surveyed height (m
    above MSL) of the fixed transponder it is, NaN for the others."""
    n = len(raw)
    times, time_sources = clock.times(raw, received)
    fl = np.asarray(raw["flight_level"], dtype=np.float64)
    # V = 1 (not validated) and G = 1 (garbled) Mode C is no height: the HeightModel's
    # stand-in and its large sigma take over, and the tracker's vertical filter skips it.
    fl_ok = (
        np.isfinite(fl) & (raw["flight_level_invalid"] != 1) & (raw["flight_level_garbled"] != 1)
    )
    fl_clean = np.where(fl_ok, fl, np.nan)
    height, height_sigma = heights.heights(fl_clean)
    rab = np.asarray(raw["rab"]) == 1
    if info.field_monitor is not None and rab.any():
        # The test transponder's height is surveyed: better than its Mode C.
        height = np.where(rab, info.field_monitor.alt_m, height)
        height_sigma = np.where(rab, 0.0, height_sigma)
    if surveyed_height is not None:
        # A fixed transponder's Mode C is often a test value (FL719), not its height.
        known = np.isfinite(surveyed_height)
        height = np.where(known, surveyed_height, height)
        height_sigma = np.where(known, 0.0, height_sigma)
    psr_only = raw["typ"] == 1
    sigma_rho = np.where(psr_only, info.psr_sigma_range_m, info.sigma_range_m)
    sigma_theta = np.where(psr_only, info.psr_sigma_azimuth_deg, info.sigma_azimuth_deg)
    rho_m = np.asarray(raw["rho"], dtype=np.float64) * NM
    theta = np.asarray(raw["theta"], dtype=np.float64)
    rho_c, theta_c, times_c = rho_m, theta, times
    if bias is not None:
        rho_c = (rho_m - bias[0]) / (1.0 + bias[1])
        theta_c = theta - np.degrees(bias[2])
        times_c = times - bias[3]

    converted = convert_plots(
        info.site, plane, rho_c, theta_c, height, height_sigma, sigma_rho, sigma_theta
    )
    c: FloatArray | None = None
    if bias is not None:
        c = np.zeros((n, 2, 4))
        c[:, :, 0] = converted.polar_jacobian[:, :, 0]
        c[:, :, 1] = converted.polar_jacobian[:, :, 0] * rho_c[:, None]
        c[:, :, 2] = converted.polar_jacobian[:, :, 1]
    ids = np.arange(first_id, first_id + n, dtype=np.int64)
    mode3a = np.asarray(raw["mode3a"], dtype=np.int64)

    batch = np.zeros(n, dtype=PLOT_DTYPE)
    batch["time"] = times_c
    batch["x"] = converted.x
    batch["y"] = converted.y
    batch["R"] = converted.R
    batch["flight_level"] = fl
    batch["fl_valid"] = fl_ok
    batch["mode3a"] = mode3a
    batch["mode3a_valid"] = (
        (mode3a >= 0) & (raw["mode3a_invalid"] != 1) & (raw["mode3a_garbled"] != 1)
    )
    batch["address"] = raw["address"]
    batch["typ"] = raw["typ"]
    batch["plot_id"] = ids

    table = np.zeros(n, dtype=RAW_PLOT_DTYPE)
    table["plot_id"] = ids
    table["sequence"] = sequence
    table["record"] = np.arange(n)
    table["time"] = times
    table["time_source"] = time_sources
    table["x"] = converted.x
    table["y"] = converted.y
    table["R"] = converted.R
    table["rho_m"] = rho_m
    table["theta_deg"] = theta
    table["flight_level"] = fl_clean
    table["typ"] = raw["typ"]
    table["rab"] = rab
    table["address"] = raw["address"]
    table["mode3a"] = mode3a
    table["callsign"] = np.char.strip(raw["callsign"])
    table["kind"] = KIND_UNKNOWN
    table["aircraft"] = -1
    table["detection_time"] = np.nan
    table["use"] = np.select(
        [rab, np.asarray(raw["tst"]) == 1, np.asarray(raw["sim"]) == 1],
        [PlotUse.FIELD_MONITOR, PlotUse.TEST_TARGET, PlotUse.SIMULATED],
        PlotUse.TRACKED,
    )
    table["use"][raw["track_report"] == 1] = PlotUse.RADAR_TRACK
    table["use"][~(np.isfinite(raw["rho"]) & np.isfinite(raw["theta"]))] = PlotUse.NO_POSITION
    if bias is not None and c is not None:
        # The table keeps the plots as sent: uncorrected, to first order.
        shift = c[:, :, :3] @ bias[:3]
        table["x"] += shift[:, 0]
        table["y"] += shift[:, 1]
        table["time"] = times
    return batch, table, c


@dataclass
class BatchOutput:
    """What one radar's part of a datagram produced: its plots (``RAW_PLOT_DTYPE``, every
    plot of the datagram, field monitors included), its local-track updates and the
    system-track rows they caused (``fusion.SYSTEM_UPDATE_DTYPE``)."""

    source: str
    plots: npt.NDArray[Any]
    local: npt.NDArray[Any]
    system: npt.NDArray[Any]
    time: TimeReport | None = None
    """The radar's time as status shows it."""


@dataclass
class RadarState:
    """One radar in the chain: what it is, its plane and its tracker."""

    info: RadarInfo
    plane: SystemPlane
    tracker_config: TrackerConfig
    tracker: LocalTracker
    index: int | None
    """The radar's number in fusion and bias estimation; None when kept out of them."""
    fixed: FixedTargets
    sequence: int = 0
    monitor_xy: FloatArray = field(default_factory=lambda: np.zeros((0, 2)))
    """Per plot of the latest batch, the surveyed position of the field monitor or fixed
    transponder it is (NaN for the others): the bias estimator's monitor observations."""


@dataclass
class ChainStats:
    datagrams: int = 0
    plots: int = 0
    field_monitor_plots: int = 0
    unknown_radars: list[str] = field(default_factory=list)
    decode_errors: int = 0
    """Records (CAT034, CAT048) the codec could not decode inside a valid block chain."""


class Chain:
    """See the module docstring. ``tracker``: ``TrackerConfig`` fields for every radar
    (``scan_period_s`` comes from each radar's period unless given); ``fusion``: the
    fuser's configuration (None: local tracks only); ``make_tracker(source, config)``
    builds each radar's tracker (a benchmark passes one that times it);
    ``max_unknown_sources``: radars not in ``radars`` tracked at most (``sources``)."""

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
    ) -> None:
        self.infos = dict(radars)
        self.fixed_targets = fixed_targets or FixedTargetConfig()
        self.admission = SourceAdmission(self.infos, max_unknown_sources)
        self.plane = plane
        # Fusion numbers the configured radars in SAC/SIC order, so that the same
        # configuration numbers them the same way in every run.
        self.sources = sorted(self.infos, key=source_order)
        self.fuser: SystemTracker | None = None
        if fusion is not None and self.sources:
            longest = max(self.infos[s].period_s for s in self.sources)
            if fusion.longest_period_s < longest:
                fusion = replace(fusion, longest_period_s=longest)
            self.fuser = SystemTracker(len(self.sources), fusion)
        self.bias: BiasEstimator | None = None
        # "off" with reference values still corrects (the true biases given, say).
        if bias is not None and (bias.method != "off" or bias.reference_radars) and self.sources:
            self.bias = make_bias_estimator(bias, len(self.sources))
        self.bias_history: list[tuple[float, str, FloatArray, FloatArray]] = []
        """(time, source, bias, covariance) of each radar every ``BIAS_HISTORY_S`` of data."""
        self.adsb = AdsbReference(plane) if self.bias is not None else None
        self._absolute_references = np.zeros(len(self.sources), dtype=np.int64)
        self._geometry: dict[int, tuple[FloatArray, FloatArray]] | None = (
            {} if bias is not None and bias.method == "macro" else None
        )
        self._monitors = {
            source: np.array(plane.from_geodetic(m.lat_deg, m.lon_deg, m.alt_m), dtype=float)
            for source, info in self.infos.items()
            if (m := info.field_monitor) is not None
        }
        self.stats = ChainStats()
        self.radars: dict[str, RadarState] = {}
        self._tracker_overrides = dict(tracker or {})
        self._make_tracker = make_tracker or (lambda _source, config: LocalTracker(config))
        self._bias_recorded: dict[str, float] = {}
        self._clock = PlotClock()
        self.time_sanity = TimeSanity(
            time_sanity,
            {source: info.time_base for source, info in self.infos.items()},
            {source: info.period_s for source, info in self.infos.items()},
        )
        self._heights = HeightModel()
        self._next_plot_id = 0

    def feed(self, payload: bytes, received: float) -> list[BatchOutput]:
        """Process one datagram received at ``received`` (POSIX s)."""
        self.stats.datagrams += 1
        for category in SERVICE_CATEGORIES:
            for block in blocks_of(payload, category):
                for event in decode_blocks(block):
                    if isinstance(event, Block):
                        for items in event.records:
                            self._clock.service_message(items, received)
                            self.time_sanity.service_message(items, received)
                    else:
                        self.stats.decode_errors += 1
        if self.adsb is not None:
            for block in blocks_of(payload, CAT021):
                self.adsb.feed(block, received)
        if not any(next(blocks_of(payload, c), None) for c in PLOT_CATEGORIES):
            return []  # service messages or ADS-B only: no plot to extract
        extracted = extract_plots(payload)
        self.stats.decode_errors += len(extracted.errors)
        raw = self.admission.admit(extracted.plots)
        if len(raw) == 0:
            return []
        sac, sic = np.asarray(raw["sac"], np.int64), np.asarray(raw["sic"], np.int64)
        keys = np.unique(sac * 256 + sic)
        if len(keys) == 1:
            return [self._radar_batch(f"{sac[0]}/{sic[0]}", raw, received)]
        # Only odd captures mix radars in one datagram.
        return [
            self._radar_batch(f"{key >> 8}/{key & 255}", raw[sac * 256 + sic == key], received)
            for key in keys.tolist()
        ]

    def _radar(self, source: str) -> RadarState:
        state = self.radars.get(source)
        if state is not None:
            return state
        info = self.infos.get(source)
        plane = self.plane
        if info is None:
            log.warning(
                "radar %s is not in the configuration: tracked at an assumed site (the "
                "system centre), in a plane of its own, and kept out of fusion; configure "
                "its site to fuse it",
                source,
            )
            self.stats.unknown_radars.append(source)
            site = RadarSite(plane.centre_lat, plane.centre_lon, 0.0)
            sac, sic = source_order(source)
            period = self._clock.antenna_period(sac, sic) or 5.0  # from its north markers
            info = RadarInfo(source, site, period, 50.0, 0.07, 50.0, 0.07, surveyed=False)
            plane = SystemPlane(site.lat_deg, site.lon_deg, plane.kind)
        overrides = {"scan_period_s": info.period_s, **self._tracker_overrides}
        config = TrackerConfig(**overrides)
        index = self.sources.index(source) if info.surveyed else None
        fixed = FixedTargets(
            info.site, plane, info.period_s, info.fixed_transponders, self.fixed_targets
        )
        state = RadarState(info, plane, config, self._make_tracker(source, config), index, fixed)
        self.radars[source] = state
        return state

    def bias_estimates(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Each fused radar's current bias [range offset m, gain, azimuth rad, time s] and
        its covariance; empty without bias estimation."""
        if self.bias is None:
            return {}
        return {source: self.bias.correction(k) for k, source in enumerate(self.sources)}

    def bias_observed_from(self) -> dict[str, ObservedFrom]:
        """Each fused radar's sources of each bias component (``BiasEstimates``); empty
        without bias estimation."""
        if self.bias is None:
            return {}
        observed = self.bias.estimates().observed_from
        return {source: observed[k] for k, source in enumerate(self.sources)}

    def _radar_batch(self, source: str, raw: npt.NDArray[Any], received: float) -> BatchOutput:
        state = self._radar(source)
        index = state.index
        bias = bias_cov = None
        if self.bias is not None and index is not None:
            bias, bias_cov = self.bias.correction(index)
        batch, table, c = convert_batch(
            raw,
            state.info,
            state.plane,
            self._clock,
            self._heights,
            received,
            self._next_plot_id,
            state.sequence,
            bias,
            state.fixed.surveyed_heights(raw),
        )
        times, implausible = self.time_sanity.check(
            source, table["time"], table["time_source"], table["theta_deg"], received
        )
        shift = times - table["time"]
        if shift.any():
            table["time"] = times
            batch["time"] += shift
        if implausible.any():
            table["use"][implausible & (table["use"] == PlotUse.TRACKED)] = PlotUse.TIME_IMPLAUSIBLE
        state.sequence += 1
        self._next_plot_id += len(raw)
        self.stats.plots += len(raw)
        monitor = table["rab"]
        n_monitor = int(np.count_nonzero(monitor))
        if n_monitor:
            self.stats.field_monitor_plots += n_monitor
        self._fixed_transponders(state, table, batch)
        # The batch keeps the tracker's plots only; the table keeps every plot with its use.
        tracked = table["use"] == PlotUse.TRACKED
        if not tracked.all():
            batch = batch[tracked]
        local = state.tracker.process(batch)
        report = self.time_sanity.report(source, state.tracker)
        # A radar out of step with the others would be fused at the wrong time.
        out_of_step = report.out_of_step_s is not None
        if self.fuser is None or index is None or not len(local) or out_of_step:
            return BatchOutput(source, table, local, _NO_SYSTEM_ROWS, report)
        extra = None
        if bias is not None and bias_cov is not None and c is not None:
            extra = self._estimate_biases(state, table, batch, local, c, bias, bias_cov)
        system = self.fuser.process(index, local, batch, extra)
        return BatchOutput(source, table, local, system, report)

    def _fixed_transponders(
        self, state: RadarState, table: npt.NDArray[Any], batch: npt.NDArray[Any]
    ) -> None:
        """Marks the table's fixed transponders (``fixed_targets``) and keeps, per plot, the
        surveyed position of each field monitor and surveyed fixed transponder."""
        found = state.fixed.classify(
            table, table["use"] == PlotUse.TRACKED, np.asarray(batch["mode3a_valid"])
        )
        table["use"][found.fixed] = PlotUse.FIXED_TRANSPONDER
        monitor_xy = found.reference_xy
        surveyed = self._monitors.get(state.info.source)
        if surveyed is not None:
            monitor_xy[table["rab"]] = surveyed
        state.monitor_xy = monitor_xy

    def _estimate_biases(
        self,
        state: RadarState,
        table: npt.NDArray[Any],
        batch: npt.NDArray[Any],
        local: npt.NDArray[Any],
        c: FloatArray,
        bias: FloatArray,
        bias_cov: FloatArray,
    ) -> FloatArray:
        """Feed the bias estimator this batch's plots with a reference (see DOMAIN.md
        section 6, variant 3: predictions these plots have not updated) and return the
        residual bias covariance of each local update, for the fuser."""
        assert self.bias is not None and self.fuser is not None and state.index is not None
        radar = state.index
        first_id = int(table["plot_id"][0])
        n_radars = len(self.sources)
        observations = []
        # Other radars' tracks are a relative reference that carries their own residual
        # errors, which separate filters cannot tell apart: a radar with an absolute
        # reference (ADS-B) keeps to it. Measured on three_sites: with traffic beside
        # ADS-B the time offsets came out 55-115 ms off, without it within 27 ms.
        relative = self._absolute_references[radar] < ABSOLUTE_ENOUGH
        if relative or self._geometry is not None:
            traffic = self._traffic_observations(radar, table, batch, local, c, bias, relative)
            if traffic is not None:
                observations.append(traffic)
        monitor = np.flatnonzero(np.isfinite(state.monitor_xy[:, 0]))
        if monitor.size:
            observations.append(
                make_observations(
                    n_radars,
                    np.full(monitor.size, radar),
                    table["time"][monitor],
                    np.column_stack([table["x"][monitor], table["y"][monitor]]),
                    table["R"][monitor],
                    c[monitor],
                    state.monitor_xy[monitor],
                    np.broadcast_to(np.eye(2) * MONITOR_SURVEY_VARIANCE_M2, (monitor.size, 2, 2)),
                    kind=ObservationKind.FIELD_MONITOR,
                )
            )
        if self.adsb is not None:
            adsb = self._adsb_observations(radar, table, c)
            self._absolute_references[radar] += len(adsb)
            observations.append(adsb)
        if observations:
            self.bias.update(concatenate(observations))
            self._record_bias(state, float(table["time"].max()))
        # Each local update's share of the residual bias, at its plot.
        extra = np.zeros((len(local), 2, 2))
        with_plot = np.flatnonzero(local["plot_id"] >= 0)
        if with_plot.size:
            cu = c[local["plot_id"][with_plot] - first_id].copy()
            cu[:, :, 3] = -np.column_stack([local["vx"][with_plot], local["vy"][with_plot]])
            extra[with_plot] = cu @ bias_cov @ np.swapaxes(cu, 1, 2)
        return extra

    def _traffic_observations(
        self,
        radar: int,
        table: npt.NDArray[Any],
        batch: npt.NDArray[Any],
        local: npt.NDArray[Any],
        c: FloatArray,
        bias: FloatArray,
        relative: bool,
    ) -> BiasObservations | None:
        """The batch's plots of aircraft that other radars see, against those radars'
        fused tracks (``relative``: still wanted as a reference); the macro filter's
        record of each aircraft's radars is kept up to date either way."""
        assert self.fuser is not None
        first_id = int(table["plot_id"][0])
        refs = self.fuser.references(radar, local, batch)
        if self._geometry is not None:
            self._remember_geometry(radar, refs, table["R"], c, first_id)
        usable = refs.others_valid & relative
        if not usable.any():
            return None
        row = refs.plot_id[usable] - first_id
        rc = c[row].copy()
        rc[:, :, 3] = -refs.others_v[usable]
        contributors = refs.radars_seen[usable]
        contributor_r = contributor_c = None
        if self._geometry is not None:
            contributor_r, contributor_c = self._contributor_geometry(refs.system_number[usable])
            contributors = contributors & (contributor_r[:, :, 0, 0] > 0)
        # The reference at the plot's time as labelled, where the uncorrected plot lies:
        # the batch's time had the estimated time offset taken off.
        ref_xy = refs.others_xy[usable] + refs.others_v[usable] * bias[3]
        return make_observations(
            len(self.sources),
            np.full(len(row), radar),
            table["time"][row],
            np.column_stack([table["x"][row], table["y"][row]]),  # as sent: uncorrected
            table["R"][row],
            rc,
            ref_xy,
            refs.others_P[usable],
            kind=ObservationKind.AIRCRAFT,
            group=refs.system_number[usable],
            reference_v=refs.others_v[usable],
            prediction_xy=refs.all_xy[usable] + refs.others_v[usable] * bias[3],
            prediction_P=refs.all_P[usable],
            contributors=contributors,
            contributor_R=contributor_r,
            contributor_C=contributor_c,
        )

    def _remember_geometry(
        self, radar: int, refs: References, r: FloatArray, c: FloatArray, first_id: int
    ) -> None:
        """The macro filter's F_x and F_s need, per aircraft, the latest R and C of each
        radar that sees it: kept per system track."""
        assert self._geometry is not None
        rows = refs.plot_id - first_id
        for k, number in enumerate(refs.system_number.tolist()):
            if number <= 0:
                continue
            entry = self._geometry.get(number)
            if entry is None:
                n = len(self.sources)
                entry = self._geometry[number] = (np.zeros((n, 2, 2)), np.zeros((n, 2, 4)))
            entry[0][radar] = r[rows[k]]
            entry[1][radar] = c[rows[k]]

    def _contributor_geometry(self, numbers: IntArray) -> tuple[FloatArray, FloatArray]:
        assert self._geometry is not None
        n = len(self.sources)
        r = np.zeros((len(numbers), n, 2, 2))
        c = np.zeros((len(numbers), n, 2, 4))
        for k, number in enumerate(numbers.tolist()):
            entry = self._geometry.get(number)
            if entry is not None:
                r[k], c[k] = entry
        return r, c

    def _adsb_observations(
        self, radar: int, table: npt.NDArray[Any], c: FloatArray
    ) -> BiasObservations:
        """The batch's Mode S plots against the ADS-B track of their address at their
        time stamp (an absolute reference: see ``tracker_service.adsb``)."""
        assert self.adsb is not None
        rows = np.flatnonzero((table["address"] >= 0) & ~table["rab"])
        refs = self.adsb.at(table["address"][rows], table["time"][rows])
        rows = rows[refs.valid]
        rc = c[rows].copy()
        rc[:, :, 3] = -refs.v[refs.valid]
        return make_observations(
            len(self.sources),
            np.full(rows.size, radar),
            table["time"][rows],
            np.column_stack([table["x"][rows], table["y"][rows]]),
            table["R"][rows],
            rc,
            refs.xy[refs.valid],
            refs.P[refs.valid],
            kind=ObservationKind.ADSB,
            reference_v=refs.v[refs.valid],
        )

    def _record_bias(self, state: RadarState, time: float) -> None:
        assert self.bias is not None and state.index is not None
        last = self._bias_recorded.get(state.info.source, -np.inf)
        if time - last >= BIAS_HISTORY_S:
            s, p = self.bias.correction(state.index)
            self.bias_history.append((time, state.info.source, s, p))
            self._bias_recorded[state.info.source] = time


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
