"""Tracks against truth: association, and the surveillance metrics of each radar.

Association rule (per track update, then per track):

1. An update from a plot (``plot_id`` >= 0) belongs to the aircraft the plot came from
   (``/truth/plots``) when the plot is a detection or a split of that aircraft. A plot of
   clutter, a reflection or an unknown origin falls back to the nearest true aircraft at
   the update time, if one lies within ``association_gate_m`` of the track's position;
   otherwise the update belongs to no aircraft (-1). The radar's field monitor is a real,
   fixed transponder: its updates get their own label (-2), neither aircraft nor false.
2. An update without a plot (coasting, deletion) keeps the label of the track's last
   update from a plot: the track has learnt nothing new.
3. A track's identity is its sequence of labels with stray runs removed: a run of fewer
   than ``min_identity_updates`` plot updates of one aircraft inside a track (one wrong
   plot taken) is not an identity. An identity change is a change between two kept
   runs of different aircraft. A track is *false* when most of its confirmed updates
   belong to no aircraft.

Metric definitions (per radar, ``LocalMetrics``):

- Accuracy (position, along/across track, velocity, flight level, NEES) over the
  confirmed updates from a fresh plot (status CONFIRMED, plot_id >= 0) that belong to an
  aircraft, against that aircraft's truth interpolated at the update time. Horizontal
  position RMS is the radial sqrt(mean(dx^2 + dy^2)), so position^2 = along^2 +
  across^2; along-track is the error along the true velocity. Velocity RMS is the
  radial one too. Flight level RMS (ft) over updates with a flight level.
  ``position_p95_m`` and ``position_max_m``: the 95th percentile and the largest of the
  same radial errors.
- Coasting: the confirmed or coasting updates without a fresh plot (a track's own
  prediction, published all the same; rule 2 labels them) are scored apart
  (``coasting_updates``, ``coasting_position_rms_m``) and together with the plot updates
  (``position_rms_with_coasting_m``, ``..._p95_...``, ``..._max_...``): the error a user of
  every published update sees.
- NEES: e^T P^-1 e of the horizontal position (dof 2, ``nees_mean``) and of the whole
  state [x, y, vx, vy] (dof 4, ``nees_state_mean``); averaged first within each antenna
  period of the radar, then over those periods (a time average, as over Monte Carlo
  runs, so that busy scans do not weigh more). Target window ``NEES_WINDOW``: 0.8-1.25
  x dof (``nees_in_window``).
- Probability of update (ESASSP): the radar's antenna periods are the intervals
  [t_scan, t_scan + period) of ``/truth/coverage``; an interval with the aircraft in
  coverage counts as updated when a confirmed update from a plot of that aircraft falls
  in it. Per continuous stretch of coverage, the intervals before the first confirmed
  update are initiation (measured by ``initiation_delay_s``) and left out; a stretch
  never initiated counts all its intervals as misses. Intervals that end after the
  radar's last plot are left out (the recording stops mid-scan).
  ``probability_of_update_with_initiation`` counts every interval.
  ``update_interval_s`` is the interval ``probability_of_update`` used (the radar's period;
  the system's: its slowest radar's); ``probability_of_update_10s`` counts the same way
  over 10 s intervals (the ESASSP target's), the aircraft in coverage in an interval when
  it is in coverage at its middle.
- Tracks per aircraft: per stretch of coverage that holds at least one confirmed
  update of the aircraft, the number of distinct tracks with an identity run of that
  aircraft in the stretch; averaged over those stretches.
- Initiation delay: per stretch initiated, the first confirmed update's time minus the
  time of the stretch's first scan; averaged.
- False tracks: the number of false confirmed tracks; ``false_track_max_scans`` is the
  longest one's confirmed life in antenna periods.
"""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.pipeline import (
    KIND_AIRCRAFT,
    KIND_FIELD_MONITOR,
    KIND_SPLIT,
)
from tracker_service.geodesy import SystemPlane
from tracker_service.simulator.recording import Recording
from tracker_service.tracking import COASTING, CONFIRMED

