"""The system tracker on synthetic plots of three rotating radars, each with its own real
``LocalTracker``; and the ML formula on DOMAIN.md section 7's worked example."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tests.test_tracking import State, flight, wandering
from tracker_service.evaluation.metrics import nees_in_window
from tracker_service.fusion import (
    COASTING,
    CONFIRMED,
    ENDED,
    SYSTEM_UPDATE_DTYPE,
    FusionConfig,
    SystemTracker,
    ml_fuse,
)
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig
from tracker_service.tracking.plots import BASE_PLOT_DTYPE, as_plot_arrays

T0 = 1.7e9
DURATION = 300.0
SECTORS = 8
SIGMA_R = 60.0
SIGMA_THETA = np.radians(0.08)


@dataclass(frozen=True)
class Radar:
    site: tuple[float, float]
    period: float
    phase: float
    blind: dict[int, float] = field(default_factory=dict)
    """Aircraft index -> time (s) from which this radar no longer sees it."""


@dataclass(frozen=True)
class Aircraft:
    truth: State
    address: int
    mode3a: int


AIRCRAFT = [
    Aircraft(flight(20e3, 90e3, 100.0, 220.0, []), 0xA00001, 0o1001),
    Aircraft(flight(100e3, 20e3, 0.0, 200.0, [(60, 0), (30, 3), (60, 0), (30, -3)]), 0xA2, 0o1002),
    # Crossing at (64.5 km, 60 km) at t = 150 s, 45 degrees apart, same level.
    Aircraft(flight(30e3, 60e3, 90.0, 230.0, []), 0xA00003, 0o1003),
    Aircraft(flight(40.1e3, 35.6e3, 45.0, 230.0, []), 0xA00004, 0o1004),
    # Same Mode 3/A, no address, 30 km or more apart.
    Aircraft(flight(110e3, 50e3, 200.0, 210.0, []), -1, 0o4321),
    Aircraft(flight(20e3, 10e3, 80.0, 210.0, []), -1, 0o4321),
]
RADARS = [
    Radar((0.0, 0.0), 4.0, 0.3),
    Radar((120e3, 0.0), 5.0, 1.7),
    Radar((60e3, 110e3), 6.0, 4.1, blind={0: 150.0}),
]
HANDOVER = (2, 0)  # radar 2 loses aircraft 0


def _plot(
    rng: np.random.Generator, site: tuple[float, float], x: float, y: float
) -> tuple[float, float, npt.NDArray[np.float64]]:
    dx, dy = x - site[0], y - site[1]
    rho = np.hypot(dx, dy) + rng.normal(0, SIGMA_R)
    theta = np.arctan2(dx, dy) + rng.normal(0, SIGMA_THETA)
    j = np.array([[np.sin(theta), rho * np.cos(theta)], [np.cos(theta), -rho * np.sin(theta)]])
    r = j @ np.diag([SIGMA_R**2, SIGMA_THETA**2]) @ j.T
    return site[0] + rho * np.sin(theta), site[1] + rho * np.cos(theta), r


@dataclass
class Scenario:
    batches: list[tuple[int, npt.NDArray[Any]]]  # (radar, plots), in time order of ends
    owner: dict[int, int]
    truth_time: dict[int, float]


def build(aircraft: list[Aircraft], radars: list[Radar], seed: int = 3) -> Scenario:
    rng = np.random.default_rng(seed)
    owner: dict[int, int] = {}
    truth_time: dict[int, float] = {}
    batches: list[tuple[float, int, npt.NDArray[Any]]] = []
    for ri, radar in enumerate(radars):
        rows: list[tuple[object, ...]] = []
        for k in range(int(DURATION / radar.period)):
            start = radar.phase + k * radar.period
            for ai, a in enumerate(aircraft):
                t = start
                for _ in range(3):  # the beam meets the moving target: fixed point of time
                    s = a.truth(t)
                    az = np.arctan2(s[0] - radar.site[0], s[1] - radar.site[1]) % (2 * np.pi)
                    t = start + az / (2 * np.pi) * radar.period
                if t >= radar.blind.get(ai, np.inf):
                    continue
                s = a.truth(t)
                x, y, r = _plot(rng, radar.site, s[0], s[1])
                pid = len(owner)
                owner[pid], truth_time[pid] = ai, t
                rows.append((T0 + t, x, y, r, 330.0, True, a.mode3a, True, a.address, 2, pid))
        plots = as_plot_arrays(np.array(rows, dtype=BASE_PLOT_DTYPE)).rows
        plots = plots[np.argsort(plots["time"], kind="stable")]
        sector = np.floor((plots["time"] - T0 - radar.phase) / (radar.period / SECTORS))
        cuts = np.flatnonzero(np.diff(sector)) + 1
        batches += [(float(b["time"].max()), ri, b) for b in np.split(plots, cuts) if b.size]
    batches.sort(key=lambda b: b[0])
    return Scenario([(ri, b) for _, ri, b in batches], owner, truth_time)


@dataclass
class Run:
    rows: npt.NDArray[Any]
    local: list[npt.NDArray[Any]]  # per radar, its local tracker's output


Q_CV = 0.1
"""The synthetic aircraft here wander (up to 0.5 m^2/s^3 of acceleration noise): the
filters get a CV model tuned to that, not the default's, tuned to airliners."""


