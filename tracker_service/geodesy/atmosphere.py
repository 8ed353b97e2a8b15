"""The atmosphere of the plot conversion: Mode C pressure altitude to geometric height.

Mode C (and ADS-B's barometric altitude, CAT021 I145) is pressure altitude: the
geopotential height at which the ICAO standard atmosphere (ISA, ISO 2533: 1013.25 hPa and
288.15 K at MSL, -6.5 K/km to the tropopause at 11 km, isothermal above) has the pressure
the aircraft's altimeter measures. The slant-range projection needs the aircraft's
geometric height above MSL, which differs from it as soon as the sea-level pressure (QNH)
or the temperature is not standard: about 8.3 m per hPa of QNH near the ground, and the
ratio T / T_ISA of the column's temperature (ISA - 15 K puts FL350 about 600 m lower).
Near a radar the height error moves the ground range by tan(elevation) times as much,
the same way for every aircraft at a level: a range bias the bias filters then learn as
the radar's (issue 14: 14-31 m at QNH 1004 hPa, ISA - 7 K).

The model: ISA with ``qnh_hpa`` at MSL and every temperature shifted by
``isa_deviation_k`` (T(H) = T_ISA(H) + dT, tropopause at geopotential 11 km), the pressure
following the hydrostatic equation in geopotential height H; geometric height h = r H /
(r - H). Written here apart from the simulator's model (``simulator.geometry``) so that a
mistake common to both cannot cancel in tests against simulated truth.

QNH is taken as the actual pressure at mean sea level. Operationally it is an aerodrome's
pressure reduced to MSL through ISA, which differs from it by about 1 hPa for an aerodrome
a few hundred metres high at ISA +/- 15 K: a residual the height sigma covers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.ellipsoid import FloatArray, as_float

FEET = 0.3048
ISA_EARTH_RADIUS_M = 6356766.0
"""The radius ISO 2533 turns geopotential height into geometric height with."""
ISA_SEA_LEVEL_PRESSURE_HPA = 1013.25
ISA_SEA_LEVEL_TEMPERATURE_K = 288.15
ISA_LAPSE_RATE_K_PER_M = 0.0065
ISA_TROPOPAUSE_M = 11000.0
STANDARD_GRAVITY = 9.80665
GAS_CONSTANT_AIR = 287.05287
"""J/(kg K), ISO 2533's specific gas constant of dry air."""
QNH_RANGE_HPA = (900.0, 1100.0)
"""Sea-level pressures ever met (records: 870 and 1084 hPa); outside, a typing error."""
ISA_DEVIATION_RANGE_K = (-40.0, 40.0)

_POWER = STANDARD_GRAVITY / (GAS_CONSTANT_AIR * ISA_LAPSE_RATE_K_PER_M)
"""g / (R L), the exponent of the troposphere's pressure law (5.2559)."""


