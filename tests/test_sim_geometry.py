"""The simulator's geometry, checked against independent computations.

Independent means: closed-form WGS84 formulas written out here, PROJ's topocentric
conversion, pyproj's geodesics, the spherical-earth elevation formula of DOMAIN.md section
3, ICAO standard atmosphere table values, and EGM96 values read from NGA's 15-minute grid.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pyproj import Geod, Transformer

from tracker_service.simulator import geometry
from tracker_service.simulator.geometry import (
    FT_M,
    WGS84_A_M,
    WGS84_E2,
    WGS84_F,
    FloatArray,
    RadarSite,
    ecef_to_geodetic,
    enu,
    geodetic_to_ecef,
    geoid_undulation_m,
    geometric_height_m,
    line_of_sight,
    measure,
    pressure_altitude_ft,
)

NM = 1852.0
GEOD = Geod(ellps="WGS84")
MOSNIK = RadarSite(48.79621389, 21.54087778, 949.0)


def _angle_diff_deg(a: object, b: object) -> FloatArray:
    """Smallest signed difference a - b between angles, in degrees."""
    return np.asarray((np.asarray(a) - np.asarray(b) + 180.0) % 360.0 - 180.0, dtype=np.float64)


def _meridian_radius_m(lat_deg: float) -> float:
    # DOMAIN.md's Rc = a (1 - e^2) / (1 - e^2 sin^2 L)^(3/2).
    s2 = math.sin(math.radians(lat_deg)) ** 2
    return float(WGS84_A_M * (1 - WGS84_E2) / (1 - WGS84_E2 * s2) ** 1.5)


def _target(
    site: RadarSite, azimuth_deg: float, distance_m: float, h_msl_m: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF of a point ``distance_m`` along the geodesic from the site, at a height above MSL."""
    lon, lat, _ = GEOD.fwd(site.lon_deg, site.lat_deg, azimuth_deg, distance_m)
    return geodetic_to_ecef(lat, lon, h_msl_m + geoid_undulation_m(lat, lon))


# --- WGS84 --------------------------------------------------------------------------------


def test_constants_are_wgs84() -> None:
    assert pytest.approx(1 / 298.257223563, rel=1e-15) == WGS84_F
    assert pytest.approx(0.00669437999014, rel=1e-12) == WGS84_E2


def test_ecef_of_known_points() -> None:
    b = WGS84_A_M * (1 - WGS84_F)
    cases = [
        ((0, 0, 0), (WGS84_A_M, 0, 0)),
        ((0, 90, 0), (0, WGS84_A_M, 0)),
        ((90, 0, 0), (0, 0, b)),
        ((-90, 0, 100), (0, 0, -b - 100)),
        ((0, 180, 1000), (-WGS84_A_M - 1000, 0, 0)),
    ]
    for (lat, lon, h), expected in cases:
        assert np.allclose(geodetic_to_ecef(lat, lon, h), expected, rtol=0, atol=1e-6)


def test_ecef_matches_the_closed_form() -> None:
    rng = np.random.default_rng(1)
    lat = rng.uniform(-90, 90, 500)
    lon = rng.uniform(-180, 180, 500)
    h = rng.uniform(-500, 20000, 500)
    n = WGS84_A_M / np.sqrt(1 - WGS84_E2 * np.sin(np.radians(lat)) ** 2)
    la, lo = np.radians(lat), np.radians(lon)
    expected = (
        (n + h) * np.cos(la) * np.cos(lo),
        (n + h) * np.cos(la) * np.sin(lo),
        (n * (1 - WGS84_E2) + h) * np.sin(la),
    )
    for got, want in zip(geodetic_to_ecef(lat, lon, h), expected, strict=True):
        assert np.max(np.abs(got - want)) < 1e-6


