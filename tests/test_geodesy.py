"""The tracker's geodesy stage: sites, plot conversion, covariances, the system plane.

The truth here is independent of the code under test: targets are placed with pyproj
(geodesic forward problem, EPSG:4979 -> 4978, PROJ's topocentric conversion), and the
covariances are checked against DOMAIN.md's worked numbers and finite differences of the
conversion itself.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pyproj
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tracker_service.geodesy import (
    E2,
    A,
    ConvertedPlots,
    HeightModel,
    RadarSite,
    SystemPlane,
    convert_plots,
    ecef_to_geodetic,
    enu_rotation,
    flight_level_to_height_m,
    geodetic_to_ecef,
    normal_section_radius_m,
    polar_covariance,
    polar_to_ecef,
    polar_to_local,
    slant_geometry,
)

NM = 1852.0
SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "asterix"
# DOMAIN.md section 8's Mosnik, with a plausible geoid and a north offset, so that both are
# exercised.
MOSNIK = RadarSite(48.79621389, 21.54087778, 949.0, geoid_m=45.0, north_offset_deg=0.3)
PLANES = [SystemPlane(48.5, 19.5), SystemPlane(48.5, 19.5, kind="tangent", centre_height_m=300.0)]

GEOD = pyproj.Geod(ellps="WGS84")
GEODETIC_TO_ECEF = pyproj.Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)
ECEF_TO_GEODETIC = pyproj.Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


def topocentric(site: RadarSite) -> Any:
    """PROJ's own geodetic -> ENU at the antenna."""
    return pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 "
        f"+lat_0={site.lat_deg} +lon_0={site.lon_deg} +h_0={site.ellipsoidal_height_m}"
    )


def place_targets(
    site: RadarSite, distance_m: np.ndarray, azimuth_deg: np.ndarray, height_msl_m: np.ndarray
) -> dict[str, np.ndarray]:
    """Targets at a ground distance and azimuth from the site, at heights above a geoid
    that stays at the site's undulation; what the radar measures of them, exactly."""
    lon, lat, _ = GEOD.fwd(
        np.full_like(distance_m, site.lon_deg),
        np.full_like(distance_m, site.lat_deg),
        azimuth_deg,
        distance_m,
    )
    h = height_msl_m + site.geoid_m
    x, y, z = GEODETIC_TO_ECEF.transform(lon, lat, h)
    e, n, u = topocentric(site).transform(lon, lat, h)
    return {
        "lat": np.asarray(lat),
        "lon": np.asarray(lon),
        "h": h,
        "ecef": np.stack([x, y, z], axis=-1),
        "rho": np.sqrt(e * e + n * n + u * u),
        # What the radar reports: its north offset is what must be added back.
        "theta": np.degrees(np.arctan2(e, n)) - site.north_offset_deg,
        "height": height_msl_m,
    }


def horizontal_error(truth: dict[str, np.ndarray], x: Any, y: Any, z: Any) -> np.ndarray:
    d = np.stack([x, y, z], axis=-1) - truth["ecef"]
    local = np.einsum("nij,nj->ni", enu_rotation(truth["lat"], truth["lon"]), d)
    return np.asarray(np.hypot(local[:, 0], local[:, 1]))


def grid_targets(site: RadarSite, distance_nm: float) -> dict[str, np.ndarray]:
    az, fl = np.meshgrid(np.arange(0.0, 360.0, 15.0), np.array([30.0, 100.0, 200.0, 300.0, 450.0]))
    distance = np.full(az.size, distance_nm * NM)
    return place_targets(site, distance, az.ravel(), flight_level_to_height_m(fl.ravel()))


# Sites and WGS84.


def test_wgs84_constants() -> None:
    assert A == 6378137.0
    assert abs(E2 - 0.00669437999014) < 1e-14


