"""System tracks and bias estimates against truth.

System tracks are measured with the local-track rules (``metrics`` module docstring),
over the system's own antenna periods: intervals as long as the longest period of the
radars, an aircraft being in system coverage in an interval when at least one radar has
it in coverage at the interval's middle. Only rows that carry a fresh plot count as
updates. The split by coverage counts the radars that have the aircraft in coverage at
the update's time (or the interval's middle): ``multi`` at least two, ``single`` one.

``rms_ratio_to_best_local``: over the system updates of aircraft in multi-radar
coverage, the system position error RMS divided by the RMS, at the same moments, of the
aircraft's best local track (per aircraft the radar whose local tracks, extrapolated
to those moments from their latest confirmed update, have the smallest RMS; a radar
counts for an aircraft when it has a local estimate at most one of its periods old at
nine in ten of the moments). ``rms_ratio_to_best_local_own_updates``: the same system
errors over the same local RMS taken at that radar's own confirmed updates from a plot
over the span of those moments (not extrapolated: the local track at its best, so the
larger of the two ratios).

Coasting updates, the 95th percentile and maximum error, and the probability of update
over 10 s beside the slowest radar's period: ``metrics`` module docstring.

Clock (``clock_metrics``, under each radar's "bias" with ``[bias] clock_states`` 2 or 3):
``time_drift_s_per_h`` (and ``time_drift_rate_s_per_h2``) estimate, truth (the slope and
curvature of the radar's true time offsets over the recording) and sigma at the end, and
``converged_after_s``.

Bias errors: per radar each estimated component at the end of the recording against
the simulator's ``/truth/biases`` (measured minus true, range gain dimensionless).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.adsb_cover import AdsbCover, split_by_adsb
from tracker_service.evaluation.metrics import (
    UPDATE_INTERVAL_S,
    Coverage,
    LocalMetrics,
    PlotOrigins,
    Truth,
    associate_updates,
    local_metrics,
)
from tracker_service.fusion import ENDED
from tracker_service.fusion.messages import MAX_SYSTEM_NUMBER
from tracker_service.simulator.recording import Recording
from tracker_service.tracking import CONFIRMED, track_update_dtype

__all__ = [
    "BIAS_COMPONENTS",
    "SystemEvaluation",
    "bias_metrics",
    "clock_metrics",
    "coverage_counts",
    "system_coverage",
    "system_metrics",
    "truth_biases",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

BIAS_COMPONENTS = ("range_offset_m", "range_gain", "azimuth_deg", "time_s")
"""The bias vector's components as ``evaluate --json`` names them; the estimator's state
holds the azimuth in radians."""
DRIFT = "time_drift_s_per_h"
DRIFT_RATE = "time_drift_rate_s_per_h2"
"""The extra clock states as ``evaluate --json`` names them (``BiasConfig.clock_states``)."""
DRIFT_TOLERANCE = 0.1
DRIFT_FLOOR_S_PER_H = 1e-3
"""Issue 14's clock target: the drift within 10 % or 1 ms/h, whichever is larger."""
SECONDS_PER_HOUR = 3600.0

_SHARED_FIELDS = ("time", "x", "y", "vx", "vy", "P", "flight_level", "status")
"""Fields a system-track row has as a local-track row has them."""
_LOCAL_VIEW = np.dtype(
    [(name, track_update_dtype(1)[name]) for name in ("track_number", *_SHARED_FIELDS, "plot_id")]
)
"""The fields of local-track updates that the metrics read."""


