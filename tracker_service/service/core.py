"""The service core: one ``Chain`` wired to the outputs (Zenoh, MCAP).

``TrackerService.process(input_name, datagram)`` hands the raw datagram to the outputs
(for the log), feeds it to the chain and hands what comes out to ``Outputs``, which turns
it into the published messages: system tracks (and their end), local tracks, CAT062/CAT065
batches, bias estimates and status. ``Outputs`` runs in the same process (the replay) or
in one of its own (the daemon: ``command.OutputProcess``), so that the chain has a core
to itself. The core reads no clock:
every time it uses is a reception time of the data ("data time"), so the same datagrams in
the same order give the same messages, whether they come from a replay or from the
daemon's inputs. Only ``advance`` (called by the daemon while its feeds are quiet) moves
data time without data.
"""

from __future__ import annotations

import logging
import math
import os
from collections import Counter, defaultdict
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from asterix.containers import Datagram
from tracker_service.adsb import AdsbReports
from tracker_service.adsb_status import AdsbCount, adsb_count
from tracker_service.bias import BiasConfig, ObservedFrom
from tracker_service.chain import (
    CAT021,
    PLOT_CATEGORIES,
    SERVICE_CATEGORIES,
    BatchOutput,
    Chain,
    FieldMonitor,
    PlotUse,
    RadarInfo,
    RadarStageFailed,
    RadarStages,
    recording_atmosphere,
    rejections,
    source_order,
)
from tracker_service.fixed_targets import FixedTransponder
from tracker_service.fusion import FusionConfig
from tracker_service.fusion.lifecycle import number_shortage_reasons
from tracker_service.geodesy import RadarSite, SystemPlane
from tracker_service.inputs.udp import InputCounters, block_chain_error
from tracker_service.loop_load import LoadShares, LoopLoad, LoopTotals
from tracker_service.outputs.asterix_udp import AsterixUdpSink
from tracker_service.outputs.cat062 import PeriodRecords, encode_cat065
from tracker_service.outputs.foxglove_scene import MapRadar
from tracker_service.outputs.foxglove_sink import live_sink, with_map_channels
from tracker_service.outputs.mapping import MessageMapper
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.mcap_sink import CAT062_TOPIC, SYSTEM_TRACKS_TOPIC, McapSink
from tracker_service.outputs.messages import (
    OutputStatus,
    RadarStatus,
    StatusMessage,
    SystemTrackMessage,
)
from tracker_service.outputs.sink import Backoff, IsolatedSink, OutputState, QueuedSink, Sink
from tracker_service.outputs.updates import SystemUpdate
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_picture import ZenohPictureSink
from tracker_service.outputs.zenoh_sink import ZenohSink
from tracker_service.radar_stage import RadarStage
from tracker_service.ratelimit import RateLimitedLog
from tracker_service.service.config import ServiceConfig, parse_service_config
from tracker_service.service.memory import resident_mb
from tracker_service.sources import SourceCounts
from tracker_service.stage_messages import RadarBatch
from tracker_service.test_targets import SeenTestTargets
from tracker_service.time_sanity import (
    TimeReport,
    TimeSanityConfig,
    implausible_reasons,
    status_reasons,
)
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.validation import dataclass_kwargs

__all__ = [
    "CAT062_TOPIC",
    "HANDLED_CATEGORIES",
    "SYSTEM_TRACKS_TOPIC",
    "CoreState",
    "OutputSink",
    "Outputs",
    "OutputsFailed",
    "ServiceTimings",
    "TrackerService",
    "bias_config",
    "build_chain",
    "config_from_recording",
    "input_name",
    "radar_key",
]

log = logging.getLogger(__name__)

SILENT_PERIODS = 3.0
"""A radar whose last datagram is this many antenna periods old is not receiving; one
whose tracked plots updated no local track for as long is not tracking."""
ADSB_SILENT_S = 10.0
"""An ADS-B feed (no antenna) silent this long is not receiving (ground stations report
each aircraft every 0.5-1 s)."""
FUTURE_PLOT_S = 2.0
"""A plot time this far after its reception: the radar's clock is ahead."""
LATE_PERIODS = 3.0
"""A plot received this many antenna periods after its time of measurement: the radar's
clock is behind (a sector is sent within a fraction of a turn)."""
LAG_LIMIT_S = 5.0
"""The chain this far behind the wall clock (beyond the holding window): degraded."""
RESTART_DEGRADED_S = 60.0
"""Health stays degraded this long (data time) after the output process was restarted."""
HANDLED_CATEGORIES = frozenset((CAT021, *PLOT_CATEGORIES, *SERVICE_CATEGORIES))
"""ASTERIX categories the chain reads; blocks of others are counted (unknown_category)."""
ERROR_KINDS = (
    "not_asterix",
    "decode_error",
    "unknown_category",
    "no_source",
    "unknown_source",
    "processing_failed",
)
"""The kinds of ``RadarStatus.errors``: a fixed set, so that status stays bounded."""


@dataclass(frozen=True)
class ServiceTimings:
    """Cadences of the periodic outputs, in seconds of data time."""

    cat062_s: float = 1.0
    status_s: float = 5.0
    bias_s: float = 10.0


def input_name(source: str) -> str:
    """The input (and MCAP topic) name of a feed: "25/11" -> "25_11"."""
    return source.replace("/", "_")


def radar_key(name: str) -> str:
    """The inverse of :func:`input_name`."""
    return name.replace("_", "/")


