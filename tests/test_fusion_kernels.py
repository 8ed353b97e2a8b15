"""The compiled fusion kernels (``fusion.kernels``) against the numpy reference (``consider``,
``ml``, ``estimator_tracks``) to 1e-9: each kernel through its call site on random system
and local tables (hypothesis-drawn sizes, seeds, radars, steps backwards and forwards), and
two fusers, one of each implementation, side by side on three radars' traffic."""

from __future__ import annotations

import copy
import dataclasses
import itertools
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tests.test_fusion import AIRCRAFT, RADARS, build
from tests.test_tracking_kernels import TOLERANCE, close
from tracker_service.fusion import (
    FusionConfig,
    SystemTracker,
    arrays,
    associate,
    consider,
    estimator_plots,
    lifecycle,
    nearby,
    rows,
)
from tracker_service.fusion.estimator import SystemEstimator
from tracker_service.fusion.estimator_tracks import TrackFusionEstimator, fuse_local_tracks
from tracker_service.fusion.messages import COASTING, ENDED, MAX_SYSTEM_NUMBER
from tracker_service.fusion.references import References, references
from tracker_service.fusion.state import FusionState, PairEvidence
from tracker_service.fusion.table import Columns, LocalTrackTable
from tracker_service.tracking import PLOT_DTYPE, LocalTracker, TrackerConfig
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    DAP_FIELDS,
    DAP_TURN_RATE,
    DAP_VELOCITY,
    PlotArrays,
    as_plot_arrays,
)
from tracker_service.tracking.tracker import CONFIRMED as LOCAL_CONFIRMED
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED
from tracker_service.tracking.tracker import TENTATIVE as LOCAL_TENTATIVE

FloatArray = npt.NDArray[np.float64]


def _spd(rng: np.random.Generator, shape: tuple[int, ...], scale: FloatArray) -> FloatArray:
    d = scale.shape[0]
    a = rng.normal(0.0, 1.0, (*shape, d, d)) * scale[:, None]
    return np.asarray(a @ np.swapaxes(a, -1, -2) + np.diag(scale**2) * 0.01)


def _states(
    seed: int, n_radars: int, k: int, use_daps: bool = False
) -> tuple[FusionState, FusionState, Any]:
    """Two fusion states, compiled and numpy, with the same random system tracks 1..k and
    local tracks 0..k-1 (metres and m/s as the fuser holds them)."""
    rng = np.random.default_rng(seed)
    models = ModelSet.from_config(FusionConfig().plot_filter)
    states = [
        FusionState(FusionConfig(implementation=impl, use_daps=use_daps), n_radars, models)
        for impl in ("compiled", "numpy")
    ]
    m = states[0].models.n_models
    sys = states[0].sys
    n = np.arange(1, k + 1)
    sys["alive"][n] = True
    sys["t"][n] = rng.uniform(0.0, 10.0, k)
    centre = rng.uniform(-3e5, 3e5, (k, 1, 2))
    sys["mx"][n, :, :2] = centre + rng.normal(0, 200, (k, m, 2))
    sys["mx"][n, :, 2:] = rng.uniform(-250, 250, (k, 1, 2)) + rng.normal(0, 10, (k, m, 2))
    sys["mP"][n] = _spd(rng, (k, m), np.array([300.0, 300.0, 20.0, 20.0]))
    sys["mu"][n] = rng.dirichlet(np.full(m, 0.5), k)
    sys["mM"][n] = rng.normal(0.0, 0.5, (k, m, n_radars, 4, 2))
    # A system track holds no sensitivity to the radars none of whose plots updated it,
    # which the kernels skip.
    insensitive = rng.uniform(size=(k, n_radars)) < 0.4
    mm = sys["mM"][n]
    mm[np.broadcast_to(insensitive[:, None, :], (k, m, n_radars))] = 0.0
    sys["mM"][n] = mm
    sys["B"][n] = _spd(rng, (k, n_radars), np.array([60.0, 60.0]))
    local = states[0].local
    rows = local.find(0, _local_updates(rng, k), create=True)
    local.rows["t"][rows] = rng.uniform(-5.0, 15.0, k)
    local.rows["x"][rows] = np.column_stack(
        [rng.uniform(-3e5, 3e5, (k, 2)), rng.uniform(-250, 250, (k, 2))]
    )
    local.rows["P"][rows] = _spd(rng, (k,), np.array([100.0, 100.0, 8.0, 8.0]))
    local.rows["extra"][rows] = _spd(rng, (k,), np.array([40.0, 40.0]))
    states[1].sys.put(slice(None), sys)
    states[1].local = local  # read only by the ML fusion
    return states[0], states[1], rng


def _local_updates(rng: np.random.Generator, k: int) -> npt.NDArray[Any]:
    u = np.zeros(k, dtype=LocalTracker().output_dtype)
    u["track_number"] = np.arange(1, k + 1)
    u["plot_id"] = -1
    return u


def _plots(rng: np.random.Generator, state: FusionState, numbers: Any) -> PlotArrays:
    p = np.zeros(numbers.size, dtype=PLOT_DTYPE)
    sys = state.sys
    p["time"] = sys["t"][numbers] + rng.uniform(-4.0, 12.0, numbers.size)
    p["x"], p["y"] = (sys["x"][numbers, :2] + rng.normal(0, 300, (numbers.size, 2))).T
    p["R"] = _spd(rng, (numbers.size,), np.array([150.0, 150.0]))
    for name in DAP_FIELDS:
        p[name] = np.nan
    # BDS 5,0 on about two plots in three (a few far off: gated out), a turn rate on half.
    v = sys["x"][numbers, 2:] + rng.normal(0, 15, (numbers.size, 2))
    velocity = rng.uniform(size=numbers.size) < 0.67
    p["dap_vx"][velocity], p["dap_vy"][velocity] = v[velocity].T
    turn = rng.uniform(size=numbers.size) < 0.5
    p["dap_turn_rate_rad_s"][turn] = rng.normal(0.0, 0.04, int(turn.sum()))
    p["dap_flags"] = np.where(velocity, DAP_VELOCITY, 0) | np.where(turn, DAP_TURN_RATE, 0)
    return as_plot_arrays(p)


SIZES = st.integers(min_value=1, max_value=40)
SEEDS = st.integers(min_value=0, max_value=2**32 - 1)
GROWN_FROM = 8
"""The local-track tables' rows at first here (the service's start with
``table.LOCAL_ROWS``): the draws create more, so that the tables grow on the way."""


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(min_value=1, max_value=5))
def test_consider_prediction_and_bias_share(seed: int, k: int, n_radars: int) -> None:
    compiled, reference, rng = _states(seed, n_radars, k)
    numbers = rng.permutation(np.arange(1, k + 1))
    dt = rng.uniform(-5.0, 15.0, k)
    got = estimator_plots.combined_prediction(compiled, numbers, dt)
    want = estimator_plots.combined_prediction(reference, numbers, dt)
    for a, b in zip(want, got, strict=True):
        close(a, b)
    from tracker_service.fusion.kernels import bias_share

    b = compiled.sys["B"]
    close(consider.bias_share(want[2], b[numbers]), bias_share(got[2], b, numbers))
    # The radars without sensitivities skipped, to the bit of the sum over all of them
    # (a non-finite bias of such a radar still counts: 0 times infinity is NaN).
    m = got[2].copy()
    m[:, rng.uniform(size=n_radars) < 0.5] = 0.0
    m[rng.uniform(size=m.shape) < 0.1] = -0.0
    b = b.copy()
    b[numbers[0], rng.integers(0, n_radars)] = np.inf
    want_bits = _textbook_bias_share(m, b[numbers])
    assert bias_share(m, b, numbers).tobytes() == want_bits.tobytes()


