"""Mode S DAPs in the tracker (tracking.daps): the plane velocity of BDS 5,0, the
plausibility checks, the velocity update and the turn-rate evidence."""

from __future__ import annotations

import numpy as np
import pytest
from pyproj import Geod

from asterix.plots import PLOT_DTYPE as RAW_DTYPE
from tracker_service.geodesy import SystemPlane
from tracker_service.tracking import LocalTracker, TrackerConfig, imm
from tracker_service.tracking.config import KNOT_M_S
from tracker_service.tracking.daps import (
    G0,
    DapUpdate,
    plot_daps,
    turn_evidence,
    velocity_update,
)
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import DAP_TURN_RATE, DAP_VELOCITY, PlotArrays, empty_plots


def raw_rows(n: int, **columns: float) -> np.ndarray:
    rows = np.zeros(n, dtype=RAW_DTYPE)
    for name in RAW_DTYPE.names or ():
        if RAW_DTYPE[name] == np.float64:
            rows[name] = np.nan
    for name, value in columns.items():
        rows[name] = value
    return rows


def test_velocity_is_turned_by_the_grid_convergence() -> None:
    """Far east of the plane's centre grid north is not true north (convergence about
    dlon sin(lat)): the plane velocity must point where the track goes in the plane."""
    plane = SystemPlane(48.0, 16.0)
    lat, lon, h = 49.0, 21.0, 10000.0
    track = 30.0
    raw = raw_rows(1, true_track_deg=track, ground_speed_kt=400.0, true_airspeed_kt=400.0)
    out, bad = plot_daps(raw, plane, np.array([lat]), np.array([lon]), np.array([h]))
    assert not bad.any() and out["dap_flags"][0] == DAP_VELOCITY
    lon2, lat2, _ = Geod(ellps="WGS84").fwd(lon, lat, track, 1000.0)
    x0, y0 = plane.from_geodetic(lat, lon)
    x1, y1 = plane.from_geodetic(lat2, lon2)
    grid = np.degrees(np.arctan2(float(x1 - x0), float(y1 - y0)))
    plane_track = np.degrees(np.arctan2(out["dap_vx"][0], out["dap_vy"][0]))
    assert abs(grid - track) > 3.0  # the convergence is large here
    assert plane_track == pytest.approx(grid, abs=0.01)
    speed = np.hypot(out["dap_vx"][0], out["dap_vy"][0])
    assert speed == pytest.approx(400.0 * KNOT_M_S, rel=3e-3)  # scale factor and height


def test_implausible_daps_are_dropped_and_flagged() -> None:
    raw = raw_rows(
        4,
        true_track_deg=90.0,
        ground_speed_kt=300.0,
        true_airspeed_kt=300.0,
        roll_deg=0.0,
        track_angle_rate_deg_s=0.0,
    )
    raw["roll_deg"][1] = 75.0  # beyond any airliner's bank
    raw["true_airspeed_kt"][2] = 600.0  # 300 kt of "wind"
    raw["track_angle_rate_deg_s"][3] = 2.5  # a turn with the wings level
    plane = SystemPlane(48.0, 16.0)
    ll = np.full(4, 48.0), np.full(4, 16.0), np.zeros(4)
    out, bad = plot_daps(raw, plane, *ll)
    assert bad.tolist() == [False, True, True, True]
    assert np.isnan(out["roll_deg"][1]) and np.isfinite(out["dap_vx"][1])
    assert np.isnan(out["dap_vx"][2])  # the ground speed is not trusted
    assert np.isnan(out["dap_turn_rate_rad_s"][3])
    both = DAP_VELOCITY | DAP_TURN_RATE
    # The roll alone is dropped (the track angle rate stays), the wind leaves the turn
    # rate (not the velocity), the disagreement the velocity (not the turn rate).
    assert out["dap_flags"].tolist() == [both, both, DAP_TURN_RATE, DAP_VELOCITY]


def test_roll_gives_the_coordinated_turn_rate_in_the_plane_sense() -> None:
    raw = raw_rows(
        1, true_track_deg=0.0, ground_speed_kt=400.0, true_airspeed_kt=400.0, roll_deg=25.0
    )
    out, _ = plot_daps(
        raw, SystemPlane(48.0, 16.0), np.array([48.0]), np.array([16.0]), np.zeros(1)
    )
    # Right wing down: a right (clockwise) turn, negative in the plane.
    assert out["dap_turn_rate_rad_s"][0] == pytest.approx(
        -9.80665 * np.tan(np.radians(25.0)) / (400.0 * KNOT_M_S)
    )


