"""Run the local trackers over a recording that carries truth.

The recording's datagrams, in reception order, LAN B copies skipped, go through the
processing chain (``tracker_service.chain``: plot clock, system plane, one
``LocalTracker`` per radar, one sector per batch). Every plot gets a global ``plot_id``;
the table of plots
keeps, for each id, where it came from (source, LAN A datagram sequence, record index)
and what the simulator says it is (``/truth/plots``), so that the metrics can tell which
aircraft each track update came from.

The radars come from the recording's metadata (site, sigmas, period): a simulated
recording needs no configuration. ``EvaluationConfig`` overrides what the metadata does
not give or gives wrong (geoid, north alignment, tracker tunables).
"""

from __future__ import annotations

import logging
from collections import defaultdict
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.bias import BiasConfig
from tracker_service.chain import (
    KIND_UNKNOWN,
    RAW_PLOT_DTYPE,
    Chain,
    RadarInfo,
    radar_infos,
    recording_atmosphere,
    source_order,
    system_plane,
)
from tracker_service.fusion import SYSTEM_UPDATE_DTYPE, FusionConfig
from tracker_service.geodesy import Atmosphere, SystemPlane
from tracker_service.simulator.recording import Recording, read_recording
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.validation import dataclass_kwargs

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

# Origin kinds of /truth/plots as small integers, so that they fit a numpy column.
KIND_AIRCRAFT, KIND_CLUTTER, KIND_REFLECTION, KIND_SPLIT, KIND_FIELD_MONITOR = 0, 1, 2, 3, 4
KIND_NAMES: dict[str, int] = {
    "aircraft": KIND_AIRCRAFT,
    "clutter": KIND_CLUTTER,
    "reflection": KIND_REFLECTION,
    "split": KIND_SPLIT,
    "field_monitor": KIND_FIELD_MONITOR,
}


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
    plot has no aircraft origin to be counted as that aircraft's. ``atmosphere``: QNH and
    ISA deviation of the Mode C conversion (the ``[atmosphere]`` table); None takes the
    recording's own (its scenario's ``atmosphere``: the met report an operator would
    configure, as the sites are what they would survey); ``Atmosphere()`` is ISA.
    """

    geoid_m: float = 0.0
    radars: Mapping[str, Mapping[str, float]] = field(default_factory=dict)
    tracker: Mapping[str, Any] = field(default_factory=dict)
    association_gate_m: float = 1000.0
    min_identity_updates: int = 2
    fusion: FusionConfig = field(default_factory=FusionConfig)
    bias: BiasConfig = field(default_factory=BiasConfig)
    atmosphere: Atmosphere | None = None

    @classmethod
    def from_mapping(cls, doc: Mapping[str, Any]) -> EvaluationConfig:
        """From a parsed TOML document: ``[evaluation]`` (geoid_m, association_gate_m,
        min_identity_updates), ``[tracker]``, ``[fusion]``, ``[bias]`` and ``[radars."25/11"]``
        tables."""
        known = {"evaluation", "tracker", "fusion", "bias", "radars", "atmosphere"}
        unknown = set(doc) - known
        if unknown:
            raise ValueError(f"unknown configuration tables {sorted(unknown)}; known: {known}")
        evaluation = dict(doc.get("evaluation", {}))
        allowed = {"geoid_m", "association_gate_m", "min_identity_updates"}
        if set(evaluation) - allowed:
            raise ValueError(f"[evaluation] knows only {sorted(allowed)}")
        tracker = dataclass_kwargs("tracker", doc.get("tracker", {}), TrackerConfig)
        fusion = FusionConfig(**dataclass_kwargs("fusion", doc.get("fusion", {}), FusionConfig))
        bias = BiasConfig(**dataclass_kwargs("bias", doc.get("bias", {}), BiasConfig))
        radars = {str(k): dict(v) for k, v in dict(doc.get("radars", {})).items()}
        atmosphere = None
        if "atmosphere" in doc:
            atmosphere = Atmosphere(**dataclass_kwargs("atmosphere", doc["atmosphere"], Atmosphere))
        return cls(
            radars=radars,
            tracker=tracker,
            fusion=fusion,
            bias=bias,
            atmosphere=atmosphere,
            **evaluation,
        )


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
    system: npt.NDArray[Any]
    """System-track rows (``fusion.SYSTEM_UPDATE_DTYPE``) in processing order."""
    sources: list[str]
    """The radars in fusion order: ``system["radar"]`` indexes this list."""
    bias: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]]
    """Each radar's bias estimate and covariance at the end (empty when not estimated)."""
    bias_history: list[tuple[float, str, npt.NDArray[np.float64], npt.NDArray[np.float64]]]
    clock: dict[str, tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]] = field(
        default_factory=dict
    )
    """Each radar's extra clock states [drift s/s, drift rate s/s^2] and covariance at the end
    (``BiasConfig.clock_states`` - 1 of them; empty when not estimated)."""
    clock_history: list[tuple[float, str, npt.NDArray[np.float64], npt.NDArray[np.float64]]] = (
        field(default_factory=list)
    )


