"""The compiled gate (``association.gate_kernels``) against the numpy reference (``Gate``
with ``implementation = "numpy"``): the same pairs in the same order, every value to the
bit. Both gates predict with the compiled IMM, so that only the gate's own steps are
compared (the IMM kernels are held to the textbook equations by test_tracking_kernels)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from scipy.spatial import cKDTree

from tracker_service.tracking import PLOT_DTYPE, TrackerConfig
from tracker_service.tracking.association import Gate, GateResult
from tracker_service.tracking.association.gate import tree_port_follows_scipy
from tracker_service.tracking.association.gate_kernels import gate_pairs, kdtree_indices
from tracker_service.tracking.imm import make_imm
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import PlotArrays


def track_table(rng: np.random.Generator, n: int, models: ModelSet) -> dict[str, Any]:
    """n tracks over a 60 km square (clustered, so that boxes hold many), with the
    columns the gate reads."""
    m = models.n_models
    centre = rng.uniform(-30e3, 30e3, (n, 2))
    if n > 4:
        centre[: n // 4] = centre[0] + rng.normal(0, 500.0, (n // 4, 2))  # a dense knot
        centre[n // 4 + 1] = centre[n // 4]  # two tracks at one place
    x = np.empty((n, m, 4))
    x[..., :2] = centre[:, None, :] + rng.normal(0, 30.0, (n, m, 2))
    x[..., 2:] = rng.uniform(-250, 250, (n, 1, 2)) + rng.normal(0, 5.0, (n, m, 2))
    a = rng.normal(0, 1, (n, m, 4, 4)) * np.array([150.0, 150.0, 10.0, 10.0])[:, None]
    p = a @ np.swapaxes(a, -1, -2) + np.diag([100.0, 100.0, 1.0, 1.0])
    mu = rng.dirichlet(np.full(m, 0.5), n)
    xc = np.einsum("nm,nmi->ni", mu, x)
    pc = np.einsum("nm,nmij->nij", mu, p)
    address = np.where(rng.random(n) < 0.6, rng.integers(0, 40, n), -1)
    code = np.where(rng.random(n) < 0.6, rng.choice([0o1234, 0o7000, 0o4321, 0o2000], n), -1)
    return {
        "x": x,
        "P": p,
        "mu": mu,
        "xc": xc,
        "Pc": pc,
        "t": 1000.0 + rng.uniform(-6.0, 0.0, n),
        "address": address.astype(np.int64),
        "mode3a": code.astype(np.int64),
    }


def plot_batch(rng: np.random.Generator, cols: dict[str, Any], k: int) -> PlotArrays:
    """k plots near the tracks (some far, some older than the tracks)."""
    n = cols["t"].size
    rows = np.zeros(k, dtype=PLOT_DTYPE)
    source = rng.integers(0, n, k)
    dt = rng.uniform(0.0, 4.0, k)
    late = rng.random(k) < 0.1
    dt[late] = -rng.uniform(0.5, 20.0, late.sum())
    position = cols["xc"][source, :2] + cols["xc"][source, 2:] * dt[:, None]
    position += rng.normal(0, 150.0, (k, 2)) * np.where(rng.random(k) < 0.2, 30.0, 1.0)[:, None]
    if k > 3:
        position[1] = position[0]  # two plots at one place
    rows["time"] = cols["t"][source] + dt
    rows["x"], rows["y"] = position.T
    b = rng.normal(0, 1, (k, 2, 2)) * 80.0
    rows["R"] = b @ np.swapaxes(b, -1, -2) + np.eye(2) * 900.0
    rows["address"] = np.where(rng.random(k) < 0.5, cols["address"][source], -1)
    rows["address"][rng.random(k) < 0.1] = 7
    rows["mode3a"] = np.where(rng.random(k) < 0.7, cols["mode3a"][source], 0o7000)
    rows["mode3a_valid"] = rng.random(k) < 0.9
    rows["plot_id"] = np.arange(k)
    return PlotArrays(rows)


def gates(config: TrackerConfig) -> tuple[Gate, Gate]:
    """The numpy and the compiled gate, both predicting with the compiled IMM."""
    models = ModelSet.from_config(config)
    imm = make_imm("compiled", models)
    return (
        Gate(dataclasses.replace(config, implementation="numpy"), models, imm),
        Gate(dataclasses.replace(config, implementation="compiled"), models, imm),
    )


def assert_same(reference: GateResult, compiled: GateResult) -> None:
    np.testing.assert_array_equal(reference.too_old, compiled.too_old)
    if reference.pairs is None:
        assert compiled.pairs is None
        return
    assert compiled.pairs is not None
    a, b = reference.pairs, compiled.pairs
    for name in ("track", "plot", "nis", "log_det", "identity_cost"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)
    for name in ("x", "P", "c", "x_comb", "P_comb"):
        np.testing.assert_array_equal(getattr(a.pred, name), getattr(b.pred, name), err_msg=name)


@pytest.mark.parametrize("tracks", [1, 5, 16, 17, 40, 150])
@pytest.mark.parametrize("plots", [1, 7, 16, 17, 45])
def test_compiled_gate_is_the_reference(tracks: int, plots: int) -> None:
    config = TrackerConfig()
    numpy_gate, compiled_gate = gates(config)
    models = ModelSet.from_config(config)
    for seed in range(6):
        rng = np.random.default_rng(1000 * tracks + 10 * plots + seed)
        cols = track_table(rng, tracks, models)
        batch = plot_batch(rng, cols, plots)
        assert_same(numpy_gate(cols, tracks, batch), compiled_gate(cols, tracks, batch))


def test_compiled_gate_spare_rows_and_far_batch() -> None:
    """Rows past the live ones are ignored; a batch far from every track has no pair."""
    config = TrackerConfig()
    numpy_gate, compiled_gate = gates(config)
    rng = np.random.default_rng(5)
    cols = track_table(rng, 30, ModelSet.from_config(config))
    batch = plot_batch(rng, cols, 12)
    assert_same(numpy_gate(cols, 20, batch), compiled_gate(cols, 20, batch))
    far = PlotArrays(batch.rows.copy())
    far.rows["x"] += 1e6
    result = compiled_gate(cols, 30, far)
    assert result.pairs is None
    assert_same(numpy_gate(cols, 30, far), result)


def pair_order(a: npt.NDArray[np.float64], b: npt.NDArray[np.float64], reach: float) -> Any:
    """``gate_pairs``' (i, j) pairs of points a and b within reach (no prediction)."""
    na, nb = a.shape[0], b.shape[0]
    tree_a = cKDTree(a, leafsize=16).indices if na > 16 else np.zeros(0, np.int64)
    tree_b = cKDTree(b, leafsize=16).indices if nb > 16 else np.zeros(0, np.int64)
    m = 1
    _, ti, pj, *_ = gate_pairs(
        np.arange(na), a[:, 0].copy(), a[:, 1].copy(), np.full(na, reach), tree_a,
        b[:, 0].copy(), b[:, 1].copy(), np.zeros(nb), tree_b, reach, np.zeros(nb),
        np.tile(np.eye(2), (nb, 1, 1)), np.full(nb, -1), np.full(nb, -1), np.ones(nb, bool),
        np.zeros(na), np.zeros((na, m, 4)), np.tile(np.eye(4), (na, m, 1, 1)),
        np.ones((na, m)), np.full(na, -1), np.full(na, -1), np.zeros(m), np.zeros(m),
        np.ones(m), 1e9, 1e9, 1e9, False, np.zeros(0, np.int64), 0.0, 0.0, 0.0, False,
        np.zeros(nb, bool),
    )  # fmt: skip
    return ti, pj


