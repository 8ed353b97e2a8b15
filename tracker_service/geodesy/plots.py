"""Radar plots: slant range, azimuth and height to local Cartesian, ECEF and covariance.

The elevation comes from the earth-curvature formula (DOMAIN.md section 3). In the plane
through the earth's centre, the radar and the target, with the radar at Rc + h and the
target at Rc + H from the centre, the law of cosines gives

    sin psi = (2 Rc (H - h) + H^2 - h^2 - rho^2) / (2 rho (Rc + h))

and the angle gamma the two subtend at the centre: tan gamma = rho cos psi / (Rc + h +
rho sin psi).

The approximation: both heights are above mean sea level, and the formula treats mean sea
level as a sphere of radius Rc whose normal at the radar is the ellipsoid normal; the true
sea level (the geoid, near the ellipsoid's normal section in the look direction) falls
away from the radar at a slightly different rate. At ground distance d a radius error dR
puts the target d^2 dR / (2 R^2) too high or low on its slant-range sphere (56 m at 250 NM
for the meridian radius looking east at 45 deg N, where the normal section's radius is
0.34 % larger), and the geoid's slope between radar and target adds its change in
undulation (metres to tens of metres). A height error dH moves the target along its
slant-range sphere, horizontally by only tan(psi + gamma) dH at the target (0.06 at 250 NM
and FL350), so the horizontal error stays at metres: against the exact ellipsoidal
geometry (the tests), at most 0.7 m at 100 NM and 3.1 m at 250 NM. The radar's
refraction is not modelled: the straight-line slant range is what this stage assumes, and
a range bias from refraction is left to the systematic-error estimation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.ellipsoid import (
    FloatArray,
    as_float,
    radii_m,
)
from tracker_service.geodesy.sites import RadarSite

CrossRange = Literal["exact", "tan"]
CovarianceFrame = Literal["radar", "target"]

MIN_RANGE_M = 1.0
"""Slant ranges below this are treated as this, so that a zero range cannot divide by 0."""
MIN_COS_ELEVATION = 0.05
"""Bound on 1/cos(elevation) in the covariance (87 deg): radars do not see steeper than
their cone of silence, and an impossible height (an assumed one above the slant range)
must not make the covariance infinite."""


@dataclass(frozen=True)
class SlantGeometry:
    """Per plot: elevation psi at the radar, central angle gamma, ground range rho cos psi.

    The ground range is the horizontal distance in the radar's local ENU frame, the arm of
    the azimuth error.
    """

    slant_range_m: FloatArray
    elevation_rad: FloatArray
    central_angle_rad: FloatArray
    ground_range_m: FloatArray

    def range_gain(self, frame: CovarianceFrame = "radar") -> FloatArray:
        """d(ground position)/d(rho) along the line of sight, at constant height."""
        return self.gains(frame)[0]

    def height_gain(self, frame: CovarianceFrame = "radar") -> FloatArray:
        """d(ground position)/dH along the line of sight, at constant slant range."""
        return self.gains(frame)[1]

    def gains(self, frame: CovarianceFrame = "radar") -> tuple[FloatArray, FloatArray]:
        """(``range_gain``, ``height_gain``) at once."""
        return _gains(self.elevation_rad, self.central_angle_rad, frame)


def normal_section_radius_m(lat_deg: npt.ArrayLike, azimuth_deg: npt.ArrayLike) -> FloatArray:
    """Euler's radius of the ellipsoid's normal section in the given azimuth.

    Offered for ``earth_radius_m`` when the last metre at long range matters: it is the
    sphere that follows the ellipsoid in the look direction.
    """
    m, n = radii_m(lat_deg)
    az = np.radians(as_float(azimuth_deg))
    return np.asarray(m * n / (n * np.cos(az) ** 2 + m * np.sin(az) ** 2), dtype=np.float64)


def slant_geometry(
    site: RadarSite,
    rho_m: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
    *,
    earth_radius_m: npt.ArrayLike | None = None,
) -> SlantGeometry:
    """Elevation, central angle and ground range of plots at the given heights above MSL.

    ``earth_radius_m`` defaults to the site's Rc (the meridian radius, as DOMAIN.md writes
    the formula); pass ``site.gaussian_radius_m`` or ``normal_section_radius_m`` to use
    another sphere. A height the slant range cannot reach (the target would be above or
    below the range sphere) gives +-90 deg.
    """
    rc = site.earth_radius_m if earth_radius_m is None else as_float(earth_radius_m)
    h = site.alt_m
    rho = as_float(rho_m)
    height = as_float(height_msl_m)
    k = rc + h
    rho_safe = np.maximum(rho, MIN_RANGE_M)
    # (H - h)(2 Rc + H + h) is 2 Rc (H - h) + H^2 - h^2 without adding squares of 1e7 m.
    sin_psi = ((height - h) * (2.0 * rc + height + h) - rho_safe * rho_safe) / (2.0 * rho_safe * k)
    sin_psi = np.clip(sin_psi, -1.0, 1.0)
    cos_psi = np.sqrt(1.0 - sin_psi * sin_psi)
    ground = rho * cos_psi
    gamma = np.arctan2(ground, k + rho * sin_psi)
    return SlantGeometry(
        slant_range_m=rho,
        elevation_rad=np.arcsin(sin_psi),
        central_angle_rad=np.asarray(gamma, dtype=np.float64),
        ground_range_m=ground,
    )


def local_from_geometry(
    site: RadarSite, geometry: SlantGeometry, theta_deg: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    azimuth = np.radians(as_float(theta_deg) + site.north_offset_deg)
    return local_from_azimuth(geometry, np.sin(azimuth), np.cos(azimuth))


def local_from_azimuth(
    geometry: SlantGeometry, sin_azimuth: FloatArray, cos_azimuth: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """``local_from_geometry`` given the sine and cosine of the true azimuth (the
    conversion computes them once for the position and the covariance)."""
    ground = geometry.ground_range_m
    return (
        ground * sin_azimuth,
        ground * cos_azimuth,
        geometry.slant_range_m * np.sin(geometry.elevation_rad),
    )


def polar_to_local(
    site: RadarSite,
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
    *,
    earth_radius_m: npt.ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Local ENU metres at the antenna (x east, y north, z up) of plots.

    x = rho cos psi sin(theta + north), y = rho cos psi cos(theta + north), z = rho sin psi,
    theta clockwise from north as the radar reports it, north the site's north offset.
    """
    geometry = slant_geometry(site, rho_m, height_msl_m, earth_radius_m=earth_radius_m)
    return local_from_geometry(site, geometry, theta_deg)


