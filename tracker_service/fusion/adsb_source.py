"""ADS-B (CAT021) as a surveillance source of the fuser (``[fusion] adsb = "fuse"``).

ADS-B is one source of the fuser beside the radars (the index after theirs), whatever
the number of ground stations: a squitter heard by two stations carries one GNSS error,
so it must be fused once, and a per-address track across stations is what tells a copy
(same address, time of applicability no newer than the address's latest) from news.
Its "local tracks" are light: one constant-velocity Kalman filter per 24-bit address,
fed the report's position and GNSS velocity (I021/160) with their covariance from the
quality indicators (``tracker_service.adsb.position_sigma_m``), confirmed at its second
report, deleted after ``MAX_SILENCE_S`` without one. They pass the fuser's interface
as a radar's local tracks do (``track_update_dtype`` rows and ``PLOT_DTYPE`` plots), so
association, track life and the "plots" estimator are the radars': an ADS-B-only aircraft
founds its system track as a radar's local track would, and ADS-B has no bias (its
residual-bias covariance is 0: never bias-estimated).

Latency: a report is stamped with its time of applicability, which lies up to a report
interval plus the ground latency in the past. A report older than the system track it
updates would move that track back in time; it is moved forward instead, to the track's
time, along its own GNSS velocity, its covariance grown by the velocity's error and a
manoeuvre over the step (at most a second or two: the velocity error of a few tenths of
a m/s adds centimetres). The correction uses only the report's own data, so no
information is counted twice; the system track never steps back.

Double use with the bias estimator: ADS-B stays the absolute reference of the radars'
biases, and a report used as a reference is not fused. Per address, while a radar tracks
that address (a report could then be some radar plot's reference), successive new
reports alternate between the two roles: one fused, the next kept as the reference
(``ReportUse.REFERENCE``). Each report thus enters either the bias estimate or a system
track, never both. Where no radar tracks the address every report is fused. The bias
estimator's relative references (other radars' fused tracks) leave the ADS-B source out
(``SystemTracker.references(..., sources=radars)``) for the same reason.

Consistency: each confirmed radar local-track update from a plot with a Mode S address
is compared with the ADS-B position of that address at the update's own time (the
nearest report within ``MAX_GAP_S``, moved along its velocity: ``check_radar``), with the
local track's covariance, its radar's residual bias and the report's own: a chi-square
distance beyond ``INCONSISTENCY_GATE`` is a disagreement (a spoofed or faulty position,
or a wrong address). Compared at the radar's time, a turn costs nothing (a radar track
predicted to the report's time would lag hundreds of metres behind a turning aircraft
after a 10 s scan). From a disagreement on, the address's reports are not fused;
``FLAG_AFTER`` disagreements in a row flag it: its ADS-B track leaves fusion and every
system track carrying the address is flagged (``adsb_inconsistent``, I062/080 AFF)
until ``CLEAR_AFTER`` radar updates in a row agree again.

Checked before fused: an address's first reports inside radar cover could be a spoofer's
(or a wrong address's), and a system track founded on them is a false target on the
controller's display before any radar comparison (adsb_cover's spoofer founded one). So a
new ADS-B track feeds the fuser only once it is cleared: a radar update of its address
has agreed with it, or no radar can see it (``cover``, the radars' cover learnt from
their plots: no radar plot near it, once every radar has swept a full antenna period),
or ``CHECK_TIMEOUT_PERIODS`` of the slowest radar's antenna period have gone by without a
comparison (a radar that sees it without its address, or not at all). Until then its
reports are filtered (its track is ready when cleared) but not fused
(``ReportUse.UNCHECKED``). Outside radar cover, after the radars' first sweep, a report
is cleared at once.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.adsb import AdsbReports
from tracker_service.fusion.cover import RadarCover
from tracker_service.fusion.tracker import SystemTracker
from tracker_service.tracking.models import cv_transition
from tracker_service.tracking.plots import PLOT_DTYPE, FloatArray, IntArray
from tracker_service.tracking.tracker import CONFIRMED, DELETED, TENTATIVE, track_update_dtype

__all__ = [
    "ADSB_MODES",
    "AdsbFusionStats",
    "AdsbSource",
    "AdsbStep",
    "ReportUse",
    "moved_forward",
]

ADSB_MODES = ("fuse", "reference", "off")
"""``[fusion] adsb``: fused and the bias reference; the bias reference only; unused."""

ADSB_Q = 16.0
"""White-acceleration intensity (m^2/s^3) of the per-address filter, fed the GNSS
velocity every second. Measured on adsb_cover seed 1 (ADS-B-only aircraft, two of them
turning at 2 deg/s): q = 4 gave RMS 7.7 m and NEES 2.50 (dof 2: over-confident in the
turns), q = 16 RMS 7.4 m and NEES 1.79."""
VELOCITY_VARIANCE_FLOOR = 25.0
"""The velocity variance (m^2/s^2 per axis) at least of an ADS-B track as the fuser gets
it. The system track's IMM is fed positions only and lags a turn's velocity by several
m/s; against a GNSS velocity known to a few tenths, the fuser's 4-dof review cut ADS-B
tracks from their system tracks in turns (adsb_cover seed 4: 1.4 system tracks per
ADS-B-only aircraft). Position variance is left as it is (the position NEES stays
honest); the velocity's errs on the safe side."""
MANOEUVRE_M_S2 = 2.0
"""The acceleration a report moved forward along its velocity may have missed."""
MAX_SILENCE_S = 10.0
"""An address silent this long loses its ADS-B track (ten report intervals)."""
INCONSISTENCY_GATE = 18.47
"""Chi-square (2 dof) beyond which a report disagrees with the radars (the fuser's own
4-dof gate value: on a 2-dof test a false alarm per report of 1e-4)."""
FLAG_AFTER = 3
CLEAR_AFTER = 3
MAX_GAP_S = 1.5
"""A radar update is compared with a report at most this far from it in time."""
CHECK_TIMEOUT_PERIODS = 4.0
"""An ADS-B track inside radar cover that no radar update has been compared with for this
many antenna periods of the slowest radar is fused anyway: a radar's local track needs
a few scans to be confirmed (adsb_cover: the first comparisons 10-25 s in, 10 s
period)."""
COVER_CELL_M = 10_000.0
"""Cells of the radars' cover (``fusion.cover``): a spoofed position 2 NM off its
aircraft lies in the cell of the aircraft's radar plots or a neighbouring one."""
COVER_MEMORY_S = 300.0