def _textbook_bias_share(M: FloatArray, B: FloatArray) -> FloatArray:
    """sum_l M_l B_l M_l^T in Python floats, every radar's terms added in order."""
    k, n_radars = M.shape[:2]
    out = np.zeros((k, 4, 4))
    for r, sensor, a, b in itertools.product(range(k), range(n_radars), range(4), range(4)):
        mb = [
            float(M[r, sensor, a, 0]) * float(B[r, sensor, 0, c])
            + float(M[r, sensor, a, 1]) * float(B[r, sensor, 1, c])
            for c in range(2)
        ]
        out[r, a, b] = float(out[r, a, b]) + (
            mb[0] * float(M[r, sensor, b, 0]) + mb[1] * float(M[r, sensor, b, 1])
        )
    return out


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(min_value=1, max_value=5), data=st.data())
def test_filter_round_updates_the_table_in_place_as_the_reference(
    seed: int, k: int, n_radars: int, data: st.DataObject
) -> None:
    compiled, reference, rng = _states(seed, n_radars, k, use_daps=data.draw(st.booleans()))
    radar = data.draw(st.integers(min_value=0, max_value=n_radars - 1))
    numbers = rng.permutation(np.arange(1, k + 1))[: max(1, k // 2)]
    plots = _plots(rng, compiled, numbers)
    extra = _spd(rng, (numbers.size,), np.array([50.0, 50.0]))
    for state in (compiled, reference):
        estimator_plots._filter_round(state, radar, numbers, plots, extra)
    assert compiled.stats == reference.stats
    for name in ("mx", "mP", "mM", "mu", "x", "P", "M", "B", "t"):
        close_per_track(reference.sys[name], compiled.sys[name], name)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(1, 4), updates=st.integers(0, 30))
def test_absorb_is_the_reference(seed: int, k: int, n_radars: int, updates: int) -> None:
    """A batch's plots absorbed in one compiled call (``kernels.absorb_plots``) against
    the numpy path's rounds: the same system tables (1e-9 of each track's scale), the
    same statistics and the pre-selection's terms of the updated tracks as
    ``nearby.refresh`` computes them; local rows feeding a track several times in the
    batch (several rounds), late plots, plot ids not found, created tracks and rows
    feeding none among the draws."""
    compiled, reference, rng = _states(seed, n_radars, k)
    local = compiled.local  # both states' (``_states``)
    local.rows["system"][:k] = rng.integers(0, k + 1, k)
    local.relink()
    rows = rng.integers(0, k, updates)
    numbers = np.maximum(local.rows["system"][rows], 1)
    plots = _plots(rng, compiled, numbers)
    plots.rows["plot_id"] = np.arange(updates)
    late = rng.random(updates) < 0.15
    plots.rows["time"][late] = compiled.sys["t"][numbers[late]] - 6.0
    u = _local_updates(rng, updates)
    u["plot_id"] = np.where(rng.random(updates) < 0.1, updates + 1, np.arange(updates))
    has_plot = rng.random(updates) < 0.85
    created = rng.choice(np.arange(1, k + 1), int(rng.integers(0, min(k, 3) + 1)), replace=False)
    extra = _spd(rng, (updates,), np.array([50.0, 50.0]))
    radar = int(rng.integers(0, n_radars))
    t_before = compiled.sys["t"].copy()
    for state in (compiled, reference):
        estimator_plots.PlotFilterEstimator().absorb(
            state, radar, rows, u, extra, has_plot, plots, created
        )
    assert compiled.stats == reference.stats
    for name in ("mx", "mP", "mM", "mu", "x", "P", "M", "B", "t"):
        close_per_track(reference.sys[name], compiled.sys[name], name)
    nearby.refresh(reference.sys, np.flatnonzero(reference.sys["t"] != t_before), compiled=True)
    for name in ("moments", "sensitivity", "largest_bias"):
        close(reference.sys[name], compiled.sys[name])


def close_per_track(reference: FloatArray, compiled: FloatArray, name: str) -> None:
    """Equal to 1e-9 of each track's scale: covariances (..., 4, 4) in units of their
    diagonal's standard deviations (correlation units), states' positions and velocities
    apart, anything else (vectors) relative to the track's largest entry of the field (an entry
    far smaller than the others it is computed from is as exact as they are, not more)."""
    if reference.size == 0:
        return
    if name in ("P", "mP"):
        sd = np.sqrt(np.abs(np.diagonal(reference, axis1=-2, axis2=-1)))
        scale = np.maximum(sd[..., :, None] * sd[..., None, :], 1e-300)
    elif name in ("x", "mx"):
        scale = np.zeros(reference.shape)
        for part in (slice(0, 2), slice(2, 4)):
            top = np.abs(reference[..., part]).max(axis=-1, keepdims=True)
            scale[..., part] = np.maximum(top, 1e-300)
    else:
        flat = np.abs(reference).reshape(reference.shape[0], -1).max(axis=1)
        scale = np.maximum(flat, 1e-300).reshape((-1,) + (1,) * (reference.ndim - 1))
    np.testing.assert_array_less(np.abs(compiled - reference) / scale, TOLERANCE, err_msg=name)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, correlation=st.sampled_from([0.0, 0.3, 0.9]))
def test_ml_fusion_of_local_tracks(seed: int, k: int, correlation: float) -> None:
    compiled, reference, rng = _states(seed, 1, k)
    for state in (compiled, reference):
        state.config = dataclasses.replace(state.config, correlation=correlation)
    # Rows of 0..8 distinct sources, valid first; some rows with none (NaN).
    slots = np.full((k, 8), -1, dtype=np.int64)
    for row in range(k):
        n = int(rng.integers(0, min(8, k) + 1))
        slots[row, :n] = rng.choice(k, n, replace=False)
    t = rng.uniform(-5.0, 20.0, k)
    want = fuse_local_tracks(reference, slots, t)
    got = fuse_local_tracks(compiled, slots, t)
    for name, a, b in zip(("x", "P"), want, got, strict=True):
        np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
        fused = (slots >= 0).any(axis=1)
        assert not np.isnan(a[fused]).any()
        close_per_track(a[fused], b[fused], name)