__all__ = [
    "FIELD_MONITOR",
    "NO_AIRCRAFT",
    "Coverage",
    "LocalMetrics",
    "PlotMetrics",
    "PlotOrigins",
    "Truth",
    "UpdateErrors",
    "associate_updates",
    "coverage_from_recording",
    "local_metrics",
    "plot_metrics",
    "truth_from_recording",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

NO_AIRCRAFT = -1
FIELD_MONITOR = -2
FEET_PER_FL = 100.0
UPDATE_INTERVAL_S = 10.0
"""The probability-of-update target's interval (ESASSP: 10 s), beside the radar's (or the
system's slowest radar's) own period."""
NEES_WINDOW = (0.8, 1.25)
"""The time-averaged NEES target, as multiples of its degrees of freedom (issue 14)."""


def nees_in_window(mean: float | None, dof: int) -> bool:
    """Whether a time-averaged NEES lies in ``NEES_WINDOW`` x dof."""
    return mean is not None and NEES_WINDOW[0] * dof <= mean <= NEES_WINDOW[1] * dof


# --- truth ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Truth:
    """Every aircraft's state in the system plane at the truth snapshots: ``times`` (T,),
    the others (T, A), aircraft by index; NaN where an aircraft has no state."""

    times: FloatArray
    x: FloatArray
    y: FloatArray
    vx: FloatArray
    vy: FloatArray
    fl: FloatArray

    @property
    def n_aircraft(self) -> int:
        return int(self.x.shape[1])

    def _bracket(self, t: FloatArray) -> tuple[IntArray, FloatArray, FloatArray, BoolArray]:
        t = np.asarray(t, dtype=np.float64)
        i = np.clip(np.searchsorted(self.times, t, side="right") - 1, 0, len(self.times) - 2)
        h = self.times[i + 1] - self.times[i]
        s = (t - self.times[i]) / h
        inside = (t >= self.times[0]) & (t <= self.times[-1])
        return i, s, h, inside

    def at(self, aircraft: IntArray, t: FloatArray) -> tuple[FloatArray, ...]:
        """(x, y, vx, vy, fl) of each aircraft at each time (arrays of one shape); NaN
        outside the truth's time span or for an aircraft index out of range.

        Position by cubic Hermite interpolation from the snapshots' positions and
        velocities (a 3 deg/s turn sampled at 1 Hz leaves under a metre, where linear
        interpolation leaves 1.5 m); velocity and flight level linearly."""
        aircraft = np.asarray(aircraft, dtype=np.int64)
        t = np.asarray(t, dtype=np.float64)
        if len(self.times) < 2:
            nan = np.full(np.broadcast(aircraft, t).shape, np.nan)
            return nan, nan, nan, nan, nan
        i, s, h, inside = self._bracket(t)
        ok = inside & (aircraft >= 0) & (aircraft < self.n_aircraft)
        a = np.where(ok, aircraft, 0)
        h00 = 2 * s**3 - 3 * s**2 + 1
        h10 = s**3 - 2 * s**2 + s
        h01 = -2 * s**3 + 3 * s**2
        h11 = s**3 - s**2

        def hermite(p: FloatArray, v: FloatArray) -> FloatArray:
            return np.asarray(
                h00 * p[i, a] + h10 * h * v[i, a] + h01 * p[i + 1, a] + h11 * h * v[i + 1, a]
            )

        def linear(v: FloatArray) -> FloatArray:
            return np.asarray((1 - s) * v[i, a] + s * v[i + 1, a])

        out = (
            hermite(self.x, self.vx),
            hermite(self.y, self.vy),
            linear(self.vx),
            linear(self.vy),
            linear(self.fl),
        )
        return tuple(np.where(ok, v, np.nan) for v in out)

    def nearest(self, t: FloatArray, x: FloatArray, y: FloatArray) -> tuple[IntArray, FloatArray]:
        """The nearest aircraft to each (t, x, y) and its distance (-1, inf when none)."""
        t = np.asarray(t, dtype=np.float64)
        n = t.shape[0]
        if n == 0 or self.n_aircraft == 0:
            return np.full(n, -1, dtype=np.int64), np.full(n, np.inf)
        every = np.arange(self.n_aircraft)
        tx, ty, *_ = self.at(every[None, :], t[:, None])
        distance = np.hypot(tx - np.asarray(x)[:, None], ty - np.asarray(y)[:, None])
        distance = np.where(np.isfinite(distance), distance, np.inf)
        best = np.argmin(distance, axis=1)
        d = distance[np.arange(n), best]
        return np.where(np.isfinite(d), best, -1).astype(np.int64), d


def truth_from_recording(recording: Recording, plane: SystemPlane) -> Truth:
    """``/truth/aircraft`` in the system plane (velocities turned and scaled by the
    plane's Jacobian at each point, so that they are d(x, y)/dt)."""
    times: list[float] = []
    rows: list[list[dict[str, Any]]] = []
    for snapshot in recording.messages("/truth/aircraft"):
        times.append(float(snapshot["time"]))
        rows.append(list(snapshot["aircraft"]))
    n_aircraft = 1 + max((int(a["index"]) for row in rows for a in row), default=-1)
    shape = (len(times), n_aircraft)
    names = ("lat", "lon", "h_msl_m", "fl", "vel_east_mps", "vel_north_mps", "vel_up_mps")
    values = {name: np.full(shape, np.nan) for name in names}
    for k, row in enumerate(rows):
        index = np.array([int(a["index"]) for a in row], dtype=np.int64)
        for name in names:
            values[name][k, index] = [float(a[name]) for a in row]
    lat, lon, h = values["lat"], values["lon"], values["h_msl_m"]
    known = np.isfinite(lat)
    x = np.full(shape, np.nan)
    y = np.full(shape, np.nan)
    vx = np.full(shape, np.nan)
    vy = np.full(shape, np.nan)
    if known.any():
        # h_msl is not the ellipsoidal height; only the tangent plane would care.
        e, n = plane.from_geodetic(lat[known], lon[known], h[known])
        x[known], y[known] = e, n
        jacobian = plane.jacobian(lat[known], lon[known], h[known])
        velocity = np.stack(
            [
                values["vel_east_mps"][known],
                values["vel_north_mps"][known],
                values["vel_up_mps"][known],
            ],
            axis=-1,
        )
        v = np.einsum("nij,nj->ni", jacobian, velocity)
        vx[known], vy[known] = v[:, 0], v[:, 1]
    return Truth(np.array(times), x, y, vx, vy, values["fl"])


# --- coverage --------------------------------------------------------------------------------


@dataclass(frozen=True)
class Coverage:
    """One radar's antenna scans: start times (S,), and the aircraft in coverage in each."""

    times: FloatArray
    aircraft: Sequence[frozenset[int]]
    period_s: float


def coverage_from_recording(
    recording: Recording, periods: Mapping[str, float]
) -> dict[str, Coverage]:
    scans: dict[str, dict[int, tuple[float, frozenset[int]]]] = {}
    if "/truth/coverage" in recording.topics:
        for message in recording.messages("/truth/coverage"):
            per = scans.setdefault(str(message["source"]), {})
            per[int(message["scan"])] = (float(message["time"]), frozenset(message["aircraft"]))
    out: dict[str, Coverage] = {}
    for source, per in scans.items():
        ordered = [per[k] for k in sorted(per)]
        out[source] = Coverage(
            np.array([t for t, _ in ordered]),
            [a for _, a in ordered],
            float(periods.get(source, 5.0)),
        )
    return out


# --- plot origins and association ------------------------------------------------------------


@dataclass(frozen=True)
class PlotOrigins:
    """Truth origin of every plot id of one radar: sorted ids, kind (KIND_*), aircraft."""

    plot_id: IntArray
    kind: npt.NDArray[np.int8]
    aircraft: IntArray

    @classmethod
    def from_plots(cls, plots: npt.NDArray[Any]) -> PlotOrigins:
        order = np.argsort(plots["plot_id"], kind="stable")
        return cls(
            np.asarray(plots["plot_id"][order], dtype=np.int64),
            np.asarray(plots["kind"][order], dtype=np.int8),
            np.asarray(plots["aircraft"][order], dtype=np.int64),
        )

    def labels(self, plot_ids: IntArray) -> IntArray:
        """Aircraft of each plot (detections and splits), FIELD_MONITOR, or NO_AIRCRAFT."""
        plot_ids = np.asarray(plot_ids, dtype=np.int64)
        out = np.full(plot_ids.shape, NO_AIRCRAFT, dtype=np.int64)
        if self.plot_id.size == 0:
            return out
        at = np.clip(np.searchsorted(self.plot_id, plot_ids), 0, self.plot_id.size - 1)
        found = self.plot_id[at] == plot_ids
        kind = self.kind[at]
        real = found & ((kind == KIND_AIRCRAFT) | (kind == KIND_SPLIT)) & (self.aircraft[at] >= 0)
        out[real] = self.aircraft[at][real]
        out[found & (kind == KIND_FIELD_MONITOR)] = FIELD_MONITOR
        return out


def associate_updates(
    updates: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    gate_m: float,
) -> IntArray:
    """The label of every update (rules 1 and 2 of the module docstring)."""
    n = len(updates)
    plot_id = np.asarray(updates["plot_id"], dtype=np.int64)
    has_plot = plot_id >= 0
    labels = np.full(n, NO_AIRCRAFT, dtype=np.int64)
    labels[has_plot] = origins.labels(plot_id[has_plot])
    fallback = np.flatnonzero(has_plot & (labels == NO_AIRCRAFT))
    if fallback.size:
        nearest, distance = truth.nearest(
            updates["time"][fallback], updates["x"][fallback], updates["y"][fallback]
        )
        labels[fallback] = np.where(distance <= gate_m, nearest, NO_AIRCRAFT)
    # Coasting rows inherit: walk each track's rows in order (rows come in time order).
    last: dict[int, int] = {}
    tracks = updates["track_number"].tolist()
    for row in range(n):
        number = tracks[row]
        if has_plot[row]:
            last[number] = int(labels[row])
        else:
            labels[row] = last.get(number, NO_AIRCRAFT)
    return labels


@dataclass(frozen=True)
class IdentityRun:
    track: int
    aircraft: int
    start: float
    end: float
    updates: int


def identity_runs(
    updates: npt.NDArray[Any], labels: IntArray, min_updates: int
) -> dict[int, list[IdentityRun]]:
    """Each track's kept identity runs (rule 3), over its updates from a plot."""
    runs: dict[int, list[IdentityRun]] = {}
    has_plot = updates["plot_id"] >= 0
    for number in np.unique(updates["track_number"]).tolist():
        rows = np.flatnonzero((updates["track_number"] == number) & has_plot)
        if rows.size == 0:
            continue
        lab = labels[rows]
        times = updates["time"][rows]
        cuts = np.flatnonzero(np.diff(lab)) + 1
        raw = []
        for a, b in zip(np.r_[0, cuts], np.r_[cuts, rows.size], strict=True):
            raw.append(
                IdentityRun(number, int(lab[a]), float(times[a]), float(times[b - 1]), int(b - a))
            )
        kept = [r for r in raw if r.updates >= min_updates] or [max(raw, key=lambda r: r.updates)]
        merged: list[IdentityRun] = []
        for r in kept:
            if merged and merged[-1].aircraft == r.aircraft:
                m = merged[-1]
                merged[-1] = IdentityRun(number, m.aircraft, m.start, r.end, m.updates + r.updates)
            else:
                merged.append(r)
        runs[number] = merged
    return runs


# --- metrics ---------------------------------------------------------------------------------


@dataclass
class UpdateErrors:
    """Per evaluated update (confirmed, from a plot, of an aircraft): for the report."""

    track: IntArray
    aircraft: IntArray
    time: FloatArray
    x: FloatArray
    y: FloatArray
    dx: FloatArray
    dy: FloatArray
    along: FloatArray
    across: FloatArray
    dv: FloatArray
    dfl_ft: FloatArray
    nees2: FloatArray
    nees4: FloatArray


@dataclass
class LocalMetrics:
    position_rms_m: float | None
    along_track_rms_m: float | None
    across_track_rms_m: float | None
    velocity_rms_mps: float | None
    probability_of_update: float | None
    tracks_per_aircraft: float | None
    id_changes: int
    false_tracks: int
    nees_mean: float | None
    nees_dof: int
    flight_level_rms_ft: float | None
    initiation_delay_s: float | None
    probability_of_update_with_initiation: float | None
    nees_state_mean: float | None
    nees_state_dof: int
    false_track_max_scans: float
    confirmed_tracks: int
    evaluated_updates: int
    position_p95_m: float | None = None
    position_max_m: float | None = None
    coasting_updates: int = 0
    coasting_position_rms_m: float | None = None
    position_rms_with_coasting_m: float | None = None
    position_p95_with_coasting_m: float | None = None
    position_max_with_coasting_m: float | None = None
    probability_of_update_10s: float | None = None
    update_interval_s: float | None = None
    errors: UpdateErrors | None = field(default=None, repr=False)

    def as_json(self) -> dict[str, Any]:
        doc = asdict(self)
        doc.pop("errors")
        return doc


@dataclass
class PlotMetrics:
    position_rms_m: float | None
    plots: int
    evaluated: int
    ranges_m: FloatArray | None = field(default=None, repr=False)
    errors_m: FloatArray | None = field(default=None, repr=False)

    def as_json(self) -> dict[str, Any]:
        return {
            "position_rms_m": self.position_rms_m,
            "plots": self.plots,
            "evaluated": self.evaluated,
        }


def _rms(values: FloatArray) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.sqrt(np.mean(values**2))) if values.size else None