def test_site_position_and_enu_rotation_match_pyproj() -> None:
    site = MOSNIK
    x, y, z = GEODETIC_TO_ECEF.transform(site.lon_deg, site.lat_deg, 949.0 + 45.0)
    np.testing.assert_allclose(site.ecef_m, [x, y, z], atol=1e-6)
    s = site.enu_rotation
    np.testing.assert_allclose(s @ s.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(s) == pytest.approx(1.0)
    # ENU of a few points, ours against PROJ's topocentric conversion.
    lat = np.array([48.0, 49.5, 50.2])
    lon = np.array([20.0, 22.7, 21.5])
    h = np.array([10_000.0, 300.0, 12_000.0])
    ours = np.einsum("ij,nj->ni", s, np.stack(geodetic_to_ecef(lat, lon, h), axis=-1) - site.ecef_m)
    np.testing.assert_allclose(
        ours, np.stack(topocentric(site).transform(lon, lat, h), -1), atol=1e-6
    )
    with pytest.raises(AttributeError):
        site.alt_m = 0.0  # type: ignore[misc]


def test_site_earth_radii() -> None:
    site = MOSNIK
    s2 = math.sin(math.radians(site.lat_deg)) ** 2
    rc = A * (1 - E2) / (1 - E2 * s2) ** 1.5
    n = A / math.sqrt(1 - E2 * s2)
    assert site.earth_radius_m == pytest.approx(rc, rel=1e-15)
    assert site.gaussian_radius_m == pytest.approx(math.sqrt(rc * n), rel=1e-15)
    assert rc < site.gaussian_radius_m < n
    np.testing.assert_allclose(normal_section_radius_m(site.lat_deg, [0.0, 90.0]), [rc, n])
    assert RadarSite(45.0, 16.0, 100.0).geoid_m == 0.0
    with pytest.raises(ValueError, match="latitude"):
        RadarSite(91.0, 0.0, 0.0)


def test_geodetic_round_trip() -> None:
    lat = np.array([-89.9, -30.0, 0.0, 48.8, 89.9])
    lon = np.array([-179.0, 10.0, 0.0, 21.5, 120.0])
    h = np.array([0.0, -50.0, 12_000.0, 949.0, 30.0])
    x, y, z = geodetic_to_ecef(lat, lon, h)
    np.testing.assert_allclose(
        np.stack([x, y, z]), GEODETIC_TO_ECEF.transform(lon, lat, h), atol=1e-6
    )
    back = ecef_to_geodetic(x, y, z)
    np.testing.assert_allclose(back[0], lat, atol=1e-10)
    np.testing.assert_allclose(back[1], lon, atol=1e-10)
    np.testing.assert_allclose(back[2], h, atol=1e-5)


# Heights.


def test_flight_level_to_height() -> None:
    assert flight_level_to_height_m(0.0) == 0.0
    assert flight_level_to_height_m(350.0, geometric=False) == pytest.approx(10_668.0)
    r = 6_356_766.0
    assert flight_level_to_height_m(350.0) == pytest.approx(r * 10_668.0 / (r - 10_668.0))
    assert float(flight_level_to_height_m(350.0)) - 10_668.0 == pytest.approx(17.9, abs=0.1)
    plain = flight_level_to_height_m([-10.0, 100.0], geometric=False)
    np.testing.assert_allclose(plain, [-304.8, 3048.0], atol=1e-9)


def test_height_model_falls_back_without_mode_c() -> None:
    model = HeightModel()
    fl = np.array([350.0, np.nan, np.nan])
    height, sigma = model.heights(fl, last_known_height_m=np.array([np.nan, np.nan, 9_000.0]))
    assert height[0] == pytest.approx(float(flight_level_to_height_m(350.0)))
    assert height[1] == pytest.approx(float(flight_level_to_height_m(200.0)))
    assert height[2] == 9_000.0
    assert sigma[0] == pytest.approx(math.hypot(100.0, 0.03 * height[0]))
    assert sigma[1] == model.assumed_sigma_m
    assert sigma[2] == model.last_level_sigma_m
    height, sigma = HeightModel(assumed_height_m=4_000.0, assumed_sigma_m=2_000.0).heights([np.nan])
    assert (height[0], sigma[0]) == (4_000.0, 2_000.0)


# Plot conversion.


@pytest.mark.parametrize(
    ("distance_nm", "bound_m"),
    [(5, 0.05), (20, 0.2), (50, 0.5), (100, 1.0), (150, 1.5), (200, 2.5), (250, 4.0)],
)
def test_conversion_error_against_exact_geometry(distance_nm: float, bound_m: float) -> None:
    """The sphere of radius Rc against the ellipsoid: metres at 250 NM, not hundreds.

    Measured (24 azimuths x FL30-450): max horizontal error 0.03 m at 5 NM, 0.66 m at
    100 NM, 3.1 m at 250 NM with Rc; 1.8 m with the Gaussian radius; 0.27 m with the
    normal-section radius."""
    truth = grid_targets(MOSNIK, distance_nm)
    xyz = polar_to_ecef(MOSNIK, truth["rho"], truth["theta"], truth["height"])
    assert horizontal_error(truth, *xyz).max() < bound_m
    gaussian = polar_to_ecef(
        MOSNIK,
        truth["rho"],
        truth["theta"],
        truth["height"],
        earth_radius_m=MOSNIK.gaussian_radius_m,
    )
    assert horizontal_error(truth, *gaussian).max() < 0.6 * bound_m
    normal = polar_to_ecef(
        MOSNIK,
        truth["rho"],
        truth["theta"],
        truth["height"],
        earth_radius_m=normal_section_radius_m(
            MOSNIK.lat_deg, truth["theta"] + MOSNIK.north_offset_deg
        ),
    )
    assert horizontal_error(truth, *normal).max() < 0.1 * bound_m


def test_local_conversion_formula() -> None:
    """Flat check of the formula's pieces: psi from the law of cosines, x/y/z from psi."""
    site = RadarSite(45.0, 16.0, 500.0, north_offset_deg=-1.0)
    rho, theta, height = 100_000.0, 29.0, 9_000.0
    rc = site.earth_radius_m
    k = rc + 500.0
    sin_psi = (2 * rc * (height - 500.0) + height**2 - 500.0**2 - rho**2) / (2 * rho * k)
    psi = math.asin(sin_psi)
    x, y, z = polar_to_local(site, rho, theta, height)
    assert x == pytest.approx(rho * math.cos(psi) * math.sin(math.radians(28.0)), abs=1e-6)
    assert y == pytest.approx(rho * math.cos(psi) * math.cos(math.radians(28.0)), abs=1e-6)
    assert z == pytest.approx(rho * sin_psi, abs=1e-6)
    # The target really is at the height: distance from the sphere's centre.
    assert math.hypot(math.hypot(x, y), k + z) - rc == pytest.approx(height, abs=1e-6)


def test_unreachable_height_stays_finite() -> None:
    """An assumed FL200 for a plot 3 km out: the target cannot be there; the conversion
    puts it overhead and the covariance stays bounded."""
    geometry = slant_geometry(MOSNIK, 3_000.0, 6_000.0)
    assert geometry.elevation_rad == pytest.approx(math.pi / 2)
    assert geometry.ground_range_m == pytest.approx(0.0, abs=1e-6)
    r = polar_covariance(
        3_000.0, 10.0, 50.0, 0.07, elevation_rad=geometry.elevation_rad, height_sigma_m=3_500.0
    )
    assert np.all(np.isfinite(r))
    assert np.trace(r) <= 3_000.0**2 + 50.0**2 + 1e-6


# Plot covariance: DOMAIN.md's worked checks.


def test_worked_covariance_azimuth_clockwise_from_north() -> None:
    """r = 100 km, theta = 30 deg clockwise from north: the brief's value and sign.

    The off-diagonal is sin(theta) cos(theta) (sigma_r^2 - (r sigma_theta)^2): the
    cross-range spread (122 m) exceeds the range spread (50 m), and at theta = 30 deg the
    cross-range axis runs north-west to south-east, hence negative."""
    r = polar_covariance(100_000.0, 30.0, 50.0, 0.07)
    np.testing.assert_allclose(r, [[11819.69, -5380.73], [-5380.73, 5606.56]], atol=0.01)
    cross = (100_000.0 * math.radians(0.07)) ** 2
    assert r[0, 1] == pytest.approx(
        math.sin(math.radians(30)) * math.cos(math.radians(30)) * (2500 - cross)
    )


def test_worked_covariance_catches_a_mathematical_angle_mix_up() -> None:
    """Reading theta = 30 deg as the mathematical angle (from east, anticlockwise) puts the
    target at azimuth 60 deg: the same off-diagonal, but x and y variances swapped."""
    mixed_up = polar_covariance(100_000.0, 60.0, 50.0, 0.07)
    np.testing.assert_allclose(mixed_up, [[5606.56, -5380.73], [-5380.73, 11819.69]], atol=0.01)
    # And with the range spread dominant the off-diagonal turns positive at azimuth 30.
    assert polar_covariance(100_000.0, 30.0, 200.0, 0.07)[0, 1] > 0


def test_worked_covariance_of_the_thesis() -> None:
    """r = 4949.74 m, sigma_r = 200 m, sigma_theta = 0.3 rad, line of sight at 45 deg."""
    sigma_theta = math.degrees(0.3)
    tan = polar_covariance(4949.74, 45.0, 200.0, sigma_theta, cross_range="tan")
    np.testing.assert_allclose(
        tan, [[1192185.68, -1152185.68], [-1152185.68, 1192185.68]], atol=0.01
    )
    exact = polar_covariance(4949.74, 45.0, 200.0, sigma_theta)
    np.testing.assert_allclose(
        exact, [[1122496.67, -1082496.67], [-1082496.67, 1122496.67]], atol=0.01
    )
    with pytest.raises(ValueError, match="cross_range"):
        polar_covariance(1.0, 0.0, 1.0, 1.0, cross_range="sin")  # type: ignore[arg-type]


@settings(max_examples=200, deadline=None)
@given(
    r=st.floats(100.0, 500_000.0),
    theta=st.floats(0.0, 360.0),
    sigma_r=st.floats(1.0, 500.0),
    sigma_theta=st.floats(0.001, 1.0),
)
def test_covariance_is_the_jacobian_form(
    r: float, theta: float, sigma_r: float, sigma_theta: float
) -> None:
    """J diag(sigma_r^2, sigma_theta^2) J^T, J of x = r sin(theta), y = r cos(theta)."""
    t = math.radians(theta)
    j = np.array([[math.sin(t), r * math.cos(t)], [math.cos(t), -r * math.sin(t)]])
    expected = j @ np.diag([sigma_r**2, math.radians(sigma_theta) ** 2]) @ j.T
    got = polar_covariance(r, theta, sigma_r, sigma_theta)
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9 * np.abs(expected).max())
    assert np.all(np.linalg.eigvalsh(got) >= -1e-9 * np.abs(expected).max())


