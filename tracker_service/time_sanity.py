"""Per-radar time sanity: each plot's time against its own radar's timeline.

The plot clock (``ingest.PlotClock``) gives every plot a POSIX time from its I140 on the
day nearest its reception, or from its azimuth, or the reception time itself. Nothing
there says whether that time is plausible. ``TimeSanity`` keeps, per radar, the evidence
of its stream: the offset of its data time from the reception time (data - reception,
the median over the last ``evidence`` datagrams and north markers, so that no single
stamp moves it), its last north marker and the usual phase of its plots' times against
the azimuth the antenna had then. Each plot of a datagram is judged against them:

- its time must lie within ``latency_s`` + ``plausible_periods`` antenna periods of the
  time the radar's data is expected at (reception + offset);
- where a recent north marker is known, the time must agree with the plot's azimuth
  (THETA) within ``azimuth_tolerance`` of a turn, beside the radar's usual phase;
- a time of day is put on the day nearest the radar's expected time, not the reception's:
  midnight in both directions (ToD already wrapped or still above 86,400 s) lands on the
  radar's own timeline even when that is hours from the reception;
- a plot timed by the reception (no I140, no north marker yet) gets reception + offset,
  and one timed from its azimuth is moved by whole turns onto the radar's timeline.

A plot that fails is not tracked (``PlotUse.TIME_IMPLAUSIBLE``, counted in status) and is
logged, rate-limited. A feed whose offset exceeds ``max_offset_s`` (a replayed capture
sent live, a radar with a wrong clock) is reported (``TimeReport``, ``status_reasons``):
tracked on its own time, or, with ``time_base = "reception"``, re-based on reception
(times shifted by the offset, re-estimated only when it moves by more than the
tolerance). A radar whose time is out of step with the other radars' is kept out of
fusion by the chain: its tracks cannot be fused with theirs.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
import numpy.typing as npt

from tracker_service.ingest import DAY_S, TimeSource, posix_from_time_of_day
from tracker_service.small_arrays import median
from tracker_service.tracking import LocalTracker

__all__ = [
    "TIME_BASES",
    "TimeBase",
    "TimeReport",
    "TimeSanity",
    "TimeSanityConfig",
    "implausible_reasons",
    "status_reasons",
]

log = logging.getLogger(__name__)

TimeBase = Literal["data", "reception"]
TIME_BASES: tuple[TimeBase, ...] = ("data", "reception")
FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]


@dataclass(frozen=True)
class TimeSanityConfig:
    """The knobs of ``TimeSanity``; seconds unless the name says otherwise."""

    evidence: int = 16
    """Datagrams and north markers of a radar whose offset from reception is kept: the
    feed offset is their median, so it follows a jump once half of them show it."""
    min_evidence: int = 4
    """Pieces of evidence before a feed's offset is reported or compared across radars."""
    latency_s: float = 4.0
    """Reception lags measurement by the sector's buffering and the network."""
    plausible_periods: float = 1.0
    """A plot further than ``latency_s`` + this many antenna periods from the time its
    radar's data is expected at is implausible."""
    azimuth_tolerance: float = 0.125
    """Turns (0.125: 45 degrees) a plot's time may stray from the phase its azimuth and
    the last north marker give, beside the radar's usual phase."""
    max_offset_s: float = 10.0
    """A feed whose data time is further than this from its reception is reported (and
    one this far from the other radars' is kept out of fusion)."""
    log_interval_s: float = 60.0
    """Implausible plots are logged at most once per this much reception time per radar,
    with the count of those not logged."""

    def __post_init__(self) -> None:
        if not 1 <= self.min_evidence <= self.evidence:
            raise ValueError("need 1 <= min_evidence <= evidence")
        for name in ("latency_s", "plausible_periods", "max_offset_s", "log_interval_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)!r}")
        if not 0 < self.azimuth_tolerance < 0.5:
            raise ValueError(f"azimuth_tolerance must be in (0, 0.5), not {self.azimuth_tolerance}")


