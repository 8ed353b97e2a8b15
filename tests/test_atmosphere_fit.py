"""QNH and ISA deviation learnt from ADS-B geometric and barometric heights
(tracker_service.geodesy.atmosphere_fit), against the simulator's own atmosphere model."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.geodesy.atmosphere_fit import fit_atmosphere
from tracker_service.simulator import geometry

FT = 0.3048


def _reports(
    qnh: float,
    deviation: float,
    seed: int,
    *,
    n: int = 400,
    levels: tuple[float, float] = (50, 390),
) -> tuple[np.ndarray, np.ndarray]:
    """Aircraft at geometric heights spread over ``levels`` (FL): their I145 (25 ft
    quantised, from the simulator's model) and their GNSS height with 15 m of noise."""
    rng = np.random.default_rng(seed)
    height = rng.uniform(levels[0] * 100 * FT, levels[1] * 100 * FT + 1e-6, n)
    pressure_ft = np.asarray(geometry.pressure_altitude_ft(height, qnh, deviation))
    reported = np.round(pressure_ft / 25.0) * 25.0
    return reported, height + rng.normal(0.0, 15.0, n)


@pytest.mark.parametrize(
    ("qnh", "deviation"), [(1004.0, -7.0), (990.0, -15.0), (1035.0, 15.0), (1013.25, 0.0)]
)
def test_fit_recovers_qnh_and_temperature(qnh: float, deviation: float) -> None:
    pressure, height = _reports(qnh, deviation, seed=1)
    fit = fit_atmosphere(pressure, height)
    sigma_q, sigma_t = fit.sigma
    assert abs(fit.atmosphere.qnh_hpa - qnh) <= max(3 * sigma_q, 0.3)
    assert abs(fit.atmosphere.isa_deviation_k - deviation) <= max(3 * sigma_t, 0.3)
    assert sigma_q < 0.5 and sigma_t < 0.5
    assert fit.rejected == 0 and 12.0 < fit.residual_rms_m < 18.0


def test_one_level_cannot_separate_qnh_from_temperature() -> None:
    pressure, height = _reports(1004.0, -7.0, seed=2, levels=(350, 350))
    fit = fit_atmosphere(pressure, height)
    # The combination fits, the parts do not: the covariance says so.
    assert fit.residual_rms_m < 18.0
    assert fit.sigma[0] > 5.0 or fit.sigma[1] > 5.0


def test_gross_errors_are_rejected() -> None:
    pressure, height = _reports(1021.0, 6.0, seed=3)
    height[::20] += 400.0  # a wrong I145 or a GNSS height without integrity
    fit = fit_atmosphere(pressure, height)
    assert fit.rejected == 20
    assert abs(fit.atmosphere.qnh_hpa - 1021.0) < 0.5
    assert abs(fit.atmosphere.isa_deviation_k - 6.0) < 0.5


def test_bad_input_is_refused() -> None:
    with pytest.raises(ValueError, match="need 3"):
        fit_atmosphere([10000.0, 20000.0], [3000.0, 6000.0])
    with pytest.raises(ValueError, match="against"):
        fit_atmosphere([10000.0, 20000.0, 30000.0], [3000.0, 6000.0])
