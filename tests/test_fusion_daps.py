"""Mode S DAPs in the fuser's plot filter (fusion.plot_daps): the bias-free velocity as a
consider update, against the optimal Kalman update of the full error covariance."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.fusion import FusionConfig, consider, plot_daps
from tracker_service.tracking import daps as tracking_daps
from tracker_service.tracking import imm


def _spd(rng: np.random.Generator, d: int, scale: float) -> np.ndarray:
    a = rng.normal(0.0, scale, (d, d))
    return a @ a.T + np.eye(d) * scale**2 * 0.1


@pytest.mark.parametrize("seed", range(5))
def test_velocity_update_is_the_optimal_update_of_the_whole_error(seed: int) -> None:
    """The error e = n - sum_l M_l b_l has covariance C = P + sum_l M_l B_l M_l^T; a
    velocity z = v + w without bias updates it optimally to C - K S K^T (K = C H^T S^-1,
    H = [0 I2]): what P + sum M B M^T must be after the consider update, with the same
    state."""
    rng = np.random.default_rng(seed)
    radars = 3
    x = rng.normal(0.0, 100.0, (1, 1, 4))
    P = _spd(rng, 4, 30.0)[None, None]
    M = rng.normal(0.0, 0.6, (1, 1, radars, 4, 2))
    B = np.stack([_spd(rng, 2, 40.0) for _ in range(radars)])[None]
    z = rng.normal(0.0, 100.0, (1, 2))
    R = _spd(rng, 2, 2.0)[None]
    mu = np.ones((1, 1))
    x_new, p_new, m_new, mu_new = plot_daps.velocity_update(x, P, M, mu, B, z, R)
    C = P[0, 0] + consider.bias_share(M[0, 0], B[0])
    H = np.hstack([np.zeros((2, 2)), np.eye(2)])
    S = H @ C @ H.T + R[0]
    K = C @ H.T @ np.linalg.inv(S)
    np.testing.assert_allclose(x_new[0, 0], x[0, 0] + K @ (z[0] - H @ x[0, 0]), atol=1e-9)
    total = p_new[0, 0] + consider.bias_share(m_new[0, 0], B[0])
    np.testing.assert_allclose(total, C - K @ S @ K.T, atol=1e-8 * np.abs(C).max())
    assert mu_new.shape == (1, 1) and np.isclose(mu_new.sum(), 1.0)


def test_without_bias_it_is_the_local_trackers_update() -> None:
    rng = np.random.default_rng(7)
    k, m = 4, 5
    x = rng.normal(0.0, 100.0, (k, m, 4))
    P = np.stack([_spd(rng, 4, 20.0) for _ in range(k * m)]).reshape(k, m, 4, 4)
    mu = rng.dirichlet(np.ones(m), k)
    z = rng.normal(0.0, 100.0, (k, 2))
    R = np.stack([_spd(rng, 2, 2.0) for _ in range(k)])
    M = rng.normal(0.0, 0.6, (k, m, 2, 4, 2))
    want = tracking_daps.velocity_update(x, P, mu, z, R)
    got = plot_daps.velocity_update(x, P, M, mu, np.zeros((k, 2, 2, 2)), z, R)
    for a, b in zip(want, (got[0], got[1], got[3]), strict=True):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)


def test_use_daps_is_validated() -> None:
    with pytest.raises(ValueError, match="use_daps"):
        FusionConfig(use_daps=1)  # type: ignore[arg-type]


def test_the_plot_filter_takes_the_velocity_only_with_use_daps() -> None:
    """One round of plots with BDS 5,0 velocities 20 m/s off the tracks' velocity: with
    ``use_daps`` the system tracks' velocities move toward them and their velocity
    variances shrink; without, the round ignores the DAP columns."""
    from tests.test_fusion_kernels import _plots, _states
    from tracker_service.fusion import estimator_plots
    from tracker_service.tracking.plots import DAP_VELOCITY, as_plot_arrays

    results = {}
    for use_daps in (False, True):
        _, state, rng = _states(3, 2, 6, use_daps=use_daps)
        numbers = np.arange(1, 7)
        sys = state.sys
        sys["x"][numbers], _ = imm.combine(
            sys["mx"][numbers], sys["mP"][numbers], sys["mu"][numbers]
        )
        rows = _plots(rng, state, numbers).rows.copy()
        rows["time"] = sys["t"][numbers] + 1.0
        target = sys["x"][numbers, 2:] + 20.0
        rows["dap_vx"], rows["dap_vy"] = target.T
        rows["dap_flags"] = DAP_VELOCITY
        extra = np.broadcast_to(np.eye(2) * 900.0, (6, 2, 2)).copy()
        estimator_plots._filter_round(state, 0, numbers, as_plot_arrays(rows), extra)
        miss = np.linalg.norm(state.sys["x"][numbers, 2:] - target, axis=1)
        var = state.sys["P"][numbers, 2, 2] + state.sys["P"][numbers, 3, 3]
        results[use_daps] = (miss, var, state.stats.dap_velocity_updates)
    assert results[False][2] == 0
    updated = results[True][2]
    assert updated > 0
    assert np.sum(results[True][0] < results[False][0]) >= updated
    assert np.sum(results[True][1] < results[False][1]) >= updated