class ReportUse(IntEnum):
    FUSED = 0
    REFERENCE = 1
    REPEATED = 2
    INCONSISTENT = 3
    UNCHECKED = 4
    """Inside radar cover and not yet compared with a radar (module docstring)."""


@dataclass
class AdsbFusionStats:
    """Running counts since start; ``flagged``: the addresses flagged now."""

    reports: int = 0
    fused: int = 0
    references: int = 0
    repeated: int = 0
    inconsistent: int = 0
    unchecked: int = 0
    """Reports not fused because their track had not been checked against a radar."""
    disagreements: int = 0
    """Radar local-track updates that disagreed with their address's ADS-B."""
    moved_forward: int = 0
    flags_raised: int = 0
    flagged: set[int] = field(default_factory=set)


@dataclass
class _Track:
    number: int
    t: float
    x: FloatArray
    P: FloatArray
    last_seen: float
    reports: int = 0
    fed: bool = False
    """Known to the fuser under ``number`` (it needs a deletion when it leaves)."""
    parity: int = 0
    fails: int = 0
    passes: int = 0
    fl: float = np.nan
    mode3a: int = -1
    first_report: float = np.nan
    cleared: bool = False
    """Checked against the radars, or out of their sight (module docstring)."""
    history: deque[tuple[float, float, float, float, float, float, float]] = field(
        default_factory=lambda: deque(maxlen=4)
    )
    """The latest reports (t, x, y, vx, vy, sigma, sigma_v), whatever became of them."""


@dataclass(frozen=True)
class AdsbStep:
    """One batch for the fuser: local-track rows (``track_update_dtype``), plots
    (``PLOT_DTYPE``), and what became of each report (``ReportUse``, in ``reports``
    order) with the plot id of the fused ones (-1 otherwise)."""

    updates: npt.NDArray[Any]
    plots: npt.NDArray[Any]
    use: npt.NDArray[np.int8]
    plot_id: IntArray
    reference: npt.NDArray[np.bool_]