def _percentile(values: FloatArray, q: float) -> float | None:
    values = values[np.isfinite(values)]
    return float(np.percentile(values, q)) if values.size else None


def _maximum(values: FloatArray) -> float | None:
    values = values[np.isfinite(values)]
    return float(values.max()) if values.size else None


def resampled(coverage: Coverage, period_s: float) -> Coverage:
    """``coverage`` over intervals of ``period_s`` from its first scan: an aircraft is in an
    interval when it is in the scan that holds the interval's middle (the rule of the
    system's intervals, ``system_metrics.system_coverage``)."""
    if not len(coverage.times):
        return Coverage(coverage.times, [], period_s)
    end = float(coverage.times[-1]) + coverage.period_s
    starts = np.arange(float(coverage.times[0]), end - period_s + 1e-9, period_s)
    scan = np.searchsorted(coverage.times, starts + period_s / 2, side="right") - 1
    inside = (scan >= 0) & (starts + period_s / 2 < coverage.times[scan] + coverage.period_s)
    empty: frozenset[int] = frozenset()
    sets = [coverage.aircraft[int(k)] if ok else empty for k, ok in zip(scan, inside, strict=True)]
    return Coverage(starts, sets, period_s)


def _time_average(times: FloatArray, values: FloatArray, period_s: float) -> float | None:
    ok = np.isfinite(values)
    if not ok.any():
        return None
    bins = np.floor((times[ok] - times[ok].min()) / period_s).astype(np.int64)
    sums = np.bincount(bins, weights=values[ok])
    counts = np.bincount(bins)
    used = counts > 0
    return float(np.mean(sums[used] / counts[used]))


