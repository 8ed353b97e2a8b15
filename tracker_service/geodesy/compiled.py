"""``convert_plots`` in a few compiled passes, for the radar stage's batches and the
central stage's re-projection of plots without a height (``fusion.psr_height``): the
same values to the bit, in the stereographic plane.

A radar's batch is a few dozen plots, and ``convert_plots`` spends most of its time in the
set-up of its ~120 numpy calls. Here the arithmetic runs as numba loops over the batch
(``cache=True``), in the order of operations of the numpy code, and what is not plain
arithmetic stays where it was computed before, so that every value is the same:

- numpy computes ``arcsin``, ``arctan2`` and ``power`` with its own SIMD routines, which
  differ from the C library's that numba calls in the last bit of about one value in ten:
  those stay numpy calls on whole arrays, between the compiled passes (``sin``, ``cos``,
  ``sqrt`` and ``hypot`` are the same in both, and are compiled);
- PROJ's geodetic and stereographic transforms stay PROJ calls (pyproj's, on the arrays
  in place), each made once: the plane's position and the Jacobian's base point are one
  projection (``convert_plots`` projected it twice);
- numpy's 2x2 matrix products (``@``) go through BLAS, whose kernel accumulates the two
  products from 0 with fused multiply-adds (``_fma`` reproduces it); its ``einsum`` sums
  from 0 too (0 + -0 is +0), the radar turn's three products in the order (0 + 2) + 1.

NaN results (a plot without a range) may differ in their sign bit: no output tells them
apart.

``tests/test_geodesy_compiled.py`` holds every output to ``convert_plots``'s, bit for bit,
on drawn and recorded batches. The tangent plane uses ``convert_plots`` itself
(``convert_plots_compiled`` chooses).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, cast

import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic
from pyproj.enums import TransformDirection

from tracker_service.compiled_arrays import maximum, minimum
from tracker_service.geodesy.convert import ConvertedPlots, convert_plots
from tracker_service.geodesy.ellipsoid import E2, A, FloatArray, ecef_to_geodetic_transformer
from tracker_service.geodesy.plane import STEP_DEG, SystemPlane
from tracker_service.geodesy.plots import MIN_COS_ELEVATION, MIN_RANGE_M
from tracker_service.geodesy.sites import RadarSite
from tracker_service.numba_symbols import numba

__all__ = ["PlaneSteps", "convert_batch_plots", "convert_plots_compiled", "plane_jacobian_at"]

_MERIDIAN_NUMERATOR = A * (1.0 - E2)
"""As ``radii_m`` computes it: one Python constant, then divided by w^1.5."""
_STEP_RAD = float(np.radians(STEP_DEG))


@intrinsic
def _fused_multiply_add(typingctx, a, b, c):  # type: ignore[no-untyped-def]  # pragma: no cover
    """a * b + c rounded once, as BLAS's 2x2 kernel sums its products."""
    signature = types.float64(types.float64, types.float64, types.float64)

    def codegen(context, builder, sig, args):  # type: ignore[no-untyped-def]
        double = ir.DoubleType()
        fused = builder.module.declare_intrinsic(
            "llvm.fma", [double], ir.FunctionType(double, [double, double, double])
        )
        return builder.call(fused, args)

    return signature, codegen


_fma = cast(Callable[[float, float, float], float], _fused_multiply_add)


class PlaneSteps(NamedTuple):
    """What the conversion projected: each plot's point and its steps north and east
    (``SystemPlane.jacobian``'s differences) and the radii's w and w^1.5, for the DAPs'
    velocity turned at another height (``plane_jacobian_at``)."""

    e0: FloatArray
    n0: FloatArray
    e_north: FloatArray
    n_north: FloatArray
    e_east: FloatArray
    n_east: FloatArray
    w: FloatArray
    w15: FloatArray


@numba.njit(cache=True, error_model="numpy", inline="always")
def plane_jacobian_at(
    i: int, lat: FloatArray, h: float, steps: PlaneSteps
) -> tuple[float, float, float, float]:  # pragma: no cover - compiled
    """``SystemPlane.jacobian``'s horizontal block (j00, j01, j10, j11) at point ``i``
    and height ``h``, from the projections made (``PlaneSteps``)."""
    meridian = _MERIDIAN_NUMERATOR / steps.w15[i]
    prime_vertical = A / np.sqrt(steps.w[i])
    north_m = (meridian + h) * _STEP_RAD
    east_m = (prime_vertical + h) * np.cos(np.radians(lat[i])) * _STEP_RAD
    return (
        (steps.e_east[i] - steps.e0[i]) / east_m,
        (steps.e_north[i] - steps.e0[i]) / north_m,
        (steps.n_east[i] - steps.n0[i]) / east_m,
        (steps.n_north[i] - steps.n0[i]) / north_m,
    )


