"""Run the local trackers over a recording that carries truth.

Per radar (a source with CAT048), in reception order, LAN B copies skipped: extract the
plots, time them with ``PlotClock`` (fed with the CAT034 north markers), convert them to
the system plane, and feed each datagram (one sector of one radar) to that radar's
``LocalTracker`` as one batch. Every plot gets a global ``plot_id``; the table of plots
keeps, for each id, where it came from (source, LAN A datagram sequence, record index)
and what the simulator says it is (``/truth/plots``), so that the metrics can tell which
aircraft each track update came from.

The radars come from the recording's metadata (site, sigmas, period): a simulated
recording needs no configuration. ``EvaluationConfig`` overrides what the metadata does
not give or gives wrong (geoid, north alignment, tracker tunables).
"""

from __future__ import annotations

import logging
import math
from collections import defaultdict
from collections.abc import Callable, Iterator, Mapping
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from asterix.plots import extract_plots
from tracker_service.geodesy import HeightModel, RadarSite, SystemPlane, convert_plots
from tracker_service.ingest import PlotClock
from tracker_service.simulator.recording import Recording, read_recording
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig

__all__ = [
    "KIND_AIRCRAFT",
    "KIND_CLUTTER",
    "KIND_FIELD_MONITOR",
    "KIND_NAMES",
    "KIND_REFLECTION",
    "KIND_SPLIT",
    "KIND_UNKNOWN",
    "RAW_PLOT_DTYPE",
    "EvaluationConfig",
    "PipelineResult",
    "RadarInfo",
    "RadarRun",
    "radar_infos",
    "run_pipeline",
]

log = logging.getLogger(__name__)

NM = 1852.0
CAT034 = 34
CAT048 = 48

# Origin kinds of /truth/plots as small integers, so that they fit a numpy column.
KIND_UNKNOWN, KIND_AIRCRAFT, KIND_CLUTTER, KIND_REFLECTION, KIND_SPLIT, KIND_FIELD_MONITOR = (
    -1,
    0,
    1,
    2,
    3,
    4,
)
KIND_NAMES: dict[str, int] = {
    "aircraft": KIND_AIRCRAFT,
    "clutter": KIND_CLUTTER,
    "reflection": KIND_REFLECTION,
    "split": KIND_SPLIT,
    "field_monitor": KIND_FIELD_MONITOR,
}

RAW_PLOT_DTYPE = np.dtype(
    [
        ("plot_id", np.int64),
        ("sequence", np.int64),  # LAN A datagram number of the source (as /truth/plots)
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
        ("address", np.int64),  # Mode S address, -1 when absent
        ("mode3a", np.int64),  # Mode 3/A code as an integer, -1 when absent
        ("kind", np.int8),  # KIND_*
        ("aircraft", np.int64),  # origin aircraft index, -1 when none
        ("detection_time", np.float64),  # true time of detection, NaN when unknown
    ]
)
"""One converted plot of one radar, with its truth origin."""


@dataclass(frozen=True)
class RadarInfo:
    """What the evaluation needs to know of one radar."""

    source: str
    site: RadarSite
    period_s: float
    sigma_range_m: float
    sigma_azimuth_deg: float
    psr_sigma_range_m: float
    psr_sigma_azimuth_deg: float


@dataclass(frozen=True)
class EvaluationConfig:
    """Overrides of what the recording's metadata gives, and the evaluation's own rules.

    ``geoid_m``: the geoid undulation given to every site. The tracker may not use the
    simulator's EGM96 table, so it is 0 by default (about 40 m off in central Europe; a
    few metres of horizontal error at most through the elevation formula). ``radars``:
    per "SAC/SIC", any ``RadarInfo``/``RadarSite`` field (lat_deg, lon_deg, alt_m,
    geoid_m, north_offset_deg, period_s, sigma_*). ``tracker``: ``TrackerConfig`` fields
    for every radar (``scan_period_s`` is taken from each radar's period unless given).
    ``association_gate_m``: how far the nearest aircraft may be for a track update whose
    plot has no aircraft origin to be counted as that aircraft's.
    """

    geoid_m: float = 0.0
    radars: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    tracker: Mapping[str, Any] = field(default_factory=dict)
    association_gate_m: float = 1000.0
    min_identity_updates: int = 2

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any]) -> EvaluationConfig:
        """From a parsed TOML document: ``[evaluation]`` (geoid_m, association_gate_m,
        min_identity_updates), ``[tracker]`` and ``[radars."25/11"]`` tables."""
        known = {"evaluation", "tracker", "radars"}
        unknown = set(doc) - known
        if unknown:
            raise ValueError(f"unknown configuration tables {sorted(unknown)}; known: {known}")
        evaluation = dict(doc.get("evaluation", {}))
        allowed = {"geoid_m", "association_gate_m", "min_identity_updates"}
        if set(evaluation) - allowed:
            raise ValueError(f"[evaluation] knows only {sorted(allowed)}")
        tracker = dict(doc.get("tracker", {}))
        tracker_fields = {f.name for f in fields(TrackerConfig)}
        if set(tracker) - tracker_fields:
            raise ValueError(
                f"[tracker] fields {sorted(set(tracker) - tracker_fields)} are not "
                "TrackerConfig fields"
            )
        # TOML has arrays, the config wants tuples.
        tracker = {k: tuple(v) if isinstance(v, list) else v for k, v in tracker.items()}
        radars = {str(k): dict(v) for k, v in dict(doc.get("radars", {})).items()}
        return cls(radars=radars, tracker=tracker, **evaluation)