@dataclass(frozen=True)
class TimeReport:
    """A radar's time as status shows it: plain data, so that it crosses to the output
    process as it is."""

    source: str
    time_base: TimeBase
    offset_s: float | None
    """Its data time minus its reception time (median of the evidence); None before
    ``min_evidence`` pieces of it."""
    offset_reported: bool
    """``offset_s`` beyond ``max_offset_s``."""
    out_of_step_s: float | None
    """Its offset from the other radars' when beyond ``max_offset_s`` (kept out of
    fusion), else None."""
    implausible: int
    """Plots kept out of tracking as implausible, since start."""
    clock_resyncs: int = 0
    """Times its local tracker's clock followed a jump of its time (not an outage)."""
    last_clock_jump_s: float = 0.0
    last_clock_jump_at: float = -math.inf
    """The tracker's clock just after that jump."""
    out_of_line_plots: int = 0
    """Plots its local tracker's clock refused (too far ahead of it or behind), since start."""


CONSENSUS_INTERVAL_S = 1.0
RECENT_JUMP_S = 300.0
"""A jump its tracker's clock followed stays a reason in status this long (data time)."""


def status_reasons(report: TimeReport, data_time: float | None) -> list[str]:
    """The lines status gives for a radar's time (``data_time``: its latest plot's);
    empty when it is sane. A feed re-based on reception as configured is no fault."""
    reasons = []
    source = report.source
    if report.offset_reported and report.offset_s is not None and report.time_base == "data":
        offset = report.offset_s
        way = "ahead of" if offset > 0 else "behind"
        reasons.append(
            f"radar {source}: data time {abs(offset):.1f} s {way} its reception (a "
            'replayed capture or a wrong clock); time_base = "reception" in its '
            "[[radars]] table re-bases it"
        )
    if report.out_of_step_s is not None:
        way = "ahead of" if report.out_of_step_s > 0 else "behind"
        reasons.append(
            f"radar {source}: time {abs(report.out_of_step_s):.1f} s {way} the other "
            "radars': kept out of fusion"
        )
    recent = data_time is not None and data_time - report.last_clock_jump_at <= RECENT_JUMP_S
    if report.clock_resyncs and recent:
        reasons.append(
            f"radar {source}: its time jumped by {report.last_clock_jump_s:+.1f} s and its "
            f"tracker followed ({report.clock_resyncs} time(s) since start)"
        )
    return reasons


IMPLAUSIBLE_SHARE = 0.05
"""A radar more of whose plots than this had implausible times since the last status is a
reason for "degraded": a stray corrupt stamp is counted, a stream of them is a fault."""


IMPLAUSIBLE_MIN = 3


def implausible_reasons(source: str, implausible: int, plots: int) -> list[str]:
    """The line status gives for a radar ``implausible`` of whose ``plots`` since the
    last status had implausible times, when they are more than ``IMPLAUSIBLE_SHARE`` of
    them and at least ``IMPLAUSIBLE_MIN``."""
    if implausible < IMPLAUSIBLE_MIN or implausible <= IMPLAUSIBLE_SHARE * plots:
        return []
    return [
        f"radar {source}: {implausible} of its {plots} plots since the last status had "
        "implausible times (kept out of tracking)"
    ]


@dataclass
class _Timeline:
    """What is known of one radar's time."""

    source: str
    time_base: TimeBase
    period_s: float
    offsets: deque[float]
    north_posix: float = math.nan
    phases: deque[float] = field(default_factory=lambda: deque(maxlen=32))
    """Recent per-datagram median phase of plot times against their azimuth (turns)."""
    rebase_s: float | None = None
    implausible: int = 0
    reported_offset: float | None = None
    logged_at: float = -math.inf
    unlogged: int = 0
    tracker_resyncs: int = 0
    """Re-synchronisations of its tracker's clock already seen."""
    clock_jumps: int = 0
    """Those that followed a jump of the radar's clock (not data again after an outage)."""
    last_jump: tuple[float, float] = (0.0, -math.inf)
    """(jump, the tracker's clock after it) of the latest."""
    settled_offset: float | None = None
    """Its offset from reception at its tracker's latest re-synchronisation (or start)."""

    def offset(self) -> float | None:
        return _median(self.offsets) if self.offsets else None