def fd_jacobian(f: Any, rho: np.ndarray, theta: np.ndarray, height: np.ndarray) -> np.ndarray:
    """d f / d(rho m, theta rad, H m) by central differences; f -> (N, 2)."""
    steps = (0.5, 1e-6, 0.5)
    columns = []
    for i, step in enumerate(steps):
        up = [rho, theta, height]
        down = [rho, theta, height]
        scale = math.degrees(step) if i == 1 else step
        up[i] = up[i] + scale
        down[i] = down[i] - scale
        columns.append((f(*up) - f(*down)) / (2 * step))
    return np.stack(columns, axis=-1)


def propagate(jac: np.ndarray, sigmas: tuple[float, float, float]) -> np.ndarray:
    d = np.diag([s * s for s in sigmas])
    return np.asarray(jac @ d @ np.swapaxes(jac, -1, -2))


SAMPLE_RANGES_NM = np.array([8.0, 20.0, 60.0, 150.0, 250.0, 120.0])
SAMPLE_AZIMUTHS = np.array([10.0, 100.0, 200.0, 300.0, 80.0, 250.0])
SAMPLE_FL = np.array([100.0, 350.0, 250.0, 400.0, 350.0, 100.0])
SIGMAS = (60.0, math.radians(0.08), 300.0)