@dataclass
class RadarRun:
    """One radar's run: its track updates (``track_update_dtype``) and its plots."""

    info: RadarInfo
    updates: npt.NDArray[Any]
    plots: npt.NDArray[Any]  # RAW_PLOT_DTYPE, in processing order
    tracker_config: TrackerConfig


@dataclass
class PipelineResult:
    recording: Recording
    plane: SystemPlane
    radars: dict[str, RadarRun]
    origins: dict[int, tuple[str, int, int]]
    """plot_id -> (source, datagram sequence, record index)."""


def _float(value: Any, default: float) -> float:
    return float(value) if isinstance(value, int | float) and math.isfinite(value) else default


def radar_infos(metadata: Mapping[str, Any], config: EvaluationConfig) -> dict[str, RadarInfo]:
    """The radars of a simulated recording's metadata, with the configuration's overrides."""
    infos: dict[str, RadarInfo] = {}
    for source, radar in dict(metadata.get("radars", {})).items():
        override = dict(config.radars.get(source, {}))
        site = RadarSite(
            lat_deg=float(override.pop("lat_deg", radar["lat"])),
            lon_deg=float(override.pop("lon_deg", radar["lon"])),
            alt_m=float(override.pop("alt_m", radar["alt_m"])),
            geoid_m=float(override.pop("geoid_m", config.geoid_m)),
            north_offset_deg=float(override.pop("north_offset_deg", 0.0)),
        )
        sigma_range = float(override.pop("sigma_range_m", _float(radar.get("sigma_range_m"), 50.0)))
        sigma_azimuth = float(
            override.pop("sigma_azimuth_deg", _float(radar.get("sigma_azimuth_deg"), 0.07))
        )
        # Without PSR sigmas, PSR-only plots are taken as accurate as the others.
        psr_range = _float(radar.get("psr_sigma_range_m"), sigma_range)
        psr_azimuth = _float(radar.get("psr_sigma_azimuth_deg"), sigma_azimuth)
        infos[source] = RadarInfo(
            source=source,
            site=site,
            period_s=float(override.pop("period_s", _float(radar.get("antenna_period_s"), 5.0))),
            sigma_range_m=sigma_range,
            sigma_azimuth_deg=sigma_azimuth,
            psr_sigma_range_m=float(override.pop("psr_sigma_range_m", psr_range)),
            psr_sigma_azimuth_deg=float(override.pop("psr_sigma_azimuth_deg", psr_azimuth)),
        )
        if override:
            raise ValueError(f'[radars."{source}"]: unknown fields {sorted(override)}')
    for source in config.radars:
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


def blocks_of(payload: bytes, category: int) -> Iterator[bytes]:
    """The data blocks of one category in a datagram, by their headers alone (cheap: the
    plot path needs CAT034 decoded, not every block)."""
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
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """One datagram's plots of one radar (``asterix.plots`` rows): timed, converted to the
    system plane, as the tracker's batch (``tracking.PLOT_DTYPE``) and as a
    ``RAW_PLOT_DTYPE`` table (origins unknown) with plot ids from ``first_id``."""
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
    psr_only = raw["typ"] == 1
    sigma_rho = np.where(psr_only, info.psr_sigma_range_m, info.sigma_range_m)
    sigma_theta = np.where(psr_only, info.psr_sigma_azimuth_deg, info.sigma_azimuth_deg)
    rho_m = np.asarray(raw["rho"], dtype=np.float64) * NM
    theta = np.asarray(raw["theta"], dtype=np.float64)
    converted = convert_plots(
        info.site, plane, rho_m, theta, height, height_sigma, sigma_rho, sigma_theta
    )
    ids = np.arange(first_id, first_id + n, dtype=np.int64)
    mode3a = np.asarray(raw["mode3a"], dtype=np.int64)

    batch = np.zeros(n, dtype=PLOT_DTYPE)
    batch["time"] = times
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
    table["address"] = raw["address"]
    table["mode3a"] = mode3a
    table["kind"] = KIND_UNKNOWN
    table["aircraft"] = -1
    table["detection_time"] = np.nan
    return batch, table


