"""CAT062/065 encoding: the bytes decode back, by our codec, to what the messages say."""

from __future__ import annotations

import math
from typing import Any

import pyobelix
import pytest

from asterix.codec import Block, decode_blocks
from tracker_service.outputs.cat062 import encode_cat065, encode_system_tracks
from tracker_service.outputs.messages import SystemTrackMessage
from tracker_service.service import SystemConfig

SYSTEM = SystemConfig(centre_lat=48.6, centre_lon=18.6, sac=25, sic=100, service_id=3)
LAT_LSB = 180.0 / 2**25
NOON = 1_780_315_200.0  # 2026-06-01T12:00:00Z


def _track(**changes: object) -> SystemTrackMessage:
    fields: dict[str, object] = {
        "time": NOON + 0.3,
        "x_m": -123_456.7,
        "y_m": 65_432.1,
        "vx_mps": 180.3,
        "vy_mps": -95.6,
        "covariance": [
            [900.0, -300.0, 0.0, 0.0],
            [-300.0, 400.0, 0.0, 0.0],
            [0.0, 0.0, 9.0, 0.0],
            [0.0, 0.0, 0.0, 16.0],
        ],
        "climb_rate_fl_per_s": 0.31,
        "number": 4321,
        "lat": 48.6000001,
        "lon": 18.6000001,
        "flight_level": 351.3,
        "altitude_m": 10_750.0,
        "address": "4CA7A8",
        "callsign": "RYR174C",
        "mode3a": "1275",
        "mode3a_changed": True,
        "sources": [
            {"radar": "25/11", "local_track": 17, "age_s": 0.4, "plot_id": 99},
            {"radar": "25/13", "local_track": 5, "age_s": 2.1},
        ],
        "status": "confirmed",
        "last_plot": {
            "radar": "25/13",
            "time": NOON + 0.1,
            "lat": 48.6,
            "lon": 18.6,
            "range_m": 150_000.0,
            "azimuth_deg": 33.3,
        },
        "ages": {"psr": 70.0, "ssr": 0.4, "mode_s": 0.4},
    }
    fields.update(changes)
    return SystemTrackMessage.from_state(**fields)  # type: ignore[arg-type]


def _records(data: bytes) -> list[dict[str, Any]]:
    events = list(decode_blocks(data))
    assert all(isinstance(e, Block) and e.cat == 62 for e in events), events
    return [r for e in events if isinstance(e, Block) for r in e.records]


def test_record_decodes_to_the_message() -> None:
    m = _track()
    (r,) = _records(encode_system_tracks([m], SYSTEM))
    assert r["010"] == {"SAC": 25, "SIC": 100}
    assert r["015"] == 3
    assert r["040"] == 4321
    assert r["070"] == pytest.approx(43_200.3, abs=1 / 256)
    assert abs(r["105"]["LAT"] - m.lat) <= LAT_LSB / 2
    assert abs(r["105"]["LON"] - m.lon) <= LAT_LSB / 2
    assert r["100"] == {"X": pytest.approx(m.x_m, abs=0.25), "Y": pytest.approx(m.y_m, abs=0.25)}
    # At the plane's centre the plane's axes are the target's east and north.
    assert r["185"]["VX"] == pytest.approx(m.vx_mps, abs=0.125 + 1e-3)
    assert r["185"]["VY"] == pytest.approx(m.vy_mps, abs=0.125 + 1e-3)
    assert r["136"] == 351.25
    assert r["135"] == {"QNH": 1, "CTB": pytest.approx(10_750 / 0.3048 / 100, abs=0.125)}
    assert r["220"] == pytest.approx(0.31 * 6000, abs=3.125)
    assert r["060"] == {"V": 0, "G": 0, "CH": 1, "MODE3A": "1275"}
    assert r["245"]["CHR"].rstrip() == "RYR174C"
    assert r["380"]["ADR"] == "4CA7A8"
    assert r["380"]["ID"].rstrip() == "RYR174C"
    status = r["080"]
    assert (status["MON"], status["CNF"], status["CST"], status["TSB"], status["TSE"]) == (
        0,
        0,
        0,
        0,
        0,
    )
    assert (status["PSR"], status["SSR"], status["MDS"], status["ADS"]) == (0, 0, 0, 1)
    assert "DUPM" not in status
    assert r["290"] == {"PSR": 63.75, "SSR": 0.5, "MDS": 0.5}  # capped; 0.4 s to 1/4 s
    assert r["340"]["SID"] == {"SAC": 25, "SIC": 13}
    assert r["340"]["POS"]["RHO"] == pytest.approx(150_000 / 1852, abs=1 / 512)
    assert r["340"]["POS"]["THETA"] == pytest.approx(33.3, abs=360 / 2**17)
    accuracy = r["500"]
    assert accuracy["APC"] == {"X": 30.0, "Y": 20.0}
    assert accuracy["COV"] == pytest.approx(-math.sqrt(300.0), abs=0.25)
    assert accuracy["ATV"] == {"X": 3.0, "Y": 4.0}
    # 20 m north and 30 m east, in degrees of latitude and longitude at 48.6 N.
    assert accuracy["APW"]["LAT"] == pytest.approx(20.0 / 111_180, abs=LAT_LSB / 2 + 2e-7)
    assert accuracy["APW"]["LON"] == pytest.approx(30.0 / 73_756, abs=LAT_LSB / 2 + 2e-7)


