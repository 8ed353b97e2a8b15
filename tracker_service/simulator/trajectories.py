"""Aircraft truth of a scenario: where every aircraft is, sampled every ``dt`` seconds.

Conventions (the radar and ADS-B models rely on them):

* Heights. Aircraft fly on pressure levels, as their altimeters make them: a flight
  plan's levels and climb rates are pressure altitude (FL f is f * 100 ft of it, a
  climb's ``climb_fpm`` its rate, what the vertical speed indicator shows), integrated as
  such, and the truth is the geometric height of that pressure altitude above MSL in the
  scenario's atmosphere (``geometry.geometric_height_m``: QNH and temperature offset), its
  vertical speed scaled by the same conversion. So Mode C reports the flight plan's level
  in any atmosphere, and the geometric height differs from it as it does in reality (ISA
  - 15 K puts FL350 about 600 m lower).
* Speeds. There is no wind: speed = ground speed = true airspeed, and the heading is the
  track angle over ground (clockwise from true north). Speeds are the aircraft's speed at
  its own height: the step along the ellipsoid surface is shortened by R / (R + h), R the
  radius of curvature in the direction of flight, so that finite differences of the 3-D
  (ECEF) positions agree with ``vel_east/north/up``. At FL350 this is 0.17 %, 0.4 m/s.
* Horizontal motion. Fixed steps of ``dt`` (0.5 s) with ``pyproj.Geod.fwd``, vectorised
  over aircraft. A step of a constant-rate turn goes along its chord: at the heading
  plus half the heading change, for ``2 R_turn sin(dpsi / 2)``, and the new heading is
  the geodesic's azimuth at the end of the chord (back azimuth + 180) plus the other
  half. That is exact for a circle on a plane, and for no turn it is a chain of geodesic
  pieces that continue each other: a straight leg is a geodesic.
* Flight plans. Each leg acts only during its ``duration_s``: it turns at its rate,
  climbs or descends at ``|climb_fpm|`` towards ``target_fl`` (the sign comes from the
  target; it levels off on reaching it) and changes speed at ``accel_kt_s`` towards
  ``target_speed_kt``. Zero or unset means none of that during the leg (a ``target_fl``
  without ``climb_fpm`` does nothing). After the last leg the aircraft flies straight
  and level at constant speed to the end of the scenario. Leg ends need not fall on the
  sample grid: the integration stops at them.
* Lifetime. An explicit aircraft exists from ``start_s`` to the end of the scenario,
  generated ones for the whole scenario, or, with ``mean_flight_s``, from when they enter
  to when they leave (on the sample grid); aircraft leaving the traffic area keep flying.
  ``start_s`` need not be on the grid either: ``Truth.start_state``/``end_state`` hold
  the exact states at ``t0``/``t1``, so ``state_at`` covers the whole lifetime.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np
import numpy.typing as npt
from pyproj import Geod

from tracker_service.simulator.geometry import geometric_height_m
from tracker_service.simulator.scenario import NM, Aircraft, Area, Atmosphere, Scenario, Traffic

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Transponder = Literal["mode_s", "mode_ac", "none"]

DT = 0.5  # s, sampling step of the stored tracks and integration step
FT = 0.3048
KT = 1852.0 / 3600.0
FPM = FT / 60.0
G0 = 9.80665  # standard gravity, for the coordinated-turn roll angle

_GEOD = Geod(ellps="WGS84")
_A = 6378137.0
_F = 1.0 / 298.257223563
_E2 = _F * (2.0 - _F)
# Times closer than this are the same instant (sums of leg durations carry rounding).
_EPS = 1e-9

# Codes with a meaning (hijack, radio failure, emergency, conspicuity, VFR, test/monitor
# and the "no code" 0000): random traffic must not squawk them by accident.
RESERVED_CODES = frozenset({"7500", "7600", "7700", "7000", "2000", "1200", "7777", "0000"})

# Generated traffic (times in seconds).
TURN_RATE_DEG_S = (1.0, 3.0)
TURN_DURATION_S = (30.0, 120.0)
STRAIGHT_BETWEEN_TURNS_S = (30.0, 180.0)
FIRST_TURN_BEFORE_S = 120.0
CLIMB_FPM = (1000.0, 3000.0)
CLIMB_BY_FL = (20.0, 100.0)
CLIMB_STARTS_BEFORE_S = 300.0
ADSB_NACP = (8, 10)
CODE_CHANGE_WINDOW = (0.1, 0.9)  # fraction of the scenario: both codes get seen

_FIELDS = (
    "lat",
    "lon",
    "h_msl",
    "vel_east",
    "vel_north",
    "vel_up",
    "heading_deg",
    "ground_speed_mps",
    "roll_deg",
    "turn_rate_deg_s",
)


@dataclass(frozen=True)
class Identity:
    """What an aircraft's transponder and ADS-B would say about it."""

    callsign: str
    address: str | None
    transponder: Transponder
    adsb: bool
    nacp: int
    mode3a: str | None
    """Initial Mode 3/A code."""
    code_changes: tuple[tuple[float, str], ...]
    """(scenario time s, new code), in time order."""
    adsb_offset_m: tuple[float, float] = (0.0, 0.0)
    """(east, north) offset of its ADS-B positions from the truth: a spoofed transponder."""