def run(scenario: Scenario, config: FusionConfig, n_radars: int = 3) -> Run:
    trackers = [
        LocalTracker(TrackerConfig(scan_period_s=r.period, q_cv=Q_CV)) for r in RADARS[:n_radars]
    ]
    config = dataclasses.replace(
        config, plot_filter=dataclasses.replace(config.plot_filter, q_cv=Q_CV)
    )
    fuser = SystemTracker(n_radars, config)
    rows, local = [], [[] for _ in trackers]
    for ri, plots in scenario.batches:
        if ri >= n_radars:
            continue
        updates = trackers[ri].process(plots)
        local[ri].append(updates)
        rows.append(fuser.process(ri, updates, plots))
    return Run(np.concatenate(rows), [np.concatenate(u) for u in local])


@pytest.fixture(scope="module")
def scenario() -> Scenario:
    return build(AIRCRAFT, RADARS)


@pytest.fixture(scope="module")
def runs(scenario: Scenario) -> dict[str, Run]:
    return {m: run(scenario, FusionConfig(method=m)) for m in ("tracks", "plots")}


def _errors(
    scenario: Scenario,
    rows: npt.NDArray[Any],
    aircraft: list[Aircraft] = AIRCRAFT,
    after_s: float = 40.0,
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[Any]]:
    """Position error (k, 2) and 2-dof position NEES of the rows with a plot after
    ``after_s``, at the rows' times against the truth of their plot's aircraft."""
    rows = rows[rows["plot_id"] >= 0]
    rows = rows[[scenario.truth_time[int(p)] > after_s for p in rows["plot_id"]]]
    truth = np.array(
        [
            aircraft[scenario.owner[int(p)]].truth(t - T0)
            for p, t in zip(rows["plot_id"], rows["time"], strict=True)
        ]
    )
    err = np.column_stack([rows["x"], rows["y"]]) - truth[:, :2]
    p = rows["P"].reshape(-1, 4, 4)[:, :2, :2]
    nees = np.einsum("ka,kab,kb->k", err, np.linalg.inv(p), err)
    return err, nees, rows


def _owners(scenario: Scenario, rows: npt.NDArray[Any]) -> dict[int, set[int]]:
    """System number -> aircraft of the plots in its rows."""
    found: dict[int, set[int]] = {}
    for number, pid in zip(rows["system_number"], rows["plot_id"], strict=True):
        if pid >= 0:
            found.setdefault(int(number), set()).add(scenario.owner[int(pid)])
    return found


def _rms(err: npt.NDArray[np.float64]) -> float:
    return float(np.sqrt(np.mean(np.sum(err**2, axis=1))))


# ----------------------------------------------------------------------------- ml_fuse


def _polar(
    site: tuple[float, float], r: float, theta: float, sigma: tuple[float, float]
) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """DOMAIN.md section 7: the measurement, and its covariance converted at the true
    point (4000, 2000) with the cross-range term r tan(sigma_theta)."""
    z = np.array(site) + r * np.array([np.sin(theta), np.cos(theta)])
    d = np.array([4000.0, 2000.0]) - np.array(site)
    rt, tt = np.hypot(*d), np.arctan2(d[0], d[1])
    u, w = np.array([np.sin(tt), np.cos(tt)]), np.array([np.cos(tt), -np.sin(tt)])
    cov = sigma[0] ** 2 * np.outer(u, u) + (rt * np.tan(sigma[1])) ** 2 * np.outer(w, w)
    return z, cov