def test_radar_frame_covariance_is_the_local_jacobian() -> None:
    """frame="radar": the covariance of the local ENU x, y, height share included."""
    site = MOSNIK
    rho = SAMPLE_RANGES_NM * NM
    height = flight_level_to_height_m(SAMPLE_FL)

    def local(rho: np.ndarray, theta: np.ndarray, height: np.ndarray) -> np.ndarray:
        x, y, _ = polar_to_local(site, rho, theta, height)
        return np.stack([x, y], axis=-1)

    expected = propagate(fd_jacobian(local, rho, SAMPLE_AZIMUTHS, height), SIGMAS)
    geometry = slant_geometry(site, rho, height)
    got = polar_covariance(
        rho,
        SAMPLE_AZIMUTHS + site.north_offset_deg,
        SIGMAS[0],
        math.degrees(SIGMAS[1]),
        elevation_rad=geometry.elevation_rad,
        central_angle_rad=geometry.central_angle_rad,
        height_sigma_m=SIGMAS[2],
    )
    np.testing.assert_allclose(got, expected, rtol=1e-5, atol=1e-3)
    # DOMAIN.md: near the radar a 300 m height error moves the ground range by tens of
    # metres (here 8 NM at FL100 and 20 NM at FL350), and by a few metres at long range.
    height_share = np.abs(geometry.height_gain("radar")) * 300.0
    assert 20.0 < height_share[0] < 150.0
    assert 20.0 < height_share[1] < 150.0
    assert height_share[4] < 10.0


