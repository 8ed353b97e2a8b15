"""The atmosphere of the Mode C conversion: pressure altitude to geometric height with QNH
and ISA deviation, against the simulator's own model and hand figures; its configuration."""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np
import pytest

from tracker_service.chain import recording_atmosphere
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.geodesy import Atmosphere, HeightModel, flight_level_to_height_m
from tracker_service.service import ConfigError, parse_service_config
from tracker_service.simulator import geometry

REPO = Path(__file__).resolve().parents[1]
FT = 0.3048


def test_the_standard_atmosphere_is_the_geopotential_conversion() -> None:
    fl = np.array([-10.0, 0.0, 100.0, 350.0, 450.0])
    assert np.allclose(Atmosphere().flight_level_height_m(fl), flight_level_to_height_m(fl))
    assert Atmosphere().is_standard and not Atmosphere(1004.0).is_standard


def test_the_tracker_and_the_simulator_agree_on_every_atmosphere() -> None:
    # Two implementations of one model (the tracker's must not import the simulator's).
    feet = np.array([-1000.0, 0.0, 5000.0, 24000.0, 35000.0, 36089.0, 41000.0, 60000.0])
    for qnh in (990.0, 1004.0, 1013.25, 1035.0):
        for deviation in (-15.0, -7.0, 0.0, 15.0):
            ours = Atmosphere(qnh, deviation).height_m(feet)
            theirs = geometry.geometric_height_m(feet, qnh, deviation)
            assert np.allclose(ours, theirs, rtol=0, atol=1e-6)
            back = Atmosphere(qnh, deviation).pressure_altitude_ft(ours)
            assert np.allclose(back, feet, rtol=0, atol=1e-6)


def test_hand_figures() -> None:
    # QNH 1003 hPa: sea level shows about +281 ft; 27-28 ft per hPa near the ground.
    assert float(Atmosphere(1003.0).height_m(281.0)) == pytest.approx(0.0, abs=2.0)
    # The case, QNH 1004 hPa and ISA - 7 K: FL350 about 330 m below its ISA height.
    drop = float(Atmosphere().flight_level_height_m(350.0)) - float(
        Atmosphere(1004.0, -7.0).flight_level_height_m(350.0)
    )
    assert 300.0 < drop < 360.0
    # ISA - 15 K: 5.2 % of the geopotential height below 11 km (T / T_ISA at every level).
    cold = float(Atmosphere(1013.25, -15.0).flight_level_height_m(300.0))
    r = 6356766.0
    assert r * cold / (r + cold) == pytest.approx(30000.0 * FT * 273.15 / 288.15, rel=1e-9)


def test_the_height_model_converts_with_its_atmosphere() -> None:
    cold = HeightModel(atmosphere=Atmosphere(1004.0, -7.0))
    height, sigma = cold.heights(np.array([350.0, np.nan]))
    assert height[0] == pytest.approx(float(Atmosphere(1004.0, -7.0).flight_level_height_m(350)))
    assert height[1] == HeightModel().assumed_height_m and sigma[1] == HeightModel().assumed_sigma_m


def _service(atmosphere: dict[str, object]) -> dict[str, object]:
    doc = tomllib.loads((REPO / "config" / "example.toml").read_text(encoding="utf-8"))
    doc["atmosphere"] = atmosphere
    return doc


def test_the_configuration_names_a_wrong_atmosphere_in_one_line() -> None:
    config = parse_service_config(_service({"qnh_hpa": 1004, "isa_deviation_k": -7.0}))
    assert config.atmosphere_config() == Atmosphere(1004.0, -7.0)
    assert parse_service_config(_service({})).atmosphere_config().is_standard
    for table, words in [
        ({"qnh_hpa": 29.92}, ["qnh_hpa", "29.92", "hPa"]),
        ({"isa_deviation_k": 288.0}, ["isa_deviation_k", "288"]),
        ({"qnh_hpa": "1004"}, ["qnh_hpa", "not a number"]),
        ({"qnh": 1004.0}, ["qnh", "qnh_hpa", "isa_deviation_k"]),
    ]:
        with pytest.raises(ConfigError) as error:
            parse_service_config(_service(table))
        # The service's format: a count, then one line per problem.
        lines = str(error.value).splitlines()
        assert len(lines) == 2 and all(w in lines[1] for w in words), lines


def test_evaluate_takes_the_recordings_atmosphere_unless_configured() -> None:
    metadata = {"scenario": {"atmosphere": {"qnh_hpa": 990.0, "temperature_offset_k": 15.0}}}
    assert recording_atmosphere(metadata) == Atmosphere(990.0, 15.0)
    assert recording_atmosphere({}).is_standard
    config = EvaluationConfig.from_mapping({"atmosphere": {"qnh_hpa": 1013.25}})
    assert config.atmosphere is not None and config.atmosphere.is_standard
    assert EvaluationConfig.from_mapping({}).atmosphere is None
    with pytest.raises(ValueError, match="isa_deviation_k"):
        EvaluationConfig.from_mapping({"atmosphere": {"isa_deviation_k": -80.0}})