def _truth_plot_index(recording: Recording) -> dict[tuple[str, int], list[dict[str, Any]]]:
    index: dict[tuple[str, int], list[dict[str, Any]]] = {}
    if "/truth/plots" not in recording.topics:
        return index
    for message in recording.messages("/truth/plots"):
        index[(str(message["source"]), int(message["sequence"]))] = list(message["records"])
    return index


class RadarState:
    """What a run keeps per radar while it reads: its tracker, and the track updates and
    converted plots of every datagram so far."""

    def __init__(
        self,
        info: RadarInfo,
        tracker_config: TrackerConfig,
        tracker: LocalTracker | None = None,
    ) -> None:
        self.info = info
        self.tracker_config = tracker_config
        self.tracker = tracker or LocalTracker(tracker_config)
        self.updates: list[npt.NDArray[Any]] = []
        self.plots: list[npt.NDArray[Any]] = []

    def results(self) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
        """(track updates, RAW_PLOT_DTYPE plots) of the whole run."""
        updates = (
            np.concatenate(self.updates)
            if self.updates
            else np.zeros(0, dtype=self.tracker.output_dtype)
        )
        plots = np.concatenate(self.plots) if self.plots else np.zeros(0, RAW_PLOT_DTYPE)
        return updates, plots


def source_order(source: str) -> tuple[int, ...]:
    """Sort key of "SAC/SIC" texts: by number, not as text."""
    return tuple(int(part) for part in source.split("/"))


def run_pipeline(
    path: str | Path | Recording,
    config: EvaluationConfig | None = None,
    make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
) -> PipelineResult:
    """Track every radar of a recording; see the module docstring. ``make_tracker(source,
    config)`` builds each radar's tracker (a benchmark passes one that times ``process``)."""
    config = config or EvaluationConfig()
    recording = path if isinstance(path, Recording) else read_recording(path)
    infos = radar_infos(recording.metadata, config)
    plane = system_plane(recording.metadata, infos)
    truth_plots = _truth_plot_index(recording)
    heights = HeightModel()
    clock = PlotClock()
    sequences: dict[str, int] = defaultdict(int)
    states: dict[str, RadarState] = {}
    skipped: set[str] = set()
    origins: dict[int, tuple[str, int, int]] = {}
    next_id = 0
    tracker_overrides = dict(config.tracker)

    for datagram in recording.datagrams():
        if datagram.lan == "B":
            # The redundant LAN's copy: same bytes, and /truth/plots counts LAN A only.
            continue
        sequence = sequences[datagram.source]
        sequences[datagram.source] += 1
        for block in blocks_of(datagram.payload, CAT034):
            for event in decode_blocks(block):
                if isinstance(event, Block):
                    for items in event.records:
                        clock.service_message(items, datagram.time)
        raw = extract_plots(datagram.payload).plots
        if len(raw) == 0:
            continue
        state = states.get(datagram.source)
        if state is None:
            if datagram.source in skipped:
                continue
            info = infos.get(datagram.source)
            if info is None:
                # Not in the metadata: no site to convert with. Fusion needs real sites,
                # and so does an evaluation against geodetic truth.
                log.warning(
                    "source %s has CAT048 but no radar in the metadata: skipped",
                    datagram.source,
                )
                skipped.add(datagram.source)
                continue
            tracker_config = TrackerConfig(**{"scan_period_s": info.period_s, **tracker_overrides})
            tracker = (
                None if make_tracker is None else make_tracker(datagram.source, tracker_config)
            )
            state = states[datagram.source] = RadarState(info, tracker_config, tracker)
        batch, table = convert_batch(
            raw, state.info, plane, clock, heights, datagram.time, next_id, sequence
        )
        next_id += len(raw)
        state.updates.append(state.tracker.process(batch))
        n, ids = len(raw), table["plot_id"]
        records = truth_plots.get((datagram.source, sequence))
        if records is not None and len(records) != n:
            # A record the plot path could not read would shift every later index.
            log.warning(
                "%s datagram %d: %d plots read, truth lists %d records; origins dropped",
                datagram.source,
                sequence,
                n,
                len(records),
            )
            records = None
        if records is not None:
            table["kind"] = [KIND_NAMES.get(r["kind"], KIND_UNKNOWN) for r in records]
            table["aircraft"] = [-1 if r["aircraft"] is None else r["aircraft"] for r in records]
            table["detection_time"] = [r["detection_time"] for r in records]
        state.plots.append(table)
        for row, plot_id in enumerate(ids.tolist()):
            origins[plot_id] = (datagram.source, sequence, row)

    radars: dict[str, RadarRun] = {}
    for source in sorted(states, key=source_order):
        state = states[source]
        updates, plots = state.results()
        radars[source] = RadarRun(state.info, updates, plots, state.tracker_config)
        log.info(
            "%s: %d plots, %d track updates, stats %s",
            source,
            len(plots),
            len(updates),
            state.tracker.stats,
        )
    return PipelineResult(recording, plane, radars, origins)