@pytest.mark.parametrize("method", ["plots", "tracks"])
def test_compiled_and_numpy_fusers_give_the_same_rows(method: str) -> None:
    """Three radars' local tracks of six aircraft (crossings, a turn, a shared code, a
    handover), with a residual-bias covariance per update: the same rows, the same
    references and the same counts from both implementations."""
    scenario = build(AIRCRAFT, RADARS)
    trackers = [LocalTracker(TrackerConfig(scan_period_s=r.period)) for r in RADARS]
    fusers = {
        impl: SystemTracker(3, FusionConfig(method=method, implementation=impl))
        for impl in ("compiled", "numpy")
    }
    rows: dict[str, list[npt.NDArray[Any]]] = {impl: [] for impl in fusers}
    for ri, plots in scenario.batches[: len(scenario.batches) // 2]:
        updates = trackers[ri].process(plots)
        extra = np.broadcast_to(np.diag([40.0**2, 25.0**2]), (len(updates), 2, 2)).copy()
        # Every source, and the first two only (as the bias estimator takes the radars
        # and not the ADS-B source).
        for sources in (None, 2):
            refs = {impl: f.references(ri, updates, plots, sources) for impl, f in fusers.items()}
            for name in ("others_xy", "others_P", "others_v", "all_xy", "all_P"):
                a, b = getattr(refs["numpy"], name), getattr(refs["compiled"], name)
                np.testing.assert_array_equal(np.isnan(a), np.isnan(b))
                valid = ~np.isnan(a).any(axis=tuple(range(1, a.ndim)))
                close_per_track(a[valid], b[valid], name[-1])  # "P", or vectors by size
            for name in ("plot_id", "system_number", "time", "others_valid", "radars_seen"):
                a, b = getattr(refs["numpy"], name), getattr(refs["compiled"], name)
                np.testing.assert_array_equal(a, b, err_msg=name)
            # The others' predictions alone are the same numbers, bit for bit.
            for impl, f in fusers.items():
                alone = references(f.state, ri, updates, as_plot_arrays(plots), sources, False)
                for name in References.__dataclass_fields__:
                    a, b = getattr(alone, name), getattr(refs[impl], name)
                    if name.startswith("all_"):
                        assert np.isnan(a).all(), name
                    else:
                        assert a.tobytes() == b.tobytes(), (impl, name)
        for impl, f in fusers.items():
            rows[impl].append(f.process(ri, updates, plots, extra))
    a, b = np.concatenate(rows["numpy"]), np.concatenate(rows["compiled"])
    assert len(a) > 400
    for name in a.dtype.names or ():
        if name == "P":
            close_per_track(a[name].reshape(-1, 4, 4), b[name].reshape(-1, 4, 4), name)
        elif name in ("x", "y", "vx", "vy"):  # as vectors: position, velocity
            pair = ("x", "y") if name in ("x", "y") else ("vx", "vy")
            ref = np.column_stack([a[pair[0]], a[pair[1]]])
            close_per_track(ref, np.column_stack([b[pair[0]], b[pair[1]]]), "vector")
        elif a.dtype[name].kind == "f":
            np.testing.assert_array_equal(np.isnan(a[name]), np.isnan(b[name]))
            finite = ~np.isnan(a[name])
            close(a[name][finite], b[name][finite])
        else:
            np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert fusers["numpy"].stats == fusers["compiled"].stats
    # The pre-selection's terms kept by every writer are those the live tracks hold now.
    sys = fusers["compiled"].state.sys
    alive = np.flatnonzero(sys["alive"])
    kept = {name: sys[name][alive].copy() for name in ("moments", "sensitivity", "largest_bias")}
    nearby.refresh(sys, alive, compiled=True)
    for name, value in kept.items():
        np.testing.assert_array_equal(value, sys[name][alive], err_msg=name)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=0, max_value=60), max_sources=st.integers(1, 8))
def test_slots_are_the_references(seed: int, k: int, max_sources: int) -> None:
    """The same rows, in the same order: most recent plot first, ties in row order (plot
    times drawn from few values), dead rows and other system tracks left out."""
    rng = np.random.default_rng(seed)
    tables = [LocalTrackTable(5, 3, compiled=flag, capacity=GROWN_FROM) for flag in (False, True)]
    u = _local_updates(rng, k)
    rows = tables[1].find(0, u, create=True)
    assert (tables[0].find(0, u, create=True) == rows).all()
    # The compiled table's lists of feeders kept through moves (rows given twice among
    # them: the last number holds), the reference's column written at once.
    compiled = tables[1]
    for _ in range(3):
        moved = rng.choice(rows, rows.size) if rows.size else rows
        compiled.feed(moved, rng.integers(0, 12, moved.size))
    tables[0].rows["system"][:] = compiled.rows["system"]
    alive, t_plot = rng.random(k) < 0.8, rng.choice([-np.inf, 1.0, 2.0, 3.0], k)
    for table in tables:
        table.rows["alive"][rows] = alive
        table.rows["t_plot"][rows] = t_plot
    drawn = rng.integers(0, 14, int(rng.integers(0, 20)))
    # With a 0 (the unfed rows: by the pass over the table) and without.
    for numbers in (drawn, drawn[drawn > 0]):
        want, got = (table.slots(numbers, max_sources) for table in tables)
        np.testing.assert_array_equal(want, got)
        relinked = copy.deepcopy(compiled)
        relinked.relink()
        np.testing.assert_array_equal(want, relinked.slots(numbers, max_sources))


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=0, max_value=30))
def test_radar_feeders_are_the_reference(seed: int, k: int) -> None:
    """``LocalTrackTable.radar_feeders`` from the lists against the pass over the table:
    the same rows, ascending; rows of three radars moved between tracks three times, dead
    rows, numbers repeated and 0 among them."""
    rng = np.random.default_rng(seed)
    tables = [LocalTrackTable(5, 3, compiled=flag, capacity=GROWN_FROM) for flag in (False, True)]
    radar = rng.integers(0, 3, k)
    u = _local_updates(rng, k)
    for r in range(3):
        rows = tables[1].find(r, u[radar == r], create=True)
        assert (tables[0].find(r, u[radar == r], create=True) == rows).all()
    rows = np.arange(tables[1].n)
    compiled = tables[1]
    for _ in range(3):
        moved = rng.choice(rows, rows.size) if rows.size else rows
        compiled.feed(moved, rng.integers(0, 8, moved.size))
    tables[0].rows["system"][:] = compiled.rows["system"]
    alive = rng.random(rows.size) < 0.8
    for table in tables:
        table.rows["alive"][rows] = alive
    numbers = rng.integers(0, 10, int(rng.integers(0, 12)))
    for r in range(3):
        want, got = (table.radar_feeders(numbers, r) for table in tables)
        np.testing.assert_array_equal(want, got)


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=0, max_value=30), n=st.integers(0, 60))
def test_store_is_the_reference(seed: int, k: int, n: int) -> None:
    """``LocalTrackTable.store`` by its kernel against the numpy path, every field equal:
    rows updated several times a batch, unknown identities, flight levels missing or
    with an infinite rate, updates with and without a plot, tracks without a state."""
    rng = np.random.default_rng(seed)
    tables = [LocalTrackTable(5, 3, compiled=flag, capacity=GROWN_FROM) for flag in (False, True)]
    rows = tables[0].find(0, _local_updates(rng, max(k, 1)), create=True)
    loc = tables[0].rows
    loc["t"][rows] = np.where(rng.random(rows.size) < 0.3, np.nan, rng.uniform(0, 9, rows.size))
    loc["address"][rows] = rng.integers(-1, 3, rows.size)
    tables[1].rows = Columns(loc.dtype, {name: loc[name].copy() for name in loc.dtype.names or ()})
    tables[1].n = tables[0].n
    u = np.zeros(n, dtype=LocalTracker().output_dtype)
    u["status"] = rng.integers(0, 4, n)
    u["time"] = rng.uniform(0.0, 10.0, n)
    for name in ("x", "y", "vx", "vy"):
        u[name] = rng.normal(0.0, 1e4, n)
    u["P"] = rng.normal(0.0, 100.0, (n, 16))
    u["address"] = np.where(rng.random(n) < 0.5, -1, rng.integers(0, 1 << 24, n))
    u["mode3a"] = np.where(rng.random(n) < 0.5, -1, rng.integers(0, 4096, n))
    u["flight_level"] = np.where(rng.random(n) < 0.4, np.nan, rng.uniform(0.0, 400.0, n))
    u["climb_rate_fl_per_s"] = rng.choice([np.nan, np.inf, -np.inf, 0.5, -1.0], n)
    u["model_probabilities"] = rng.dirichlet(np.ones(5), n)
    u["plot_id"] = rng.integers(0, 1000, n)
    which = rng.integers(0, rows.size, n)
    extra = _spd(rng, (n,), np.array([40.0, 40.0]))
    has_plot = rng.random(n) < 0.6
    for table in tables:
        table.store(rows[which], u, extra, has_plot)
    want, got = tables[0].rows, tables[1].rows
    for name in want.dtype.names or ():
        np.testing.assert_array_equal(want[name], got[name], err_msg=name)


