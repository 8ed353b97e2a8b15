"""The vertical IMM (``tracking.vertical``): compiled step against the numpy reference to
1e-9 with downlinked rates and selected levels, climb rate and level-off on quantised
levels, garbled Mode C, and what a downlinked rate and a selected altitude change."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
import pytest

from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig, kernels, vertical

FloatArray = npt.NDArray[np.float64]
CONFIG = TrackerConfig()
T0 = 1.7e9


def _measurements(
    t: FloatArray, z: FloatArray, rate_fpm: FloatArray, selected_fl: FloatArray
) -> vertical.VerticalMeasurements:
    rate, rate_variance = vertical.rate_measurements(None, rate_fpm, CONFIG, t.size)
    return vertical.VerticalMeasurements(
        t, z, np.full(t.size, 0.25**2 / 12.0), rate, rate_variance, selected_fl
    )


def _compiled_step(
    state: vertical.VerticalState,
    t_fl: FloatArray,
    ok: npt.NDArray[np.bool_],
    m: vertical.VerticalMeasurements,
) -> tuple[vertical.VerticalState, FloatArray, FloatArray, FloatArray]:
    k = t_fl.size
    x, p, mu = state.x.copy(), state.P.copy(), state.mu.copy()
    fl, rate, pv = np.zeros(k), np.zeros(k), np.zeros((k, 2, 2))
    t_state, fl_ok, rejects = t_fl.copy(), ok.copy(), np.zeros(k, dtype=np.int64)
    kernels.vertical_update(
        np.arange(k), m.time, m.level, m.level_variance, m.rate, m.rate_variance,
        m.selected_level, x, p, mu, fl, rate, pv, t_state, fl_ok, rejects,
        np.array(CONFIG.vertical_q), np.array(CONFIG.vertical_sojourn_s),
        np.array(CONFIG.vertical_initial_probabilities), 1e9, CONFIG.fl_max_rejects,
        CONFIG.initial_climb_variance, CONFIG.level_rate_variance,
    )  # fmt: skip
    return vertical.VerticalState(x, p, mu), fl, rate, pv


def test_the_compiled_step_is_the_reference() -> None:
    rng = np.random.default_rng(7)
    k = 400
    level = rng.uniform(50.0, 400.0, k)
    climb = rng.choice([0.0, 0.3, -0.4], k) * rng.random(k)
    x = np.empty((k, 3, 2))
    x[:, :, 0] = level[:, None] + rng.normal(0.0, 0.3, (k, 3))
    x[:, :, 1] = climb[:, None] + rng.normal(0.0, 0.05, (k, 3))
    x[:, 0, 1] = 0.0
    a = rng.normal(0.0, 0.3, (k, 3, 2, 2))
    p = a @ np.swapaxes(a, -1, -2) + 0.01 * np.eye(2)
    mu = rng.dirichlet(np.ones(3), k)
    dt = rng.uniform(-1.0, 12.0, k)
    t_fl = T0 + rng.uniform(0.0, 100.0, k)
    t = t_fl + dt
    dt = t - t_fl  # what the kernel takes, to the last bit
    z = np.round((level + climb * dt + rng.normal(0.0, 0.2, k)) * 4.0) / 4.0
    rate_fpm = np.where(rng.random(k) < 0.5, climb * 6000.0 + rng.normal(0, 80, k), np.nan)
    selected = np.where(rng.random(k) < 0.5, level + climb * rng.uniform(0.0, 15.0, k), np.nan)
    m = _measurements(t, z, rate_fpm, selected)
    state = vertical.VerticalState(x, p, mu)
    pred = vertical.predict(state, dt, selected, CONFIG)
    expected, xc, pc = vertical.update(pred, m)
    ok = np.ones(k, dtype=bool)
    got, fl, rate, pv = _compiled_step(state, t_fl, ok, m)
    scale = 1e-9 * max(float(np.abs(expected.x).max()), 1.0)
    np.testing.assert_allclose(got.x, expected.x, rtol=1e-9, atol=scale)
    np.testing.assert_allclose(got.P, expected.P, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got.mu, expected.mu, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.column_stack([fl, rate]), xc, rtol=1e-9, atol=scale)
    np.testing.assert_allclose(pv, pc, rtol=1e-9, atol=1e-9)
    # The selected level bounded some climbs, and the rates moved some probabilities.
    assert (pred.x[:, vertical.STEADY, 0] == selected).sum() > 20
    assert np.isfinite(rate_fpm).sum() > 150
    # A first level starts the filter at it, with the downlinked rate where there is one.
    fresh = vertical.start(m, CONFIG)
    got, fl, rate, _ = _compiled_step(state, t_fl, np.zeros(k, dtype=bool), m)
    np.testing.assert_allclose(got.x, fresh.x, rtol=0, atol=0)
    np.testing.assert_allclose(got.P, fresh.P, rtol=0, atol=0)


def _climb_and_level_off(rate_fl_s: float, period: float, mode_c: bool) -> tuple[FloatArray, ...]:
    """A track level for 60 s at FL200, climbing at rate_fl_s for 150 s, then level: its
    rows at each plot (times from the climb start) and the truth climb rate."""
    tracker = LocalTracker(TrackerConfig(scan_period_s=period))
    rng = np.random.default_rng(3)
    times, rates, truth = [], [], []
    for scan in range(int(400 / period)):
        t = scan * period + rng.uniform(0.0, 0.1)
        climbing = 60.0 <= t < 210.0
        level = 200.0 + rate_fl_s * np.clip(t - 60.0, 0.0, 150.0)
        plot = np.zeros(1, dtype=PLOT_DTYPE)
        plot["time"] = T0 + t
        plot["x"] = 200.0 * t + rng.normal(0.0, 50.0)
        plot["y"] = rng.normal(0.0, 50.0)
        plot["R"] = np.eye(2) * 2500.0
        plot["flight_level"] = np.round(level) if mode_c else np.round(level * 4.0) / 4.0
        plot["fl_valid"] = True
        plot["mode3a"] = 0o1234
        plot["mode3a_valid"] = True
        plot["address"] = -1 if mode_c else 0x3C660C
        plot["typ"] = 2 if mode_c else 5
        plot["plot_id"] = scan
        rows = tracker.process(plot)
        if len(rows) and np.isfinite(rows["climb_rate_fl_per_s"][0]):
            times.append(t - 60.0)
            rates.append(float(rows["climb_rate_fl_per_s"][0]))
            truth.append(rate_fl_s if climbing else 0.0)
    return np.array(times), np.array(rates) * 6000.0, np.array(truth) * 6000.0


@pytest.mark.parametrize(("mode_c", "period"), [(False, 5.0), (True, 5.0), (False, 10.0)])
def test_steady_climbs_are_honest_and_level_offs_quick(mode_c: bool, period: float) -> None:
    t, rate, truth = _climb_and_level_off(2000.0 / 6000.0, period, mode_c)
    steady = (t >= 40.0) & (t < 150.0)
    level = t < 0.0
    print(f"mode C {mode_c}, {period} s: steady error max {np.abs(rate - truth)[steady].max():.0f}")
    assert np.abs(rate - truth)[steady].max() < 300.0
    assert np.abs(rate[level & (t > -40.0)]).max() < 150.0
    # Levelled off at 150 s: the rate falls below 300 ft/min within two or three scans.
    after = t >= 150.0
    settled = t[after & (np.abs(rate) < 300.0)]
    assert settled.size and settled.min() - 150.0 <= 3.0 * period
    assert np.abs(rate[t >= 150.0 + 4.0 * period]).max() < 300.0


def test_a_garbled_level_is_ignored_and_a_real_jump_restarts() -> None:
    m = _measurements(np.array([T0]), np.array([300.0]), np.array([np.nan]), np.array([np.nan]))
    start = vertical.start(m, CONFIG)
    x, p, mu = start.x.copy(), start.P.copy(), start.mu.copy()
    fl, rate, pv = np.array([300.0]), np.zeros(1), np.zeros((1, 2, 2))
    t_fl, ok, rejects = np.array([T0]), np.ones(1, dtype=bool), np.zeros(1, dtype=np.int64)

    def step(t: float, level: float) -> None:
        g = _measurements(np.array([t]), np.array([level]), np.array([np.nan]), np.array([np.nan]))
        kernels.vertical_update(
            np.array([0]), g.time, g.level, g.level_variance, g.rate, g.rate_variance,
            g.selected_level, x, p, mu, fl, rate, pv, t_fl, ok, rejects,
            np.array(CONFIG.vertical_q), np.array(CONFIG.vertical_sojourn_s),
            np.array(CONFIG.vertical_initial_probabilities), CONFIG.fl_gate,
            CONFIG.fl_max_rejects, CONFIG.initial_climb_variance, CONFIG.level_rate_variance,
        )  # fmt: skip

    step(T0 + 5.0, 370.0)  # garbled: ignored, the state stays at its time
    assert fl[0] == 300.0 and rejects[0] == 1 and t_fl[0] == T0
    step(T0 + 10.0, 300.25)
    assert fl[0] == pytest.approx(300.1, abs=0.2) and rejects[0] == 0
    step(T0 + 15.0, 370.0)
    step(T0 + 20.0, 370.0)  # twice in a row: a real jump, the filter restarts there
    assert fl[0] == 370.0 and rejects[0] == 0 and t_fl[0] == T0 + 20.0


def test_a_downlinked_rate_announces_the_climb_before_the_levels() -> None:
    # Level at FL300, then the first plot of a 1,500 ft/min climb: the level has not moved
    # out of its 25 ft step yet, but BDS 6,0 says the rate.
    m = _measurements(np.array([T0]), np.array([300.0]), np.array([np.nan]), np.array([np.nan]))
    state = vertical.start(m, CONFIG)
    for k in range(1, 6):  # a minute level: the level model takes the probability
        step = _measurements(
            np.array([T0 + 10.0 * k]), np.array([300.0]), np.array([0.0]), np.array([np.nan])
        )
        pred = vertical.predict(state, np.array([10.0]), step.selected_level, CONFIG)
        state, _, _ = vertical.update(pred, step)
    assert state.mu[0, vertical.LEVEL] > 0.9
    for rate_fpm, expect_level in ((np.nan, True), (1500.0, False)):
        step = _measurements(
            np.array([T0 + 60.0]), np.array([300.0]), np.array([rate_fpm]), np.array([np.nan])
        )
        pred = vertical.predict(state, np.array([10.0]), step.selected_level, CONFIG)
        after, xc, _ = vertical.update(pred, step)
        assert (after.mu[0, vertical.LEVEL] > 0.5) == expect_level
        if not expect_level:
            assert xc[0, 1] * 6000.0 > 1000.0


def test_the_selected_altitude_stops_the_climb_at_it() -> None:
    m = _measurements(np.array([T0]), np.array([295.0]), np.array([2000.0]), np.array([np.nan]))
    state = vertical.start(m, CONFIG)
    free = vertical.predict(state, np.array([30.0]), np.array([np.nan]), CONFIG)
    assert free.x[0, vertical.STEADY, 0] > 301.0  # through FL300 (mixed with the level model)
    bound = vertical.predict(state, np.array([30.0]), np.array([300.0]), CONFIG)
    assert bound.x[0, vertical.STEADY, 0] == 300.0
    assert bound.x[0, vertical.STEADY, 1] == 0.0  # captured: level at the selected altitude
    # Below the selected level the climb goes on.
    on = vertical.predict(state, np.array([30.0]), np.array([320.0]), CONFIG)
    np.testing.assert_array_equal(on.x, free.x)


def test_vertical_metrics_score_steady_climbs_and_level_offs() -> None:
    from tracker_service.evaluation.metrics import PlotOrigins, Truth
    from tracker_service.evaluation.vertical_metrics import vertical_metrics
    from tracker_service.tracking.tracker import track_update_dtype

    times = np.arange(0.0, 301.0)
    fl = 200.0 + (2000.0 / 6000.0) * np.clip(times - 60.0, 0.0, 120.0)  # FL200 -> FL240
    zeros = np.zeros((times.size, 1))
    truth = Truth(times, zeros, zeros, zeros + 200.0, zeros, fl[:, None])
    t = np.arange(2.0, 300.0, 5.0)
    # A track whose rate lags the truth by 10 s and reads 100 ft/min high in the climb.
    lagged = np.interp(t - 10.0, times[:-1], np.diff(fl) * 6000.0)
    updates = np.zeros(t.size, dtype=track_update_dtype(5))
    updates["time"], updates["status"], updates["plot_id"] = t, 1, np.arange(t.size)
    updates["climb_rate_fl_per_s"] = (lagged + np.where(lagged > 0, 100.0, 0.0)) / 6000.0
    plots = np.zeros(t.size, dtype=[("plot_id", "i8"), ("kind", "i1"), ("aircraft", "i8")])
    plots["plot_id"] = np.arange(t.size)
    m = vertical_metrics(updates, PlotOrigins.from_plots(plots), truth)
    assert m["climb_rate_rms_fpm_steady"] == pytest.approx(100.0)
    assert m["steady_updates"] == 17  # 90 s to 175 s: 30 s after the onset, 5 s before the end
    assert m["level_offs"] == 1
    assert m["level_off_delay_mean_s"] == pytest.approx(12.0)  # the first update at t >= 190