class TimeSanity:
    """See the module docstring. ``bases``: each radar's ``TimeBase`` (default "data");
    ``periods``: each radar's configured antenna period (north markers update it)."""

    def __init__(
        self,
        config: TimeSanityConfig | None = None,
        bases: Mapping[str, TimeBase] | None = None,
        periods: Mapping[str, float] | None = None,
        compiled: bool = True,
    ) -> None:
        self.config = config or TimeSanityConfig()
        self.compiled = compiled
        """``check`` by ``time_sanity_kernels.judge_times`` (the same values), not numpy."""
        self._bases = dict(bases or {})
        self._periods = dict(periods or {})
        self._timelines: dict[str, _Timeline] = {}
        self._latest = -math.inf
        self._consensus_at = -math.inf
        self._consensus_value: float | None = None

    def _timeline(self, source: str) -> _Timeline:
        timeline = self._timelines.get(source)
        if timeline is None:
            timeline = self._timelines[source] = _Timeline(
                source,
                self._bases.get(source, "data"),
                self._periods.get(source, 5.0),
                deque(maxlen=self.config.evidence),
            )
        return timeline

    def service_message(self, items: dict[str, Any], received: float) -> None:
        """A CAT034 record: a north marker is evidence of the radar's time and its phase."""
        source, kind, tod = items.get("010"), items.get("000"), items.get("030")
        if kind != 1 or not isinstance(source, dict) or not isinstance(tod, float):
            return
        timeline = self._timeline(f"{source['SAC']}/{source['SIC']}")
        period = items.get("041")
        if isinstance(period, float) and period > 0.0:
            timeline.period_s = period
        prior = timeline.offset()
        north = float(posix_from_time_of_day(np.array([tod]), received + (prior or 0.0))[0])
        timeline.north_posix = north
        timeline.offsets.append(north - received)

    def check(
        self,
        source: str,
        times: FloatArray,
        time_sources: npt.NDArray[np.int8],
        theta_deg: FloatArray,
        received: float,
    ) -> tuple[FloatArray, BoolArray]:
        """One datagram's plots of one radar: their times put on the radar's timeline (and
        re-based, if so configured), and which are implausible."""
        if self.compiled:
            return self._check_compiled(source, times, time_sources, theta_deg, received)
        cfg = self.config
        self._latest = received
        timeline = self._timeline(source)
        period = timeline.period_s
        times = np.array(times, dtype=np.float64)
        # Plain values: numpy compares with an IntEnum member through a slow path.
        stamped = time_sources == TimeSource.I140.value
        prior = timeline.offset()
        if prior is not None and stamped.any():
            times[stamped] = _nearest(times[stamped], received + prior, DAY_S)
        plot_offsets = (times[stamped] - received).tolist()
        history = list(timeline.offsets)
        if plot_offsets and len(history) >= 2:
            # This datagram is one piece of evidence beside the others, however many
            # plots it holds: a jump is followed only once half the evidence shows it.
            offset = _median([*history, _median(plot_offsets)])
        elif plot_offsets:
            # Thin evidence (the start): the plots themselves, the middle one nearest
            # reception when they split evenly.
            offset = _median([*history, *plot_offsets], toward=0.0)
        else:
            offset = prior if prior is not None else 0.0
        expected = received + offset
        if prior is None and plot_offsets:
            times[stamped] = _nearest(times[stamped], expected, DAY_S)
        by_reception = time_sources == TimeSource.RECEPTION.value
        times[by_reception] = expected
        by_azimuth = time_sources == TimeSource.AZIMUTH.value
        if by_azimuth.any() and abs(offset) > cfg.max_offset_s:
            # The plot clock counted the turns up to the reception; the radar's own time
            # is elsewhere by whole turns.
            times[by_azimuth] = _nearest(times[by_azimuth], expected, period)
        implausible = np.abs(times - expected) > self._tolerance_s(timeline)
        implausible |= self._off_azimuth(timeline, times, stamped & ~implausible, theta_deg)
        if plot_offsets:
            plausible = stamped & ~implausible
            evidence = plausible if plausible.any() else stamped
            timeline.offsets.append(_median((times[evidence] - received).tolist()))
        self._note(timeline, times, theta_deg, implausible, expected, received)
        if timeline.time_base == "reception":
            times -= self._rebase(timeline, offset)
        return times, implausible

    def _check_compiled(
        self,
        source: str,
        times: FloatArray,
        time_sources: npt.NDArray[np.int8],
        theta_deg: FloatArray,
        received: float,
    ) -> tuple[FloatArray, BoolArray]:
        """``check`` with its arithmetic in one compiled pass (``time_sanity_kernels``)."""
        from tracker_service.time_sanity_kernels import judge_times

        cfg = self.config
        self._latest = received
        timeline = self._timeline(source)
        phases = timeline.phases
        assert phases.maxlen is not None
        checked, implausible, offset, new_offset, new_phase = judge_times(
            np.ascontiguousarray(times, np.float64),
            np.ascontiguousarray(time_sources, np.int8),
            np.ascontiguousarray(theta_deg, np.float64),
            float(received),
            np.array(timeline.offsets, np.float64),
            np.array(phases, np.float64),
            min(len(phases), phases.maxlen - 1),
            float(timeline.period_s),
            float(timeline.north_posix),
            float(cfg.latency_s),
            float(cfg.plausible_periods),
            float(cfg.max_offset_s),
            float(cfg.azimuth_tolerance),
        )
        if not math.isnan(new_phase):
            phases.append(new_phase)
        if not math.isnan(new_offset):
            timeline.offsets.append(new_offset)
        self._note(timeline, checked, theta_deg, implausible, received + offset, received)
        if timeline.time_base == "reception":
            checked -= self._rebase(timeline, offset)
        return checked, implausible

    def _off_azimuth(
        self, timeline: _Timeline, times: FloatArray, judged: BoolArray, theta_deg: FloatArray
    ) -> BoolArray:
        """Plots whose time disagrees with the antenna position their THETA implies."""
        off = np.zeros(times.size, dtype=bool)
        period = timeline.period_s
        recent = judged & (np.abs(times - timeline.north_posix) <= 2.0 * period)
        recent &= np.isfinite(theta_deg)
        if not recent.any():
            return off
        phase = _azimuth_phase(timeline, times[recent], theta_deg[recent])
        # The radar's usual phase (its stamping convention), from the datagrams' medians:
        # a lone stray plot is no datagram's median.
        timeline.phases.append(median(phase))
        usual = median(timeline.phases)
        stray = np.abs(_wrap(phase - usual)) > self.config.azimuth_tolerance
        off[np.flatnonzero(recent)[stray]] = True
        return off

    def _rebase(self, timeline: _Timeline, offset: float) -> float:
        """The shift taken off a re-based radar's times: the offset, held steady (the
        jitter of reception must not jitter the plots) until it moves by more than the
        plausible tolerance."""
        tolerance = self._tolerance_s(timeline)
        if timeline.rebase_s is None or abs(offset - timeline.rebase_s) > tolerance:
            timeline.rebase_s = offset
            log.info(
                "radar %s: time re-based on reception, its data time %+.3f s from it",
                timeline.source,
                offset,
            )
        return timeline.rebase_s

    def _note(
        self,
        timeline: _Timeline,
        times: FloatArray,
        theta_deg: FloatArray,
        implausible: BoolArray,
        expected: float,
        received: float,
    ) -> None:
        """Count and log (rate-limited) the implausible plots; warn when the feed's
        offset from reception becomes large, or changes."""
        cfg = self.config
        count = int(np.count_nonzero(implausible))
        if count:
            timeline.implausible += count
            timeline.unlogged += count
            if received - timeline.logged_at >= cfg.log_interval_s:
                log.warning(
                    "radar %s: %d plot(s) with an implausible time kept out of tracking (%s)",
                    timeline.source,
                    timeline.unlogged,
                    self._example(timeline, times[implausible], theta_deg[implausible], expected),
                )
                timeline.logged_at = received
                timeline.unlogged = 0
        offset = self._reportable(timeline)
        reported = timeline.reported_offset
        tolerance = self._tolerance_s(timeline)
        if offset is not None and (reported is None or abs(offset - reported) > tolerance):
            timeline.reported_offset = offset
            way = "ahead of" if offset > 0 else "behind"
            action = (
                "re-based on reception"
                if timeline.time_base == "reception"
                else 'tracked on its own time; time_base = "reception" re-bases it'
            )
            log.warning(
                "radar %s: data time %.1f s %s its reception (a replayed capture or a "
                "wrong clock?): %s",
                timeline.source,
                abs(offset),
                way,
                action,
            )
        elif offset is None and reported is not None:
            log.warning("radar %s: data time back in step with its reception", timeline.source)
            timeline.reported_offset = None

    def _tolerance_s(self, timeline: _Timeline) -> float:
        """How far from the radar's expected time a plot's time may lie."""
        return self.config.latency_s + self.config.plausible_periods * timeline.period_s

    def _example(
        self, timeline: _Timeline, times: FloatArray, theta_deg: FloatArray, expected: float
    ) -> str:
        """The worst of a datagram's implausible plots (their ``times`` and THETA), in
        words: a time far from the radar's, or else an azimuth the antenna did not point
        at then (a reflection timed as its true plot, a wrong THETA or time)."""
        error = times - expected
        worst = int(np.argmax(np.abs(error)))
        if abs(error[worst]) > self._tolerance_s(timeline):
            return f"e.g. {error[worst]:+.1f} s from the radar's expected time"
        phases = timeline.phases
        usual = median(phases) if phases else 0.0
        off = _wrap(_azimuth_phase(timeline, times, theta_deg) - usual)
        k = int(np.nanargmax(np.abs(off))) if np.isfinite(off).any() else 0
        return (
            f"e.g. THETA {theta_deg[k]:.1f} deg where the antenna pointed "
            f"{360.0 * off[k]:+.0f} deg from it at the plot's time"
        )

    def _reportable(self, timeline: _Timeline) -> float | None:
        """The feed's offset when it has enough evidence and exceeds ``max_offset_s``."""
        if len(timeline.offsets) < self.config.min_evidence:
            return None
        offset = timeline.offset()
        return offset if offset is not None and abs(offset) > self.config.max_offset_s else None

    def _effective(self, timeline: _Timeline) -> float | None:
        """A radar's offset from reception with enough evidence, after re-basing."""
        offset = timeline.offset()
        if offset is None or len(timeline.offsets) < self.config.min_evidence:
            return None
        if timeline.time_base == "reception" and timeline.rebase_s is not None:
            offset -= timeline.rebase_s
        return offset

    def _consensus(self) -> float | None:
        """The offset of the largest group of radars whose offsets agree (the one nearest
        reception on a tie); None with fewer than two radars known. Recomputed once per
        ``CONSENSUS_INTERVAL_S`` of reception time: it moves as slowly as its medians."""
        if abs(self._latest - self._consensus_at) < CONSENSUS_INTERVAL_S:
            return self._consensus_value
        self._consensus_at = self._latest
        values = [v for t in self._timelines.values() if (v := self._effective(t)) is not None]
        self._consensus_value = consensus_of(values, self.config.max_offset_s)
        return self._consensus_value

    def effective_offset(self, source: str) -> float | None:
        """The radar's offset from reception with enough evidence, after re-basing (what
        the central stage's ``TimeConsensus`` compares)."""
        return self._effective(self._timeline(source))

    def out_of_step(self, source: str) -> float | None:
        """How far a radar's time is from the other radars' (``_consensus``), when beyond
        ``max_offset_s``; None when in step or unknown."""
        own = self._effective(self._timeline(source))
        consensus = self._consensus()
        if own is None or consensus is None:
            return None
        step = own - consensus
        return step if abs(step) > self.config.max_offset_s else None

    def report(self, source: str, tracker: LocalTracker | None = None) -> TimeReport:
        """The radar's time for status, with what its local ``tracker``'s clock did."""
        timeline = self._timeline(source)
        enough = len(timeline.offsets) >= self.config.min_evidence
        offset = timeline.offset() if enough else None
        if tracker is not None:
            self._follow(timeline, tracker, offset)
        jump, at = timeline.last_jump
        return TimeReport(
            source=source,
            time_base=timeline.time_base,
            offset_s=offset,
            offset_reported=self._reportable(timeline) is not None,
            out_of_step_s=self.out_of_step(source),
            implausible=timeline.implausible,
            clock_resyncs=timeline.clock_jumps,
            last_clock_jump_s=jump,
            last_clock_jump_at=at,
            out_of_line_plots=0 if tracker is None else tracker.stats.out_of_line_plots,
        )

    def _follow(self, timeline: _Timeline, tracker: LocalTracker, offset: float | None) -> None:
        """When the tracker's clock has just followed a jump, the radar's offset from
        reception says what it was: data again after an outage (the offset has not
        moved), or the radar's clock (a warning, and a reason in status)."""
        stats = tracker.stats
        if timeline.settled_offset is None:
            timeline.settled_offset = offset
        if stats.clock_resyncs <= timeline.tracker_resyncs:
            return
        timeline.tracker_resyncs = stats.clock_resyncs
        jump = stats.last_clock_jump_s
        settled, timeline.settled_offset = timeline.settled_offset, offset
        tolerance = max(2.0 * tracker.config.scan_period_s, self.config.max_offset_s)
        if offset is not None and settled is not None and abs(offset - settled) <= tolerance:
            log.info("radar %s: data again, %+.1f s on", timeline.source, jump)
            return
        timeline.clock_jumps += 1
        timeline.last_jump = (jump, tracker.clock.now)
        log.warning(
            "radar %s: its time jumped by %+.1f s for good: its tracker follows",
            timeline.source,
            jump,
        )


