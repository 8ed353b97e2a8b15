"""The system-track estimator behind one protocol, chosen by ``FusionConfig.method``:
"tracks" (``estimator_tracks``: ML fusion of the local tracks at the output time) or
"plots" (``estimator_plots``: an IMM per system track updated by its local tracks' plots,
the residual biases considered)."""

from __future__ import annotations

from typing import Any, Protocol

import numpy.typing as npt

from tracker_service.fusion.estimator_plots import PlotFilterEstimator
from tracker_service.fusion.estimator_tracks import TrackFusionEstimator
from tracker_service.fusion.state import FusionState
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, PlotArrays


class SystemEstimator(Protocol):
    founder_carries_bias: bool
    """A new system track's sensitivity to its founder's radar bias is [I; 0] (the
    residual bias considered apart from P) rather than 0 (inside P)."""

    def gate_prediction(
        self, state: FusionState, numbers: IntArray, dt: FloatArray
    ) -> tuple[FloatArray, FloatArray, FloatArray]:
        """System tracks ``numbers`` predicted over dt for the association gate: states
        (k, 4), covariances (k, 4, 4), bias sensitivities (k, radars, 4, 2)."""
        ...

    coarse_from_models: bool
    """The state ``gate_prediction`` starts from, for the pre-selection of the pairs it
    may pass (``nearby.system_reach``): the combination of the system table's IMM models
    (mx, mP, mu) rather than its x and P."""

    def absorb(
        self,
        state: FusionState,
        radar: int,
        rows: IntArray,
        u: npt.NDArray[Any],
        extra: FloatArray,
        has_plot: BoolArray,
        plots: PlotArrays,
        created: IntArray,
    ) -> None:
        """Take in a batch of local updates (local-table ``rows``) once associated;
        ``created``: the system tracks the batch founded."""
        ...

    def output(
        self,
        state: FusionState,
        numbers: IntArray,
        t: FloatArray,
        slots: IntArray,
        latest: npt.NDArray[Any],
    ) -> tuple[FloatArray, FloatArray]:
        """State (k, 4) and reported covariance (k, 4, 4) of system tracks ``numbers``
        (distinct) at times t, fed by local rows ``slots``; ``latest``: the batch's
        latest local update of each."""
        ...


def make_system_estimator(method: str) -> SystemEstimator:
    """The estimator ``FusionConfig.method`` names."""
    return _ESTIMATORS[method]()


_ESTIMATORS: dict[str, type[SystemEstimator]] = {
    "tracks": TrackFusionEstimator,
    "plots": PlotFilterEstimator,
}