def _nees(e: FloatArray, p: FloatArray) -> FloatArray:
    out = np.full(e.shape[0], np.nan)
    if e.shape[0] == 0:
        return out
    det = np.linalg.det(p)
    ok = np.all(np.isfinite(p), axis=(1, 2)) & np.isfinite(det) & (det > 0)
    ok &= np.all(np.isfinite(e), axis=1)
    if ok.any():
        solved = np.linalg.solve(p[ok], e[ok][:, :, None])[:, :, 0]
        out[ok] = np.einsum("ni,ni->n", e[ok], solved)
    return out


def _stretches(coverage: Coverage) -> dict[int, list[tuple[int, int]]]:
    """Per aircraft, its continuous stretches of coverage as [first scan, last scan]."""
    scans: dict[int, list[int]] = {}
    for k, inside in enumerate(coverage.aircraft):
        for a in inside:
            scans.setdefault(int(a), []).append(k)
    out: dict[int, list[tuple[int, int]]] = {}
    for a, ks in scans.items():
        spans: list[tuple[int, int]] = []
        for k in ks:
            if spans and spans[-1][1] == k - 1:
                spans[-1] = (spans[-1][0], k)
            else:
                spans.append((k, k))
        out[a] = spans
    return out


@dataclass(frozen=True)
class _TrackRuns:
    confirmed: set[int]
    runs: dict[int, list[IdentityRun]]


