"""The height of aircraft without one (primary-only), estimated centrally, and the
re-projection of their plots and local tracks with it.

A plot without a usable height comes from the radar stage at the equivalent height of its
radar's band (``geodesy.unknown_height``) with the height Jacobian J = d(x, y)/dH of its
plane position. Its error from the unknown height is one per aircraft and radar, along
that radar's line of sight: white noise it is not. Here, per system track:

- the height H (m above MSL) is a scalar random walk (``PsrHeightConfig.q_m2_per_s``:
  level changes) with prior the band's mean and variance (uniform);
- a plot of radar i whose system track other radars also see (the fuser's references:
  their local tracks predicted to the plot's time, ``fusion.references``) measures it:
  re-projected at the current estimate, the plot lies off the others' prediction by
  y = (J_o - J_i)(H - H_hat) + noise, J_o the others' height Jacobian (0 for a radar
  that has the height from Mode C). Slant ranges from different sites agree in the
  horizontal only at the right height; a single radar leaves H where the prior put it;
- once the height is measured, or the aircraft is in another radar's primary cover
  (``fusion.cover``: that radar's local track may have to join), every plot and local
  update of the system track is re-projected exactly at H_hat
  (``convert_plots`` from its slant range and azimuth), its covariance becomes the
  measurement noise alone, and J J^T var(H) goes to the fuser as the error common to
  that radar's plots of the aircraft (the ``extra`` consider term the residual biases
  use: fusion/consider.py), which the association gate and the system covariance carry.

A local track's update moves with its plot (the same shift); a coasting one with its
last plot's Jacobian. The re-projection happens before fusion, after the bias
correction: the two are first order in different parameters and add.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.cover import PSR_TYPES, RadarCover
from tracker_service.fusion.references import References
from tracker_service.geodesy import RadarSite, SystemPlane
from tracker_service.geodesy.compiled import convert_plots_compiled
from tracker_service.geodesy.unknown_height import JACOBIAN_STEP_M, HeightBand, feasible_band
from tracker_service.tracking.plots import FloatArray, IntArray
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED

SHIFT_RATE_SMOOTHING = 0.5
"""Weight of the newest plot pair in the shift's rate (plot noise moves the shift)."""

__all__ = ["PsrHeightConfig", "PsrHeights", "RadarGeometry", "SystemHeight"]


@dataclass(frozen=True)
class PsrHeightConfig:
    q_m2_per_s: float = 200.0
    """Random-walk intensity of the height: 110 m of drift a minute (a slow climb)."""
    gate: float = 13.82
    """Chi-square (2 dof, 99.9 %) on a plot's residual to the others' prediction: beyond
    it the pair is not one aircraft at any height, and the plot does not measure it."""
    jacobian_age_s: float = 60.0
    """Another radar's height Jacobian of the aircraft older than this is not used."""
    cover_cell_m: float = 10_000.0
    """Side of the cells of the radars' primary cover (``fusion.cover``): a primary plot's
    position is kilometres uncertain near the radar, and a neighbouring cell counts too."""
    cover_memory_s: float = 300.0
    """A radar's PSR plots older than this no longer say it covers their cell (a radar
    that went down covers nothing)."""
    stale_s: float = 120.0
    """A system track's height untouched for this long belongs to a track that ended
    (a live one has a plot within the fuser's silence, 3 x the longest period): a new
    track under its reused number (after ``number_reuse_delay_s``, 300 s) starts afresh.
    A number reused early (no number past its delay idle: the one ended longest ago is
    taken) would inherit its last aircraft's height if that ended less than this ago:
    only with over 8,191 less the live tracks ending within it."""


def _applies(entry: SystemHeight) -> bool:
    """Whether a system track's plots are re-projected at its height estimate with the
    estimate's uncertainty as a consider term: once another radar has measured the height,
    or once the aircraft was in another radar's primary cover (that radar's local track,
    off by its own height error, has to join: the consider term is what holds the gap).
    A lone radar's aircraft is left alone: its local tracker took the band as white noise
    in R, and a system track that takes it as one common error instead (noise-only R)
    is a different filter of the same plots; by the algebra (not traced plot by plot) it
    drifts off that local track and the fuser's review cuts them apart (canalA: 41
    breaks against 24)."""
    return entry.measurements > 0 or entry.shared


