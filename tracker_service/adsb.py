"""ADS-B reports (CAT021) as a reference for the radars' biases.

An ADS-B position comes from the aircraft's GNSS with a GNSS time of applicability
(I021/071): no radar bias, no radar clock. Per Mode S address the reference keeps the
latest reports in the system plane; a radar plot of that address is then compared with
the ADS-B track at the plot's own time stamp, which makes the radar's time offset
observable (DOMAIN.md section 6), as well as its range and azimuth errors.

The reference at a time is the report nearest to it, moved along its own GNSS velocity
(I021/160): reports reach the ground after a latency, so the next one may not be there
yet, and the velocity from differencing two reports is useless when they are a few
hundredths of a second apart (aircraft report at their own pace).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass, replace
from functools import cache
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.columns import Column, ColumnReader
from tracker_service.geodesy import SystemPlane
from tracker_service.ingest import DAY_S, posix_from_time_of_day

__all__ = [
    "ADSB_TYP",
    "CAT021_COLUMNS",
    "NACP_EPU_M",
    "NACP_SIGMA_M",
    "SIGMA_PER_EPU",
    "AdsbReference",
    "AdsbReports",
    "decode_reports",
    "position_sigma_m",
    "velocity_sigma_m_s",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CAT021 = 21
ADSB_TYP = 8
"""The ``typ`` of an ADS-B report's row in a plot table (I048/020 TYP has three bits:
no radar's plot has it)."""
FT = 0.3048
NM = 1852.0
EARTH_RADIUS_M = 6_371_000.0
MANOEUVRE_M_S2 = 2.0

NACP_EPU_M = {
    11: 3.0,
    10: 10.0,
    9: 30.0,
    8: 92.6,
    7: 185.2,
    6: 555.6,
    5: 926.0,
    4: 1852.0,
    3: 3704.0,
    2: 7408.0,
    1: 18520.0,
    0: 37040.0,
}
"""NACp -> the 95 % horizontal position error bound (EPU) in metres, DO-260B."""
NUCP_ACCURACY_M = {
    9: 3.0,
    8: 10.0,
    7: 92.6,
    6: 185.2,
    5: 463.0,
    4: 926.0,
    3: 1852.0,
    2: 9260.0,
    1: 18520.0,
}
"""NUCp (DO-260, MOPS version 0) -> its 95 % horizontal accuracy in metres; 0: none."""
NIC_RC_M = {
    11: 7.5,
    10: 25.0,
    9: 75.0,
    8: 185.2,
    7: 370.4,
    6: 1111.2,
    5: 1852.0,
    4: 3704.0,
    3: 7408.0,
    2: 14816.0,
    1: 37040.0,
}
"""NIC (DO-260A/B) -> the containment radius Rc in metres (NIC 6 without its supplements:
the largest of its three radii); 0: unknown."""
NACV_BOUND_M_S = {4: 0.3, 3: 1.0, 2: 3.0, 1: 10.0}
"""NACv (or version 0's NUCr) -> the 95 % horizontal velocity error bound, m/s."""
SIGMA_PER_EPU = 1.0 / 2.448
"""A circular 2-D Gaussian holds 95 % of its mass within 2.448 sigma."""
WORST_BOUND_M = 1852.0
"""A report whose 95 % bound is worse than 1 NM is not fit for a reference or fusion."""
NACP_SIGMA_M = {
    nacp: bound * SIGMA_PER_EPU for nacp, bound in NACP_EPU_M.items() if bound <= WORST_BOUND_M
}
UNKNOWN_VELOCITY_SIGMA_M_S = 1000.0
"""No velocity, or no NACv: a velocity that says nothing."""


def _sigma_per_value(
    bounds: dict[int, float], bits: int, unfit: float, worst: float = math.inf
) -> FloatArray:
    """The 1-sigma per axis of each value of a ``bits``-bit quality field from its 95 %
    bound (``unfit``: no bound, or one worse than ``worst``), then of an absent field (-1,
    which indexes the last entry)."""
    table = np.full((1 << bits) + 1, unfit)
    for value, bound in bounds.items():
        if bound <= worst:
            table[value] = bound * SIGMA_PER_EPU
    return table