def moved_forward(
    x: FloatArray,
    y: FloatArray,
    vx: FloatArray,
    vy: FloatArray,
    R: FloatArray,
    sigma_v: FloatArray,
    dt: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Report positions moved ``dt`` >= 0 along their own velocity, and their covariance
    grown by the velocity's error and a manoeuvre of ``MANOEUVRE_M_S2`` over dt."""
    return x + vx * dt, y + vy * dt, R + _growth(sigma_v, dt)[..., None, None] * np.eye(2)


def _growth(sigma_v: Any, dt: Any) -> Any:
    """The variance per axis a report moved by dt gains: its velocity's error and a
    manoeuvre of ``MANOEUVRE_M_S2``."""
    return (sigma_v * dt) ** 2 + (0.5 * MANOEUVRE_M_S2 * dt * dt) ** 2


class AdsbSource:
    """See the module docstring. ``index``: the fuser's source number of ADS-B (after
    the radars, which are ``0..index-1``); ``share_reference``: alternate the roles of an
    address's reports (``[fusion] adsb = "fuse"`` with bias estimation);
    ``radar_periods``: per radar index, its antenna period (s); without radars every
    track is cleared at once. The central stage feeds ``cover`` every radar's plots."""

    def __init__(
        self,
        fuser: SystemTracker,
        index: int,
        share_reference: bool,
        radar_periods: dict[int, float] | None = None,
    ) -> None:
        self.fuser = fuser
        self.index = index
        self.share_reference = share_reference
        self.radar_periods = radar_periods or {}
        self.check_timeout_s = CHECK_TIMEOUT_PERIODS * max(self.radar_periods.values(), default=0.0)
        self.cover = RadarCover(COVER_CELL_M, COVER_MEMORY_S)
        self.stats = AdsbFusionStats()
        self._tracks: dict[int, _Track] = {}
        self._next_number = 1
        self._next_plot_id = 0
        self._dtype = track_update_dtype(fuser.models.n_models)

    def step(self, reports: AdsbReports, first_plot_id: int) -> AdsbStep:
        """One datagram's reports (``tracker_service.adsb.decode_reports``): their fate
        and the fuser's batch; fused reports get plot ids from ``first_plot_id`` on."""
        n = len(reports)
        self.stats.reports += n
        use = np.full(n, ReportUse.REPEATED, dtype=np.int8)
        plot_id = np.full(n, -1, dtype=np.int64)
        order = np.argsort(reports.time, kind="stable")
        tracked = self._radar_tracked()
        candidates: list[int] = []
        for k in order.tolist():
            address, t = int(reports.address[k]), float(reports.time[k])
            track = self._tracks.get(address)
            if track is not None and t <= track.last_seen:
                continue
            if track is None:
                track = self._tracks[address] = self._new_track(reports, k)
            track.last_seen = t
            track.history.append(
                (
                    t,
                    float(reports.x[k]),
                    float(reports.y[k]),
                    float(reports.vx[k]),
                    float(reports.vy[k]),
                    float(reports.sigma[k]),
                    float(reports.sigma_v[k]),
                )
            )
            track.parity ^= 1
            if self.share_reference and address in tracked and track.parity == 0:
                use[k] = ReportUse.REFERENCE
                continue
            candidates.append(k)
        self.stats.repeated += int(np.count_nonzero(use == ReportUse.REPEATED))
        self.stats.references += int(np.count_nonzero(use == ReportUse.REFERENCE))
        updates, plots = [], []
        next_id = first_plot_id
        for k in candidates:
            address = int(reports.address[k])
            track = self._tracks[address]
            if track.fails or address in self.stats.flagged:
                use[k] = ReportUse.INCONSISTENT
                self.stats.inconsistent += 1
                if track.fed and address in self.stats.flagged:
                    updates.append(self._deletion(track))
                continue
            if not self._cleared(track, reports, k):
                use[k] = ReportUse.UNCHECKED
                self.stats.unchecked += 1
                self._filter(track, reports, k)
                continue
            use[k] = ReportUse.FUSED
            plot_id[k] = next_id
            next_id += 1
            update, plot = self._fuse(track, reports, k, int(plot_id[k]))
            updates.append(update)
            plots.append(plot)
        self.stats.fused += len(plots)
        updates += self._silent(float(reports.time.max()) if n else -np.inf)
        return AdsbStep(
            np.array(updates, dtype=self._dtype),
            np.array(plots, dtype=PLOT_DTYPE),
            use,
            plot_id,
            use == ReportUse.REFERENCE,
        )

    def _new_track(self, reports: AdsbReports, k: int) -> _Track:
        sigma, sigma_v = float(reports.sigma[k]), float(reports.sigma_v[k])
        track = _Track(
            number=self._next_number,
            t=float(reports.time[k]),
            x=np.array(
                [reports.x[k], reports.y[k], reports.vx[k], reports.vy[k]], dtype=np.float64
            ),
            P=np.diag([sigma**2, sigma**2, sigma_v**2, sigma_v**2]),
            last_seen=-np.inf,
        )
        self._next_number += 1
        return track

    def _cleared(self, track: _Track, reports: AdsbReports, k: int) -> bool:
        """Whether the track may feed the fuser (module docstring: checked before fused)."""
        if not track.cleared:
            t = float(reports.time[k])
            if not np.isfinite(track.first_report):
                track.first_report = t
            track.cleared = (
                track.passes > 0
                or t - track.first_report >= self.check_timeout_s
                or (
                    self.cover.known(self.radar_periods, t)
                    and not self.cover.covered(reports.x[k : k + 1], reports.y[k : k + 1], t)[0]
                )
            )
        return track.cleared

    def _radar_tracked(self) -> set[int]:
        """The addresses of the fuser's live, confirmed radar local tracks."""
        loc = self.fuser.state.local.used
        rows = (
            loc["alive"]
            & (loc["radar"] < self.index)
            & (loc["address"] >= 0)
            & (loc["status"] != TENTATIVE)
        )
        return set(loc["address"][rows].tolist())

    def check_radar(self, updates: npt.NDArray[Any], extra: FloatArray | None) -> int:
        """Compare a radar batch's confirmed local-track updates from a plot (bias-
        corrected, ``extra`` their residual-bias covariance) with the ADS-B position of
        their address at their time (module docstring); returns the disagreements."""
        use = np.flatnonzero(
            (updates["plot_id"] >= 0) & (updates["status"] == CONFIRMED) & (updates["address"] >= 0)
        )
        disagreements = 0
        for k in use.tolist():
            address = int(updates["address"][k])
            track = self._tracks.get(address)
            if track is None or not track.history:
                continue
            t = float(updates["time"][k])
            t0, x0, y0, vx, vy, sigma, sigma_v = min(track.history, key=lambda r: abs(r[0] - t))
            dt = t - t0
            if abs(dt) > MAX_GAP_S:
                continue
            position = np.array([x0 + vx * dt, y0 + vy * dt])
            r = np.eye(2) * (sigma**2 + _growth(sigma_v, abs(dt)))
            p = np.asarray(updates["P"][k], dtype=np.float64).reshape(4, 4)[:2, :2]
            s = p + r + (extra[k] if extra is not None else 0.0)
            d = np.array([updates["x"][k], updates["y"][k]]) - position
            d2 = float(d @ np.linalg.solve(s, d))
            disagreements += int(not self._judge(track, address, d2))
        return disagreements

    def _judge(self, track: _Track, address: int, d2: float) -> bool:
        """Count a radar comparison of the address; True when it agrees."""
        stats = self.stats
        if d2 > INCONSISTENCY_GATE:
            track.fails, track.passes = track.fails + 1, 0
            stats.disagreements += 1
            if track.fails >= FLAG_AFTER and address not in stats.flagged:
                stats.flagged.add(address)
                stats.flags_raised += 1
            return False
        track.fails = 0
        track.passes += 1
        if address in stats.flagged and track.passes >= CLEAR_AFTER:
            stats.flagged.discard(address)
        return True

    def _deletion(self, track: _Track) -> Any:
        """The fuser's row that takes the track out of fusion; it comes back under a
        new number."""
        row = np.zeros((), dtype=self._dtype)
        row["track_number"] = track.number
        row["time"] = self._now()
        row["status"] = DELETED
        row["plot_id"] = -1
        row["address"] = -1
        row["mode3a"] = -1
        row["flight_level"] = np.nan
        row["climb_rate_fl_per_s"] = np.nan
        track.fed = False
        track.number = self._next_number
        self._next_number += 1
        track.reports = 0
        return row

    def _now(self) -> float:
        now = self.fuser.clock.now
        return float(now) if np.isfinite(now) else 0.0

    def _filter(self, track: _Track, reports: AdsbReports, k: int) -> None:
        """The address's filter updated with report k."""
        t = float(reports.time[k])
        sigma, sigma_v = float(reports.sigma[k]), float(reports.sigma_v[k])
        z = np.array([reports.x[k], reports.y[k], reports.vx[k], reports.vy[k]])
        r = np.diag([sigma**2, sigma**2, sigma_v**2, sigma_v**2])
        if track.reports:
            x, p = _predicted(track.x, track.P, t - track.t)
            gain = p @ np.linalg.inv(p + r)
            x = x + gain @ (z - x)
            identity = np.eye(4) - gain
            p = identity @ p @ identity.T + gain @ r @ gain.T
        else:
            x, p = z, r
        track.x, track.P, track.t = x, p, t
        track.reports += 1
        if np.isfinite(reports.flight_level[k]):
            track.fl = float(reports.flight_level[k])
        if reports.mode3a[k] >= 0:
            track.mode3a = int(reports.mode3a[k])

    def _fuse(self, track: _Track, reports: AdsbReports, k: int, plot_id: int) -> tuple[Any, Any]:
        """Report k filtered, as the fuser's local-track update and plot."""
        self._filter(track, reports, k)
        t, x, p = track.t, track.x, track.P
        sigma = float(reports.sigma[k])
        # Never behind the system track it updates (module docstring: latency).
        ahead = max(self._system_time(track, int(reports.address[k])) - t, 0.0)
        if ahead > 0.0:
            self.stats.moved_forward += 1
        x_out, p_out = _predicted(x, p, ahead) if ahead > 0.0 else (x, p)
        update = np.zeros((), dtype=self._dtype)
        update["track_number"] = track.number
        update["time"] = t + ahead
        update["x"], update["y"], update["vx"], update["vy"] = x_out
        p_out = p_out.copy()
        for axis in (2, 3):
            p_out[axis, axis] = max(p_out[axis, axis], VELOCITY_VARIANCE_FLOOR)
        update["P"] = p_out.reshape(16)
        update["flight_level"] = track.fl
        update["climb_rate_fl_per_s"] = np.nan
        update["status"] = CONFIRMED if track.reports >= 2 else TENTATIVE
        update["plot_id"] = plot_id
        update["mode3a"] = track.mode3a
        update["address"] = int(reports.address[k])
        track.fed = True
        plot = _blank_plot()
        px, py, pr = moved_forward(
            reports.x[k : k + 1],
            reports.y[k : k + 1],
            reports.vx[k : k + 1],
            reports.vy[k : k + 1],
            np.eye(2)[None] * sigma**2,
            reports.sigma_v[k : k + 1],
            np.array([ahead]),
        )
        plot["time"] = t + ahead
        plot["x"], plot["y"], plot["R"] = px[0], py[0], pr[0]
        plot["flight_level"] = track.fl
        plot["fl_valid"] = bool(np.isfinite(track.fl))
        plot["mode3a"] = track.mode3a
        plot["mode3a_valid"] = track.mode3a >= 0
        plot["address"] = int(reports.address[k])
        plot["typ"] = -1
        plot["plot_id"] = plot_id
        return update, plot

    def _system_time(self, track: _Track, address: int) -> float:
        """The time of the system track the report will update: the one its ADS-B track
        feeds, else the live ones carrying its address (which it will most likely join)."""
        state = self.fuser.state
        sys = state.sys
        if track.fed:
            key = np.zeros(1, dtype=[("track_number", np.int64), ("status", np.int8)])
            key["track_number"] = track.number
            row = state.local.find(self.index, key, create=False)[0]
            number = int(state.local.rows["system"][row]) if row >= 0 else 0
            if number > 0 and sys["alive"][number]:
                return float(sys["t"][number])
        carrying = sys["alive"] & (sys["address"] == address)
        carrying[0] = False
        return float(sys["t"][carrying].max()) if carrying.any() else -np.inf

    def _silent(self, now: float) -> list[Any]:
        """Deletions of the tracks silent for ``MAX_SILENCE_S``."""
        out = []
        for address in [a for a, t in self._tracks.items() if now - t.last_seen > MAX_SILENCE_S]:
            track = self._tracks.pop(address)
            if track.fed:
                out.append(self._deletion(track))
            self.stats.flagged.discard(address)
        return out


def _predicted(x: FloatArray, p: FloatArray, dt: float) -> tuple[FloatArray, FloatArray]:
    f = cv_transition(np.array([dt]))[0]
    q = ADSB_Q * np.array(
        [
            [dt**3 / 3, 0.0, dt**2 / 2, 0.0],
            [0.0, dt**3 / 3, 0.0, dt**2 / 2],
            [dt**2 / 2, 0.0, dt, 0.0],
            [0.0, dt**2 / 2, 0.0, dt],
        ]
    )
    return f @ x, f @ p @ f.T + q


def _blank_plot() -> Any:
    """A plot row with every measurement absent (NaN floats): columns a radar plot may
    carry and a report does not (Mode S DAPs, say) stay absent."""
    plot = np.zeros((), dtype=PLOT_DTYPE)
    for name in PLOT_DTYPE.names or ():
        if PLOT_DTYPE[name].kind == "f" and PLOT_DTYPE[name].shape == ():
            plot[name] = np.nan
    return plot