def _coverage_metrics(
    coverage: Coverage,
    cf_label: IntArray,
    cf_time: FloatArray,
    last: float,
    tracks_of: _TrackRuns,
) -> tuple[float | None, float | None, float | None, float | None]:
    """Probability of update (without and with initiation), tracks per aircraft and
    initiation delay over ``coverage``'s intervals, from the confirmed updates from a plot
    (labels and times)."""
    period = coverage.period_s
    scan_of = np.searchsorted(coverage.times, cf_time, side="right") - 1
    in_period = (scan_of >= 0) & (cf_time < coverage.times[np.maximum(scan_of, 0)] + period)
    hit = set(zip(cf_label[in_period].tolist(), scan_of[in_period].tolist(), strict=True))
    first_confirmed: dict[int, list[float]] = {}
    for lab, t in zip(cf_label.tolist(), cf_time.tolist(), strict=True):
        first_confirmed.setdefault(lab, []).append(t)
    complete = coverage.times + period <= last + 1e-9
    expected = updated = expected_all = updated_all = 0
    delays: list[float] = []
    counts: list[int] = []
    for aircraft, spans in _stretches(coverage).items():
        times_a = np.array(sorted(first_confirmed.get(aircraft, [])))
        for k0, k1 in spans:
            t0 = float(coverage.times[k0])
            t1 = float(coverage.times[k1]) + period
            in_stretch = times_a[(times_a >= t0) & (times_a < t1)]
            ks = [k for k in range(k0, k1 + 1) if complete[k]]
            got = [(aircraft, k) in hit for k in ks]
            expected_all += len(ks)
            updated_all += sum(got)
            if in_stretch.size == 0:
                expected += len(ks)
                continue
            start = float(in_stretch[0])
            delays.append(start - t0)
            after = [g for k, g in zip(ks, got, strict=True) if coverage.times[k] + period > start]
            expected += len(after)
            updated += sum(after)
            tracks = {
                r.track
                for number in tracks_of.confirmed
                for r in tracks_of.runs.get(number, [])
                if r.aircraft == aircraft and r.end >= t0 and r.start < t1
            }
            counts.append(max(len(tracks), 1))
    return (
        updated / expected if expected else None,
        updated_all / expected_all if expected_all else None,
        float(np.mean(counts)) if counts else None,
        float(np.mean(delays)) if delays else None,
    )