@dataclass
class State:
    """Aircraft states; every array has the shape of the query."""

    lat: FloatArray
    lon: FloatArray
    h_msl: FloatArray
    vel_east: FloatArray
    vel_north: FloatArray
    vel_up: FloatArray
    heading_deg: FloatArray
    ground_speed_mps: FloatArray
    roll_deg: FloatArray
    turn_rate_deg_s: FloatArray

    @staticmethod
    def nan(shape: tuple[int, ...]) -> State:
        return State(*(np.full(shape, np.nan) for _ in _FIELDS))


@dataclass
class Truth:
    """Sampled aircraft tracks: arrays (n_aircraft, n_samples), NaN outside [t0, t1]."""

    identities: list[Identity]
    dt: float
    t0: FloatArray
    t1: FloatArray
    times: FloatArray
    lat: FloatArray
    lon: FloatArray
    h_msl: FloatArray
    vel_east: FloatArray
    vel_north: FloatArray
    vel_up: FloatArray
    heading_deg: FloatArray
    ground_speed_mps: FloatArray
    roll_deg: FloatArray
    turn_rate_deg_s: FloatArray
    start_state: State
    """Per aircraft, the exact state at t0 (t0 need not be a sample time)."""
    end_state: State
    """Per aircraft, the exact state at t1 (t1 need not be a sample time)."""

    def alive(self, aircraft: npt.ArrayLike, t: npt.ArrayLike) -> BoolArray:
        """Whether each aircraft exists at each time (arrays of the same shape)."""
        a, tt = np.broadcast_arrays(np.asarray(aircraft, dtype=np.int64), _floats(t))
        with np.errstate(invalid="ignore"):  # NaN times are simply not alive
            return np.asarray((tt >= self.t0[a]) & (tt <= self.t1[a]), dtype=np.bool_)

    def state_at(self, aircraft: npt.ArrayLike, t: npt.ArrayLike) -> State:
        """States at arbitrary times, NaN where the aircraft does not exist.

        Positions: cubic Hermite between the two samples around ``t``, in ECEF with the
        stored velocities rotated from ENU. ECEF because it is smooth everywhere (no
        longitude wrap, no pole), and its error in a 3 deg/s turn at 250 m/s is tens of
        micrometres. For that conversion ``h_msl`` stands in for the ellipsoidal height:
        it is only the interpolation's coordinate system, converted back the same way.
        Other quantities are linear (the heading the short way round); the horizontal
        velocity is rebuilt from the interpolated speed and heading, so it stays
        consistent with them. Where the vertical speed differs at the two ends (a climb
        starting or levelling off between samples) the height profile has one kink: the
        Hermite cubic would miss it by metres, so height and vertical speed come from the
        two straight lines through the ends instead, which is exact.
        """
        a_in, t_in = np.broadcast_arrays(np.asarray(aircraft, dtype=np.int64), _floats(t))
        shape = a_in.shape
        a_all, t_all = a_in.ravel(), t_in.ravel()
        out = State.nan((a_all.size,))
        sel = np.flatnonzero(self.alive(a_all, t_all))
        if sel.size:
            values = self._interpolate(a_all[sel], t_all[sel])
            for name in _FIELDS:
                getattr(out, name)[sel] = getattr(values, name)
        return State(*(getattr(out, name).reshape(shape) for name in _FIELDS))

    def mode3a_at(self, aircraft: int, t: float) -> str | None:
        """The Mode 3/A code set at time ``t`` (whether or not the aircraft exists)."""
        identity = self.identities[aircraft]
        code = identity.mode3a
        for at_s, new_code in identity.code_changes:
            if t >= at_s:
                code = new_code
        return code

    def _interpolate(self, a: IntArray, t: FloatArray) -> State:
        n_samples = self.times.size
        k = np.clip(np.floor(t / self.dt).astype(np.int64), 0, n_samples - 1)
        right_k = np.minimum(k + 1, n_samples - 1)
        # Before the first sample of an aircraft that started off the grid, the left end
        # is its exact start state; after its last sample, the right end its end state.
        head = self.times[k] < self.t0[a] - _EPS
        tail = (k + 1 >= n_samples) | (self.times[right_k] > self.t1[a] + _EPS)
        t_left = np.where(head, self.t0[a], self.times[k])
        t_right = np.where(tail, self.t1[a], self.times[right_k])
        left = self._samples(a, k, head, self.start_state)
        right = self._samples(a, right_k, tail, self.end_state)
        span = t_right - t_left
        safe = np.where(span > 0.0, span, 1.0)
        s = np.clip(np.where(span > 0.0, (t - t_left) / safe, 0.0), 0.0, 1.0)

        p0 = _geodetic_to_ecef(left.lat, left.lon, left.h_msl)
        p1 = _geodetic_to_ecef(right.lat, right.lon, right.h_msl)
        v0 = _enu_to_ecef(left.vel_east, left.vel_north, left.vel_up, left.lat, left.lon)
        v1 = _enu_to_ecef(right.vel_east, right.vel_north, right.vel_up, right.lat, right.lon)
        s2, s3 = s * s, s * s * s
        h00, h10 = 2 * s3 - 3 * s2 + 1, (s3 - 2 * s2 + s) * span
        h01, h11 = -2 * s3 + 3 * s2, (s3 - s2) * span
        x, y, z = (h00 * p0[i] + h10 * v0[i] + h01 * p1[i] + h11 * v1[i] for i in range(3))
        lat, lon, h = _ecef_to_geodetic(x, y, z)

        # Height is piecewise linear: with one kink between the ends, it is the lower of
        # the two lines when the vertical speed drops there, the higher when it rises.
        up0, up1 = left.vel_up, right.vel_up
        from_left = left.h_msl + up0 * (t - t_left)
        from_right = right.h_msl - up1 * (t_right - t)
        kink = up0 != up1
        use_left = np.where(up0 > up1, from_left <= from_right, from_left >= from_right)
        h = np.where(kink, np.where(use_left, from_left, from_right), h)

        def lerp(name: str) -> FloatArray:
            lo, hi = getattr(left, name), getattr(right, name)
            return np.asarray(lo + (hi - lo) * s, dtype=np.float64)

        turned = (right.heading_deg - left.heading_deg + 180.0) % 360.0 - 180.0
        heading = (left.heading_deg + turned * s) % 360.0
        speed = lerp("ground_speed_mps")
        psi = np.radians(heading)
        return State(
            lat=lat,
            lon=lon,
            h_msl=h,
            vel_east=speed * np.sin(psi),
            vel_north=speed * np.cos(psi),
            vel_up=np.where(kink, np.where(use_left, up0, up1), up0),
            heading_deg=heading,
            ground_speed_mps=speed,
            roll_deg=lerp("roll_deg"),
            turn_rate_deg_s=lerp("turn_rate_deg_s"),
        )

    def _samples(self, a: IntArray, k: IntArray, exact: BoolArray, state: State) -> State:
        """Stored samples (a, k), or ``state[a]`` where ``exact``."""
        return State(
            *(
                np.where(exact, getattr(state, name)[a], getattr(self, name)[a, k])
                for name in _FIELDS
            )
        )