def _counted_feeders(table: LocalTrackTable) -> npt.NDArray[np.int64]:
    """``LocalTrackTable.confirmed_feeders``' counts from the columns, by numpy."""
    used = table.used
    counted = used["alive"] & (used["system"] > 0) & (used["status"] == LOCAL_CONFIRMED)
    want = np.zeros_like(table.confirmed_feeders())
    radars = want.shape[0] - 1
    np.add.at(want, (used["radar"][counted], used["system"][counted]), 1)
    want[:radars, 0] = want[:radars].sum(axis=1)
    want[radars] = want[:radars].sum(axis=0)
    return want


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=1, max_value=30), rounds=st.integers(1, 8))
def test_confirmed_feeders_are_counted_as_the_columns_say(seed: int, k: int, rounds: int) -> None:
    """The counts of confirmed live feeders per radar and system track that ``feed``,
    ``store``, ``remove`` and ``relink`` keep (the exchange test's sets without a pass
    over the table) against a count of the columns after every step: rows of three
    radars created, stored with every status (confirmed, tentative, deleted), moved
    between tracks (to none too, rows given twice), removed, the table grown and
    compacted (its rows moved)."""
    rng = np.random.default_rng(seed)
    table = LocalTrackTable(5, 3, compiled=True, capacity=GROWN_FROM)
    for _ in range(rounds):
        radar = int(rng.integers(0, 3))
        u = _local_updates(rng, k)
        u["track_number"] = rng.integers(1, 2 * k + 1, k)
        u["status"] = rng.choice([LOCAL_CONFIRMED, LOCAL_TENTATIVE, LOCAL_DELETED], k)
        rows = table.find(radar, u, create=True)
        known = rows >= 0
        u, rows = u[known], rows[known]
        table.store(rows, u, np.zeros((rows.size, 2, 2)), rng.random(rows.size) < 0.5)
        np.testing.assert_array_equal(table.confirmed_feeders(), _counted_feeders(table))
        live = np.flatnonzero(table.used["alive"])
        moved = rng.choice(live, int(rng.integers(0, 2 * live.size + 1))) if live.size else live
        table.feed(moved, rng.integers(0, 6, moved.size))
        np.testing.assert_array_equal(table.confirmed_feeders(), _counted_feeders(table))
        deleted = np.unique(rows[table.rows["status"][rows] == LOCAL_DELETED])
        table.remove(deleted)
        table.compact()
        np.testing.assert_array_equal(table.confirmed_feeders(), _counted_feeders(table))
    relinked = copy.deepcopy(table)
    relinked.relink()
    np.testing.assert_array_equal(relinked.confirmed_feeders(), table.confirmed_feeders())


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, n=st.integers(1, 60), candidates=st.integers(0, 80))
def test_exchange_witnesses_are_the_reference(seed: int, n: int, candidates: int) -> None:
    """The exchange test's feeding sets and its pairs and votes by their kernels
    (``kernels.feeding_sets`` from the table's counts, ``kernels.exchange_witnesses``)
    against the numpy path, every array equal: local rows of four radars feeding eight
    system tracks, candidates repeating pairs from either side, near system tracks with
    and without a row of the candidate's radar or of another."""
    from tracker_service.fusion.kernels import exchange_witnesses, feeding_sets

    rng = np.random.default_rng(seed)
    states = [
        FusionState(
            FusionConfig(implementation=impl), 4, ModelSet.from_config(FusionConfig().plot_filter)
        )
        for impl in ("compiled", "numpy")
    ]
    radar = rng.integers(0, 4, n)
    for state in states:
        for r in range(4):
            u = _local_updates(rng, n)
            state.local.find(r, u[radar == r], create=True)
    loc = states[0].local.rows
    system = rng.integers(1, 9, states[0].local.n)
    # Feeding: confirmed and live (the kernel reads the lists of feeders, the numpy path
    # ``confirmed_feeding``'s rows); tentative rows and removed ones in the lists' way;
    # ``_feeding``'s sets by the kernel and the numpy path alike.
    status = np.where(rng.random(states[0].local.n) < 0.8, LOCAL_CONFIRMED, LOCAL_TENTATIVE)
    removed = np.flatnonzero(rng.random(states[0].local.n) < 0.1)
    for state in states:
        state.local.rows["system"][: state.local.n] = system
        state.local.rows["status"][: state.local.n] = status
        state.local.relink()
        state.local.remove(removed)
    feeding = associate.confirmed_feeding(states[1])
    for radar in range(4):
        compiled_sets = feeding_sets(states[0].local.confirmed_feeders(), radar)
        numpy_sets = associate._feeding(states[1], radar)
        assert compiled_sets[0] == numpy_sets[0]
        for a, b in zip(compiled_sets[1:], numpy_sets[1:], strict=True):
            np.testing.assert_array_equal(a, b)
    li = rng.choice(feeding, candidates) if feeding.size else np.zeros(0, dtype=np.int64)
    # As in use, S' is fed by a feeding row (of the candidate's radar or not; the
    # candidate's own system track among them, which is no candidate).
    sj = rng.choice(system[feeding], li.size) if feeding.size else li
    got = exchange_witnesses(
        li,
        sj,
        *states[0].local.feeder_lists(),
        loc["alive"],
        loc["status"],
        LOCAL_CONFIRMED,
        loc["system"],
        loc["radar"],
        MAX_SYSTEM_NUMBER + 1,
    )
    want = associate._exchange_witnesses(states[1], li, sj)
    assert np.array_equal(loc["key"], states[1].local.rows["key"])
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, touched=st.integers(0, 12), alive=st.integers(0, 60))
def test_identity_candidates_are_the_reference(seed: int, touched: int, alive: int) -> None:
    """Merging's identity pre-filter by the kernel: the same tracks, addresses and codes
    drawn from few values, unknown (-1) in both sets."""
    rng = np.random.default_rng(seed)
    states = [
        FusionState(
            FusionConfig(implementation=impl), 2, ModelSet.from_config(FusionConfig().plot_filter)
        )
        for impl in ("compiled", "numpy")
    ]
    address, code = rng.integers(-1, 6, 99), rng.integers(-1, 6, 99)
    for state in states:
        state.sys["address"][1:100], state.sys["mode3a"][1:100] = address, code
    numbers = rng.integers(1, 100, touched), np.sort(rng.choice(99, alive, replace=False) + 1)
    got, want = (lifecycle._identity_candidates(state, *numbers) for state in states)
    np.testing.assert_array_equal(want, got)


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, n_a=st.integers(0, 60), n_b=st.integers(0, 60))
def test_near_pairs_are_the_reference(seed: int, n_a: int, n_b: int) -> None:
    """The pre-selection's pairs by the kernel: the same pairs in the same order, either
    set the larger, points spread beyond the box and radii of every size."""
    rng = np.random.default_rng(seed)
    xy_a, xy_b = rng.normal(0.0, 3e4, (n_a, 2)), rng.normal(0.0, 3e4, (n_b, 2))
    r_a, r_b = rng.exponential(5e3, n_a), rng.exponential(5e3, n_b)
    got = nearby.near_pairs(xy_a, r_a, xy_b, r_b, compiled=True)
    want = nearby.near_pairs(xy_a, r_a, xy_b, r_b, compiled=False)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=0, max_value=40), n_radars=st.integers(1, 5))
