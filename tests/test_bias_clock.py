"""Clock drift in the bias filters (issue 14): the 2- and 3-state time error per radar."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.bias import (
    BiasConfig,
    BiasEstimator,
    ObservationKind,
    SeparatedBiasFilter,
    make_bias_estimator,
    make_observations,
)
from tracker_service.bias.clock import ClockModel
from tracker_service.bias.reception import ReceptionEvidence

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
    config = BiasConfig(clock_states=3, reception_clock=False)
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


# --- CAT034 time stamps against reception (BiasConfig.reception_clock) ---------------------

DELAY_S = 0.07
SECTOR_S = 10.0 / 16


def _feed_with_reception(
    drift_s_per_h: float, seed: int, *, reception: bool, late: float = 0.0
) -> BiasEstimator:
    """One 10 s radar for 10 minutes: plots of 10 ADS-B aircraft per scan with noise of
    150 m (0.6 s of time offset per plot: about the clock_drift scenario's worst radar),
    and 16 CAT034 messages per scan received DELAY_S after their stamp with 20 ms of
    uniform jitter; a fraction ``late`` of them held 0.5 s in a queue."""
    rng = np.random.default_rng(seed)
    config = BiasConfig(clock_states=2, reception_clock=reception)
    estimator = make_bias_estimator(config, 1)
    n = 10
    for k in range(60):
        t = 10.0 * k
        offset = OFFSET_S + drift_s_per_h / 3600.0 * np.arange(t, t + 10.0, SECTOR_S)
        stamps = np.arange(t, t + 10.0, SECTOR_S) + offset
        received = stamps - offset + DELAY_S + rng.uniform(0.0, 0.02, len(stamps))
        received += np.where(rng.random(len(stamps)) < late, 0.5, 0.0)
        estimator.update_reception(0, np.column_stack([stamps, received]))
        azimuth = rng.uniform(0.0, 2 * np.pi, n)
        rho = rng.uniform(5e4, 2e5, n)
        u_r = np.stack([np.sin(azimuth), np.cos(azimuth)], axis=1)
        u_theta = np.stack([np.cos(azimuth), -np.sin(azimuth)], axis=1) * rho[:, None]
        v = rng.normal(0.0, 180.0, (n, 2))
        C = np.stack([u_r, u_r * rho[:, None], u_theta, -v], axis=2)
        s = np.array([100.0, 1e-4, 1e-3, OFFSET_S + drift_s_per_h / 3600.0 * (t + 9.9)])
        p = rng.normal(0.0, 1e5, (n, 2))
        y = p + C @ s + rng.normal(0.0, 150.0, (n, 2))
        estimator.update(
            make_observations(
                1,
                np.zeros(n),
                np.full(n, t + 9.9),
                y,
                np.broadcast_to(np.eye(2) * 150.0**2, (n, 2, 2)),
                C,
                p,
                np.broadcast_to(np.eye(2), (n, 2, 2)),
                kind=ObservationKind.ADSB,
            )
        )
    return estimator


def _drift(estimator: BiasEstimator) -> tuple[float, float]:
    estimates = estimator.estimates()
    assert estimates.clock.shape == (1, 1)  # the delay is not published
    return estimates.clock[0, 0] * 3600.0, float(np.sqrt(estimates.clock_P[0, 0, 0])) * 3600.0


@pytest.mark.parametrize("truth", [0.3, -0.3, 1.0])
def test_reception_stamps_pin_the_drift_where_adsb_alone_cannot(truth: float) -> None:
    _, alone_sigma = _drift(_feed_with_reception(truth, seed=7, reception=False))
    both, sigma = _drift(_feed_with_reception(truth, seed=7, reception=True))
    # ADS-B alone: a sigma of about half the drift (the Cramer-Rao bound's order).
    assert alone_sigma > 0.1
    assert abs(both - truth) <= 0.1 * abs(truth)
    assert abs(both - truth) <= 3.0 * sigma
    assert sigma < 0.05 * alone_sigma


def test_queued_cat034_messages_are_gated_out() -> None:
    estimator = _feed_with_reception(0.3, seed=8, reception=True, late=0.05)
    drift, sigma = _drift(estimator)
    assert abs(drift - 0.3) <= 3.0 * sigma
    assert isinstance(estimator, SeparatedBiasFilter)
    used, rejected = int(estimator.reception_used[0]), int(estimator.reception_rejected[0])
    assert used + rejected == 59 * 16  # the first scan's come before the first ADS-B
    assert 0.03 * 960 <= rejected <= 0.08 * 960


def test_reception_stamps_wait_for_the_time_offset_to_be_estimated() -> None:
    """Before any ADS-B the offset is not free: the stamps change nothing."""
    estimator = make_bias_estimator(BiasConfig(clock_states=2), 1)
    stamps = np.arange(0.0, 60.0, SECTOR_S)
    estimator.update_reception(0, np.column_stack([stamps, stamps + 1.0]))
    estimates = estimator.estimates()
    assert estimates.clock[0, 0] == 0.0 and estimates.s[0, 3] == 0.0


def test_the_delay_is_a_state_the_transition_leaves_alone() -> None:
    model = ClockModel(BiasConfig(clock_states=3))
    assert (model.n_clock, model.n_extra) == (2, 3)
    offset, extra = model.indices(1)
    x = np.arange(7.0)
    P = np.eye(7)
    model.predict(x, P, 5.0, offset, extra, np.ones(1, dtype=bool))
    assert x[6] == 6.0 and P[6, 6] == 1.0 and not P[6, :6].any()
    assert ClockModel(BiasConfig(clock_states=1)).n_extra == 0


def test_service_messages_become_evidence_of_their_radar() -> None:
    evidence = ReceptionEvidence()
    day = 86400.0 * 20000
    north = {"010": {"SAC": 25, "SIC": 11}, "000": 1, "030": 86399.95}
    evidence.service_message(north, day + 0.02)  # stamped before midnight, received after
    evidence.service_message({**north, "000": 2, "030": 0.6}, day + 0.68)
    evidence.service_message({**north, "000": 3, "030": 1.0}, day + 1.1)  # not a boundary
    evidence.service_message({**north, "030": 50.0}, day + 0.7)  # 49 s off: no evidence
    taken = evidence.take("25/11")
    np.testing.assert_allclose(taken, [[day - 0.05, day + 0.02], [day + 0.6, day + 0.68]])
    assert evidence.take("25/11").shape == (0, 2)
    assert evidence.take("25/12").shape == (0, 2)
