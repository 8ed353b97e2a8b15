"""Aircraft truth: geodesic straight legs, turns, climbs, speed changes, interpolation,
velocities, and the traffic generator."""

from __future__ import annotations

import math
import re
import time
from typing import Any

import numpy as np
import pytest
from pyproj import Geod

from tracker_service.simulator.geometry import geometric_height_m, pressure_altitude_ft
from tracker_service.simulator.scenario import Area, Scenario
from tracker_service.simulator.trajectories import (
    RESERVED_CODES,
    Truth,
    area_m2,
    build_truth,
)

GEOD = Geod(ellps="WGS84")
KT = 1852.0 / 3600.0
FT = 0.3048
G0 = 9.80665
A, F = 6378137.0, 1.0 / 298.257223563
E2 = F * (2.0 - F)
R_ISA = 6356766.0


def pressure_m(h_msl: Any) -> Any:
    """Pressure altitude (m) of geometric heights in the standard atmosphere."""
    return pressure_altitude_ft(h_msl) * FT


def scenario(
    aircraft: list[dict[str, Any]], traffic: dict[str, Any] | None = None, duration: float = 600.0
) -> Scenario:
    data: dict[str, Any] = {
        "name": "test",
        "system_centre": {"lat": 50.0, "lon": 5.0},
        "radars": [
            {
                "name": "r",
                "sac": 1,
                "sic": 1,
                "lat": 50.0,
                "lon": 5.0,
                "alt_m": 0.0,
                "antenna_period_s": 4.0,
            }
        ],
        "aircraft": aircraft,
        "duration_s": duration,
    }
    if traffic is not None:
        data["traffic"] = traffic
    return Scenario.model_validate(data)


def one(duration: float = 600.0, dt: float = 0.5, **fields: Any) -> Truth:
    """The truth of a single explicit aircraft (Mode S at 50N 5E unless told)."""
    aircraft = {"lat": 50.0, "lon": 5.0, "address": "3C660C", "callsign": "TEST1"} | fields
    return build_truth(
        scenario([aircraft], duration=duration), np.random.default_rng(1), duration, dt=dt
    )


def ecef(lat: np.ndarray, lon: np.ndarray, h: np.ndarray) -> np.ndarray:
    la, lo = np.radians(lat), np.radians(lon)
    n = A / np.sqrt(1.0 - E2 * np.sin(la) ** 2)
    return np.stack(
        [
            (n + h) * np.cos(la) * np.cos(lo),
            (n + h) * np.cos(la) * np.sin(lo),
            (n * (1.0 - E2) + h) * np.sin(la),
        ]
    )


