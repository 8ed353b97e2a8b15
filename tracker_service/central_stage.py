"""The central stage: bias estimation, fusion, and the bias correction of the radars' data.

It takes the radar stages' ``stage_messages.RadarBatch`` one at a time, in the order of
their input (the one-process chain: as they come; over Zenoh: merged by reception time,
``distribution``), and for each:

- numbers its plots for the system (a radar stage numbers its radar's own) and, after a
  radar stage restarted, its local tracks anew, so that a new stage's track 1 is not
  taken for the old one's;
- judges the radar's time against the other radars' (``time_sanity.TimeConsensus``): a
  radar out of step is kept out of fusion;
- corrects its plots and local updates with the radar's current bias estimate, to first
  order through the Jacobian the radar stage sent (x - C s, time - s_t): the same as
  converting corrected range and azimuth within a metre or two for biases of 150 m and
  0.15 degrees (the second order, rho dtheta^2 / 2, is 0.7 m at 200 km), against plot
  errors of tens of metres;
- feeds the bias estimator the batch's observations (other radars' fused tracks, field
  monitors, ADS-B), then the fuser.

CAT021 datagrams (``feed_adsb`` of their reports, ``decode_adsb``) are the bias
estimator's absolute reference and, with ``[fusion] adsb = "fuse"``, a source of the fuser
of their own (``fusion.adsb_source``: one per-address track across every ground station,
each report either fused or kept as a reference, never both). The core decodes them once
(``Chain.decode_adsb``), for this stage and for the status of the ADS-B feeds.

The correction is the one of the central stage's own moment, so the output depends only
on the order the batches are taken in, not on when they crossed the network.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.adsb import ADSB_TYP, AdsbReference, AdsbReports, decode_reports
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
from tracker_service.fusion import SYSTEM_UPDATE_DTYPE, FusionConfig, References, SystemTracker
from tracker_service.fusion.adsb_source import AdsbSource, AdsbStep, ReportUse
from tracker_service.fusion.psr_height import PsrHeights, RadarGeometry
from tracker_service.geodesy import SystemPlane
from tracker_service.radar_stage import (
    CAT021,
    KIND_UNKNOWN,
    RAW_PLOT_DTYPE,
    PlotUse,
    RadarInfo,
    blocks_of,
    source_order,
)
from tracker_service.small_arrays import concatenate_rows, copy_rows, take_rows
from tracker_service.stage_messages import RadarBatch
from tracker_service.time_sanity import TimeConsensus, TimeReport, TimeSanityConfig
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED

__all__ = ["BatchOutput", "CentralStage", "corrected"]

MONITOR_SURVEY_VARIANCE_M2 = 1.0
"""A field monitor's surveyed position: metre-level, against plots of tens of metres."""
BIAS_HISTORY_S = 10.0
ABSOLUTE_ENOUGH = 100
"""ADS-B observations of a radar after which other radars' tracks no longer serve as its
reference."""

ADSB_PLOT_ID_BASE = 1 << 48
"""ADS-B reports fused are numbered from here: apart from the radars' plot ids."""
UNNAMED_ADSB_SOURCE = "0/0"
"""The fuser's ADS-B source's name until a ground station is heard (then its SAC/SIC)."""
_REPORT_USE = {
    ReportUse.FUSED: PlotUse.TRACKED,
    ReportUse.REFERENCE: PlotUse.ADSB_REFERENCE,
    ReportUse.REPEATED: PlotUse.ADSB_REPEATED,
    ReportUse.INCONSISTENT: PlotUse.ADSB_INCONSISTENT,
    ReportUse.UNCHECKED: PlotUse.ADSB_UNCHECKED,
}

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
_NO_SYSTEM_ROWS = np.zeros(0, dtype=SYSTEM_UPDATE_DTYPE)


def corrected(rows: npt.NDArray[Any], c: FloatArray, bias: FloatArray) -> npt.NDArray[Any]:
    """A copy of plot or track ``rows`` (fields time, x, y) with the radar's bias
    ``bias`` [range offset m, gain, azimuth rad, time s] taken off through their Jacobian
    ``c`` (N, 2, 4; the time column unused: a time offset moves the time stamp)."""
    out = copy_rows(rows)
    if len(out):
        shift = c[:, :, :3] @ bias[:3]
        out["x"] -= shift[:, 0]
        out["y"] -= shift[:, 1]
        out["time"] -= bias[3]
    return out


