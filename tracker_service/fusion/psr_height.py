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
- every plot and local update of the system track is re-projected exactly at H_hat
  (``convert_plots`` from its slant range and azimuth), its covariance becomes the
  measurement noise alone, and J J^T var(H) goes to the fuser as the error common to
  that radar's plots of the aircraft (the ``extra`` consider term the residual biases
  use: fusion/consider.py), which the association gate and the system covariance carry.

A local track's update moves with its plot (the same shift); a coasting one with its
last plot's Jacobian. The re-projection happens before fusion, after the bias
correction: the two are first order in different parameters and add.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.references import References
from tracker_service.geodesy import RadarSite, SystemPlane, convert_plots
from tracker_service.geodesy.unknown_height import HeightBand, feasible_band, height_jacobian
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
    stale_s: float = 120.0
    """A system track's height untouched for this long belongs to a track that ended
    (a live one has a plot within the fuser's silence, 3 x the longest period): a new
    track under its reused number (after ``number_reuse_delay_s``, 300 s) starts afresh."""


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
        self._previous: dict[tuple[int, int], tuple[npt.NDArray[Any], FloatArray]] = {}
        """Per (radar, local track number): its last plot (a table row) and the rate of
        its shift (m/s, smoothed)."""
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
        self, radar: int, rows: npt.NDArray[Any], height: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Plane xy (n, 2), noise-only R (n, 2, 2) and J (n, 2) of plot table rows at
        the given heights, clipped to what each slant range allows."""
        g = self.radars[radar]
        low, high = feasible_band(g.site, rows["rho_m"], g.band)
        height = np.clip(height, low, high)
        psr = rows["typ"] == 1
        converted = convert_plots(
            g.site,
            self.plane,
            rows["rho_m"],
            rows["theta_deg"],
            height,
            0.0,
            np.where(psr, g.psr_sigma_range_m, g.sigma_range_m),
            np.where(psr, g.psr_sigma_azimuth_deg, g.sigma_azimuth_deg),
        )
        j = height_jacobian(g.site, self.plane, rows["rho_m"], rows["theta_deg"], height)
        return np.column_stack([converted.x, converted.y]), converted.R, j

    def observe(self, radar: int, table: npt.NDArray[Any], refs: References) -> None:
        """Measure the heights of the system tracks of this batch's plots without a
        height that other radars' tracks see (module docstring)."""
        if radar not in self.radars or not len(table):
            return
        first_id = int(table["plot_id"][0])
        row = refs.plot_id - first_id
        usable = refs.others_valid & (refs.system_number > 0)
        usable &= ~table["height_known"][row]
        for k in np.flatnonzero(usable).tolist():
            plot = table[row[k] : row[k] + 1]
            number = int(refs.system_number[k])
            entry = self._system(number, radar, float(plot["time"][0]))
            xy, r, j = self._convert(radar, plot, np.array([entry.height_m]))
            j_others = self._others_jacobian(entry, radar, float(plot["time"][0]))
            # At H_hat the plot lies at truth + J_i (H_hat - H), the others' prediction
            # at truth + J_o (H_hat - H): y = (J_o - J_i)(H - H_hat) + noise.
            g = j_others - j[0]
            y = xy[0] - refs.others_xy[k]
            noise = r[0] + refs.others_P[k]
            s = entry.variance_m2 * np.outer(g, g) + noise
            s_inv_y = np.linalg.solve(s, y)
            if float(y @ s_inv_y) > self.config.gate:
                self.rejected += 1
                continue
            s_inv_g = np.linalg.solve(s, g)
            # y = g (H - H_hat) + n: the scalar Kalman update of H.
            gain = entry.variance_m2 * s_inv_g
            entry.height_m += float(gain @ y)
            entry.variance_m2 = max(entry.variance_m2 * (1.0 - float(gain @ g)), 1.0)
            band = self.radars[radar].band
            entry.height_m = float(np.clip(entry.height_m, band.min_m, band.max_m))
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
        for k in np.flatnonzero(unknown).tolist():
            plot = table[row[k] : row[k] + 1]
            time = float(plot["time"][0])
            number = int(systems[k])
            if number > 0:
                entry = self._system(number, radar, time)
                height, variance = entry.height_m, entry.variance_m2
            else:
                entry = None
                height, variance = float(plot["height_m"][0]), float(plot["height_sigma_m"][0]) ** 2
            xy, r, j = self._convert(radar, plot, np.array([height]))
            shift = xy[0] - np.array([plot["x"][0], plot["y"][0]])
            local["x"][k] += shift[0]
            local["y"][k] += shift[1]
            key = (radar, int(local["track_number"][k]))
            rate = self._shift_rate(radar, key, plot, shift, height)
            local["vx"][k] += rate[0]
            local["vy"][k] += rate[1]
            # The rate is first order and lags the geometry: as uncertain as it is large
            # (the local filter's velocity knows nothing of it).
            p = local["P"][k].reshape(4, 4)
            p[2:, 2:] += np.outer(rate, rate) + 0.25 * float(rate @ rate) * np.eye(2)
            local["P"][k] = p.ravel()
            extra[k] = variance * np.outer(j[0], j[0])
            at = np.flatnonzero(tracked["plot_id"] == plot["plot_id"][0])
            if at.size:
                tracked["x"][at] += shift[0]
                tracked["y"][at] += shift[1]
                tracked["R"][at] = r[0]
            if entry is not None:
                entry.jacobians[radar] = (j[0], time)
            self._last_plot[key] = (j[0], float(plot["height_m"][0]), number)
        # Coasting updates (no plot): their last plot's shift at today's height.
        for k in np.flatnonzero(~with_plot).tolist():
            key = (radar, int(local["track_number"][k]))
            last = self._last_plot.get(key)
            if last is not None:
                j, used, number = last
                entry = self.systems.get(number) if number > 0 else None
                if entry is not None:
                    shift = j * (entry.height_m - used)
                    local["x"][k] += shift[0]
                    local["y"][k] += shift[1]
                    extra[k] = entry.variance_m2 * np.outer(j, j)
            if local["status"][k] == LOCAL_DELETED:
                self._last_plot.pop(key, None)
                self._previous.pop(key, None)
        return Reprojection(tracked, local, extra)

    def _shift_rate(
        self,
        radar: int,
        key: tuple[int, int],
        plot: npt.NDArray[Any],
        shift: FloatArray,
        height: float,
    ) -> FloatArray:
        """How fast the re-projection's shift changes along the track (m/s): near the
        radar the band's error changes by kilometres a minute, and the local track's
        velocity carries that rate. The previous plot is re-projected at the same height
        so that a new height estimate is not taken for motion."""
        previous = self._previous.get(key)
        rate = np.zeros(2) if previous is None else previous[1]
        if previous is not None:
            before = previous[0]
            dt = float(plot["time"][0] - before["time"][0])
            if dt > 0.5:
                xy, _, _ = self._convert(radar, before, np.array([height]))
                shift_before = xy[0] - np.array([before["x"][0], before["y"][0]])
                raw = (shift - shift_before) / dt
                rate = rate + SHIFT_RATE_SMOOTHING * (raw - rate)
        self._previous[key] = (plot.copy(), rate)
        return rate
