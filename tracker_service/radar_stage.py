"""The radar stage: what belongs to one radar, from its datagrams to its local tracks.

Source admission (``sources``), the plot clock (``ingest.PlotClock``, fed with the CAT034
and CAT002 service messages), time sanity (``time_sanity``), the conversion to the system
plane (``geodesy``), test targets and fixed transponders (``PlotUse``, ``fixed_targets``)
and one ``LocalTracker`` per radar. It knows nothing of fusion nor of the bias estimate:
it tracks each radar's plots as the radar sent them and hands over, per datagram and
radar, a ``stage_messages.RadarBatch`` with the bias Jacobian of every plot and local
update, so that the central stage corrects them with the estimate of its own moment (the
result depends on the order the central stage takes the batches in, not on when they
arrive). One stage may hold every radar (``chain.Chain``, in one process) or a few of
them (``tracker-service run --role radar``, a replay worker).

A radar that the configuration does not know is still tracked (with a warning), in a
plane of its own centred on an assumed site (the system centre): its local tracks are
shaped right, but without a surveyed site they are placed wrong, so the central stage
keeps them out of fusion and bias estimation. Field-monitor plots (I020 RAB = 1) are a
radar's test transponder at a surveyed position: never tracked, they are a reference for
its biases. Test targets (I020 TST) and simulated reports (SIM) are never tracked either,
nor fixed transponders (``fixed_targets``: configured or detected), the surveyed ones of
which are bias references like field monitors.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from asterix.daps import DAP_COLUMNS
from asterix.plots import extract_plots
from tracker_service.bias.reception import ReceptionEvidence
from tracker_service.fixed_targets import FixedTargetConfig, FixedTargets, FixedTransponder
from tracker_service.geodesy import (
    Atmosphere,
    ConvertedPlots,
    HeightModel,
    RadarSite,
    SystemPlane,
)
from tracker_service.geodesy.compiled import PlaneSteps, convert_plots_compiled
from tracker_service.geodesy.unknown_height import (
    HeightBand,
    height_jacobian,
    unknown_height_prior,
)
from tracker_service.ingest import PlotClock
from tracker_service.radar_kernels import plot_columns
from tracker_service.sources import DEFAULT_MAX_UNKNOWN, SourceAdmission
from tracker_service.stage_messages import RadarBatch
from tracker_service.time_sanity import TimeBase, TimeSanity, TimeSanityConfig
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.tracking.dap_kernels import INPUTS as DAP_INPUTS
from tracker_service.tracking.dap_kernels import PUBLISHED as PUBLISHED_DAPS
from tracker_service.tracking.dap_kernels import fill_daps
from tracker_service.tracking.daps import plot_daps
from tracker_service.tracking.plots import DAP_FIELDS, empty_plots
from tracker_service.tracking.plots import PUBLISHED_DAP_FIELDS as DAP_NAMES

__all__ = [
    "KIND_UNKNOWN",
    "RAW_PLOT_DTYPE",
    "FieldMonitor",
    "PlotUse",
    "RadarInfo",
    "RadarStage",
    "RadarState",
    "StageStats",
    "blocks_of",
    "convert_batch",
    "local_jacobian",
    "rejections",
    "source_order",
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
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
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
        ("implausible_daps", np.bool_),  # some Mode S DAP dropped as implausible (tracking.daps)
        ("has_daps", np.bool_),  # the DAP columns below hold DAPs (then NaN: absent); else unset
        *((name, np.float64) for name in DAP_NAMES),
        # The height the conversion used (m above MSL) and its sigma; without a usable
        # one (geodesy.unknown_height) the band's equivalent height, height_known False,
        # and d(x, y)/dH for the central stage's re-projection (0 where it is known).
        ("height_m", np.float64),
        ("height_sigma_m", np.float64),
        ("height_known", np.bool_),
        ("height_jacobian", np.float64, (2,)),
    ]
)
"""One converted plot of one radar, as received (before any bias correction), with room
for its truth origin."""


class PlotUse(IntEnum):
    """What the chain did with a plot: tracked, or kept out of traffic tracking and why.
    Every plot of a radar's table carries one; status counts the others per radar by
    their lower-case name. Arrays are compared with a member's ``.value``: numpy
    compares with an IntEnum member through a slow path (7 us a call against 2)."""

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
    ADSB_REFERENCE = 8
    """An ADS-B report kept as the bias estimator's absolute reference, so not fused
    (``[fusion] adsb = "fuse"``: no report serves both; fusion/adsb_source.py)."""
    ADSB_REPEATED = 9
    """An ADS-B report no newer than its address's latest (another ground station's copy
    of the same squitter, or one out of sequence): it adds nothing."""
    ADSB_INCONSISTENT = 10
    """An ADS-B position that disagrees with the radars' tracks of its address beyond the
    gate (a spoofed or faulty transponder, a wrong address): flagged, not fused."""
    ADSB_UNFIT = 11
    """A CAT021 record without address, time or position, or with a position quality
    (NACp, NIC or NUCp) worse than 1 NM."""
    ADSB_UNCHECKED = 12
    """An ADS-B report inside radar cover whose address no radar has confirmed yet: not
    fused until one has (or a time-out), so a spoofer founds no system track."""


def rejections(use: npt.NDArray[np.int8]) -> dict[str, int]:
    """Counts of a table's plots kept out of tracking, by reason (``PlotUse`` names)."""
    rejected = use[use != PlotUse.TRACKED.value]
    if not len(rejected):
        return {}  # most batches: np.unique's set-up is not needed
    codes, counts = np.unique(rejected, return_counts=True)
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
    height_band: HeightBand = field(default_factory=HeightBand)
    """Where its plots without a usable height may be (``geodesy.unknown_height``)."""


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
    surveyed_height: FloatArray | None = None,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any], FloatArray]:
    """One datagram's plots of one radar (``asterix.plots`` rows): timed, converted to the
    system plane as the radar sent them (no bias correction: the central stage applies it,
    ``central_stage``), as the tracker's batch (``tracking.PLOT_DTYPE``), as a
    ``RAW_PLOT_DTYPE`` table (origins unknown) with plot ids from ``first_id``, and the
    bias Jacobian C (N, 2, 4) of each plot's plane position (its time column, which needs
    the aircraft's velocity, left 0).

    ``surveyed_height``: per plot, the surveyed height (m above MSL) of the fixed
    transponder it is, NaN for the others."""
    n = len(raw)
    monitor = info.field_monitor
    sigmas = np.array(
        [
            info.sigma_range_m,
            info.sigma_azimuth_deg,
            info.psr_sigma_range_m,
            info.psr_sigma_azimuth_deg,
        ]
    )
    # V = 1 (not validated) and G = 1 (garbled) Mode C is no height: the HeightModel's
    # stand-in and its large sigma take over, and the tracker's vertical filter skips it.
    # The field monitor's height is surveyed, as is a configured fixed transponder's
    # (whose Mode C is often a test value, FL719): better than their Mode C.
    columns = plot_columns(
        raw, received, heights, sigmas, None if monitor is None else monitor.alt_m, surveyed_height
    )
    if columns.stamped:
        times, time_sources = columns.times, columns.time_sources
    else:
        times, time_sources = clock.times(raw, received)
    fl = np.asarray(raw["flight_level"], dtype=np.float64)
    fl_ok, fl_clean = columns.fl_ok, columns.fl_clean
    height, height_sigma = columns.height, columns.height_sigma
    rab, rho_m, unknown = columns.rab, columns.rho_m, columns.unknown
    any_unknown = columns.any_unknown
    theta = np.asarray(raw["theta"], dtype=np.float64)
    if any_unknown:
        # No usable height: the band's prior instead of a fixed level
        # (geodesy.unknown_height).
        height[unknown], height_sigma[unknown] = unknown_height_prior(
            info.site, rho_m[unknown], info.height_band
        )
    sigma_rho, sigma_theta = columns.sigma_rho, columns.sigma_theta
    converted, steps = convert_plots_compiled(
        info.site, plane, rho_m, theta, height, height_sigma, sigma_rho, sigma_theta
    )
    c = np.zeros((n, 2, 4))
    c[:, :, 0] = converted.polar_jacobian[:, :, 0]
    c[:, :, 1] = converted.polar_jacobian[:, :, 0] * rho_m[:, None]
    c[:, :, 2] = converted.polar_jacobian[:, :, 1]
    ids = np.arange(first_id, first_id + n, dtype=np.int64)
    mode3a = np.asarray(raw["mode3a"], dtype=np.int64)

    batch = empty_plots(n)
    table = np.zeros(n, dtype=RAW_PLOT_DTYPE)
    implausible_daps = _fill_daps(batch, table, raw, plane, converted, steps)
    batch["time"] = times
    batch["x"] = converted.x
    batch["y"] = converted.y
    batch["R"] = converted.R
    batch["flight_level"] = fl
    batch["fl_valid"] = fl_ok
    batch["mode3a"] = mode3a
    batch["mode3a_valid"] = columns.mode3a_valid
    batch["address"] = raw["address"]
    batch["typ"] = raw["typ"]
    batch["plot_id"] = ids

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
    table["implausible_daps"] = implausible_daps
    table["use"] = columns.use
    table["height_m"] = height
    table["height_sigma_m"] = height_sigma
    table["height_known"] = ~unknown
    if any_unknown:
        table["height_jacobian"][unknown] = height_jacobian(
            info.site,
            plane,
            rho_m[unknown],
            theta[unknown],
            height[unknown],
            at=(converted.x[unknown], converted.y[unknown]),
        )
    return batch, table, c