def test_status_bits_of_first_coasting_ended_and_duplicate_address() -> None:
    messages = [
        _track(first=True, sources=[{"radar": "25/11", "local_track": 1, "age_s": 0.0}]),
        _track(status="coasting"),
        _track(status="ended"),
        _track(duplicate_address=True),
    ]
    first, coasting, ended, duplicate = (
        r["080"] for r in _records(encode_system_tracks(messages, SYSTEM))
    )
    assert (first["TSB"], first["MON"], first["TSE"]) == (1, 1, 0)
    assert (coasting["CST"], coasting["TSE"]) == (1, 0)
    assert (ended["TSE"], ended["TSB"]) == (1, 0)
    assert duplicate["DUPM"] == 1
    assert all("DUPM" not in s for s in (first, coasting, ended))


def test_optional_items_are_absent_when_unknown() -> None:
    m = _track(
        flight_level=None,
        altitude_m=None,
        climb_rate_fl_per_s=None,
        address=None,
        callsign=None,
        mode3a=None,
        last_plot=None,
        ages={},
    )
    (r,) = _records(encode_system_tracks([m], SYSTEM))
    assert not {"136", "135", "220", "380", "245", "060", "340", "290"} & r.keys()
    assert {"010", "015", "040", "070", "080", "100", "105", "185", "500"} <= r.keys()


def test_velocity_is_on_the_targets_own_north() -> None:
    # 3 deg east of the centre the meridian leans towards the plane's centre line by
    # about 3 deg x sin(48.6 deg) = 2.25 deg: plane north is 2.25 deg east of true north.
    m = _track(lat=48.6, lon=21.6, vx_mps=0.0, vy_mps=200.0)
    (r,) = _records(encode_system_tracks([m], SYSTEM))
    vx, vy = r["185"]["VX"], r["185"]["VY"]
    assert math.hypot(vx, vy) == pytest.approx(200.0, rel=2e-3)
    assert math.degrees(math.atan2(vx, vy)) == pytest.approx(2.25, abs=0.1)


def test_time_of_day_wraps_at_midnight() -> None:
    midnight = NOON + 12 * 3600
    (before, after) = _records(
        encode_system_tracks([_track(time=midnight - 1 / 1024), _track(time=midnight + 1)], SYSTEM)
    )
    assert before["070"] == 0.0
    assert after["070"] == 1.0


def test_blocks_respect_the_size_limit_and_keep_order() -> None:
    messages = [_track(number=n) for n in range(100)]
    data = encode_system_tracks(messages, SYSTEM, max_block_octets=600)
    events = list(decode_blocks(data))
    assert len(events) > 10
    sizes = []
    pos = 0
    while pos < len(data):
        size = int.from_bytes(data[pos + 1 : pos + 3])
        sizes.append(size)
        pos += size
    assert max(sizes) <= 600
    assert [r["040"] for r in _records(data)] == list(range(100))
    with pytest.raises(ValueError, match="does not fit"):
        encode_system_tracks(messages[:1], SYSTEM, max_block_octets=40)
    assert encode_system_tracks([], SYSTEM) == b""


def test_pyobelix_frames_the_blocks() -> None:
    # pyobelix 0.1 decodes only CAT048 and CAT034: it can check the block framing of
    # CAT062/065 (category and length), not the items.
    data = encode_system_tracks([_track(number=n) for n in range(30)], SYSTEM)
    data += encode_cat065("end_of_batch", NOON, 1, SYSTEM)
    framed = list(pyobelix.iter_records(data))
    assert [f["cat"] for f in framed] == [62] * (len(framed) - 1) + [65]
    assert all(f["_unparsed"] for f in framed)
    assert sum(len(f["_raw"]) + 3 for f in framed) == len(data)


def test_cat065_messages() -> None:
    def decoded(data: bytes) -> dict[str, Any]:
        (block,) = decode_blocks(data)
        assert isinstance(block, Block) and block.cat == 65
        (record,) = block.records
        return record

    status = decoded(encode_cat065("sdps_status", NOON + 0.5, 0, SYSTEM, degraded=True))
    assert status["000"] == 1
    assert status["010"] == {"SAC": 25, "SIC": 100}
    assert status["015"] == 3
    assert status["030"] == 43_200.5
    assert status["040"]["NOGO"] == 1 and status["040"]["OVL"] == 0
    batch = decoded(encode_cat065("end_of_batch", NOON, 257, SYSTEM))
    assert (batch["000"], batch["020"]) == (2, 1)
    assert "040" not in batch
    report = decoded(encode_cat065("service_status", NOON, 0, SYSTEM, report=1))
    assert (report["000"], report["050"]) == (3, 1)
    with pytest.raises(ValueError, match="report code"):
        encode_cat065("service_status", NOON, 0, SYSTEM)
