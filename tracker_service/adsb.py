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
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from tracker_service.geodesy import SystemPlane
from tracker_service.ingest import posix_from_time_of_day

__all__ = [
    "ADSB_TYP",
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


def position_sigma_m(version: int | None, nacp: int | None, nucp_or_nic: int | None) -> float:
    """The 1-sigma per axis of a report's position (NaN: not fit for use), from I021/090
    as its MOPS version (I021/210 VN) defines it: NACp, the 95 % accuracy bound, from
    version 1 on; without NACp the NIC's containment radius taken as that bound (an
    integrity bound: larger than the accuracy, so on the safe side); version 0 (DO-260)
    its NUCp's accuracy. Without a version, NACp if present, else the field as a NUCp."""
    if nacp is not None and version != 0:
        bound = NACP_EPU_M.get(nacp)
    elif version is None or version == 0:
        bound = NUCP_ACCURACY_M.get(nucp_or_nic) if nucp_or_nic is not None else None
    else:
        bound = NIC_RC_M.get(nucp_or_nic) if nucp_or_nic is not None else None
    if bound is None or bound > WORST_BOUND_M:
        return math.nan
    return bound * SIGMA_PER_EPU


def velocity_sigma_m_s(nacv: int | None) -> float:
    """The 1-sigma per axis of a report's velocity from its NACv (NUCr)."""
    bound = NACV_BOUND_M_S.get(nacv) if nacv is not None else None
    return UNKNOWN_VELOCITY_SIGMA_M_S if bound is None else bound * SIGMA_PER_EPU


@dataclass(frozen=True)
class AdsbReports:
    """Reports of one datagram that are fit for use: address, time of applicability
    (POSIX), plane position, plane velocity, the position's and velocity's 1-sigma per
    axis, flight level (NaN absent), Mode 3/A (-1 absent), the record's index in the
    datagram's CAT021 records, and the station (SAC/SIC) that sent it. ``records``: every
    CAT021 record read, fit or not."""

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


def _int_or_none(value: Any) -> int | None:
    return int(value) if isinstance(value, int | float) else None


def decode_reports(block: bytes, received: float, plane: SystemPlane) -> AdsbReports:
    """The reports of one CAT021 data block received at ``received`` (POSIX s), in the
    system plane: time of applicability I071 (else I073, reception of position),
    position I131 (else I130), velocity I160, quality I090 as ``position_sigma_m`` reads
    it; records without address, time or position, or too inaccurate, are left out."""
    columns: dict[str, list[Any]] = {name: [] for name in _REPORT_COLUMNS}
    lat, lon, height, speed, track = [], [], [], [], []
    station = ""
    records = 0
    for event in decode_blocks(block):
        if not isinstance(event, Block):
            continue
        for items in event.records:
            index = records
            records += 1
            source = items.get("010")
            if isinstance(source, dict) and not station:
                station = f"{source.get('SAC')}/{source.get('SIC')}"
            quality = items.get("090")
            quality = quality if isinstance(quality, dict) else {}
            version = items.get("210")
            vn = _int_or_none(version.get("VN")) if isinstance(version, dict) else None
            position = items.get("131", items.get("130"))
            tod = items.get("071", items.get("073"))
            sigma = position_sigma_m(
                vn, _int_or_none(quality.get("NACP")), _int_or_none(quality.get("NUCPNIC"))
            )
            if (
                not isinstance(position, dict)
                or not isinstance(tod, int | float)
                or "080" not in items
                or not math.isfinite(sigma)
            ):
                continue
            velocity = items.get("160")
            moving = isinstance(velocity, dict) and velocity.get("RE") == 0
            columns["address"].append(int(str(items["080"]), 16))
            columns["time"].append(float(tod))
            columns["sigma"].append(sigma)
            columns["sigma_v"].append(
                velocity_sigma_m_s(_int_or_none(quality.get("NUCRNACV")))
                if moving
                else UNKNOWN_VELOCITY_SIGMA_M_S
            )
            level = items.get("145")
            columns["flight_level"].append(
                float(level) if isinstance(level, int | float) else math.nan
            )
            code = items.get("070")
            columns["mode3a"].append(
                int(str(code["MODE3A"]), 8) if isinstance(code, dict) and "MODE3A" in code else -1
            )
            columns["record"].append(index)
            lat.append(float(position["LAT"]))
            lon.append(float(position["LON"]))
            height.append(float(items.get("140", 0.0)) * FT)
            speed.append(float(velocity["GS"]) * NM if moving else 0.0)  # type: ignore[index]
            track.append(float(velocity["TA"]) if moving else 0.0)  # type: ignore[index]
    if not lat:
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
        )
    lat_a, lon_a, h = np.array(lat), np.array(lon), np.array(height)
    x, y = plane.from_geodetic(lat_a, lon_a, h)
    # The plane's axes are not true north and east away from its centre: turn the
    # velocity with the plane by projecting a point one second ahead.
    angle = np.radians(np.array(track))
    step = np.array(speed)
    ahead_lat = lat_a + np.degrees(step * np.cos(angle) / EARTH_RADIUS_M)
    ahead_lon = lon_a + np.degrees(
        step * np.sin(angle) / (EARTH_RADIUS_M * np.cos(np.radians(lat_a)))
    )
    x1, y1 = plane.from_geodetic(ahead_lat, ahead_lon, h)
    return AdsbReports(
        np.array(columns["address"], dtype=np.int64),
        posix_from_time_of_day(np.array(columns["time"]), received),
        np.asarray(x, dtype=np.float64),
        np.asarray(y, dtype=np.float64),
        np.asarray(x1 - x, dtype=np.float64),
        np.asarray(y1 - y, dtype=np.float64),
        np.array(columns["sigma"]),
        np.array(columns["sigma_v"]),
        np.array(columns["flight_level"]),
        np.array(columns["mode3a"], dtype=np.int64),
        np.array(columns["record"], dtype=np.int64),
        station=station,
        records=records,
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
