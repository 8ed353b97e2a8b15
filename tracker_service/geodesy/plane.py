"""The system plane: one plane for all radars, where the tracker and the fuser work.

Two kinds, both centred on a configured point:

- ``"stereographic"`` (the default): PROJ's oblique stereographic ``+proj=sterea`` on
  WGS84 (Gauss conformal sphere, then the stereographic projection). Conformal: the
  plane's axes at a point are the local east and north turned by the grid convergence and
  scaled by one factor k, 1 at the centre and 1 + (d / 2R)^2 at distance d (1.0013 at
  250 NM). A position depends only on latitude and longitude, not on height.
- ``"tangent"``: the local ENU frame at the centre (ECEF -> ENU); e and n are the
  orthogonal projection onto the tangent plane, so they depend on height away from the
  centre (a target 400 km out lies 630 m further out at 10 km than on the ground
  below it): one reason to prefer the stereographic plane for tracking.

In both, the third coordinate (``up``) is the ellipsoidal height, so that
``from_ecef``/``to_ecef`` and ``from_geodetic``/``to_geodetic`` invert each other the
same way for both kinds.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property
from typing import Any, Literal

import numpy as np
import numpy.typing as npt
import pyproj

from tracker_service.geodesy.ellipsoid import (
    FloatArray,
    as_float,
    ecef_to_geodetic,
    enu_rotation,
    gaussian_radius_m,
    geodetic_to_ecef,
    radii_m,
)
from tracker_service.geodesy.sites import RadarSite

PlaneKind = Literal["stereographic", "tangent"]

STEP_DEG = 1e-4
"""Latitude/longitude step (about 11 m) of the stereographic plane's local Jacobian: far
above PROJ's rounding, far below the distance at which the scale factor changes."""
_HEIGHT_ITERATIONS = 4
"""Fixed point steps of the tangent plane's inverse at a given height: each multiplies the
error by 1 - cos(central angle) (0.012 at 1,000 km), so 4 leave micrometres."""