def consensus_of(values: Sequence[float], limit: float) -> float | None:
    """The offset of the largest group of ``values`` that agree within ``limit`` (the one
    nearest reception on a tie); None with fewer than two."""
    if len(values) < 2:
        return None
    return max(values, key=lambda v: (sum(abs(v - w) <= limit for w in values), -abs(v)))


class TimeConsensus:
    """The radars' time against each other where their radar stages are apart: each
    batch brings its radar's effective offset (``TimeSanity.effective_offset``); a radar
    out of step with the consensus (as ``TimeSanity.out_of_step`` judges it in one
    stage) is kept out of fusion. Recomputed once per ``CONSENSUS_INTERVAL_S`` of
    reception time, in the order the central stage takes the batches."""

    def __init__(self, config: TimeSanityConfig | None = None) -> None:
        self.config = config or TimeSanityConfig()
        self._offsets: dict[str, float] = {}
        self._at = -math.inf
        self._value: float | None = None

    def out_of_step(self, source: str, offset: float | None, received: float) -> float | None:
        """Notes ``source``'s ``offset`` at ``received``; its step from the consensus when
        beyond ``max_offset_s``, else None."""
        if offset is None:
            self._offsets.pop(source, None)
        else:
            self._offsets[source] = offset
        if abs(received - self._at) >= CONSENSUS_INTERVAL_S:
            self._at = received
            self._value = consensus_of(list(self._offsets.values()), self.config.max_offset_s)
        if offset is None or self._value is None:
            return None
        step = offset - self._value
        return step if abs(step) > self.config.max_offset_s else None


def _median(values: Sequence[float], toward: float | None = None) -> float:
    """The middle one of the values: always a value that was seen, never the mean of two
    times that disagree. Of two middle ones, the upper, or the one nearer ``toward``."""
    ordered = sorted(values)
    upper = ordered[len(ordered) // 2]
    if toward is None or len(ordered) % 2:
        return float(upper)
    lower = ordered[len(ordered) // 2 - 1]
    return float(lower if abs(lower - toward) < abs(upper - toward) else upper)


def _nearest(times: FloatArray, reference: float, step: float) -> FloatArray:
    """Each time moved by whole ``step`` (days, turns) to lie nearest ``reference``."""
    return np.asarray(times + step * np.round((reference - times) / step))


def _azimuth_phase(timeline: _Timeline, times: FloatArray, theta_deg: FloatArray) -> FloatArray:
    """Each plot's time against its azimuth: the turns from the radar's last north marker
    less THETA's, within half a turn (the radar's usual phase where all is well)."""
    return _wrap((times - timeline.north_posix) / timeline.period_s - theta_deg / 360.0)


def _wrap(turns: FloatArray) -> FloatArray:
    return np.asarray(turns - np.round(turns))
