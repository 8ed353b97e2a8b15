"""WGS84: constants, radii of curvature, geodetic <-> ECEF, local ENU rotations.

Everything is vectorised over numpy arrays. Geodetic -> ECEF and the rotations are closed
forms in numpy; ECEF -> geodetic is PROJ's (exact to well under a millimetre), which is as
fast as numpy and saves writing an iteration of our own.
"""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt
import pyproj

FloatArray = npt.NDArray[np.float64]

A = 6378137.0
"""WGS84 semi-major axis, m."""
F = 1.0 / 298.257223563
"""WGS84 flattening (one source document prints 1/299.257...: a typo)."""
E2 = F * (2.0 - F)
"""First eccentricity squared, 0.00669437999014."""


def as_float(values: npt.ArrayLike) -> FloatArray:
    return np.asarray(values, dtype=np.float64)


def meridian_radius_m(lat_deg: npt.ArrayLike) -> FloatArray:
    """M = a(1-e^2)/(1-e^2 sin^2 L)^(3/2): the radius of curvature along the meridian."""
    return radii_m(lat_deg)[0]


def prime_vertical_radius_m(lat_deg: npt.ArrayLike) -> FloatArray:
    """N = a/(1-e^2 sin^2 L)^(1/2): the radius of curvature across the meridian."""
    return radii_m(lat_deg)[1]


def radii_m(lat_deg: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """(``meridian_radius_m``, ``prime_vertical_radius_m``) at once, for callers that
    need both (one sine)."""
    s = np.sin(np.radians(as_float(lat_deg)))
    w = 1.0 - E2 * s * s
    return (
        np.asarray(A * (1.0 - E2) / w**1.5, dtype=np.float64),
        np.asarray(A / np.sqrt(w), dtype=np.float64),
    )


def gaussian_radius_m(lat_deg: npt.ArrayLike) -> FloatArray:
    """sqrt(M N): the sphere that osculates the ellipsoid best, averaged over azimuth."""
    return np.asarray(
        np.sqrt(meridian_radius_m(lat_deg) * prime_vertical_radius_m(lat_deg)), dtype=np.float64
    )


def geodetic_to_ecef(
    lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF metres of geodetic latitude, longitude and ellipsoidal height."""
    lat = np.radians(as_float(lat_deg))
    lon = np.radians(as_float(lon_deg))
    h = as_float(h_m)
    sin_lat = np.sin(lat)
    cos_lat = np.cos(lat)
    n = A / np.sqrt(1.0 - E2 * sin_lat * sin_lat)
    x = (n + h) * cos_lat * np.cos(lon)
    y = (n + h) * cos_lat * np.sin(lon)
    z = (n * (1.0 - E2) + h) * sin_lat
    return x, y, z


@cache
def ecef_to_geodetic_transformer() -> Any:
    # A bare PROJ pipeline: no CRS database lookup, no datum choice, degrees out.
    return pyproj.Transformer.from_pipeline("+proj=pipeline +step +inv +proj=cart +ellps=WGS84")


def ecef_to_geodetic(
    x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(lat_deg, lon_deg, ellipsoidal height m) of ECEF metres."""
    lon, lat, h = ecef_to_geodetic_transformer().transform(as_float(x), as_float(y), as_float(z))
    return as_float(lat), as_float(lon), as_float(h)


def enu_rotation(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> FloatArray:
    """S: rows are the local east, north and up unit vectors in ECEF, shape (..., 3, 3).

    r_local = S (r_ecef - r_origin) and r_ecef = S^T r_local + r_origin. Up is the
    ellipsoid normal (geodetic latitude), as a radar's levelled antenna sees it.
    """
    lat = np.radians(as_float(lat_deg))
    lon = np.radians(as_float(lon_deg))
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    sin_lon, cos_lon = np.sin(lon), np.cos(lon)
    # Filled in place rather than stacked: a radar's batch is a few dozen plots, where
    # the nine stacks cost more than the arithmetic.
    rotation = np.empty((*lat.shape, 3, 3))
    rotation[..., 0, 0] = -sin_lon
    rotation[..., 0, 1] = cos_lon
    rotation[..., 0, 2] = 0.0
    rotation[..., 1, 0] = -sin_lat * cos_lon
    rotation[..., 1, 1] = -sin_lat * sin_lon
    rotation[..., 1, 2] = cos_lat
    rotation[..., 2, 0] = cos_lat * cos_lon
    rotation[..., 2, 1] = cos_lat * sin_lon
    rotation[..., 2, 2] = sin_lat
    return rotation