def test_pre_selection_reads_sensitivities_and_biases_as_the_reference(
    seed: int, k: int, n_radars: int
) -> None:
    """``nearby``'s in-place reads of the coarse states, M and B (association's and
    merging's radii) against the gathers they replace; numbers repeat and skip rows, as
    candidates do."""
    compiled, _, rng = _states(seed, n_radars, max(k, 1))
    sys = compiled.sys
    sys["M"][1 : k + 1] = rng.normal(0.0, 0.5, (k, n_radars, 4, 2))
    sys["x"][1 : k + 1] = sys["mx"][1 : k + 1, 0]
    sys["P"][1 : k + 1] = sys["mP"][1 : k + 1, -1]
    # As every writer of the models, sensitivities and biases does.
    nearby.refresh(sys, np.arange(1, k + 1), compiled=True)
    numbers = rng.integers(1, k + 1, k) if k else np.zeros(0, dtype=np.int64)
    t_mid, spread = float(rng.uniform(0.0, 10.0)), float(rng.uniform(0.0, 3.0))
    for from_models in (True, False):
        args = (from_models, float(rng.uniform(0.0, 2e4)), t_mid, spread, 16.0, 4.0, 0.05)
        got_xy, got_r = nearby.system_reach(sys, numbers, *args, compiled=True)
        want_xy, want_r = nearby.system_reach(sys, numbers, *args, compiled=False)
        np.testing.assert_allclose(got_xy, want_xy, rtol=TOLERANCE, atol=0.0)
        np.testing.assert_allclose(got_r, want_r, rtol=TOLERANCE, atol=0.0)
    got_b = nearby.system_largest_bias(sys, numbers, compiled=True)
    want_b = nearby.largest_bias(sys["B"][numbers])
    assert got_b == pytest.approx(want_b, rel=TOLERANCE, abs=0.0)
    assert nearby.system_largest_bias(sys, numbers, compiled=False) == want_b


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(min_value=1, max_value=5))
def test_gate_distances_are_the_reference(seed: int, k: int, n_radars: int) -> None:
    """The association gate's distances in one compiled pass (``kernels.gate_distances``)
    against ``associate.distance``'s numpy path: pairs of any local track (of any radar)
    with any system track, numbers repeating, steps backwards and forwards."""
    compiled, reference, rng = _states(seed, n_radars, k)
    local = compiled.local.rows
    local["radar"][:k] = rng.integers(0, n_radars, k)
    # Radars none of whose plots updated a system track hold no bias in it (B = 0),
    # which the kernel skips.
    unseen = rng.uniform(size=(k, n_radars)) < 0.5
    for table in (compiled.sys, reference.sys):
        table["B"][1 : k + 1][unseen] = 0.0
    pairs = 2 * k
    rows = rng.integers(0, k, pairs)
    numbers = rng.integers(1, k + 1, pairs)
    estimator = estimator_plots.PlotFilterEstimator()
    got = associate.distance(compiled, estimator, rows, numbers)
    want = associate.distance(reference, estimator, rows, numbers)
    np.testing.assert_allclose(got, want, rtol=TOLERANCE, atol=0.0)


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, sizes=st.lists(st.integers(min_value=0, max_value=300), max_size=12))
def test_segment_sums_are_numpy_sums_to_the_bit(seed: int, sizes: list[int]) -> None:
    """The exchange test's per-pair sums by segments (``kernels.segment_sums``): the bits
    of ``values[lo:hi].sum()`` of every slice, lengths across numpy's pairwise blocks."""
    from tracker_service.fusion.kernels import segment_sums

    rng = np.random.default_rng(seed)
    ends = np.concatenate([[0], np.cumsum(sizes, dtype=np.int64)]).astype(np.int64)
    values = rng.normal(0.0, 1.0, int(ends[-1])) * 10.0 ** rng.uniform(-3, 6, int(ends[-1]))
    want = [values[lo:hi].sum() for lo, hi in itertools.pairwise(ends.tolist())]
    assert segment_sums(values, ends).tolist() == want


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, pairs=st.integers(0, 12))
def test_exchange_votes_are_the_reference(seed: int, k: int, pairs: int) -> None:
    """The exchange test's deltas and agreements in one pass (``kernels.exchange_votes``)
    against ``associate._votes``'s numpy path: deltas to 1e-9, agreements equal; a pair
    of 1 to 8 votes, witnesses repeating, some votes unanimous."""
    from tracker_service.fusion.kernels import exchange_votes

    compiled, reference, rng = _states(seed, 2, k)
    ends = np.concatenate([[0], np.cumsum(rng.integers(1, 9, pairs))]).astype(np.int64)
    n = int(ends[-1])
    closer, farther, witness = rng.integers(0, k, n), rng.integers(0, k, n), rng.integers(0, k, n)
    # A witness that is the track it should be farther from favours the exchange.
    same = rng.random(n) < 0.5
    witness[same] = farther[same]
    loc = compiled.local.rows
    got = exchange_votes(
        loc["t"],
        loc["x"],
        loc["P"],
        loc["extra"],
        closer,
        farther,
        witness,
        ends,
        compiled.config.q,
    )
    want = associate._votes(reference, closer, farther, witness, ends)
    np.testing.assert_allclose(got[0], want[0], rtol=TOLERANCE, atol=0.0)
    np.testing.assert_array_equal(got[1], want[1])


def _textbook_quadratic_form(s: FloatArray, d: FloatArray) -> float:
    """d^T s^-1 d by Gaussian elimination with partial pivoting over lists, in Python
    floats (IEEE doubles, a zero pivot's division raising as the kernels' does)."""
    a, y, x = [[float(v) for v in row] for row in s], [float(v) for v in d], [0.0] * 4
    for col in range(4):
        pivot = col
        for r in range(col + 1, 4):
            if abs(a[r][col]) > abs(a[pivot][col]):
                pivot = r
        a[col], a[pivot] = a[pivot], a[col]
        y[col], y[pivot] = y[pivot], y[col]
        for r in range(col + 1, 4):
            factor = a[r][col] / a[col][col]
            for b in range(col, 4):
                a[r][b] -= factor * a[col][b]
            y[r] -= factor * y[col]
    for row in range(3, -1, -1):
        acc = y[row]
        for b in range(row + 1, 4):
            acc -= a[row][b] * x[b]
        x[row] = acc / a[row][row]
    total = 0.0
    for row in range(4):
        total += float(d[row]) * x[row]
    return total


