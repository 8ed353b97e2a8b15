"""The tracker's entry point: a batch of one radar's plots into the system plane."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.ellipsoid import FloatArray, as_float, ecef_to_geodetic
from tracker_service.geodesy.plane import SystemPlane
from tracker_service.geodesy.plots import (
    CrossRange,
    SlantGeometry,
    covariance_from_gains,
    local_from_azimuth,
    local_to_ecef,
    slant_geometry,
)
from tracker_service.geodesy.sites import RadarSite


@dataclass(frozen=True)
class ConvertedPlots:
    """Plots in the system plane, one row per plot (arrays of shape (N,), R (N, 2, 2)).

    - ``x``, ``y``: plane metres (east, north of the plane's grid).
    - ``height_m``, ``height_sigma_m``: the height above MSL the conversion assumed (Mode C
      or its stand-in) and its sigma: the tracker's vertical measurement.
    - ``R``: horizontal covariance in the plane, m^2.
    - ``lat_deg``, ``lon_deg``: geodetic position (for outputs and for other planes).
    - ``elevation_rad``: elevation at the radar (a steep plot is one whose height matters).
    - ``polar_jacobian``: (N, 2, 2), the plane position's derivatives with respect to the
      slant range (m per m, first column) and the azimuth (m per rad, second column), at
      constant height: what a range or azimuth bias does to the plot.
    """

    x: FloatArray
    y: FloatArray
    height_m: FloatArray
    height_sigma_m: FloatArray
    R: FloatArray
    lat_deg: FloatArray
    lon_deg: FloatArray
    elevation_rad: FloatArray
    polar_jacobian: FloatArray

    def __len__(self) -> int:
        return int(self.x.shape[0])


def convert_plots(
    site: RadarSite,
    plane: SystemPlane,
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
    height_sigma_m: npt.ArrayLike,
    sigma_rho_m: npt.ArrayLike,
    sigma_theta_deg: npt.ArrayLike,
    *,
    cross_range: CrossRange = "exact",
    earth_radius_m: npt.ArrayLike | None = None,
) -> ConvertedPlots:
    """Convert one radar's plots: slant range (m), azimuth as reported (deg, the site's
    north offset is added here), height above MSL (m, from ``HeightModel.heights``) and the
    sigmas (scalars or per plot) into plane positions and covariances."""
    rho, theta, height, height_sigma, sigma_rho, sigma_theta = _plot_columns(
        rho_m, theta_deg, height_msl_m, height_sigma_m, sigma_rho_m, sigma_theta_deg
    )
    geometry, sin_az, cos_az, lat, lon, h, e, n = _placed(
        site, plane, rho, theta, height, earth_radius_m
    )
    range_gain, height_gain = geometry.gains("target")
    horizontal = covariance_from_gains(
        rho,
        sin_az,
        cos_az,
        sigma_rho,
        np.radians(sigma_theta),
        geometry.elevation_rad,
        (range_gain, height_gain),
        0.0,
        cross_range,
    )
    jacobian = plane.jacobian(lat, lon, h)
    a = jacobian[..., :2] @ plane.radar_turn(site, lat, lon)
    covariance = a @ horizontal @ np.swapaxes(a, -1, -2)
    # One height error moves the target along its slant-range sphere: along the line of
    # sight at the target and up by as much as the error, both at once, so the two shares
    # add as one vector (the up one only counts in the tangent plane). The slide is
    # bounded by rho, as in polar_covariance: an impossible height must not blow it up.
    slide = np.clip(height_gain * height_sigma, -rho, rho)
    along = np.stack([sin_az, cos_az], axis=-1)
    shift = (
        np.einsum("nij,nj->ni", a, along * slide[:, None])
        + jacobian[..., 2] * height_sigma[:, None]
    )
    covariance += shift[:, :, None] * shift[:, None, :]
    across = np.stack([cos_az, -sin_az], axis=-1)
    polar_jacobian = np.stack(
        [
            np.einsum("nij,nj->ni", a, along * range_gain[:, None]),
            np.einsum("nij,nj->ni", a, across * geometry.ground_range_m[:, None]),
        ],
        axis=-1,
    )
    return ConvertedPlots(
        x=e,
        y=n,
        height_m=np.array(height),
        height_sigma_m=np.array(height_sigma),
        R=covariance,
        lat_deg=lat,
        lon_deg=lon,
        elevation_rad=geometry.elevation_rad,
        polar_jacobian=polar_jacobian,
    )


def plane_positions(
    site: RadarSite,
    plane: SystemPlane,
    rho_m: npt.ArrayLike,
    theta_deg: npt.ArrayLike,
    height_msl_m: npt.ArrayLike,
) -> tuple[FloatArray, FloatArray]:
    """``convert_plots(...).x, .y`` alone (the same arithmetic, so the same bits), without
    the covariance and the Jacobians."""
    rho, theta, height = _plot_columns(rho_m, theta_deg, height_msl_m)
    _, _, _, _, _, _, e, n = _placed(site, plane, rho, theta, height, None)
    return e, n


def _plot_columns(*values: npt.ArrayLike) -> list[FloatArray]:
    """Each argument as a float column, scalars and shapes broadcast to one 1-d length
    (the usual case, columns of one length already, passes untouched)."""
    columns = [as_float(v) for v in values]
    shape = columns[0].shape
    if not all(c.ndim == 1 and c.shape == shape for c in columns):
        columns = [np.ravel(c) for c in np.broadcast_arrays(*columns)]
    return columns


def _placed(
    site: RadarSite,
    plane: SystemPlane,
    rho: FloatArray,
    theta: FloatArray,
    height: FloatArray,
    earth_radius_m: npt.ArrayLike | None,
) -> tuple[
    SlantGeometry,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
    FloatArray,
]:
    """The plots' geometry, the true azimuth's sine and cosine, their geodetic position
    (lat, lon, h) and plane position (x, y)."""
    geometry = slant_geometry(site, rho, height, earth_radius_m=earth_radius_m)
    # The true azimuth's sine and cosine, once for the position, the covariance and the
    # Jacobians (a batch is a few dozen plots: the calls cost more than the arithmetic).
    azimuth = np.radians(theta + site.north_offset_deg)
    sin_az, cos_az = np.sin(azimuth), np.cos(azimuth)
    x, y, z = local_to_ecef(site, *local_from_azimuth(geometry, sin_az, cos_az))
    lat, lon, h = ecef_to_geodetic(x, y, z)
    e, n = plane.plane_xy(x, y, z, lat, lon)
    return geometry, sin_az, cos_az, lat, lon, h, e, n
