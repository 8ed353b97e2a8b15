"""The compiled IMM kernels (``tracking.kernels``) against the numpy reference
(``tracking.imm``, the textbook equations) to 1e-9, on random and on tracker-like states,
and the two trackers run side by side on the same plots."""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig
from tracker_service.tracking.imm import ImmFilter, ImmPrediction, make_imm
from tracker_service.tracking.initiate import TwoPointInitiator
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import PlotArrays

FloatArray = npt.NDArray[np.float64]
TOLERANCE = 1e-9


def close(reference: FloatArray, compiled: FloatArray) -> None:
    """Equal to 1e-9 of the reference's scale (entry-wise relative where the entries
    are not tiny)."""
    assert reference.shape == compiled.shape
    if reference.size == 0:
        return
    scale = np.maximum(np.abs(reference), TOLERANCE * max(float(np.abs(reference).max()), 1.0))
    np.testing.assert_array_less(np.abs(compiled - reference) / scale, TOLERANCE)


def close_to_scale(reference: FloatArray, compiled: FloatArray) -> None:
    """Equal to 1e-9 of the reference's scale, entry-wise relative where the entries are
    not small: the vertical filter's exactly-zero rates (a level Mode C, y = 0) come out
    at 1e-15 when the two exp() differ in their last bit."""
    assert reference.shape == compiled.shape
    if reference.size == 0:
        return
    scale = max(float(np.abs(reference).max()), 1.0)
    np.testing.assert_allclose(compiled, reference, rtol=TOLERANCE, atol=TOLERANCE * scale)


def random_tracks(
    seed: int, k: int, models: ModelSet, dt_range: tuple[float, float]
) -> tuple[FloatArray, ...]:
    """Per-model states, SPD covariances, probabilities, steps and plots as a tracker sees
    them (metres, m/s, positions to 300 km, steps of a scan, backwards too)."""
    rng = np.random.default_rng(seed)
    m = models.n_models
    x = np.empty((k, m, 4))
    x[..., :2] = rng.uniform(-3e5, 3e5, (k, 1, 2)) + rng.normal(0, 200, (k, m, 2))
    x[..., 2:] = rng.uniform(-250, 250, (k, 1, 2)) + rng.normal(0, 10, (k, m, 2))
    a = rng.normal(0, 1, (k, m, 4, 4)) * np.array([300.0, 300.0, 20.0, 20.0])[:, None]
    p = a @ np.swapaxes(a, -1, -2) + np.diag([100.0, 100.0, 1.0, 1.0])
    mu = rng.dirichlet(np.full(m, 0.5), k)
    dt = rng.uniform(*dt_range, k)
    z = x[:, 0, :2] + rng.normal(0, 300, (k, 2))
    b = rng.normal(0, 1, (k, 2, 2)) * 200.0
    r = b @ np.swapaxes(b, -1, -2) + np.eye(2) * 400.0
    return x, p, mu, dt, z, r


def models_of(config: TrackerConfig) -> tuple[ModelSet, ImmFilter, ImmFilter]:
    models = ModelSet.from_config(config)
    return models, make_imm("numpy", models), make_imm("compiled", models)


def assert_same_prediction(a: ImmPrediction, b: ImmPrediction) -> None:
    for name in ("x", "P", "c", "x_comb", "P_comb"):
        close(getattr(a, name), getattr(b, name))


CONFIGS = {
    "default": TrackerConfig(),
    "cv only": TrackerConfig(
        turn_rates_deg_s=(), initial_model_probabilities=(1.0,), mean_sojourn_s=(60.0,)
    ),
    "two turns": TrackerConfig(
        turn_rates_deg_s=(2.0, -6.0),
        initial_model_probabilities=(0.6, 0.2, 0.2),
        mean_sojourn_s=(30.0, 10.0, 5.0),
        q_cv=0.1,
        q_ct=2.0,
    ),
}