@dataclass(frozen=True)
class Atmosphere:
    """QNH (hPa) and temperature deviation from ISA (K) of the air the aircraft fly in.

    The defaults are the standard atmosphere, in which a pressure altitude is a
    geopotential height: FL350 is then 10,686 m above MSL (18 m more than 35,000 ft)."""

    qnh_hpa: float = ISA_SEA_LEVEL_PRESSURE_HPA
    isa_deviation_k: float = 0.0

    def __post_init__(self) -> None:
        for name in ("qnh_hpa", "isa_deviation_k"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"atmosphere: {name} = {value!r} is not a number")
        low, high = QNH_RANGE_HPA
        if not low <= self.qnh_hpa <= high:
            raise ValueError(
                f"atmosphere: qnh_hpa = {self.qnh_hpa} is outside [{low:g}, {high:g}] hPa "
                "(give the sea-level pressure in hPa, e.g. 1013.25)"
            )
        low, high = ISA_DEVIATION_RANGE_K
        if not low <= self.isa_deviation_k <= high:
            raise ValueError(
                f"atmosphere: isa_deviation_k = {self.isa_deviation_k} is outside "
                f"[{low:g}, {high:g}] K (the temperature minus the ISA one, e.g. -7)"
            )

    @property
    def is_standard(self) -> bool:
        return self.qnh_hpa == ISA_SEA_LEVEL_PRESSURE_HPA and self.isa_deviation_k == 0.0

    def height_m(self, pressure_altitude_ft: npt.ArrayLike) -> FloatArray:
        """Geometric height above MSL (m) of pressure altitudes (ft; Mode C's FL x 100)."""
        pressure = _standard_pressure_hpa(as_float(pressure_altitude_ft) * FEET)
        geopotential = _geopotential_height_m(pressure, self.qnh_hpa, self.isa_deviation_k)
        return np.asarray(
            ISA_EARTH_RADIUS_M * geopotential / (ISA_EARTH_RADIUS_M - geopotential),
            dtype=np.float64,
        )

    def flight_level_height_m(self, flight_level: npt.ArrayLike) -> FloatArray:
        """Geometric height above MSL (m) of flight levels (hundreds of feet)."""
        return self.height_m(as_float(flight_level) * 100.0)

    def pressure_altitude_ft(self, height_m: npt.ArrayLike) -> FloatArray:
        """Inverse of ``height_m``: the pressure altitude (ft) an altimeter at a geometric
        height above MSL (m) shows."""
        h = as_float(height_m)
        geopotential = ISA_EARTH_RADIUS_M * h / (ISA_EARTH_RADIUS_M + h)
        pressure = _pressure_hpa(geopotential, self.qnh_hpa, self.isa_deviation_k)
        standard = _geopotential_height_m(pressure, ISA_SEA_LEVEL_PRESSURE_HPA, 0.0)
        return np.asarray(standard / FEET, dtype=np.float64)


STANDARD = Atmosphere()


def _standard_pressure_hpa(geopotential_m: FloatArray) -> FloatArray:
    return _pressure_hpa(geopotential_m, ISA_SEA_LEVEL_PRESSURE_HPA, 0.0)


def _pressure_hpa(geopotential_m: FloatArray, p0_hpa: float, deviation_k: float) -> FloatArray:
    """Static pressure at a geopotential height: p0 (T(H) / T0)^(g / R L) up to the
    tropopause, then p_trop exp(-g (H - 11 km) / (R T_trop))."""
    t0 = ISA_SEA_LEVEL_TEMPERATURE_K + deviation_k
    t_trop = t0 - ISA_LAPSE_RATE_K_PER_M * ISA_TROPOPAUSE_M
    below = np.minimum(geopotential_m, ISA_TROPOPAUSE_M)
    above = np.maximum(geopotential_m - ISA_TROPOPAUSE_M, 0.0)
    return np.asarray(
        p0_hpa
        * np.power(1.0 - ISA_LAPSE_RATE_K_PER_M * below / t0, _POWER)
        * np.exp(-STANDARD_GRAVITY * above / (GAS_CONSTANT_AIR * t_trop)),
        dtype=np.float64,
    )


def _geopotential_height_m(
    pressure_hpa: FloatArray, p0_hpa: float, deviation_k: float
) -> FloatArray:
    """Inverse of ``_pressure_hpa``: the geopotential height at which the pressure occurs."""
    t0 = ISA_SEA_LEVEL_TEMPERATURE_K + deviation_k
    t_trop = t0 - ISA_LAPSE_RATE_K_PER_M * ISA_TROPOPAUSE_M
    p_trop = p0_hpa * math.pow(t_trop / t0, _POWER)
    ratio = np.maximum(pressure_hpa, 1e-9)
    troposphere = t0 / ISA_LAPSE_RATE_K_PER_M * (1.0 - np.power(ratio / p0_hpa, 1.0 / _POWER))
    stratosphere = ISA_TROPOPAUSE_M + GAS_CONSTANT_AIR * t_trop / STANDARD_GRAVITY * np.log(
        p_trop / ratio
    )
    return np.asarray(np.where(ratio >= p_trop, troposphere, stratosphere), dtype=np.float64)
