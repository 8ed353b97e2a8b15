"""Radar sites: where the antenna is, and what follows from it (cached once per site)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from tracker_service.geodesy.ellipsoid import (
    FloatArray,
    enu_rotation,
    gaussian_radius_m,
    geodetic_to_ecef,
    meridian_radius_m,
)


@dataclass(frozen=True)
class RadarSite:
    """A radar antenna on WGS84.

    - ``lat_deg``, ``lon_deg``: geodetic latitude and east longitude.
    - ``alt_m``: antenna height above mean sea level (the geoid), as site surveys give it.
    - ``geoid_m``: geoid undulation at the site (geoid height above the ellipsoid), so that
      the ellipsoidal height is ``alt_m + geoid_m``. The default 0 is only for tests and
      synthetic sites: a real configuration must give it (about 45 m in central Europe,
      from EGM96/EGM2008), or every converted plot lands that much too low in ECEF.
    - ``north_offset_deg``: the radar's north alignment correction, added to every
      reported azimuth to get the true azimuth (clockwise from geodetic north).
    """

    lat_deg: float
    lon_deg: float
    alt_m: float
    geoid_m: float = 0.0
    north_offset_deg: float = 0.0

    def __post_init__(self) -> None:
        values = (self.lat_deg, self.lon_deg, self.alt_m, self.geoid_m, self.north_offset_deg)
        if not all(math.isfinite(v) for v in values):
            raise ValueError(f"radar site values must be finite: {self}")
        if not -90.0 <= self.lat_deg <= 90.0:
            raise ValueError(f"radar site latitude {self.lat_deg} is outside [-90, 90] deg")

    @property
    def ellipsoidal_height_m(self) -> float:
        return self.alt_m + self.geoid_m

    @cached_property
    def ecef_m(self) -> FloatArray:
        """T_R: the antenna's ECEF position, shape (3,)."""
        position = np.array(
            [
                float(v)
                for v in geodetic_to_ecef(self.lat_deg, self.lon_deg, self.ellipsoidal_height_m)
            ]
        )
        position.flags.writeable = False
        return position

    @cached_property
    def enu_rotation(self) -> FloatArray:
        """S_R: rows east, north, up at the antenna in ECEF; r_G = S_R^T r_L + T_R."""
        rotation = enu_rotation(self.lat_deg, self.lon_deg)
        rotation.flags.writeable = False
        return rotation

    @cached_property
    def earth_radius_m(self) -> float:
        """Rc = a(1-e^2)/(1-e^2 sin^2 L)^(3/2), the meridian radius of curvature.

        This is the radius the elevation formula uses, as the domain documents write it.
        The better sphere for all azimuths is the Gaussian mean radius (below), and the
        exact one for one look direction is Euler's radius of that normal section
        (``plots.normal_section_radius_m``); but the horizontal position barely depends
        on the choice: a radius error dR shifts the target's height over the sphere by
        d^2 dR / (2 R^2) at ground distance d, and its horizontal position by only
        tan(elevation at the target) times that (see ``plots``). Against the exact
        ellipsoidal geometry (the tests measure it) the horizontal error is at most 0.7 m
        at 100 NM and 3.1 m at 250 NM with Rc, 1.8 m with the Gaussian radius and 0.3 m
        with the normal section's: all below the 7 m LSB of I040 RHO, so the formula
        keeps the documented radius.
        """
        return float(meridian_radius_m(self.lat_deg))

    @cached_property
    def gaussian_radius_m(self) -> float:
        """sqrt(M N) at the site: the azimuth-independent best sphere."""
        return float(gaussian_radius_m(self.lat_deg))