@numba.njit(cache=True, error_model="numpy")
def _slant(
    rho: FloatArray,
    height: FloatArray,
    rc: float,
    site_alt: float,
    sin_psi: FloatArray,
    ground: FloatArray,
    gamma_x: FloatArray,
) -> None:  # pragma: no cover - compiled
    """``slant_geometry`` up to its ``arcsin`` and ``arctan2``: sin psi, the ground range
    and the second argument of gamma's arctan2 (k + rho sin psi)."""
    k = rc + site_alt
    for i in range(rho.shape[0]):
        r = rho[i]
        h = height[i]
        rho_safe = maximum(r, MIN_RANGE_M)
        s = ((h - site_alt) * (2.0 * rc + h + site_alt) - rho_safe * rho_safe) / (
            2.0 * rho_safe * k
        )
        if s < -1.0:
            s = -1.0
        elif s > 1.0:
            s = 1.0
        sin_psi[i] = s
        ground[i] = r * np.sqrt(1.0 - s * s)
        gamma_x[i] = k + r * s


@numba.njit(cache=True, error_model="numpy")
def _ecef(
    rho: FloatArray,
    theta: FloatArray,
    north_offset: float,
    ground: FloatArray,
    elevation: FloatArray,
    s: FloatArray,
    t: FloatArray,
    sin_az: FloatArray,
    cos_az: FloatArray,
    x: FloatArray,
    y: FloatArray,
    z: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The true azimuth's sine and cosine, the local ENU position
    (``local_from_azimuth``) and ECEF (``local_to_ecef``, ``s`` the site's ENU rotation,
    ``t`` its ECEF position)."""
    for i in range(rho.shape[0]):
        azimuth = np.radians(theta[i] + north_offset)
        sa = np.sin(azimuth)
        ca = np.cos(azimuth)
        sin_az[i] = sa
        cos_az[i] = ca
        east = ground[i] * sa
        north = ground[i] * ca
        up = rho[i] * np.sin(elevation[i])
        x[i] = s[0, 0] * east + s[1, 0] * north + s[2, 0] * up + t[0]
        y[i] = s[0, 1] * east + s[1, 1] * north + s[2, 1] * up + t[1]
        z[i] = s[0, 2] * east + s[1, 2] * north + s[2, 2] * up + t[2]


@numba.njit(cache=True, error_model="numpy")
def _turn_terms(
    lat: FloatArray,
    lon: FloatArray,
    site_rotation: FloatArray,
    w: FloatArray,
    turn_y: FloatArray,
    turn_x: FloatArray,
) -> None:  # pragma: no cover - compiled
    """Per point: w = 1 - e^2 sin^2 lat of ``radii_m`` (numpy raises it to 1.5), and the
    arguments of ``SystemPlane.radar_turn``'s arctan2 (M10 - M01, M00 + M11, M the
    target's east and north against the radar's, by ``einsum``'s order of sums)."""
    q = site_rotation
    for i in range(lat.shape[0]):
        lat_r = np.radians(lat[i])
        lon_r = np.radians(lon[i])
        sin_lat = np.sin(lat_r)
        w[i] = 1.0 - E2 * sin_lat * sin_lat
        cos_lat = np.cos(lat_r)
        sin_lon = np.sin(lon_r)
        cos_lon = np.cos(lon_r)
        # enu_rotation's first two rows.
        e0, e1, e2 = -sin_lon, cos_lon, 0.0
        n0, n1, n2 = -sin_lat * cos_lon, -sin_lat * sin_lon, cos_lat
        m00 = 0.0 + e0 * q[0, 0] + e2 * q[0, 2] + e1 * q[0, 1]
        m01 = 0.0 + e0 * q[1, 0] + e2 * q[1, 2] + e1 * q[1, 1]
        m10 = 0.0 + n0 * q[0, 0] + n2 * q[0, 2] + n1 * q[0, 1]
        m11 = 0.0 + n0 * q[1, 0] + n2 * q[1, 2] + n1 * q[1, 1]
        turn_y[i] = m10 - m01
        turn_x[i] = m00 + m11


@numba.njit(cache=True, error_model="numpy")
def _plane_terms(
    rho: FloatArray,
    height_sigma: FloatArray,
    sigma_rho: FloatArray,
    sigma_theta_deg: FloatArray,
    sin_psi: FloatArray,
    elevation: FloatArray,
    gamma: FloatArray,
    ground: FloatArray,
    sin_az: FloatArray,
    cos_az: FloatArray,
    lat: FloatArray,
    h: FloatArray,
    steps: PlaneSteps,
    angle: FloatArray,
    covariance: FloatArray,
    polar_jacobian: FloatArray,
) -> None:  # pragma: no cover - compiled
    """The rest of ``convert_plots``: the gains at the target, the horizontal covariance
    (``covariance_from_gains``), the plane's Jacobian (``SystemPlane.jacobian``, from
    the projections given), the radar turn, R and the polar Jacobian."""
    for i in range(rho.shape[0]):
        r = rho[i]
        psi = elevation[i]
        at_target = psi + gamma[i]
        cos_at_target = maximum(np.cos(at_target), MIN_COS_ELEVATION)
        range_gain = 1.0 / cos_at_target
        height_gain = -np.sin(at_target) / cos_at_target
        # covariance_from_gains, its height sigma 0.
        sr = sigma_rho[i]
        t1 = range_gain * sr
        t2 = height_gain * 0.0
        along = t1 * t1 + t2 * t2
        along = minimum(along, r * r + sr * sr)
        spread = np.radians(sigma_theta_deg[i])
        t3 = r * np.cos(psi) * spread
        cross = t3 * t3
        s = sin_az[i]
        c = cos_az[i]
        h00 = along * s * s + cross * c * c
        h11 = along * c * c + cross * s * s
        h01 = (along - cross) * s * c
        # SystemPlane.jacobian (stereographic: its up column is zero).
        j00, j01, j10, j11 = plane_jacobian_at(i, lat, h[i], steps)
        # a = jacobian[:2] @ radar_turn.
        ca = np.cos(angle[i])
        sa = np.sin(angle[i])
        a00 = _fma(j01, sa, _fma(j00, ca, 0.0))
        a01 = _fma(j01, ca, _fma(j00, -sa, 0.0))
        a10 = _fma(j11, sa, _fma(j10, ca, 0.0))
        a11 = _fma(j11, ca, _fma(j10, -sa, 0.0))
        # a @ horizontal @ a^T.
        b00 = _fma(a01, h01, _fma(a00, h00, 0.0))
        b01 = _fma(a01, h11, _fma(a00, h01, 0.0))
        b10 = _fma(a11, h01, _fma(a10, h00, 0.0))
        b11 = _fma(a11, h11, _fma(a10, h01, 0.0))
        c00 = _fma(b01, a01, _fma(b00, a00, 0.0))
        c01 = _fma(b01, a11, _fma(b00, a10, 0.0))
        c10 = _fma(b11, a01, _fma(b10, a00, 0.0))
        c11 = _fma(b11, a11, _fma(b10, a10, 0.0))
        # The height error's slide along the line of sight (the up column adds 0 * sigma).
        hs = height_sigma[i]
        slide = minimum(maximum(height_gain * hs, -r), r)
        u0 = s * slide
        u1 = c * slide
        shift0 = 0.0 + a00 * u0 + a01 * u1 + 0.0 * hs
        shift1 = 0.0 + a10 * u0 + a11 * u1 + 0.0 * hs
        covariance[i, 0, 0] = c00 + shift0 * shift0
        covariance[i, 0, 1] = c01 + shift0 * shift1
        covariance[i, 1, 0] = c10 + shift1 * shift0
        covariance[i, 1, 1] = c11 + shift1 * shift1
        v0 = s * range_gain
        v1 = c * range_gain
        polar_jacobian[i, 0, 0] = 0.0 + a00 * v0 + a01 * v1
        polar_jacobian[i, 1, 0] = 0.0 + a10 * v0 + a11 * v1
        g = ground[i]
        v0 = c * g
        v1 = -s * g
        polar_jacobian[i, 0, 1] = 0.0 + a00 * v0 + a01 * v1
        polar_jacobian[i, 1, 1] = 0.0 + a10 * v0 + a11 * v1


def _transform(transformer: Any, *columns: FloatArray) -> None:
    """``transformer.transform(*columns)`` written into the columns (float64, C order, of
    this module's own): pyproj's public call first tries its scalar path (an exception
    for arrays) and copies every input, which costs more than PROJ's work on a batch.
    The same PROJ call (pyproj 3.7, pinned in constraints.txt)."""
    x, y, *z = columns
    transformer._transformer._transform(
        inx=x,
        iny=y,
        inz=z[0] if z else None,
        intime=None,
        direction=TransformDirection.FORWARD,
        radians=False,
        errcheck=False,
    )


def convert_batch_plots(
    site: RadarSite,
    plane: SystemPlane,
    rho: FloatArray,
    theta: FloatArray,
    height: FloatArray,
    height_sigma: FloatArray,
    sigma_rho: FloatArray,
    sigma_theta: FloatArray,
) -> tuple[ConvertedPlots, PlaneSteps]:
    """``convert_plots(site, plane, rho, theta, height, height_sigma, sigma_rho,
    sigma_theta)`` of 1-D float64 arrays of one length, in a stereographic plane, with
    what it projected (``PlaneSteps``)."""
    assert plane.kind == "stereographic"
    n = rho.shape[0]
    sin_psi, ground, gamma_x = np.empty(n), np.empty(n), np.empty(n)
    _slant(rho, height, site.earth_radius_m, site.alt_m, sin_psi, ground, gamma_x)
    elevation = np.arcsin(sin_psi)
    gamma = np.arctan2(ground, gamma_x)
    sin_az, cos_az = np.empty(n), np.empty(n)
    x, y, z = np.empty(n), np.empty(n), np.empty(n)
    _ecef(
        rho, theta, site.north_offset_deg, ground, elevation, site.enu_rotation, site.ecef_m,
        sin_az, cos_az, x, y, z,
    )  # fmt: skip
    # PROJ in place: x, y, z become lon, lat, h.
    _transform(ecef_to_geodetic_transformer(), x, y, z)
    lon, lat, h = x, y, z
    project = plane._stereographic
    e0, n0 = lon.copy(), lat.copy()
    _transform(project, e0, n0)
    e_north, n_north = lon.copy(), lat + STEP_DEG
    _transform(project, e_north, n_north)
    e_east, n_east = lon + STEP_DEG, lat.copy()
    _transform(project, e_east, n_east)
    w, turn_y, turn_x = np.empty(n), np.empty(n), np.empty(n)
    _turn_terms(lat, lon, site.enu_rotation, w, turn_y, turn_x)
    steps = PlaneSteps(e0, n0, e_north, n_north, e_east, n_east, w, w**1.5)
    angle = np.arctan2(turn_y, turn_x)
    covariance = np.empty((n, 2, 2))
    polar_jacobian = np.empty((n, 2, 2))
    _plane_terms(
        rho, height_sigma, sigma_rho, sigma_theta, sin_psi, elevation, gamma, ground, sin_az,
        cos_az, lat, h, steps, angle, covariance, polar_jacobian,
    )  # fmt: skip
    converted = ConvertedPlots(
        x=e0,
        y=n0,
        height_m=np.array(height),
        height_sigma_m=np.array(height_sigma),
        R=covariance,
        lat_deg=lat,
        lon_deg=lon,
        elevation_rad=elevation,
        polar_jacobian=polar_jacobian,
    )
    return converted, steps


def convert_plots_compiled(
    site: RadarSite,
    plane: SystemPlane,
    rho_m: FloatArray,
    theta: FloatArray,
    height: FloatArray,
    height_sigma: FloatArray,
    sigma_rho: FloatArray,
    sigma_theta: FloatArray,
) -> tuple[ConvertedPlots, PlaneSteps | None]:
    """``convert_plots`` of one batch (1-D arrays of one length): in compiled passes in
    the stereographic plane (``convert_batch_plots``, the same values), with the
    projections it made."""
    if plane.kind != "stereographic":
        converted = convert_plots(
            site, plane, rho_m, theta, height, height_sigma, sigma_rho, sigma_theta
        )
        return converted, None
    columns = (rho_m, theta, height, height_sigma, sigma_rho, sigma_theta)
    return convert_batch_plots(site, plane, *(np.ascontiguousarray(c) for c in columns))
