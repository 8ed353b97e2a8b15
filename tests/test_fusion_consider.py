"""The system track's residual-bias "consider" terms (fusion/consider.py) against the
Schmidt-Kalman filter written out on the augmented state [x; b_1; b_2], and what they
mean: one radar's track follows its plots as its local tracker does, two radars are
weighed by their bias uncertainty."""

from __future__ import annotations

import numpy as np

from tracker_service.fusion import consider
from tracker_service.tracking import TrackerConfig
from tracker_service.tracking.models import ModelSet

CV_ONLY = ModelSet.from_config(
    TrackerConfig(turn_rates_deg_s=(), initial_model_probabilities=(1.0,), mean_sojourn_s=(60.0,))
)
H = np.hstack([np.eye(2), np.zeros((2, 2))])


def _random_cov(rng: np.random.Generator, n: int, scale: float) -> np.ndarray:
    a = rng.normal(size=(n, n))
    return np.asarray(scale * (a @ a.T + n * np.eye(n)))


def _prediction(x: np.ndarray, p: np.ndarray, m: np.ndarray) -> consider.ConsiderPrediction:
    return consider.predict(
        x[None, None], p[None, None], m[None, None], np.ones((1, 1)), np.zeros(1), CV_ONLY
    )


def test_update_is_the_schmidt_kalman_filter_of_the_augmented_state() -> None:
    rng = np.random.default_rng(5)
    x = rng.normal(size=4) * 100.0
    p = _random_cov(rng, 4, 50.0)
    m = rng.normal(size=(2, 4, 2)) * 0.5
    b = np.stack([_random_cov(rng, 2, 400.0), _random_cov(rng, 2, 100.0)])
    r = _random_cov(rng, 2, 900.0)
    z = rng.normal(size=2) * 100.0
    radar = 1

    # Augmented error [e_x; b_1; b_2] with e_x = n - sum_l M_l b_l.
    a = np.zeros((8, 8))
    a[:4, :4] = p + sum(m[j] @ b[j] @ m[j].T for j in range(2))
    for j in range(2):
        rows = slice(4 + 2 * j, 6 + 2 * j)
        a[:4, rows] = -m[j] @ b[j]
        a[rows, :4] = a[:4, rows].T
        a[rows, rows] = b[j]
    h = np.zeros((2, 8))
    h[:, :4] = H
    h[:, 4 + 2 * radar : 6 + 2 * radar] = np.eye(2)
    s = h @ a @ h.T + r
    cross = (a @ h.T)[:4]
    gain = cross @ np.linalg.inv(s)
    x_expected = x + gain @ (z - H @ x)
    a_xx = a[:4, :4] - gain @ cross.T - cross @ gain.T + gain @ s @ gain.T
    a_xb = a[:4, 4:] - gain @ (h @ a)[:, 4:]

    x_new, p_new, m_new, mu = consider.update(
        _prediction(x, p, m), z[None], r[None], radar, b[None]
    )
    assert np.allclose(x_new[0, 0], x_expected)
    total = p_new[0, 0] + consider.bias_share(m_new[0, 0], b)
    assert np.allclose(total, a_xx)
    for j in range(2):
        assert np.allclose(-m_new[0, 0, j] @ b[j], a_xb[:, 2 * j : 2 * j + 2])
    assert np.allclose(mu, 1.0)


def test_a_track_carrying_its_radars_bias_updates_as_without_it() -> None:
    """Founded by a local track (sensitivity [I; 0]), a system track fed by that radar
    alone takes its plots with the plot noise only, whatever the bias prior: no lag."""
    rng = np.random.default_rng(6)
    x, p, r = rng.normal(size=4) * 100.0, _random_cov(rng, 4, 50.0), _random_cov(rng, 2, 900.0)
    m = np.zeros((2, 4, 2))
    m[0] = consider.POSITION
    b = np.stack([np.diag([800.0**2, 300.0**2]), np.zeros((2, 2))])
    z = rng.normal(size=2) * 100.0
    x_new, p_new, m_new, _ = consider.update(_prediction(x, p, m), z[None], r[None], 0, b[None])
    gain = p @ H.T @ np.linalg.inv(H @ p @ H.T + r)
    assert np.allclose(x_new[0, 0], x + gain @ (z - H @ x))
    assert np.allclose(p_new[0, 0], (np.eye(4) - gain @ H) @ p)
    assert np.allclose(m_new[0, 0], m)
    # The reported covariance still holds the bias whole.
    total = p_new[0, 0] + consider.bias_share(m_new[0, 0], b)
    assert np.allclose(total[:2, :2] - p_new[0, 0, :2, :2], b[0])


def test_two_radars_are_weighed_by_their_bias_uncertainty() -> None:
    """Two plots of equal noise at one time, one radar's bias well known and the other's
    not: the fused position leans to the well-known radar, and its covariance holds
    the weighted biases."""
    p = np.diag([1e8, 1e8, 1e4, 1e4])  # no prior knowledge of the position
    b = np.stack([np.eye(2) * 10.0**2, np.eye(2) * 300.0**2])
    r = np.eye(2) * 50.0**2
    prediction = _prediction(np.zeros(4), p, np.zeros((2, 4, 2)))
    x1, p1, m1, _ = consider.update(prediction, np.array([[0.0, 0.0]]), r[None], 0, b[None])
    prediction = _prediction(x1[0, 0], p1[0, 0], m1[0, 0])
    x2, p2, m2, _ = consider.update(prediction, np.array([[1000.0, 0.0]]), r[None], 1, b[None])
    # Weights 1 / (R + B): (50^2 + 10^2) against (50^2 + 300^2).
    w = (1 / (50.0**2 + 300.0**2)) / (1 / (50.0**2 + 10.0**2) + 1 / (50.0**2 + 300.0**2))
    assert np.isclose(x2[0, 0, 0], 1000.0 * w, rtol=1e-3)
    total = p2[0, 0] + consider.bias_share(m2[0, 0], b)
    expected = 1 / (1 / (50.0**2 + 10.0**2) + 1 / (50.0**2 + 300.0**2))
    assert np.isclose(total[0, 0], expected, rtol=1e-3)
