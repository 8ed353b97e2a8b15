"""Aircraft heights for the plot conversion: Mode C flight levels, and what stands in when
Mode C is missing.

Mode C reports pressure altitude: the height at which the standard atmosphere (ISA,
ISO 2533) has the pressure the aircraft measures, referenced to 1013.25 hPa. It equals the
height above mean sea level only in a standard atmosphere with a standard sea-level
pressure. ``HeightModel`` converts it with the configured ``Atmosphere`` (QNH and ISA
deviation, ``geodesy.atmosphere``); what that leaves unknown (a QNH a few hPa off, a
temperature that is not the same everywhere) is part of the height sigma below.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.atmosphere import STANDARD, Atmosphere
from tracker_service.geodesy.ellipsoid import FloatArray, as_float

FEET = 0.3048
ISA_EARTH_RADIUS_M = 6356766.0
"""The radius ISO 2533 uses to turn geopotential height into geometric height."""


def flight_level_to_height_m(flight_level: npt.ArrayLike, *, geometric: bool = True) -> FloatArray:
    """Height above MSL of a flight level (hundreds of feet of pressure altitude), in ISA.

    ISA is defined in geopotential height, so a pressure altitude is a geopotential height;
    ``geometric`` (the default) converts it to geometric height, z = r H / (r - H), which
    is 18 m more at FL350. With ``geometric=False`` it is the plain FL x 100 ft.
    """
    pressure_altitude = as_float(flight_level) * (100.0 * FEET)
    if not geometric:
        return pressure_altitude
    return np.asarray(
        ISA_EARTH_RADIUS_M * pressure_altitude / (ISA_EARTH_RADIUS_M - pressure_altitude),
        dtype=np.float64,
    )


@dataclass(frozen=True)
class HeightModel:
    """Height and height sigma of each plot, from Mode C or, without it, a stand-in.

    - With Mode C: the geometric height of its pressure altitude in ``atmosphere``, with
      sigma = sqrt(mode_c_sigma_m^2 + (mode_c_relative_sigma H)^2). The constant term
      covers an error of the configured QNH (about 8 m per hPa near the ground) and the
      100 ft Gillham steps; the relative one a temperature off the configured one (10 K
      is 3.5 % of the height).
    - Without Mode C (missing, or invalid and garbled plots that the caller masked out as
      NaN): the track's last known height when the caller has one, with
      ``last_level_sigma_m`` (the aircraft may have climbed since), otherwise the
      configured ``assumed_height_m`` (FL200 by default) with ``assumed_sigma_m``, large
      enough to span the levels where traffic flies. The sigma enters the plot covariance
      along the line of sight, so a badly guessed height costs weight, not position.
    """

    assumed_height_m: float = float(flight_level_to_height_m(200.0))
    assumed_sigma_m: float = 3500.0
    last_level_sigma_m: float = 300.0
    mode_c_sigma_m: float = 100.0
    mode_c_relative_sigma: float = 0.03
    atmosphere: Atmosphere = STANDARD

    def heights(
        self,
        flight_level: npt.ArrayLike,
        last_known_height_m: npt.ArrayLike | None = None,
    ) -> tuple[FloatArray, FloatArray]:
        """(height above MSL m, height sigma m) per plot; NaN flight level = no Mode C.

        ``last_known_height_m``: per plot, the height of the track the plot may belong
        to (NaN where there is none).
        """
        fl = as_float(flight_level)
        mode_c = self.atmosphere.flight_level_height_m(fl)
        mode_c_sigma = np.hypot(self.mode_c_sigma_m, self.mode_c_relative_sigma * mode_c)
        fallback = np.full_like(fl, self.assumed_height_m)
        fallback_sigma = np.full_like(fl, self.assumed_sigma_m)
        if last_known_height_m is not None:
            last = np.broadcast_to(as_float(last_known_height_m), fl.shape)
            known = np.isfinite(last)
            fallback = np.where(known, last, fallback)
            fallback_sigma = np.where(known, self.last_level_sigma_m, fallback_sigma)
        has_mode_c = np.isfinite(fl)
        return (
            np.where(has_mode_c, mode_c, fallback),
            np.where(has_mode_c, mode_c_sigma, fallback_sigma),
        )