@pytest.mark.parametrize("name", list(CONFIGS))
@pytest.mark.parametrize("k", [1, 7, 200])
def test_predict_gate_update_match_the_reference(name: str, k: int) -> None:
    models, reference, compiled = models_of(CONFIGS[name])
    x, p, mu, dt, z, r = random_tracks(k, k, models, (-2.0, 12.0))
    expected = reference.predict(x, p, mu, dt)
    got = compiled.predict(x, p, mu, dt)
    assert_same_prediction(expected, got)
    for e, g in zip(
        reference.innovation_test(expected, z, r),
        compiled.innovation_test(expected, z, r),
        strict=True,
    ):
        close(e, g)
    updated, compiled_update = reference.update(expected, z, r), compiled.update(expected, z, r)
    for field in ("x", "P", "mu", "x_comb", "P_comb"):
        close(getattr(updated, field), getattr(compiled_update, field))
    assert np.allclose(compiled_update.mu.sum(axis=1), 1.0)


def test_far_plots_keep_the_probabilities_finite() -> None:
    """A plot far from every model makes every likelihood underflow: both normalise in the
    log domain and agree."""
    models, reference, compiled = models_of(TrackerConfig())
    x, p, mu, dt, z, r = random_tracks(3, 5, models, (4.0, 5.0))
    pred = reference.predict(x, p, mu, dt)
    far = z + 1e6
    expected, got = reference.update(pred, far, r), compiled.update(pred, far, r)
    assert np.isfinite(got.mu).all()
    close(expected.mu, got.mu)
    close(expected.P_comb, got.P_comb)


def test_zero_step_and_exact_cv() -> None:
    """dt = 0 leaves the mixed states where they are; the CV model moves by v dt exactly."""
    models, reference, compiled = models_of(TrackerConfig())
    x, p, mu, _, _, _ = random_tracks(4, 6, models, (0.0, 1.0))
    got = compiled.predict(x, p, mu, np.zeros(6))
    assert_same_prediction(reference.predict(x, p, mu, np.zeros(6)), got)
    one = np.ones((1, 1))
    cv = ModelSet.from_config(CONFIGS["cv only"])
    single = make_imm("compiled", cv).predict(x[:1, :1], p[:1, :1], one, np.array([4.0]))
    np.testing.assert_allclose(single.x[0, 0, :2], x[0, 0, :2] + 4.0 * x[0, 0, 2:], rtol=1e-15)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    seed=st.integers(0, 2**32 - 1),
    k=st.integers(1, 40),
    dt_low=st.floats(-5.0, 30.0),
    span=st.floats(0.0, 60.0),
)
def test_random_batches_match_the_reference(seed: int, k: int, dt_low: float, span: float) -> None:
    models, reference, compiled = models_of(TrackerConfig())
    x, p, mu, dt, z, r = random_tracks(seed, k, models, (dt_low, dt_low + span))
    expected = reference.predict(x, p, mu, dt)
    assert_same_prediction(expected, compiled.predict(x, p, mu, dt))
    e, g = reference.update(expected, z, r), compiled.update(expected, z, r)
    for field in ("x", "P", "mu", "x_comb", "P_comb"):
        close(getattr(e, field), getattr(g, field))


def sector_stream(seed: int, targets: int, scans: int) -> list[npt.NDArray[np.void]]:
    """Straight-flying targets around a radar at the origin, one batch per sector."""
    rng = np.random.default_rng(seed)
    period, sectors = 5.0, 8
    start = rng.uniform(-1.5e5, 1.5e5, (targets, 2))
    speed = rng.uniform(100.0, 250.0, targets)
    heading = rng.uniform(0, 2 * np.pi, targets)
    velocity = speed[:, None] * np.column_stack([np.sin(heading), np.cos(heading)])
    level = rng.uniform(50.0, 400.0, targets)
    climb = np.where(rng.random(targets) < 0.3, rng.uniform(-0.5, 0.5, targets), 0.0)
    mode_s = rng.random(targets) < 0.5
    batches = []
    for scan in range(scans):
        t = scan * period + rng.uniform(0, period, targets)
        pos = start + velocity * t[:, None]
        plots = np.zeros(targets, dtype=PLOT_DTYPE)
        plots["time"] = 1.7e9 + t
        plots["x"] = pos[:, 0] + rng.normal(0, 60.0, targets)
        plots["y"] = pos[:, 1] + rng.normal(0, 60.0, targets)
        plots["R"] = np.eye(2) * 3600.0
        # Mode S levels in 25 ft, Mode C in 100 ft, a few garbled (the filter rejects).
        fl = level + climb * t
        fl = np.where(mode_s, np.round(fl * 4.0) / 4.0, np.round(fl))
        garbled = rng.random(targets) < 0.03
        plots["flight_level"] = np.where(garbled, fl + rng.choice([-70.0, 120.0], targets), fl)
        plots["fl_valid"] = rng.random(targets) < 0.95
        plots["mode3a"] = -1
        plots["address"] = np.where(mode_s, np.arange(targets), -1)
        plots["typ"] = np.where(mode_s, 5, 2)
        plots["plot_id"] = scan * targets + np.arange(targets)
        sector = np.minimum((t - scan * period) / period * sectors, sectors - 1).astype(int)
        for s in range(sectors):
            chosen = plots[sector == s]
            batches.append(chosen[np.argsort(chosen["time"])])
    return batches