def _fill_daps(
    batch: npt.NDArray[Any],
    table: npt.NDArray[Any],
    raw: npt.NDArray[Any],
    plane: SystemPlane,
    converted: ConvertedPlots,
    steps: PlaneSteps | None,
) -> npt.NDArray[np.bool_]:
    """The plots' Mode S DAPs into the tracker's batch (``tracking.daps.plot_daps``, or
    its compiled pass when the conversion's projections are at hand) and the plot table
    (for the outputs); per plot, whether one was implausible. Batches without any DAP
    (CAT001, Mode A/C) cost one look."""
    names = raw.dtype.names or ()
    if steps is not None and all(name in names for name in DAP_INPUTS):
        found = fill_daps(raw, converted.lat_deg, converted.height_m, steps)
        if found is None:
            return np.zeros(len(raw), dtype=bool)
        out, flags, implausible = found
        for k, name in enumerate(DAP_FIELDS):
            batch[name] = out[:, k]
        batch["dap_flags"] = flags
        for name, k in zip(DAP_NAMES, PUBLISHED_DAPS, strict=True):
            table[name] = out[:, k]
        table["has_daps"] = np.isfinite(out[:, PUBLISHED_DAPS]).any(axis=1)
        return implausible
    if not any(name in names and np.isfinite(raw[name]).any() for name in DAP_COLUMNS):
        return np.zeros(len(raw), dtype=bool)
    columns, implausible = plot_daps(
        raw, plane, converted.lat_deg, converted.lon_deg, converted.height_m
    )
    for name, values in columns.items():
        batch[name] = values
    published = [columns[name] for name in DAP_NAMES]
    for name, values in zip(DAP_NAMES, published, strict=True):
        table[name] = values
    table["has_daps"] = np.isfinite(np.stack(published)).any(axis=0)
    return implausible