@dataclass(frozen=True)
class SystemPlane:
    """The plane every radar's plots are converted into (``centre_lat``/``centre_lon`` in
    degrees; ``centre_height_m``, the tangent point's ellipsoidal height, only matters to
    the tangent plane)."""

    centre_lat: float
    centre_lon: float
    kind: PlaneKind = "stereographic"
    centre_height_m: float = 0.0

    def __post_init__(self) -> None:
        if self.kind not in ("stereographic", "tangent"):
            raise ValueError(f"plane kind must be 'stereographic' or 'tangent', not {self.kind!r}")
        if not -90.0 < self.centre_lat < 90.0:
            raise ValueError(f"plane centre latitude {self.centre_lat} is outside (-90, 90) deg")

    @cached_property
    def proj_string(self) -> str:
        """The PROJ definition of the stereographic plane (also for other tools)."""
        return (
            f"+proj=sterea +lat_0={self.centre_lat!r} +lon_0={self.centre_lon!r} +k=1 "
            "+x_0=0 +y_0=0 +ellps=WGS84 +units=m"
        )

    @cached_property
    def _stereographic(self) -> Any:
        return pyproj.Transformer.from_pipeline(self.proj_string)

    @cached_property
    def centre_rotation(self) -> FloatArray:
        """ENU rotation at the centre: the tangent plane's axes (rows east, north, up)."""
        rotation = enu_rotation(self.centre_lat, self.centre_lon)
        rotation.flags.writeable = False
        return rotation

    @cached_property
    def centre_ecef_m(self) -> FloatArray:
        centre = np.array(
            [
                float(v)
                for v in geodetic_to_ecef(self.centre_lat, self.centre_lon, self.centre_height_m)
            ]
        )
        centre.flags.writeable = False
        return centre

    # Positions.

    def from_ecef(
        self, x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(e, n, up) plane metres of ECEF points; up is the ellipsoidal height."""
        x, y, z = as_float(x), as_float(y), as_float(z)
        lat, lon, h = ecef_to_geodetic(x, y, z)
        e, n = self.plane_xy(x, y, z, lat, lon)
        return e, n, h

    def to_ecef(
        self, e: npt.ArrayLike, n: npt.ArrayLike, up: npt.ArrayLike = 0.0
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """ECEF metres of plane points at ellipsoidal height ``up``."""
        lat, lon = self.to_geodetic(e, n, up)
        return geodetic_to_ecef(lat, lon, np.broadcast_to(as_float(up), lat.shape))

    def from_geodetic(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """(e, n) plane metres of geodetic points (``h_m`` only matters to the tangent plane)."""
        lat, lon = np.broadcast_arrays(as_float(lat_deg), as_float(lon_deg))
        if self.kind == "stereographic":
            return self._project(lat, lon)
        x, y, z = geodetic_to_ecef(lat, lon, h_m)
        return self._tangent_xy(x, y, z)

    def to_geodetic(
        self, e: npt.ArrayLike, n: npt.ArrayLike, h_m: npt.ArrayLike = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """(lat_deg, lon_deg) of plane points. For the tangent plane, of the point at
        ellipsoidal height ``h_m`` over (e, n): e and n alone do not fix it."""
        e, n = np.broadcast_arrays(as_float(e), as_float(n))
        if self.kind == "stereographic":
            lon, lat = self._stereographic.transform(e, n, direction="INVERSE")
            return as_float(lat), as_float(lon)
        h = np.broadcast_to(as_float(h_m), e.shape)
        # Start from a sphere through the centre, then correct along the plane normal by the
        # height still missing.
        radius = float(gaussian_radius_m(self.centre_lat))
        up = (
            np.sqrt(np.maximum((radius + h) ** 2 - e * e - n * n, 0.0))
            - radius
            - self.centre_height_m
        )
        for _ in range(_HEIGHT_ITERATIONS):
            _, _, height = ecef_to_geodetic(*self._tangent_to_ecef(e, n, up))
            up = up + (h - height)
        lat, lon, _ = ecef_to_geodetic(*self._tangent_to_ecef(e, n, up))
        return lat, lon

    def plane_xy(
        self,
        x: FloatArray,
        y: FloatArray,
        z: FloatArray,
        lat_deg: FloatArray,
        lon_deg: FloatArray,
    ) -> tuple[FloatArray, FloatArray]:
        """(e, n) of points given both ways (ECEF and geodetic), for callers that have both:
        each kind uses the one it needs, so nothing is converted twice."""
        if self.kind == "stereographic":
            return self._project(lat_deg, lon_deg)
        return self._tangent_xy(x, y, z)

    def _project(self, lat: FloatArray, lon: FloatArray) -> tuple[FloatArray, FloatArray]:
        e, n = self._stereographic.transform(lon, lat)
        return as_float(e), as_float(n)

    def _tangent_to_ecef(
        self, e: FloatArray, n: FloatArray, up: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        s = self.centre_rotation
        t = self.centre_ecef_m
        return (
            s[0, 0] * e + s[1, 0] * n + s[2, 0] * up + t[0],
            s[0, 1] * e + s[1, 1] * n + s[2, 1] * up + t[1],
            s[0, 2] * e + s[1, 2] * n + s[2, 2] * up + t[2],
        )

    def _tangent_xy(
        self, x: npt.ArrayLike, y: npt.ArrayLike, z: npt.ArrayLike
    ) -> tuple[FloatArray, FloatArray]:
        s = self.centre_rotation
        t = self.centre_ecef_m
        dx, dy, dz = as_float(x) - t[0], as_float(y) - t[1], as_float(z) - t[2]
        e = s[0, 0] * dx + s[0, 1] * dy + s[0, 2] * dz
        n = s[1, 0] * dx + s[1, 1] * dy + s[1, 2] * dz
        return e, n

    # Covariances.

    def jacobian(
        self, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_m: npt.ArrayLike = 0.0
    ) -> FloatArray:
        """d(e, n)/d(east, north, up): plane metres per metre of displacement at the point,
        on the point's own ENU axes, shape (..., 2, 3).

        Stereographic: the horizontal block is k Rot(convergence), taken by differences of
        the projection itself and divided by the metres a step of latitude/longitude spans
        at the point's height (a target at 11 km moves 0.17 % more than its footprint);
        the up column is zero. Tangent: the projection of the point's east, north and up
        onto the centre's east and north, exact; up is not zero away from the centre
        (sin(central angle): 0.07 at 250 NM), which is how height leaks into that plane.
        """
        lat, lon, h = np.broadcast_arrays(as_float(lat_deg), as_float(lon_deg), as_float(h_m))
        out = np.zeros((*lat.shape, 2, 3))
        if self.kind == "tangent":
            out[...] = np.einsum(
                "ij,...kj->...ik", self.centre_rotation[:2, :], enu_rotation(lat, lon)
            )
            return out
        e0, n0 = self._project(lat, lon)
        e_north, n_north = self._project(lat + STEP_DEG, lon)
        e_east, n_east = self._project(lat, lon + STEP_DEG)
        step = np.radians(STEP_DEG)
        meridian, prime_vertical = radii_m(lat)
        north_m = (meridian + h) * step
        east_m = (prime_vertical + h) * np.cos(np.radians(lat)) * step
        out[..., 0, 0] = (e_east - e0) / east_m
        out[..., 1, 0] = (n_east - n0) / east_m
        out[..., 0, 1] = (e_north - e0) / north_m
        out[..., 1, 1] = (n_north - n0) / north_m
        return out

    def radar_turn(
        self, site: RadarSite, lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike
    ) -> FloatArray:
        """Q (..., 2, 2): from axes parallel to the radar's east and north, carried along
        the line of sight to targets at the given positions, to the targets' own east and
        north.

        The radar's north, carried to the target, is not the target's north: meridians
        converge, by about delta-longitude x sin(latitude): 4.7 deg at 250 NM east or
        west of a radar at 49 N. Q is the rotation part of M = [target east, north] . [radar
        east, north]^T: M carries the radar's cross-range axis to the target's unchanged
        (it is horizontal at both) and shortens its range axis by cos(central angle), so
        M = Q S with S symmetric, and Q is M's closest rotation, angle
        atan2(M10 - M01, M00 + M11).
        """
        lat, lon = np.broadcast_arrays(as_float(lat_deg), as_float(lon_deg))
        m = np.einsum(
            "...ik,jk->...ij", enu_rotation(lat, lon)[..., :2, :], site.enu_rotation[:2, :]
        )
        angle = np.arctan2(m[..., 1, 0] - m[..., 0, 1], m[..., 0, 0] + m[..., 1, 1])
        cos_a, sin_a = np.cos(angle), np.sin(angle)
        turn = np.empty((*lat.shape, 2, 2))
        turn[..., 0, 0] = cos_a
        turn[..., 0, 1] = -sin_a
        turn[..., 1, 0] = sin_a
        turn[..., 1, 1] = cos_a
        return turn

    def covariance_from_radar(
        self,
        site: RadarSite,
        covariance: npt.ArrayLike,
        lat_deg: npt.ArrayLike,
        lon_deg: npt.ArrayLike,
        h_m: npt.ArrayLike = 0.0,
    ) -> FloatArray:
        """Plane covariance (..., 2, 2) of horizontal errors at the targets, given on axes
        parallel to the radar's east and north (``polar_covariance`` with
        ``frame="target"``): turned to each target's north (``radar_turn``), then into
        the plane (``jacobian``: grid convergence and scale).

        Horizontal errors only: in the tangent plane a height error also moves a plot
        through the plane's tilt, which ``convert_plots`` adds with its own sign.
        """
        a = self.jacobian(lat_deg, lon_deg, h_m)[..., :2] @ self.radar_turn(site, lat_deg, lon_deg)
        return np.asarray(a @ as_float(covariance) @ np.swapaxes(a, -1, -2), dtype=np.float64)