def test_trackers_agree_on_a_stream() -> None:
    """The same plots through the compiled and the numpy tracker: the same tracks (numbers,
    statuses, plots), states and levels equal to 1e-9 of their scale."""
    compiled = LocalTracker(TrackerConfig(scan_period_s=5.0))
    reference = LocalTracker(TrackerConfig(scan_period_s=5.0, implementation="numpy"))
    rows = 0
    for batch in sector_stream(11, 40, 12):
        a, b = reference.process(batch), compiled.process(batch)
        for field in ("track_number", "status", "plot_id", "address"):
            np.testing.assert_array_equal(a[field], b[field])
        for field in ("x", "y", "vx", "vy", "P", "model_probabilities"):
            close(a[field], b[field])
        for field in ("flight_level", "climb_rate_fl_per_s"):
            np.testing.assert_array_equal(np.isnan(a[field]), np.isnan(b[field]))
            known = ~np.isnan(a[field])
            close_to_scale(a[field][known], b[field][known])
        rows += len(a)
    assert rows > 300
    tracks, expected = compiled.tracks, reference.tracks
    for field in ("number", "status", "hist", "misses", "address", "mode3a", "fl_rejects"):
        np.testing.assert_array_equal(expected[field], tracks[field])
    for field in ("t", "t_hit", "due", "t_fl"):
        np.testing.assert_array_equal(expected[field], tracks[field])
    for field in ("x", "P", "mu", "xc", "Pc"):
        close(expected[field], tracks[field])
    assert (tracks["status"] == 1).sum() >= 30
    # The stream exercised the vertical filter's restarts and rejections.
    assert tracks["fl_ok"].sum() >= 30
    ok = tracks["fl_ok"]
    for field in ("Pv", "xv", "Pvm", "muv"):
        close_to_scale(expected[field][ok], tracks[field][ok])
    close(expected["fl"][ok], tracks["fl"][ok])


def test_unknown_implementation_is_refused() -> None:
    with pytest.raises(ValueError, match="implementation"):
        TrackerConfig(implementation="fortran")


@pytest.mark.parametrize("targets", [12, 60, 200])
def test_compiled_initiation_pairs_as_the_reference(targets: int) -> None:
    """Two-point initiation from its compiled candidate pairs: the same pairs in the same
    order (the k-d trees' of the reference, with batches and waiting plots of one leaf and
    of many) and the same plots left waiting, with identities that agree, differ and are
    shared codes."""
    config = TrackerConfig(scan_period_s=5.0)
    reference = TwoPointInitiator(dataclasses.replace(config, implementation="numpy"))
    compiled = TwoPointInitiator(config)
    rng = np.random.default_rng(targets)
    started = 0
    for batch in sector_stream(targets, targets, 6):
        batch = batch.copy()
        batch["mode3a"] = rng.choice([-1, 0o1200, 0o4321, 0o4322], len(batch))
        batch["mode3a_valid"] = rng.random(len(batch)) < 0.9
        batch["address"] = np.where(rng.random(len(batch)) < 0.1, 7, batch["address"])
        plots = PlotArrays(batch)
        now = float(batch["time"].max()) if len(batch) else 0.0
        a, b = reference.pair(plots, now), compiled.pair(plots, now)
        for want, got in zip(a, b, strict=True):
            assert want.rows.tobytes() == got.rows.tobytes()
        assert reference.pending.rows.tobytes() == compiled.pending.rows.tobytes()
        started += len(a[0])
    assert started >= targets // 2