_NACP_SIGMA_M = _sigma_per_value(NACP_EPU_M, 4, math.nan, WORST_BOUND_M)
_NUCP_SIGMA_M = _sigma_per_value(NUCP_ACCURACY_M, 4, math.nan, WORST_BOUND_M)
_NIC_SIGMA_M = _sigma_per_value(NIC_RC_M, 4, math.nan, WORST_BOUND_M)
_NACV_SIGMA_M_S = _sigma_per_value(NACV_BOUND_M_S, 3, UNKNOWN_VELOCITY_SIGMA_M_S)


def position_sigma_m(version: IntArray, nacp: IntArray, nucp_or_nic: IntArray) -> FloatArray:
    """The 1-sigma per axis of reports' positions (NaN: not fit for use), from I021/090
    as their MOPS version (I021/210 VN) defines it, each -1 when absent: NACp, the 95 %
    accuracy bound, from version 1 on; without NACp the NIC's containment radius taken as
    that bound (an integrity bound: larger than the accuracy, so on the safe side);
    version 0 (DO-260) its NUCp's accuracy. Without a version, NACp if present, else the
    field as a NUCp."""
    return np.where(
        (nacp >= 0) & (version != 0),
        _NACP_SIGMA_M[nacp],
        np.where(version <= 0, _NUCP_SIGMA_M[nucp_or_nic], _NIC_SIGMA_M[nucp_or_nic]),
    )


def velocity_sigma_m_s(nacv: IntArray) -> FloatArray:
    """The 1-sigma per axis of reports' velocities from their NACv (NUCr), -1 when
    absent."""
    return _NACV_SIGMA_M_S[nacv]


@dataclass(frozen=True)
class AdsbReports:
    """Reports of one datagram that are fit for use: address, time of applicability
    (POSIX), plane position, plane velocity, the position's and velocity's 1-sigma per
    axis, flight level (NaN absent), Mode 3/A (-1 absent), the record's index in the
    datagram's CAT021 records, and the station (SAC/SIC) that sent it. ``records``: every
    CAT021 record read, fit or not; ``latest``: the latest time of applicability (I071,
    else I073) of any of them, POSIX s on the day nearest the reception (None without
    one): with ``records``, what the status says of an ADS-B feed (``adsb_status``)."""

    address: IntArray
    time: FloatArray
    x: FloatArray
    y: FloatArray
    vx: FloatArray
    vy: FloatArray
    sigma: FloatArray
    sigma_v: FloatArray
    flight_level: FloatArray
    mode3a: IntArray
    record: IntArray
    station: str = ""
    records: int = 0
    latest: float | None = None

    def __len__(self) -> int:
        return len(self.address)

    def take(self, index: npt.NDArray[Any]) -> AdsbReports:
        return replace(self, **{name: getattr(self, name)[index] for name in _REPORT_COLUMNS})


_REPORT_COLUMNS = (
    "address",
    "time",
    "x",
    "y",
    "vx",
    "vy",
    "sigma",
    "sigma_v",
    "flight_level",
    "mode3a",
    "record",
)


CAT021_COLUMNS = (
    Column("sac", "010", ("SAC",)),
    Column("sic", "010", ("SIC",)),
    Column("time_of_applicability", "071"),
    Column("time_of_reception", "073"),
    Column("latitude", "131", ("LAT",)),
    Column("longitude", "131", ("LON",)),
    Column("latitude_low", "130", ("LAT",)),
    Column("longitude_low", "130", ("LON",)),
    Column("address", "080"),
    Column("nucr_nacv", "090", ("NUCRNACV",)),
    Column("nucp_nic", "090", ("NUCPNIC",)),
    Column("nacp", "090", ("NACP",)),
    Column("version", "210", ("VN",)),
    Column("geometric_height", "140"),
    Column("flight_level", "145"),
    Column("range_exceeded", "160", ("RE",)),
    Column("ground_speed", "160", ("GS",)),
    Column("track_angle", "160", ("TA",)),
    Column("mode3a", "070", ("MODE3A",)),
)
"""The elements of a CAT021 record the reports are made of (``asterix.columns``)."""