@dataclass(frozen=True)
class RadarGeometry:
    """What the re-projection needs of one radar: its site, band and plot sigmas."""

    site: RadarSite
    band: HeightBand
    sigma_range_m: float
    sigma_azimuth_deg: float
    psr_sigma_range_m: float
    psr_sigma_azimuth_deg: float


@dataclass
class SystemHeight:
    height_m: float
    variance_m2: float
    time: float
    measurements: int = 0
    shared: bool = False
    """A plot of the aircraft lay in another radar's primary cover: from then on its
    plots are re-projected at the estimate, with its uncertainty as a consider term, so
    that the other radar's local track can join the system track (``PsrHeights``)."""
    jacobians: dict[int, tuple[FloatArray, float]] = field(default_factory=dict)
    """Per radar, its latest height Jacobian of this aircraft and when."""


@dataclass(frozen=True)
class Reprojection:
    """A batch's tracked plots and local updates re-projected at their system tracks'
    heights, and the consider covariance (n_local, 2, 2) of each local update."""

    tracked: npt.NDArray[Any]
    local: npt.NDArray[Any]
    extra: FloatArray


class PsrHeights:
    """See the module docstring. ``radars``: per radar index, its geometry."""

    def __init__(
        self,
        radars: dict[int, RadarGeometry],
        plane: SystemPlane,
        config: PsrHeightConfig | None = None,
    ) -> None:
        self.radars = radars
        self.plane = plane
        self.config = config or PsrHeightConfig()
        self.systems: dict[int, SystemHeight] = {}
        self._last_plot: dict[tuple[int, int], tuple[FloatArray, float, int]] = {}
        """Per (radar, local track number): its last plot's J, height used, system."""
        self._previous: dict[tuple[int, int], tuple[tuple[float, ...], tuple[float, ...]]] = {}
        """Per (radar, local track number): its last plot (``_PREVIOUS_FIELDS``) and the
        rate of its shift (m/s, smoothed)."""
        self.cover = RadarCover(self.config.cover_cell_m, self.config.cover_memory_s, PSR_TYPES)
        """The radars' primary cover, from their tracked plots (not clutter)."""
        self.measurements = 0
        self.rejected = 0

    def estimate(self, system_number: int) -> tuple[float, float] | None:
        """(height m above MSL, sigma m) of a system track's aircraft, if estimated from
        several radars; None otherwise."""
        entry = self.systems.get(system_number)
        if entry is None or entry.measurements == 0:
            return None
        return entry.height_m, float(np.sqrt(entry.variance_m2))

    def _system(self, number: int, radar: int, time: float) -> SystemHeight:
        entry = self.systems.get(number)
        band = self.radars[radar].band
        prior = (band.max_m - band.min_m) ** 2 / 12.0
        if entry is None or time - entry.time > self.config.stale_s:
            entry = SystemHeight(0.5 * (band.min_m + band.max_m), prior, time)
            self.systems[number] = entry
        elif time > entry.time:
            entry.variance_m2 = min(
                entry.variance_m2 + self.config.q_m2_per_s * (time - entry.time), prior
            )
            entry.time = time
        return entry

    def _convert(
        self, radar: int, parts: Sequence[_Slant]
    ) -> list[tuple[FloatArray, FloatArray, FloatArray]]:
        """Per part (``_Slant``: plots, their heights, whether J is wanted): plane xy (n, 2),
        noise-only R (n, 2, 2) and J (n, 2; ``height_jacobian``'s forward difference, zeros
        unless wanted) of the rows at the given heights, clipped to what each slant range
        allows. All parts and the Jacobians' stepped heights in one conversion: a batch
        has a few dozen such plots, where a conversion's calls cost more than its
        arithmetic (which is row by row: the same numbers as one call per part), and in
        compiled passes (``geodesy.compiled``: the same numbers as ``convert_plots``)."""
        g = self.radars[radar]
        rho = np.concatenate([part.rho_m for part in parts])
        theta = np.concatenate([part.theta_deg for part in parts])
        psr = np.concatenate([part.typ == 1 for part in parts])
        low, high = feasible_band(g.site, rho, g.band)
        height = np.clip(np.concatenate([part.height_m for part in parts]), low, high)
        stepped = np.flatnonzero(
            np.concatenate([np.full(len(part.rho_m), part.jacobian) for part in parts])
        )
        sigma_range = np.where(psr, g.psr_sigma_range_m, g.sigma_range_m)
        sigma_azimuth = np.where(psr, g.psr_sigma_azimuth_deg, g.sigma_azimuth_deg)
        n = rho.size
        converted, _ = convert_plots_compiled(
            g.site,
            self.plane,
            np.concatenate([rho, rho[stepped]]),
            np.concatenate([theta, theta[stepped]]),
            np.concatenate([height, height[stepped] + JACOBIAN_STEP_M]),
            np.zeros(n + stepped.size),
            np.concatenate([sigma_range, sigma_range[stepped]]),
            np.concatenate([sigma_azimuth, sigma_azimuth[stepped]]),
        )
        x, y = converted.x[:n], converted.y[:n]
        j = np.zeros((n, 2))
        j[stepped] = (
            np.column_stack([converted.x[n:] - x[stepped], converted.y[n:] - y[stepped]])
            / JACOBIAN_STEP_M
        )
        xy = np.column_stack([x, y])
        out = []
        start = 0
        for part in parts:
            end = start + len(part.rho_m)
            out.append((xy[start:end], converted.R[start:end], j[start:end]))
            start = end
        return out

    def observe(
        self,
        radar: int,
        table: npt.NDArray[Any],
        tracked: npt.NDArray[Any],
        refs: References,
    ) -> None:
        """Measure the heights of the system tracks of this batch's plots without a
        height that other radars' tracks see (module docstring). ``tracked``: the
        batch's tracked plots, bias-corrected (the references are)."""
        if radar not in self.radars or not len(table):
            return
        first_id = int(table["plot_id"][0])
        row = refs.plot_id - first_id
        usable = refs.others_valid & (refs.system_number > 0)
        usable &= ~table["height_known"][row]
        picked = np.flatnonzero(usable)
        if not picked.size:
            return
        plots = table[row[picked]]
        entries = [
            self._system(int(refs.system_number[k]), radar, float(t))
            for k, t in zip(picked.tolist(), plots["time"].tolist(), strict=True)
        ]
        [(xy, r, j)] = self._convert(
            radar, [_Slant.of(plots, np.array([e.height_m for e in entries]), True)]
        )
        # The bias correction the central stage applied to each plot.
        at = np.searchsorted(tracked["plot_id"], plots["plot_id"])
        at = np.minimum(at, max(len(tracked) - 1, 0))
        found = len(tracked) > 0
        if found:
            same = tracked["plot_id"][at] == plots["plot_id"]
            xy[same, 0] += tracked["x"][at[same]] - plots["x"][same]
            xy[same, 1] += tracked["y"][at[same]] - plots["y"][same]
        band = self.radars[radar].band
        for n, k in enumerate(picked.tolist()):
            entry = entries[n]
            j_others = self._others_jacobian(entry, radar, float(plots["time"][n]))
            # At H_hat the plot lies at truth + J_i (H_hat - H), the others' prediction
            # at truth + J_o (H_hat - H): y = (J_o - J_i)(H - H_hat) + noise.
            g = j_others - j[n]
            y = xy[n] - refs.others_xy[k]
            s = entry.variance_m2 * np.outer(g, g) + r[n] + refs.others_P[k]
            s_inv_y = np.linalg.solve(s, y)
            if float(y @ s_inv_y) > self.config.gate:
                self.rejected += 1
                continue
            # y = g (H - H_hat) + n: the scalar Kalman update of H.
            gain = entry.variance_m2 * np.linalg.solve(s, g)
            # min and max of Python floats: np.clip's value, without its call on a scalar.
            entry.height_m = min(max(float(entry.height_m + gain @ y), band.min_m), band.max_m)
            entry.variance_m2 = max(entry.variance_m2 * (1.0 - float(gain @ g)), 1.0)
            entry.measurements += 1
            self.measurements += 1

    def _others_jacobian(self, entry: SystemHeight, radar: int, time: float) -> FloatArray:
        recent = [
            j
            for other, (j, t) in entry.jacobians.items()
            if other != radar and time - t <= self.config.jacobian_age_s
        ]
        return np.mean(recent, axis=0) if recent else np.zeros(2)

    def reproject(
        self,
        radar: int,
        table: npt.NDArray[Any],
        tracked: npt.NDArray[Any],
        local: npt.NDArray[Any],
        systems: IntArray,
    ) -> Reprojection:
        """The batch's tracked plots (``tracked``, bias-corrected, rows of ``table``'s
        tracked plots by plot id) and local updates (``local``, bias-corrected; their
        system tracks ``systems``, 0 for none) moved to their aircraft's height
        (module docstring)."""
        extra = np.zeros((len(local), 2, 2))
        if radar not in self.radars or not len(local):
            return Reprojection(tracked, local, extra)
        tracked, local = tracked.copy(), local.copy()
        first_id = int(table["plot_id"][0]) if len(table) else 0
        with_plot = local["plot_id"] >= 0
        row = np.where(with_plot, local["plot_id"] - first_id, 0)
        in_batch = with_plot & (row < len(table))
        unknown = in_batch.copy()
        unknown[in_batch] = ~table["height_known"][row[in_batch]]
        picked = np.flatnonzero(unknown)
        if picked.size:
            self._move_plotted(radar, table[row[picked]], picked, tracked, local, systems, extra)
        # Coasting updates (no plot): their last plot's shift at today's height. Only
        # tracks that had a plot without a height are remembered (``_move_plotted``).
        coasting = np.flatnonzero(~with_plot)
        if not coasting.size or not self._last_plot:
            return Reprojection(tracked, local, extra)
        numbers = local["track_number"][coasting].tolist()
        deleted = (local["status"][coasting] == LOCAL_DELETED).tolist()
        for k, number, gone in zip(coasting.tolist(), numbers, deleted, strict=True):
            key = (radar, number)
            last = self._last_plot.get(key)
            if last is not None:
                j, used, number = last
                entry = self.systems.get(number) if number > 0 else None
                if entry is not None and _applies(entry):
                    shift = j * (entry.height_m - used)
                    local["x"][k] += shift[0]
                    local["y"][k] += shift[1]
                    extra[k] = entry.variance_m2 * np.outer(j, j)
            if gone:
                self._last_plot.pop(key, None)
                self._previous.pop(key, None)
        return Reprojection(tracked, local, extra)

    def _move_plotted(
        self,
        radar: int,
        plots: npt.NDArray[Any],
        picked: IntArray,
        tracked: npt.NDArray[Any],
        local: npt.NDArray[Any],
        systems: IntArray,
        extra: FloatArray,
    ) -> None:
        """``reproject`` for the local updates ``picked`` with a plot without a height
        (``plots``, theirs), in place."""
        n = picked.size
        height = plots["height_m"].copy()
        variance = plots["height_sigma_m"] ** 2
        entries: list[SystemHeight | None] = []
        covered = self.cover.covered(
            plots["x"], plots["y"], float(plots["time"].max()), besides=radar
        )
        times = plots["time"].tolist()
        numbers = systems[picked].tolist()
        for m, (number, time) in enumerate(zip(numbers, times, strict=True)):
            entry = self._system(number, radar, time) if number > 0 else None
            if entry is not None:
                entry.shared |= bool(covered[m])
            # Where no other radar can see the aircraft, the plot stays where its radar
            # stage put it (the band's equivalent height, its spread in the local
            # tracker's R): a lone radar's system tracks follow its local tracks (canalA;
            # docs/fusion.md "Primary-only aircraft").
            if entry is not None and _applies(entry):
                height[m], variance[m] = entry.height_m, entry.variance_m2
            entries.append(entry)
        applied = np.array([e is not None and _applies(e) for e in entries], dtype=bool)
        keys = [(radar, int(t)) for t in local["track_number"][picked].tolist()]
        rate, before, which = self._previous_plots(keys, plots)
        parts = [_Slant.of(plots, height, True)]
        if which.size:
            parts.append(_Slant(before[:, 3], before[:, 4], before[:, 5], height[which], False))
        converted = self._convert(radar, parts)
        xy, r, j = converted[0]
        shift = xy - np.column_stack([plots["x"], plots["y"]])
        shift[~applied] = 0.0
        local["x"][picked] += shift[:, 0]
        local["y"][picked] += shift[:, 1]
        # The height's error as a consider term only where the estimate is the system's:
        # before, the band's spread is in the plot's own covariance already.
        extra[picked] = np.where(applied, variance, 0.0)[:, None, None] * (
            j[:, :, None] * j[:, None, :]
        )
        if which.size:
            self._shift_rates(rate, which, plots, shift, before, converted[1][0])
        fields = zip(*(plots[name].tolist() for name in _PREVIOUS_FIELDS), strict=True)
        for key, plot, plot_rate in zip(keys, fields, rate.tolist(), strict=True):
            self._previous[key] = (plot, tuple(plot_rate))
        # Not applied, the plot is not moved, and neither is its velocity.
        rate = rate * applied[:, None]
        local["vx"][picked] += rate[:, 0]
        local["vy"][picked] += rate[:, 1]
        # The rate is first order and lags the geometry: as uncertain as it is large
        # (the local filter's velocity knows nothing of it).
        p = local["P"][picked].reshape(n, 4, 4)
        p[:, 2:, 2:] += rate[:, :, None] * rate[:, None, :] + 0.25 * np.einsum(
            "ka,ka->k", rate, rate
        )[:, None, None] * np.eye(2)
        local["P"][picked] = p.reshape(n, 16)
        # The tracked plots move with their local updates (np.add.at: in order, as one
        # plot per update would be moved).
        at = np.searchsorted(tracked["plot_id"], plots["plot_id"])
        inside = np.flatnonzero(at < len(tracked))
        moved = np.zeros(n, dtype=bool)
        moved[inside] = tracked["plot_id"][at[inside]] == plots["plot_id"][inside]
        moved &= applied
        np.add.at(tracked["x"], at[moved], shift[moved, 0])
        np.add.at(tracked["y"], at[moved], shift[moved, 1])
        tracked["R"][at[moved]] = r[moved]
        used = plots["height_m"].tolist()
        for m, entry in enumerate(entries):
            if entry is not None:
                entry.jacobians[radar] = (j[m], times[m])
            self._last_plot[keys[m]] = (j[m], used[m], numbers[m])

    def _previous_plots(
        self, keys: list[tuple[int, int]], plots: npt.NDArray[Any]
    ) -> tuple[FloatArray, FloatArray, IntArray]:
        """Per local track (``keys``) of ``plots``: the rate of its shift so far (m/s,
        n x 2: zeros for a track without one), and its previous plot where it is over
        half a second old (rows of ``_PREVIOUS_FIELDS``, and which tracks they are), for
        ``_shift_rates``."""
        rate = np.zeros((len(keys), 2))
        before_rows: list[tuple[float, ...]] = []
        which: list[int] = []
        for m, (key, time) in enumerate(zip(keys, plots["time"].tolist(), strict=True)):
            previous = self._previous.get(key)
            if previous is None:
                continue
            rate[m] = previous[1]
            if time - previous[0][0] > 0.5:
                before_rows.append(previous[0])
                which.append(m)
        before = np.array(before_rows, dtype=np.float64).reshape(-1, len(_PREVIOUS_FIELDS))
        return rate, before, np.array(which, dtype=np.int64)

    def _shift_rates(
        self,
        rate: FloatArray,
        which: IntArray,
        plots: npt.NDArray[Any],
        shift: FloatArray,
        before: FloatArray,
        xy_before: FloatArray,
    ) -> None:
        """How fast the re-projection's shift changes along the tracks ``which`` (m/s,
        into ``rate``): near the radar the band's error changes by kilometres a minute,
        and the local track's velocity carries that rate. Their previous plots
        (``before``) re-projected at the same heights (``xy_before``) so that a new
        height estimate is not taken for motion."""
        shift_before = xy_before - before[:, 1:3]
        dt = (plots["time"][which] - before[:, 0])[:, None]
        raw = (shift[which] - shift_before) / dt
        rate[which] += SHIFT_RATE_SMOOTHING * (raw - rate[which])


_PREVIOUS_FIELDS = ("time", "x", "y", "rho_m", "theta_deg", "typ")
"""What ``PsrHeights`` keeps of a local track's last plot (``_shift_rates``)."""


@dataclass(frozen=True)
class _Slant:
    """Plots to convert at given heights (``PsrHeights._convert``): their slant ranges,
    azimuths, types (I048/020 TYP: 1 primary), the heights, and whether the height
    Jacobian is wanted."""

    rho_m: FloatArray
    theta_deg: FloatArray
    typ: npt.NDArray[Any]
    height_m: FloatArray
    jacobian: bool

    @staticmethod
    def of(plots: npt.NDArray[Any], height: FloatArray, jacobian: bool) -> _Slant:
        return _Slant(plots["rho_m"], plots["theta_deg"], plots["typ"], height, jacobian)