def _fixed_transponder(entry: Any) -> FixedTransponder:
    return FixedTransponder(
        address=None if entry.address is None else int(entry.address, 16),
        mode3a=None if entry.mode3a is None else int(entry.mode3a, 8),
        lat_deg=entry.lat,
        lon_deg=entry.lon,
        alt_m=entry.alt_m,
        tolerance_m=entry.tolerance_m,
        name=entry.name,
    )


def _radar_info(radar: Any) -> RadarInfo:
    monitor = radar.field_monitor
    return RadarInfo(
        source=radar.key,
        site=RadarSite(radar.lat, radar.lon, radar.alt_m, radar.geoid_m, radar.north_offset_deg),
        period_s=radar.antenna_period_s,
        sigma_range_m=radar.sigma_range_m,
        sigma_azimuth_deg=radar.sigma_azimuth_deg,
        psr_sigma_range_m=radar.psr_sigma_range_m or radar.sigma_range_m,
        psr_sigma_azimuth_deg=radar.psr_sigma_azimuth_deg or radar.sigma_azimuth_deg,
        field_monitor=(
            None if monitor is None else FieldMonitor(monitor.lat, monitor.lon, monitor.alt_m)
        ),
        time_base=radar.time_base,
        fixed_transponders=tuple(_fixed_transponder(e) for e in radar.fixed_transponders),
    )


def bias_config(config: ServiceConfig) -> BiasConfig:
    """The ``[bias]`` table as a ``BiasConfig``; radars marked ``reference`` anchor the bias
    filters with a zero bias (their index is their place in the chain's SAC/SIC order)."""
    values = dataclass_kwargs("bias", config.bias, BiasConfig)
    order = sorted((radar.key for radar in config.radars), key=source_order)
    references = {
        order.index(radar.key): (0.0, 0.0, 0.0, 0.0) for radar in config.radars if radar.reference
    }
    if references:
        values["reference_radars"] = references | dict(values.get("reference_radars", {}))
    return BiasConfig(**values)


def _chain_arguments(config: ServiceConfig) -> dict[str, Any]:
    """``Chain`` arguments of a configuration (the radar stage takes its share of them)."""
    return {
        "radars": {radar.key: _radar_info(radar) for radar in config.radars},
        "plane": SystemPlane(
            config.system.centre_lat, config.system.centre_lon, config.system.projection
        ),
        "tracker": dataclass_kwargs("tracker", config.tracker, TrackerConfig),
        "time_sanity": TimeSanityConfig(
            **dataclass_kwargs("time_sanity", config.time_sanity, TimeSanityConfig)
        ),
        "fixed_targets": config.fixed_target_config(),
        "max_unknown_sources": config.system.max_unknown_sources,
        "atmosphere": config.atmosphere_config(),
    }


def build_chain(
    config: ServiceConfig,
    make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
    radar_stage: RadarStages | None = None,
) -> Chain:
    """The chain of a configuration: its radars, plane, tracker, fusion and bias settings;
    ``make_tracker`` as for ``Chain`` (assess passes one that keeps the plots it tracks);
    ``radar_stage``: radar stages in other processes (``distribution``)."""
    fusion = FusionConfig(**dataclass_kwargs("fusion", config.fusion, FusionConfig))
    return Chain(
        **_chain_arguments(config),
        make_tracker=make_tracker,
        fusion=fusion,
        bias=bias_config(config),
        radar_stage=radar_stage,
    )


def build_radar_stage(config: ServiceConfig, incarnation: int = 0) -> RadarStage:
    """The radar stage of a configuration, as ``build_chain`` makes it (every configured
    radar known to it: which of them it is fed is its caller's choice)."""
    arguments = _chain_arguments(config)
    return RadarStage(
        arguments["radars"],
        arguments["plane"],
        arguments["tracker"],
        None,
        arguments["time_sanity"],
        arguments["fixed_targets"],
        arguments["max_unknown_sources"],
        incarnation,
        arguments["atmosphere"],
    )


def config_from_recording(metadata: Mapping[str, Any]) -> ServiceConfig:
    """A service configuration for a simulator recording: its radars (what an operator would
    know: site, period, sigmas, field monitor), ADS-B stations and system centre; the
    service's own SAC/SIC is the first radar's SAC with the first SIC from 100 unused."""
    radars = [dict(r) for r in dict(metadata.get("radars", {})).values()]
    if not radars:
        raise ValueError("the recording's metadata names no radar")
    keep = (
        "name",
        "sac",
        "sic",
        "lat",
        "lon",
        "alt_m",
        "antenna_period_s",
        "sigma_range_m",
        "sigma_azimuth_deg",
        "psr_sigma_range_m",
        "psr_sigma_azimuth_deg",
        "field_monitor",
    )
    adsb = [
        {"name": s.get("name", ""), "sac": s["sac"], "sic": s["sic"]}
        for s in dict(metadata.get("adsb_stations", {})).values()
    ]
    used = {(r["sac"], r["sic"]) for r in radars} | {(s["sac"], s["sic"]) for s in adsb}
    sac = int(radars[0]["sac"])
    sic = next(n for n in range(100, 256) if (sac, n) not in used)
    centre = dict(metadata.get("scenario", {})).get("system_centre")
    if not isinstance(centre, dict):
        centre = {
            "lat": float(np.mean([r["lat"] for r in radars])),
            "lon": float(np.mean([r["lon"] for r in radars])),
        }
    atmosphere = recording_atmosphere(metadata)
    doc = {
        "atmosphere": {
            "qnh_hpa": atmosphere.qnh_hpa,
            "isa_deviation_k": atmosphere.isa_deviation_k,
        },
        "radars": [{k: r[k] for k in keep if r.get(k) is not None} for r in radars],
        "adsb": adsb,
        "system": {
            "centre_lat": centre["lat"],
            "centre_lon": centre["lon"],
            "sac": sac,
            "sic": sic,
        },
    }
    return parse_service_config(doc, "the recording's metadata")