@dataclass
class BatchOutput:
    """What one radar's part of a datagram produced: its plots (``RAW_PLOT_DTYPE``, every
    plot of the datagram, field monitors included, as the radar sent them), its
    local-track updates (bias-corrected) and the system-track rows they caused
    (``fusion.SYSTEM_UPDATE_DTYPE``)."""

    source: str
    plots: npt.NDArray[Any]
    local: npt.NDArray[Any]
    system: npt.NDArray[Any]
    time: TimeReport | None = None
    """The radar's time as status shows it."""


class CentralStage:
    """See the module docstring. ``radars``: the configured radars (fusion numbers them
    in SAC/SIC order, so that the same configuration numbers them the same way in every
    run); ``fusion`` None: local tracks only; ``bias`` None: no bias estimation;
    ``bias_history``: keep ``bias_history`` and ``clock_history`` (an evaluation's: they
    grow with the run, which a service's must not)."""

    def __init__(
        self,
        radars: Mapping[str, RadarInfo],
        plane: SystemPlane,
        fusion: FusionConfig | None = None,
        bias: BiasConfig | None = None,
        time_sanity: TimeSanityConfig | None = None,
        bias_history: bool = False,
    ) -> None:
        self.infos = dict(radars)
        self.plane = plane
        self.sources = sorted(self.infos, key=source_order)
        self.fuser: SystemTracker | None = None
        fuse_adsb = fusion is not None and fusion.adsb == "fuse"
        self.fusion_sources = [*self.sources, *([UNNAMED_ADSB_SOURCE] if fuse_adsb else [])]
        """The fuser's sources by index (``system["radar"]``): the radars, then ADS-B."""
        if fusion is not None and self.sources:
            longest = max(self.infos[s].period_s for s in self.sources)
            if fusion.longest_period_s < longest:
                fusion = replace(fusion, longest_period_s=longest)
            self.fuser = SystemTracker(len(self.fusion_sources), fusion)
        self.bias: BiasEstimator | None = None
        # "off" with reference values still corrects (the true biases given, say).
        if bias is not None and (bias.method != "off" or bias.reference_radars) and self.sources:
            self.bias = make_bias_estimator(bias, len(self.sources))
        self.adsb_source: AdsbSource | None = None
        if self.fuser is not None and fuse_adsb:
            self.adsb_source = AdsbSource(
                self.fuser,
                len(self.sources),
                share_reference=self.bias is not None,
                radar_periods={k: self.infos[s].period_s for k, s in enumerate(self.sources)},
            )
        self._next_adsb_plot_id = ADSB_PLOT_ID_BASE
        self.keeps_bias_history = bias_history
        self.bias_history: list[tuple[float, str, FloatArray, FloatArray]] = []
        """(time, source, bias, covariance) of each radar every ``BIAS_HISTORY_S`` of data,
        when kept (``bias_history``)."""
        self.clock_history: list[tuple[float, str, FloatArray, FloatArray]] = []
        """(time, source, extra clock states, covariance) beside ``bias_history``."""
        uses_reference = self.bias is not None and (fusion is None or fusion.adsb != "off")
        self.adsb = AdsbReference(plane) if uses_reference else None
        self._absolute_references = np.zeros(len(self.sources), dtype=np.int64)
        self._geometry: dict[int, tuple[FloatArray, FloatArray]] | None = (
            {} if bias is not None and bias.method == "macro" else None
        )
        self._bias_recorded: dict[str, float] = {}
        self.consensus = TimeConsensus(time_sanity)
        self._next_plot_id = 0
        self._incarnations: dict[str, tuple[int, int]] = {}
        """Per radar, its stage's incarnation and the offset added to its track numbers."""
        self._highest_track: dict[str, int] = {}
        self._live_local: dict[str, dict[int, tuple[npt.NDArray[Any], int]]] = {}
        self.heights: PsrHeights | None = None
        """Heights of aircraft without one (``fusion.psr_height``), with fusion."""
        if self.fuser is not None:
            self.heights = PsrHeights(
                {
                    k: RadarGeometry(
                        info.site,
                        info.height_band,
                        info.sigma_range_m,
                        info.sigma_azimuth_deg,
                        info.psr_sigma_range_m,
                        info.psr_sigma_azimuth_deg,
                    )
                    for k, source in enumerate(self.sources)
                    if (info := self.infos[source]).surveyed
                },
                plane,
            )

    @property
    def takes_adsb(self) -> bool:
        """Whether ``feed_adsb`` uses ADS-B reports (bias reference or fusion)."""
        return self.adsb is not None or self.adsb_source is not None

    def decode_adsb(self, payload: bytes, received: float) -> list[AdsbReports]:
        """The reports of each CAT021 block of a datagram received at ``received`` (POSIX
        s), in the system plane (``adsb.decode_reports``): what ``feed_adsb`` takes, and
        what the status counts of an ADS-B feed (``adsb_status``)."""
        return [decode_reports(block, received, self.plane) for block in blocks_of(payload, CAT021)]

    def feed_adsb(self, blocks: Sequence[AdsbReports]) -> list[BatchOutput]:
        """The reports of a datagram's CAT021 blocks (``decode_adsb``): the bias
        estimator's absolute reference, and with ``[fusion] adsb = "fuse"`` the fuser's
        ADS-B source (one output per block)."""
        if not self.takes_adsb:
            return []
        outputs = []
        for reports in blocks:
            if self.adsb_source is None:
                assert self.adsb is not None
                self.adsb.rejected += reports.records - len(reports)
                self.adsb.add(reports)
                continue
            outputs.append(self._fuse_adsb(reports))
        return outputs

    def _fuse_adsb(self, reports: AdsbReports) -> BatchOutput:
        """One block's reports through the fuser's ADS-B source (``fusion.adsb_source``)."""
        assert self.adsb_source is not None and self.fuser is not None
        if reports.station and self.fusion_sources[-1] == UNNAMED_ADSB_SOURCE:
            self.fusion_sources[-1] = reports.station
        step = self.adsb_source.step(reports, self._next_adsb_plot_id)
        self._next_adsb_plot_id += len(step.plots)
        if self.adsb is not None:
            self.adsb.rejected += reports.records - len(reports)
            self.adsb.add(reports.take(step.reference))
        system = _NO_SYSTEM_ROWS
        if len(step.updates):
            system = self.fuser.process(self.adsb_source.index, step.updates, step.plots)
            self._mark_inconsistent(system)
        return BatchOutput(
            reports.station or self.fusion_sources[-1],
            _report_table(reports, step),
            step.updates,
            system,
        )

    def _mark_inconsistent(self, system: npt.NDArray[Any]) -> None:
        """Flag the system rows of the addresses whose ADS-B disagrees with the radars."""
        if self.adsb_source is not None and self.adsb_source.stats.flagged and len(system):
            flagged = np.fromiter(self.adsb_source.stats.flagged, dtype=np.int64)
            system["adsb_inconsistent"] = np.isin(system["address"], flagged)

    def bias_estimates(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Each fused radar's current bias [range offset m, gain, azimuth rad, time s],
        then its clock's drift s/s and drift rate s/s^2 as ``BiasConfig.clock_states``
        has them, and the covariance of the biases and of the clock states (block
        diagonal: what the messages publish); empty without bias estimation."""
        if self.bias is None:
            return {}
        out = {}
        for k, source in enumerate(self.sources):
            (s, p), (c, pc) = self.bias.correction(k), self.bias.clock_correction(k)
            covariance = np.zeros((len(s) + len(c),) * 2)
            covariance[: len(s), : len(s)] = p
            covariance[len(s) :, len(s) :] = pc
            out[source] = (np.concatenate([s, c]), covariance)
        return out

    def clock_estimates(self) -> dict[str, tuple[FloatArray, FloatArray]]:
        """Each fused radar's extra clock states [drift s/s, drift rate s/s^2] (as many as
        ``BiasConfig.clock_states`` - 1) and their covariance; empty without bias
        estimation."""
        if self.bias is None:
            return {}
        return {source: self.bias.clock_correction(k) for k, source in enumerate(self.sources)}

    def bias_observed_from(self) -> dict[str, ObservedFrom]:
        """Each fused radar's sources of each bias component (``BiasEstimates``); empty
        without bias estimation."""
        if self.bias is None:
            return {}
        observed = self.bias.estimates().observed_from
        return {source: observed[k] for k, source in enumerate(self.sources)}

    def process(self, message: RadarBatch) -> BatchOutput:
        """One radar batch, in input order (see the module docstring)."""
        restarted = self._renumber(message)
        source = message.source
        info = self.infos.get(source)
        index = self.sources.index(source) if info is not None and info.surveyed else None
        ended = _NO_SYSTEM_ROWS
        if restarted and self.fuser is not None and index is not None:
            ended = self._end_local_tracks(index, source, message)
        output = self._process(message, index)
        if len(ended):
            output.system = concatenate_rows([ended, output.system])
        self._remember(source, output.local)
        return output

    def _end_local_tracks(self, index: int, source: str, message: RadarBatch) -> npt.NDArray[Any]:
        """A restarted radar stage's predecessor's local tracks, deleted in the fuser:
        their system tracks go on with the other radars (or end, as orphans), and the new
        stage's tracks join them afresh instead of founding duplicates beside tracks the
        fuser still holds for that radar."""
        assert self.fuser is not None
        old = self._live_local.pop(source, {})
        if not old:
            return _NO_SYSTEM_ROWS
        rows = np.array([batch[k] for batch, k in old.values()], dtype=message.local.dtype)
        rows["status"] = LOCAL_DELETED
        rows["plot_id"] = -1
        # At the fuser's own time: their last updates are as old as the outage, which
        # its clock would refuse as out of line.
        now = self.fuser.clock.now
        rows["time"] = now if math.isfinite(now) else message.received
        return self.fuser.process(index, rows, np.zeros(0, dtype=message.tracked.dtype), None)

    def _remember(self, source: str, local: npt.NDArray[Any]) -> None:
        """The latest update of each live local track of each radar: its batch (a copy)
        and its index there, taken as a row only when a restart needs it (a row copied
        per update cost more than the bias correction)."""
        if not len(local):
            return
        live = self._live_local.setdefault(source, {})
        kept = copy_rows(local)
        numbers = kept["track_number"].tolist()
        deleted = kept["status"] == LOCAL_DELETED
        if not deleted.any():
            n = len(numbers)
            at = zip(itertools.repeat(kept, n), range(n), strict=True)
            live.update(zip(numbers, at, strict=True))
            return
        for k, (number, gone) in enumerate(zip(numbers, deleted.tolist(), strict=True)):
            if gone:
                live.pop(number, None)
            else:
                live[number] = (kept, k)

    def _process(self, message: RadarBatch, index: int | None) -> BatchOutput:
        source = message.source
        out_of_step = self.consensus.out_of_step(
            source, message.effective_offset_s, message.received
        )
        report = message.time
        if out_of_step != report.out_of_step_s:
            report = replace(report, out_of_step_s=out_of_step)
        local, batch = message.local, message.tracked
        bias = bias_cov = None
        if self.bias is not None and index is not None:
            bias, bias_cov = self.bias.correction(index)
            local = corrected(local, message.local_jacobian, bias)
            tracked_c = message.jacobian[message.plots["use"] == PlotUse.TRACKED.value]
            batch = corrected(batch, tracked_c, bias)
        if index is not None and not message.snapshot:
            self._note_cover(index, message, batch)
        # A radar out of step with the others would be fused at the wrong time.
        if self.fuser is None or index is None or not len(local) or out_of_step is not None:
            return BatchOutput(source, message.plots, local, _NO_SYSTEM_ROWS, report)
        height_extra = None
        unknown_height = not message.plots["height_known"].all()
        if self.heights is not None and unknown_height and not message.snapshot:
            local, batch, height_extra = self._reproject_heights(index, message, batch, local)
        extra = None
        if bias is not None and bias_cov is not None and not message.snapshot:
            assert self.bias is not None
            self.bias.update_reception(index, message.clock_evidence)
            extra = self._estimate_biases(index, message, batch, local, bias, bias_cov)
        if height_extra is not None:
            extra = height_extra if extra is None else extra + height_extra
        system = self.fuser.process(index, local, batch, extra)
        if self.adsb_source is not None:
            self.adsb_source.check_radar(local, extra)
        self._mark_inconsistent(system)
        return BatchOutput(source, message.plots, local, system, report)

    def _note_cover(self, radar: int, message: RadarBatch, batch: npt.NDArray[Any]) -> None:
        """Where the radar sees targets (``fusion.cover``): its tracked PSR plots for the
        primary-only heights, all its plots for the ADS-B source's check."""
        if self.heights is not None:
            self.heights.cover.note(radar, batch)
        if self.adsb_source is not None:
            self.adsb_source.cover.note(radar, message.plots)

    def _reproject_heights(
        self, radar: int, message: RadarBatch, batch: npt.NDArray[Any], local: npt.NDArray[Any]
    ) -> tuple[npt.NDArray[Any], npt.NDArray[Any], FloatArray]:
        """Plots without a height and their local updates at their aircraft's estimated
        height, and its uncertainty as a consider covariance (``fusion.psr_height``)."""
        assert self.fuser is not None and self.heights is not None
        table = self.fuser.state.local
        rows = table.find(radar, local, create=False)
        systems = np.where(rows >= 0, table.rows["system"][np.maximum(rows, 0)], 0)
        # The heights are measured on the plots without one: their references only.
        without_height = _updates_of_plots(local, message.plots, ~message.plots["height_known"])
        if len(without_height):
            refs = self._references(radar, without_height, batch, everyone=False)
            self.heights.observe(radar, message.plots, batch, refs)
        moved = self.heights.reproject(radar, message.plots, batch, local, systems)
        return moved.local, moved.tracked, moved.extra

    def _references(
        self,
        radar: int,
        local: npt.NDArray[Any],
        batch: npt.NDArray[Any],
        sources: int | None = None,
        *,
        everyone: bool,
    ) -> References:
        """``SystemTracker.references`` of the updates ``local``; ``everyone`` False: the
        other radars' predictions only, without the prediction from all local tracks (a
        second fusion per row, which only the macro filter's observations take)."""
        assert self.fuser is not None
        return self.fuser.references(radar, local, batch, sources, everyone=everyone)

    def _renumber(self, message: RadarBatch) -> bool:
        """Plot ids for the system, in the order batches are taken; a restarted radar
        stage's track numbers after the highest its predecessor used. True for the first
        batch of a restarted stage."""
        n = len(message.plots)
        if n:
            offset = self._next_plot_id - int(message.plots["plot_id"][0])
            self._next_plot_id += n
            if offset:
                message.plots["plot_id"] += offset
                message.tracked["plot_id"] += offset
                with_plot = message.local["plot_id"] >= 0
                message.local["plot_id"][with_plot] += offset
        source = message.source
        known = self._incarnations.get(source)
        restarted = known is not None and known[0] != message.incarnation
        if known is None or restarted:
            shift = 0 if known is None else self._highest_track.get(source, 0)
            self._incarnations[source] = known = (message.incarnation, shift)
        if len(message.local):
            if known[1]:
                message.local["track_number"] += known[1]
            highest = int(message.local["track_number"].max())
            if highest > self._highest_track.get(source, 0):
                self._highest_track[source] = highest
        return restarted

    def _estimate_biases(
        self,
        radar: int,
        message: RadarBatch,
        batch: npt.NDArray[Any],
        local: npt.NDArray[Any],
        bias: FloatArray,
        bias_cov: FloatArray,
    ) -> FloatArray:
        """Feed the bias estimator this batch's plots with a reference (see DOMAIN.md
        section 6, variant 3: predictions these plots have not updated) and return the
        residual bias covariance of each local update, for the fuser."""
        assert self.bias is not None and self.fuser is not None
        table, c, monitor_xy = message.plots, message.jacobian, message.monitor_xy
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
        monitor = np.flatnonzero(np.isfinite(monitor_xy[:, 0]))
        if monitor.size:
            observations.append(
                make_observations(
                    n_radars,
                    np.full(monitor.size, radar),
                    table["time"][monitor],
                    np.column_stack([table["x"][monitor], table["y"][monitor]]),
                    table["R"][monitor],
                    c[monitor],
                    monitor_xy[monitor],
                    np.broadcast_to(np.eye(2) * MONITOR_SURVEY_VARIANCE_M2, (monitor.size, 2, 2)),
                    kind=ObservationKind.FIELD_MONITOR,
                )
            )
        if self.adsb is not None:
            adsb = self._adsb_observations(radar, table, c)
            if adsb is not None:
                self._absolute_references[radar] += len(adsb)
                observations.append(adsb)
        if observations:
            self.bias.update(
                observations[0] if len(observations) == 1 else concatenate(observations)
            )
        if self.keeps_bias_history and (observations or self.adsb is not None):
            self._record_bias(radar, message.source, float(table["time"].max()))
        # Each local update's share of the residual bias, at its plot.
        extra = np.zeros((len(local), 2, 2))
        with_plot = np.flatnonzero(local["plot_id"] >= 0)
        if with_plot.size:
            cu = c[local["plot_id"][with_plot] - first_id].copy()
            cu[:, 0, 3] = -local["vx"][with_plot]
            cu[:, 1, 3] = -local["vy"][with_plot]
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
        # ADS-B's local tracks are no relative reference: its reports are fused or are the
        # absolute reference already (fusion/adsb_source.py: no double use).
        n_radars = len(self.sources)
        if self._geometry is None:
            # Only plots with a height serve: the references of the others are not made.
            local = _updates_of_plots(local, table, table["height_known"])
            if not len(local):
                return None
        refs = self._references(radar, local, batch, n_radars, everyone=self._geometry is not None)
        if self._geometry is not None:
            self._remember_geometry(radar, refs, table["R"], c, first_id)
        # A plot without a height is off by an error of its aircraft's, not its radar's.
        usable = refs.others_valid & relative & table["height_known"][refs.plot_id - first_id]
        if not usable.any():
            return None
        row = refs.plot_id[usable] - first_id
        others_v = refs.others_v[usable]
        rc = c[row].copy()
        rc[:, :, 3] = -others_v
        # The prediction from every radar and the contributors are the macro filter's
        # (``everyone``, with its geometry): the others' defaults otherwise.
        prediction_xy = prediction_p = contributors = contributor_r = contributor_c = None
        if self._geometry is not None:
            contributor_r, contributor_c = self._contributor_geometry(refs.system_number[usable])
            contributors = refs.radars_seen[usable][:, :n_radars] & (contributor_r[:, :, 0, 0] > 0)
            prediction_xy = refs.all_xy[usable] + others_v * bias[3]
            prediction_p = refs.all_P[usable]
        # The reference at the plot's time as labelled, where the uncorrected plot lies:
        # the batch's time had the estimated time offset taken off.
        ref_xy = refs.others_xy[usable] + others_v * bias[3]
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
            reference_v=others_v,
            prediction_xy=prediction_xy,
            prediction_P=prediction_p,
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
    ) -> BiasObservations | None:
        """The batch's Mode S plots against the ADS-B track of their address at their
        time stamp (an absolute reference: see ``tracker_service.adsb``); None without
        any."""
        assert self.adsb is not None
        rows = np.flatnonzero((table["address"] >= 0) & ~table["rab"])
        if not rows.size:  # a conventional SSR or a primary radar's batch
            return None
        refs = self.adsb.at(table["address"][rows], table["time"][rows])
        rows = rows[refs.valid]
        if not rows.size:
            return None
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

    def _record_bias(self, radar: int, source: str, time: float) -> None:
        assert self.bias is not None
        last = self._bias_recorded.get(source, -np.inf)
        if time - last >= BIAS_HISTORY_S:
            s, p = self.bias.correction(radar)
            self.bias_history.append((time, source, s, p))
            self.clock_history.append((time, source, *self.bias.clock_correction(radar)))
            self._bias_recorded[source] = time


