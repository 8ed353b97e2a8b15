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
from collections import Counter, defaultdict
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from asterix.containers import Datagram
from tracker_service.bias import BiasConfig, ObservedFrom
from tracker_service.chain import (
    BatchOutput,
    Chain,
    FieldMonitor,
    PlotUse,
    RadarInfo,
    rejections,
    source_order,
)
from tracker_service.fixed_targets import FixedTransponder
from tracker_service.fusion import FusionConfig
from tracker_service.geodesy import RadarSite, SystemPlane
from tracker_service.inputs.udp import InputCounters, block_chain_error
from tracker_service.outputs.cat062 import encode_cat065, encode_system_tracks
from tracker_service.outputs.mapping import MessageMapper
from tracker_service.outputs.mcap_log import McapLog
from tracker_service.outputs.mcap_sink import CAT062_TOPIC, SYSTEM_TRACKS_TOPIC, McapSink
from tracker_service.outputs.messages import RadarStatus, StatusMessage, SystemTrackMessage
from tracker_service.outputs.sink import Backoff, IsolatedSink, OutputState, QueuedSink, Sink
from tracker_service.outputs.zenoh_out import ZenohPublisher
from tracker_service.outputs.zenoh_sink import ZenohSink
from tracker_service.service.config import ServiceConfig, parse_service_config
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
    "SYSTEM_TRACKS_TOPIC",
    "OutputSink",
    "Outputs",
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
"""A radar whose last plot is this many antenna periods old makes the health "degraded"."""


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


