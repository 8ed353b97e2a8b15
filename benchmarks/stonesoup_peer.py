"""Stone Soup's multi-target tracker over a plot stream (run by bench_stonesoup.py in the
Stone Soup venv, ``python -I``, so that nothing of this repository is imported).

    benchmarks/.venvs/stonesoup/bin/python -I benchmarks/stonesoup_peer.py STREAM.npz \
        PERIOD_S REPEATS

STREAM.npz holds per plot ``time`` (POSIX s), ``x``, ``y`` (m), ``R`` (2x2, m^2) and
``batch`` (the sector it came in). The tracker is Stone Soup 1.9.1's
``MultiTargetTracker`` with a Kalman filter on a constant-velocity model (per axis,
the same white-acceleration intensity as our CV model), each plot with its own
measurement covariance, global nearest neighbour (``GNNWith2DAssignment`` over a
``DistanceHypothesiser`` on the Mahalanobis distance, gate 3.5 sigma), a two-point
initiator (``MultiMeasurementInitiator``, min_points=2, the same gate) and a deleter
on the time since the last update (2.5 antenna periods). One step per sector.
Detections are built before the clock starts; only the tracker's steps are timed (CPU
seconds, ``time.process_time``).
Prints one JSON object: seconds per repeat, plots, tracks at the end.
"""

from __future__ import annotations

import datetime
import json
import sys
import time

import numpy as np
from stonesoup.dataassociator.neighbour import GNNWith2DAssignment
from stonesoup.deleter.time import UpdateTimeDeleter
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.initiator.simple import MultiMeasurementInitiator
from stonesoup.measures import Mahalanobis
from stonesoup.models.measurement.linear import LinearGaussian
from stonesoup.models.transition.linear import (
    CombinedLinearGaussianTransitionModel,
    ConstantVelocity,
)
from stonesoup.predictor.kalman import KalmanPredictor
from stonesoup.tracker.simple import MultiTargetTracker
from stonesoup.types.detection import Detection
from stonesoup.types.state import GaussianState
from stonesoup.updater.kalman import KalmanUpdater

Q_CV = 0.02
"""m^2/s^3, our TrackerConfig.q_cv."""
GATE_SIGMAS = 3.5
"""Mahalanobis distance: 3.5^2 = 12.25, near our 2-dof gate (TrackerConfig.gate)."""
VELOCITY_PRIOR_M_S = 300.0


def steps(stream: dict[str, np.ndarray]) -> list[tuple[datetime.datetime, set[Detection]]]:
    """One (time, detections) per sector, each detection with its own R."""
    out = []
    utc = datetime.UTC
    for b in np.unique(stream["batch"]):
        rows = np.flatnonzero(stream["batch"] == b)
        detections = set()
        for i in rows:
            model = LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=stream["R"][i])
            stamp = datetime.datetime.fromtimestamp(float(stream["time"][i]), utc)
            detections.add(
                Detection(
                    np.array([[stream["x"][i]], [stream["y"][i]]]),
                    timestamp=stamp,
                    measurement_model=model,
                )
            )
        last = datetime.datetime.fromtimestamp(float(stream["time"][rows].max()), utc)
        out.append((last, detections))
    return out


def tracker(
    period_s: float, sectors: list[tuple[datetime.datetime, set[Detection]]]
) -> MultiTargetTracker:
    transition = CombinedLinearGaussianTransitionModel(
        [ConstantVelocity(Q_CV), ConstantVelocity(Q_CV)]
    )
    predictor = KalmanPredictor(transition)
    # The updater's own model is a stand-in: every detection brings its R.
    updater = KalmanUpdater(LinearGaussian(ndim_state=4, mapping=(0, 2), noise_covar=np.eye(2)))
    hypothesiser = DistanceHypothesiser(
        predictor, updater, measure=Mahalanobis(), missed_distance=GATE_SIGMAS
    )
    associator = GNNWith2DAssignment(hypothesiser)
    deleter = UpdateTimeDeleter(datetime.timedelta(seconds=2.5 * period_s))
    prior = GaussianState(
        np.zeros((4, 1)),
        np.diag([0.0, VELOCITY_PRIOR_M_S**2, 0.0, VELOCITY_PRIOR_M_S**2]),
    )
    initiator = MultiMeasurementInitiator(
        prior, deleter, GNNWith2DAssignment(hypothesiser), updater, min_points=2
    )
    return MultiTargetTracker(initiator, deleter, sectors, associator, updater)


def main() -> None:
    path, period_s, repeats = sys.argv[1], float(sys.argv[2]), int(sys.argv[3])
    with np.load(path) as data:
        stream = {name: data[name] for name in data.files}
    seconds = []
    tracks = 0
    for _ in range(repeats):
        sectors = steps(stream)
        run = tracker(period_s, sectors)
        started = time.process_time()
        for _step in run:
            pass
        seconds.append(time.process_time() - started)
        tracks = len(run.tracks)
    json.dump({"seconds": seconds, "plots": int(stream["time"].size), "tracks": tracks}, sys.stdout)


if __name__ == "__main__":
    main()