def test_ml_fuse_reproduces_the_worked_example() -> None:
    z1, p1 = _polar((0.0, 0.0), 4461.9, 1.413, (300.0, 0.3))
    z2, p2 = _polar((6000.0, 1000.0), 1971.9, 5.455, (150.0, 0.4))
    x, p = ml_fuse(np.array([[z1, z2]]), np.array([[p1, p2]]))
    np.testing.assert_allclose(x[0], [4116.2, 1484.2], rtol=1e-3)
    np.testing.assert_allclose(p[0], [[32288.1, 34030.8], [34030.8, 116355.6]], rtol=1e-3)


def test_ml_fuse_correlation_is_honest() -> None:
    """Two estimates with a known error correlation: the fused covariance matches the
    scatter of the fused errors, and fully correlated equal estimates gain nothing."""
    rng = np.random.default_rng(0)
    p = np.array([[[400.0, 50.0], [50.0, 100.0]], [[200.0, -30.0], [-30.0, 300.0]]])
    rho = 0.6
    root = np.linalg.cholesky(p)
    common = rng.standard_normal((20000, 2))
    own = rng.standard_normal((20000, 2, 2))
    e = np.einsum("nab,kb->kna", root, np.sqrt(rho) * common[:, None, :].repeat(2, 1)[:, 0])
    e = e + np.einsum("nab,knb->kna", root, np.sqrt(1 - rho) * own)
    # Cholesky factors give cross-covariance rho L1 L2^T; ml_fuse approximates it with
    # symmetric roots, so compare with the formula's own cross term through `noise`.
    k = e.shape[0]
    states = e
    covs = np.broadcast_to((1 - rho) * p, (k, 2, 2, 2))
    noise = np.zeros((k, 2, 2, 2, 2))
    for i in range(2):
        for j in range(2):
            noise[:, i, j] = rho * root[i] @ root[j].T
    x, pf = ml_fuse(states, covs, 0.0, noise)
    scatter = np.cov(x.T)
    np.testing.assert_allclose(scatter, pf[0], rtol=0.05)
    same = np.broadcast_to(p[0], (1, 2, 2, 2))
    _, p_same = ml_fuse(np.zeros((1, 2, 2)), same, 0.999)
    np.testing.assert_allclose(p_same[0], p[0], rtol=2e-3)


# ----------------------------------------------------------------- the synthetic scenario


@pytest.mark.parametrize("method", ["tracks", "plots"])
def test_one_system_track_per_aircraft(
    scenario: Scenario, runs: dict[str, Run], method: str
) -> None:
    rows = runs[method].rows
    owners = _owners(scenario, rows)
    assert all(len(a) == 1 for a in owners.values()), owners  # no swap, no merge
    per_aircraft: dict[int, set[int]] = {}
    for number, aircraft in owners.items():
        per_aircraft.setdefault(aircraft.pop(), set()).add(number)
    assert {a: len(n) for a, n in per_aircraft.items()} == dict.fromkeys(range(len(AIRCRAFT)), 1)
    for ai, a in enumerate(AIRCRAFT):
        (number,) = per_aircraft[ai]
        mine = rows[rows["system_number"] == number]
        if a.address >= 0:
            assert set(mine["address"][mine["address"] >= 0]) == {a.address}
        assert mine["status"][-1] == ENDED or mine["time"][-1] > T0 + DURATION - 20
        assert np.count_nonzero(mine["status"] == ENDED) <= 1


