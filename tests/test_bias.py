"""Bias estimators on synthetic plots with known biases (DOMAIN.md section 6).

Three radars at surveyed sites in a plane see straight-flying aircraft; each plot is made
non-linearly (true position at t - b_t, range (1+g) rho + b_r, azimuth + b_theta, polar
noise), so the estimators' linear model is only an approximation, as with real data.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import get_args

import numpy as np
import pytest

from tracker_service.bias import (
    BiasConfig,
    BiasEstimates,
    BiasEstimator,
    BiasObservations,
    CoupledSizeError,
    ObservationKind,
    common,
    fuse_references,
    make_bias_estimator,
    make_observations,
)
from tracker_service.bias.config import TIME
from tracker_service.outputs.messages import BiasSource

SITES = np.array([[0.0, 0.0], [150e3, 0.0], [75e3, 130e3]])
TRUE_BIAS = np.array(
    [
        [120.0, 8e-4, math.radians(0.12), 0.08],
        [-80.0, -5e-4, math.radians(-0.08), -0.05],
        [50.0, 1.2e-3, math.radians(0.05), 0.12],
    ]
)
SIGMA_RHO = 40.0
SIGMA_THETA = math.radians(0.06)
SCAN_S = 4.0
ADSB_SIGMA = 15.0
TOLERANCE = np.array([15.0, 1e-4, math.radians(0.01), 0.03])


class Scene:
    """Aircraft on straight lines and the radars' biased plots of them."""

    def __init__(self, n_radars: int, n_aircraft: int, true_bias: np.ndarray, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.sites = SITES[:n_radars]
        self.bias = true_bias[:n_radars]
        self.start = self.rng.uniform([20e3, 20e3], [130e3, 110e3], size=(n_aircraft, 2))
        heading = self.rng.uniform(0, 2 * np.pi, n_aircraft)
        self.velocity = 220.0 * np.column_stack([np.sin(heading), np.cos(heading)])

    def position(self, t: float | np.ndarray) -> np.ndarray:
        position: np.ndarray = self.start + self.velocity * np.reshape(t, (-1, 1))
        return position

    def plots(
        self, radar: int, truth_at: np.ndarray, velocity: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """y, R, C of radar's plots of positions truth_at (already at t - b_t)."""
        b_r, g, b_theta, _ = self.bias[radar]
        d = truth_at - self.sites[radar]
        rho = np.hypot(d[:, 0], d[:, 1])
        theta = np.arctan2(d[:, 0], d[:, 1])
        n = len(rho)
        rho_m = (1 + g) * rho + b_r + self.rng.normal(0, SIGMA_RHO, n)
        theta_m = theta + b_theta + self.rng.normal(0, SIGMA_THETA, n)
        u_r = np.column_stack([np.sin(theta_m), np.cos(theta_m)])
        u_theta = rho_m[:, None] * np.column_stack([np.cos(theta_m), -np.sin(theta_m)])
        y = self.sites[radar] + rho_m[:, None] * u_r
        J = np.stack([u_r, u_theta], axis=2)
        R = J @ np.diag([SIGMA_RHO**2, SIGMA_THETA**2]) @ J.transpose(0, 2, 1)
        C = np.stack([u_r, rho_m[:, None] * u_r, u_theta, -velocity], axis=2)
        return y, R, C

    def scan(self, t: float) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
        """Every radar's plots of every aircraft labelled t."""
        v = np.broadcast_to(self.velocity, self.start.shape)
        return [
            self.plots(r, self.position(t - self.bias[r, TIME]), v) for r in range(len(self.sites))
        ]


def corrections(estimator: BiasEstimator, n_radars: int) -> tuple[np.ndarray, np.ndarray]:
    pairs = [estimator.correction(r) for r in range(n_radars)]
    return np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs])


