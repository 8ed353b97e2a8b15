"""Mode S DAPs through the chain: an EHS radar's registers every scan reach the tracker's
plots (with their flags), the plot table and the system-track messages."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from tracker_service.evaluation.pipeline import run_pipeline
from tracker_service.outputs.mapping import MessageMapper
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario
from tracker_service.tracking.plots import PUBLISHED_DAP_FIELDS

REPO = Path(__file__).resolve().parent.parent


def _scenario(registers: str) -> Scenario:
    data = tomllib.loads((REPO / "config/scenarios/turns.toml").read_text())
    data["radars"][0]["ehs_registers"] = registers
    data["traffic"]["count"] = 3
    return Scenario.model_validate(data)


@pytest.fixture(scope="module")
def ehs_recording(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("daps") / "ehs.mcap"
    simulate(_scenario("every_scan"), out, duration_s=60.0)
    return out


def test_every_scan_registers_reach_plots_and_system_messages(ehs_recording: Path) -> None:
    result = run_pipeline(ehs_recording)
    (radar,) = result.radars.values()
    plots = radar.plots
    aircraft = plots[plots["aircraft"] >= 0]
    assert len(aircraft) > 20
    # Every Mode S plot carries all three registers.
    assert aircraft["has_daps"].all()
    for name in PUBLISHED_DAP_FIELDS:
        assert np.isfinite(aircraft[name]).all(), name
    assert not aircraft["implausible_daps"].any()
    mapper = MessageMapper(result.plane)
    updates = mapper.system_updates(result.system, plots, tuple(result.radars))
    named = [u.doc["daps"] for u in updates if u.doc["daps"]]
    assert named and [d["name"] for d in named[-1]] == list(PUBLISHED_DAP_FIELDS)
    assert all(d["age_s"] >= 0.0 for d in named[-1])


def test_the_rotating_schedule_sends_one_register_a_scan(tmp_path: Path) -> None:
    out = tmp_path / "rotating.mcap"
    simulate(_scenario("rotating"), out, duration_s=30.0)
    plots = run_pipeline(out).radars.popitem()[1].plots
    aircraft = plots[plots["aircraft"] >= 0]
    speed = np.isfinite(aircraft["ground_speed_kt"])
    heading = np.isfinite(aircraft["magnetic_heading_deg"])
    selected = np.isfinite(aircraft["selected_altitude_ft"])
    assert speed.any() and heading.any() and selected.any()
    assert not (speed & heading).any() and not (speed & selected).any()