def _truth_plot_index(recording: Recording) -> dict[tuple[str, int], list[dict[str, Any]]]:
    index: dict[tuple[str, int], list[dict[str, Any]]] = {}
    if "/truth/plots" not in recording.topics:
        return index
    for message in recording.messages("/truth/plots"):
        index[(str(message["source"]), int(message["sequence"]))] = list(message["records"])
    return index


def run_pipeline(
    path: str | Path | Recording,
    config: EvaluationConfig | None = None,
    make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
) -> PipelineResult:
    """Track every radar of a recording; see the module docstring. ``make_tracker(source,
    config)`` builds each radar's tracker (a benchmark passes one that times ``process``)."""
    config = config or EvaluationConfig()
    recording = path if isinstance(path, Recording) else read_recording(path)
    infos = radar_infos(recording.metadata, config.radars, config.geoid_m)
    plane = system_plane(recording.metadata, infos)
    truth_plots = _truth_plot_index(recording)
    atmosphere = config.atmosphere or recording_atmosphere(recording.metadata)
    chain = Chain(
        infos,
        plane,
        config.tracker,
        make_tracker,
        config.fusion,
        config.bias,
        atmosphere=atmosphere,
        bias_history=True,
    )
    system: list[npt.NDArray[Any]] = []
    sequences: dict[str, int] = defaultdict(int)
    updates: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    tables: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    origins: dict[int, tuple[str, int, int]] = {}

    for datagram in recording.datagrams():
        if datagram.lan == "B":
            # The redundant LAN's copy: same bytes, and /truth/plots counts LAN A only.
            continue
        sequence = sequences[datagram.source]
        sequences[datagram.source] += 1
        outputs = chain.feed(datagram.payload, datagram.time)
        for output in outputs:
            table = output.plots
            # The truth numbers every datagram of the source, plotless ones included.
            table["sequence"] = sequence
            records = truth_plots.get((datagram.source, sequence))
            if records is not None and (len(outputs) > 1 or len(records) != len(table)):
                # A record the plot path could not read would shift every later index.
                log.warning(
                    "%s datagram %d: %d plots read, truth lists %d records; origins dropped",
                    datagram.source,
                    sequence,
                    len(table),
                    len(records),
                )
                records = None
            if records is not None:
                table["kind"] = [KIND_NAMES.get(r["kind"], KIND_UNKNOWN) for r in records]
                table["aircraft"] = [
                    -1 if r["aircraft"] is None else r["aircraft"] for r in records
                ]
                table["detection_time"] = [r["detection_time"] for r in records]
            tables[output.source].append(table)
            updates[output.source].append(output.local)
            if len(output.system):
                system.append(output.system)
            for row, plot_id in enumerate(table["plot_id"].tolist()):
                origins[plot_id] = (datagram.source, sequence, row)

    radars: dict[str, RadarRun] = {}
    for source in sorted(chain.radars, key=source_order):
        state = chain.radars[source]
        radars[source] = RadarRun(
            state.info,
            np.concatenate(updates[source]),
            np.concatenate(tables[source]),
            state.tracker_config,
        )
        log.info(
            "%s: %d plots, %d track updates, stats %s",
            source,
            len(radars[source].plots),
            len(radars[source].updates),
            state.tracker.stats,
        )
    rows = np.concatenate(system) if system else np.zeros(0, SYSTEM_UPDATE_DTYPE)
    return PipelineResult(
        recording,
        plane,
        radars,
        origins,
        rows,
        chain.sources,
        chain.bias_estimates(),
        chain.bias_history,
        chain.clock_estimates(),
        chain.clock_history,
    )
