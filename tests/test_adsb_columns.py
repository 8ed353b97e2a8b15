"""The ADS-B reports over arrays (``adsb.decode_reports`` on ``asterix.columns``) against
the general decoder's dict per record, the path they replace (``reference_reports``
below, kept as it was): bit for bit, on the real CAT021 samples, on the simulator's
recording, on generated records and on damaged ones; and the status's count taken from
the same decoding."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from asterix import spec
from asterix.codec import Block, DecodeError, decode_blocks, encode_block
from asterix.columns import ColumnReader
from asterix.containers import Datagram, read_file
from tests.conftest import REPO, shared_file
from tests.test_codec_properties import _record, _variation
from tracker_service.adsb import (
    CAT021_COLUMNS,
    FT,
    NACP_EPU_M,
    NACV_BOUND_M_S,
    NIC_RC_M,
    NM,
    NUCP_ACCURACY_M,
    SIGMA_PER_EPU,
    UNKNOWN_VELOCITY_SIGMA_M_S,
    WORST_BOUND_M,
    AdsbReports,
    decode_reports,
    position_sigma_m,
    velocity_sigma_m_s,
)
from tracker_service.adsb_status import adsb_count
from tracker_service.geodesy import SystemPlane
from tracker_service.ingest import DAY_S, posix_from_time_of_day
from tracker_service.radar_stage import CAT021, blocks_of
from tracker_service.service.replay import open_replay

PLANE = SystemPlane(48.0, 17.0)
RECEIVED = 1_780_300_800.0 + 36002.0


def _int_or_none(value: Any) -> int | None:
    return int(value) if isinstance(value, int | float) else None


def _position_sigma(version: int | None, nacp: int | None, nucp_or_nic: int | None) -> float:
    if nacp is not None and version != 0:
        bound = NACP_EPU_M.get(nacp)
    elif version is None or version == 0:
        bound = NUCP_ACCURACY_M.get(nucp_or_nic) if nucp_or_nic is not None else None
    else:
        bound = NIC_RC_M.get(nucp_or_nic) if nucp_or_nic is not None else None
    if bound is None or bound > WORST_BOUND_M:
        return math.nan
    return bound * SIGMA_PER_EPU


def _velocity_sigma(nacv: int | None) -> float:
    bound = NACV_BOUND_M_S.get(nacv) if nacv is not None else None
    return UNKNOWN_VELOCITY_SIGMA_M_S if bound is None else bound * SIGMA_PER_EPU


def reference_reports(block: bytes, received: float, plane: SystemPlane) -> dict[str, Any]:
    """The reports as ``decode_reports`` made them before the columns: a dict per record
    from the general decoder; with the status's latest time as ``adsb_status`` had it."""
    names = ("address", "time", "sigma", "sigma_v", "flight_level", "mode3a", "record")
    columns: dict[str, list[Any]] = {name: [] for name in names}
    lat, lon, height, speed, track = [], [], [], [], []
    station = ""
    records = 0
    latest: float | None = None
    for decoded in decode_blocks(block):
        if not isinstance(decoded, Block):
            continue
        for items in decoded.records:
            index = records
            records += 1
            source = items.get("010")
            if isinstance(source, dict) and not station:
                station = f"{source.get('SAC')}/{source.get('SIC')}"
            quality = items.get("090")
            quality = quality if isinstance(quality, dict) else {}
            version = items.get("210")
            vn = _int_or_none(version.get("VN")) if isinstance(version, dict) else None
            position = items.get("131", items.get("130"))
            tod = items.get("071", items.get("073"))
            if isinstance(tod, float | int):
                shift = (float(tod) - received % DAY_S + DAY_S / 2) % DAY_S - DAY_S / 2
                latest = received + shift if latest is None else max(latest, received + shift)
            sigma = _position_sigma(
                vn, _int_or_none(quality.get("NACP")), _int_or_none(quality.get("NUCPNIC"))
            )
            if (
                not isinstance(position, dict)
                or not isinstance(tod, int | float)
                or "080" not in items
                or not math.isfinite(sigma)
            ):
                continue
            velocity = items.get("160")
            moving = isinstance(velocity, dict) and velocity.get("RE") == 0
            columns["address"].append(int(str(items["080"]), 16))
            columns["time"].append(float(tod))
            columns["sigma"].append(sigma)
            columns["sigma_v"].append(
                _velocity_sigma(_int_or_none(quality.get("NUCRNACV")))
                if moving
                else UNKNOWN_VELOCITY_SIGMA_M_S
            )
            level = items.get("145")
            columns["flight_level"].append(
                float(level) if isinstance(level, int | float) else math.nan
            )
            code = items.get("070")
            columns["mode3a"].append(
                int(str(code["MODE3A"]), 8) if isinstance(code, dict) and "MODE3A" in code else -1
            )
            columns["record"].append(index)
            lat.append(float(position["LAT"]))
            lon.append(float(position["LON"]))
            height.append(float(items.get("140", 0.0)) * FT)
            speed.append(float(velocity["GS"]) * NM if moving else 0.0)  # type: ignore[index]
            track.append(float(velocity["TA"]) if moving else 0.0)  # type: ignore[index]
    out: dict[str, Any] = {"station": station, "records": records, "latest": latest}
    if not lat:
        return out | {name: np.zeros(0) for name in ("address", "x", "y", "vx", "vy")}
    lat_a, lon_a, h = np.array(lat), np.array(lon), np.array(height)
    x, y = plane.from_geodetic(lat_a, lon_a, h)
    angle = np.radians(np.array(track))
    step = np.array(speed)
    ahead_lat = lat_a + np.degrees(step * np.cos(angle) / 6_371_000.0)
    ahead_lon = lon_a + np.degrees(step * np.sin(angle) / (6_371_000.0 * np.cos(np.radians(lat_a))))
    x1, y1 = plane.from_geodetic(ahead_lat, ahead_lon, h)
    return out | {
        "address": np.array(columns["address"], dtype=np.int64),
        "time": posix_from_time_of_day(np.array(columns["time"]), received),
        "x": np.asarray(x, dtype=np.float64),
        "y": np.asarray(y, dtype=np.float64),
        "vx": np.asarray(x1 - x, dtype=np.float64),
        "vy": np.asarray(y1 - y, dtype=np.float64),
        "sigma": np.array(columns["sigma"]),
        "sigma_v": np.array(columns["sigma_v"]),
        "flight_level": np.array(columns["flight_level"]),
        "mode3a": np.array(columns["mode3a"], dtype=np.int64),
        "record": np.array(columns["record"], dtype=np.int64),
    }