def ecef_to_enu(d: np.ndarray, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    la, lo = np.radians(lat), np.radians(lon)
    east = -np.sin(lo) * d[0] + np.cos(lo) * d[1]
    north = -np.sin(la) * np.cos(lo) * d[0] - np.sin(la) * np.sin(lo) * d[1] + np.cos(la) * d[2]
    up = np.cos(la) * np.cos(lo) * d[0] + np.cos(la) * np.sin(lo) * d[1] + np.sin(la) * d[2]
    return np.stack([east, north, up])


def radius_along(lat: float, azimuth: float) -> float:
    """Radius of curvature of the ellipsoid along an azimuth (Euler)."""
    w2 = 1.0 - E2 * math.sin(math.radians(lat)) ** 2
    m, n = A * (1.0 - E2) / w2**1.5, A / math.sqrt(w2)
    az = math.radians(azimuth)
    return float(1.0 / (math.cos(az) ** 2 / m + math.sin(az) ** 2 / n))


# --- flight plans -----------------------------------------------------------------------------


def test_a_straight_leg_at_sea_level_is_the_geodesic_flown_at_its_speed() -> None:
    truth = one(fl=0.0, speed_kt=480.0, heading_deg=37.0)
    speed = 480.0 * KT
    azimuth, back, distance = GEOD.inv(5.0, 50.0, truth.lon[0, -1], truth.lat[0, -1])
    assert truth.times[-1] == 600.0
    assert distance == pytest.approx(speed * 600.0, abs=0.01)
    assert azimuth == pytest.approx(37.0, abs=1e-7)
    # The heading at the end is the geodesic's azimuth there, not the initial one.
    assert truth.heading_deg[0, -1] == pytest.approx((back + 180.0) % 360.0, abs=1e-7)
    assert abs(truth.heading_deg[0, -1] - 37.0) > 0.5  # meridian convergence over 144 km


def test_a_straight_leg_at_altitude_stays_on_the_geodesic_and_flies_its_speed_up_there() -> None:
    truth = one(fl=350.0, speed_kt=480.0, heading_deg=300.0)
    h = float(geometric_height_m(35000.0))  # on the pressure level: 18 m above 35,000 ft
    n = truth.times.size
    azimuth, _, distance = GEOD.inv(
        np.full(n - 1, 5.0), np.full(n - 1, 50.0), truth.lon[0, 1:], truth.lat[0, 1:]
    )
    cross_track = np.radians((azimuth - 300.0 + 180.0) % 360.0 - 180.0) * distance
    assert np.abs(cross_track).max() < 0.01  # metres, over 10 minutes
    # The ground projection is shorter by R / (R + h): 250 m less than at sea level.
    r = radius_along(50.0, 300.0)
    assert distance[-1] == pytest.approx(480.0 * KT * 600.0 * r / (r + h), abs=1.0)
    assert np.all(truth.h_msl[0] == h)


def test_a_360_turn_comes_back_to_its_start_with_the_coordinated_roll() -> None:
    speed = 250.0
    truth = one(
        duration=200.0,
        fl=350.0,
        speed_kt=speed / KT,
        heading_deg=10.0,
        legs=[{"duration_s": 120.0, "turn_rate_deg_s": 3.0}],
    )
    k = int(120.0 / truth.dt)
    _, _, miss = GEOD.inv(5.0, 50.0, truth.lon[0, k], truth.lat[0, k])
    assert miss < 1.0  # metres (measured: 8 mm)
    assert truth.heading_deg[0, k] == pytest.approx(10.0, abs=0.01)
    # Halfway round: the far side of a circle of radius V / omega.
    _, _, across = GEOD.inv(5.0, 50.0, truth.lon[0, k // 2], truth.lat[0, k // 2])
    radius = (
        speed
        / math.radians(3.0)
        * radius_along(50.0, 100.0)
        / (radius_along(50.0, 100.0) + 350 * 100 * FT)
    )
    assert across == pytest.approx(2.0 * radius, abs=1.0)
    roll = math.degrees(math.atan(speed * math.radians(3.0) / G0))
    assert truth.roll_deg[0, 10] == pytest.approx(roll, abs=1e-9)
    assert truth.turn_rate_deg_s[0, 10] == pytest.approx(3.0)
    assert truth.roll_deg[0, k] == 0.0 and truth.turn_rate_deg_s[0, k] == 0.0  # leg over
    left = one(
        duration=10.0,
        fl=100.0,
        speed_kt=300.0,
        heading_deg=10.0,
        legs=[{"duration_s": 10.0, "turn_rate_deg_s": -2.0}],
    )
    assert left.roll_deg[0, 0] < 0.0
    assert left.heading_deg[0, -1] == pytest.approx(350.0, abs=0.01)


def test_a_climb_reaches_its_flight_level_and_levels_off() -> None:
    truth = one(
        fl=100.0,
        speed_kt=300.0,
        heading_deg=90.0,
        legs=[{"duration_s": 30.0}, {"duration_s": 500.0, "climb_fpm": 2000.0, "target_fl": 200.0}],
    )
    rate = 2000.0 * FT / 60.0
    t, h, up = truth.times, pressure_m(truth.h_msl[0]), truth.vel_up[0]
    levels_at = 30.0 + 100 * 100 * FT / rate  # 300 s of climb
    climbing = (t > 30.0) & (t < levels_at)
    # Flown in pressure altitude; the geometric climb rate is faster by dh/dHp.
    assert np.allclose(h[climbing], 100 * 100 * FT + rate * (t[climbing] - 30.0), atol=1e-6)
    dh_dhp = (R_ISA / (R_ISA - h[climbing])) ** 2
    assert np.allclose(up[climbing], rate * dh_dhp, rtol=1e-6)
    assert np.all(h[t >= levels_at] == pytest.approx(200 * 100 * FT, abs=1e-6))
    assert np.all(up[t >= levels_at] == 0.0) and np.all(up[t <= 29.5] == 0.0)
    # A descent: the direction comes from the target, whatever the sign of climb_fpm.
    down = one(
        duration=200.0,
        fl=300.0,
        speed_kt=300.0,
        heading_deg=90.0,
        legs=[{"duration_s": 200.0, "climb_fpm": 3000.0, "target_fl": 250.0}],
    )
    assert down.vel_up[0, 0] == pytest.approx(-3000.0 * FT / 60.0, rel=3e-3)
    assert pressure_m(down.h_msl[0, -1]) == pytest.approx(250 * 100 * FT)


def test_a_speed_change_ramps_at_its_acceleration() -> None:
    truth = one(
        duration=60.0,
        fl=0.0,
        speed_kt=250.0,
        heading_deg=0.0,
        legs=[{"duration_s": 60.0, "target_speed_kt": 300.0, "accel_kt_s": 2.0}],
    )
    t, v = truth.times, truth.ground_speed_mps[0] / KT
    ramp = t <= 25.0
    assert np.allclose(v[ramp], 250.0 + 2.0 * t[ramp])
    assert np.allclose(v[~ramp], 300.0)
    # The distance is the integral of that speed profile: 25 s of ramp, then 35 s at 300 kt.
    flown = ((250.0 + 300.0) / 2 * 25.0 + 300.0 * 35.0) * KT
    assert GEOD.inv(5.0, 50.0, truth.lon[0, -1], truth.lat[0, -1])[2] == pytest.approx(
        flown, abs=0.01
    )


def test_legs_that_end_between_samples_are_flown_exactly() -> None:
    # A 10.3 s turn: the heading change is exactly 30.9 degrees whatever the grid.
    truth = one(
        duration=20.0,
        fl=100.0,
        speed_kt=300.0,
        heading_deg=0.0,
        legs=[{"duration_s": 10.3, "turn_rate_deg_s": 3.0}],
    )
    fine = one(
        duration=20.0,
        dt=0.05,
        fl=100.0,
        speed_kt=300.0,
        heading_deg=0.0,
        legs=[{"duration_s": 10.3, "turn_rate_deg_s": 3.0}],
    )
    assert (
        truth.turn_rate_deg_s[0, 20] == pytest.approx(3.0) and truth.turn_rate_deg_s[0, 21] == 0.0
    )
    # 30.9 degrees of turn, plus the meridian convergence of the straight 9.7 s after it.
    assert truth.heading_deg[0, -1] == pytest.approx(fine.heading_deg[0, -1], abs=1e-6)
    assert truth.heading_deg[0, -1] == pytest.approx(30.9, abs=0.02)
    _, _, gap = GEOD.inv(truth.lon[0, -1], truth.lat[0, -1], fine.lon[0, -1], fine.lat[0, -1])
    assert gap < 0.01


# --- interpolation and velocities -------------------------------------------------------------


def test_state_at_stays_within_a_metre_in_a_3_deg_s_turn_at_250_m_s() -> None:
    legs = [{"duration_s": 20.0}, {"duration_s": 120.0, "turn_rate_deg_s": 3.0}]
    fields: dict[str, Any] = {
        "fl": 300.0,
        "speed_kt": 250.0 / KT,
        "heading_deg": 45.0,
        "legs": legs,
    }
    truth = one(duration=180.0, **fields)
    fine = one(duration=180.0, dt=0.05, **fields)
    t = fine.times[:-1]
    state = truth.state_at(np.zeros(t.size, dtype=np.int64), t)
    _, _, error = GEOD.inv(state.lon, state.lat, fine.lon[0, :-1], fine.lat[0, :-1])
    print(f"interpolation error in the turn: max {error.max():.2e} m")
    assert error.max() < 1.0
    assert np.abs(state.h_msl - fine.h_msl[0, :-1]).max() < 1e-6
    turning = (t > 21.0) & (t < 139.0)
    assert np.allclose(state.turn_rate_deg_s[turning], 3.0)
    heading_error = (state.heading_deg - fine.heading_deg[0, :-1] + 180.0) % 360.0 - 180.0
    assert np.abs(heading_error).max() < 0.01
    # Linear interpolation between samples would miss the arc by V^2 dt^2 omega / 8.
    assert 250.0 * 0.5**2 * math.radians(3.0) / 8.0 > 0.4


def test_state_at_broadcasts_and_is_nan_outside_the_lifetime() -> None:
    truth = one(duration=100.3, start_s=3.2, fl=200.0, speed_kt=400.0, heading_deg=0.0)
    assert truth.t0[0] == 3.2 and truth.t1[0] == 100.3
    assert np.isnan(truth.lat[0, :7]).all() and np.isfinite(truth.lat[0, 7:]).all()
    state = truth.state_at(np.zeros((2, 3), dtype=np.int64), np.array([3.1, 3.2, 3.35]))
    assert state.lat.shape == (2, 3)
    assert np.isnan(state.lat[:, 0]).all()
    # At t0 exactly: the start of the flight plan; then the interpolation from it.
    assert state.lat[0, 1] == pytest.approx(50.0, abs=1e-12)
    assert state.lon[0, 1] == pytest.approx(5.0, abs=1e-12)
    _, _, moved = GEOD.inv(5.0, 50.0, state.lon[0, 2], state.lat[0, 2])
    assert moved == pytest.approx(
        400.0 * KT * 0.15 * radius_along(50, 0) / (radius_along(50, 0) + 200 * 100 * FT), abs=1e-3
    )
    end = truth.state_at(np.array([0, 0, 0]), np.array([100.2, 100.3, 100.4]))
    assert np.isfinite(end.lat[:2]).all() and np.isnan(end.lat[2])
    assert end.lat[1] == pytest.approx(truth.end_state.lat[0])
    assert list(truth.alive(np.array([0, 0, 0]), np.array([3.0, 50.0, np.nan]))) == [
        False,
        True,
        False,
    ]
    # Queries on the samples give the samples back.
    on = truth.state_at(np.zeros(3, dtype=np.int64), truth.times[[7, 50, 200]])
    assert np.allclose(on.lat, truth.lat[0, [7, 50, 200]], rtol=0, atol=1e-11)
    assert np.allclose(on.h_msl, truth.h_msl[0, [7, 50, 200]], atol=1e-6)


def test_state_at_follows_climbs_and_turns_that_start_or_stop_between_samples() -> None:
    legs: list[dict[str, Any]] = [
        {"duration_s": 10.3},
        {"duration_s": 30.15, "turn_rate_deg_s": 3.0},
        {"duration_s": 60.0, "climb_fpm": 6000.0, "target_fl": 301.3},  # 43.65 s to 44.95 s
    ]
    fields: dict[str, Any] = {
        "fl": 300.0,
        "speed_kt": 250.0 / KT,
        "heading_deg": 45.0,
        "legs": legs,
    }
    truth = one(duration=60.3, start_s=3.2, **fields)
    fine = one(duration=60.3, dt=0.01, start_s=3.2, **fields)
    alive = fine.times >= 3.2
    t = fine.times[alive]
    state = truth.state_at(np.zeros(t.size, dtype=np.int64), t)
    _, _, error = GEOD.inv(state.lon, state.lat, fine.lon[0, alive], fine.lat[0, alive])
    print(f"across leg changes between samples: max {error.max():.2e} m")
    assert error.max() < 0.2  # the Hermite cubic across a kink in the curvature: ~5 cm
    # Kinks: exact in pressure altitude; the geometric height of a steady pressure climb
    # curves a little (d2h/dHp2 = 2 r^2 / (r - Hp)^3), 30 um over a 0.5 s sample at 6,000 fpm.
    assert np.abs(state.h_msl - fine.h_msl[0, alive]).max() < 1e-4
    # The vertical speed too, except at the very instants of the kinks (either value).
    wrong = t[np.abs(state.vel_up - fine.vel_up[0, alive]) > 1e-3]
    assert np.all(np.isclose(wrong, 43.65) | np.isclose(wrong, 44.95))
    assert fine.times[-1] == 60.3 and np.isfinite(state.lat[-1])


@pytest.mark.parametrize("fl", [0.0, 350.0])
def test_velocities_agree_with_the_positions(fl: float) -> None:
    truth = one(
        fl=fl,
        speed_kt=450.0,
        heading_deg=123.0,
        legs=[
            {"duration_s": 200.0},
            {"duration_s": 100.0, "climb_fpm": 1500.0, "target_fl": fl + 20.0},
        ],
    )
    p = ecef(truth.lat[0], truth.lon[0], truth.h_msl[0])
    central = ecef_to_enu(
        (p[:, 2:] - p[:, :-2]) / (2 * truth.dt), truth.lat[0, 1:-1], truth.lon[0, 1:-1]
    )
    stored = np.stack([truth.vel_east[0], truth.vel_north[0], truth.vel_up[0]])[:, 1:-1]
    t = truth.times[1:-1]
    # Away from the start of the climb and the level-off, where the vertical speed jumps.
    levels_at = 200.0 + 20 * 100 * FT / (1500 * FT / 60)
    steady = (np.abs(t - 200.0) > 0.6) & (np.abs(t - levels_at) > 0.6)
    error = np.abs(central - stored)[:, steady]
    print(f"FL{fl:.0f}: |finite difference - velocity| max {error.max():.1e} m/s")
    assert error.max() < 0.1
    assert np.allclose(np.hypot(truth.vel_east[0], truth.vel_north[0]), 450.0 * KT)


# --- traffic ---------------------------------------------------------------------------------

AREA = {"lat_min": 48.0, "lat_max": 52.0, "lon_min": 2.0, "lon_max": 8.0}


def traffic(**fields: Any) -> Scenario:
    return scenario([], traffic={"count": 2000, "area": AREA} | fields)


def test_the_area_of_a_box_is_the_ellipsoids() -> None:
    # Parallels are not geodesics: densify them so that the polygon follows them.
    lons = np.linspace(2.0, 8.0, 2001)
    lon = np.concatenate([lons, lons[::-1]])
    lat = np.concatenate([np.full(lons.size, 48.0), np.full(lons.size, 52.0)])
    reference, _ = GEOD.polygon_area_perimeter(lon, lat)
    assert area_m2(Area(**AREA)) == pytest.approx(abs(reference), rel=1e-6)


def test_density_gives_the_count_and_positions_fill_the_area() -> None:
    density = 1.336e-3
    scen = scenario([], traffic={"density_per_km2": density, "area": AREA}, duration=10.0)
    truth = build_truth(scen, np.random.default_rng(3), 10.0)
    assert len(truth.identities) == round(density * area_m2(Area(**AREA)) / 1e6)
    lat, lon = truth.lat[:, 0], truth.lon[:, 0]
    assert lat.min() >= 48.0 and lat.max() <= 52.0 and lon.min() >= 2.0 and lon.max() <= 8.0
    # Uniform over the area, not over latitude: slightly more aircraft to the south.
    phi = np.radians(np.linspace(48.0, 52.0, 10001))
    expected = np.average(np.degrees(phi), weights=np.cos(phi))
    assert np.mean(lat) == pytest.approx(expected, abs=4 * 4.0 / math.sqrt(12 * lat.size))


def test_traffic_mix_matches_its_fractions() -> None:
    scen = traffic(
        psr_only_fraction=0.1,
        mode_s_fraction=0.8,
        adsb_fraction=0.5,
        turning_fraction=0.25,
        climbing_fraction=0.2,
        fl_min=100,
        fl_max=390,
    )
    truth = build_truth(scen, np.random.default_rng(5), 600.0)
    ids = truth.identities
    n = len(ids)

    def near(count: int, total: int, p: float) -> bool:
        return abs(count / total - p) < 4.0 * math.sqrt(p * (1 - p) / total)

    kinds = [i.transponder for i in ids]
    squawking = n - kinds.count("none")
    assert near(kinds.count("none"), n, 0.1)
    assert near(kinds.count("mode_s"), squawking, 0.8)
    mode_s = [i for i in ids if i.transponder == "mode_s"]
    assert near(sum(i.adsb for i in mode_s), len(mode_s), 0.5)
    assert all(not i.adsb for i in ids if i.transponder != "mode_s")
    assert all(8 <= i.nacp <= 10 for i in ids if i.adsb)
    turning = np.nanmax(np.abs(truth.turn_rate_deg_s), axis=1) > 0
    climbing = np.nanmax(np.abs(truth.vel_up), axis=1) > 0
    assert not np.any(turning & climbing)
    assert near(int(turning.sum()), n, 0.25) and near(int(climbing.sum()), n, 0.2)
    rates = np.abs(truth.turn_rate_deg_s[turning])
    rates = rates[rates > 0]
    assert rates.min() >= 1.0 and rates.max() <= 3.0
    vertical = np.abs(truth.vel_up[climbing])
    vertical = vertical[vertical > 0] / (FT / 60.0)
    # Geometric rates: the pressure-altitude rates times dh/dHp (<= 0.4 % at FL400 in ISA).
    assert vertical.min() >= 1000.0 - 1e-6 and vertical.max() <= 3000.0 * 1.004
    level_fl = np.round(pressure_m(truth.h_msl[~climbing, 0]) / (100 * FT), 6)
    assert np.allclose(level_fl, np.round(level_fl / 10) * 10)
    assert level_fl.min() >= 100 and level_fl.max() <= 390
    # Climbers end on a 10 FL level, 20 to 100 FL away (unless a limit was in the way).
    first = np.round(pressure_m(truth.h_msl[climbing, 0]) / (100 * FT), 6)
    last = np.round(pressure_m(truth.h_msl[climbing, -1]) / (100 * FT), 6)
    done = np.abs(truth.vel_up[climbing, -1]) == 0
    assert np.allclose(last[done], np.round(last[done] / 10) * 10)
    assert np.all(np.abs(last[done] - first[done]) <= 105.0)
    speeds = truth.ground_speed_mps[:, 0] / KT
    assert speeds.min() >= 250.0 and speeds.max() <= 480.0
    assert np.all(truth.t0 == 0.0) and np.all(truth.t1 == 600.0)
    assert np.isfinite(truth.lat).all()  # generated aircraft exist all the time


def test_identities_are_well_formed_unique_and_shared_on_purpose() -> None:
    scen = scenario(
        [
            {
                "lat": 50.0,
                "lon": 5.0,
                "fl": 100.0,
                "speed_kt": 200.0,
                "heading_deg": 0.0,
                "address": "ABC123",
                "callsign": "EXPL1",
                "mode3a": "4321",
            }
        ],
        traffic={"count": 1500, "area": AREA, "shared_address_pairs": 4, "code_changes": 12},
    )
    truth = build_truth(scen, np.random.default_rng(9), 600.0)
    ids = truth.identities
    assert len(ids) == 1501 and ids[0].callsign == "EXPL1"  # explicit aircraft first
    generated = ids[1:]
    addresses = [i.address for i in generated if i.transponder == "mode_s"]
    assert all(a is not None and re.fullmatch(r"[0-9A-F]{6}", a) for a in addresses)
    assert not {"000000", "FFFFFF", "ABC123"} & set(addresses)
    assert all(i.address is None for i in generated if i.transponder != "mode_s")
    counts: dict[str | None, int] = {}
    for a in addresses:
        counts[a] = counts.get(a, 0) + 1
    assert sorted(counts.values())[-5:] == [1, 2, 2, 2, 2]  # 4 pairs, the rest unique
    callsigns = [i.callsign for i in ids]
    assert len(set(callsigns)) == len(callsigns)
    assert all(re.fullmatch(r"[A-Z]{3}[1-9][0-9]{2,3}", c) for c in callsigns[1:])
    codes = [i.mode3a for i in generated if i.transponder != "none"]
    assert all(c is not None and re.fullmatch(r"[0-7]{4}", c) for c in codes)
    assert not RESERVED_CODES & set(codes) and "4321" not in codes
    assert len(set(codes)) == len(codes)  # distinct while there are codes enough
    assert all(i.mode3a is None for i in generated if i.transponder == "none")
    changed = [i for i in generated if i.code_changes]
    assert len(changed) == 12
    for i in changed:
        ((at_s, new),) = i.code_changes
        assert 60.0 <= at_s <= 540.0 and new != i.mode3a and new not in RESERVED_CODES
        assert i.transponder != "none"


def test_a_seed_gives_the_same_traffic() -> None:
    scen = traffic(count=300, shared_address_pairs=2, code_changes=3)
    a = build_truth(scen, np.random.default_rng(42), 120.0)
    b = build_truth(scen, np.random.default_rng(42), 120.0)
    c = build_truth(scen, np.random.default_rng(43), 120.0)
    assert a.identities == b.identities
    assert np.array_equal(a.lat, b.lat, equal_nan=True)
    assert np.array_equal(a.h_msl, b.h_msl, equal_nan=True)
    assert a.identities != c.identities
    assert not np.array_equal(a.lat, c.lat)


def test_mode3a_at_follows_the_code_changes() -> None:
    truth = one(
        fl=100.0,
        speed_kt=200.0,
        heading_deg=0.0,
        mode3a="1234",
        code_changes=[{"at_s": 300.0, "mode3a": "4567"}, {"at_s": 100.0, "mode3a": "3456"}],
    )
    assert truth.identities[0].code_changes == ((100.0, "3456"), (300.0, "4567"))
    assert truth.mode3a_at(0, 0.0) == "1234"
    assert truth.mode3a_at(0, 99.9) == "1234"
    assert truth.mode3a_at(0, 100.0) == "3456"
    assert truth.mode3a_at(0, 299.0) == "3456"
    assert truth.mode3a_at(0, 300.0) == "4567"


def test_2000_aircraft_for_10_minutes_build_quickly() -> None:
    scen = traffic(shared_address_pairs=5, code_changes=20)
    started = time.perf_counter()
    truth = build_truth(scen, np.random.default_rng(1), 600.0)
    elapsed = time.perf_counter() - started
    print(f"2,000 aircraft x 600 s: truth built in {elapsed:.2f} s")
    assert truth.lat.shape == (2000, 1201)
    assert elapsed < 30.0  # typically ~2 s; generous for slow CI machines


def test_traffic_enters_and_leaves_at_a_constant_count() -> None:
    """With ``mean_flight_s``: exactly ``count`` aircraft in the air between samples (one
    leaves on the sample where the next enters), flights 0.5-1.5x the mean, those entering
    inside the area, and no state outside an aircraft's life."""
    scen = scenario([], traffic={"count": 40, "area": AREA, "mean_flight_s": 120.0}, duration=600)
    truth = build_truth(scen, np.random.default_rng(5), 600.0)
    n = len(truth.identities)
    assert 40 + 600 / 180 * 40 < n < 40 + 600 / 60 * 40  # about 40 + 600 / 120 * 40 = 240
    between = truth.times[:-1] + 0.25
    for t in between[::20]:
        assert truth.alive(np.arange(n), np.full(n, t)).sum() == 40, t
    entering = truth.t0 > 0
    flights = truth.t1[entering & (truth.t1 < 600.0)] - truth.t0[entering & (truth.t1 < 600.0)]
    assert flights.size > 100 and flights.min() >= 59.5 and flights.max() <= 180.5
    assert np.all(truth.t0[entering] % 0.5 == 0) and np.all(truth.t1 % 0.5 == 0)
    first = truth.state_at(np.flatnonzero(entering), truth.t0[entering])
    assert np.all((first.lat >= AREA["lat_min"]) & (first.lat <= AREA["lat_max"]))
    gone = np.flatnonzero(truth.t1 < 590.0)
    assert np.isnan(truth.state_at(gone, truth.t1[gone] + 5.0).lat).all()
    assert np.isfinite(truth.state_at(gone, truth.t1[gone]).lat).all()
    later = truth.lat[gone][:, -1]
    assert np.isnan(later).all()
