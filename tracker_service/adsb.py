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

from collections import deque
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from tracker_service.geodesy import SystemPlane
from tracker_service.ingest import posix_from_time_of_day

__all__ = ["NACP_EPU_M", "NACP_SIGMA_M", "SIGMA_PER_EPU", "AdsbReference", "AdsbReports"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

CAT021 = 21
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
SIGMA_PER_EPU = 1.0 / 2.448
"""A circular 2-D Gaussian holds 95 % of its mass within 2.448 sigma."""
NACP_SIGMA_M = {nacp: bound * SIGMA_PER_EPU for nacp, bound in NACP_EPU_M.items() if nacp >= 4}
"""Only NACp 4 and better is used: worse says the position is not fit for a reference."""


@dataclass(frozen=True)
class AdsbReports:
    """Reports of one datagram: address, time of applicability (POSIX), plane position,
    plane velocity and the position's 1-sigma per axis."""

    address: IntArray
    time: FloatArray
    x: FloatArray
    y: FloatArray
    vx: FloatArray
    vy: FloatArray
    sigma: FloatArray


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
        """One CAT021 data block received at ``received`` (POSIX s)."""
        address, tod, lat, lon, height, sigma, speed, track = [], [], [], [], [], [], [], []
        for event in decode_blocks(block):
            if not isinstance(event, Block):
                continue
            for items in event.records:
                quality = items.get("090")
                position = items.get("131")
                velocity = items.get("160")
                nacp = quality.get("NACP") if isinstance(quality, dict) else None
                if (
                    not isinstance(position, dict)
                    or not isinstance(velocity, dict)
                    or velocity.get("RE") != 0
                    or "071" not in items
                    or "080" not in items
                    or nacp not in NACP_SIGMA_M
                ):
                    self.rejected += 1
                    continue
                address.append(int(str(items["080"]), 16))
                tod.append(float(items["071"]))
                lat.append(float(position["LAT"]))
                lon.append(float(position["LON"]))
                height.append(float(items.get("140", 0.0)) * FT)
                sigma.append(NACP_SIGMA_M[int(nacp)])
                speed.append(float(velocity["GS"]) * NM)
                track.append(float(velocity["TA"]))
        if not address:
            empty = np.zeros(0)
            return AdsbReports(
                np.zeros(0, dtype=np.int64), empty, empty, empty, empty, empty, empty
            )
        lat_a, lon_a, h = np.array(lat), np.array(lon), np.array(height)
        x, y = self.plane.from_geodetic(lat_a, lon_a, h)
        # The plane's axes are not true north and east away from its centre: turn the
        # velocity with the plane by projecting a point one second ahead.
        angle = np.radians(np.array(track))
        step = np.array(speed)
        ahead_lat = lat_a + np.degrees(step * np.cos(angle) / EARTH_RADIUS_M)
        ahead_lon = lon_a + np.degrees(
            step * np.sin(angle) / (EARTH_RADIUS_M * np.cos(np.radians(lat_a)))
        )
        x1, y1 = self.plane.from_geodetic(ahead_lat, ahead_lon, h)
        reports = AdsbReports(
            np.array(address, dtype=np.int64),
            posix_from_time_of_day(np.array(tod), received),
            np.asarray(x, dtype=np.float64),
            np.asarray(y, dtype=np.float64),
            np.asarray(x1 - x, dtype=np.float64),
            np.asarray(y1 - y, dtype=np.float64),
            np.array(sigma),
        )
        for k in range(len(address)):
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
        self.reports += len(address)
        return reports

    def at(self, address: IntArray, time: FloatArray) -> AdsbReferences:
        """The ADS-B position of each (address, time): the nearest report, at most
        ``max_gap_s`` away, moved along its velocity."""
        n = len(address)
        valid = np.zeros(n, dtype=bool)
        xy = np.zeros((n, 2))
        p = np.zeros((n, 2, 2))
        v = np.zeros((n, 2))
        for k in range(n):
            history = self._tracks.get(int(address[k]))
            if not history:
                continue
            t = float(time[k])
            t0, x0, y0, vx, vy, sigma = min(history, key=lambda r: abs(r[0] - t))
            dt = t - t0
            if abs(dt) > self.max_gap_s:
                continue
            xy[k] = (x0 + vx * dt, y0 + vy * dt)
            v[k] = (vx, vy)
            # Position noise, and a manoeuvre of up to MANOEUVRE_M_S2 since the report.
            p[k] = np.eye(2) * (sigma**2 + (0.5 * MANOEUVRE_M_S2 * dt * dt) ** 2)
            valid[k] = True
        return AdsbReferences(valid, xy, p, v)

    def forget(self, now: float) -> None:
        """Drop the tracks silent for ``max_age_s``."""
        stale = [a for a, track in self._tracks.items() if now - track[-1][0] > self.max_age_s]
        for a in stale:
            del self._tracks[a]