def test_geodetic_round_trip() -> None:
    rng = np.random.default_rng(2)
    lat = rng.uniform(-90, 90, 2000)
    lon = rng.uniform(-180, 180, 2000)
    h = rng.uniform(-1000, 30000, 2000)
    lat2, lon2, h2 = ecef_to_geodetic(*geodetic_to_ecef(lat, lon, h))
    # PROJ's inverse (Bowring's closed form) is good to about 10 micrometres at 30 km.
    assert np.max(np.abs(lat2 - lat)) < 1e-9
    # Longitude is undefined at the poles: compare it where it means something.
    away = np.abs(lat) < 89.999
    assert np.max(np.abs(_angle_diff_deg(lon2[away], lon[away]))) < 1e-9
    assert np.max(np.abs(h2 - h)) < 1e-4


@settings(max_examples=200, deadline=None)
@given(
    st.floats(-90, 90),
    st.floats(-180, 180),
    st.floats(-1000, 50000),
)
def test_ecef_round_trip_property(lat: float, lon: float, h: float) -> None:
    x, y, z = geodetic_to_ecef(lat, lon, h)
    assert np.allclose(geodetic_to_ecef(*ecef_to_geodetic(x, y, z)), (x, y, z), rtol=0, atol=1e-4)


def test_functions_broadcast_scalars_and_arrays() -> None:
    x, y, z = geodetic_to_ecef([48.0, 49.0], 17.0, [[0.0], [1000.0]])
    assert x.shape == y.shape == z.shape == (2, 2)
    _, _, h = ecef_to_geodetic(x, y, z)
    assert np.allclose(h, [[0, 0], [1000, 1000]], atol=1e-6)
    scalar = geodetic_to_ecef(48.0, 17.0, 0.0)
    assert all(isinstance(c, np.ndarray) and c.shape == () for c in scalar)
    assert geoid_undulation_m([[48.0], [49.0]], [16.0, 17.0, 18.0]).shape == (2, 3)
    assert pressure_altitude_ft([0.0, 1000.0], 1003.0).shape == (2,)
    rho, az, el = measure(MOSNIK, *scalar)
    assert rho.shape == az.shape == el.shape == ()
    assert line_of_sight(MOSNIK, x, y, z).shape == (2, 2)
    assert line_of_sight(MOSNIK, *scalar).dtype == np.bool_