@settings(max_examples=200, deadline=None)
@given(seed=SEEDS, kind=st.sampled_from(["spd", "scaled", "nan", "inf", "singular"]))
def test_quadratic_form_is_the_textbook_elimination_to_the_bit(seed: int, kind: str) -> None:
    """The 4x4 quadratic form in scalars (``kernels._quadratic_form4``, through
    ``_quadratic_form_lu``) against the textbook loop, bit for bit: covariances, rows
    scaled by up to 1e12 so that the pivots come in every order, NaN and infinite
    entries, a zero pivot (both raise)."""
    from tracker_service.fusion.kernels import _quadratic_form_lu

    rng = np.random.default_rng(seed)
    d = rng.normal(0.0, 1e3, 4)
    if kind == "spd":
        s = _spd(rng, (), np.array([300.0, 300.0, 20.0, 20.0]))
    else:
        s = rng.normal(0.0, 1.0, (4, 4)) * 10.0 ** rng.uniform(-6, 6, (4, 1))
        s = s[rng.permutation(4)]
    if kind in ("nan", "inf"):
        s[rng.integers(0, 4), rng.integers(0, 4)] = np.nan if kind == "nan" else -np.inf
    if kind == "singular":
        s[:, int(rng.integers(0, 4))] = 0.0
    try:
        want = _textbook_quadratic_form(s, d)
    except ZeroDivisionError:
        with pytest.raises(ZeroDivisionError):
            _quadratic_form_lu(s, d)
        return
    got = _quadratic_form_lu(s, d)
    assert np.array([got]).tobytes() == np.array([want]).tobytes() or (
        np.isnan(got) and np.isnan(want)
    )
    if kind == "spd":
        assert got == pytest.approx(float(d @ np.linalg.solve(s, d)), rel=TOLERANCE)


@settings(max_examples=50, deadline=None)
@given(
    values=st.lists(st.integers(-1, 40), max_size=30),
    members=st.lists(st.integers(-1, 40), max_size=80),
)
def test_membership_helpers_are_isin(values: list[int], members: list[int]) -> None:
    """``arrays.among`` (few values, many members) and the table of ``marked_numbers``
    against ``np.isin``: repeated and unknown (-1) values, no member, no value."""
    v, m = np.array(values, dtype=np.int64), np.array(members, dtype=np.int64)
    want = np.isin(v, m)
    np.testing.assert_array_equal(arrays.among(v, m), want)
    numbers = v[v >= 0]
    np.testing.assert_array_equal(
        arrays.marked_numbers(m[m >= 0])[numbers], np.isin(numbers, m[m >= 0])
    )


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=1, max_value=40), n_radars=st.integers(1, 4))
def test_merge_candidates_are_the_reference(seed: int, k: int, n_radars: int) -> None:
    """Merging's pre-selection in one compiled call (``kernels.merge_candidates``) against
    ``lifecycle._merge_candidates``' numpy path: the same pairs in the same order, among
    tracks packed close enough to pair, some orphaned or dead, identities from few
    values, touched numbers repeating."""
    compiled, reference, rng = _states(seed, n_radars, k)
    sys = compiled.sys
    n = np.arange(1, k + 1)
    # Some 5 % of the pairs near enough (all of them at 3 km apart, as good as none at 100).
    sys["x"][n] = np.column_stack([rng.normal(0.0, 3e4, (k, 2)), rng.uniform(-250, 250, (k, 2))])
    sys["P"][n] = sys["mP"][n, -1]
    sys["M"][n] = rng.normal(0.0, 0.5, (k, n_radars, 4, 2))
    sys["address"][n], sys["mode3a"][n] = rng.integers(-1, 4, k), rng.integers(-1, 4, k)
    sys["orphaned"][n[rng.uniform(size=k) < 0.2]] = 1.0
    sys["alive"][n[rng.uniform(size=k) < 0.1]] = False
    nearby.refresh(sys, n, compiled=True)
    reference.sys.put(slice(None), sys)
    touched = rng.integers(1, k + 1, int(rng.integers(0, 6)))
    touched = touched[sys["alive"][touched]]
    got = lifecycle._merge_candidates(compiled, touched)
    want = lifecycle._merge_candidates(reference, touched)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=40, deadline=None)
@given(
    seed=SEEDS,
    k=st.integers(min_value=1, max_value=40),
    n_radars=st.integers(1, 4),
    nan_track=st.booleans(),
)
def test_near_pairs_of_local_tracks_are_the_reference(
    seed: int, k: int, n_radars: int, nan_track: bool
) -> None:
    """Association's pre-selection in one compiled call (``kernels.near_local_system``)
    against ``associate._near``'s numpy path: the same (row, number) pairs in the same
    order, for either estimator's coarse state, the bias bound over a superset; also with
    one system track's covariance NaN (the compiled bound must not drop it alone where
    the reference's NaN radius leaves no pair)."""
    compiled, reference, rng = _states(seed, n_radars, k)
    sys, loc = compiled.sys, compiled.local.rows
    n = np.arange(1, k + 1)
    sys["x"][n] = np.column_stack([rng.normal(0.0, 3e4, (k, 2)), rng.uniform(-250, 250, (k, 2))])
    if nan_track:
        sys["mP"][int(rng.integers(1, k + 1)), :, 0, 0] = np.nan
    sys["P"][n] = sys["mP"][n, -1]
    sys["M"][n] = rng.normal(0.0, 0.5, (k, n_radars, 4, 2))
    nearby.refresh(sys, n, compiled=True)
    reference.sys.put(slice(None), sys)
    # Each local track 1 km about some system track: a few percent of the pairs near.
    loc["x"][:k, :2] = sys["moments"][rng.integers(1, k + 1, k), :2] + rng.normal(0, 1e3, (k, 2))
    free = np.sort(rng.choice(k, int(rng.integers(1, k + 1)), replace=False))
    candidates = np.sort(rng.choice(n, int(rng.integers(1, k + 1)), replace=False))
    for estimator in (estimator_plots.PlotFilterEstimator(), associate.STRAIGHT_LINE):
        for bias_over in (None, n):
            got = associate._near(compiled, estimator, free, candidates, bias_over)
            want = associate._near(reference, estimator, free, candidates, bias_over)
            for a, b in zip(want, got, strict=True):
                np.testing.assert_array_equal(a, b)