def traffic_batch(
    scene: Scene,
    estimator: BiasEstimator,
    radar: int,
    t: float,
    measured: tuple[np.ndarray, np.ndarray, np.ndarray],
    others: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    n_adsb: int,
) -> BiasObservations:
    """Radar's plots with references as the chain would build them: the other radars'
    positions corrected by their current estimates (separated), the fused prediction of
    all radars (macro), ADS-B reports for the first n_adsb aircraft."""
    n_radars = len(scene.sites)
    y, R, C = measured
    n = len(y)
    s, P_s = corrections(estimator, n_radars)
    ys = np.stack([o[0] for o in others], axis=1)
    Rs = np.stack([o[1] for o in others], axis=1)
    Cs = np.stack([o[2] for o in others], axis=1)
    s_k = np.broadcast_to(s, (n, *s.shape))
    P_k = np.broadcast_to(P_s, (n, *P_s.shape))
    everyone = np.ones((n, n_radars), dtype=bool)
    not_me = everyone.copy()
    not_me[:, radar] = False
    ref_xy, ref_P = fuse_references(ys, Rs, Cs, s_k, P_k, not_me)
    pred_xy, pred_P = fuse_references(ys, Rs, Cs, s_k, np.zeros_like(P_k), everyone)
    kind = np.full(n, ObservationKind.AIRCRAFT, dtype=np.int8)
    kind[:n_adsb] = ObservationKind.ADSB
    truth = scene.position(t)
    ref_xy[:n_adsb] = truth[:n_adsb] + scene.rng.normal(0, ADSB_SIGMA, (n_adsb, 2))
    ref_P[:n_adsb] = np.eye(2) * ADSB_SIGMA**2
    if n_radars == 1:
        ref_xy[n_adsb:], ref_P[n_adsb:] = ys[n_adsb:, 0], Rs[n_adsb:, 0]
    return make_observations(
        n_radars,
        np.full(n, radar),
        np.full(n, t),
        y,
        R,
        C,
        ref_xy,
        ref_P,
        kind=kind,
        group=np.arange(n),
        reference_v=scene.velocity + scene.rng.normal(0, 5.0, (n, 2)),
        prediction_xy=pred_xy,
        prediction_P=pred_P,
        contributors=everyone,
        contributor_R=Rs,
        contributor_C=Cs,
    )


BatchHook = Callable[[int, BiasObservations], BiasObservations]


def run(
    method: str,
    *,
    n_radars: int = 3,
    n_aircraft: int = 10,
    n_scans: int = 100,
    n_adsb: int = 3,
    true_bias: np.ndarray = TRUE_BIAS,
    hook: BatchHook | None = None,
    seed: int = 1,
    **config: object,
) -> tuple[BiasEstimator, Scene]:
    scene = Scene(n_radars, n_aircraft, true_bias, seed)
    estimator = make_bias_estimator(BiasConfig(method=method, **config), n_radars)  # type: ignore[arg-type]
    for k in range(n_scans):
        t = k * SCAN_S
        measured, fresh = scene.scan(t), scene.scan(t)
        for radar in range(n_radars):
            batch = traffic_batch(scene, estimator, radar, t, measured[radar], fresh, n_adsb)
            estimator.update(hook(radar, batch) if hook else batch)
    return estimator, scene


def assert_recovered(est: BiasEstimates, truth: np.ndarray, components: list[int]) -> None:
    error = est.s - truth
    sigma = est.sigma()
    for c in components:
        assert np.all(np.abs(error[:, c]) < TOLERANCE[c]), (c, error[:, c], sigma[:, c])
        assert np.all(np.abs(error[:, c]) < 3 * sigma[:, c]), (c, error[:, c], sigma[:, c])


@pytest.mark.parametrize("method", ["separated", "macro", "coupled"])
def test_recovers_biases_and_time_with_adsb(method: str) -> None:
    estimator, _ = run(method, n_adsb=5, n_scans=150)
    est = estimator.estimates()
    assert est.estimated.all()
    assert_recovered(est, TRUE_BIAS, [0, 1, 2, 3])
    assert (est.n_used > 0).all()
    # The separated filters learn time offsets from ADS-B alone (traffic never moves them).
    time_sources = {"adsb"} if method == "separated" else {"adsb", "other_radars"}
    for radar in est.observed_from:
        assert [set(c) for c in radar[:TIME]] == [{"adsb", "other_radars"}] * TIME
        assert set(radar[TIME]) == time_sources


def test_time_offset_left_at_prior_without_clock_reference() -> None:
    no_time = TRUE_BIAS.copy()
    no_time[:, TIME] = 0.0
    estimator, _ = run("macro", n_adsb=0, true_bias=no_time, n_scans=150, seed=2)
    est = estimator.estimates()
    assert not est.estimated[:, TIME].any()
    assert est.estimated[:, :TIME].all()
    assert est.observed_from == ((("other_radars",),) * TIME + ((),),) * 3
    assert np.all(est.s[:, TIME] == 0.0)
    assert np.allclose(est.sigma()[:, TIME], 0.3)
    assert_recovered(est, no_time, [0, 1, 2])