# --- flight plans as flat arrays of segments ------------------------------------------------


@dataclass
class _Segments:
    """Every aircraft's flight plan, one row per leg, aircraft after aircraft.

    ``offset[i]`` is aircraft i's first row; its last row is the open-ended straight and
    level flight (``end`` = inf), so the integration never runs past an aircraft's rows.
    """

    offset: IntArray
    end: FloatArray  # scenario time s at which the segment ends
    omega: FloatArray  # turn rate, rad/s, positive right
    climb: FloatArray  # vertical speed magnitude, m/s; 0 = level
    h_target: FloatArray  # m, where a climb or descent levels off; NaN = none
    accel: FloatArray  # m/s^2, magnitude
    v_target: FloatArray  # m/s; NaN = keep the speed

    @staticmethod
    def concat(parts: list[_Segments]) -> _Segments:
        shifts = np.cumsum([0] + [p.end.size for p in parts[:-1]])
        return _Segments(
            offset=np.concatenate([p.offset + s for p, s in zip(parts, shifts, strict=True)]),
            end=np.concatenate([p.end for p in parts]),
            omega=np.concatenate([p.omega for p in parts]),
            climb=np.concatenate([p.climb for p in parts]),
            h_target=np.concatenate([p.h_target for p in parts]),
            accel=np.concatenate([p.accel for p in parts]),
            v_target=np.concatenate([p.v_target for p in parts]),
        )


@dataclass
class _Start:
    """Initial conditions and end of life (inf: the end of the run), one per aircraft."""

    t0: FloatArray
    lat: FloatArray
    lon: FloatArray
    h: FloatArray
    heading: FloatArray
    speed: FloatArray
    t1: FloatArray

    @staticmethod
    def concat(parts: list[_Start]) -> _Start:
        return _Start(
            *(
                np.concatenate([getattr(p, name) for p in parts])
                for name in ("t0", "lat", "lon", "h", "heading", "speed", "t1")
            )
        )