def assert_same(reports: AdsbReports, expected: dict[str, Any]) -> None:
    assert (reports.station, reports.records) == (expected["station"], expected["records"])
    if expected["latest"] is None:
        assert reports.latest is None
    else:
        assert reports.latest is not None
        assert reports.latest.hex() == expected["latest"].hex()
    assert len(reports) == len(expected["address"])
    if not len(reports):
        return
    for name in expected.keys() - {"station", "records", "latest"}:
        got, want = getattr(reports, name), expected[name]
        assert got.dtype == want.dtype, name
        assert got.tobytes() == want.tobytes(), (name, got, want)


@pytest.fixture
def walked_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """The general decoder refused: every block must be read by the walk."""

    def refused(self: ColumnReader, block: bytes) -> None:
        raise AssertionError(f"the walk gave up on {block.hex()}")

    monkeypatch.setattr(ColumnReader, "read_decoded", refused)


@pytest.mark.usefixtures("walked_only")
def test_the_real_cat021_samples_read_as_the_general_decoder_reads_them() -> None:
    blocks = 0
    for name in ("croatiacontrol/cat21_re.ast", "jasterix/cat021ed2.1.bin"):
        for unit in read_file(shared_file(name)):
            assert isinstance(unit, Datagram)
            for block in blocks_of(unit.payload, CAT021):
                assert_same(
                    decode_reports(block, RECEIVED, PLANE),
                    reference_reports(block, RECEIVED, PLANE),
                )
                blocks += 1
    assert blocks >= 2


@pytest.mark.usefixtures("walked_only")
def test_the_simulated_stations_read_as_the_general_decoder_reads_them() -> None:
    source = open_replay(str(REPO / "recordings" / "three_sites.mcap"), None, None)
    fit = blocks = 0
    for _name, datagram in source.datagrams:
        assert datagram.time is not None
        for block in blocks_of(datagram.payload, CAT021):
            reports = decode_reports(block, datagram.time, PLANE)
            assert_same(reports, reference_reports(block, datagram.time, PLANE))
            fit += len(reports)
            blocks += 1
        if blocks >= 60:
            break
    assert fit > 500