@pytest.mark.parametrize("sizes", [(17, 17), (40, 100), (300, 33), (5, 200), (1000, 70)])
def test_pairs_in_the_order_of_scipys_search(sizes: tuple[int, int]) -> None:
    """Two trees of many leaves (and repeated points): scipy's dual-tree search order."""
    rng = np.random.default_rng(sizes[0] * sizes[1])
    a = np.round(rng.uniform(0, 100, (sizes[0], 2)))
    b = np.round(rng.uniform(0, 100, (sizes[1], 2)))
    a[: sizes[0] // 5] = a[0]  # a node of equal points: a leaf of more than 16
    for reach in (3.0, 15.0, 60.0):
        found = cKDTree(a, leafsize=16).sparse_distance_matrix(
            cKDTree(b, leafsize=16), reach, output_type="ndarray"
        )
        ti, pj = pair_order(a, b, reach)
        np.testing.assert_array_equal(ti, found["i"])
        np.testing.assert_array_equal(pj, found["j"])


def point_sets(rng: np.random.Generator, n: int, kind: int) -> npt.NDArray[np.float64]:
    """n points: spread, on a small grid (many equal values and points), on a line,
    repeated, sorted (an introselect's hard case)."""
    if kind == 0:
        return rng.normal(0.0, 1e5, (n, 2))
    if kind == 1:
        return rng.integers(0, 5, (n, 2)).astype(np.float64)
    if kind == 2:
        return np.column_stack([rng.normal(0.0, 1.0, n), np.zeros(n)])
    if kind == 3:
        points = np.repeat(rng.normal(0.0, 1.0, (n // 7 + 1, 2)), 7, axis=0)[:n]
        return points[rng.permutation(n)]
    return np.sort(rng.normal(0.0, 1.0, (n, 2)), axis=0)


def test_kdtree_indices_are_scipys() -> None:
    """The compiled balanced build gives scipy's leaf order, or says it cannot."""
    rng = np.random.default_rng(11)
    followed = fallen_back = 0
    for trial in range(3000):
        points = point_sets(rng, int(rng.integers(17, 300)), trial % 5)
        indices, ok = kdtree_indices(points[:, 0].copy(), points[:, 1].copy())
        if not ok:
            fallen_back += 1
            continue
        followed += 1
        np.testing.assert_array_equal(indices, cKDTree(points, leafsize=16).indices)
    assert fallen_back < 0.01 * followed
    assert fallen_back > 0  # the hard cases reach libstdc++'s heap selection
    assert tree_port_follows_scipy()  # the gate's own check agrees


def test_gate_with_scipys_trees_is_the_reference() -> None:
    """The gate's path for the trees the compiled build cannot follow (a batch's, or
    every batch's on a platform whose C++ library the build does not follow)."""
    config = TrackerConfig()
    numpy_gate, compiled_gate = gates(config)
    compiled_gate._tree_port = False
    models = ModelSet.from_config(config)
    for seed in range(6):
        rng = np.random.default_rng(seed)
        cols = track_table(rng, 150, models)
        batch = plot_batch(rng, cols, 45)
        assert_same(numpy_gate(cols, 150, batch), compiled_gate(cols, 150, batch))