def _explicit(aircraft: list[Aircraft]) -> tuple[list[Identity], _Start, _Segments]:
    identities = [
        Identity(
            callsign=ac.callsign,
            address=ac.address,
            transponder=ac.transponder,
            adsb=ac.adsb,
            nacp=ac.nacp,
            mode3a=ac.mode3a,
            code_changes=tuple(sorted((c.at_s, c.mode3a) for c in ac.code_changes)),
            adsb_offset_m=(
                ac.adsb_offset_nm * NM * math.sin(math.radians(ac.adsb_offset_bearing_deg)),
                ac.adsb_offset_nm * NM * math.cos(math.radians(ac.adsb_offset_bearing_deg)),
            ),
        )
        for ac in aircraft
    ]
    start = _Start(
        t0=_floats([ac.start_s for ac in aircraft]),
        lat=_floats([ac.lat for ac in aircraft]),
        lon=_floats([ac.lon for ac in aircraft]),
        h=_floats([ac.fl * 100.0 * FT for ac in aircraft]),
        heading=_floats([ac.heading_deg % 360.0 for ac in aircraft]),
        speed=_floats([ac.speed_kt * KT for ac in aircraft]),
        t1=np.full(len(aircraft), np.inf),
    )
    offset: list[int] = []
    rows: list[tuple[float, float, float, float, float, float]] = []
    for ac in aircraft:
        offset.append(len(rows))
        t = ac.start_s
        for leg in ac.legs:
            t += leg.duration_s
            target_h = math.nan if leg.target_fl is None else leg.target_fl * 100.0 * FT
            target_v = math.nan if leg.target_speed_kt is None else leg.target_speed_kt * KT
            rows.append(
                (
                    t,
                    math.radians(leg.turn_rate_deg_s),
                    abs(leg.climb_fpm) * FPM,
                    target_h,
                    leg.accel_kt_s * KT,
                    target_v,
                )
            )
        rows.append((math.inf, 0.0, 0.0, math.nan, 0.0, math.nan))
    table = np.array(rows, dtype=np.float64).reshape(-1, 6)
    segments = _Segments(np.array(offset, dtype=np.int64), *(table[:, i].copy() for i in range(6)))
    return identities, start, segments


# --- generated traffic ------------------------------------------------------------------------


def area_m2(area: Area) -> float:
    """Area of a latitude/longitude box on the WGS84 ellipsoid, m^2."""
    _, cumulative, width = _latitude_cdf(area)
    return float(cumulative[-1] * width)


def _latitude_cdf(area: Area) -> tuple[FloatArray, FloatArray, float]:
    # dA = M N cos(phi) dphi dlambda: integrated on a fine grid, it both gives the area and,
    # inverted, draws latitudes uniformly over the area (denser towards the equator).
    phi = np.radians(np.linspace(area.lat_min, area.lat_max, 4097))
    w2 = 1.0 - _E2 * np.sin(phi) ** 2
    density = _A * (1.0 - _E2) / w2**1.5 * (_A / np.sqrt(w2)) * np.cos(phi)
    steps = 0.5 * (density[1:] + density[:-1]) * np.diff(phi)
    cumulative = np.concatenate([[0.0], np.cumsum(steps)])
    return phi, cumulative, math.radians(area.lon_max - area.lon_min)


def traffic_count(traffic: Traffic) -> int:
    if traffic.count is not None:
        return traffic.count
    assert traffic.density_per_km2 is not None  # the model insists on one of the two
    return round(traffic.density_per_km2 * area_m2(traffic.area) / 1e6)


def _round_to(x: FloatArray, step: float) -> FloatArray:
    return np.asarray(np.maximum(np.round(x / step), 1.0) * step, dtype=np.float64)


def _lifetimes(
    traffic: Traffic, rng: np.random.Generator, duration_s: float, dt: float
) -> tuple[FloatArray, FloatArray]:
    """(t0, t1) of every generated aircraft, those in the air at the start first.

    Without ``mean_flight_s`` the ``count`` aircraft fly the whole scenario. With it, each
    of ``count`` places in the air holds one flight after another, each 0.5-1.5 times the
    mean long; the one under way at the start is a random part of its flight through.
    Times are on the sample grid, so that a flight's ends are samples.
    """
    n = traffic_count(traffic)
    if traffic.mean_flight_s is None:
        return np.zeros(n), np.full(n, np.inf)
    mean = traffic.mean_flight_s
    per_place = math.ceil(duration_s / (0.5 * mean)) + 1
    flights = rng.uniform(0.5 * mean, 1.5 * mean, (n, per_place))
    flights[:, 0] *= rng.random(n)
    ends = _round_to(np.cumsum(flights, axis=1), dt)
    starts = np.concatenate([np.zeros((n, 1)), ends[:, :-1]], axis=1)
    flying = starts < duration_s
    order = np.argsort(starts[flying], kind="stable")
    return starts[flying][order], ends[flying][order]


