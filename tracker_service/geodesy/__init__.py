"""The tracker's geodesy stage: radar plots to one system plane, vectorised over plots.

``RadarSite`` (where a radar is) and ``SystemPlane`` (where every radar's plots meet) are
configured once; ``convert_plots`` turns a batch of one radar's plots (slant range,
azimuth, height from ``HeightModel``) into plane positions and per-plot covariances.
The pieces are public too: ``polar_to_local``/``polar_to_ecef`` (DOMAIN.md section 3's
earth-curvature elevation), ``polar_covariance`` (with the worked checks of DOMAIN.md)
and the WGS84 helpers.

This geometry is independent of the simulator's (``tracker_service.simulator``): nothing
here imports it, so an error common to both cannot cancel in tests against simulated
truth.
"""

from tracker_service.geodesy.atmosphere import Atmosphere
from tracker_service.geodesy.convert import ConvertedPlots, convert_plots
from tracker_service.geodesy.ellipsoid import (
    E2,
    A,
    F,
    ecef_to_geodetic,
    enu_rotation,
    gaussian_radius_m,
    geodetic_to_ecef,
    meridian_radius_m,
    prime_vertical_radius_m,
)
from tracker_service.geodesy.heights import HeightModel, flight_level_to_height_m
from tracker_service.geodesy.plane import PlaneKind, SystemPlane
from tracker_service.geodesy.plots import (
    CovarianceFrame,
    CrossRange,
    SlantGeometry,
    local_to_ecef,
    normal_section_radius_m,
    polar_covariance,
    polar_to_ecef,
    polar_to_local,
    slant_geometry,
)
from tracker_service.geodesy.sites import RadarSite

__all__ = [
    "E2",
    "A",
    "Atmosphere",
    "ConvertedPlots",
    "CovarianceFrame",
    "CrossRange",
    "F",
    "HeightModel",
    "PlaneKind",
    "RadarSite",
    "SlantGeometry",
    "SystemPlane",
    "convert_plots",
    "ecef_to_geodetic",
    "enu_rotation",
    "flight_level_to_height_m",
    "gaussian_radius_m",
    "geodetic_to_ecef",
    "local_to_ecef",
    "meridian_radius_m",
    "normal_section_radius_m",
    "polar_covariance",
    "polar_to_ecef",
    "polar_to_local",
    "prime_vertical_radius_m",
    "slant_geometry",
]