@pytest.mark.parametrize("method", ["separated", "macro", "coupled"])
def test_one_radar_without_reference_keeps_the_prior(method: str) -> None:
    estimator, _ = run(method, n_radars=1, n_adsb=0, n_scans=20)
    est = estimator.estimates()
    assert not est.estimated.any()
    assert est.observed_from == (((),) * 4,)
    assert np.all(est.s == 0.0)
    assert np.allclose(est.sigma()[0], BiasConfig().prior_sigma())


def test_reference_radar_is_not_estimated_and_anchors_time() -> None:
    """Without ADS-B, a reference radar makes the others' time offsets absolute (the macro
    filter: the separated one learns time offsets from clock references only)."""
    known = TRUE_BIAS[0]
    reference = {0: (known[0], known[1], math.degrees(known[2]), known[3])}
    estimator, _ = run("macro", n_adsb=0, n_scans=150, reference_radars=reference)
    est = estimator.estimates()
    assert est.reference[0] and not est.estimated[0].any()
    assert est.observed_from[0] == (("configuration",),) * 4
    assert est.observed_from[1:] == ((("reference_radar", "other_radars"),) * 4,) * 2
    assert np.array_equal(est.s[0], known) and np.all(est.P[0] == 0.0)
    assert est.estimated[1:].all()
    error = est.s[1:] - TRUE_BIAS[1:]
    assert np.all(np.abs(error) < TOLERANCE), error


def test_field_monitor_pins_range_and_azimuth_of_a_single_radar() -> None:
    rng = np.random.default_rng(3)
    scene = Scene(1, 1, TRUE_BIAS, 3)
    estimator = make_bias_estimator(BiasConfig(), 1)
    monitor = np.array([[18e3, 21e3]])
    rho = float(np.hypot(*monitor[0]))
    for k in range(150):
        y, R, C = scene.plots(0, monitor, np.zeros((1, 2)))
        surveyed = monitor + rng.normal(0, 1.0, (1, 2))
        obs = make_observations(
            1,
            [0],
            [k * SCAN_S],
            y,
            R,
            C,
            surveyed,
            np.eye(2)[None],
            kind=ObservationKind.FIELD_MONITOR,
        )
        estimator.update(obs)
    est = estimator.estimates()
    # One range only: offset and gain are seen as their sum at that range.
    seen = est.s[0, 0] + est.s[0, 1] * rho
    truth = TRUE_BIAS[0, 0] + TRUE_BIAS[0, 1] * rho
    assert abs(seen - truth) < 15.0
    assert abs(est.s[0, 2] - TRUE_BIAS[0, 2]) < math.radians(0.01)
    assert not est.estimated[0, TIME]
    assert est.observed_from == ((("field_monitor",),) * TIME + ((),),)


@pytest.mark.parametrize("method", ["separated", "macro", "coupled"])
def test_gross_outliers_are_gated_and_counted(method: str) -> None:
    injected = 0
    rng = np.random.default_rng(7)

    def wrong_association(radar: int, batch: BiasObservations) -> BiasObservations:
        nonlocal injected
        if batch.time[0] < 5 * SCAN_S:
            # A coupled track started on an outlier rejects its aircraft's plots until it
            # times out; here the outliers come once the aircraft are initialised.
            return batch
        row = rng.choice(np.flatnonzero(batch.kind == ObservationKind.AIRCRAFT))
        batch.y[row] += 5000.0 * np.array([math.cos(row), math.sin(row)])
        injected += 1
        return batch

    estimator, _ = run(method, hook=wrong_association, n_adsb=5, n_scans=150)
    est = estimator.estimates()
    assert injected > 400
    assert est.n_rejected.sum() >= injected
    assert est.n_rejected.sum() < injected + 0.02 * est.n_used.sum()
    assert_recovered(est, TRUE_BIAS, [0, 2])