def test_velocity_update_is_the_kalman_update_of_each_model() -> None:
    rng = np.random.default_rng(3)
    k, m = 3, 2
    x = rng.normal(0, 50, (k, m, 4))
    a = rng.normal(0, 1, (k, m, 4, 4))
    P = a @ np.swapaxes(a, -1, -2) + 4 * np.eye(4)
    mu = np.array([[0.7, 0.3]] * k)
    z = rng.normal(0, 50, (k, 2))
    R = np.array([[[2.0, 0.3], [0.3, 1.0]]] * k)
    x_new, p_new, mu_new = velocity_update(x, P, mu, z, R)
    H = np.hstack([np.zeros((2, 2)), np.eye(2)])
    lik = np.zeros((k, m))
    for i in range(k):
        for j in range(m):
            S = H @ P[i, j] @ H.T + R[i]
            K = P[i, j] @ H.T @ np.linalg.inv(S)
            y = z[i] - H @ x[i, j]
            assert np.allclose(x_new[i, j], x[i, j] + K @ y, atol=1e-9)
            assert np.allclose(p_new[i, j], (np.eye(4) - K @ H) @ P[i, j], atol=1e-9)
            lik[i, j] = np.exp(-0.5 * y @ np.linalg.solve(S, y)) / np.sqrt(np.linalg.det(S))
    want = mu * lik
    assert np.allclose(mu_new, want / want.sum(axis=1, keepdims=True), atol=1e-9)


def test_turn_evidence_moves_probability_to_the_reported_turn() -> None:
    rates = np.radians([0.0, 1.5, -1.5, 3.0, -3.0])
    mu = np.array([[0.8, 0.05, 0.05, 0.05, 0.05]])
    out = turn_evidence(mu, np.radians([-3.0]), rates, np.radians(0.5))
    assert out[0].argmax() == 4 and out[0, 4] > 0.9
    level = turn_evidence(mu, np.radians([0.0]), rates, np.radians(0.5))
    assert level[0, 0] > mu[0, 0]
    back = turn_evidence(out, np.radians([-3.0]), rates, np.radians(0.5), inverse=True)
    np.testing.assert_allclose(back, mu, rtol=1e-9)


def test_dap_step_gates_a_velocity_far_from_its_track_and_ignores_zero_rows() -> None:
    config = TrackerConfig()
    models = ModelSet.from_config(config)
    step = DapUpdate(config, models)
    m = models.n_models
    x = np.zeros((2, m, 4))
    x[..., 2] = 200.0
    P = np.broadcast_to(np.diag([100.0, 100.0, 25.0, 25.0]), (2, m, 4, 4)).copy()
    mu = np.full((2, m), 1.0 / m)
    xc, pc = imm.combine(x, P, mu)
    update = imm.ImmUpdate(x, P, mu, xc, pc)
    assert step.apply(update, PlotArrays(np.zeros(2, dtype=empty_plots(0).dtype))) is update
    plots = empty_plots(2)
    plots["dap_flags"] = DAP_VELOCITY
    plots["dap_vx"] = [201.0, -200.0]  # the second flies the other way
    plots["dap_vy"] = 0.0
    out = step.apply(update, PlotArrays(plots))
    assert step.counts.dap_velocity_updates == 1 and step.counts.dap_velocity_gated_out == 1
    assert np.allclose(out.x[1], x[1])
    assert out.P_comb[0, 2, 2] < 5.0


def test_use_daps_is_validated() -> None:
    with pytest.raises(ValueError, match="use_daps"):
        TrackerConfig(use_daps="yes")  # type: ignore[arg-type]