@pytest.mark.parametrize("plane", PLANES, ids=lambda p: p.kind)
def test_plane_covariance_is_the_full_jacobian(plane: SystemPlane) -> None:
    """convert_plots' R against finite differences of the whole chain, (rho, theta, H) ->
    plane (x, y): the turn between the norths, the plane's scale and tilt, the height's
    share, each error source on its own.

    The height share agrees to 2 %, not better: the conversion's own "up" at the target
    is the radius of its sphere, which at 250 NM leans about 0.01 deg from the ellipsoid
    normal the covariance uses; on a slide of 17 m per 300 m that is under 1 % (0.2 m)."""
    site = MOSNIK
    rho = SAMPLE_RANGES_NM * NM
    height = flight_level_to_height_m(SAMPLE_FL)

    def to_plane(rho: np.ndarray, theta: np.ndarray, height: np.ndarray) -> np.ndarray:
        out = convert_plots(site, plane, rho, theta, height, 0.0, 1.0, 1.0)
        return np.stack([out.x, out.y], axis=-1)

    jac = fd_jacobian(to_plane, rho, SAMPLE_AZIMUTHS, height)
    for sigmas, rtol in [
        ((SIGMAS[0], 0.0, 0.0), 1e-4),
        ((0.0, SIGMAS[1], 0.0), 1e-5),
        ((0.0, 0.0, SIGMAS[2]), 2e-2),
    ]:
        expected = propagate(jac, sigmas)
        got = convert_plots(
            site, plane, rho, SAMPLE_AZIMUTHS, height, sigmas[2], sigmas[0], math.degrees(sigmas[1])
        ).R
        scale = np.abs(expected).max(axis=(1, 2), keepdims=True)
        assert np.all(np.abs(got - expected) <= rtol * scale), sigmas
    # Together, as the tracker gets them.
    expected = propagate(jac, SIGMAS)
    got = convert_plots(
        site, plane, rho, SAMPLE_AZIMUTHS, height, SIGMAS[2], SIGMAS[0], math.degrees(SIGMAS[1])
    ).R
    np.testing.assert_allclose(got, expected, rtol=1e-3)


# The system plane.


def test_stereographic_plane_matches_pyproj() -> None:
    plane = SystemPlane(45.5, 16.0)
    crs = pyproj.CRS("+proj=sterea +lat_0=45.5 +lon_0=16 +k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m")
    reference = pyproj.Transformer.from_crs("EPSG:4326", crs, always_xy=True)
    lat = np.array([45.5, 46.0, 43.1, 48.9, 44.0])
    lon = np.array([16.0, 20.0, 12.5, 15.0, 21.3])
    e, n = plane.from_geodetic(lat, lon, 10_000.0)
    np.testing.assert_allclose(np.stack([e, n]), reference.transform(lon, lat), atol=1e-6)
    back = plane.to_geodetic(e, n)
    np.testing.assert_allclose(back, [lat, lon], atol=1e-10)
    # The scale and the grid convergence of the local Jacobian, against PROJ's factors.
    factors = pyproj.Proj(crs).get_factors(lon, lat)
    jac = plane.jacobian(lat, lon)
    np.testing.assert_allclose(
        np.hypot(jac[:, 0, 1], jac[:, 1, 1]), factors.meridional_scale, rtol=1e-7
    )
    np.testing.assert_allclose(
        np.hypot(jac[:, 0, 0], jac[:, 1, 0]), factors.parallel_scale, rtol=1e-7
    )
    # PROJ's convergence is positive where true north lies west of grid north.
    grid_bearing_of_north = np.degrees(np.arctan2(jac[:, 0, 1], jac[:, 1, 1]))
    np.testing.assert_allclose(
        grid_bearing_of_north, -np.asarray(factors.meridian_convergence), atol=1e-5
    )
    assert np.all(jac[:, :, 2] == 0.0)


def test_tangent_plane_matches_pyproj() -> None:
    plane = SystemPlane(45.5, 16.0, kind="tangent", centre_height_m=150.0)
    reference = pyproj.Transformer.from_pipeline(
        "+proj=pipeline +step +proj=cart +ellps=WGS84 +step +proj=topocentric +ellps=WGS84 "
        "+lat_0=45.5 +lon_0=16 +h_0=150"
    )
    lat = np.array([45.5, 46.0, 43.1, 48.9, 44.0])
    lon = np.array([16.0, 20.0, 12.5, 15.0, 21.3])
    h = np.array([150.0, 10_000.0, 0.0, 12_500.0, 3_000.0])
    e, n = plane.from_geodetic(lat, lon, h)
    ref_e, ref_n, _ = reference.transform(lon, lat, h)
    np.testing.assert_allclose(np.stack([e, n]), np.stack([ref_e, ref_n]), atol=1e-6)
    back = plane.to_geodetic(e, n, h)
    np.testing.assert_allclose(back, [lat, lon], atol=1e-10)
    np.testing.assert_allclose(plane.jacobian(45.5, 16.0), [[1, 0, 0], [0, 1, 0]], atol=1e-15)


