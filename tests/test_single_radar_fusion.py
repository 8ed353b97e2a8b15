"""One radar alone with its biases and nothing to estimate them from (issue 10 finding 5):
`config/scenarios/single_biased.toml` (Mosnik of three_sites, no ADS-B, no field
monitor), shortened. The bias filter keeps its prior; the system tracks must be no worse
than the radar's own local tracks, and their covariance must hold the unknown bias."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tests.conftest import REPO, shared_file
from tracker_service.bias import BiasConfig
from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.real_data import NOMINAL_SITE_068, track_capture
from tracker_service.fusion import FusionConfig
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

DURATION_S = 200.0


@pytest.fixture(scope="module")
def metrics(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    out = tmp_path_factory.mktemp("single_biased") / "single_biased.mcap"
    scenario = load_scenario(REPO / "config" / "scenarios" / "single_biased.toml")
    simulate(scenario, out, duration_s=DURATION_S)
    return evaluate(out).as_json()


def test_the_bias_is_unobservable_and_kept_at_its_prior(metrics: dict[str, Any]) -> None:
    (bias,) = metrics["bias"].values()
    assert bias["range_offset_m"]["estimate"] == 0.0
    assert bias["range_offset_m"]["truth"] == 120.0


def test_system_tracks_are_no_worse_than_the_local_tracks(metrics: dict[str, Any]) -> None:
    local = metrics["local"]["25/11"]
    system = metrics["system"]
    # On main the residual bias was white noise on each plot: velocity RMS 14.6 m/s
    # against the local tracks' 8.5 (300 s), position 301 m against 288.
    assert system["position_rms_m"] <= local["position_rms_m"] + 1e-6
    assert system["velocity_rms_mps"] <= local["velocity_rms_mps"] + 1e-6
    assert system["tracks_per_aircraft"] <= local["tracks_per_aircraft"]
    assert system["probability_of_update"] >= local["probability_of_update"]


def test_system_covariance_holds_the_unknown_bias(metrics: dict[str, Any]) -> None:
    local = metrics["local"]["25/11"]
    system = metrics["system"]
    # The local tracks know nothing of the 120 m, 0.12 deg bias: NEES far above its dof.
    assert local["nees_mean"] > 5.0 * local["nees_dof"]
    # The system tracks carry the bias prior's share (C P_s C^T): never over-confident.
    # Under-confident here, as the prior (300 m, 0.3 deg) is wider than this radar's bias.
    assert system["nees_mean"] <= system["nees_dof"]


def system_against_local(capture: Path) -> tuple[int, float, float]:
    """The real single-radar capture fused with the default configuration: how many of
    its plots both a system track and a local track took, and the largest position and
    velocity difference between them at those plots."""
    (run,) = track_capture(
        capture, NOMINAL_SITE_068, fusion=FusionConfig(), bias=BiasConfig()
    ).values()
    assert run.system is not None
    system = run.system[run.system["fresh"] & (run.system["plot_id"] >= 0)]
    local = run.updates[run.updates["plot_id"] >= 0]
    local = local[np.argsort(local["plot_id"], kind="stable")]
    at = np.searchsorted(local["plot_id"], system["plot_id"])
    matched = local[at]
    assert np.array_equal(matched["plot_id"], system["plot_id"])
    dp = np.hypot(system["x"] - matched["x"], system["y"] - matched["y"])
    dv = np.hypot(system["vx"] - matched["vx"], system["vy"] - matched["vy"])
    return len(system), float(np.max(dp)), float(np.max(dv))


@pytest.mark.slow
def test_real_single_radar_system_tracks_follow_their_local_tracks() -> None:
    """068test_bds30.gps: one Mode S radar, no ADS-B, no field monitor. On main the system
    tracks were 14.6 m/s (median) away from the local tracks, with plot innovations of
    301 m against 152 m (median)."""
    compared, dp, dv = system_against_local(shared_file("reader_network/068test_bds30.gps"))
    assert compared > 1500
    # Measured: identical at every plot; the bounds leave room for a system track that
    # goes on across a restart of its local track (its own IMM then takes over).
    assert dp < 50.0
    assert dv < 10.0
