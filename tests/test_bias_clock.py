"""Clock drift in the bias filters (issue 14): the 2- and 3-state time error per radar."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.bias import (
    BiasConfig,
    BiasEstimator,
    ObservationKind,
    make_bias_estimator,
    make_observations,
)
from tracker_service.bias.clock import ClockModel

DRIFT_S_PER_H = 1.0
OFFSET_S = 0.1


def _feed(
    method: str, states: int, seed: int, *, kind: int = ObservationKind.ADSB
) -> BiasEstimator:
    """One radar seeing 20 ADS-B-referenced aircraft every 5 s for 10 minutes, its clock
    drifting; plots of 10 m noise (the time offset per plot: 10 m over 250 m/s)."""
    rng = np.random.default_rng(seed)
    estimator = make_bias_estimator(BiasConfig(method=method, clock_states=states), 1)
    n = 20
    for k in range(120):
        t = 5.0 * k
        azimuth = rng.uniform(0.0, 2 * np.pi, n)
        rho = rng.uniform(2e4, 2e5, n)
        u_r = np.stack([np.sin(azimuth), np.cos(azimuth)], axis=1)
        u_theta = np.stack([np.cos(azimuth), -np.sin(azimuth)], axis=1) * rho[:, None]
        v = rng.normal(0.0, 250.0, (n, 2))
        C = np.stack([u_r, u_r * rho[:, None], u_theta, -v], axis=2)
        s = np.array([100.0, 1e-4, 1e-3, OFFSET_S + DRIFT_S_PER_H / 3600.0 * t])
        p = rng.normal(0.0, 1e5, (n, 2))
        y = p + C @ s + rng.normal(0.0, 10.0, (n, 2))
        estimator.update(
            make_observations(
                1,
                np.zeros(n),
                np.full(n, t),
                y,
                np.broadcast_to(np.eye(2) * 100.0, (n, 2, 2)),
                C,
                p,
                np.broadcast_to(np.eye(2), (n, 2, 2)),
                kind=kind,
            )
        )
    return estimator


@pytest.mark.parametrize("states", [2, 3])
def test_drift_estimated_within_ten_percent_in_ten_minutes(states: int) -> None:
    estimator = _feed("separated", states, seed=1)
    estimates = estimator.estimates()
    drift = estimates.clock[0, 0] * 3600.0
    sigma = np.sqrt(estimates.clock_P[0, 0, 0]) * 3600.0
    assert estimates.clock.shape == (1, states - 1)
    assert abs(drift - DRIFT_S_PER_H) <= 0.1 * DRIFT_S_PER_H
    assert abs(drift - DRIFT_S_PER_H) <= 3.0 * sigma
    # The offset is the one at the filter's time (595 s), not the start's.
    assert estimates.s[0, 3] == pytest.approx(OFFSET_S + DRIFT_S_PER_H * 595.0 / 3600.0, abs=5e-3)


def test_the_three_variants_agree_on_one_radar() -> None:
    """One radar, fixed references only: the macro and coupled filters reduce to the
    separated one's algebra (batch information form against one plot at a time)."""
    results = [_feed(method, 3, seed=2).estimates() for method in ("separated", "macro", "coupled")]
    for other in results[1:]:
        np.testing.assert_allclose(other.clock, results[0].clock, rtol=1e-6, atol=1e-12)
        np.testing.assert_allclose(other.s, results[0].s, rtol=1e-6, atol=1e-9)


def test_one_state_clock_has_no_drift() -> None:
    estimates = _feed("separated", 1, seed=3).estimates()
    assert estimates.clock.shape == (1, 0)
    # A random walk lags a drifting clock: the offset trails the truth.
    assert estimates.s[0, 3] < OFFSET_S + DRIFT_S_PER_H * 595.0 / 3600.0


def test_traffic_alone_leaves_the_separated_clock_at_its_prior() -> None:
    estimates = _feed("separated", 2, seed=4, kind=ObservationKind.AIRCRAFT).estimates()
    assert not estimates.estimated[0, 3]
    assert estimates.clock[0, 0] == 0.0
    assert np.sqrt(estimates.clock_P[0, 0, 0]) * 3600.0 == pytest.approx(1.0)


def test_transition_is_f_p_f_transpose() -> None:
    config = BiasConfig(clock_states=3)
    model = ClockModel(config)
    rng = np.random.default_rng(5)
    n_radars = 2
    size = 6 * n_radars
    a = rng.normal(size=(size, size))
    P = a @ a.T
    x = rng.normal(size=size)
    offset, extra = model.indices(n_radars)
    dt = 7.0
    F = np.eye(size)
    for radar in range(n_radars):
        o, (d, r) = offset[radar], extra[radar]
        F[o, d] = dt * model.scale[0] / model.offset_scale
        F[o, r] = 0.5 * dt**2 * model.scale[1] / model.offset_scale
        F[d, r] = dt * model.scale[1] / model.scale[0]
    x2, P2 = x.copy(), P.copy()
    model.predict(x2, P2, dt, offset, extra, np.ones(n_radars, dtype=bool))
    np.testing.assert_allclose(x2, F @ x)
    np.testing.assert_allclose(P2, F @ P @ F.T)


@pytest.mark.parametrize("value", [0, 4, True, 2.5])
def test_clock_states_validated(value: object) -> None:
    with pytest.raises(ValueError, match="clock_states"):
        BiasConfig(clock_states=value)  # type: ignore[arg-type]
