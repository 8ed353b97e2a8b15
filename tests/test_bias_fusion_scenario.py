"""Bias estimation and fusion on the shipped `three_sites` scenario with its systematic
errors on, measured by `evaluate` against the truth: the targets of issue 5, and the
same scenario without bias estimation clearly worse."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.conftest import REPO
from tracker_service.bias import BiasConfig
from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.metrics import nees_in_window
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

# The whole of three_sites (15 minutes, with its biases) through the chain, evaluated twice.
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("three_sites") / "three_sites.mcap"
    simulate(load_scenario(REPO / "config" / "scenarios" / "three_sites.toml"), out)
    return out


@pytest.fixture(scope="module")
def estimated(recording: Path) -> dict[str, Any]:
    return evaluate(recording).as_json()


def test_bias_estimates_meet_the_targets(estimated: dict[str, Any]) -> None:
    assert set(estimated["bias"]) == {"25/11", "25/12", "25/13"}
    for radar, bias in estimated["bias"].items():
        azimuth = bias["azimuth_deg"]
        assert abs(azimuth["estimate"] - azimuth["truth"]) <= 0.01, radar
        offset = bias["range_offset_m"]
        error = abs(offset["estimate"] - offset["truth"])
        assert error <= 15.0, radar
        assert error <= 3.0 * offset["sigma"], radar
        # Against the ADS-B reference (the scenario has an ADS-B station).
        clock = bias["time_s"]
        assert abs(clock["estimate"] - clock["truth"]) <= 0.030, radar


def test_system_tracks_meet_the_targets(estimated: dict[str, Any]) -> None:
    multi = estimated["system_by_coverage"]["multi"]
    single = estimated["system_by_coverage"]["single"]
    assert multi["position_rms_m"] <= 100.0
    assert estimated["fusion"]["rms_ratio_to_best_local"] <= 0.7
    assert single["position_rms_m"] <= 300.0
    # Single coverage here is Mosnik's alone (the aircraft east of it).
    assert single["position_rms_m"] <= estimated["local"]["25/11"]["position_rms_m"]
    system = estimated["system"]
    assert system["probability_of_update"] >= 0.99
    assert system["probability_of_update_10s"] >= 0.99
    assert system["tracks_per_aircraft"] <= 1.02
    # Coasting updates are scored beside the plot updates, and worse than them.
    assert system["coasting_updates"] > 0
    assert system["position_rms_with_coasting_m"] >= system["position_rms_m"]
    assert system["position_max_m"] >= system["position_p95_m"] >= 0.0
    # At their own updates the local tracks are better than extrapolated: a larger ratio.
    fusion = estimated["fusion"]
    assert fusion["rms_ratio_to_best_local_own_updates"] >= fusion["rms_ratio_to_best_local"]


@pytest.mark.xfail(
    strict=True,
    reason="issue 14's window 0.8-1.25 x dof: the system NEES is 1.44 on this seed (1.43-1.99 "
    "on four unseen seeds, 3.44 on the fifth): mostly under-confident; docs/fusion.md 'Evaluation'",
)
def test_system_nees_in_the_target_window(estimated: dict[str, Any]) -> None:
    system = estimated["system"]
    assert nees_in_window(system["nees_mean"], system["nees_dof"])


def test_without_bias_estimation_it_is_clearly_worse(
    recording: Path, estimated: dict[str, Any]
) -> None:
    plain = evaluate(recording, EvaluationConfig(bias=BiasConfig(method="off"))).as_json()
    with_bias = estimated["system_by_coverage"]["multi"]["position_rms_m"]
    assert plain["system_by_coverage"]["multi"]["position_rms_m"] > 3.0 * with_bias
    assert plain["system"]["tracks_per_aircraft"] > 1.5