def own_track_references(scene: Scene, *, corrected: bool) -> BatchHook:
    """Radar 0's references from its own track (its own plots, carrying its own bias)."""

    def hook(radar: int, batch: BiasObservations) -> BiasObservations:
        if radar != 0:
            return batch
        t = float(batch.time[0])
        v = np.broadcast_to(scene.velocity, scene.start.shape)
        y, R, C = scene.plots(0, scene.position(t - scene.bias[0, TIME]), v)
        if corrected:
            s, P = hook.estimator.correction(0)  # type: ignore[attr-defined]
            ref_xy, ref_P = fuse_references(
                y[:, None],
                R[:, None],
                C[:, None],
                s[None, None],
                P[None, None],
                np.ones((len(y), 1), bool),
            )
        else:
            ref_xy, ref_P = y, np.zeros_like(R)
        traffic = batch.kind == ObservationKind.AIRCRAFT
        batch.reference_xy[traffic] = ref_xy[batch.group[traffic]]
        batch.reference_P[traffic] = ref_P[batch.group[traffic]]
        return batch

    return hook


def test_separated_own_track_reference_does_not_drift_when_corrected() -> None:
    """Radar 0 converges on other radars' references, then gets only its own track.
    Corrected by the current estimate, with its covariance in reference_P
    (``fuse_references``), the residual carries no bias and the estimate stays. Taken as
    is (bias inside, reference_P = 0) the residual is -C s: it would pull s to 0, and
    the gate rejects it."""
    results = {}
    for corrected in (True, False):
        scene = Scene(3, 10, TRUE_BIAS, 5)
        estimator = make_bias_estimator(BiasConfig(), 3)
        hook = own_track_references(scene, corrected=corrected)
        hook.estimator = estimator  # type: ignore[attr-defined]
        for k in range(160):
            t = k * SCAN_S
            measured, fresh = scene.scan(t), scene.scan(t)
            for radar in range(3):
                batch = traffic_batch(scene, estimator, radar, t, measured[radar], fresh, 3)
                if radar == 0 and k >= 60:
                    batch = hook(radar, batch.subset(batch.kind == ObservationKind.AIRCRAFT))
                estimator.update(batch)
        results[corrected] = estimator.estimates()
    good, raw = results[True], results[False]
    assert abs(good.s[0, 0] - TRUE_BIAS[0, 0]) < 15.0
    assert abs(good.s[0, 2] - TRUE_BIAS[0, 2]) < math.radians(0.01)
    assert good.n_rejected[0] < 20
    # Once the estimate is sure, the uncorrected reference's residual -C s is caught by
    # the gate: the own-track plots of radar 0 are rejected instead of dragging s to 0.
    assert raw.n_rejected[0] > 0.8 * 100 * 7


def test_coupled_refuses_a_state_too_large() -> None:
    with pytest.raises(CoupledSizeError, match="max_coupled_states"):
        run("coupled", n_aircraft=10, n_scans=1, max_coupled_states=30)


def test_off_returns_reference_values_or_zero() -> None:
    estimator, _ = run("off", n_scans=3, reference_radars={1: (10.0, 0.0, 0.1, 0.0)})
    s, _ = estimator.correction(1)
    assert np.allclose(s, [10.0, 0.0, math.radians(0.1), 0.0])
    assert np.all(estimator.correction(0)[0] == 0.0)


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("method", "kalman", "method: 'kalman' is not one of"),
        ("estimate_time", "maybe", "estimate_time"),
        ("prior_sigma_range_m", -1.0, "prior_sigma_range_m"),
        ("walk_sigma_gain", float("nan"), "walk_sigma_gain"),
        ("reference_radars", {0: (1.0, 2.0)}, r"reference_radars\[0\]"),
    ],
)
def test_config_errors_name_the_field(field: str, value: object, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        BiasConfig(**{field: value})  # type: ignore[arg-type]


def test_observation_shapes_are_checked() -> None:
    with pytest.raises(ValueError, match=r"BiasObservations.C: shape"):
        make_observations(
            2,
            [0],
            [0.0],
            np.zeros((1, 2)),
            np.zeros((1, 2, 2)),
            np.zeros((1, 2, 3)),
            np.zeros((1, 2)),
            np.zeros((1, 2, 2)),
        )


def test_bias_sources_are_the_messages_vocabulary() -> None:
    names = {value for key, value in vars(common).items() if key.startswith("FROM_")}
    assert names == set(get_args(BiasSource))
