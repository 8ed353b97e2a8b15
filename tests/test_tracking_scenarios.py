"""The local trackers on the shipped scenarios, without systematic errors, measured by
`evaluate` against the truth: the targets of issue 4."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pytest

from tests.conftest import REPO
from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.metrics import nees_in_window
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

SCENARIOS = REPO / "config" / "scenarios"


def _local(name: str, tmp_path: Path) -> dict[str, dict[str, Any]]:
    out = tmp_path / f"{name}.mcap"
    simulate(load_scenario(SCENARIOS / f"{name}.toml"), out, no_bias=True)
    return evaluate(out).as_json()


@pytest.fixture(scope="module")
def three_sites(tmp_path_factory: pytest.TempPathFactory) -> dict[str, dict[str, Any]]:
    return _local("three_sites", tmp_path_factory.mktemp("three_sites"))


@pytest.mark.slow
def test_crossings_keep_every_identity(tmp_path: Path) -> None:
    metrics = _local("crossings", tmp_path)
    for radar, local in metrics["local"].items():
        assert local["id_changes"] == 0, radar
        assert local["tracks_per_aircraft"] <= 1.05, radar
        assert local["false_tracks"] == 0, radar


@pytest.mark.slow
def test_three_sites_targets_met(three_sites: dict[str, dict[str, Any]]) -> None:
    for radar, local in three_sites["local"].items():
        ratio = local["position_rms_m"] / three_sites["plots"][radar]["position_rms_m"]
        assert ratio <= 0.6, radar
        assert local["probability_of_update"] >= 0.97, radar
        assert local["tracks_per_aircraft"] <= 1.05, radar
        assert local["false_track_max_scans"] <= 3, radar
        assert local["id_changes"] == 0, radar


@pytest.mark.slow
def test_three_sites_local_nees_in_the_window(three_sites: dict[str, dict[str, Any]]) -> None:
    for radar, local in three_sites["local"].items():
        assert nees_in_window(local["nees_mean"], local["nees_dof"]), radar