def _turning_flight_plots(daps: bool) -> np.ndarray:
    """A three_sites case (25/11, aircraft 32 of seed 20261125 without biases): 225 m/s
    straight at 323 deg, BDS 5,0 every third scan of 10 s (roll 0), then a left turn at
    47 deg of roll (2.7 deg/s) starting 5 s before the last straight-flight plot; the
    first plot 10 s later, 1.1 km left of the straight line, reports the turn. The plots
    240 km from the radar (that plot's R), without noise."""
    speed, heading0 = 225.0, np.radians(323.0)
    roll = np.radians(-47.3)  # left wing down
    rate = G0 * np.tan(roll) / speed  # clockwise heading rate (negative: left)
    t_turn = 115.0
    times = np.arange(0.0, 141.0, 10.0)

    def state(t: float) -> tuple[float, float, float]:
        """x, y and heading (clockwise from grid north) at t."""
        if t <= t_turn:
            d = speed * t
            return d * np.sin(heading0), d * np.cos(heading0), heading0
        x0, y0 = speed * t_turn * np.sin(heading0), speed * t_turn * np.cos(heading0)
        h = heading0 + rate * (t - t_turn)
        radius = speed / rate
        return (
            x0 + radius * (np.cos(heading0) - np.cos(h)),
            y0 + radius * (np.sin(h) - np.sin(heading0)),
            h,
        )

    plots = empty_plots(len(times))
    for i, t in enumerate(times):
        x, y, h = state(float(t))
        plots[i]["time"], plots[i]["x"], plots[i]["y"] = t, x, y
        plots[i]["R"] = [[13345.0, -25394.0], [-25394.0, 56681.0]]
        plots[i]["address"] = 0x4CA123
        plots[i]["typ"] = 5  # Mode S roll-call
        plots[i]["flight_level"], plots[i]["fl_valid"] = 350.0, True
        plots[i]["plot_id"] = i
        if daps and i % 3 == 1:
            plots[i]["dap_vx"], plots[i]["dap_vy"] = speed * np.sin(h), speed * np.cos(h)
            plots[i]["dap_turn_rate_rad_s"] = -G0 * np.tan(roll if t > t_turn else 0.0) / speed
            plots[i]["dap_flags"] = DAP_VELOCITY | DAP_TURN_RATE
    return plots


@pytest.mark.parametrize("implementation", ["numpy", "compiled"])
def test_a_plot_reporting_a_sharp_turn_stays_in_its_track(implementation: str) -> None:
    """The cause of DAPs' extra local tracks on three_sites: applied after the position
    update, the reported turn rate came too late for the gate. The straight-flight
    registers had put the turn models near zero and the DAP velocity had pinned the
    velocity, so the first plot of a sharp turn, whose own register reported the turn,
    fell out of the straight prediction's gate (address gate, chi-square 23) and the track
    was lost (here: no track takes that plot). Weighed into the prediction before the
    gate, the reported turn keeps the plot, and the next ones, in their track."""
    tracker = LocalTracker(
        TrackerConfig(use_daps=True, scan_period_s=10.0, implementation=implementation)
    )
    plots = _turning_flight_plots(daps=True)
    out = [tracker.process(plots[i : i + 1]) for i in range(len(plots))]
    numbers = [int(o["track_number"][0]) if len(o) else -1 for o in out]
    assert numbers[-4] > 0 and numbers[-3:] == [numbers[-4]] * 3
    assert tracker.stats.dap_turn_evidence > 0 and tracker.stats.dap_velocity_updates > 0


def test_turn_prior_opens_the_gate_to_a_reported_turn_and_never_closes_it() -> None:
    """Two pairs of one straight track: a plot 600 m left of the straight prediction whose
    register reports a 3 deg/s left turn, and one on the straight line whose (late)
    register reports the same turn. The weighed test passes the first far more easily;
    the second keeps its plain test; both carry the weighed model probabilities."""
    config = TrackerConfig(use_daps=True)
    models = ModelSet.from_config(config)
    step = DapUpdate(config, models)
    m = models.n_models
    x = np.zeros((2, m, 4))
    x[..., 3] = 200.0  # north at 200 m/s
    P = np.broadcast_to(np.diag([100.0, 100.0, 1.0, 1.0]), (2, m, 4, 4)).copy()
    mu = np.tile(np.array([0.998, 0.0005, 0.0005, 0.0005, 0.0005]), (2, 1))
    pred = imm.NumpyImm(models).predict(x, P, mu, np.array([10.0, 10.0]))
    plots = empty_plots(2)
    straight = pred.x[0, 0, :2]
    left = pred.x[0, 3, :2]  # the +3 deg/s (left) model's prediction
    plots["x"], plots["y"] = np.array([left, straight]).T
    plots["R"] = np.diag([30.0**2, 30.0**2])
    plots["dap_turn_rate_rad_s"] = np.radians(3.0)
    plots["dap_flags"] = DAP_TURN_RATE
    p = PlotArrays(plots)
    z = np.column_stack([p.x, p.y])
    nis, _ = imm.innovation_test(pred, z, p.R)
    weighed, gate_nis = step.turn_prior(pred, nis, p, np.array([0, 1]))
    assert gate_nis[0] < 0.25 * nis[0]
    assert gate_nis[1] == nis[1]
    assert (weighed.c[:, 3] > 0.5).all()
