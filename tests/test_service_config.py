"""The service configuration: the example loads; mistakes are refused, naming the field."""

from __future__ import annotations

import tomllib
from ipaddress import IPv4Address
from pathlib import Path
from typing import Any

import pytest

from tracker_service.service import (
    ConfigError,
    ServiceConfig,
    load_service_config,
    parse_service_config,
)
from tracker_service.simulator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "config" / "example.toml"


def _example() -> dict[str, Any]:
    return tomllib.loads(EXAMPLE.read_text(encoding="utf-8"))


def _load(data: dict[str, Any]) -> ServiceConfig:
    return parse_service_config(data, "service.toml")


def test_example_matches_the_three_sites_scenario() -> None:
    config = load_service_config(EXAMPLE)
    scenario = load_scenario(REPO / "config" / "scenarios" / "three_sites.toml")
    assert [r.key for r in config.radars] == [r.key for r in scenario.radars]
    for radar, site in zip(config.radars, scenario.radars, strict=True):
        assert (radar.lat, radar.lon, radar.alt_m) == (site.lat, site.lon, site.alt_m)
        assert (radar.sigma_range_m, radar.sigma_azimuth_deg) == (
            site.sigma_range_m,
            site.sigma_azimuth_deg,
        )
        assert radar.antenna_period_s == site.antenna_period_s
        assert radar.input is not None
        assert radar.input.address == IPv4Address(site.output.group)
        assert radar.input.port == site.output.port
        if site.dual_lan:
            assert radar.input.second_lan is not None
            assert radar.input.second_lan.address == IPv4Address(site.output.second_lan_group)
    assert (config.system.centre_lat, config.system.centre_lon) == (
        scenario.system_centre.lat,
        scenario.system_centre.lon,
    )
    assert config.tracker_config().gate == 13.82


def test_unknown_field_is_named_with_the_allowed_ones() -> None:
    data = _example()
    data["radars"][1]["sigma_rnage_m"] = 40.0
    with pytest.raises(ConfigError) as caught:
        _load(data)
    message = str(caught.value)
    assert "radars.1.sigma_rnage_m = 40.0" in message
    assert "sigma_range_m" in message.split("allowed here:")[1]


def test_wrong_value_names_field_value_and_what_is_allowed() -> None:
    data = _example()
    data["zenoh"]["mode"] = "server"
    data["radars"][0]["input"]["second_lan"]["port"] = 70000
    with pytest.raises(ConfigError) as caught:
        _load(data)
    message = str(caught.value)
    assert "zenoh.mode = 'server'" in message
    assert "'peer', 'client' or 'router'" in message
    assert "radars.0.input.second_lan.port = 70000" in message
    assert "65535" in message


def test_unknown_tracker_setting_is_refused() -> None:
    data = _example()
    data["tracker"]["gating"] = 9.2
    with pytest.raises(ConfigError, match=r"tracker.*'gating'.*allowed: .*'gate'"):
        _load(data)


def test_duplicate_sac_sic_refused() -> None:
    data = _example()
    data["radars"][2]["sic"] = 11
    with pytest.raises(ConfigError, match=r"SAC/SIC used twice: \['25/11'\]"):
        _load(data)


def test_system_sac_sic_must_differ_from_the_radars() -> None:
    data = _example()
    data["system"]["sic"] = 13
    with pytest.raises(ConfigError, match=r"SAC/SIC used twice: \['25/13'\]"):
        _load(data)


def test_duplicate_input_endpoint_refused() -> None:
    data = _example()
    data["radars"][1]["input"] = {"address": "232.2.1.11", "port": 8600}
    with pytest.raises(ConfigError, match=r"inputs of 25/11 and 25/12"):
        _load(data)


def test_wildcard_input_takes_its_whole_port() -> None:
    data = _example()
    data["adsb"][0]["input"] = {"address": "0.0.0.0", "port": 8600}
    with pytest.raises(ConfigError, match=r"0.0.0.0 takes the whole port"):
        _load(data)
    data["adsb"][0]["input"] = {"address": "0.0.0.0", "port": 8621}
    assert _load(data).adsb[0].input is not None


def test_replay_needs_no_inputs_and_defaults_apply() -> None:
    data = {
        "radars": [
            {
                "name": "r",
                "sac": 1,
                "sic": 2,
                "lat": 48.0,
                "lon": 17.0,
                "alt_m": 100.0,
                "antenna_period_s": 4.0,
                "sigma_range_m": 50.0,
                "sigma_azimuth_deg": 0.07,
            }
        ],
        "system": {"centre_lat": 48.0, "centre_lon": 17.0, "sac": 1, "sic": 100},
    }
    config = _load(data)
    assert config.radars[0].input is None
    assert config.system.holding_window_s == 1.0
    assert config.zenoh.mode is None and config.zenoh.prefix == "tracker"
    assert not config.zenoh.scouting and not config.zenoh.allow_plaintext
    assert config.mcap.directory is None


def test_missing_file_and_bad_toml(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="no such configuration file"):
        load_service_config(tmp_path / "absent.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[system\n", encoding="utf-8")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_service_config(bad)
