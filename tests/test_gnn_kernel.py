"""GNN's compiled assignment (``association.kernels.gnn_assignment``) against the numpy
reference (``associate.global_nearest_neighbour``, scipy's solver): the same pairs, ties
included, on square and rectangular problems of either shape."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.tracking.associate import UNASSIGNABLE, global_nearest_neighbour
from tracker_service.tracking.association.kernels import gnn_assignment


@pytest.mark.parametrize("shape", [(1, 1), (3, 3), (2, 6), (7, 2), (12, 9), (30, 30)])
def test_gnn_assignment_is_scipys(shape: tuple[int, int]) -> None:
    for seed in range(40):
        rng = np.random.default_rng(seed)
        density = rng.uniform(0.2, 1.0)
        keep = rng.random(shape) < density
        rows, cols = np.nonzero(keep)
        order = rng.permutation(rows.size)  # pairs come in any order
        rows, cols = rows[order] * 3 + 1, cols[order] * 2  # and with gaps in the indices
        if seed % 2:
            cost = rng.integers(-3, 3, rows.size).astype(np.float64)  # many ties
        else:
            cost = rng.normal(0.0, 5.0, rows.size)
        expected = global_nearest_neighbour(rows, cols, cost)
        np.testing.assert_array_equal(gnn_assignment(rows, cols, cost, UNASSIGNABLE), expected)


def test_gnn_assignment_without_pairs() -> None:
    none = np.zeros(0, dtype=np.int64)
    assert gnn_assignment(none, none, np.zeros(0), UNASSIGNABLE).size == 0