def test_every_radar_feeds_and_rows_list_their_sources(runs: dict[str, Run]) -> None:
    rows = runs["tracks"].rows
    live = rows[rows["status"] != ENDED]
    assert set(np.unique(live["local_radars"][live["local_radars"] >= 0])) == {0, 1, 2}
    assert (live["n_sources"] == (live["local_radars"] >= 0).sum(axis=1)).all()
    assert np.count_nonzero(live["n_sources"] == 3) > 0.5 * len(live)
    assert set(np.unique(live["status"])) <= {CONFIRMED, COASTING}
    assert (live["fresh"] == (live["status"] == CONFIRMED)).all()
    assert (live["plot_id"][live["fresh"]] >= 0).all()
    assert np.isfinite(live["flight_level"]).all()
    assert rows.dtype == SYSTEM_UPDATE_DTYPE


@pytest.mark.parametrize("method", ["tracks", "plots"])
def test_fused_tracks_beat_the_best_local_track(
    scenario: Scenario, runs: dict[str, Run], method: str
) -> None:
    err, _, _ = _errors(scenario, runs[method].rows)
    local = [_rms(_errors(scenario, u)[0]) for u in runs[method].local]
    assert _rms(err) < 0.8 * min(local)


WANDERING = [
    Aircraft(wandering(40e3 + 15e3 * i, 30e3 + 10e3 * i, 30.0 * i, 220.0, 0.5, i), 0xB0 + i, -1)
    for i in range(4)
]
"""Aircraft whose white acceleration (the CV model's own noise) every local track shares."""


@pytest.fixture(scope="module")
def wander() -> Scenario:
    return build(WANDERING, [Radar(r.site, r.period, r.phase) for r in RADARS])


@pytest.mark.xfail(
    strict=True,
    reason="issue 14's NEES window 0.8-1.25 x dof: the default method measures 1.51 for dof 2 "
    "here (under-confident, as on three_sites); docs/fusion.md 'Evaluation'",
)
def test_default_method_is_consistent(
    scenario: Scenario, runs: dict[str, Run], wander: Scenario
) -> None:
    _, nees, _ = _errors(scenario, runs[FusionConfig().method].rows)
    assert nees_in_window(float(nees.mean()), 2)
    _, nees, _ = _errors(wander, run(wander, FusionConfig()).rows, WANDERING)
    assert nees_in_window(float(nees.mean()), 2)


def test_correlation_makes_track_fusion_honest(wander: Scenario) -> None:
    """Local tracks sharing the manoeuvres: fused as if independent, the covariance is
    too small; the cross-covariance brings the NEES back towards its 2 dof."""
    naive = _errors(wander, run(wander, FusionConfig("tracks", correlation=0.0)).rows, WANDERING)
    fair = _errors(wander, run(wander, FusionConfig("tracks")).rows, WANDERING)
    assert naive[1].mean() > 3.0
    assert 1.4 <= fair[1].mean() <= 2.8


def test_handover_keeps_the_number_without_a_jump(scenario: Scenario, runs: dict[str, Run]) -> None:
    radar, aircraft = HANDOVER
    blind_from = T0 + RADARS[radar].blind[aircraft]
    for method in ("tracks", "plots"):
        _, nees, rows = _errors(scenario, runs[method].rows)
        mine = np.array([scenario.owner[int(p)] == aircraft for p in rows["plot_id"]])
        assert len(np.unique(rows["system_number"][mine])) == 1
        after = mine & (rows["time"] > blind_from) & (rows["time"] < blind_from + 60)
        assert after.sum() > 10
        assert nees[after].max() < 25.0, method  # 5 sigma
        sources = rows["local_radars"][mine & (rows["time"] > blind_from + 40)]
        assert not (sources == radar).any()


def test_same_code_far_apart_and_lone_radar() -> None:
    """The two aircraft with one Mode 3/A code stay apart even with one radar, and a
    single radar's tracks are system tracks."""
    scen = build(AIRCRAFT[4:], RADARS[:1])
    rows = run(scen, FusionConfig(), n_radars=1).rows
    owners = _owners(scen, rows)
    assert sorted(a.pop() for a in owners.values()) == [0, 1]
    assert (rows["n_sources"][rows["status"] != ENDED] == 1).all()


# ------------------------------------------------------------------------- references