@pytest.mark.parametrize("plane", PLANES, ids=lambda p: p.kind)
def test_plane_ecef_round_trip(plane: SystemPlane) -> None:
    lat = np.array([48.5, 50.0, 46.2, 47.0])
    lon = np.array([19.5, 15.0, 22.8, 18.0])
    h = np.array([0.0, 11_000.0, 6_000.0, 300.0])
    x, y, z = geodetic_to_ecef(lat, lon, h)
    e, n, up = plane.from_ecef(x, y, z)
    np.testing.assert_allclose(up, h, atol=1e-6)
    np.testing.assert_allclose(np.stack(plane.to_ecef(e, n, up)), np.stack([x, y, z]), atol=1e-4)
    np.testing.assert_allclose(
        np.stack(plane.from_geodetic(lat, lon, h)), np.stack([e, n]), atol=1e-6
    )


def test_plane_rejects_unknown_kind() -> None:
    with pytest.raises(ValueError, match="kind"):
        SystemPlane(45.0, 16.0, kind="mercator")  # type: ignore[arg-type]


@pytest.mark.parametrize("plane", PLANES, ids=lambda p: p.kind)
@pytest.mark.parametrize("distance_nm", [30.0, 120.0, 250.0])
def test_plot_through_the_plane_lands_on_its_lat_lon(
    plane: SystemPlane, distance_nm: float
) -> None:
    """radar -> ECEF -> plane -> lat/lon: within a millimetre of PROJ's geodetic position of
    the same ECEF point, and within 1 m of where the target really was (with the
    normal-section radius; Rc's own error is the conversion test's)."""
    truth = grid_targets(MOSNIK, distance_nm)
    radius = normal_section_radius_m(MOSNIK.lat_deg, truth["theta"] + MOSNIK.north_offset_deg)
    out = convert_plots(
        MOSNIK,
        plane,
        truth["rho"],
        truth["theta"],
        truth["height"],
        100.0,
        50.0,
        0.07,
        earth_radius_m=radius,
    )
    x, y, z = polar_to_ecef(
        MOSNIK, truth["rho"], truth["theta"], truth["height"], earth_radius_m=radius
    )
    ref_lon, ref_lat, ref_h = ECEF_TO_GEODETIC.transform(x, y, z)
    lat, lon = plane.to_geodetic(out.x, out.y, ref_h)
    _, _, distance = GEOD.inv(lon, lat, ref_lon, ref_lat)
    assert np.max(distance) < 1e-3
    np.testing.assert_allclose(out.lat_deg, ref_lat, atol=1e-9)
    np.testing.assert_allclose(out.lon_deg, ref_lon, atol=1e-9)
    _, _, from_truth = GEOD.inv(lon, lat, truth["lon"], truth["lat"])
    assert np.max(from_truth) < 1.0


@pytest.mark.parametrize("plane", PLANES, ids=lambda p: p.kind)
def test_covariance_along_the_line_of_sight_stays_along_it(plane: SystemPlane) -> None:
    """A covariance elongated along the radar's line of sight is, in the plane, elongated
    along the direction in which the plot moves when only its range grows. 250 NM east or
    west of the radar the turn between the norths is 4.7 deg, and the grid convergence
    adds to it: without them the axis would be off by as much."""
    site = MOSNIK
    rho = np.array([50.0, 150.0, 250.0, 250.0, 250.0]) * NM
    theta = np.array([45.0, 90.0, 90.0, 270.0, 160.0])
    height = np.full(5, 10_000.0)
    out = convert_plots(site, plane, rho, theta, height, 0.0, 500.0, 0.001)
    further = convert_plots(site, plane, rho + 10.0, theta, height, 0.0, 500.0, 0.001)
    los = np.degrees(np.arctan2(further.x - out.x, further.y - out.y))
    _, vectors = np.linalg.eigh(out.R)
    major = vectors[:, :, 1]
    axis = np.degrees(np.arctan2(major[:, 0], major[:, 1]))
    off = (axis - los + 90.0) % 180.0 - 90.0
    assert np.max(np.abs(off)) < 0.01
    # The same covariance merely scaled into the plane, unturned, would miss it.
    geometry = slant_geometry(site, rho, height)
    at_target = polar_covariance(
        rho,
        theta + site.north_offset_deg,
        500.0,
        0.001,
        elevation_rad=geometry.elevation_rad,
        central_angle_rad=geometry.central_angle_rad,
        frame="target",
    )
    _, unturned = np.linalg.eigh(at_target)
    unturned_axis = np.degrees(np.arctan2(unturned[:, 0, 1], unturned[:, 1, 1]))
    unturned_off = (unturned_axis - los + 90.0) % 180.0 - 90.0
    assert np.max(np.abs(unturned_off)) > 1.0


