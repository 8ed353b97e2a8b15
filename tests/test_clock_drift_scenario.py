"""clock_drift.toml through the whole chain for 3 minutes: the CAT034 stamps reach the bias
estimator through the radar stage and the stage messages, and pin each radar's drift
(docs/fusion.md "Clock drift")."""

from __future__ import annotations

from pathlib import Path

import pytest

from tracker_service.bias import BiasConfig
from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

SCENARIO = Path(__file__).resolve().parents[1] / "config" / "scenarios" / "clock_drift.toml"


@pytest.mark.slow
def test_drifts_from_the_stamps_in_three_minutes(tmp_path: Path) -> None:
    recording = tmp_path / "clock.mcap"
    simulate(load_scenario(SCENARIO), recording, seed=11, duration_s=180.0)
    doc = evaluate(recording, EvaluationConfig(bias=BiasConfig(clock_states=2))).as_json()
    truth = {"25/11": 0.5, "25/12": -0.3, "25/13": 1.0}
    for source, expected in truth.items():
        drift = doc["bias"][source]["time_drift_s_per_h"]
        assert drift["truth"] == pytest.approx(expected, abs=1e-6)
        error = drift["estimate"] - expected
        # ADS-B alone gives about 1 s/h of sigma in three minutes; the stamps about 0.1.
        assert drift["sigma"] < 0.12, source
        assert abs(error) <= 3.0 * drift["sigma"], source
    assert abs(doc["bias"]["25/13"]["time_drift_s_per_h"]["estimate"] - 1.0) <= 0.1