def as_track_rows(system: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """System-track rows in the shape the local-track metrics read: a row counts as an
    update from a plot only when it carries a fresh one. System numbers are reused once
    a track has ended: each life gets a number of its own here (number + (MAX_SYSTEM_NUMBER
    + 1) x the lives before it), since the metrics take a number for one track."""
    rows = np.zeros(len(system), dtype=_LOCAL_VIEW)
    lives: dict[int, int] = {}
    numbers = np.empty(len(system), dtype=np.int64)
    for k, (number, status) in enumerate(
        zip(system["system_number"].tolist(), system["status"].tolist(), strict=True)
    ):
        life = lives.get(number, 0)
        numbers[k] = number + (MAX_SYSTEM_NUMBER + 1) * life
        if status == ENDED:
            lives[number] = life + 1
    rows["track_number"] = numbers
    for name in _SHARED_FIELDS:
        rows[name] = system[name]
    rows["plot_id"] = np.where(system["fresh"], system["plot_id"], -1)
    return rows


def coverage_counts(
    coverages: Mapping[str, Coverage], aircraft: IntArray, times: FloatArray
) -> IntArray:
    """How many radars have each (aircraft, time) in coverage."""
    counts = np.zeros(len(aircraft), dtype=np.int64)
    for coverage in coverages.values():
        if not len(coverage.times):
            continue
        scan = np.searchsorted(coverage.times, times, side="right") - 1
        inside = (scan >= 0) & (times < coverage.times[np.maximum(scan, 0)] + coverage.period_s)
        for row in np.flatnonzero(inside).tolist():
            if int(aircraft[row]) in coverage.aircraft[int(scan[row])]:
                counts[row] += 1
    return counts


def system_coverage(
    coverages: Mapping[str, Coverage],
    least: int = 1,
    most: int | None = None,
    period_s: float | None = None,
) -> Coverage | None:
    """The system's intervals (see the module docstring), holding the aircraft seen by
    ``least`` to ``most`` radars; intervals of ``period_s`` instead of the longest
    radar period when given."""
    scanning = [c for c in coverages.values() if len(c.times)]
    if not scanning:
        return None
    period = period_s if period_s is not None else max(c.period_s for c in scanning)
    start = min(float(c.times[0]) for c in scanning)
    end = max(float(c.times[-1]) + c.period_s for c in scanning)
    starts = np.arange(start, end - period + 1e-9, period)
    everyone = sorted({a for c in scanning for inside in c.aircraft for a in inside})
    middles = starts + period / 2
    aircraft = np.repeat(np.array(everyone, dtype=np.int64), len(starts))
    times = np.tile(middles, len(everyone))
    counts = coverage_counts(coverages, aircraft, times).reshape(len(everyone), len(starts))
    keep = (counts >= least) & (counts <= (most if most is not None else counts.max(initial=0)))
    sets = [
        frozenset(int(everyone[i]) for i in np.flatnonzero(keep[:, k])) for k in range(len(starts))
    ]
    return Coverage(starts, sets, period)


@dataclass
class SystemEvaluation:
    system: LocalMetrics
    multi: LocalMetrics
    single: LocalMetrics
    rms_ratio_to_best_local: float | None
    rows: npt.NDArray[Any]
    """The system rows as track rows (``as_track_rows``), for the report."""
    rms_ratio_to_best_local_own_updates: float | None = None
    """As ``rms_ratio_to_best_local``, the best local track scored at its own updates from a
    plot (over the same aircraft and span) instead of extrapolated to the system's."""
    adsb_only: LocalMetrics | None = None
    """In some ADS-B station's cover and no radar's (``adsb_cover``); None: no ADS-B."""
    radar_and_adsb: LocalMetrics | None = None


def _local_estimates(
    local: npt.NDArray[Any], labels: IntArray, aircraft: int, times: FloatArray, max_age_s: float
) -> tuple[FloatArray, FloatArray, BoolArray]:
    """The radar's confirmed local estimate of ``aircraft`` at ``times``: its latest
    confirmed update from a plot, extrapolated at constant velocity."""
    rows = local[(labels == aircraft) & (local["status"] == CONFIRMED) & (local["plot_id"] >= 0)]
    n = len(times)
    if len(rows) == 0:
        return np.zeros(n), np.zeros(n), np.zeros(n, dtype=bool)
    rows = rows[np.argsort(rows["time"], kind="stable")]
    at = np.searchsorted(rows["time"], times, side="right") - 1
    ok = at >= 0
    r = rows[np.maximum(at, 0)]
    dt = times - r["time"]
    ok &= dt <= max_age_s
    return r["x"] + r["vx"] * dt, r["y"] + r["vy"] * dt, ok


def _own_update_errors(
    local: npt.NDArray[Any], labels: IntArray, aircraft: int, t0: float, t1: float, truth: Truth
) -> FloatArray:
    """Squared position errors of a radar's confirmed updates from a plot of ``aircraft``
    in [t0, t1], at their own times."""
    sel = (
        (labels == aircraft)
        & (local["status"] == CONFIRMED)
        & (local["plot_id"] >= 0)
        & (local["time"] >= t0)
        & (local["time"] <= t1)
    )
    rows = local[sel]
    tx, ty, *_ = truth.at(np.full(len(rows), aircraft, dtype=np.int64), rows["time"])
    sq = (rows["x"] - tx) ** 2 + (rows["y"] - ty) ** 2
    return np.asarray(sq[np.isfinite(sq)], dtype=np.float64)


def _best_local_ratio(
    errors: Any,
    multi: BoolArray,
    locals_: Mapping[str, tuple[npt.NDArray[Any], IntArray, float]],
    truth: Truth,
) -> tuple[float | None, float | None]:
    """``rms_ratio_to_best_local`` and ``rms_ratio_to_best_local_own_updates`` (module
    docstring): per aircraft the best radar among those that count for it, by the RMS of
    its local tracks extrapolated to the system's moments, and by the RMS at its own
    updates over the span of those moments."""
    system_sq = local_sq = 0.0
    system_sq_own = local_sq_own = 0.0
    for aircraft in np.unique(errors.aircraft[multi]).tolist():
        sel = multi & (errors.aircraft == aircraft)
        times = errors.time[sel]
        tx, ty, *_ = truth.at(np.full(len(times), aircraft, dtype=np.int64), times)
        best: tuple[float, BoolArray] | None = None
        best_own: float | None = None
        for rows, labels, period in locals_.values():
            x, y, ok = _local_estimates(rows, labels, aircraft, times, period)
            ok &= np.isfinite(tx) & np.isfinite(x) & np.isfinite(errors.dx[sel])
            if np.count_nonzero(ok) < 0.9 * len(times):
                continue
            rms = float(np.sqrt(np.mean((x[ok] - tx[ok]) ** 2 + (y[ok] - ty[ok]) ** 2)))
            if best is None or rms < best[0]:
                best = (rms, ok)
            own = _own_update_errors(
                rows, labels, aircraft, float(times.min()), float(times.max()), truth
            )
            if own.size:
                own_rms = float(np.sqrt(np.mean(own)))
                best_own = own_rms if best_own is None else min(best_own, own_rms)
        if best is None:
            continue
        rms, ok = best
        system_sq += float(np.sum(errors.dx[sel][ok] ** 2 + errors.dy[sel][ok] ** 2))
        local_sq += rms**2 * np.count_nonzero(ok)
        if best_own is not None:
            # The system at the same moments as the extrapolated ratio's.
            system_sq_own += float(np.sum(errors.dx[sel][ok] ** 2 + errors.dy[sel][ok] ** 2))
            local_sq_own += best_own**2 * np.count_nonzero(ok)
    return (
        float(np.sqrt(system_sq / local_sq)) if local_sq > 0 else None,
        float(np.sqrt(system_sq_own / local_sq_own)) if local_sq_own > 0 else None,
    )


def system_metrics(
    system: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    coverages: Mapping[str, Coverage],
    locals_: Mapping[str, tuple[npt.NDArray[Any], PlotOrigins]],
    *,
    gate_m: float = 1000.0,
    min_identity_updates: int = 2,
    end_time: float | None = None,
    adsb: AdsbCover | None = None,
) -> SystemEvaluation:
    """Every system-track metric (see the module docstring). ``origins``: the plot origins
    of every radar; ``locals_``: per radar its local-track updates and plot origins."""
    rows = as_track_rows(system)
    options: dict[str, Any] = {
        "gate_m": gate_m,
        "min_identity_updates": min_identity_updates,
        "end_time": end_time,
    }
    overall = local_metrics(
        rows,
        origins,
        truth,
        system_coverage(coverages),
        fixed_interval_coverage=system_coverage(coverages, period_s=UPDATE_INTERVAL_S),
        **options,
    )
    errors = overall.errors
    if errors is None or len(errors.time) == 0:
        counts = np.zeros(0, dtype=np.int64)
    else:
        counts = coverage_counts(coverages, errors.aircraft, errors.time)
    # The split re-evaluates the same updates, masked by their coverage at the time.
    labels = associate_updates(rows, origins, truth, gate_m)
    row_counts = np.zeros(len(rows), dtype=np.int64)
    labelled = labels >= 0
    row_counts[labelled] = coverage_counts(
        coverages, labels[labelled], np.asarray(rows["time"][labelled], dtype=np.float64)
    )
    multi = local_metrics(
        rows,
        origins,
        truth,
        system_coverage(coverages, least=2),
        evaluate_mask=row_counts >= 2,
        fixed_interval_coverage=system_coverage(coverages, least=2, period_s=UPDATE_INTERVAL_S),
        **options,
    )
    single = local_metrics(
        rows,
        origins,
        truth,
        system_coverage(coverages, least=1, most=1),
        evaluate_mask=row_counts == 1,
        fixed_interval_coverage=system_coverage(
            coverages, least=1, most=1, period_s=UPDATE_INTERVAL_S
        ),
        **options,
    )
    ratio = ratio_own = None
    if errors is not None and len(errors.time):
        local_labels = {
            source: (
                updates,
                associate_updates(updates, plot_origins, truth, gate_m),
                coverages[source].period_s if source in coverages else 10.0,
            )
            for source, (updates, plot_origins) in locals_.items()
        }
        ratio, ratio_own = _best_local_ratio(errors, counts >= 2, local_labels, truth)
    by_adsb: list[LocalMetrics | None] = [None, None]
    radar_grid = system_coverage(coverages)
    if adsb is not None and radar_grid is not None:
        in_adsb = np.zeros(len(rows), dtype=bool)
        grid = adsb.on_grid(radar_grid)
        times = np.asarray(rows["time"][labelled], dtype=np.float64)
        in_adsb[labelled] = coverage_counts({"adsb": grid}, labels[labelled], times) > 0
        for i, (cover, mask) in enumerate(
            zip(split_by_adsb(radar_grid, grid), (row_counts == 0, row_counts >= 1), strict=True)
        ):
            by_adsb[i] = local_metrics(
                rows, origins, truth, cover, evaluate_mask=mask & in_adsb, **options
            )
    return SystemEvaluation(overall, multi, single, ratio, rows, ratio_own, *by_adsb)


def truth_biases(recording: Recording) -> dict[str, dict[str, float]]:
    """The last ``/truth/biases`` message of each radar, with its clock's drift (s/h) and
    drift rate (s/h^2): the slope and curvature of its time offsets over the recording
    (least squares; the simulator's drift is constant, its wander a random walk of the
    offset)."""
    out: dict[str, dict[str, float]] = {}
    if "/truth/biases" not in recording.topics:
        return out
    offsets: dict[str, list[tuple[float, float]]] = {}
    for message in recording.messages("/truth/biases"):
        source = str(message["source"])
        out[source] = {k: float(message[k]) for k in BIAS_COMPONENTS}
        offsets.setdefault(source, []).append((float(message["time"]), float(message["time_s"])))
    for source, series in offsets.items():
        t, offset = np.array(series).T
        if len(t) >= 3 and np.ptp(t) > 0:
            hours = (t - t[-1]) / SECONDS_PER_HOUR
            curvature, slope, _ = np.polyfit(hours, offset, 2)
            out[source][DRIFT] = float(slope)
            out[source][DRIFT_RATE] = float(2.0 * curvature)
    return out


def _converged_after(
    history: Sequence[tuple[float, float]], truth: float, tolerance: float
) -> float | None:
    """Seconds from the first of ``history`` (time, drift s/h) after which every estimate
    lies within ``tolerance`` of ``truth``; None when the last one does not."""
    if not history:
        return None
    times = np.array([t for t, _ in history])
    errors = np.abs(np.array([value for _, value in history]) - truth)
    outside = np.flatnonzero(errors > tolerance)
    if not outside.size:
        return 0.0
    if outside[-1] == len(times) - 1:
        return None
    return float(times[outside[-1] + 1] - times[0])


def clock_metrics(
    clock: Mapping[str, tuple[FloatArray, FloatArray]],
    history: Sequence[tuple[float, str, FloatArray, FloatArray]],
    truth: Mapping[str, Mapping[str, float]],
) -> dict[str, dict[str, dict[str, float | None]]]:
    """Per radar the clock drift (s/h) and, with 3 clock states, its rate (s/h^2): estimate,
    truth, sigma at the end, and for the drift ``converged_after_s``: from the radar's first
    bias estimate, when the estimate entered for good the issue's tolerance (10 % of the
    true drift or 1 ms/h, the larger). Empty with a 1-state clock."""
    out: dict[str, dict[str, dict[str, float | None]]] = {}
    units = (SECONDS_PER_HOUR, SECONDS_PER_HOUR**2)
    for source, (state, covariance) in clock.items():
        sigmas = np.sqrt(np.clip(np.diag(covariance), 0.0, None))
        true = truth.get(source, {})
        entries: dict[str, dict[str, float | None]] = {}
        for i, name in enumerate((DRIFT, DRIFT_RATE)[: len(state)]):
            entries[name] = {
                "estimate": float(state[i]) * units[i],
                "truth": true.get(name),
                "sigma": float(sigmas[i]) * units[i],
            }
        drift = entries.get(DRIFT)
        if drift is not None:
            true_drift = drift["truth"]
            converged = None
            if true_drift is not None:
                tolerance = max(DRIFT_TOLERANCE * abs(true_drift), DRIFT_FLOOR_S_PER_H)
                series = [(t, float(c[0]) * units[0]) for t, s, c, _ in history if s == source]
                converged = _converged_after(series, true_drift, tolerance)
            drift["converged_after_s"] = converged
        if entries:
            out[source] = entries
    return out


def bias_metrics(
    estimates: Mapping[str, tuple[FloatArray, FloatArray]],
    truth: Mapping[str, Mapping[str, float]],
) -> dict[str, dict[str, dict[str, float | None]]]:
    """Per radar and component: estimate, truth and sigma (``evaluate --json``'s "bias").
    ``estimates``: per radar the state [range offset m, gain, azimuth rad, time s] and
    its 4x4 covariance."""
    scale = np.array([1.0, 1.0, np.degrees(1.0), 1.0])
    out: dict[str, dict[str, dict[str, float | None]]] = {}
    for source, (state, covariance) in estimates.items():
        # The 4 biases; a clock's drift after them is ``clock_metrics``'.
        values = np.asarray(state, dtype=np.float64)[:4] * scale
        sigmas = np.sqrt(np.clip(np.diag(covariance)[:4], 0.0, None)) * scale
        true = truth.get(source, {})
        out[source] = {
            name: {
                "estimate": float(values[i]),
                "truth": true.get(name),
                "sigma": float(sigmas[i]),
            }
            for i, name in enumerate(BIAS_COMPONENTS)
        }
    return out