def _replay_until(
    scen: Scenario, stop: int, n_radars: int = 3, shift: float = 0.0
) -> tuple[SystemTracker, list[LocalTracker], list[npt.NDArray[Any]]]:
    """The batches before ``stop`` through local trackers and the fuser, radar 0's plots
    moved east by ``shift``; returns them and the radar-0 plots of batch ``stop``."""
    trackers = [LocalTracker(TrackerConfig(scan_period_s=r.period)) for r in RADARS[:n_radars]]
    fuser = SystemTracker(n_radars)
    moved: list[npt.NDArray[Any]] = []
    for i, (ri, plots) in enumerate(scen.batches[: stop + 1]):
        if ri == 0:
            plots = plots.copy()
            plots["x"] += shift
            moved.append(plots)
        if ri < n_radars and i < stop:
            fuser.process(ri, trackers[ri].process(plots), plots)
    return fuser, trackers, moved


def test_references_others_ignore_this_radar(scenario: Scenario) -> None:
    """Radar 0 moved by 150 m all along: the others' prediction does not move, the
    prediction from all contributors does."""
    stop = next(
        i for i, (ri, b) in enumerate(scenario.batches) if ri == 0 and b["time"][0] > T0 + 120
    )
    refs = []
    for shift in (0.0, 150.0):
        fuser, trackers, moved = _replay_until(scenario, stop, shift=shift)
        updates = trackers[0].process(moved[-1])
        refs.append(fuser.references(0, updates, moved[-1]))
    a, b = refs
    assert len(a.plot_id) > 0 and a.others_valid.all()
    np.testing.assert_array_equal(a.plot_id, b.plot_id)
    np.testing.assert_array_equal(a.system_number, b.system_number)
    np.testing.assert_allclose(a.others_xy, b.others_xy)
    np.testing.assert_allclose(a.others_P, b.others_P)
    np.testing.assert_allclose(a.others_v, b.others_v)
    assert (b.all_xy[:, 0] - a.all_xy[:, 0] > 10.0).all()
    assert a.radars_seen.all()
    truth = np.array(
        [
            AIRCRAFT[scenario.owner[int(p)]].truth(t - T0)
            for p, t in zip(a.plot_id, a.time, strict=True)
        ]
    )
    for xy, cov in ((a.others_xy, a.others_P), (a.all_xy, a.all_P)):
        err = xy - truth[:, :2]
        assert (np.einsum("ka,kab,kb->k", err, np.linalg.inv(cov), err) < 20.0).all()


def test_references_invalid_with_one_radar(scenario: Scenario) -> None:
    stop = next(
        i for i, (ri, b) in enumerate(scenario.batches) if ri == 0 and b["time"][0] > T0 + 60
    )
    fuser, trackers, moved = _replay_until(scenario, stop, n_radars=1)
    refs = fuser.references(0, trackers[0].process(moved[-1]), moved[-1])
    assert len(refs.plot_id) > 0
    assert not refs.others_valid.any()
    assert np.isfinite(refs.all_xy).all()
    assert (refs.radars_seen == [[True]]).all()


def test_config_errors_name_the_field() -> None:
    with pytest.raises(ValueError, match="method"):
        FusionConfig(method="votes")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="correlation"):
        FusionConfig(correlation=1.0)
    with pytest.raises(ValueError, match="max_silence_s"):
        FusionConfig(max_silence_s=-1.0)
    with pytest.raises(ValueError, match="radar"):
        SystemTracker(2).process(
            2, np.zeros(0, dtype=LocalTracker().output_dtype), np.zeros(0, dtype=PLOT_DTYPE)
        )


def test_old_and_repeated_batches_do_not_crash(scenario: Scenario) -> None:
    """A batch replayed late (older than the system tracks) and plots it cannot find are
    counted or absorbed, never fatal; the numbers stay the same."""
    trackers = [LocalTracker(TrackerConfig(scan_period_s=r.period)) for r in RADARS]
    fuser = SystemTracker(3)
    kept: list[tuple[int, npt.NDArray[Any], npt.NDArray[Any]]] = []
    for ri, plots in scenario.batches[:400]:
        updates = trackers[ri].process(plots)
        fuser.process(ri, updates, plots)
        kept.append((ri, updates, plots))
    numbers = set(fuser.system_tracks.tolist())
    for ri, updates, plots in kept[-60:-30]:
        fuser.process(ri, updates, plots[:0])  # older than the tracks, plots not found
    assert set(fuser.system_tracks.tolist()) == numbers
    assert fuser.stats.unknown_plot_ids > 0