def test_impossible_latitude_is_refused() -> None:
    with pytest.raises(ValueError, match="latitude"):
        geodetic_to_ecef(91.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        geoid_undulation_m(-100.0, 0.0)
    with pytest.raises(ValueError, match="latitude"):
        RadarSite(95.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="non-finite"):
        RadarSite(45.0, math.nan, 0.0)


# --- Geoid --------------------------------------------------------------------------------

# EGM96 from NGA's 15-minute grid (WW15MGH), bilinearly interpolated at the point.
EGM96_REFERENCE = [
    (48.79621389, 21.54087778, 39.86),  # Mosnik
    (49.65964167, 16.13339444, 45.13),  # Buchtuv kopec
    (47.29415556, 17.75358056, 45.01),  # Koris-hegy
    (50.0, 15.0, 44.80),  # grid nodes: exact up to rounding
    (45.0, 20.0, 44.01),
    (50.0, 20.0, 40.01),
    (0.0, 0.0, 17.16),
    (-40.0, 175.0, 12.88),
    (90.0, 0.0, 13.61),
    (-90.0, 0.0, -29.53),
]


@pytest.mark.parametrize(("lat", "lon", "expected"), EGM96_REFERENCE)
def test_geoid_close_to_egm96(lat: float, lon: float, expected: float) -> None:
    # 2.5 m: the docstring's worst case between 48 and 50 N, 16 and 22 E is 2.3 m.
    assert float(geoid_undulation_m(lat, lon)) == pytest.approx(expected, abs=2.5)


def test_geoid_in_central_europe() -> None:
    lat, lon = np.meshgrid(np.linspace(48, 50, 9), np.linspace(16, 22, 25))
    n = geoid_undulation_m(lat, lon)
    # EGM96 itself spans 35.2-46.3 m in this box; DOMAIN.md says "about 45 m".
    assert n.min() > 35.0
    assert n.max() < 47.0
    assert 38.0 < float(n.mean()) < 45.0


def test_geoid_is_continuous_across_seams_and_poles() -> None:
    lat = np.linspace(-89.9, 89.9, 50)
    assert np.allclose(geoid_undulation_m(lat, 180.0), geoid_undulation_m(lat, -180.0))
    assert np.allclose(geoid_undulation_m(lat, 360.0), geoid_undulation_m(lat, 0.0))
    assert np.allclose(geoid_undulation_m(lat, -1e-9), geoid_undulation_m(lat, 0.0))
    assert np.allclose(geoid_undulation_m(lat, 370.0), geoid_undulation_m(lat, 10.0))
    around = geoid_undulation_m(90.0, np.arange(-180, 180, 7.0))
    assert np.ptp(around) < 1e-12
    # No jumps: 0.01 degree steps move N by far less than a metre anywhere.
    fine = np.arange(-180.0, 180.0, 0.01)
    assert np.max(np.abs(np.diff(geoid_undulation_m(47.3, fine)))) < 0.1
    assert np.max(np.abs(np.diff(geoid_undulation_m(np.arange(-90, 90, 0.01), 17.0)))) < 0.1


def test_geoid_propagates_nan() -> None:
    n = geoid_undulation_m([math.nan, 48.0], [17.0, math.inf])
    assert np.isnan(n).all()


# --- Atmosphere ---------------------------------------------------------------------------


def test_standard_atmosphere_is_the_geopotential_conversion() -> None:
    # In ISA a pressure altitude is the geopotential height, r h / (r + h).
    r = 6356766.0
    h = np.array([-300.0, 0.0, 1000.0, 9144.0, 11000.0, 15000.0, 20000.0])
    assert np.allclose(pressure_altitude_ft(h), r * h / (r + h) / FT_M, rtol=0, atol=1e-6)
    ft = np.array([-1000.0, 0.0, 30000.0, 36089.0, 45000.0, 65000.0])
    hp = ft * FT_M
    assert np.allclose(geometric_height_m(ft), r * hp / (r - hp), rtol=0, atol=1e-6)
    # FL350 is 17.9 m above 35,000 ft geometric.
    assert float(geometric_height_m(35000.0)) - 10668.0 == pytest.approx(17.9, abs=0.1)


def test_pressure_follows_the_icao_table() -> None:
    # Standard atmosphere pressures (hPa) at geopotential heights, the module's height.
    table = {0.0: 1013.25, 1000.0: 898.75, 5000.0: 540.20, 11000.0: 226.32, 20000.0: 54.749}
    p = geometry._pressure_hpa(np.array(list(table)), np.array(1013.25), np.array(0.0))
    assert np.allclose(p, list(table.values()), rtol=2e-5)


def test_low_qnh_raises_pressure_altitude_at_sea_level() -> None:
    # About 27-28 ft per hPa near sea level: 10.25 hPa is about 280 ft.
    assert float(pressure_altitude_ft(0.0, 1003.0)) == pytest.approx(281.0, abs=5.0)
    assert float(pressure_altitude_ft(0.0, 1023.0)) == pytest.approx(-267.0, abs=5.0)
    # At sea level the temperature does not matter: QNH is the pressure there.
    assert float(pressure_altitude_ft(0.0, 1003.0, 25.0)) == pytest.approx(281.0, abs=5.0)


def test_warm_air_puts_a_flight_level_higher() -> None:
    true_ft = float(geometric_height_m(30000.0, 1013.25, 15.0)) / FT_M
    # ISA + 15 K: T/T_ISA = 303.15 / 288.15, 5.2 %, about 1,560 ft at FL300, in
    # geopotential height (the geometric one is 0.15 % more again).
    assert 1450.0 < true_ft - 30000.0 < 1750.0
    r_ft = 6356766.0 / FT_M
    geopotential_ft = r_ft * true_ft / (r_ft + true_ft)
    assert geopotential_ft / 30000.0 == pytest.approx(303.15 / 288.15, rel=1e-9)
    cold_ft = float(geometric_height_m(30000.0, 1013.25, -15.0)) / FT_M
    assert -1650.0 < cold_ft - 30000.0 < -1350.0
    assert float(pressure_altitude_ft(true_ft * FT_M, 1013.25, 15.0)) == pytest.approx(30000.0)


def test_atmosphere_is_continuous_at_the_tropopause() -> None:
    h = 11000.0 + np.array([-1e-3, 0.0, 1e-3])
    for qnh, dt in [(1013.25, 0.0), (990.0, -20.0), (1030.0, 25.0)]:
        fl = pressure_altitude_ft(h, qnh, dt)
        assert np.all(np.diff(fl) > 0) and np.ptp(fl) < 0.01


@settings(max_examples=300, deadline=None)
@given(st.floats(-500, 20000), st.floats(940, 1060), st.floats(-40, 40))
def test_atmosphere_round_trip(h: float, qnh: float, dt: float) -> None:
    fl = pressure_altitude_ft(h, qnh, dt)
    assert float(geometric_height_m(fl, qnh, dt)) == pytest.approx(h, abs=1e-6)


# --- Radar site and measurement -----------------------------------------------------------


def test_site_position_and_frame() -> None:
    n = float(geoid_undulation_m(MOSNIK.lat_deg, MOSNIK.lon_deg))
    assert MOSNIK.h_ellipsoid_m == pytest.approx(949.0 + n)
    assert np.allclose(
        MOSNIK.ecef_m, geodetic_to_ecef(MOSNIK.lat_deg, MOSNIK.lon_deg, 949.0 + n), atol=1e-9
    )
    rot = MOSNIK.enu_rotation
    assert np.allclose(rot @ rot.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    # Up is the ellipsoid normal: moving up along it changes only the geodetic height.
    lat, lon, h = ecef_to_geodetic(*(MOSNIK.ecef_m + 1000.0 * rot[2]))
    assert float(lat) == pytest.approx(MOSNIK.lat_deg, abs=1e-10)
    assert float(lon) == pytest.approx(MOSNIK.lon_deg, abs=1e-10)
    assert float(h) == pytest.approx(MOSNIK.h_ellipsoid_m + 1000.0, abs=1e-6)
    with pytest.raises(ValueError):
        MOSNIK.ecef_m[0] = 0.0


def test_enu_matches_proj_topocentric() -> None:
    topo = Transformer.from_pipeline(
        f"+proj=topocentric +ellps=WGS84 +lat_0={MOSNIK.lat_deg} +lon_0={MOSNIK.lon_deg} "
        f"+h_0={MOSNIK.h_ellipsoid_m}"
    )
    rng = np.random.default_rng(3)
    lat = MOSNIK.lat_deg + rng.uniform(-4, 4, 300)
    lon = MOSNIK.lon_deg + rng.uniform(-6, 6, 300)
    x, y, z = geodetic_to_ecef(lat, lon, rng.uniform(0, 13000, 300))
    expected = topo.transform(x, y, z)
    for got, want in zip(enu(MOSNIK, x, y, z), expected, strict=True):
        assert np.max(np.abs(got - want)) < 1e-5
    rho, _, _ = measure(MOSNIK, x, y, z)
    assert np.allclose(rho, np.linalg.norm(np.array(expected), axis=0), rtol=1e-12)


def test_azimuth_is_clockwise_from_true_north() -> None:
    rot = MOSNIK.enu_rotation
    # Local axes from the textbook formulas, not from the site's matrix.
    lat, lon = math.radians(MOSNIK.lat_deg), math.radians(MOSNIK.lon_deg)
    east = np.array([-math.sin(lon), math.cos(lon), 0.0])
    north = np.array(
        [-math.sin(lat) * math.cos(lon), -math.sin(lat) * math.sin(lon), math.cos(lat)]
    )
    assert np.allclose(rot[0], east) and np.allclose(rot[1], north)
    for direction, expected_az in [(north, 0.0), (east, 90.0), (-north, 180.0), (-east, 270.0)]:
        _, az, el = measure(MOSNIK, *(MOSNIK.ecef_m + 5000.0 * direction))
        assert abs(float(_angle_diff_deg(az, expected_az))) < 1e-9
        assert 0.0 <= float(az) < 360.0
        assert float(el) == pytest.approx(0.0, abs=1e-9)


def test_target_straight_north_and_east() -> None:
    # Same longitude: the meridian plane holds the antenna's normal, so azimuth is 0 exactly.
    x, y, z = geodetic_to_ecef(MOSNIK.lat_deg + 1.0, MOSNIK.lon_deg, MOSNIK.h_ellipsoid_m)
    assert abs(float(_angle_diff_deg(measure(MOSNIK, x, y, z)[1], 0.0))) < 1e-9
    x, y, z = geodetic_to_ecef(MOSNIK.lat_deg - 1.0, MOSNIK.lon_deg, 5000.0)
    assert float(measure(MOSNIK, x, y, z)[1]) == pytest.approx(180.0, abs=1e-9)
    # Leaving due east along a geodesic: 90 degrees, not 0 (nor 270: clockwise).
    x, y, z = _target(MOSNIK, 90.0, 20000.0, MOSNIK.alt_msl_m)
    assert float(measure(MOSNIK, x, y, z)[1]) == pytest.approx(90.0, abs=1e-3)
    # A point on the same parallel lies a little south of east: the parallel curves away.
    x, y, z = geodetic_to_ecef(MOSNIK.lat_deg, MOSNIK.lon_deg + 1.0, MOSNIK.h_ellipsoid_m)
    assert 89.0 < float(measure(MOSNIK, x, y, z)[1]) < 90.0


def test_azimuth_matches_the_geodesic_for_a_target_at_the_same_height() -> None:
    azimuths = np.arange(0.0, 360.0, 15.0)
    for distance in (1000.0, 50000.0, 250000.0):
        lon, lat, _ = GEOD.fwd(
            np.full(azimuths.size, MOSNIK.lon_deg),
            np.full(azimuths.size, MOSNIK.lat_deg),
            azimuths,
            np.full(azimuths.size, distance),
        )
        x, y, z = geodetic_to_ecef(lat, lon, MOSNIK.h_ellipsoid_m)
        _, az, _ = measure(MOSNIK, x, y, z)
        # Normal section versus geodesic and the skew of the normals: about 1e-5 deg.
        assert np.max(np.abs(_angle_diff_deg(az, azimuths))) < 1e-4
        assert np.all((az >= 0.0) & (az < 360.0))


def test_elevation_includes_the_earth_curvature() -> None:
    site = MOSNIK
    rc = _meridian_radius_m(site.lat_deg)
    ground = 100000.0
    h_site = site.h_ellipsoid_m
    h_target = h_site + 10000.0
    x, y, z = _target(site, 0.0, ground, 0.0)
    lat, lon, _ = ecef_to_geodetic(x, y, z)
    rho, az, el = measure(site, *geodetic_to_ecef(lat, lon, h_target))
    # Spherical earth of the local radius: the target sits at central angle ground / Rc.
    gamma = ground / rc
    sphere = math.degrees(
        math.atan2(
            (rc + h_target) * math.cos(gamma) - (rc + h_site), (rc + h_target) * math.sin(gamma)
        )
    )
    assert float(el) == pytest.approx(sphere, abs=2e-4)
    # DOMAIN.md's elevation from slant range and the two heights, same sphere.
    psi = math.asin(
        (2 * rc * (h_target - h_site) + h_target**2 - h_site**2 - float(rho) ** 2)
        / (2 * float(rho) * (rc + h_site))
    )
    assert float(el) == pytest.approx(math.degrees(psi), abs=2e-4)
    # Flat earth would say atan(10/100) = 5.71 deg; the earth drops away by about
    # ground / (2 Rc) = 0.45 deg, so the radar sees about 5.26 deg.
    flat = math.degrees(math.atan2(10000.0, ground))
    assert flat - float(el) == pytest.approx(math.degrees(ground / (2 * rc)), abs=0.02)
    assert 5.2 < float(el) < 5.3
    assert float(_angle_diff_deg(az, 0.0)) == pytest.approx(0.0, abs=1e-9)


def test_measure_of_the_antenna_itself() -> None:
    rho, az, el = measure(MOSNIK, *MOSNIK.ecef_m)
    assert float(rho) == 0.0 and float(az) == 0.0 and float(el) == 0.0


# --- Coverage -----------------------------------------------------------------------------


def _fl300_at(site: RadarSite, distance_nm: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    h_msl = float(geometric_height_m(30000.0))
    azimuths = np.arange(0.0, 360.0, 30.0)
    lon, lat, _ = GEOD.fwd(
        np.full(azimuths.size, site.lon_deg),
        np.full(azimuths.size, site.lat_deg),
        azimuths,
        np.full(azimuths.size, distance_nm * NM),
    )
    return geodetic_to_ecef(lat, lon, h_msl + geoid_undulation_m(lat, lon))


def test_fl300_visible_at_200_nm_not_at_300_nm() -> None:
    site = RadarSite(48.8, 21.5, 900.0)
    assert line_of_sight(site, *_fl300_at(site, 200.0)).all()
    assert not line_of_sight(site, *_fl300_at(site, 300.0)).any()


def test_horizon_matches_the_textbook_formula() -> None:
    site = RadarSite(48.8, 21.5, 900.0)
    # d_max = sqrt(2 kR h_a) + sqrt(2 kR h_t), R the local radius: about 280 NM here.
    radius = (4 / 3) * math.sqrt(
        _meridian_radius_m(48.8)
        * WGS84_A_M
        / math.sqrt(1 - WGS84_E2 * math.sin(math.radians(48.8)) ** 2)
    )
    d_max = math.sqrt(2 * radius * 900.0) + math.sqrt(2 * radius * 9144.0)
    assert 275.0 < d_max / NM < 285.0
    assert line_of_sight(site, *_fl300_at(site, (d_max - 4000.0) / NM)).all()
    assert not line_of_sight(site, *_fl300_at(site, (d_max + 4000.0) / NM)).any()


def test_a_lower_target_near_the_radar_is_visible() -> None:
    # Below the antenna's horizontal plane (negative elevation) yet above the horizon.
    site = RadarSite(48.8, 21.5, 900.0)
    x, y, z = _target(site, 45.0, 20000.0, 300.0)
    assert float(measure(site, x, y, z)[2]) < 0.0
    assert bool(line_of_sight(site, x, y, z))


def test_surface_targets_and_refraction() -> None:
    site = RadarSite(48.8, 21.5, 900.0)
    # The antenna's own horizon over the sea: sqrt(2 * 4/3 R * 900 m), about 124 km.
    assert bool(line_of_sight(site, *_target(site, 10.0, 110000.0, 0.0)))
    assert not bool(line_of_sight(site, *_target(site, 10.0, 135000.0, 0.0)))
    # Without refraction (k = 1) the horizon for FL300 shrinks from about 280 NM to 242 NM.
    at_260 = _fl300_at(site, 260.0)
    assert line_of_sight(site, *at_260).all()
    assert not line_of_sight(site, *at_260, k_factor=1.0).any()
    with pytest.raises(ValueError, match="k_factor"):
        line_of_sight(site, *at_260, k_factor=0.0)


def test_the_antenna_sees_itself() -> None:
    assert bool(line_of_sight(MOSNIK, *MOSNIK.ecef_m))