def _generated(
    traffic: Traffic,
    rng: np.random.Generator,
    duration_s: float,
    dt: float,
    taken: list[Identity],
) -> tuple[list[Identity], _Start, _Segments]:
    t0, t1 = _lifetimes(traffic, rng, duration_s, dt)
    n = t0.size
    area = traffic.area
    phi, cumulative, _ = _latitude_cdf(area)
    lat = np.degrees(np.interp(rng.random(n) * cumulative[-1], cumulative, phi))
    lon = rng.uniform(area.lon_min, area.lon_max, n)
    heading = rng.uniform(0.0, 360.0, n)
    speed = rng.uniform(traffic.speed_min_kt, traffic.speed_max_kt, n) * KT
    fl = rng.uniform(traffic.fl_min, traffic.fl_max, n)
    kind = rng.random(n)
    # Exclusive kinds; if the two fractions add up to more than 1, climbing gets the rest.
    turning = kind < traffic.turning_fraction
    climbing = ~turning & (kind < traffic.turning_fraction + traffic.climbing_fraction)
    # Level aircraft cruise at a multiple of 10 FL, within the limits when one fits there.
    lowest, highest = math.ceil(traffic.fl_min / 10) * 10, math.floor(traffic.fl_max / 10) * 10
    if lowest <= highest:
        fl = np.where(climbing, fl, np.clip(np.round(fl / 10.0) * 10.0, lowest, highest))
    start = _Start(t0, lat, lon, fl * 100.0 * FT, heading, speed, t1)
    segments = _generated_plans(traffic, rng, duration_s, dt, t0, fl, turning, climbing)
    identities = _generated_identities(traffic, rng, duration_s, n, taken)
    return identities, start, segments


def _generated_plans(
    traffic: Traffic,
    rng: np.random.Generator,
    duration_s: float,
    dt: float,
    t0: FloatArray,
    fl: FloatArray,
    turning: BoolArray,
    climbing: BoolArray,
) -> _Segments:
    # A padded table (aircraft x legs) with a validity mask, flattened row by row at the
    # end. Leg durations are whole steps, so generated aircraft never need a sub-step.
    n = fl.size
    cycles = math.ceil(duration_s / (STRAIGHT_BETWEEN_TURNS_S[0] + TURN_DURATION_S[0])) + 1
    width = 2 * cycles + 1  # straight, turn, straight, turn, ..., open end
    shape = (n, width)
    duration = np.zeros(shape)
    omega = np.zeros(shape)
    climb = np.zeros(shape)
    h_target = np.full(shape, np.nan)
    valid = np.zeros(shape, dtype=np.bool_)

    turners = np.flatnonzero(turning)
    m = turners.size
    straight = rng.uniform(*STRAIGHT_BETWEEN_TURNS_S, (m, cycles))
    straight[:, 0] = rng.uniform(0.0, min(FIRST_TURN_BEFORE_S, 0.5 * duration_s), m)
    turn = rng.uniform(*TURN_DURATION_S, (m, cycles))
    rate = rng.uniform(*TURN_RATE_DEG_S, (m, cycles)) * rng.choice([-1.0, 1.0], (m, cycles))
    duration[turners, 0:-1:2] = _round_to(straight, dt)
    duration[turners, 1:-1:2] = _round_to(turn, dt)
    omega[turners, 1:-1:2] = np.radians(rate)

    climbers = np.flatnonzero(climbing)
    m = climbers.size
    fpm = rng.uniform(*CLIMB_FPM, m)
    up = rng.random(m) < 0.5
    by = rng.uniform(*CLIMB_BY_FL, m)
    first = fl[climbers]
    # Climb or descend as drawn unless that leaves [fl_min, fl_max]; end on a 10 FL level.
    up = np.where(
        first + by > traffic.fl_max, False, np.where(first - by < traffic.fl_min, True, up)
    )
    target = np.clip(
        np.round((first + np.where(up, by, -by)) / 10.0) * 10.0, traffic.fl_min, traffic.fl_max
    )
    climb_s = np.abs(target - first) * 100.0 * FT / (fpm * FPM)
    duration[climbers, 0] = _round_to(
        rng.uniform(0.0, min(CLIMB_STARTS_BEFORE_S, 0.5 * duration_s), m), dt
    )
    duration[climbers, 1] = np.ceil(climb_s / dt) * dt + dt  # room to level off
    climb[climbers, 1] = fpm * FPM
    h_target[climbers, 1] = target * 100.0 * FT
    valid[climbers, :2] = True

    # Each plan starts when its aircraft enters (t0, 0 for those flying from the start).
    ends = t0[:, None] + np.cumsum(duration, axis=1)
    valid[turners, :-1] = (ends - duration)[turners, :-1] < duration_s
    valid[:, -1] = True
    ends[:, -1] = np.inf
    counts = valid.sum(axis=1)
    return _Segments(
        offset=(np.cumsum(counts) - counts).astype(np.int64),
        end=ends[valid],
        omega=omega[valid],
        climb=climb[valid],
        h_target=h_target[valid],
        accel=np.zeros(int(counts.sum())),
        v_target=np.full(int(counts.sum()), np.nan),
    )