@pytest.mark.parametrize("plane", PLANES, ids=lambda p: p.kind)
def test_covariance_from_radar_is_what_convert_plots_uses(plane: SystemPlane) -> None:
    """Without a height error the public pieces give convert_plots' R."""
    site = MOSNIK
    rho = SAMPLE_RANGES_NM * NM
    height = flight_level_to_height_m(SAMPLE_FL)
    out = convert_plots(site, plane, rho, SAMPLE_AZIMUTHS, height, 0.0, 60.0, 0.08)
    geometry = slant_geometry(site, rho, height)
    at_target = polar_covariance(
        rho,
        SAMPLE_AZIMUTHS + site.north_offset_deg,
        60.0,
        0.08,
        elevation_rad=geometry.elevation_rad,
        central_angle_rad=geometry.central_angle_rad,
        frame="target",
    )
    x, y, z = polar_to_ecef(site, rho, SAMPLE_AZIMUTHS, height)
    _, _, h = plane.from_ecef(x, y, z)
    turned = plane.covariance_from_radar(site, at_target, out.lat_deg, out.lon_deg, h)
    np.testing.assert_allclose(turned, out.R, rtol=1e-12, atol=1e-9)


# The entry point.


def test_convert_plots_shapes_and_broadcasting() -> None:
    plane = PLANES[0]
    out = convert_plots(
        MOSNIK,
        plane,
        [50_000.0, 90_000.0, 200_000.0],
        [0.0, 120.0, 240.0],
        9_000.0,
        150.0,
        60.0,
        0.08,
    )
    assert len(out) == 3
    for name in ("x", "y", "height_m", "height_sigma_m", "lat_deg", "lon_deg", "elevation_rad"):
        assert getattr(out, name).shape == (3,), name
    assert out.R.shape == (3, 2, 2)
    np.testing.assert_allclose(out.R, np.swapaxes(out.R, -1, -2))
    assert np.all(np.linalg.eigvalsh(out.R) > 0)
    np.testing.assert_array_equal(out.height_m, 9_000.0)
    empty = convert_plots(MOSNIK, plane, [], [], [], [], 60.0, 0.08)
    assert len(empty) == 0
    assert empty.R.shape == (0, 2, 2)


def test_convert_plots_applies_the_north_offset() -> None:
    plane = PLANES[0]
    site = RadarSite(48.0, 20.0, 500.0, north_offset_deg=2.0)
    aligned = RadarSite(48.0, 20.0, 500.0)
    a = convert_plots(site, plane, 100_000.0, 40.0, 9_000.0, 100.0, 60.0, 0.08)
    b = convert_plots(aligned, plane, 100_000.0, 42.0, 9_000.0, 100.0, 60.0, 0.08)
    np.testing.assert_allclose([a.x, a.y], [b.x, b.y], atol=1e-6)
    np.testing.assert_allclose(a.R, b.R, rtol=1e-9)


def test_missing_mode_c_widens_the_covariance_along_the_line_of_sight() -> None:
    """Near the radar an unknown height (FL200 assumed, sigma 3.5 km) is most of the
    ground range error: 25 NM out at FL350, 410 m against 93 m with Mode C."""
    plane = PLANES[0]
    height, sigma = HeightModel().heights([350.0, np.nan])
    out = convert_plots(MOSNIK, plane, 25 * NM, 30.0, height, sigma, 60.0, 0.08)
    along_sigma = np.sqrt(np.linalg.eigvalsh(out.R)[:, 1])
    geometry = slant_geometry(MOSNIK, 25 * NM, height)
    expected = np.hypot(
        60.0 * geometry.range_gain("target"), sigma * geometry.height_gain("target")
    )
    np.testing.assert_allclose(along_sigma, expected, rtol=2e-3)
    assert along_sigma[0] < 100.0
    assert along_sigma[1] > 350.0


# Real data: the radars' own Cartesian positions (I048/042).

CROATIA_PCAP = SHARED_DATA / "croatiacontrol" / "cat_034_048.pcap"
I042_LSB_M = NM / 128.0


