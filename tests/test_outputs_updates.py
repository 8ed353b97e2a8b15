"""The batch path of the messages (``MessageMapper.local_updates``/``system_updates``)
publishes what the pydantic path (``ModelMapper``) publishes for the same rows, byte for
byte (``model_dump_json``), in the models' field order, and valid against the models
(the published JSON schemas); its values (``SystemBatch``) are the messages'."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
from mcap.reader import make_reader

from tracker_service.chain import RAW_PLOT_DTYPE
from tracker_service.fusion import COASTING, ENDED, SYSTEM_UPDATE_DTYPE
from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.foxglove_scene import TRACKS_TOPIC, MapScene, track_colour, track_label
from tracker_service.outputs.mapping import MessageMapper, ModelMapper
from tracker_service.outputs.mcap_log import McapLog, read_log_messages
from tracker_service.outputs.mcap_sink import McapSink
from tracker_service.outputs.messages import LocalTrackMessage, SystemTrackMessage
from tracker_service.outputs.updates import LOCAL_FIELDS, SYSTEM_FIELDS, SystemBatch, SystemValues
from tracker_service.tracking.plots import PUBLISHED_DAP_FIELDS
from tracker_service.tracking.tracker import track_update_dtype

PLANE = SystemPlane(48.5, 11.0)
SOURCES = ("40/1", "40/2", "40/3")
NOON = 1_780_315_200.0


def _covariances(rng: np.random.Generator, n: int) -> npt.NDArray[np.float64]:
    a = rng.normal(0.0, 30.0, (n, 4, 4))
    return (a @ a.transpose(0, 2, 1)).reshape(n, 16)


def _local_rows(rng: np.random.Generator, n: int, t: float) -> npt.NDArray[Any]:
    rows = np.zeros(n, dtype=track_update_dtype(3))
    rows["track_number"] = rng.integers(0, 30, n)
    rows["time"] = t + rng.uniform(0, 1, n)
    for name, scale in (("x", 3e5), ("y", 3e5), ("vx", 250.0), ("vy", 250.0)):
        rows[name] = rng.normal(0.0, scale, n)
    rows["P"] = _covariances(rng, n)
    rows["flight_level"] = np.where(rng.random(n) < 0.2, np.nan, rng.uniform(0, 450, n))
    rows["climb_rate_fl_per_s"] = np.where(rng.random(n) < 0.2, np.nan, rng.normal(0, 0.3, n))
    rows["status"] = rng.integers(0, 4, n)
    rows["plot_id"] = np.where(rng.random(n) < 0.3, -1, rng.integers(0, 10**6, n))
    rows["mode3a"] = np.where(rng.random(n) < 0.3, -1, rng.integers(0, 0o10000, n))
    rows["address"] = np.where(rng.random(n) < 0.3, -1, rng.integers(0, 1 << 24, n))
    mu = rng.random((n, 3))
    rows["model_probabilities"] = mu / mu.sum(axis=1, keepdims=True)
    return rows


def _plots(rng: np.random.Generator, n: int, t: float, first_id: int) -> npt.NDArray[Any]:
    plots = np.zeros(n, dtype=RAW_PLOT_DTYPE)
    plots["plot_id"] = np.arange(first_id, first_id + n)
    plots["time"] = t + rng.uniform(0, 1, n)
    plots["x"], plots["y"] = rng.normal(0, 3e5, n), rng.normal(0, 3e5, n)
    plots["rho_m"] = np.where(rng.random(n) < 0.1, np.nan, rng.uniform(1e3, 4e5, n))
    # An azimuth a hair below 360 wraps to 0 in the messages.
    plots["theta_deg"] = np.where(rng.random(n) < 0.1, -1e-14, rng.uniform(0, 360, n))
    plots["typ"] = rng.integers(0, 8, n)
    plots["address"] = rng.integers(0, 40, n)
    plots["callsign"] = np.where(rng.random(n) < 0.5, "", "RYR1")
    # Mode S DAPs on half the plots, each there or not: the messages keep each one's
    # last value and age.
    plots["has_daps"] = rng.random(n) < 0.5
    for name in PUBLISHED_DAP_FIELDS:
        there = plots["has_daps"] & (rng.random(n) < 0.7)
        plots[name] = np.where(there, rng.uniform(0.0, 300.0, n), np.nan)
    return plots


def _system_rows(
    rng: np.random.Generator, n: int, t: float, plots: npt.NDArray[Any]
) -> npt.NDArray[Any]:
    rows = np.zeros(n, dtype=SYSTEM_UPDATE_DTYPE)
    rows["system_number"] = rng.integers(0, 25, n)
    rows["time"] = t + rng.uniform(0, 1, n)
    for name, scale in (("x", 3e5), ("y", 3e5), ("vx", 250.0), ("vy", 250.0)):
        rows[name] = rng.normal(0.0, scale, n)
    rows["vx"][:2] = 0.0  # a track standing still: angle 0
    rows["vy"][0] = -1e-20  # a hair west of north: 360.0 before wrapping
    rows["P"] = _covariances(rng, n)
    rows["flight_level"] = np.where(rng.random(n) < 0.2, np.nan, rng.uniform(0, 450, n))
    rows["climb_rate_fl_per_s"] = np.where(rng.random(n) < 0.2, np.nan, rng.normal(0, 0.3, n))
    rows["status"] = rng.choice([0, COASTING, ENDED], n, p=[0.7, 0.2, 0.1])
    rows["fresh"] = rng.random(n) < 0.8
    rows["radar"] = rng.integers(0, len(SOURCES), n)
    rows["plot_id"] = np.where(rng.random(n) < 0.2, -1, rng.choice(plots["plot_id"], n))
    # Few addresses and codes: duplicates, code changes and callsigns happen.
    rows["address"] = np.where(rng.random(n) < 0.2, -1, rng.integers(0, 40, n))
    rows["mode3a"] = np.where(rng.random(n) < 0.2, -1, rng.integers(0o1000, 0o1004, n))
    rows["n_sources"] = rng.integers(1, 4, n)
    rows["local_radars"] = rng.integers(0, len(SOURCES), (n, rows["local_radars"].shape[1]))
    rows["local_numbers"] = rng.integers(0, 30, (n, rows["local_numbers"].shape[1]))
    rows["local_plot_ids"] = np.where(rng.random((n, rows["local_plot_ids"].shape[1])) < 0.3, -1, 5)
    return rows


def _valid(message: SystemTrackMessage) -> SystemTrackMessage:
    """The message as a subscriber reads it (a NaN published as null)."""
    return SystemTrackMessage.model_validate_json(message.model_dump_json())


def _pictures(mapper: MessageMapper | ModelMapper) -> dict[int, SystemTrackMessage]:
    return {n: _valid(m) for n, m in mapper.picture().items()}


def test_writers_follow_the_models_field_order() -> None:
    assert list(LocalTrackMessage.model_fields) == list(LOCAL_FIELDS)
    assert list(SystemTrackMessage.model_fields) == list(SYSTEM_FIELDS)


@pytest.mark.parametrize("seed", range(5))
def test_batch_path_publishes_what_the_models_publish(seed: int) -> None:
    """Every message, byte for byte; track numbers drawn from few (one number ending and
    starting again within a batch), and from all of CAT062's (the per-track arrays grow)."""
    rng = np.random.default_rng(seed)
    numbers = rng.choice(65536, 25, replace=False) if seed % 2 else np.arange(25)
    models, batch = ModelMapper(PLANE), MessageMapper(PLANE)
    first_id = 0
    for step in range(12):
        t = NOON + 5.0 * step
        plots = _plots(rng, 20, t, first_id)
        first_id += 20
        source = SOURCES[step % len(SOURCES)]
        local = _local_rows(rng, 15, t)
        expected_local = [m.model_dump_json() for m in models.local(source, local)]
        updates = batch.local_updates(source, local)
        assert [u.number for u in updates] == local["track_number"].tolist()
        for want, local_update in zip(expected_local, updates, strict=True):
            assert list(json.loads(local_update.payload)) == list(LOCAL_FIELDS)
            assert local_update.payload == want.encode()
            assert local_update.message() == LocalTrackMessage.model_validate_json(want)
        system = _system_rows(rng, 25, t, plots)
        system["system_number"] = numbers[system["system_number"]]
        expected = models.system(system, plots, SOURCES)
        system_updates = batch.system_updates(system, plots, SOURCES)
        for message, update in zip(expected, system_updates, strict=True):
            assert list(json.loads(update.payload)) == list(SYSTEM_FIELDS)
            assert update.payload == message.model_dump_json().encode(), message.number
            assert update.values == SystemValues.of_message(_valid(message))
            # Valid against the model (and so the published schema), as built.
            assert SystemTrackMessage.model_validate_json(update.payload) == _valid(message)
            assert _valid(update.message()) == _valid(message)
            assert update.ended == (message.status == "ended")
        assert _pictures(batch) == _pictures(models)
    ended = batch.end_all_updates()
    assert [u.payload for u in ended] == [m.model_dump_json().encode() for m in models.end_all()]
    assert batch.live_tracks == models.live_tracks == []