def local_jacobian(
    local: npt.NDArray[Any], plot_c: FloatArray, first_id: int, site_xy: FloatArray
) -> FloatArray:
    """(n_local, 2, 4): the bias Jacobian at each local update: its plot's (``plot_c``,
    rows from plot id ``first_id``) when it has one in the batch, else the flat-earth
    one at the track's position seen from the site (coasting and ended tracks: their
    correction is as old as their last plot anyway). Time column 0, as for plots."""
    n = len(local)
    c = np.zeros((n, 2, 4))
    if not n:
        return c
    rows = local["plot_id"] - first_id
    with_plot = (local["plot_id"] >= 0) & (rows < len(plot_c))
    c[with_plot] = plot_c[rows[with_plot]]
    flat = ~with_plot
    if flat.any():
        dx = local["x"][flat] - site_xy[0]
        dy = local["y"][flat] - site_xy[1]
        ground = np.maximum(np.hypot(dx, dy), 1.0)
        ux, uy = dx / ground, dy / ground
        c[flat, 0, 0], c[flat, 1, 0] = ux, uy
        c[flat, 0, 1], c[flat, 1, 1] = dx, dy
        # Azimuth clockwise from north: d(x, y)/d(theta) = (y, -x) about the site.
        c[flat, 0, 2], c[flat, 1, 2] = dy, -dx
    return c


