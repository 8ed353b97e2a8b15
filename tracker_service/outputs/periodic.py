"""The periodic air picture: every live system track extrapolated to one common time.

An SDPS feeds its users either on update (each track when it is updated, at its own
time) or periodically: every N seconds, the whole picture at one time, every track moved
there along its velocity. ``PeriodicPicture`` keeps the latest message of every live
system track (from the messages any output receives) and, when a period falls due in
data time, gives each one extrapolated to the period's grid time: position along the
plane velocity (constant velocity, as the fuser predicts between updates), the
covariance grown by the same model with white-acceleration noise, the flight level along
the climb rate, the sensor ages older by the time moved. Any output (CAT062 over UDP,
Zenoh, ...) can hold one; the extrapolation is a pure function (``extrapolate``).

Tracks are given at the grid times ``k * period_s`` (from POSIX 0), so that two outputs
with the same period give the same times, and a track not updated for more than
``max_age_s`` (coasting that long) is not extrapolated further: it is left out until its
next update or its end.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.messages import (
    SensorAges,
    SystemTrackMessage,
    iso_time,
    position_sigma_m,
)

__all__ = ["DEFAULT_ACCELERATION_MPS2", "PeriodicPicture", "extrapolate", "extrapolate_all"]

DEFAULT_ACCELERATION_MPS2 = 1.0
"""Standard deviation of the unknown horizontal acceleration over an extrapolation (the
white-acceleration spectral density is its square, m²/s³): a standard-rate turn at
250 kt is about 2.6 m/s², a straight leg nearly 0."""
_FL_PER_FPM_S = 1.0 / 100.0 / 60.0


def extrapolate(
    message: SystemTrackMessage,
    time: float,
    plane: SystemPlane,
    acceleration_mps2: float = DEFAULT_ACCELERATION_MPS2,
) -> SystemTrackMessage:
    """``message`` moved to ``time`` (later or earlier) at constant plane velocity; its
    covariance F P F' + Q (discrete white-noise acceleration, ``acceleration_mps2``²),
    lat/lon of the new position, flight level along the climb rate, ages older."""
    return extrapolate_all([message], time, plane, acceleration_mps2)[0]


def extrapolate_all(
    messages: Sequence[SystemTrackMessage],
    time: float,
    plane: SystemPlane,
    acceleration_mps2: float = DEFAULT_ACCELERATION_MPS2,
    first: frozenset[int] = frozenset(),
) -> list[SystemTrackMessage]:
    """``extrapolate`` of each message, the states and their conversion to lat/lon on
    arrays (a picture of thousands of tracks); the tracks numbered in ``first`` say so."""
    if not messages:
        return []
    dt = time - np.array([m.time for m in messages])
    velocity = np.array([[m.vx_mps, m.vy_mps] for m in messages])
    xy = np.array([[m.x_m, m.y_m] for m in messages]) + velocity * dt[:, None]
    lat, lon = plane.to_geodetic(xy[:, 0], xy[:, 1])
    f = np.tile(np.eye(4), (len(messages), 1, 1))
    f[:, 0, 2] = f[:, 1, 3] = dt
    q = np.zeros((len(messages), 4, 4))
    adt = np.abs(dt)
    q[:, 0, 0] = q[:, 1, 1] = adt**3 / 3
    q[:, 0, 2] = q[:, 2, 0] = q[:, 1, 3] = q[:, 3, 1] = dt**2 / 2
    q[:, 2, 2] = q[:, 3, 3] = adt
    p = f @ np.array([m.covariance for m in messages]) @ f.transpose(0, 2, 1)
    p += acceleration_mps2**2 * q
    covariances = p.tolist()
    stamp = iso_time(time)
    moved = []
    for k, message in enumerate(messages):
        step = float(dt[k])
        covariance = covariances[k]
        flight_level = message.flight_level
        altitude = message.altitude_m
        if message.climb_rate_fpm is not None:
            if flight_level is not None:
                flight_level += message.climb_rate_fpm * _FL_PER_FPM_S * step
            if altitude is not None:
                altitude += message.climb_rate_fpm * 0.3048 / 60.0 * step
        ages = message.ages
        aged = SensorAges.model_construct(
            None,
            **{
                name: max(age + step, 0.0)
                for name in ("psr", "ssr", "mode_s", "adsb")
                if (age := getattr(ages, name)) is not None
            },
        )
        moved.append(
            message.model_copy(
                update={
                    "time": time,
                    "time_iso": stamp,
                    "x_m": float(xy[k, 0]),
                    "y_m": float(xy[k, 1]),
                    "lat": float(lat[k]),
                    "lon": (float(lon[k]) + 180.0) % 360.0 - 180.0,
                    "covariance": covariance,
                    "position_sigma_m": position_sigma_m(covariance),
                    "flight_level": flight_level,
                    "altitude_m": altitude,
                    "ages": aged,
                    "daps": [
                        d.model_copy(update={"age_s": max(d.age_s + step, 0.0)})
                        for d in message.daps
                    ],
                    "first": message.number in first,
                    "mode3a_changed": False,
                }
            )
        )
    return moved


class PeriodicPicture:
    """The live picture, given every ``period_s`` of data time at the grid times; see the
    module docstring. ``update`` with every system-track message; ``due(now)`` the grid
    time of a picture that fell due, if any; ``at(t)`` the picture extrapolated to ``t``,
    in track-number order: a track's first message in the pictures says ``first`` (CAT062
    TSB), and a track that ended since the last picture is in the next one once more, with
    status "ended" (TSE), then forgotten."""

    def __init__(
        self,
        plane: SystemPlane,
        period_s: float,
        max_age_s: float = 60.0,
        acceleration_mps2: float = DEFAULT_ACCELERATION_MPS2,
    ) -> None:
        if not period_s > 0.0:
            raise ValueError(f"period_s {period_s} must be positive")
        self.plane = plane
        self.period_s = period_s
        self.max_age_s = max_age_s
        self.acceleration_mps2 = acceleration_mps2
        self._tracks: dict[int, SystemTrackMessage] = {}
        self._given: set[int] = set()
        """Tracks already in a picture (the others' next one is their first)."""
        self._next: float | None = None

    def __len__(self) -> int:
        return len(self._tracks)

    def update(self, message: SystemTrackMessage) -> None:
        if message.status == "ended" and message.number not in self._given:
            # Never given: its end says nothing to a user of the pictures.
            self._tracks.pop(message.number, None)
            return
        self._tracks[message.number] = message

    def due(self, now: float) -> float | None:
        """The latest grid time at or before ``now`` not yet given, or None; a long
        silence gives one picture, not a burst."""
        grid = math.floor(now / self.period_s) * self.period_s
        if self._next is None:
            self._next = grid + self.period_s
            return None
        if now < self._next:
            return None
        self._next = grid + self.period_s
        return grid

    def at(self, time: float) -> list[SystemTrackMessage]:
        chosen = []
        for number in sorted(self._tracks):
            message = self._tracks[number]
            if message.status == "ended":
                del self._tracks[number]
                self._given.discard(number)
            elif time - message.time > self.max_age_s:
                continue
            chosen.append(message)
        first = frozenset(
            m.number for m in chosen if m.status != "ended" and m.number not in self._given
        )
        self._given |= first
        return extrapolate_all(chosen, time, self.plane, self.acceleration_mps2, first)