def test_non_finite_values_are_null_as_pydantic_writes_them() -> None:
    rng = np.random.default_rng(9)
    local = _local_rows(rng, 3, NOON)
    local["x"][0], local["P"][1, 5] = np.inf, np.nan
    models, batch = ModelMapper(PLANE), MessageMapper(PLANE)
    for message, update in zip(
        models.local("40/1", local), batch.local_updates("40/1", local), strict=True
    ):
        assert update.payload == message.model_dump_json().encode()


def test_non_finite_system_values_are_null_as_pydantic_writes_them() -> None:
    rng = np.random.default_rng(10)
    plots = _plots(rng, 5, NOON, 0)
    system = _system_rows(rng, 4, NOON, plots)
    system["status"] = 0
    system["P"][1, 3] = np.inf
    models, batch = ModelMapper(PLANE), MessageMapper(PLANE)
    expected = models.system(system, plots, SOURCES)
    for message, update in zip(expected, batch.system_updates(system, plots, SOURCES), strict=True):
        assert update.payload == message.model_dump_json().encode()


def test_batches_logged_read_back_by_mcap_and_the_streaming_reader(tmp_path: Path) -> None:
    """A batch of updates through the MCAP sink: every payload, in order, one LocationFix
    per live system update, the same as the per-message calls log."""
    rng = np.random.default_rng(3)
    plots = _plots(rng, 30, NOON, 0)
    mapper = MessageMapper(PLANE)
    local = mapper.local_updates("40/2", _local_rows(rng, 12, NOON))
    system = mapper.system_updates(_system_rows(rng, 20, NOON, plots), plots, SOURCES)
    with McapLog(tmp_path / "batch") as log:
        sink = McapSink(log)
        sink.local_updates("40/2", local, NOON + 1)
        sink.local_updates("40/2", [], NOON + 1)
        sink.system_updates(system, NOON + 1)
    with McapLog(tmp_path / "single") as log:
        sink = McapSink(log)
        for u in local:
            sink.local(u.message(), u.payload, NOON + 1)
        for s in system:
            sink.system(s.message(), s.payload, NOON + 1)

    def read(path: Path) -> list[tuple[str, float, dict[str, Any]]]:
        with path.open("rb") as stream:
            official = [
                (c.topic, m.log_time, json.loads(m.data))
                for _, c, m in make_reader(stream).iter_messages(log_time_order=False)
            ]
        streamed = [(m.topic, m.time, m.data) for m in read_log_messages(path)]
        assert [(t, d) for t, _, d in official] == [(t, d) for t, _, d in streamed]
        return sorted(((t, n / 1e9, d) for t, n, d in official), key=lambda m: m[0])

    batch = read(next((tmp_path / "batch").glob("*.mcap")))
    assert batch == read(next((tmp_path / "single").glob("*.mcap")))
    topics = [t for t, _, _ in batch]
    assert topics.count("/local_tracks/40_2") == len(local)
    assert topics.count("/system_tracks") == len(system)


