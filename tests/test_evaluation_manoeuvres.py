"""Turn onsets from the truth and the manoeuvre metrics (evaluation.manoeuvres)."""

from __future__ import annotations

import numpy as np
import pytest

from tests.test_evaluation import make_updates, origins_for
from tracker_service.evaluation.manoeuvres import manoeuvre_metrics, turns
from tracker_service.evaluation.metrics import local_metrics
from tracker_service.evaluation.pipeline import KIND_AIRCRAFT

SPEED = 200.0
ONSET = 100.4  # between truth snapshots
OMEGA = np.radians(-3.0)  # a right turn
TURN_END = 160.0


def turning_truth():  # type: ignore[no-untyped-def]
    """One aircraft: east, then from ONSET a 3 deg/s right turn until TURN_END, then
    straight; sampled at 1 Hz, exact on the circle."""
    from tracker_service.evaluation.metrics import Truth

    t = np.arange(0.0, 301.0)
    psi = np.where(t < ONSET, 0.0, OMEGA * (np.minimum(t, TURN_END) - ONSET))
    vx, vy = SPEED * np.cos(psi), SPEED * np.sin(psi)
    x = np.where(t < ONSET, SPEED * t, 0.0)
    y = np.zeros_like(t)
    turned = t >= ONSET
    r = SPEED / OMEGA
    tt = np.minimum(t, TURN_END) - ONSET
    x[turned] = SPEED * ONSET + r * np.sin(OMEGA * tt[turned])
    y[turned] = r * (1 - np.cos(OMEGA * tt[turned]))
    after = t > TURN_END
    x[after] += vx[after] * (t[after] - TURN_END)
    y[after] += vy[after] * (t[after] - TURN_END)
    col = lambda v: v[:, None]  # noqa: E731
    return Truth(t, col(x), col(y), col(vx), col(vy), col(np.full_like(t, 300.0)))


def test_the_onset_is_found_inside_its_snapshot_interval() -> None:
    found = turns(turning_truth())
    assert len(found) == 1
    assert found[0].onset == pytest.approx(ONSET, abs=0.05)
    assert found[0].sign == -1 and found[0].end == pytest.approx(TURN_END, abs=1.0)


def test_delay_is_the_first_update_showing_the_turn_the_right_way() -> None:
    truth = turning_truth()
    times = np.arange(2.0, 300.0, 5.0)
    updates = make_updates(truth, 1, 0, times, 0)
    rates = np.radians([0.0, 3.0, -3.0])  # make_updates holds three models
    mu = np.zeros((len(times), 3))
    mu[:, 0] = 1.0
    left = np.flatnonzero(rates > 0)[0]
    right = np.flatnonzero(rates < 0)[0]
    wrong_way = (times > ONSET) & (times < ONSET + 6)
    mu[wrong_way] = 0.0
    mu[wrong_way, left] = 1.0  # the wrong way does not count
    shown = (times >= ONSET + 6) & (times <= TURN_END)
    mu[shown] = 0.0
    mu[shown, right] = 1.0
    mu[times == 262.0] = 0.0
    mu[times == 262.0, left] = 1.0  # one false alarm in straight flight
    updates["model_probabilities"] = mu
    origins = origins_for(updates, 0, KIND_AIRCRAFT)
    local = local_metrics(updates, origins, truth, None)
    m = manoeuvre_metrics(updates, origins, truth, local, rates, 5.0)
    first_shown = float(times[shown][0])
    assert m.turn_onsets == 1 and m.missed_turns == 0
    assert m.detection_delay_mean_s == pytest.approx(first_shown - ONSET, abs=0.05)
    assert m.updates_in_turns == int(((times >= ONSET) & (times <= TURN_END)).sum())
    assert m.false_turn_alarm_rate is not None and 0.0 < m.false_turn_alarm_rate < 0.1