@dataclass
class _RadarCounters:
    last_plot_time: float | None = None
    last_reception: float | None = None
    plot_delay: float | None = None
    tracked_since: float | None = None
    """Data time from which the radar's tracked plots have come without a silence."""
    last_tracked_plot: float | None = None
    last_local_update: float | None = None
    plots: int = 0
    plots_at_last_status: int = 0
    implausible_at_last_status: int = 0
    errors: Counter[str] = field(default_factory=Counter)
    rejected: Counter[str] = field(default_factory=Counter)
    time: TimeReport | None = None
    test_targets: SeenTestTargets = field(default_factory=SeenTestTargets)


@dataclass(frozen=True)
class CoreState:
    """What the core (the chain's process) knows that the status needs: sent to
    ``Outputs`` with each status, wherever it runs."""

    lag_s: float | None = None
    sources: SourceCounts = field(default_factory=SourceCounts)
    restarts: int = 0
    """Times the output process was restarted."""
    last_restart: str | None = None
    """Why the output process was last restarted (its exit code)."""
    reasons: tuple[str, ...] = ()
    """Reason lines of the checks that run with the chain (``TrackerService.core_reasons``)."""
    memory_mb: tuple[tuple[str, float], ...] = ()
    """A live service's processes by role and their resident memory, lately
    (``TrackerService.note_live``; the status's ``memory_mb``)."""
    busy: tuple[tuple[str, float], ...] = ()
    """A live service's process loops by role and their busy share since the last status
    (``TrackerService.note_live``; the status's ``busy``)."""


@dataclass
class _FailedCalls:
    failures: int = 0
    failures_at_last_status: int = 0
    last_error: str | None = None


@dataclass
class ServiceCounts:
    """Totals since start, for the summary of a replay and for tests."""

    datagrams: int = 0
    plots: int = 0
    errors: int = 0
    system_updates: int = 0
    system_tracks: set[int] = field(default_factory=set)