def build_chain(
    config: ServiceConfig,
    make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
) -> Chain:
    """The chain of a configuration: its radars, plane, tracker, fusion and bias settings;
    ``make_tracker`` as for ``Chain`` (assess passes one that keeps the plots it tracks)."""
    infos = {radar.key: _radar_info(radar) for radar in config.radars}
    plane = SystemPlane(
        config.system.centre_lat, config.system.centre_lon, config.system.projection
    )
    fusion = FusionConfig(**dataclass_kwargs("fusion", config.fusion, FusionConfig))
    tracker = dataclass_kwargs("tracker", config.tracker, TrackerConfig)
    time_sanity = TimeSanityConfig(
        **dataclass_kwargs("time_sanity", config.time_sanity, TimeSanityConfig)
    )
    return Chain(
        infos,
        plane,
        tracker,
        make_tracker,
        fusion=fusion,
        bias=bias_config(config),
        time_sanity=time_sanity,
        fixed_targets=config.fixed_target_config(),
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
    doc = {
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
    plots: int = 0
    plots_at_last_status: int = 0
    implausible_at_last_status: int = 0
    decode_errors: int = 0
    rejected: Counter[str] = field(default_factory=Counter)
    time: TimeReport | None = None
    test_targets: SeenTestTargets = field(default_factory=SeenTestTargets)


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
        if log_file is not None:
            adapters.append(McapSink(log_file))
        self.sinks = [QueuedSink(IsolatedSink(sink, backoff)) for sink in adapters]
        self.timings = timings or ServiceTimings()
        self.counts = ServiceCounts()
        self.input_counters: dict[str, InputCounters] = {}
        """Per input name, what the input stage counted (duplicates, drops, malformed);
        the daemon and the replay keep it current."""
        self._periods = {radar.key: radar.antenna_period_s for radar in config.radars}
        self._feeds = [r.key for r in config.radars] + [a.key for a in config.adsb]
        self._radars: dict[str, _RadarCounters] = defaultdict(_RadarCounters)
        self._pending_cat062: dict[int, SystemTrackMessage] = {}
        self._cat062_batches = 0
        self._start: float | None = None
        self._now = -math.inf

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

    def received(self, name: str, datagram: Datagram) -> None:
        """A datagram reaches the core: data time moves to its reception, and it is logged."""
        assert datagram.time is not None
        self.advance(datagram.time)
        self.counts.datagrams += 1
        for sink in self.sinks:
            sink.datagram(name, datagram)

    def error(self, name: str, what: str) -> None:
        self.counts.errors += 1
        self._radars[radar_key(name)].decode_errors += 1
        log.warning("%s: datagram at %.3f dropped: %s", name, self._now, what)

    # --- per batch ---------------------------------------------------------------------

    def batch(self, output: BatchOutput, sources: Sequence[str]) -> None:
        """What the chain made of one radar's part of a datagram; ``sources`` names the
        chain's radars by index (``Chain.sources``)."""
        plots = output.plots
        counters = self._radars[output.source]
        self.counts.plots += len(plots)
        counters.plots += len(plots)
        if len(plots):
            # A plot whose time is implausible says nothing of when the radar was heard.
            timed = plots["time"][plots["use"] != PlotUse.TIME_IMPLAUSIBLE]
            if len(timed):
                counters.last_plot_time = float(timed.max())
            counters.rejected.update(rejections(plots["use"]))
            counters.test_targets.update(plots)
        if output.time is not None:
            counters.time = output.time
            if output.time.out_of_line_plots:
                # A running count already: the tracker's, not this batch's.
                counters.rejected["out_of_line"] = output.time.out_of_line_plots
        self.mapper.note_callsigns(plots)
        for local in self.mapper.local(output.source, output.local):
            payload = local.model_dump_json().encode()
            for sink in self.sinks:
                sink.local(local, payload, self._now)
        if len(output.system):
            for message in self.mapper.system(output.system, plots, sources):
                self._emit_system(message)

    def _emit_system(self, message: SystemTrackMessage) -> None:
        self.counts.system_updates += 1
        self.counts.system_tracks.add(message.number)
        self._pending_cat062[message.number] = message
        payload = message.model_dump_json().encode()
        for sink in self.sinks:
            sink.system(message, payload, self._now)

    # --- periodic outputs (the core says when) -----------------------------------------

    def publish_cat062(self) -> None:
        messages = [self._pending_cat062[n] for n in sorted(self._pending_cat062)]
        self._pending_cat062.clear()
        system = self.config.system
        data = encode_system_tracks(messages, system) + encode_cat065(
            "end_of_batch", self._now, self._cat062_batches, system
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

    def status(self) -> StatusMessage:
        """The current status: per feed, last plot time, plot rate since the last published status,
        errors, duplicates and drops; health "degraded" when a radar has gone silent."""
        start = self._now if self._start is None else self._start
        interval = self.timings.status_s
        radars = []
        degraded = False
        reasons: list[str] = []
        for key in sorted({*self._feeds, *self._radars}, key=source_order):
            counters = self._radars[key]
            inputs = self.input_counters.get(input_name(key), InputCounters())
            rate = (counters.plots - counters.plots_at_last_status) / interval
            period = self._periods.get(key)
            # The radar's own time, not the reception's: a feed's offset from it (reported
            # below) is no silence.
            offset = 0.0
            if counters.time is not None and counters.time.time_base == "data":
                offset = counters.time.offset_s or 0.0
            if period is not None and counters.last_plot_time is not None:
                degraded |= self._now + offset - counters.last_plot_time > SILENT_PERIODS * period
            if counters.time is not None:
                reasons += status_reasons(counters.time, counters.last_plot_time)
                reasons += implausible_reasons(
                    key,
                    counters.rejected["time_implausible"] - counters.implausible_at_last_status,
                    counters.plots - counters.plots_at_last_status,
                )
            radars.append(
                RadarStatus(
                    radar=key,
                    last_plot_time=counters.last_plot_time,
                    plots_per_second=max(rate, 0.0),
                    decode_errors=counters.decode_errors + inputs.malformed,
                    duplicates=inputs.duplicates,
                    drops=inputs.dropped,
                    rejected=dict(sorted(counters.rejected.items())),
                    time_offset_s=None if counters.time is None else counters.time.offset_s,
                    test_targets=counters.test_targets.checks(),
                )
            )
        reasons = self.output_reasons()
        return StatusMessage(
            time=self._now,
            uptime_s=max(self._now - start, 0.0),
            health="degraded" if degraded or reasons else "ok",
            reasons=reasons,
            radars=radars,
        )

    def publish_status(self) -> None:
        message = self.status()
        for counters in self._radars.values():
            counters.plots_at_last_status = counters.plots
            counters.implausible_at_last_status = counters.rejected["time_implausible"]
        for sink in self.sinks:
            sink.status(message, self._now)

    def close(self) -> None:
        """Ends every live track (an "ended" message each, and its key deleted), sends the
        last CAT062 batch and a status, then ``stop``."""
        try:
            if self._start is None:
                return
            for ended in self.mapper.end_all():
                self._emit_system(ended)
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


class OutputSink(Protocol):
    """What the core calls on its outputs: ``Outputs`` itself, or a proxy that sends each
    call to ``Outputs`` in another process (``command.OutputProcess``)."""

    def advance(self, time: float) -> None: ...
    def set_input_counters(self, counters: dict[str, InputCounters]) -> None: ...
    def received(self, name: str, datagram: Datagram) -> None: ...
    def error(self, name: str, what: str) -> None: ...
    def batch(self, output: BatchOutput, sources: Sequence[str]) -> None: ...
    def publish_cat062(self) -> None: ...
    def publish_bias(
        self,
        estimates: dict[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]],
        observed_from: dict[str, ObservedFrom],
    ) -> None: ...
    def publish_status(self) -> None: ...
    def close(self) -> None: ...


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
    ) -> None:
        self.config = config
        self.chain = build_chain(config)
        self.plane = self.chain.plane
        self.timings = timings or ServiceTimings()
        self.outputs = outputs or Outputs(config, publisher, log_file, self.timings)
        self._start: float | None = None
        self._now = -math.inf
        self._next: dict[str, float] = {}
        self._closed = False

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
        """Per input name, what the input stage counted (duplicates, drops, malformed)."""
        self.outputs.set_input_counters(counters)

    @property
    def now(self) -> float:
        """Data time: the latest reception time seen."""
        return self._now

    def process(self, name: str, datagram: Datagram) -> None:
        """One datagram that input ``name`` received at ``datagram.time``. Nothing raises
        out of here for bad data: an error is logged and counted, and the service goes on."""
        if datagram.time is None:
            raise ValueError("the service needs each datagram's reception time")
        received = datagram.time
        self._advance_to(received)
        self.outputs.received(name, datagram)
        reason = block_chain_error(datagram.payload)
        if reason is not None:
            self.outputs.error(name, f"not ASTERIX ({reason})")
            return
        try:
            outputs = self.chain.feed(datagram.payload, received)
            for output in outputs:
                self.outputs.batch(output, self.chain.sources)
        except Exception:
            log.exception("%s: datagram at %.3f could not be processed", name, received)
            self.outputs.error(name, "processing failed")
        self._periodic()

    def advance(self, now: float) -> None:
        """Data time moves on without data (the daemon, while every feed is quiet): the
        periodic outputs that fall due go out."""
        if self._start is None:
            return
        self._advance_to(now)
        self.outputs.advance(now)
        self._periodic()

    def _advance_to(self, time: float) -> None:
        if self._start is None:
            self._start = time
            self._next = {
                "cat062": time + self.timings.cat062_s,
                "status": time + self.timings.status_s,
                "bias": time + self.timings.bias_s,
            }
        self._now = max(self._now, time)

    def _periodic(self) -> None:
        if self._due("cat062", self.timings.cat062_s):
            self.outputs.publish_cat062()
        if self._due("bias", self.timings.bias_s):
            self.outputs.publish_bias(self.chain.bias_estimates(), self.chain.bias_observed_from())
        if self._due("status", self.timings.status_s):
            self.outputs.publish_status()

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
        self.outputs.close()
