"""The fuser's spatial pre-selection (fusion/nearby.py) keeps every pair its gates pass:
checked against the exhaustive pairs at every batch of three radars' synthetic traffic,
with residual biases large enough to matter."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_fusion import AIRCRAFT, RADARS, build
from tracker_service.fusion import FusionConfig, SystemTracker, associate, lifecycle, nearby
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.tracking.plots import FloatArray, IntArray


def _all_pairs(
    xy_a: FloatArray,
    radius_a: FloatArray,
    xy_b: FloatArray,
    radius_b: FloatArray,
    compiled: bool = False,
) -> tuple[IntArray, IntArray]:
    i, j = np.meshgrid(np.arange(len(xy_a)), np.arange(len(xy_b)), indexing="ij")
    return i.reshape(-1), j.reshape(-1)


@pytest.mark.parametrize("method", ["plots", "tracks"])
def test_preselection_keeps_every_gated_pair(method: str, monkeypatch: pytest.MonkeyPatch) -> None:
    scenario = build(AIRCRAFT, RADARS, seed=5)
    trackers = [LocalTracker(TrackerConfig(scan_period_s=r.period)) for r in RADARS]
    # A wide gate makes many pairs pass: the bound is tested where it is tight.
    fuser = SystemTracker(len(RADARS), FusionConfig(method=method, gate=200.0))
    state, estimator = fuser.state, fuser.estimator
    rng = np.random.default_rng(1)
    checked_local = checked_merge = 0
    for radar, plots in scenario.batches:
        updates = trackers[radar].process(plots)
        side = rng.uniform(50.0, 400.0, len(updates))
        extra = np.einsum("k,ab->kab", side**2, np.eye(2))
        fuser.process(radar, updates, plots, extra)
        loc = state.local.used
        free = np.flatnonzero(loc["alive"] & np.isfinite(loc["t"]))
        systems = np.flatnonzero(state.sys["alive"])
        systems = systems[systems > 0]
        if free.size == 0 or systems.size == 0:
            continue
        li, sj = associate._near(state, estimator, free, systems)
        everything = (np.repeat(free, systems.size), np.tile(systems, free.size))
        d2 = associate.distance(state, estimator, *everything)
        passed = d2 <= state.config.gate
        near = set(zip(li.tolist(), sj.tolist(), strict=True))
        wanted = set(
            zip(everything[0][passed].tolist(), everything[1][passed].tolist(), strict=True)
        )
        assert wanted <= near
        checked_local += len(wanted)
        a, b, d2 = lifecycle._merge_tests(state, systems)
        kept = set(
            zip(
                a[d2 <= state.config.gate].tolist(),
                b[d2 <= state.config.gate].tolist(),
                strict=True,
            )
        )
        with monkeypatch.context() as patch:
            # Every pair near, by the numpy path (the compiled one is one kernel).
            patch.setattr(type(state), "compiled", property(lambda _: False))
            patch.setattr(nearby, "near_pairs", _all_pairs)
            a, b, d2 = lifecycle._merge_tests(state, systems)
        exhaustive = set(
            zip(
                a[d2 <= state.config.gate].tolist(),
                b[d2 <= state.config.gate].tolist(),
                strict=True,
            )
        )
        assert exhaustive == kept
        checked_merge += len(exhaustive)
    assert checked_local > 1000