def _reference_fix(m: SystemTrackMessage) -> bytes:
    """A ``foxglove.LocationFix`` of a message as a dict through ``json.dumps``: the
    textbook version of ``MapScene.location_fixes``."""
    p = m.covariance
    altitude = 0.0 if m.flight_level is None else m.flight_level * 30.48
    sec = math.floor(m.time)
    metadata = [
        ("label", track_label(m)),
        ("track", str(m.number)),
        ("status", m.status),
        *([("callsign", m.callsign.strip())] if m.callsign else []),
        *([("mode3a", m.mode3a)] if m.mode3a else []),
        *([("address", m.address)] if m.address else []),
        *([("flight_level", f"{m.flight_level:.2f}")] if m.flight_level is not None else []),
        ("ground_speed_kt", f"{m.ground_speed_mps * 3600.0 / 1852.0:.0f}"),
        ("track_angle_deg", f"{m.track_angle_deg:.0f}"),
        ("sources", ",".join(sorted({s.radar for s in m.sources}))),
    ]
    r, g, b = track_colour(m)
    fix = {
        "timestamp": {"sec": sec, "nsec": min(round((m.time - sec) * 1e9), 999_999_999)},
        "frame_id": f"track/{m.number}",
        "latitude": m.lat,
        "longitude": m.lon,
        "altitude": altitude,
        "position_covariance": [p[0][0], p[0][1], 0.0, p[1][0], p[1][1], 0.0, 0.0, 0.0, 1e6],
        "position_covariance_type": 3,
        "color": {"r": r, "g": g, "b": b, "a": 1.0},
        "metadata": [{"key": k, "value": v} for k, v in metadata],
    }
    return json.dumps(fix, separators=(",", ":")).encode()