@cache
def _cat021() -> ColumnReader:
    return ColumnReader(CAT021, CAT021_COLUMNS)


def _on_day_of(time_of_day: FloatArray, received: float) -> FloatArray:
    """The POSIX times nearest ``received`` whose times of day are ``time_of_day``."""
    shift = (time_of_day - received % DAY_S + DAY_S / 2) % DAY_S - DAY_S / 2
    return received + shift


def decode_reports(block: bytes, received: float, plane: SystemPlane) -> AdsbReports:
    """The reports of one CAT021 data block received at ``received`` (POSIX s), in the
    system plane: time of applicability I071 (else I073, reception of position),
    position I131 (else I130), velocity I160, quality I090 as ``position_sigma_m`` reads
    it; records without address, time or position, or too inaccurate, are left out.
    ``records`` and ``latest`` count every record, fit or not (the status's). Never
    raises on bad bytes: a malformed record ends its block, as in the general decoder
    (``asterix.columns.ColumnReader``)."""
    c = _cat021().read(block)
    records = len(c["address"])
    sources = np.flatnonzero(c["sac"] >= 0)
    station = f"{c['sac'][sources[0]]}/{c['sic'][sources[0]]}" if len(sources) else ""
    applicability = c["time_of_applicability"]
    time_of_day = np.where(np.isnan(applicability), c["time_of_reception"], applicability)
    timed = time_of_day[~np.isnan(time_of_day)]
    latest = float(_on_day_of(timed, received).max()) if len(timed) else None
    high = ~np.isnan(c["latitude"])
    latitude = np.where(high, c["latitude"], c["latitude_low"])
    longitude = np.where(high, c["longitude"], c["longitude_low"])
    sigma = position_sigma_m(c["version"], c["nacp"], c["nucp_nic"])
    rows = np.flatnonzero(
        ~np.isnan(latitude) & ~np.isnan(time_of_day) & (c["address"] >= 0) & np.isfinite(sigma)
    )
    if not len(rows):
        empty = np.zeros(0)
        none = np.zeros(0, dtype=np.int64)
        return AdsbReports(
            none,
            empty,
            empty,
            empty,
            empty,
            empty,
            empty,
            empty,
            empty,
            none,
            none,
            station=station,
            records=records,
            latest=latest,
        )
    moving = c["range_exceeded"][rows] == 0
    lat_a, lon_a = latitude[rows], longitude[rows]
    geometric = c["geometric_height"][rows]
    h = np.where(np.isnan(geometric), 0.0, geometric) * FT
    # The plane's axes are not true north and east away from its centre: turn the
    # velocity with the plane by projecting a point one second ahead (in the same
    # projection call as the reports: a block is a few dozen reports).
    angle = np.radians(np.where(moving, c["track_angle"][rows], 0.0))
    step = np.where(moving, c["ground_speed"][rows] * NM, 0.0)
    ahead_lat = lat_a + np.degrees(step * np.cos(angle) / EARTH_RADIUS_M)
    ahead_lon = lon_a + np.degrees(
        step * np.sin(angle) / (EARTH_RADIUS_M * np.cos(np.radians(lat_a)))
    )
    both_x, both_y = plane.from_geodetic(
        np.concatenate([lat_a, ahead_lat]), np.concatenate([lon_a, ahead_lon]), np.tile(h, 2)
    )
    n = len(rows)
    x, y, x1, y1 = both_x[:n], both_y[:n], both_x[n:], both_y[n:]
    return AdsbReports(
        c["address"][rows],
        posix_from_time_of_day(time_of_day[rows], received),
        np.asarray(x, dtype=np.float64),
        np.asarray(y, dtype=np.float64),
        np.asarray(x1 - x, dtype=np.float64),
        np.asarray(y1 - y, dtype=np.float64),
        sigma[rows],
        np.where(moving, velocity_sigma_m_s(c["nucr_nacv"][rows]), UNKNOWN_VELOCITY_SIGMA_M_S),
        c["flight_level"][rows],
        c["mode3a"][rows],
        rows.astype(np.int64),
        station=station,
        records=records,
        latest=latest,
    )