def _generated_identities(
    traffic: Traffic,
    rng: np.random.Generator,
    duration_s: float,
    n: int,
    taken: list[Identity],
) -> list[Identity]:
    """Transponders, addresses, callsigns and codes of the generated aircraft.

    Every aircraft gets a callsign (a label for the truth; what is transmitted is the
    radar model's business), PSR-only ones no code and no address, Mode A/C ones no
    address. Aircraft without ADS-B get NACp 0 ("unknown"). Shared address pairs and code
    changes are capped at what the drawn Mode S / squawking aircraft allow.
    """
    psr_only = rng.random(n) < traffic.psr_only_fraction
    mode_s = ~psr_only & (rng.random(n) < traffic.mode_s_fraction)
    adsb = mode_s & (rng.random(n) < traffic.adsb_fraction)
    nacp = np.where(adsb, rng.integers(ADSB_NACP[0], ADSB_NACP[1] + 1, n), 0)

    # Addresses: unique, never 000000 or FFFFFF, none already used by explicit aircraft.
    used = {int(i.address, 16) for i in taken if i.address is not None}
    squitters = np.flatnonzero(mode_s)
    drawn = rng.choice(0xFFFFFE, size=squitters.size + len(used), replace=False) + 1
    fresh = [int(x) for x in drawn if int(x) not in used][: squitters.size]
    address: list[str | None] = [None] * n
    for i, value in zip(squitters, fresh, strict=True):
        address[i] = f"{value:06X}"
    # Shared addresses: the second of each pair takes the first's (as many as there are).
    pairs = min(traffic.shared_address_pairs, squitters.size // 2)
    sharing = rng.choice(squitters, size=2 * pairs, replace=False)
    for first, second in zip(sharing[0::2], sharing[1::2], strict=True):
        address[second] = address[first]

    callsigns = _callsigns(rng, n, {i.callsign for i in taken})

    # Mode 3/A: distinct codes while the 4,096 last (then repeats, as in real traffic).
    squawkers = np.flatnonzero(~psr_only)
    changes = min(traffic.code_changes, squawkers.size)
    changing = rng.choice(squawkers, size=changes, replace=False)
    change_at = rng.uniform(*CODE_CHANGE_WINDOW, changes) * duration_s
    avoid = RESERVED_CODES.union(
        code for i in taken for code in [i.mode3a, *(c for _, c in i.code_changes)] if code
    )
    pool = [f"{c:04o}" for c in range(4096) if f"{c:04o}" not in avoid]
    needed = squawkers.size + changes
    picks = rng.choice(len(pool), size=needed, replace=needed > len(pool))
    codes: list[str | None] = [None] * n
    for i, pick in zip(squawkers, picks[: squawkers.size], strict=True):
        codes[i] = pool[pick]
    code_changes: list[tuple[tuple[float, str], ...]] = [()] * n
    for i, at_s, pick in zip(changing, change_at, picks[squawkers.size :], strict=True):
        code_changes[i] = ((float(at_s), pool[pick]),)

    transponder: list[Transponder] = [
        "none" if p else "mode_s" if s else "mode_ac" for p, s in zip(psr_only, mode_s, strict=True)
    ]
    return [
        Identity(
            callsign=callsigns[i],
            address=address[i],
            transponder=transponder[i],
            adsb=bool(adsb[i]),
            nacp=int(nacp[i]),
            mode3a=codes[i],
            code_changes=code_changes[i],
        )
        for i in range(n)
    ]


def _callsigns(rng: np.random.Generator, n: int, used: set[str]) -> list[str]:
    """Unique callsigns of 3 letters and 3 or 4 digits (no leading zero), e.g. 'KLM1234'."""
    out: list[str] = [""] * n
    seen = set(used)
    todo = np.arange(n)
    while todo.size:
        letters = rng.integers(0, 26, (todo.size, 3))
        long = rng.random(todo.size) < 0.5
        number = np.where(
            long, rng.integers(1000, 10000, todo.size), rng.integers(100, 1000, todo.size)
        )
        again = []
        for i, chars, digits in zip(todo, letters, number, strict=True):
            name = "".join(chr(65 + int(c)) for c in chars) + str(int(digits))
            if name in seen:
                again.append(i)
            else:
                seen.add(name)
                out[i] = name
        todo = np.array(again, dtype=np.int64)
    return out


# --- integration ------------------------------------------------------------------------------


class _Integrator:
    """All aircraft flown together, step by step, each from its own current time."""

    def __init__(self, start: _Start, segments: _Segments, atmosphere: Atmosphere) -> None:
        self.seg = segments
        self.atmosphere = atmosphere
        self.t = start.t0.copy()  # each aircraft's own clock: where its state is
        self.lat = start.lat.copy()
        self.lon = start.lon.copy()
        self.h = start.h.copy()
        self.heading = start.heading.copy()
        self.speed = start.speed.copy()
        self.row = segments.offset.copy()
        # The current segment's controls, refreshed only when an aircraft changes leg.
        self.end = segments.end[self.row]
        self.omega = segments.omega[self.row]
        self.climb = segments.climb[self.row]
        self.h_target = segments.h_target[self.row]
        self.accel = segments.accel[self.row]
        self.v_target = segments.v_target[self.row]
        self.everyone = np.arange(start.t0.size)

    def advance_to(self, t: float) -> None:
        """Fly every aircraft whose clock is before ``t`` up to ``t``, stopping at leg ends."""
        while True:
            pending = self.t < t - _EPS
            if not pending.any():
                return
            idx: slice | IntArray = slice(None) if pending.all() else np.flatnonzero(pending)
            until = np.minimum(t, self.end[idx])
            self._step(idx, until - self.t[idx])
            self.t[idx] = until
            rows = self.everyone[idx]
            done = rows[until >= self.end[idx] - _EPS]
            if done.size:
                self.row[done] += 1
                for name in ("end", "omega", "climb", "h_target", "accel", "v_target"):
                    getattr(self, name)[done] = getattr(self.seg, name)[self.row[done]]

    def _step(self, idx: slice | IntArray, step: FloatArray) -> None:
        """One step of constant controls: exact for speed and height, chord for the turn."""
        lat, lon, h, speed = self.lat[idx], self.lon[idx], self.h[idx], self.speed[idx]
        accel = self.accel[idx]

        # Speed ramps at accel until the target, then holds: distance integrated exactly.
        dv = np.nan_to_num(self.v_target[idx] - speed)
        sign = np.sign(dv)
        ramp = np.where(
            accel > 0.0, np.minimum(step, np.abs(dv) / np.where(accel > 0, accel, 1)), 0
        )
        new_speed = speed + sign * accel * ramp
        distance = speed * ramp + 0.5 * sign * accel * ramp**2 + new_speed * (step - ramp)

        # Height (pressure altitude): linear at the climb rate, levelling off exactly at the
        # target.
        dh = np.nan_to_num(self.h_target[idx] - h)
        move = np.sign(dh) * np.minimum(self.climb[idx] * step, np.abs(dh))
        h_mid = self._geometric(h + 0.5 * move)

        # Turn: along the chord, half the heading change before it and half after.
        dpsi = self.omega[idx] * step
        half_deg = np.degrees(0.5 * dpsi)
        chord = distance * np.sinc(dpsi / (2.0 * np.pi))  # np.sinc(x) = sin(pi x) / (pi x)
        azimuth = self.heading[idx] + half_deg
        # Flown at height h_mid, the ground projection is shorter by R / (R + h).
        sin_lat = np.sin(np.radians(lat))
        w2 = 1.0 - _E2 * sin_lat**2
        m_radius = _A * (1.0 - _E2) / w2**1.5
        n_radius = _A / np.sqrt(w2)
        az = np.radians(azimuth)
        radius = 1.0 / (np.cos(az) ** 2 / m_radius + np.sin(az) ** 2 / n_radius)
        ground = chord * radius / (radius + h_mid)
        lon2, lat2, back = _GEOD.fwd(lon, lat, azimuth, ground)

        self.lat[idx] = lat2
        self.lon[idx] = lon2
        self.h[idx] = h + move
        self.speed[idx] = new_speed
        # The geodesic continues at back azimuth + 180; the turn adds its second half.
        self.heading[idx] = (np.asarray(back) + 180.0 + half_deg) % 360.0

    def _geometric(self, pressure_altitude_m: FloatArray) -> FloatArray:
        """Geometric height above MSL of pressure altitudes (m) in the scenario's atmosphere."""
        a = self.atmosphere
        return geometric_height_m(pressure_altitude_m / FT, a.qnh_hpa, a.temperature_offset_k)

    def snapshot(self) -> State:
        """The state of every aircraft at its own clock (controls of the leg it is in)."""
        dh = np.nan_to_num(self.h_target - self.h)
        h_msl = self._geometric(self.h)
        # The geometric climb rate: the pressure-altitude rate times dh/dHp (about T/T_ISA).
        scale = self._geometric(self.h + 0.5) - self._geometric(self.h - 0.5)
        vel_up = np.where(np.abs(dh) > 1e-9, np.sign(dh) * self.climb * scale, 0.0)
        psi = np.radians(self.heading)
        return State(
            lat=self.lat.copy(),
            lon=self.lon.copy(),
            h_msl=h_msl,
            vel_east=self.speed * np.sin(psi),
            vel_north=self.speed * np.cos(psi),
            vel_up=vel_up,
            heading_deg=self.heading.copy(),
            ground_speed_mps=self.speed.copy(),
            roll_deg=np.degrees(np.arctan(self.speed * self.omega / G0)),
            turn_rate_deg_s=np.degrees(self.omega),
        )


def build_truth(
    scenario: Scenario, rng: np.random.Generator, duration_s: float, *, dt: float = DT
) -> Truth:
    """The truth of every aircraft of ``scenario`` from 0 to ``duration_s``.

    Explicit aircraft come first, then the generated traffic (drawn from ``rng`` only, so a
    seed gives the same traffic). ``dt`` is both the integration step and the sample step.
    Traffic is planned over the scenario's own duration whatever ``duration_s`` is, so a
    shorter run is the start of the full one, not other traffic.
    """
    identities, start, segments = _explicit(scenario.aircraft)
    if scenario.traffic is not None:
        planned = max(duration_s, scenario.duration_s)
        more, more_start, more_segments = _generated(scenario.traffic, rng, planned, dt, identities)
        identities = identities + more
        start = _Start.concat([start, more_start])
        segments = _Segments.concat([segments, more_segments])
    n = len(identities)
    n_samples = math.floor(duration_s / dt + 1e-9) + 1
    times = np.arange(n_samples, dtype=np.float64) * dt
    # No sample after t1, even by a rounding error (state_at would call it dead).
    times[-1] = min(times[-1], float(duration_s))
    t0 = start.t0
    t1 = np.minimum(start.t1, float(duration_s))

    flight = _Integrator(start, segments, scenario.atmosphere)
    start_state = flight.snapshot()
    # Written column by column: measured faster than sample-major rows plus a transpose.
    stored = {name: np.full((n, n_samples), np.nan) for name in _FIELDS}
    for k, t in enumerate(times):
        flight.advance_to(float(t))
        started = t0 <= t + _EPS
        state = flight.snapshot()
        for name in _FIELDS:
            values = getattr(state, name)
            if started.all():
                stored[name][:, k] = values
            else:
                stored[name][started, k] = values[started]
    flight.advance_to(float(duration_s))  # t1 off the grid: one more partial step
    end_state = flight.snapshot()
    # Aircraft that leave before the end (t1 on the grid): NaN after t1, end state at it.
    leaving = np.flatnonzero(t1 < float(duration_s))
    if leaving.size:
        last = np.round(t1[leaving] / dt).astype(np.int64)
        after = times[None, :] > t1[leaving, None] + _EPS
        for name in _FIELDS:
            getattr(end_state, name)[leaving] = stored[name][leaving, last]
            stored[name][leaving] = np.where(after, np.nan, stored[name][leaving])
    never = t0 > t1
    for state in (start_state, end_state):
        for name in _FIELDS:
            getattr(state, name)[never] = np.nan
    return Truth(
        identities=identities,
        dt=dt,
        t0=t0,
        t1=t1,
        times=times,
        **stored,
        start_state=start_state,
        end_state=end_state,
    )


# --- geodesy helpers --------------------------------------------------------------------------


def _floats(values: npt.ArrayLike) -> FloatArray:
    return np.asarray(values, dtype=np.float64)


def _geodetic_to_ecef(
    lat_deg: FloatArray, lon_deg: FloatArray, h: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sin_lat = np.sin(lat)
    n = _A / np.sqrt(1.0 - _E2 * sin_lat**2)
    return (
        (n + h) * np.cos(lat) * np.cos(lon),
        (n + h) * np.cos(lat) * np.sin(lon),
        (n * (1.0 - _E2) + h) * sin_lat,
    )


def _ecef_to_geodetic(
    x: FloatArray, y: FloatArray, z: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    # Fixed-point iteration on latitude: it contracts by about e^2 each time, so five
    # passes from the spherical guess reach far below a micrometre; the height formula
    # stays well conditioned at the poles too.
    p = np.hypot(x, y)
    lat = np.arctan2(z, p * (1.0 - _E2))
    for _ in range(5):
        sin_lat = np.sin(lat)
        n = _A / np.sqrt(1.0 - _E2 * sin_lat**2)
        lat = np.arctan2(z + _E2 * n * sin_lat, p)
    sin_lat, cos_lat = np.sin(lat), np.cos(lat)
    h = p * cos_lat + z * sin_lat - _A * np.sqrt(1.0 - _E2 * sin_lat**2)
    return np.degrees(lat), np.degrees(np.arctan2(y, x)), h


def _enu_to_ecef(
    east: FloatArray, north: FloatArray, up: FloatArray, lat_deg: FloatArray, lon_deg: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    sl, cl, so, co = np.sin(lat), np.cos(lat), np.sin(lon), np.cos(lon)
    return (
        -so * east - sl * co * north + cl * co * up,
        co * east - sl * so * north + cl * so * up,
        cl * north + sl * up,
    )