@dataclass
class RadarState:
    """One radar in its stage: what it is, its plane and its tracker."""

    info: RadarInfo
    plane: SystemPlane
    tracker_config: TrackerConfig
    tracker: LocalTracker
    index: int | None
    """The radar's number among the configured radars (SAC/SIC order: fusion's and bias
    estimation's number of it); None for a radar the configuration does not know."""
    fixed: FixedTargets
    site_xy: FloatArray
    sequence: int = 0


@dataclass
class StageStats:
    datagrams: int = 0
    plots: int = 0
    field_monitor_plots: int = 0
    unknown_radars: list[str] = field(default_factory=list)
    decode_errors: int = 0
    """Records (CAT034, CAT048) the codec could not decode inside a valid block chain."""


class RadarStage:
    """See the module docstring. ``radars``: every configured radar (their SAC/SIC order
    numbers them); ``tracker``: ``TrackerConfig`` fields for every radar
    (``scan_period_s`` comes from each radar's period unless given); ``make_tracker``
    builds each radar's tracker; ``incarnation`` marks the batches of this start of the
    stage; ``atmosphere``: what turns Mode C into geometric heights (ISA when None)."""

    def __init__(
        self,
        radars: Mapping[str, RadarInfo],
        plane: SystemPlane,
        tracker: Mapping[str, Any] | None = None,
        make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
        time_sanity: TimeSanityConfig | None = None,
        fixed_targets: FixedTargetConfig | None = None,
        max_unknown_sources: int = DEFAULT_MAX_UNKNOWN,
        incarnation: int = 0,
        atmosphere: Atmosphere | None = None,
    ) -> None:
        self.infos = dict(radars)
        self.plane = plane
        self.fixed_targets = fixed_targets or FixedTargetConfig()
        self.admission = SourceAdmission(self.infos, max_unknown_sources)
        self.sources = sorted(self.infos, key=source_order)
        self.incarnation = incarnation
        self.stats = StageStats()
        self.radars: dict[str, RadarState] = {}
        self._tracker_overrides = dict(tracker or {})
        self._make_tracker = make_tracker or (lambda _source, config: LocalTracker(config))
        self.clock = PlotClock()
        self.time_sanity = TimeSanity(
            time_sanity,
            {source: info.time_base for source, info in self.infos.items()},
            {source: info.period_s for source, info in self.infos.items()},
        )
        self._heights = HeightModel(atmosphere=atmosphere or Atmosphere())
        self.reception = ReceptionEvidence(self.time_sanity.config.max_offset_s)
        self.next_plot_id = 0
        """The stage's plots numbered in its order: in one process the system's numbers;
        the central stage renumbers those of stages in other processes."""
        self._monitors = {
            source: np.array(plane.from_geodetic(m.lat_deg, m.lon_deg, m.alt_m), dtype=float)
            for source, info in self.infos.items()
            if (m := info.field_monitor) is not None
        }

    def feed(self, payload: bytes, received: float, order: int) -> list[RadarBatch]:
        """Process one datagram received at ``received`` (POSIX s), the ``order``-th of
        its input."""
        self.stats.datagrams += 1
        for category in SERVICE_CATEGORIES:
            for block in blocks_of(payload, category):
                for event in decode_blocks(block):
                    if isinstance(event, Block):
                        for items in event.records:
                            self.clock.service_message(items, received)
                            self.time_sanity.service_message(items, received)
                            self.reception.service_message(items, received)
                    else:
                        self.stats.decode_errors += 1
        if not any(next(blocks_of(payload, c), None) for c in PLOT_CATEGORIES):
            return []  # service messages or ADS-B only: no plot to extract
        extracted = extract_plots(payload)
        self.stats.decode_errors += len(extracted.errors)
        raw = self.admission.admit(extracted.plots)
        if len(raw) == 0:
            return []
        sac, sic = np.asarray(raw["sac"], np.int64), np.asarray(raw["sic"], np.int64)
        key = sac * 256 + sic
        if (key == key[0]).all():
            return [self._radar_batch(f"{sac[0]}/{sic[0]}", raw, received, order)]
        keys = np.unique(key)
        # Only odd captures mix radars in one datagram.
        return [
            self._radar_batch(f"{k >> 8}/{k & 255}", raw[key == k], received, order)
            for k in keys.tolist()
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
            period = self.clock.antenna_period(sac, sic) or 5.0  # from its north markers
            info = RadarInfo(source, site, period, 50.0, 0.07, 50.0, 0.07, surveyed=False)
            plane = SystemPlane(site.lat_deg, site.lon_deg, plane.kind)
        site_xy = np.array(
            plane.from_geodetic(info.site.lat_deg, info.site.lon_deg, info.site.alt_m), dtype=float
        )
        overrides = {
            "scan_period_s": info.period_s,
            "clutter_origin_m": (float(site_xy[0]), float(site_xy[1])),
            **self._tracker_overrides,
        }
        config = TrackerConfig(**overrides)
        index = self.sources.index(source) if info.surveyed else None
        fixed = FixedTargets(
            info.site, plane, info.period_s, info.fixed_transponders, self.fixed_targets
        )
        tracker = self._make_tracker(source, config)
        state = RadarState(info, plane, config, tracker, index, fixed, site_xy)
        self.radars[source] = state
        return state

    def _radar_batch(
        self, source: str, raw: npt.NDArray[Any], received: float, order: int
    ) -> RadarBatch:
        state = self._radar(source)
        first_id = self.next_plot_id
        batch, table, c = convert_batch(
            raw,
            state.info,
            state.plane,
            self.clock,
            self._heights,
            received,
            first_id,
            state.sequence,
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
            table["use"][implausible & (table["use"] == PlotUse.TRACKED.value)] = (
                PlotUse.TIME_IMPLAUSIBLE
            )
        state.sequence += 1
        self.next_plot_id += len(raw)
        self.stats.plots += len(raw)
        n_monitor = int(np.count_nonzero(table["rab"]))
        if n_monitor:
            self.stats.field_monitor_plots += n_monitor
        monitor_xy = self._fixed_transponders(state, table, batch)
        # The batch keeps the tracker's plots only; the table keeps every plot with its use.
        tracked = table["use"] == PlotUse.TRACKED.value
        if not tracked.all():
            batch = batch[tracked]
        local = state.tracker.process(batch)
        return RadarBatch(
            source=source,
            received=received,
            order=order,
            plots=table,
            tracked=batch,
            jacobian=c,
            monitor_xy=monitor_xy,
            local=local,
            local_jacobian=local_jacobian(local, c, first_id, state.site_xy),
            time=self.time_sanity.report(source, state.tracker),
            effective_offset_s=self.time_sanity.effective_offset(source),
            incarnation=self.incarnation,
            clock_evidence=self._clock_evidence(source, state.info),
        )

    def _clock_evidence(self, source: str, info: RadarInfo) -> FloatArray:
        """The radar's CAT034 stamps against reception since its last batch; none for a
        feed re-based on reception (its plot times are no longer its clock's)."""
        evidence = self.reception.take(source)
        return evidence if info.time_base == "data" else evidence[:0]

    def _fixed_transponders(
        self, state: RadarState, table: npt.NDArray[Any], batch: npt.NDArray[Any]
    ) -> FloatArray:
        """Marks the table's fixed transponders (``fixed_targets``) and returns, per plot,
        the surveyed position of each field monitor and surveyed fixed transponder."""
        found = state.fixed.classify(
            table, table["use"] == PlotUse.TRACKED.value, np.asarray(batch["mode3a_valid"])
        )
        table["use"][found.fixed] = PlotUse.FIXED_TRANSPONDER
        monitor_xy: FloatArray = found.reference_xy
        surveyed = self._monitors.get(state.info.source)
        if surveyed is not None:
            monitor_xy[table["rab"]] = surveyed
        return monitor_xy

    def live_tracks(self, order: int, received: float) -> list[RadarBatch]:
        """Each radar's live local tracks (``LocalTracker.live_rows``), for a central stage
        that starts while this one runs: each confirmed or coasting track with its
        estimate as a pseudo-plot (position, its covariance as R, identity), so that the
        fuser founds its system tracks at once (``RadarBatch.snapshot``: no bias
        observation is made of them)."""
        batches = []
        for source, state in sorted(self.radars.items(), key=lambda kv: source_order(kv[0])):
            local = state.tracker.live_rows()
            local = local[local["status"] != 0]  # tentative tracks are not fused
            n = len(local)
            first_id = self.next_plot_id
            self.next_plot_id += n
            local["plot_id"] = np.arange(first_id, first_id + n)
            p = local["P"].reshape(-1, 4, 4)
            table = np.zeros(n, dtype=RAW_PLOT_DTYPE)
            tracked = empty_plots(n)
            for rows in (table, tracked):
                rows["plot_id"] = local["plot_id"]
                rows["time"] = local["time"]
                rows["x"], rows["y"] = local["x"], local["y"]
                rows["R"] = p[:, :2, :2]
                rows["flight_level"] = local["flight_level"]
                rows["address"] = local["address"]
                rows["mode3a"] = local["mode3a"]
            tracked["fl_valid"] = np.isfinite(local["flight_level"])
            tracked["mode3a_valid"] = local["mode3a"] >= 0
            tracked["typ"] = table["typ"] = 2
            table["sequence"] = state.sequence
            # Seen from the site on the plane: what CAT062 I340 says of a measured plot.
            dx, dy = local["x"] - state.site_xy[0], local["y"] - state.site_xy[1]
            table["rho_m"] = np.hypot(dx, dy)
            table["theta_deg"] = np.degrees(np.arctan2(dx, dy)) % 360.0
            table["kind"] = KIND_UNKNOWN
            table["aircraft"] = -1
            table["detection_time"] = np.nan
            c = local_jacobian(local, np.zeros((0, 2, 4)), first_id, state.site_xy)
            batches.append(
                RadarBatch(
                    source=source,
                    received=received,
                    order=order,
                    plots=table,
                    tracked=tracked,
                    jacobian=c,
                    monitor_xy=np.full((n, 2), np.nan),
                    local=local,
                    local_jacobian=c,
                    time=self.time_sanity.report(source),
                    effective_offset_s=self.time_sanity.effective_offset(source),
                    incarnation=self.incarnation,
                    snapshot=True,
                )
            )
        return batches