def _updates_of_plots(
    local: npt.NDArray[Any], table: npt.NDArray[Any], wanted: npt.NDArray[np.bool_]
) -> npt.NDArray[Any]:
    """The local updates whose plot is ``wanted`` (a mask over the batch's plot table
    ``table``): the fuser's references cost per row (each a fusion of the track's
    sources), and each of their users needs some plots only."""
    with_plot = np.flatnonzero(local["plot_id"] >= 0)
    if not with_plot.size:
        return local[:0]
    first_id = int(table["plot_id"][0])
    keep: npt.NDArray[np.bool_] = wanted[local["plot_id"][with_plot] - first_id]
    return take_rows(local, with_plot[keep])


def _report_table(reports: AdsbReports, step: AdsbStep) -> npt.NDArray[Any]:
    """One ``RAW_PLOT_DTYPE`` row per CAT021 record of the block, in record order, with
    what became of it (``use``); records unfit for use carry no position."""
    table = np.zeros(reports.records, dtype=RAW_PLOT_DTYPE)
    table["plot_id"] = -1
    table["record"] = np.arange(reports.records)
    for name in ("time", "x", "y", "rho_m", "theta_deg", "flight_level", "detection_time"):
        table[name] = np.nan
    table["typ"] = ADSB_TYP
    table["address"] = table["mode3a"] = table["aircraft"] = -1
    table["kind"] = KIND_UNKNOWN
    table["use"] = PlotUse.ADSB_UNFIT
    row = reports.record
    table["plot_id"][row] = step.plot_id
    table["time"][row] = reports.time
    table["x"][row], table["y"][row] = reports.x, reports.y
    table["R"][row] = (reports.sigma**2)[:, None, None] * np.eye(2)
    table["flight_level"][row] = reports.flight_level
    table["address"][row] = reports.address
    table["mode3a"][row] = reports.mode3a
    table["use"][row] = [_REPORT_USE[ReportUse(u)] for u in step.use.tolist()]
    return table