def local_metrics(
    updates: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    coverage: Coverage | None,
    *,
    gate_m: float = 1000.0,
    min_identity_updates: int = 2,
    end_time: float | None = None,
    evaluate_mask: BoolArray | None = None,
    update_interval_s: float | None = UPDATE_INTERVAL_S,
    fixed_interval_coverage: Coverage | None = None,
) -> LocalMetrics:
    """Every local-track metric of one radar (see the module docstring).
    ``evaluate_mask``: the rows whose errors count (all by default); the probability of
    update and the tracks per aircraft follow ``coverage`` alone.
    ``probability_of_update_10s`` is counted over ``fixed_interval_coverage``, by default
    ``coverage`` resampled to intervals of ``update_interval_s``."""
    period = coverage.period_s if coverage is not None else 5.0
    labels = associate_updates(updates, origins, truth, gate_m)
    status = updates["status"]
    fresh = updates["plot_id"] >= 0
    confirmed_fresh = (status == CONFIRMED) & fresh
    counted = confirmed_fresh & (labels >= 0)
    if evaluate_mask is not None:
        counted &= evaluate_mask
    evaluated = np.flatnonzero(counted)
    # Coasting updates (coasting, or confirmed without a fresh plot: the track's own
    # prediction, published all the same; system and local status numbers agree) keep the
    # label of their last plot; scored beside the plot updates.
    coasting = ((status == COASTING) | (status == CONFIRMED)) & ~fresh & (labels >= 0)
    if evaluate_mask is not None:
        coasting &= evaluate_mask
    coast = updates[coasting]
    cx, cy, *_ = truth.at(labels[coasting], coast["time"])
    coast_error = np.hypot(coast["x"] - cx, coast["y"] - cy)
    u = updates[evaluated]
    a = labels[evaluated]
    tx, ty, tvx, tvy, tfl = truth.at(a, u["time"])
    dx, dy = u["x"] - tx, u["y"] - ty
    dvx, dvy = u["vx"] - tvx, u["vy"] - tvy
    speed = np.hypot(tvx, tvy)
    with np.errstate(invalid="ignore", divide="ignore"):
        ux, uy = tvx / speed, tvy / speed
    along = dx * ux + dy * uy
    across = -dx * uy + dy * ux
    dfl = (u["flight_level"] - tfl) * FEET_PER_FL
    p = np.asarray(u["P"], dtype=np.float64).reshape(-1, 4, 4)
    e4 = np.stack([dx, dy, dvx, dvy], axis=-1)
    nees2 = _nees(e4[:, :2], p[:, :2, :2])
    nees4 = _nees(e4, p)
    errors = UpdateErrors(
        track=np.asarray(u["track_number"], dtype=np.int64),
        aircraft=a,
        time=np.asarray(u["time"], dtype=np.float64),
        x=np.asarray(u["x"], dtype=np.float64),
        y=np.asarray(u["y"], dtype=np.float64),
        dx=dx,
        dy=dy,
        along=along,
        across=across,
        dv=np.hypot(dvx, dvy),
        dfl_ft=dfl,
        nees2=nees2,
        nees4=nees4,
    )

    # Tracks: identities, false tracks.
    confirmed_numbers = set(updates["track_number"][status == CONFIRMED].tolist())
    runs = identity_runs(updates, labels, min_identity_updates)
    id_changes = 0
    for number in confirmed_numbers:
        kept = [r for r in runs.get(number, []) if r.aircraft >= 0]
        id_changes += sum(1 for r0, r1 in itertools.pairwise(kept) if r0.aircraft != r1.aircraft)
    false_tracks = 0
    false_max_scans = 0.0
    for number in confirmed_numbers:
        rows = np.flatnonzero((updates["track_number"] == number) & (status == CONFIRMED))
        lab = labels[rows]
        if np.count_nonzero(lab == NO_AIRCRAFT) * 2 > rows.size:
            false_tracks += 1
            life = (updates["time"][rows].max() - updates["time"][rows].min()) / period + 1.0
            false_max_scans = max(false_max_scans, float(life))

    # Coverage: probability of update, tracks per aircraft, initiation delay.
    pu = pu_all = tpa = delay = pu_fixed = None
    if coverage is not None and len(coverage.times):
        last = end_time if end_time is not None else float(np.max(updates["time"], initial=0.0))
        cf = np.flatnonzero(confirmed_fresh & (labels >= 0))
        cf_label = labels[cf]
        cf_time = np.asarray(updates["time"][cf], dtype=np.float64)
        tracks_of = _TrackRuns(confirmed_numbers, runs)
        pu, pu_all, tpa, delay = _coverage_metrics(coverage, cf_label, cf_time, last, tracks_of)
        fixed = fixed_interval_coverage
        if fixed is None and update_interval_s is not None:
            fixed = resampled(coverage, update_interval_s)
        if fixed is not None and len(fixed.times):
            pu_fixed = _coverage_metrics(fixed, cf_label, cf_time, last, tracks_of)[0]

    with_coasting = np.concatenate([np.hypot(dx, dy), coast_error])
    return LocalMetrics(
        position_rms_m=_rms(np.hypot(dx, dy)),
        along_track_rms_m=_rms(along),
        across_track_rms_m=_rms(across),
        velocity_rms_mps=_rms(np.hypot(dvx, dvy)),
        probability_of_update=pu,
        tracks_per_aircraft=tpa,
        id_changes=id_changes,
        false_tracks=false_tracks,
        nees_mean=_time_average(errors.time, nees2, period),
        nees_dof=2,
        flight_level_rms_ft=_rms(dfl),
        initiation_delay_s=delay,
        probability_of_update_with_initiation=pu_all,
        nees_state_mean=_time_average(errors.time, nees4, period),
        nees_state_dof=4,
        false_track_max_scans=false_max_scans,
        confirmed_tracks=len(confirmed_numbers),
        evaluated_updates=int(evaluated.size),
        position_p95_m=_percentile(np.hypot(dx, dy), 95.0),
        position_max_m=_maximum(np.hypot(dx, dy)),
        coasting_updates=int(np.count_nonzero(coasting)),
        coasting_position_rms_m=_rms(coast_error),
        position_rms_with_coasting_m=_rms(with_coasting),
        position_p95_with_coasting_m=_percentile(with_coasting, 95.0),
        position_max_with_coasting_m=_maximum(with_coasting),
        probability_of_update_10s=pu_fixed,
        update_interval_s=period if coverage is not None else None,
        errors=errors,
    )


