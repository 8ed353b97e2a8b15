"""The separated bias filter's compiled gate against its numpy reference, and its sorted
copy of the observations without the contributors."""

from __future__ import annotations

import numpy as np
import pytest

from tracker_service.bias import make_observations
from tracker_service.bias.kernels import gate_statistics
from tracker_service.bias.separated import gate_statistics_reference


def _spd(rng: np.random.Generator, n: int, size: int, scale: float) -> np.ndarray:
    a = rng.normal(size=(n, size, size)) * scale
    return a @ np.swapaxes(a, -1, -2) + np.eye(size) * scale**2 * 0.1


@pytest.mark.parametrize("extra", [0, 2])
def test_gate_statistics_match_numpy(extra: int) -> None:
    rng = np.random.default_rng(7 + extra)
    for n in (0, 1, 3, 40):
        C = rng.normal(size=(n, 2, 4)) * np.array([1.0, 3.0, 200.0, 0.5])
        P = _spd(rng, 1, 4 + extra, 0.3)[0]
        noise = _spd(rng, n, 2, 60.0)
        nu = rng.normal(size=(n, 2)) * 150.0
        compiled = gate_statistics(C, P, noise, nu)
        reference = gate_statistics_reference(C, P, noise, nu)
        assert compiled.shape == (n,)
        np.testing.assert_allclose(compiled, reference, rtol=1e-9, atol=0.0)


def test_subset_without_contributors_keeps_the_rows() -> None:
    rng = np.random.default_rng(3)
    n, radars = 5, 3
    obs = make_observations(
        radars,
        np.full(n, 1),
        rng.uniform(size=n),
        rng.normal(size=(n, 2)),
        np.broadcast_to(np.eye(2), (n, 2, 2)),
        rng.normal(size=(n, 2, 4)),
        rng.normal(size=(n, 2)),
        np.broadcast_to(np.eye(2), (n, 2, 2)),
        contributors=np.ones((n, radars), dtype=bool),
        contributor_C=np.ones((n, radars, 2, 4)),
    )
    order = np.array([4, 0, 2])
    scale = np.array([2.0, 1.0, 0.5, 1.0])
    full = obs.subset(order, scale_c=scale)
    rows = obs.subset(order, scale_c=scale, contributors=False)
    for name in obs.__dataclass_fields__:
        assert getattr(rows, name).shape == getattr(full, name).shape, name
        if not name.startswith("contributor"):
            np.testing.assert_array_equal(getattr(rows, name), getattr(full, name))
    assert not rows.contributors.any() and not rows.contributor_C.any()
    assert not rows.contributor_R.flags.writeable