_WANTED = tuple(dict.fromkeys(c.item for c in CAT021_COLUMNS))


@st.composite
def _adsb_record(draw: st.DrawFn) -> dict[str, Any]:
    """A record with each item the reports read present or not, and some others."""
    items = spec.category(21).items
    record = draw(_record(21)) if draw(st.booleans()) else {}
    for key in _WANTED:
        if draw(st.booleans()):
            record[key] = draw(_variation(items[key].variation))
    if not record:
        record["010"] = {"SAC": 1, "SIC": 2}
    return record


# Generated positions reach 360 degrees of latitude: the projection's NaN and inf warn.
@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    records=st.lists(_adsb_record(), min_size=1, max_size=20),
    received=st.floats(0.0, 4e9),
)
def test_generated_records_read_as_the_general_decoder_reads_them(
    records: list[dict[str, Any]], received: float
) -> None:
    block = encode_block(21, records)
    assert_same(decode_reports(block, received, PLANE), reference_reports(block, received, PLANE))


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    records=st.lists(_adsb_record(), min_size=1, max_size=6),
    damage=st.lists(st.tuples(st.integers(0, 10_000), st.integers(0, 255)), max_size=4),
    cut=st.integers(0, 8),
)
def test_damaged_blocks_read_as_the_general_decoder_reads_them(
    records: list[dict[str, Any]], damage: list[tuple[int, int]], cut: int
) -> None:
    """Bytes changed after the header, the block cut short (its length still says the
    whole): the records before a malformed one are read, the rest skipped, as before."""
    block = bytearray(encode_block(21, records))
    for at, value in damage:
        block[3 + at % (len(block) - 3)] = value
    damaged = bytes(block[: max(3, len(block) - cut)])
    event(f"well formed: {not any(isinstance(e, DecodeError) for e in decode_blocks(damaged))}")
    assert_same(
        decode_reports(damaged, RECEIVED, PLANE), reference_reports(damaged, RECEIVED, PLANE)
    )


@pytest.mark.filterwarnings("ignore::RuntimeWarning")
@settings(max_examples=200, deadline=None)
@given(body=st.binary(min_size=0, max_size=60))
def test_random_bytes_read_as_the_general_decoder_reads_them(body: bytes) -> None:
    block = bytes([21]) + (len(body) + 3).to_bytes(2) + body
    assert_same(decode_reports(block, RECEIVED, PLANE), reference_reports(block, RECEIVED, PLANE))


def test_the_status_count_is_the_decoding_the_chain_takes() -> None:
    """Every record of every CAT021 block of the datagram, and the latest time among
    them, fit for use or not; None for a datagram without CAT021."""
    good = {"010": {"SAC": 1, "SIC": 2}, "071": 100.0, "080": "ABCDEF"}
    blocks = [
        encode_block(21, [good, {"010": {"SAC": 1, "SIC": 2}, "073": 86399.5}]),
        encode_block(21, [{"010": {"SAC": 1, "SIC": 2}}]),
    ]
    payload = b"".join(blocks)
    reports = [decode_reports(block, 86400.0 * 20_000 + 50.0, PLANE) for block in blocks]
    count = adsb_count(reports)
    assert count is not None and count.records == 3
    assert count.latest == 86400.0 * 20_000 + 100.0  # 86399.5 is yesterday's
    assert adsb_count([]) is None
    assert len(list(blocks_of(payload, CAT021))) == 2


@pytest.mark.parametrize("version", [-1, 0, 1, 2])
def test_the_quality_tables_are_the_scalar_rules(version: int) -> None:
    values = np.arange(-1, 16)
    for nacp in values.tolist():
        got = position_sigma_m(np.full(17, version), np.full(17, nacp), values)
        want = [
            _position_sigma(
                None if version < 0 else version, None if nacp < 0 else nacp, None if v < 0 else v
            )
            for v in values.tolist()
        ]
        assert got.tobytes() == np.array(want).tobytes()
    nacv = np.arange(-1, 8)
    want_v = [_velocity_sigma(None if v < 0 else v) for v in nacv.tolist()]
    assert velocity_sigma_m_s(nacv).tobytes() == np.array(want_v).tobytes()