def i042_records() -> list[dict[str, Any]]:
    """Unique CAT048 records with I040, I042 and a valid, ungarbled I090."""
    if not CROATIA_PCAP.is_file():
        pytest.skip(
            f"{CROATIA_PCAP} is absent: the shared sample data (GPL) is not beside the repo"
        )
    from asterix import Block, decode_blocks
    from asterix.containers import Datagram, read_file

    seen: set[tuple[Any, ...]] = set()
    records = []
    for unit in read_file(CROATIA_PCAP):
        if not isinstance(unit, Datagram):
            continue
        for event in decode_blocks(unit.payload, unit.offset):
            if not isinstance(event, Block) or event.cat != 48:
                continue
            for record in event.records:
                if not {"040", "042", "090"} <= record.keys():
                    continue
                if record["090"]["V"] or record["090"]["G"]:
                    continue
                # The redundant LAN's copy decodes to the same record.
                key = (
                    record["010"]["SIC"],
                    record["140"],
                    record["040"]["RHO"],
                    record["040"]["THETA"],
                )
                if key not in seen:
                    seen.add(key)
                    records.append(record)
    return records


def test_radars_project_slant_range_into_i042() -> None:
    """I042 against this stage's local-plane conversion of (RHO, THETA, FL).

    The sites of Croatia Control's radars are not published with the capture, so the
    site is a stand-in at 45.5 N; only the earth radius (barely) and the antenna height
    matter, and the finding holds for antennas from sea level to 1,500 m.

    Measured on the 32 unique records (SIC 11-14, 21-202 NM, FL39-400): along the line of
    sight, |I042| - RHO is -48..+9.5 m (median |.| 4.4 m, RMS 9.9 m, all but one within
    the 1/128 NM = 14.5 m LSB); |I042| - ground range is -7 m..+1.5 km (antenna at sea
    level; +1.1 km at 1,500 m), growing with the elevation, and above 100 m on the 11
    records where the two ranges differ that much. So these radars put the slant range,
    not the ground range, on their x/y axes ("slant projection"), and their I042 is no
    better than I040 for geometry. Across the line of sight I042 differs by up to
    0.074 deg (459 m at 191 NM; median 0.012 deg, 38 m): I042 most likely comes from the
    radar's own tracker (I161 and I170 are present), smoothed, while I040 is the plot.
    """
    records = i042_records()
    assert len(records) >= 30
    rho = np.array([r["040"]["RHO"] for r in records]) * NM
    theta = np.array([r["040"]["THETA"] for r in records])
    height = flight_level_to_height_m(np.array([r["090"]["FL"] for r in records]))
    x042 = np.array([r["042"]["X"] for r in records]) * NM
    y042 = np.array([r["042"]["Y"] for r in records]) * NM
    range042 = np.hypot(x042, y042)
    azimuth042 = np.degrees(np.arctan2(x042, y042))

    slant_residual = range042 - rho
    assert np.median(np.abs(slant_residual)) < 0.5 * I042_LSB_M
    assert np.sum(np.abs(slant_residual) > I042_LSB_M) <= 1
    assert np.max(np.abs(slant_residual)) < 60.0

    for antenna_m in (0.0, 500.0, 1500.0):
        site = RadarSite(45.5, 16.0, antenna_m)
        x, y, _ = polar_to_local(site, rho, theta, height)
        ground_residual = range042 - np.hypot(x, y)
        # Where slant and ground range differ by more than 100 m, I042 follows the slant.
        steep = rho - np.hypot(x, y) > 100.0
        assert np.sum(steep) >= 8
        assert np.all(np.abs(ground_residual[steep]) > 90.0)
        assert np.all(np.abs(slant_residual[steep]) < 20.0)

    cross = (azimuth042 - theta + 180.0) % 360.0 - 180.0
    assert np.max(np.abs(cross)) < 0.1


def test_polar_jacobian_matches_finite_differences() -> None:
    # What a range or azimuth bias does to a plot in the plane, checked against converting
    # the plot again with the range and the azimuth nudged.
    site = RadarSite(48.79621389, 21.54087778, 949.0)
    plane = SystemPlane(48.6, 18.6)
    rho = np.array([20e3, 150e3, 380e3])
    theta = np.array([10.0, 200.0, 300.0])
    height = np.array([3000.0, 10000.0, 11000.0])

    def convert(r: Any, t: Any) -> ConvertedPlots:
        return convert_plots(site, plane, r, t, height, 100.0, 50.0, 0.07)

    base = convert(rho, theta)
    longer = convert(rho + 1.0, theta)
    turned = convert(rho, theta + np.degrees(1e-5))
    per_metre = np.stack([longer.x - base.x, longer.y - base.y], axis=-1)
    per_radian = np.stack([turned.x - base.x, turned.y - base.y], axis=-1) / 1e-5
    assert np.allclose(base.polar_jacobian[:, :, 0], per_metre, atol=1e-5)
    assert np.allclose(base.polar_jacobian[:, :, 1], per_radian, rtol=1e-4, atol=5.0)
