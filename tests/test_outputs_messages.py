"""Published messages: the schemas in docs/schemas are current; derived fields are right."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest
from pydantic import ValidationError

from tracker_service.outputs.messages import (
    MODELS,
    SystemTrackMessage,
    iso_time,
    position_sigma_m,
    schemas,
    write_schemas,
)

REPO = Path(__file__).resolve().parents[1]
SCHEMAS = REPO / "docs" / "schemas"


def test_schemas_in_the_repository_are_current() -> None:
    expected = schemas()
    assert sorted(p.name for p in SCHEMAS.glob("*.schema.json")) == sorted(expected)
    for name, text in expected.items():
        assert (SCHEMAS / name).read_text(encoding="utf-8") == text, (
            f"docs/schemas/{name} is stale: run python -m tracker_service.outputs.messages "
            "docs/schemas"
        )


def test_module_entry_writes_one_schema_per_model(tmp_path: Path) -> None:
    subprocess.run(
        [sys.executable, "-m", "tracker_service.outputs.messages", str(tmp_path)],
        check=True,
        capture_output=True,
    )
    written = sorted(p.name for p in tmp_path.iterdir())
    assert written == sorted(f"{m.__name__}.schema.json" for m in MODELS)
    schema = json.loads((tmp_path / "SystemTrackMessage.schema.json").read_text())
    assert schema["additionalProperties"] is False
    assert "status" in schema["required"]
    assert write_schemas(tmp_path / "again")[0].is_file()


def _track(**changes: object) -> SystemTrackMessage:
    fields: dict[str, object] = {
        "time": 1_780_308_000.25,
        "x_m": 1000.0,
        "y_m": -500.0,
        "vx_mps": 0.0,
        "vy_mps": -200.0,
        "covariance": [[100.0, 0, 0, 0], [0, 2500.0, 0, 0], [0, 0, 4.0, 0], [0, 0, 0, 4.0]],
        "climb_rate_fl_per_s": -0.25,
        "number": 7,
        "lat": 48.6,
        "lon": 18.6,
        "sources": [{"radar": "25/11", "local_track": 3, "age_s": 0.5}],
        "status": "confirmed",
    }
    fields.update(changes)
    return SystemTrackMessage.from_state(**fields)  # type: ignore[arg-type]


def test_derived_fields() -> None:
    track = _track()
    assert track.time_iso == "2026-06-01T10:00:00.250000Z"
    assert track.ground_speed_mps == 200.0
    assert track.track_angle_deg == 180.0  # southbound
    assert track.position_sigma_m == 50.0  # the larger axis (y)
    assert track.climb_rate_fpm == -1500.0
    east = _track(vx_mps=-10.0, vy_mps=0.0)
    assert east.track_angle_deg == 270.0


def test_position_sigma_of_a_tilted_ellipse() -> None:
    # Axes 30 m and 10 m turned by 30 deg: the major semi-axis is still 30 m.
    a, b, t = 30.0, 10.0, math.radians(30.0)
    c, s = math.cos(t), math.sin(t)
    sxx = a * a * c * c + b * b * s * s
    syy = a * a * s * s + b * b * c * c
    sxy = (a * a - b * b) * c * s
    cov = [[sxx, sxy, 0.0, 0.0], [sxy, syy, 0.0, 0.0], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
    assert position_sigma_m(cov) == pytest.approx(30.0)


def test_round_trip_through_json() -> None:
    track = _track(address="4CA7A8", callsign="RYR174C", mode3a="1275")
    again = SystemTrackMessage.model_validate_json(track.model_dump_json())
    assert again == track


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("address", "4ca7a"),
        ("mode3a", "1278"),
        ("status", "tentative"),
        ("covariance", [[1.0, 0.0], [0.0, 1.0]]),
        ("sources", [{"radar": "25-11", "local_track": 1, "age_s": 0.0}]),
        ("colour", "red"),
    ],
)
def test_invalid_values_are_refused(field: str, value: object) -> None:
    with pytest.raises(ValidationError, match=field):
        _track(**{field: value})


def test_iso_time_is_utc() -> None:
    assert iso_time(0.0) == "1970-01-01T00:00:00.000000Z"


def test_every_schema_field_says_what_it_is() -> None:
    """Each published field has a description; the plane's coordinates say their frame."""
    import json

    for name, text in schemas().items():
        schema = json.loads(text)
        models = {schema["title"]: schema, **schema.get("$defs", {})}
        for model, definition in models.items():
            for field, spec in definition.get("properties", {}).items():
                assert spec.get("description"), f"{name}: {model}.{field} has no description"
    track = json.loads(schemas()["SystemTrackMessage.schema.json"])["properties"]
    for field in ("x_m", "vx_mps", "vy_mps"):
        assert "system plane" in track[field]["description"], field
    assert "not true" in track["vx_mps"]["description"]