@pytest.mark.parametrize("use_daps", [True, False])
def test_compiled_vertical_measurements_as_the_reference(use_daps: bool) -> None:
    """The level's variance, the downlinked rates and the selected level of plots (Mode S
    and Mode C, whole and quarter levels, rates and selected altitudes present, absent and
    unflagged) from the compiled pass and from numpy: the same bits."""
    rng = np.random.default_rng(5)
    n = 200
    rows = np.zeros(n, dtype=PLOT_DTYPE)
    rows["flight_level"] = rng.integers(0, 1600, n) / np.where(rng.random(n) < 0.5, 4.0, 1.0)
    rows["typ"] = rng.choice([1, 2, 5, 6], n)
    rows["dap_flags"] = rng.integers(0, 16, n)
    for name in ("baro_rate_fpm", "inertial_rate_fpm"):
        rows[name] = np.where(rng.random(n) < 0.4, np.nan, rng.uniform(-3000.0, 3000.0, n))
    rows["selected_altitude_ft"] = np.where(rng.random(n) < 0.3, np.nan, 32000.0)
    plots = PlotArrays(rows)
    for mode_s in (rows["typ"] >= 4, np.ones(n, bool)):
        if mode_s.all():
            rows["typ"] = 5
        found = [
            LocalTracker(
                TrackerConfig(use_daps=use_daps, implementation=kind)
            )._vertical_measurements(plots)
            for kind in ("numpy", "compiled")
        ]
        for name in ("level_variance", "rate", "rate_variance", "selected_level"):
            want, got = (getattr(f, name) for f in found)
            assert np.asarray(want).tobytes() == np.asarray(got).tobytes(), name


@pytest.mark.parametrize("association", ["gnn", "jpda", "mht"])
def test_trackers_agree_on_primary_plots_misses_and_clutter(association: str) -> None:
    """Half the replies primary-only, a quarter of the plots missed, and persistent
    primary clutter at a few spots: the branches the Mode S stream above never takes
    (primary-seeded tentative tracks offered plots with a reply, primary plots learnt
    into the clutter map, cells above its floor) give the same tracks and the same map
    through the compiled kernels as through the numpy reference."""
    config = TrackerConfig(scan_period_s=5.0, association=association, clutter_dense_per_scan=0.3)
    compiled = LocalTracker(config)
    reference = LocalTracker(dataclasses.replace(config, implementation="numpy"))
    rng = np.random.default_rng(3)
    rows = 0
    for k, stream_batch in enumerate(sector_stream(11, 60, 25)):
        kept = stream_batch[rng.random(len(stream_batch)) < 0.75]
        primary = rng.random(len(kept)) < 0.5
        kept["typ"][primary] = 1
        kept["address"][primary] = -1
        clutter = np.zeros(6, dtype=PLOT_DTYPE)
        clutter["time"] = kept["time"].max() if len(kept) else 1.7e9 + 5.0 * k / 8
        clutter["x"] = rng.choice([2e4, -3e4, 5e4], 6) + rng.normal(0, 200, 6)
        clutter["y"] = rng.choice([1e4, -2e4], 6) + rng.normal(0, 200, 6)
        clutter["R"] = np.eye(2) * 3600.0
        clutter["typ"] = 1
        clutter["address"] = clutter["mode3a"] = -1
        clutter["flight_level"] = np.nan
        clutter["plot_id"] = 10_000_000 + 10 * k + np.arange(6)
        batch = np.concatenate([kept, clutter])
        batch = batch[np.argsort(batch["time"], kind="stable")]
        a, b = reference.process(batch), compiled.process(batch)
        for field in ("track_number", "status", "plot_id"):
            np.testing.assert_array_equal(a[field], b[field], err_msg=f"batch {k} {field}")
        close(a["x"], b["x"])
        close(a["y"], b["y"])
        # A clutter track's speed is a few mm/s: its last bits, not the filter, differ
        # entry-wise (7.6e-13 m/s of 2.3e-4 once), so to the field's scale.
        for field in ("vx", "vy", "P"):
            close_to_scale(a[field], b[field])
        rows += len(a)
    assert rows > 500
    assert reference.clutter is not None and compiled.clutter is not None
    np.testing.assert_array_equal(reference.clutter.counts, compiled.clutter.counts)
    assert (compiled.clutter.counts > 0).sum() >= 3  # the clutter spots were learnt