@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=1, max_value=12), n_radars=st.integers(1, 4))
def test_exchange_pairs_are_the_reference(seed: int, k: int, n_radars: int) -> None:
    """The exchange test from the batch's confirmed rows to its pairs' votes in one
    compiled call (``kernels.exchange_pairs``) against ``associate._exchange_pairs``'s
    numpy path (its four steps): the same pairs and keys, deltas to 1e-9, the same
    agreements; system tracks within a few kilometres of each other, each radar's rows
    about them, feeding some (confirmed or tentative, some removed), one radar alone
    (no pairs) among the draws."""
    compiled, reference, rng = _states(seed, n_radars, k)
    sys, local = compiled.sys, compiled.local
    n = np.arange(1, k + 1)
    m = compiled.models.n_models
    sys["mx"][n, :, :2] = rng.uniform(-5e3, 5e3, (k, 1, 2)) + rng.normal(0, 200, (k, m, 2))
    sys["x"][n] = sys["mx"][n, -1]
    sys["P"][n] = sys["mP"][n, -1]
    nearby.refresh(sys, n, compiled=True)
    reference.sys.put(slice(None), sys)
    for radar in range(1, n_radars):
        rows_of_radar = local.find(radar, _local_updates(rng, k), create=True)
        for name in ("t", "x", "P", "extra"):
            local.rows[name][rows_of_radar] = local.rows[name][rows_of_radar - radar * k]
    loc, used = local.rows, local.n
    system = rng.integers(0, k + 1, used)
    loc["x"][:used, :2] = sys["moments"][np.maximum(system, 1), :2] + rng.normal(0, 1e3, (used, 2))
    loc["system"][:used] = system
    loc["status"][:used] = np.where(rng.random(used) < 0.8, LOCAL_CONFIRMED, LOCAL_TENTATIVE)
    local.relink()
    local.remove(np.flatnonzero(rng.random(used) < 0.1))
    radar = int(rng.integers(0, n_radars))
    confirmed = np.flatnonzero(
        loc["alive"][:used]
        & (loc["radar"][:used] == radar)
        & (loc["system"][:used] > 0)
        & (loc["status"][:used] == LOCAL_CONFIRMED)
    )
    for estimator in (estimator_plots.PlotFilterEstimator(), associate.STRAIGHT_LINE):
        got = associate._exchange_pairs(compiled, estimator, confirmed, radar)
        want = associate._exchange_pairs(reference, estimator, confirmed, radar)
        assert (got is None) == (want is None)
        if got is None or want is None:
            continue
        *got_rows, got_deltas, got_favoured = got
        *want_rows, want_deltas, want_favoured = want
        for a, b in zip(want_rows, got_rows, strict=True):
            np.testing.assert_array_equal(a, b)
        np.testing.assert_allclose(got_deltas, want_deltas, rtol=TOLERANCE, atol=0.0)
        np.testing.assert_array_equal(got_favoured, want_favoured)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=st.integers(min_value=1, max_value=60))
def test_expiry_sets_are_the_reference(seed: int, k: int) -> None:
    """``lifecycle.expire`` with its sets by one compiled pass (``kernels.expiring``)
    against the numpy path: the same rows (numbers and statuses) of the silent tracks'
    ends and the orphans' coast and ends, and the same tracks released."""
    rng = np.random.default_rng(seed)
    models = ModelSet.from_config(FusionConfig().plot_filter)
    states = [
        FusionState(
            FusionConfig(implementation=impl, orphan_coast_s=10.0, max_silence_s=5.0), 2, models
        )
        for impl in ("compiled", "numpy")
    ]
    sys = states[0].sys
    n = np.arange(1, k + 1)
    sys["alive"][n] = rng.uniform(size=k) < 0.8
    sys["t"][n] = sys["t_plot"][n] = rng.uniform(0.0, 20.0, k)
    sys["x"][n] = rng.normal(0.0, 1e4, (k, 4))
    sys["P"][n] = np.eye(4) * 100.0
    sys["t_row"][n] = rng.uniform(10.0, 20.0, k)
    orphan = rng.uniform(size=k) < 0.4
    sys["orphaned"][n[orphan]] = rng.uniform(0.0, 20.0, int(orphan.sum()))
    states[1].sys.put(slice(None), sys)
    for state in states:
        state.now = 20.0
    got, want = (lifecycle.expire(state, 0) for state in states)
    assert (got["status"] == ENDED).sum() + (got["status"] == COASTING).sum() == len(got)
    for name in ("system_number", "status"):
        np.testing.assert_array_equal(got[name], want[name])
    for name in ("alive", "orphaned", "freed_at"):
        np.testing.assert_array_equal(states[0].sys[name], states[1].sys[name])


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(1, 40), numbers=st.integers(1, 12))
def test_emit_index_is_the_reference(seed: int, k: int, numbers: int) -> None:
    """``rows.emit``'s index by the kernel: the same last rows, numbers, times, fresh
    flags, plots and statuses, and the same ``t_plot`` written (NaN and infinite ones
    among them), for rows repeating system tracks with and without plots."""
    compiled, reference, rng = _states(seed, 2, 12)
    systems = rng.integers(1, numbers + 1, k)
    u = _local_updates(rng, k)
    u["time"] = rng.uniform(0.0, 20.0, k)
    u["time"][rng.uniform(size=k) < 0.1] = np.nan
    u["plot_id"] = rng.integers(0, 1000, k)
    has_plot = rng.uniform(size=k) < 0.6
    t_plot = rng.choice([np.nan, -np.inf, 5.0, 15.0], 13)
    for state in (compiled, reference):
        state.sys["t_plot"][:13] = t_plot
    got = rows.emit_index_of(compiled, systems, u, has_plot)
    want = rows.emit_index_of(reference, systems, u, has_plot)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(reference.sys["t_plot"], compiled.sys["t_plot"])


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(1, 4))
def test_plot_filter_output_is_the_reference(seed: int, k: int, n_radars: int) -> None:
    """The plot filter's output state and covariance by one kernel call: the IMM's
    prediction, a solo track its founder's update, the bias share added, to 1e-9."""
    compiled, reference, rng = _states(seed, n_radars, k)
    numbers = np.sort(rng.choice(np.arange(1, k + 1), int(rng.integers(1, k + 1)), replace=False))
    solo = rng.uniform(size=k + 1) < 0.3
    for state in (compiled, reference):
        state.sys["solo"][: k + 1] = solo
    t = compiled.sys["t"][numbers] + rng.uniform(-2.0, 8.0, numbers.size)
    latest = _local_updates(rng, numbers.size)
    latest["x"], latest["y"] = rng.normal(0.0, 1e5, (2, numbers.size))
    latest["vx"], latest["vy"] = rng.normal(0.0, 200.0, (2, numbers.size))
    latest["P"] = _spd(rng, (numbers.size,), np.array([90.0, 90.0, 6.0, 6.0])).reshape(-1, 16)
    estimator = estimator_plots.PlotFilterEstimator()
    slots = np.full((numbers.size, 1), -1, dtype=np.int64)
    got = estimator.output(compiled, numbers, t, slots, latest)
    want = estimator.output(reference, numbers, t, slots, latest)
    close(want[0], got[0])
    close(want[1], got[1])


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(0, 12), alive=st.integers(0, 60))
def test_identities_in_use_are_the_reference(seed: int, k: int, alive: int) -> None:
    """Founding's identity test by the kernel: whether a live system track carries each
    address and code, values drawn from few (unknown, -1, among them; track 0 never
    counts), repeated among the asked ones."""
    rng = np.random.default_rng(seed)
    states = [
        FusionState(
            FusionConfig(implementation=impl), 2, ModelSet.from_config(FusionConfig().plot_filter)
        )
        for impl in ("compiled", "numpy")
    ]
    live = rng.choice(100, alive, replace=False)
    address, code = rng.integers(-1, 6, 100), rng.integers(-1, 6, 100)
    for state in states:
        state.sys["alive"][live] = True
        state.sys["address"][:100], state.sys["mode3a"][:100] = address, code
    asked = rng.integers(-1, 8, k), rng.integers(-1, 8, k)
    got, want = (lifecycle._identities_in_use(state, *asked) for state in states)
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=40, deadline=None)
@given(seed=SEEDS, batches=st.integers(1, 30))
def test_pair_evidence_update_is_the_reference(seed: int, batches: int) -> None:
    """The exchange test's running means read, averaged and written by one kernel call
    against the numpy path: the same evidence to the bit, batch after batch of pairs
    drawn from few keys, tested keys among them and not."""
    rng = np.random.default_rng(seed)
    stores = [PairEvidence(compiled) for compiled in (True, False)]
    for _ in range(batches):
        k = int(rng.integers(0, 8))
        a, b = rng.integers(0, 10, k), rng.integers(0, 10, k)
        low, high = np.minimum(a, b), np.maximum(a, b)
        tested = rng.integers(0, 10, int(rng.integers(0, 4)))
        deltas, favoured = rng.normal(0.0, 5.0, k), rng.uniform(size=k) < 0.7
        got, want = (s.update(tested, low, high, deltas, favoured, 4) for s in stores)
        assert got.tobytes() == want.tobytes()
        if rng.uniform() < 0.3:
            dropped = rng.integers(0, 10, 2)
            for s in stores:
                s.drop(dropped)