class Outputs:
    """Everything after the chain: the messages (``outputs.mapping``), the sinks (Zenoh,
    MCAP, each isolated: ``outputs.sink``), CAT062 and the counters.

    Its state follows only from the calls it receives, in their order, and every call
    carries plain data (datagrams, the chain's numpy rows, bias arrays), so that it runs
    in the core's process or in a process of its own (``command.OutputProcess``) with the
    same messages. ``publisher`` and ``log`` are optional (a test or a benchmark may run
    without either); it closes neither. A sink that fails is reported in the status and
    retried; the others go on."""

    def __init__(
        self,
        config: ServiceConfig,
        publisher: ZenohPublisher | None = None,
        log_file: McapLog | None = None,
        timings: ServiceTimings | None = None,
        *,
        backoff: Backoff | None = None,
    ) -> None:
        self.config = config
        self.plane = SystemPlane(
            config.system.centre_lat, config.system.centre_lon, config.system.projection
        )
        self.mapper = MessageMapper(self.plane)
        self.publisher = publisher
        self.log = log_file
        adapters: list[Sink] = []
        if publisher is not None:
            adapters.append(ZenohSink(publisher))
            if config.zenoh.period_s is not None:
                picture = ZenohPictureSink(
                    publisher, self.plane, config.system, config.zenoh.period_s
                )
                adapters.append(picture)
        if log_file is not None:
            adapters.append(logged_with_map(config, McapSink(log_file), log_file))
        adapters.extend(AsterixUdpSink(o, config.system, self.plane) for o in config.asterix_udp)
        adapters.extend(live_map(config))
        self.sinks = [QueuedSink(IsolatedSink(sink, backoff)) for sink in adapters]
        self.timings = timings or ServiceTimings()
        self.counts = ServiceCounts()
        self.input_counters: dict[str, InputCounters] = {}
        """Per input name, what the input stage counted (duplicates, drops, malformed);
        the daemon and the replay keep it current."""
        self._periods = {radar.key: radar.antenna_period_s for radar in config.radars}
        self._feeds = [r.key for r in config.radars] + [a.key for a in config.adsb]
        self._adsb_feeds = frozenset(a.key for a in config.adsb)
        self._radars: dict[str, _RadarCounters] = defaultdict(_RadarCounters)
        self._cat062 = PeriodRecords(config.system)
        self._cat062_batches = 0
        self._start: float | None = None
        self._now = -math.inf
        self._unattributed: Counter[str] = Counter()
        self._behind_at_last_status = 0
        self._core = CoreState()
        self._restarted_at: float | None = None
        self._failed_calls: dict[str, _FailedCalls] = {}
        self._warn = RateLimitedLog(log)
        self.health_file: Path | None = None
        """Where each status is also written, as JSON (``tracker-service health``)."""
        self.loop: LoopLoad | None = None
        """The output process's loop (its pipe's calls), when it runs in one: its busy
        share joins the core's (``busy["outputs"]``)."""
        self._loop_shares = LoadShares()

    @property
    def live_tracks(self) -> list[int]:
        return self.mapper.live_tracks

    def picture(self) -> dict[int, SystemTrackMessage]:
        """The latest message of every live system track."""
        return self.mapper.picture()

    def output_states(self) -> list[OutputState]:
        """Each output's state (delivered, dropped, failing since when and why)."""
        return [sink.state for sink in self.sinks]

    def drain(self) -> None:
        """Waits until every output has made the calls queued to it (tests, the end)."""
        for sink in self.sinks:
            sink.drain()

    def output_reasons(self) -> list[str]:
        """A status line for each failing output, e.g. "output mcap: disk full since ..."."""
        return [line for sink in self.sinks if (line := sink.state.reason_line()) is not None]

    def advance(self, time: float) -> None:
        """Data time moves on to ``time`` (a reception time, or the daemon's quiet clock)."""
        if self._start is None:
            self._start = time
        self._now = max(self._now, time)

    def set_input_counters(self, counters: dict[str, InputCounters]) -> None:
        self.input_counters = counters

    def set_core_state(self, state: CoreState) -> None:
        if state.restarts > self._core.restarts:
            self._restarted_at = self._now
        self._core = state

    def _entry(self, key: str) -> _RadarCounters | None:
        """The status entry of a radar: configured, or met in the chain's output (which
        admits a bounded number of unknown sources); None for any other name, whose
        counts go to ``unattributed`` so that status stays bounded."""
        if key in self._radars or key in self._periods or key in self._feeds:
            return self._radars[key]
        return None

    def received(self, name: str, datagram: Datagram, adsb: AdsbCount | None = None) -> None:
        """A datagram reaches the core: data time moves to its reception, and it is logged;
        ``adsb``: its CAT021 reports (``adsb_status``), counted if it is an ADS-B feed's."""
        assert datagram.time is not None
        self.advance(datagram.time)
        self.counts.datagrams += 1
        key = radar_key(name)
        entry = self._entry(key)
        if entry is not None:
            entry.last_reception = datagram.time
            if key in self._adsb_feeds and adsb is not None:
                self._count_adsb(entry, adsb, datagram.time)
        for sink in self.sinks:
            sink.datagram(name, datagram)

    def _count_adsb(self, entry: _RadarCounters, adsb: AdsbCount, received: float) -> None:
        """An ADS-B feed's reports, which the chain makes no plots of (``adsb_status``)."""
        entry.plots += adsb.records
        if adsb.latest is not None:
            entry.last_plot_time = max(entry.last_plot_time or adsb.latest, adsb.latest)
            entry.plot_delay = received - entry.last_plot_time

    def error(self, name: str, kind: str, detail: str = "") -> None:
        """One datagram (or part) of input ``name`` dropped; ``kind``: one of
        ``ERROR_KINDS``; ``detail`` goes to the (rate-limited) log only."""
        self.count(name, kind, 1)
        text = f"{kind}: {detail}" if detail else kind
        self._warn.warning(kind, "%s: datagram at %.3f dropped (%s)", name, self._now, text)

    def count(self, name: str, kind: str, n: int) -> None:
        """``n`` more of ``kind`` (``ERROR_KINDS``) on input ``name``, not logged."""
        self.counts.errors += n
        entry = self._entry(radar_key(name))
        if entry is None:
            self._unattributed[kind] += n
        else:
            entry.errors[kind] += n

    def sink_failed(self, sink: str, error: str) -> None:
        """An output (``"zenoh"``, ``"mcap"``, ...) failed a call: health is degraded
        until a status interval passes without failure."""
        state = self._failed_calls.setdefault(sink, _FailedCalls())
        state.failures += 1
        state.last_error = error[:200]

    # --- per batch ---------------------------------------------------------------------

    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None:
        """What the chain made of one radar's part of a datagram; ``sources`` names the
        chain's radars by index (``Chain.sources``); ``received``: data time moves there
        first (``advance``)."""
        if received is not None:
            self.advance(received)
        plots = output.plots
        counters = self._radars[output.source]
        counters.last_reception = self._now
        if output.source in self._adsb_feeds:
            # Its reports are counted at reception (adsb_status); here, what fusion made
            # of them: fused, kept as the bias reference, repeated, inconsistent, unfit.
            counters.rejected.update(rejections(plots["use"]))
            plots = plots[:0]
        self.counts.plots += len(plots)
        counters.plots += len(plots)
        if len(plots):
            # A plot whose time is implausible says nothing of when the radar was heard.
            timed = plots["time"][plots["use"] != PlotUse.TIME_IMPLAUSIBLE.value]
            if len(timed):
                counters.last_plot_time = float(timed.max())
                counters.plot_delay = self._now - counters.last_plot_time
            counters.rejected.update(rejections(plots["use"]))
            if "implausible_daps" in (plots.dtype.names or ()) and plots["implausible_daps"].any():
                counters.rejected["implausible_daps"] += int(plots["implausible_daps"].sum())
            counters.test_targets.update(plots)
            if (plots["use"] == PlotUse.TRACKED.value).any():
                last = counters.last_tracked_plot
                if last is None or self._now - last > self._silence_s(output.source):
                    counters.tracked_since = self._now  # tracks need some scans to form
                counters.last_tracked_plot = self._now
        if len(output.local):
            counters.last_local_update = self._now
        if output.time is not None:
            counters.time = output.time
            if output.time.out_of_line_plots:
                # A running count already: the tracker's, not this batch's.
                counters.rejected["out_of_line"] = output.time.out_of_line_plots
        # The batch path (outputs/updates.py): JSON written from the rows, each sink
        # called once per batch, no pydantic model per update.
        local = self.mapper.local_updates(output.source, output.local)
        if local:
            for sink in self.sinks:
                sink.local_updates(output.source, local, self._now)
        if len(output.system):
            self._emit_system(self.mapper.system_updates(output.system, output.plots, sources))

    def _emit_system(self, updates: list[SystemUpdate]) -> None:
        if not updates:
            return
        self.counts.system_updates += len(updates)
        self.counts.system_tracks.update(update.number for update in updates)
        for sink in self.sinks:
            sink.system_updates(updates, self._now)
        # After the sinks have the batch: a chunk of CAT062's records may be encoded here.
        self._cat062.update(updates)

    # --- periodic outputs (the core says when) -----------------------------------------

    def publish_cat062(self) -> None:
        """The tracks updated since the last call (``cat062.PeriodRecords``: most records
        already encoded as their updates came), then a CAT065 end of batch."""
        data = self._cat062.block() + encode_cat065(
            "end_of_batch", self._now, self._cat062_batches, self.config.system
        )
        self._cat062_batches += 1
        for sink in self.sinks:
            sink.asterix(data, self._now)

    def publish_bias(
        self,
        estimates: dict[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
        observed_from: dict[str, ObservedFrom],
    ) -> None:
        for message in self.mapper.bias(estimates, observed_from, self._now):
            for sink in self.sinks:
                sink.bias(message, self._now)

    def _silence_s(self, key: str) -> float:
        period = self._periods.get(key)
        return ADSB_SILENT_S if period is None else SILENT_PERIODS * period

    def _radar_health(self, key: str, c: _RadarCounters, reasons: list[str]) -> tuple[bool, ...]:
        """(receiving, tracking, time sane) of one radar, a reason line for each that is
        not."""
        now = self._now
        silence = self._silence_s(key)
        start = self._now if self._start is None else self._start
        receiving = True
        if c.last_reception is None:
            if now - start > silence:
                receiving = False
                reasons.append(f"radar {key}: nothing received in {now - start:.0f} s")
        elif now - c.last_reception > silence:
            receiving = False
            reasons.append(
                f"radar {key}: silent for {now - c.last_reception:.0f} s (more than {silence:g} s)"
            )
        tracking = True
        if (
            receiving
            and key in self._periods
            and c.last_tracked_plot is not None
            and now - c.last_tracked_plot <= silence
            and c.tracked_since is not None
            and now - max(c.last_local_update or -math.inf, c.tracked_since) > silence
        ):
            tracking = False
            reasons.append(
                f"radar {key}: plots arrive but no local track was updated for "
                f"{silence:g} s (the tracker is stalled)"
            )
        time_sane = True
        period = self._periods.get(key)
        if receiving and c.plot_delay is not None and period is not None:
            if c.plot_delay < -FUTURE_PLOT_S:
                time_sane = False
                reasons.append(
                    f"radar {key}: plot times {-c.plot_delay:.1f} s after their reception "
                    "(its clock is ahead)"
                )
            elif c.plot_delay > LATE_PERIODS * period:
                time_sane = False
                reasons.append(
                    f"radar {key}: plots received {c.plot_delay:.1f} s after their time of "
                    f"measurement (more than {LATE_PERIODS:g} antenna periods: its clock is "
                    "behind, or the feed is buffered)"
                )
        return receiving, tracking, time_sane

    def _output_health(self, reasons: list[str]) -> list[OutputStatus]:
        """Each output's state (the sinks: Zenoh, MCAP; failed calls counted by name: the
        health file, the output process's calls; the output process itself), a reason
        line for each that is not ok."""
        outputs = []
        for state in self.output_states():
            line = state.reason_line()
            if line is not None:
                reasons.append(line)
            outputs.append(
                OutputStatus(
                    name=state.name,
                    ok=state.ok,
                    failures=state.outages,
                    last_error=state.reason or None,
                )
            )
        for name, sink in sorted(self._failed_calls.items()):
            failing = sink.failures > sink.failures_at_last_status
            if failing:
                reasons.append(
                    f"output {name}: {sink.failures - sink.failures_at_last_status} failed "
                    f"call(s) since the last status ({sink.last_error})"
                )
            outputs.append(
                OutputStatus(
                    name=name,
                    ok=not failing,
                    failures=sink.failures,
                    last_error=sink.last_error,
                )
            )
        core = self._core
        if core.restarts:
            recent = (
                self._restarted_at is not None
                and self._now - self._restarted_at <= RESTART_DEGRADED_S
            )
            if recent:
                reasons.append(
                    f"output process restarted ({core.last_restart}); {core.restarts} "
                    "restart(s) since start"
                )
            outputs.append(
                OutputStatus(
                    name="output_process",
                    ok=not recent,
                    restarts=core.restarts,
                    last_error=core.last_restart,
                )
            )
        return outputs

    def status(self) -> StatusMessage:
        """The current status: per feed, its counters and whether it is receiving,
        tracking and its time sane; per output, failures; the chain's lag; health
        "degraded" with a reason line for each state that is not ok."""
        start = self._now if self._start is None else self._start
        interval = self.timings.status_s
        radars = []
        reasons: list[str] = []
        for key in sorted({*self._feeds, *self._radars}, key=source_order):
            counters = self._radars[key]
            inputs = self.input_counters.get(input_name(key), InputCounters())
            rate = (counters.plots - counters.plots_at_last_status) / interval
            # An unknown source (not configured) is no part of the expected picture: its
            # states are shown, but its silence or its clock degrade nothing.
            expected = reasons if key in self._feeds else []
            receiving, tracking, time_sane = self._radar_health(key, counters, expected)
            causes = {
                "queue": inputs.dropped,
                "holding_window": inputs.held_dropped,
                "kernel": inputs.kernel_drops,
                "behind": inputs.behind_dropped,
                "warm_up": inputs.warm_up_dropped,
            }
            errors = {kind: counters.errors[kind] for kind in ERROR_KINDS if counters.errors[kind]}
            if counters.time is not None:
                # The radar's own timeline (time_sanity): its offset from reception, its
                # clock jumps and its plots whose time does not fit.
                time_reasons = status_reasons(counters.time, counters.last_plot_time)
                time_reasons += implausible_reasons(
                    key,
                    counters.rejected["time_implausible"] - counters.implausible_at_last_status,
                    counters.plots - counters.plots_at_last_status,
                )
                time_sane &= not time_reasons
                expected += time_reasons
            radars.append(
                RadarStatus(
                    radar=key,
                    last_plot_time=counters.last_plot_time,
                    plots_per_second=max(rate, 0.0),
                    decode_errors=sum(errors.values()) + inputs.malformed,
                    duplicates=inputs.duplicates,
                    drops=sum(causes.values()),
                    rejected=dict(sorted(counters.rejected.items())),
                    time_offset_s=None if counters.time is None else counters.time.offset_s,
                    test_targets=counters.test_targets.checks(),
                    errors=errors,
                    repeats=inputs.repeats,
                    drop_causes={cause: n for cause, n in causes.items() if n},
                    last_reception_time=counters.last_reception,
                    plot_delay_s=counters.plot_delay,
                    receiving=receiving,
                    tracking=tracking,
                    time_sane=time_sane,
                )
            )
        reasons.extend(self._core.reasons)
        outputs = self._output_health(reasons)
        lag = self._core.lag_s
        if lag is not None and lag > LAG_LIMIT_S:
            reasons.append(f"the chain is {lag:.1f} s behind the wall clock")
        shed = self._behind_dropped() - self._behind_at_last_status
        if shed > 0:
            reasons.append(
                f"the chain is overloaded: {shed} datagram(s) dropped unprocessed since the "
                "last status, their turn more than [system] max_behind_s behind the wall clock"
            )
        unattributed = dict(self._unattributed)
        if self._core.sources.unknown_sources_dropped:
            unattributed["unknown_sources_dropped"] = self._core.sources.unknown_sources_dropped
        return StatusMessage(
            # Before any data (a status asked for at once): time 0, up for 0 s.
            time=self._now if self._start is not None else 0.0,
            uptime_s=max(self._now - start, 0.0) if self._start is not None else 0.0,
            health="degraded" if reasons else "ok",
            reasons=reasons,
            radars=radars,
            outputs=outputs,
            lag_s=lag,
            unattributed=dict(sorted(unattributed.items())),
            memory_mb=dict(self._core.memory_mb),
            busy=self._busy(),
        )

    def _busy(self) -> dict[str, float]:
        busy = dict(self._core.busy)
        if self.loop is not None:
            busy.update(self._loop_shares.shares({"outputs": self.loop.totals()}))
        return busy

    def _behind_dropped(self) -> int:
        return sum(c.behind_dropped for c in self.input_counters.values())

    def publish_status(self) -> None:
        message = self.status()
        self._behind_at_last_status = self._behind_dropped()
        for counters in self._radars.values():
            counters.plots_at_last_status = counters.plots
            counters.implausible_at_last_status = counters.rejected["time_implausible"]
        for calls in self._failed_calls.values():
            calls.failures_at_last_status = calls.failures
        # The health file first: whatever the sinks do, `health` learns the state.
        if self.health_file is not None:
            try:
                write_health(self.health_file, message)
            except OSError as exc:
                self.sink_failed("health_file", f"{type(exc).__name__}: {exc}")
                self._warn.error("health_file", "cannot write %s: %s", self.health_file, exc)
        for sink in self.sinks:
            sink.status(message, self._now)

    @property
    def pid(self) -> int | None:
        """None: this process (``OutputSink``)."""
        return None

    def close(self) -> None:
        """Ends every live track (an "ended" message each, and its key deleted), sends the
        last CAT062 batch and a status, then ``stop``."""
        try:
            if self._start is None:
                return
            self._emit_system(self.mapper.end_all_updates())
            self.publish_cat062()
            self.publish_status()
            log.info(
                "%d datagrams, %d system tracks (%d updates), %d errors",
                self.counts.datagrams,
                len(self.counts.system_tracks),
                self.counts.system_updates,
                self.counts.errors,
            )
        finally:
            self.stop()

    def stop(self) -> None:
        """Each output makes the calls queued to it, and its thread ends: after this, the
        owner may close the publisher and the log. Later calls do nothing."""
        for sink in self.sinks:
            sink.close()


def logged_with_map(config: ServiceConfig, log_sink: Sink, log_file: McapLog) -> Sink:
    """The log's sink with the Foxglove map channels in the same log (``[foxglove]``)."""
    fox = config.foxglove
    return with_map_channels(
        log_sink,
        log_file,
        radar_sites(config),
        trail_s=fox.trail_s,
        picture_period_s=fox.log_picture_period_s,
    )


def live_map(config: ServiceConfig) -> list[Sink]:
    """The Foxglove live view, when ``[foxglove] listen`` (``--foxglove-listen``) asks."""
    fox = config.foxglove
    if fox.listen is None:
        return []
    sites = radar_sites(config)
    return [
        live_sink(sites, fox.listen, trail_s=fox.trail_s, picture_period_s=fox.picture_period_s)
    ]


def radar_sites(config: ServiceConfig) -> list[MapRadar]:
    """The configured radars as the map draws them (``[foxglove]`` range rings)."""
    rings = config.foxglove.ranges_nm
    return [
        MapRadar(r.key, r.name, r.lat, r.lon, rings.get(r.key, config.foxglove.range_nm))
        for r in config.radars
    ]


def block_categories(payload: bytes) -> Iterator[int]:
    """The category of each data block of a datagram whose framing is valid."""
    pos = 0
    while pos + 3 <= len(payload):
        yield payload[pos]
        pos += max((payload[pos + 1] << 8) | payload[pos + 2], 3)


def write_health(path: Path, message: StatusMessage) -> None:
    """The status as JSON in ``path``, replaced atomically (a reader never sees half)."""
    partial = path.with_name(f".{path.name}.partial")
    partial.write_text(message.model_dump_json(), encoding="utf-8")
    os.replace(partial, path)


class OutputsFailed(RuntimeError):
    """The outputs are gone for good (``command.OutputProcessFailed``: the output process
    died once too often): no datagram's fault, so the core does not count and skip the
    datagram it was publishing but lets the service stop, as for ``RadarStageFailed``."""


class OutputSink(Protocol):
    """What the core calls on its outputs: ``Outputs`` itself, or a proxy that sends each
    call to ``Outputs`` in another process (``command.OutputProcess``). A proxy whose
    outputs are gone for good raises ``OutputsFailed``."""

    def advance(self, time: float) -> None: ...
    def set_input_counters(self, counters: dict[str, InputCounters]) -> None: ...
    def set_core_state(self, state: CoreState) -> None: ...
    def received(self, name: str, datagram: Datagram, adsb: AdsbCount | None = None) -> None: ...
    def error(self, name: str, kind: str, detail: str = "") -> None: ...
    def count(self, name: str, kind: str, n: int) -> None: ...
    def batch(
        self, output: BatchOutput, sources: Sequence[str], received: float | None = None
    ) -> None: ...
    def publish_cat062(self) -> None: ...
    def publish_bias(
        self,
        estimates: dict[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
        observed_from: dict[str, ObservedFrom],
    ) -> None: ...
    def publish_status(self) -> None: ...
    def close(self) -> None: ...
    @property
    def pid(self) -> int | None:
        """The process the outputs run in when it is not this one."""


class TrackerService:
    """See the module docstring: the chain, the cadence of the periodic outputs, and the
    outputs (``Outputs`` in this process unless ``outputs`` gives another sink)."""

    def __init__(
        self,
        config: ServiceConfig,
        publisher: ZenohPublisher | None = None,
        log_file: McapLog | None = None,
        timings: ServiceTimings | None = None,
        outputs: OutputSink | None = None,
        radar_stage: RadarStages | None = None,
    ) -> None:
        self.config = config
        self.chain = build_chain(config, radar_stage=radar_stage)
        self.plane = self.chain.plane
        self.timings = timings or ServiceTimings()
        self.outputs = outputs or Outputs(config, publisher, log_file, self.timings)
        self._start: float | None = None
        self._now = -math.inf
        self._next: dict[str, float] = {}
        self._closed = False
        self._warn = RateLimitedLog(log)
        self.periodic_failures = 0
        self._input_counters: dict[str, InputCounters] | None = None
        self.core = CoreState()
        """The daemon's part of the status (lag, restarts of the output process)."""
        self._loops: dict[str, LoopTotals] = {}
        self._loop_shares = LoadShares()

    @property
    def local(self) -> Outputs:
        """The outputs when they run in this process (the replay, tests)."""
        if not isinstance(self.outputs, Outputs):
            raise RuntimeError("the outputs run in another process")
        return self.outputs

    @property
    def counts(self) -> ServiceCounts:
        return self.local.counts

    @property
    def log(self) -> McapLog | None:
        return self.local.log

    @property
    def live_tracks(self) -> list[int]:
        return self.local.live_tracks

    def picture(self) -> dict[int, SystemTrackMessage]:
        """The latest message of every live system track."""
        return self.local.picture()

    def status(self) -> StatusMessage:
        return self.local.status()

    def set_input_counters(self, counters: dict[str, InputCounters]) -> None:
        """Per input name, what the input stage counted (duplicates, drops, malformed).
        The replay's input keeps counting into the same ``counters``: sent again with each
        status, so that an output process (which got a copy) reports them as ``Outputs``
        in this process does."""
        self._input_counters = counters
        self.outputs.set_input_counters(counters)

    @property
    def now(self) -> float:
        """Data time: the latest reception time seen."""
        return self._now

    def process(self, name: str, datagram: Datagram) -> None:
        """One datagram that input ``name`` received at ``datagram.time``. Nothing raises
        out of here for bad data: what is dropped is counted by kind (``ERROR_KINDS``),
        logged at a bounded rate, and the service goes on."""
        if datagram.time is None:
            raise ValueError("the service needs each datagram's reception time")
        received = datagram.time
        self._advance_to(received)
        # Decoded once: for the chain, and for the status of an ADS-B feed (adsb_status).
        adsb = self.chain.decode_adsb(datagram.payload, received)
        self.outputs.received(name, datagram, adsb_count(adsb))
        reason = block_chain_error(datagram.payload)
        if reason is not None:
            self.outputs.error(name, "not_asterix", reason)
        else:
            self._feed(name, datagram.payload, received, adsb)
        self._periodic()

    def process_batch(self, batch: RadarBatch) -> None:
        """One radar stage's batch (``run --role fusion``): the central stage and the
        outputs, as ``process`` takes a datagram through the whole chain. Data time moves
        to the batch's reception on both sides: the outputs' own clock (status, log times,
        a radar's plot delay, CAT062/CAT065) follows no datagram here, and without this it
        stood still while radar batches kept arriving."""
        self._advance_to(batch.received)
        output = None
        try:
            output = self.chain.central.process(batch)
            self.outputs.batch(output, self.chain.sources, batch.received)
        except OutputsFailed:
            raise
        except Exception:
            if output is None:  # the outputs' data time moves all the same
                self.outputs.advance(batch.received)
            self._warn.exception(
                "processing",
                "radar %s: batch at %.3f could not be processed",
                batch.source,
                batch.received,
            )
            self.outputs.count(input_name(batch.source), "processing_failed", 1)
        self._periodic()

    def _feed(self, name: str, payload: bytes, received: float, adsb: list[AdsbReports]) -> None:
        unknown = [c for c in block_categories(payload) if c not in HANDLED_CATEGORIES]
        if unknown:
            self.outputs.error(name, "unknown_category", f"CAT{unknown[0]:03d} block(s) skipped")
        stats, admission = self.chain.stats, self.chain.admission
        errors, sources = stats.decode_errors, admission.counts
        try:
            outputs = self.chain.feed(payload, received, adsb)
            for output in outputs:
                self.outputs.batch(output, self.chain.sources)
        except (RadarStageFailed, OutputsFailed):
            raise
        except Exception:
            self._warn.exception(
                "processing", "%s: datagram at %.3f could not be processed", name, received
            )
            self.outputs.count(name, "processing_failed", 1)
        after = admission.counts
        for kind, n in (
            ("decode_error", stats.decode_errors - errors),
            ("no_source", after.no_source - sources.no_source),
            ("unknown_source", after.unknown_dropped - sources.unknown_dropped),
        ):
            if n:
                self.outputs.count(name, kind, n)

    def advance(self, now: float) -> None:
        """Data time moves on without data (the daemon: at its start, and while every feed
        is quiet): the periodic outputs that fall due go out."""
        self._advance_to(now)
        self.outputs.advance(now)
        self._periodic()

    def _advance_to(self, time: float) -> None:
        if self._start is None:
            self._start = time
            self._next = {
                "cat062": time + self.timings.cat062_s,
                # The first status at once: `health` has one from the start.
                "status": time,
                "bias": time + self.timings.bias_s,
            }
        self._now = max(self._now, time)

    def _periodic(self) -> None:
        # Each in its own guard: a failure of one (a bias estimate that does not convert,
        # a status that does not validate) is logged and counted, and neither stops the
        # others nor reaches the caller (it ended the replay, seen).
        if self._due("cat062", self.timings.cat062_s):
            self._guarded("cat062", self.outputs.publish_cat062)
        if self._due("bias", self.timings.bias_s):
            self._guarded(
                "bias",
                lambda: self.outputs.publish_bias(
                    self.chain.bias_estimates(), self.chain.bias_observed_from()
                ),
            )
        if self._due("status", self.timings.status_s):
            self._guarded("status", self._publish_status)

    def _publish_status(self) -> None:
        self._send_state()
        self.outputs.publish_status()

    def _send_state(self) -> None:
        """What a status needs of this side, current (see ``set_input_counters``)."""
        if self._input_counters is not None:
            self.outputs.set_input_counters(self._input_counters)
        self.outputs.set_core_state(self.core_state())

    def core_state(self) -> CoreState:
        """What the status needs of the core; the daemon adds the lag, the memory and the
        loops (``note_live``: their busy shares since the last call here) and the
        restarts."""
        busy = tuple(sorted(self._loop_shares.shares(self._loops).items()))
        return replace(
            self.core,
            sources=self.chain.admission.counts,
            reasons=self.core_reasons(),
            busy=busy,
        )

    def note_live(
        self,
        lag_s: float | None,
        others_mb: Mapping[str, float] | None = None,
        loops: Mapping[str, LoopTotals] | None = None,
    ) -> None:
        """What only a live service's status tells (a replay's is a function of its
        recording): its lag behind the wall clock, the memory of this process, of its
        output process and of the processes that feed it (``others_mb``, by role), and
        the totals of their loops (``loops``, by the same roles)."""
        if loops is not None:
            self._loops = dict(loops)
        memory = {"core": resident_mb()}
        if self.outputs.pid is not None:
            memory["outputs"] = resident_mb(self.outputs.pid)
        memory.update(others_mb or {})
        known = tuple((role, mb) for role, mb in memory.items() if mb is not None)
        self.core = replace(self.core, lag_s=lag_s, memory_mb=known)

    def core_reasons(self) -> tuple[str, ...]:
        """Why health is degraded, as the checks that run with the chain see it (the
        fuser's system track numbers running short), one line each naming what it
        concerns ("fusion: ..."); the status shows them beside its own and is "degraded"
        while there is any."""
        fuser = self.chain.fuser
        if fuser is None:
            return ()
        return tuple(number_shortage_reasons(fuser.stats, fuser.config, self._now))

    def _guarded(self, what: str, call: Callable[[], None]) -> None:
        try:
            call()
        except Exception:
            self.periodic_failures += 1
            self._warn.exception(what, "the periodic %s output failed", what)

    def _due(self, what: str, period: float) -> bool:
        due = self._next[what]
        if self._now < due:
            return False
        # The next one on the grid after now: a long silence does not make a burst.
        self._next[what] = due + period * (math.floor((self._now - due) / period) + 1)
        return True

    def close(self) -> None:
        """Ends every live track (an "ended" message each, and its key deleted), sends the
        last CAT062 batch and a status. The caller closes the publisher and the log."""
        if self._closed:
            return
        self._closed = True
        self._send_state()
        self.outputs.close()