def plot_metrics(
    plots: npt.NDArray[Any], truth: Truth, site_xy: tuple[float, float] | None = None
) -> PlotMetrics:
    """Raw plot accuracy: each detection of an aircraft (kind ``aircraft``: not splits,
    reflections or clutter) against its aircraft's truth at the true detection time."""
    real = (plots["kind"] == KIND_AIRCRAFT) & (plots["aircraft"] >= 0)
    sel = plots[real]
    t = np.where(np.isfinite(sel["detection_time"]), sel["detection_time"], sel["time"])
    tx, ty, *_ = truth.at(np.asarray(sel["aircraft"], dtype=np.int64), t)
    error = np.hypot(sel["x"] - tx, sel["y"] - ty)
    ranges = None
    if site_xy is not None:
        ranges = np.hypot(tx - site_xy[0], ty - site_xy[1])
    return PlotMetrics(
        position_rms_m=_rms(error),
        plots=len(plots),
        evaluated=int(np.count_nonzero(np.isfinite(error))),
        ranges_m=ranges,
        errors_m=error,
    )


def summary_keys() -> Iterable[str]:
    """The keys of each "local" object that other tools rely on (issue 4)."""
    return (
        "position_rms_m",
        "along_track_rms_m",
        "across_track_rms_m",
        "velocity_rms_mps",
        "probability_of_update",
        "tracks_per_aircraft",
        "id_changes",
        "false_tracks",
        "nees_mean",
        "nees_dof",
    )