@settings(max_examples=25, deadline=None)
@given(seed=SEEDS, k=SIZES, n_radars=st.integers(1, 4))
def test_review_tests_are_the_reference(seed: int, k: int, n_radars: int) -> None:
    """The review's gate and consistency tests by one kernel call: the same rows lost,
    the same counts of updates out of the gate and running means written, for local
    tracks near and far from their system tracks, solo ones among them, with counts
    and means about their thresholds."""
    compiled, reference, rng = _states(seed, n_radars, k)
    reference.local = copy.deepcopy(compiled.local)
    held = np.sort(rng.choice(k, int(rng.integers(1, k + 1)), replace=False))
    systems = rng.integers(1, k + 1, held.size)
    near = rng.uniform(size=held.size) < 0.5
    x = compiled.sys["moments"][systems[near], :4] + rng.normal(0, 50, (int(near.sum()), 4))
    fails, nis_n = rng.integers(0, 3, held.size), rng.integers(0, 7, held.size)
    nis_mean = rng.uniform(0.0, 30.0, held.size)
    solo = rng.uniform(size=k + 1) < 0.3
    for state in (compiled, reference):
        loc = state.local.rows
        loc["system"][held] = systems
        compiled.local.relink()
        loc["x"][held[near]] = x
        loc["fails"][held], loc["nis_n"][held], loc["nis_mean"][held] = fails, nis_n, nis_mean
        state.sys["solo"][: k + 1] = solo
    estimator = estimator_plots.PlotFilterEstimator()
    got = associate._tests(compiled, estimator, held)
    want = associate._tests(reference, estimator, held)
    np.testing.assert_array_equal(want, got)
    for name in ("fails", "nis_n"):
        np.testing.assert_array_equal(reference.local.rows[name], compiled.local.rows[name])
    close(reference.local.rows["nis_mean"], compiled.local.rows["nis_mean"])


@settings(max_examples=50, deadline=None)
@given(seed=SEEDS, k=st.integers(0, 40), n_plots=st.integers(0, 30))
def test_plotted_updates_are_the_reference(seed: int, k: int, n_plots: int) -> None:
    """The plot filter's choice of a batch's updates by the kernel: the same updates,
    system tracks, plot rows (repeated plot ids: the first), rounds and count of
    unknown plot ids, for rows feeding no system track, created ones and others."""
    compiled, reference, rng = _states(seed, 2, 12)
    rows_of = rng.integers(0, 12, k)
    system = rng.integers(0, 6, 12)
    for state in (compiled, reference):
        state.local.rows["system"][:12] = system
        state.local.relink()
    u = _local_updates(rng, k)
    u["plot_id"] = rng.integers(0, 25, k)
    p = np.zeros(n_plots, dtype=PLOT_DTYPE)
    p["plot_id"] = rng.integers(0, 25, n_plots)
    plots = as_plot_arrays(p)
    has_plot = rng.uniform(size=k) < 0.7
    created = rng.choice(np.arange(1, 6), int(rng.integers(0, 3)), replace=False)
    got, want = (
        estimator_plots._plotted_updates(state, rows_of, u, has_plot, plots, created)
        for state in (compiled, reference)
    )
    for a, b in zip(want, got, strict=True):
        np.testing.assert_array_equal(a, b)


@settings(max_examples=25, deadline=None)
@given(
    seed=SEEDS,
    founders=st.integers(0, 12),
    live=st.integers(0, 40),
    size=st.sampled_from([8, 20, 64]),
    carries_bias=st.booleans(),
)
def test_founding_is_the_reference(
    seed: int, founders: int, live: int, size: int, carries_bias: bool
) -> None:
    """``lifecycle.create`` by its kernels (``due_numbers``, ``found_system_tracks``)
    against the numpy path: the same numbers (free and due, then, when they run short,
    within their delay, or none left), every field of both tables the same bits, the
    same counts; founders with model probabilities and without, freed times in the
    future and NaN among them, on small tables so that numbers run short."""
    rng = np.random.default_rng(seed)
    models = ModelSet.from_config(FusionConfig().plot_filter)
    n_radars = 3
    states = [
        FusionState(FusionConfig(implementation=impl, number_reuse_delay_s=30.0), n_radars, models)
        for impl in ("compiled", "numpy")
    ]
    compiled = states[0]
    full = compiled.sys
    sys = compiled.sys = Columns(full.dtype, {name: full[name][:size].copy() for name in full})
    sys["alive"][1:] = rng.uniform(size=size - 1) < live / 40
    sys["freed_at"][1:] = rng.choice([-np.inf, 10.0, 80.0, 120.0, np.nan], size - 1)
    local = compiled.local
    k = max(founders, 1)
    rows_ = local.find(int(rng.integers(0, n_radars)), _local_updates(rng, k), create=True)
    loc = local.rows
    loc["radar"][rows_] = rng.integers(0, n_radars, k)
    loc["t"][rows_] = rng.uniform(0.0, 100.0, k)
    loc["x"][rows_] = rng.normal(0.0, 1e4, (k, 4))
    loc["P"][rows_] = _spd(rng, (k,), np.array([100.0, 100.0, 8.0, 8.0]))
    loc["extra"][rows_] = _spd(rng, (k,), np.array([40.0, 40.0]))
    loc["t_plot"][rows_] = rng.uniform(0.0, 100.0, k)
    loc["address"][rows_] = rng.integers(-1, 5, k)
    loc["mode3a"][rows_] = rng.integers(-1, 5, k)
    loc["mu"][rows_] = np.where(
        rng.uniform(size=(k, 1)) < 0.5, rng.dirichlet(np.ones(models.n_models), k), 0.0
    )
    loc["fails"][rows_] = 3
    loc["nis_n"][rows_] = 4
    loc["t_founder"][rows_] = 1.0
    reference = states[1]
    reference.sys = Columns(sys.dtype, {name: sys[name].copy() for name in sys})
    reference.local = copy.deepcopy(local)
    estimator: SystemEstimator = (
        estimator_plots.PlotFilterEstimator() if carries_bias else TrackFusionEstimator()
    )
    for state in states:
        state.now = 100.0
    got, want = (
        lifecycle.create(state, estimator, rows_[:founders]) for state in (compiled, reference)
    )
    np.testing.assert_array_equal(got, want)
    # The pre-selection's terms (``nearby.refresh``) only the compiled path keeps.
    for name in set(sys) - {"moments", "sensitivity", "largest_bias"}:
        np.testing.assert_array_equal(compiled.sys[name], reference.sys[name], err_msg=name)
    for name in local.rows:
        np.testing.assert_array_equal(
            compiled.local.rows[name], reference.local.rows[name], err_msg=name
        )
    assert dataclasses.asdict(compiled.stats) == dataclasses.asdict(reference.stats)
