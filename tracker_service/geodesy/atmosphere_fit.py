"""The atmosphere learnt from ADS-B: QNH and ISA deviation from geometric and barometric
heights of the same reports (issue 14: "QNH and temperature from configuration (or learnt
from ADS-B geometric height)").

A CAT021 report carries the aircraft's GNSS height above the WGS84 ellipsoid (I140) and
its barometric pressure altitude (I145, the Mode C of the same altimeter). With the geoid
undulation N at the report, h = I140 - N is the geometric height above MSL, and
``Atmosphere(qnh, dT).height_m(I145)`` must equal it. The two parameters separate with
height: a QNH change lifts every level by about 8 m per hPa, a temperature deviation
scales the column (about 0.35 % of the height per K): aircraft spread over several levels
fix both; aircraft at one level only the combination (the covariance says so).

``fit_atmosphere`` is the weighted least squares (Gauss-Newton; the model is smooth and
nearly linear over the valid range) with a few passes of rejection of residuals beyond
``REJECT_SIGMAS`` (a wrong I145, a GNSS height without integrity). The noise per report:
the GNSS vertical error (``sigma_geometric_m``; GVA 2, 45 m at 95 %, is 23 m, modern
receivers do better) and the quantisation of I145 (25 ft LSB: 2.2 m).

Not wired into the chain: the radar stages' conversion (possibly in other processes) would
need a message that takes the central stage's estimate to them, and the bias filters
would see their range offsets move while it converges (docs/fusion.md, "Vertical tracking
and atmosphere", "What is left"). ``benchmarks/atmosphere_fit.py`` fits a recording's
CAT021.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.atmosphere import (
    ISA_DEVIATION_RANGE_K,
    QNH_RANGE_HPA,
    Atmosphere,
)
from tracker_service.geodesy.ellipsoid import FloatArray, as_float

I145_QUANTISATION_M = 25.0 * 0.3048 / math.sqrt(12.0)
REJECT_SIGMAS = 5.0
ITERATIONS = 8
STEP = np.array([0.01, 0.01])
"""Finite-difference steps (hPa, K) of the Jacobian."""
PRIOR_SIGMA = np.array([30.0, 20.0])
"""A weak prior (hPa, K) around the first guess: where the reports fix only a combination
of the two (one level), the other direction keeps the prior's uncertainty instead of an
arbitrary pseudo-inverse's."""


@dataclass(frozen=True)
class AtmosphereFit:
    """The fitted atmosphere, the covariance of (QNH hPa, ISA deviation K), the reports
    used and rejected, and the RMS of the used residuals (m)."""

    atmosphere: Atmosphere
    covariance: FloatArray
    used: int
    rejected: int
    residual_rms_m: float

    @property
    def sigma(self) -> tuple[float, float]:
        return (float(math.sqrt(self.covariance[0, 0])), float(math.sqrt(self.covariance[1, 1])))


def _clamped(qnh: float, deviation: float) -> Atmosphere:
    return Atmosphere(
        float(np.clip(qnh, *QNH_RANGE_HPA)), float(np.clip(deviation, *ISA_DEVIATION_RANGE_K))
    )


def fit_atmosphere(
    pressure_altitude_ft: npt.ArrayLike,
    geometric_height_m: npt.ArrayLike,
    sigma_geometric_m: float = 15.0,
    first_guess: Atmosphere | None = None,
) -> AtmosphereFit:
    """(QNH, ISA deviation) from pairs of pressure altitude (ft, I145 x 100) and geometric
    height above MSL (m, I140 less the geoid); see the module docstring. Needs 3 reports."""
    pressure = as_float(pressure_altitude_ft).reshape(-1)
    height = as_float(geometric_height_m).reshape(-1)
    if pressure.shape != height.shape:
        raise ValueError(f"{pressure.shape} pressure altitudes against {height.shape} heights")
    finite = np.isfinite(pressure) & np.isfinite(height)
    if np.count_nonzero(finite) < 3:
        raise ValueError(f"{np.count_nonzero(finite)} usable reports: need 3 or more")
    variance = sigma_geometric_m**2 + I145_QUANTISATION_M**2
    guess = first_guess or Atmosphere()
    theta0 = np.array([guess.qnh_hpa, guess.isa_deviation_k])
    theta = theta0.copy()
    prior_information = np.diag(1.0 / PRIOR_SIGMA**2)
    use = finite.copy()
    covariance = np.full((2, 2), np.inf)
    residual = np.zeros_like(height)
    for _ in range(ITERATIONS):
        model = _clamped(*theta).height_m(pressure)
        residual = height - model
        jacobian = np.column_stack(
            [
                (_clamped(theta[0] + STEP[0], theta[1]).height_m(pressure) - model) / STEP[0],
                (_clamped(theta[0], theta[1] + STEP[1]).height_m(pressure) - model) / STEP[1],
            ]
        )
        j, r = jacobian[use], residual[use]
        covariance = np.linalg.inv(j.T @ j / variance + prior_information)
        theta = theta + covariance @ (j.T @ r / variance - prior_information @ (theta - theta0))
        theta = np.clip(
            theta,
            [QNH_RANGE_HPA[0], ISA_DEVIATION_RANGE_K[0]],
            [QNH_RANGE_HPA[1], ISA_DEVIATION_RANGE_K[1]],
        )
        # Outliers against the current fit, never below 3 reports.
        spread = REJECT_SIGMAS * math.sqrt(variance)
        keep = finite & (np.abs(height - _clamped(*theta).height_m(pressure)) <= spread)
        if np.count_nonzero(keep) >= 3:
            use = keep
    final = _clamped(*theta)
    residual = (height - final.height_m(pressure))[use]
    return AtmosphereFit(
        atmosphere=final,
        covariance=covariance,
        used=int(np.count_nonzero(use)),
        rejected=int(np.count_nonzero(finite & ~use)),
        residual_rms_m=float(np.sqrt(np.mean(residual**2))),
    )