@dataclass(frozen=True)
class AdsbReferences:
    """References at given plot rows: which rows have one, and where (N, 2), with the
    covariance (N, 2, 2) and the velocity (N, 2)."""

    valid: BoolArray
    xy: FloatArray
    P: FloatArray
    v: FloatArray


class AdsbReference:
    """The recent ADS-B track of every address (see the module docstring)."""

    def __init__(
        self, plane: SystemPlane, max_gap_s: float = 1.5, keep: int = 4, max_age_s: float = 30.0
    ) -> None:
        self.plane = plane
        self.max_gap_s = max_gap_s
        self.max_age_s = max_age_s
        self._keep = keep
        self._tracks: dict[int, deque[tuple[float, float, float, float, float, float]]] = {}
        self.reports = 0
        self.rejected = 0

    def feed(self, block: bytes, received: float) -> AdsbReports:
        """One CAT021 data block received at ``received`` (POSIX s), every report kept."""
        reports = decode_reports(block, received, self.plane)
        self.rejected += reports.records - len(reports)
        self.add(reports)
        return reports

    def add(self, reports: AdsbReports) -> None:
        """Reports (decoded) that serve as the reference: those with a velocity, which
        moves them to a plot's time stamp."""
        moving = reports.sigma_v < UNKNOWN_VELOCITY_SIGMA_M_S
        self.rejected += int(np.count_nonzero(~moving))
        for k in np.flatnonzero(moving).tolist():
            history = self._tracks.setdefault(int(reports.address[k]), deque(maxlen=self._keep))
            t = float(reports.time[k])
            if history and t <= history[-1][0]:
                continue  # a repeated or late report adds nothing
            history.append(
                (
                    t,
                    float(reports.x[k]),
                    float(reports.y[k]),
                    float(reports.vx[k]),
                    float(reports.vy[k]),
                    float(reports.sigma[k]),
                )
            )
        self.reports += int(np.count_nonzero(moving))

    def at(self, address: IntArray, time: FloatArray) -> AdsbReferences:
        """The ADS-B position of each (address, time): the nearest report, at most
        ``max_gap_s`` away, moved along its velocity."""
        n = len(address)
        valid = np.zeros(n, dtype=bool)
        xy = np.zeros((n, 2))
        p = np.zeros((n, 2, 2))
        v = np.zeros((n, 2))
        rows: list[int] = []
        found: list[tuple[float, float, float, float, float]] = []
        for k, (a, t) in enumerate(zip(address.tolist(), time.tolist(), strict=True)):
            history = self._tracks.get(a)
            if not history:
                continue
            t0, x0, y0, vx, vy, sigma = min(history, key=lambda r: abs(r[0] - t))
            dt = t - t0
            if abs(dt) > self.max_gap_s:
                continue
            rows.append(k)
            # Position noise, and a manoeuvre of up to MANOEUVRE_M_S2 since the report.
            variance = sigma**2 + (0.5 * MANOEUVRE_M_S2 * dt * dt) ** 2
            found.append((x0 + vx * dt, y0 + vy * dt, vx, vy, variance))
        if rows:
            values = np.array(found)
            valid[rows] = True
            xy[rows] = values[:, :2]
            v[rows] = values[:, 2:4]
            p[rows, 0, 0] = p[rows, 1, 1] = values[:, 4]
        return AdsbReferences(valid, xy, p, v)

    def forget(self, now: float) -> None:
        """Drop the tracks silent for ``max_age_s``."""
        stale = [a for a, track in self._tracks.items() if now - track[-1][0] > self.max_age_s]
        for a in stale:
            del self._tracks[a]
