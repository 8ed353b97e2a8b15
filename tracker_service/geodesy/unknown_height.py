"""Plots without a usable height (primary-only, or Mode C missing, invalid or garbled).

The slant range says where the target is on a sphere about the antenna; its horizontal
position needs the height (``plots.slant_geometry``). Without one, the aircraft can be
anywhere in a plausible band of heights (``HeightBand``: above the lowest level traffic
flies at, below the ceiling, and below the radar's cone of silence, which the slant range
turns into a ceiling of its own near the radar). Over that band, taken as uniform, each
height puts the target at another distance from the radar along the line of sight: the
prior here is the mean of those distances and their spread, as an equivalent height
``H_eq`` (the height whose distance is the mean) and an equivalent sigma ``sigma_eq``
(the spread divided by the distance's slope at ``H_eq``), which ``convert_plots`` turns
into the position and its covariance as it does for a Mode C height and its sigma. Near
the radar the spread is kilometres (at 20 km slant range the band's distances run from
20 km down to 14 km); far out it is tens of metres.

That error is one per aircraft and radar, the same on every plot for minutes, not white
noise: the conversion also gives each plot the height Jacobian J = d(x, y)/dH of its
plane position, so that the central stage, once it knows the height better
(``fusion.psr_height``), moves the plot by J (H - H_eq) and carries J J^T sigma_H^2 as
an error common to that radar's plots of the aircraft.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.convert import plane_positions
from tracker_service.geodesy.ellipsoid import FloatArray, as_float
from tracker_service.geodesy.plane import SystemPlane
from tracker_service.geodesy.plots import slant_geometry
from tracker_service.geodesy.sites import RadarSite

__all__ = ["HeightBand", "height_jacobian", "unknown_height_prior"]

_NODES, _WEIGHTS = np.polynomial.legendre.leggauss(24)
JACOBIAN_STEP_M = 10.0
"""Central-difference step of the height Jacobian: metres, where the position is
linear in the height to well under a millimetre."""


@dataclass(frozen=True)
class HeightBand:
    """Where an aircraft without a height may be: heights above MSL from ``min_m`` to
    ``max_m`` (uniform), at elevations up to ``max_elevation_deg`` (the radar's cone of
    silence: it does not see steeper)."""

    min_m: float = 150.0
    max_m: float = 12_500.0
    max_elevation_deg: float = 45.0

    def __post_init__(self) -> None:
        if not 0.0 < self.max_elevation_deg < 90.0:
            raise ValueError(
                f"height band max_elevation_deg must be in (0, 90), not {self.max_elevation_deg}"
            )
        if self.max_m <= self.min_m:
            raise ValueError(f"height band max_m ({self.max_m}) must exceed min_m ({self.min_m})")


def _distance_m(site: RadarSite, rho: FloatArray, height: FloatArray) -> FloatArray:
    """Arc length at sea level from the radar to below the target: the horizontal
    position along the line of sight that the height moves."""
    return np.asarray(
        site.earth_radius_m * slant_geometry(site, rho, height).central_angle_rad,
        dtype=np.float64,
    )


def feasible_band(
    site: RadarSite, rho_m: npt.ArrayLike, band: HeightBand
) -> tuple[FloatArray, FloatArray]:
    """(lowest, highest) height above MSL of each plot within the band: the cone of
    silence caps it at the height of the maximum elevation at that slant range; a
    target too close to reach the band's floor at that elevation gets the cone's
    height alone."""
    rho = np.maximum(as_float(rho_m), 1.0)
    k = site.earth_radius_m + site.alt_m
    sin_max = np.sin(np.radians(band.max_elevation_deg))
    cone = np.sqrt(k * k + rho * rho + 2.0 * k * rho * sin_max) - site.earth_radius_m
    # Below the antenna the slant range cannot reach the floor either (psi >= -90 deg):
    # a target is at least at the antenna's height minus the range, which never binds
    # for a plausible band; the floor is kept as given.
    high = np.minimum(band.max_m, cone)
    low = np.minimum(band.min_m, high)
    return np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)


def unknown_height_prior(
    site: RadarSite, rho_m: npt.ArrayLike, band: HeightBand
) -> tuple[FloatArray, FloatArray]:
    """(H_eq, sigma_eq) per plot (metres above MSL): the equivalent height and sigma of
    the band's uniform heights (module docstring), for ``convert_plots``."""
    rho = np.ravel(as_float(rho_m))
    low, high = feasible_band(site, rho, band)
    half = 0.5 * (high - low)
    heights = (0.5 * (high + low))[:, None] + half[:, None] * _NODES[None, :]
    weights = _WEIGHTS / _WEIGHTS.sum()
    distance = _distance_m(site, np.broadcast_to(rho[:, None], heights.shape), heights)
    mean = distance @ weights
    spread = np.sqrt(np.maximum((distance - mean[:, None]) ** 2 @ weights, 0.0))
    # The distance falls as the height rises: the node nearest the mean from above,
    # then one Newton step on the local slope.
    nearest = np.argmin(np.abs(distance - mean[:, None]), axis=1)
    h_eq = heights[np.arange(rho.size), nearest]
    slope = _slope(site, rho, h_eq)
    safe = np.where(np.abs(slope) > 1e-6, slope, -1e-6)
    h_eq = np.clip(h_eq + (mean - _distance_m(site, rho, h_eq)) / safe, low, high)
    slope = _slope(site, rho, h_eq)
    sigma_eq = spread / np.maximum(np.abs(slope), 1e-3)
    # Where the slope vanishes (low elevation far out) the distance hardly depends on
    # the height: the ratio is then loose, and never needs to exceed the band.
    sigma_eq = np.minimum(sigma_eq, np.maximum(high - low, 1.0))
    return h_eq, sigma_eq


def _slope(site: RadarSite, rho: FloatArray, height: FloatArray) -> FloatArray:
    step = JACOBIAN_STEP_M
    return (_distance_m(site, rho, height + step) - _distance_m(site, rho, height - step)) / (
        2.0 * step
    )


def height_jacobian(
    site: RadarSite,
    plane: SystemPlane,
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
    at: tuple[FloatArray, FloatArray] | None = None,
) -> FloatArray:
    """(N, 2) d(x, y)/dH of plane positions (m per m of height), by differences of
    ``convert_plots``' positions (``plane_positions``: the same geometry and plane): forward
    from ``at``, the plane positions at ``height_msl_m`` when the caller has them (one
    conversion; the curvature over the step is below a millimetre), else central."""
    step = JACOBIAN_STEP_M
    height = as_float(height_msl_m)
    up_x, up_y = plane_positions(site, plane, rho_m, theta_deg, height + step)
    if at is not None:
        return np.column_stack([up_x - at[0], up_y - at[1]]) / step
    down_x, down_y = plane_positions(site, plane, rho_m, theta_deg, height - step)
    return np.column_stack([up_x - down_x, up_y - down_y]) / (2.0 * step)
