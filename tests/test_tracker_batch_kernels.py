"""The local tracker's compiled per-batch passes (``kernels.record_pairs``,
``finish_pairs`` and the clutter map asked once per batch) against the same compiled
tracker without them (``LocalTracker._apply`` and the clutter map asked at each step, as
the numpy reference does): the same output rows and the same track table, to the bit,
under GNN and MHT, with primary-only plots, clutter, Mode S, Mode C and codes."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from tests.test_tracking_kernels import sector_stream
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.tracking.imm import ImmPrediction
from tracker_service.tracking.plots import IntArray, PlotArrays


class StepByStep(LocalTracker):
    """The compiled tracker without its per-batch passes."""

    def _batch_plots(self, p: PlotArrays) -> Any:
        return None

    def _apply_pairs(
        self, ti: IntArray, p: PlotArrays, plot_index: IntArray, pred: ImmPrediction, sel: IntArray
    ) -> npt.NDArray[Any]:
        return self._apply(ti, p.take(plot_index), pred.take(sel))


def mixed_stream(seed: int) -> list[npt.NDArray[np.void]]:
    """``sector_stream`` with codes, a third of the targets primary-only, and a persistent
    clutter source near the site (a cell the clutter map learns to call dense)."""
    rng = np.random.default_rng(seed)
    batches = []
    for batch in sector_stream(seed, 40, 14):
        batch = batch.copy()
        primary = batch["plot_id"] % 3 == 0
        batch["typ"][primary] = 1
        batch["address"][primary] = -1
        batch["fl_valid"][primary] = False
        coded = ~primary & (batch["plot_id"] % 3 == 1)
        batch["mode3a"][coded] = 0o1000 + batch["plot_id"][coded] % 40
        batch["mode3a_valid"][coded] = True
        if len(batch) == 0:
            continue
        clutter = batch[[0, 0]].copy()
        clutter["plot_id"][1] += 20_000_000
        clutter["x"] = 3000.0 + rng.normal(0, 100.0, 2)
        clutter["y"] = 2000.0 + rng.normal(0, 100.0, 2)
        clutter["typ"], clutter["address"], clutter["mode3a"] = 1, -1, -1
        clutter["fl_valid"] = False
        clutter["plot_id"] += 10_000_000
        joined = np.concatenate([batch, clutter])
        batches.append(joined[np.argsort(joined["time"], kind="stable")])
    return batches


@pytest.mark.parametrize("association", ["gnn", "mht"])
def test_batch_passes_change_nothing(association: str) -> None:
    config = TrackerConfig(scan_period_s=5.0, association=association)
    fused, reference = LocalTracker(config), StepByStep(config)
    rows = 0
    for batch in mixed_stream(3):
        a, b = reference.process(batch), fused.process(batch)
        assert a.tobytes() == b.tobytes()
        rows += len(a)
    assert rows > 400
    expected, tracks = reference.tracks, fused.tracks
    assert expected.tobytes() == tracks.tobytes()
    assert reference.stats == fused.stats
    assert reference.clutter is not None and fused.clutter is not None
    np.testing.assert_array_equal(reference.clutter.counts, fused.clutter.counts)
    # The stream went through every branch: confirmations, primary-only tracks held
    # back, dense clutter cells.
    assert (tracks["status"] == 1).sum() >= 20
    assert ((tracks["address"] < 0) & (tracks["mode3a"] < 0)).any()
    assert fused.clutter.dense(np.array([3000.0]), np.array([2000.0])).all()
