"""A simulated radar sent as CAT001/CAT002 is tracked like the same radar sent as CAT048.

One scenario, run twice with the same seed: the detections and measurements are the same
draws, only the encoding differs (no Mode S items, RHO to 1/128 NM, the truncated I141
unrolled on CAT002). It starts just before midnight, so the unrolling crosses it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from asterix import Block, decode_blocks
from tracker_service.evaluation.command import Evaluation, evaluate
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.ingest import TimeSource
from tracker_service.simulator.recording import read_recording
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import Scenario

SOURCE = "1/2"


def _scenario(asterix: str) -> Scenario:
    return Scenario.model_validate(
        {
            "name": f"old radar {asterix}",
            "seed": 11,
            "start": "2026-06-01T23:58:30Z",
            "duration_s": 180.0,
            "system_centre": {"lat": 48.0, "lon": 17.0},
            "radars": [
                {
                    "name": "r",
                    "sac": 1,
                    "sic": 2,
                    "lat": 48.0,
                    "lon": 17.0,
                    "alt_m": 300.0,
                    "antenna_period_s": 5.0,
                    "asterix": asterix,
                }
            ],
            "traffic": {
                "count": 16,
                "area": {"lat_min": 47.3, "lat_max": 48.7, "lon_min": 16.0, "lon_max": 18.0},
            },
        }
    )


@pytest.fixture(scope="module")
def runs(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[Path, Evaluation]]:
    out = {}
    for asterix in ("cat048", "cat001"):
        path = tmp_path_factory.mktemp(asterix) / f"{asterix}.mcap"
        simulate(_scenario(asterix), path, no_bias=True)
        # CAT001 has no I048/250: the CAT048 radar's Mode S DAPs (tracking.daps) are
        # information the other cannot carry, so both are tracked without them.
        out[asterix] = (path, evaluate(path, EvaluationConfig(tracker={"use_daps": False})))
    return out


def test_the_radar_sends_cat001_and_cat002(runs: dict[str, tuple[Path, Evaluation]]) -> None:
    categories: dict[int, int] = {}
    for datagram in read_recording(runs["cat001"][0]).datagrams():
        for event in decode_blocks(datagram.payload):
            assert isinstance(event, Block)
            categories[event.cat] = categories.get(event.cat, 0) + len(event.records)
            if event.cat == 1:
                for items in event.records:
                    assert items["020"]["TYP"] == 0 and "141" in items
    assert set(categories) == {1, 2}
    assert categories[2] >= 180 / 5 * 16 - 16  # a message per sector crossing


def test_plots_get_the_same_times_as_their_cat048_twins(
    runs: dict[str, tuple[Path, Evaluation]],
) -> None:
    old, new = (runs[a][1].pipeline.radars[SOURCE].plots for a in ("cat048", "cat001"))
    assert len(old) == len(new) > 400
    assert np.all(old["time_source"] == TimeSource.I140)
    # Before the first sector message, the reception time is the reference.
    service = new["time_source"] == TimeSource.I141_SERVICE
    assert np.mean(service) > 0.99
    assert set(np.unique(new["time_source"]).tolist()) <= {
        TimeSource.I141_SERVICE,
        TimeSource.I141_RECEPTION,
    }
    # I141 is I140 cut to 512 s, in the same 1/128 s: unrolled, the same time.
    np.testing.assert_array_equal(new["time"], old["time"])
    np.testing.assert_allclose(new["rho_m"], old["rho_m"], atol=1852.0 / 256)


def test_tracked_as_well_as_the_cat048_radar(runs: dict[str, tuple[Path, Evaluation]]) -> None:
    old, new = (runs[a][1].local[SOURCE] for a in ("cat048", "cat001"))
    assert new.confirmed_tracks >= 12
    assert new.tracks_per_aircraft is not None and new.tracks_per_aircraft <= 1.05
    assert new.id_changes == old.id_changes == 0
    assert new.probability_of_update is not None and old.probability_of_update is not None
    assert new.probability_of_update >= old.probability_of_update - 0.01
    assert new.position_rms_m is not None and old.position_rms_m is not None
    # RHO's 1/128 NM (14 m) adds about 4 m of quantisation to 50 m of noise.
    assert new.position_rms_m <= 1.05 * old.position_rms_m + 2.0