def local_to_ecef(
    site: RadarSite, x_m: npt.ArrayLike, y_m: npt.ArrayLike, z_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """r_G = S_R^T r_L + T_R."""
    s = site.enu_rotation
    t = site.ecef_m
    x, y, z = as_float(x_m), as_float(y_m), as_float(z_m)
    return (
        s[0, 0] * x + s[1, 0] * y + s[2, 0] * z + t[0],
        s[0, 1] * x + s[1, 1] * y + s[2, 1] * z + t[1],
        s[0, 2] * x + s[1, 2] * y + s[2, 2] * z + t[2],
    )


def polar_to_ecef(
    site: RadarSite,
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
    *,
    earth_radius_m: npt.ArrayLike | None = None,
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF metres of plots (slant range m, azimuth deg, height above MSL m)."""
    return local_to_ecef(
        site,
        *polar_to_local(site, rho_m, theta_deg, height_msl_m, earth_radius_m=earth_radius_m),
    )


def _gains(
    elevation_rad: FloatArray, central_angle_rad: FloatArray, frame: CovarianceFrame
) -> tuple[FloatArray, FloatArray]:
    psi = elevation_rad
    gamma = central_angle_rad
    cos_at_target = np.maximum(np.cos(psi + gamma), MIN_COS_ELEVATION)
    if frame == "radar":
        return np.cos(gamma) / cos_at_target, -np.sin(psi) / cos_at_target
    if frame == "target":
        return 1.0 / cos_at_target, -np.sin(psi + gamma) / cos_at_target
    raise ValueError(f"covariance frame must be 'radar' or 'target', not {frame!r}")


def polar_covariance(
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    sigma_rho_m: npt.ArrayLike,
    sigma_theta_deg: npt.ArrayLike,
    *,
    elevation_rad: npt.ArrayLike = 0.0,
    central_angle_rad: npt.ArrayLike = 0.0,
    height_sigma_m: npt.ArrayLike = 0.0,
    frame: CovarianceFrame = "radar",
    cross_range: CrossRange = "exact",
) -> FloatArray:
    """Horizontal covariance of converted plots, x east, y north, shape (..., 2, 2).

    R = J diag(sigma_r^2, sigma_theta^2) J^T with J the Jacobian of x = g sin(theta),
    y = g cos(theta) (theta the true azimuth, clockwise from north, so north offset
    included; g the ground range rho cos psi), plus the height error's share along the
    line of sight. Equivalently, with u = (sin theta, cos theta) along the line of sight and
    v = (cos theta, -sin theta) across it:

        R = (a_r^2 sigma_r^2 + a_h^2 sigma_h^2) u u^T + c^2 v v^T,   c = g sigma_theta

    (``cross_range="tan"``: c = g tan(sigma_theta), as the Slovak thesis writes it).
    With the defaults (no elevation, no central angle) a_r = 1, a_h = 0: the flat 2D case
    of DOMAIN.md's worked checks.

    The gains come from the elevation formula at constant theta (psi the elevation at
    the radar, gamma the central angle, both from ``slant_geometry``):

    - ``frame="radar"``: the position in the radar's local ENU plane, as a local tracker
      or a radar's own I042 sees it: a_r = dg/drho = cos gamma / cos(psi + gamma), and
      a_h = dg/dH = -sin psi / cos(psi + gamma) = -tan psi (Rc + H)/(Rc + h), which is
      -tan psi near the radar: 300 m of height error at 20 deg elevation moves the plot
      110 m.
    - ``frame="target"``: the horizontal displacement at the target itself, what its
      latitude/longitude and any map projection see, still on axes parallel to the
      radar's east and north (``SystemPlane.covariance_from_radar`` turns them): a_r =
      1 / cos(psi + gamma), a_h = -tan(psi + gamma). The two differ because a height
      error moves the target along its slant-range sphere, which at long range is steeper
      at the target than at the radar: 17 m per 300 m at 250 NM and FL350, where the
      radar frame says 5 m.

    The along-track variance is capped at rho^2 + sigma_r^2: the ground range cannot leave
    [0, rho], whatever height the plot was given.
    """
    rho, theta, sigma_rho, sigma_theta, psi, gamma, sigma_h = np.broadcast_arrays(
        as_float(rho_m),
        np.radians(as_float(theta_deg)),
        as_float(sigma_rho_m),
        np.radians(as_float(sigma_theta_deg)),
        as_float(elevation_rad),
        as_float(central_angle_rad),
        as_float(height_sigma_m),
    )
    range_gain, height_gain = _gains(psi, gamma, frame)
    return covariance_from_gains(
        rho,
        np.sin(theta),
        np.cos(theta),
        sigma_rho,
        sigma_theta,
        psi,
        (range_gain, height_gain),
        sigma_h,
        cross_range,
    )


def covariance_from_gains(
    rho: FloatArray,
    sin_azimuth: FloatArray,
    cos_azimuth: FloatArray,
    sigma_rho: FloatArray,
    sigma_theta_rad: FloatArray,
    elevation_rad: FloatArray,
    gains: tuple[FloatArray, FloatArray],
    sigma_h: FloatArray | float,
    cross_range: CrossRange,
) -> FloatArray:
    """``polar_covariance`` from the sine and cosine of the azimuth and the gains
    (``SlantGeometry.gains``), arrays of one shape: for the conversion, which has them."""
    if cross_range not in ("exact", "tan"):
        raise ValueError(f"cross_range must be 'exact' or 'tan', not {cross_range!r}")
    range_gain, height_gain = gains
    along = (range_gain * sigma_rho) ** 2 + (height_gain * sigma_h) ** 2
    along = np.minimum(along, rho * rho + sigma_rho * sigma_rho)
    spread = np.tan(sigma_theta_rad) if cross_range == "tan" else sigma_theta_rad
    cross = (rho * np.cos(elevation_rad) * spread) ** 2
    s = sin_azimuth
    c = cos_azimuth
    covariance = np.empty((*rho.shape, 2, 2))
    covariance[..., 0, 0] = along * s * s + cross * c * c
    covariance[..., 1, 1] = along * c * c + cross * s * s
    covariance[..., 0, 1] = covariance[..., 1, 0] = (along - cross) * s * c
    return covariance