@pytest.mark.parametrize("seed", range(3))
def test_the_map_from_batches_is_the_map_from_the_models(seed: int) -> None:
    """The Foxglove map written from a batch's columns (``MapScene.updates``: fixes,
    labels, colours, the periodic pictures) is what the scene makes of the per-message
    path's models, one ``update`` each, and its fixes what ``json.dumps`` writes of them."""
    rng = np.random.default_rng(seed)
    models, batch = ModelMapper(PLANE), MessageMapper(PLANE)
    from_models, from_batches = MapScene([]), MapScene([])
    first_id = 0
    for step in range(12):
        t = NOON + 0.7 * step
        plots = _plots(rng, 20, t, first_id)
        first_id += 20
        system = _system_rows(rng, 25, t, plots)
        messages = models.system(system, plots, SOURCES)
        expected = [out for m in messages for out in from_models.update(m, t)]
        updates = batch.system_updates(system, plots, SOURCES)
        written = from_batches.updates(updates[0].batch, t)
        assert written == expected
        fixes = [out.data for out in written if out.topic == TRACKS_TOPIC]
        assert fixes == [_reference_fix(m) for m in messages if m.status != "ended"]
    assert from_batches.picture_geojson() == from_models.picture_geojson()


def test_gather_takes_the_rows_of_several_batches_in_their_order() -> None:
    """``SystemBatch.gather`` (CAT062's pending rows: some 100 batches a second) is the
    batch of the rows' values, in the order asked, rows repeated and skipped."""
    rng = np.random.default_rng(3)
    mapper = MessageMapper(PLANE)
    batches = []
    for step in range(4):
        t = NOON + 5.0 * step
        plots = _plots(rng, 20, t, 20 * step)
        batches.append(
            mapper.system_updates(_system_rows(rng, 25, t, plots), plots, SOURCES)[0].batch
        )
    rows_of = [
        (batches[b], int(r))
        for b, r in zip(rng.integers(0, 4, 60), rng.integers(0, 25, 60), strict=True)
    ]
    gathered = SystemBatch.gather(rows_of)
    reference = SystemBatch.of_values([batch.values(row) for batch, row in rows_of])
    assert [gathered.values(k) for k in range(len(rows_of))] == [
        reference.values(k) for k in range(len(rows_of))
    ]
