"""The CAT062 fast path gives, byte for byte, what the generic codec gives for the same
tracks, and the codec decodes it."""

from __future__ import annotations

from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asterix import EncodeError
from asterix.codec import Block, decode_blocks
from tracker_service.outputs.cat062 import (
    MAX_BLOCK_OCTETS,
    PeriodRecords,
    encode_system_tracks,
    encode_system_tracks_generic,
)
from tracker_service.outputs.messages import SystemTrackMessage, TrackSource
from tracker_service.outputs.updates import SystemBatch, SystemUpdate, SystemValues
from tracker_service.service import SystemConfig

SYSTEM = SystemConfig(centre_lat=48.5, centre_lon=11.0, sac=25, sic=100, service_id=3)
NOON = 1_780_315_200.0  # 2026-06-01T12:00:00Z


def _num(low: float, high: float) -> st.SearchStrategy[float]:
    return st.floats(low, high, allow_nan=False, allow_infinity=False)


_optional_age = st.none() | _num(0.0, 200.0)
_radar = st.tuples(st.integers(0, 255), st.integers(0, 255)).map(lambda s: f"{s[0]}/{s[1]}")


@st.composite
def _covariance(draw: st.DrawFn) -> list[list[float]]:
    sx, sy = draw(_num(0.0, 1e5)), draw(_num(0.0, 1e5))
    rho = draw(_num(-1.0, 1.0))
    svx, svy = draw(_num(0.0, 100.0)), draw(_num(0.0, 100.0))
    sxy = rho * sx * sy
    return [
        [sx * sx, sxy, 0.0, 0.0],
        [sxy, sy * sy, 0.0, 0.0],
        [0.0, 0.0, svx**2, 0.0],
        [0.0, 0.0, 0.0, svy**2],
    ]


@st.composite
def _track(draw: st.DrawFn) -> SystemTrackMessage:
    """A track anywhere in the items' ranges, with every optional item present or not;
    times across midnight, azimuths near 360, quantities on and off their LSB grids."""
    plot: dict[str, Any] | None = None
    if draw(st.booleans()):
        polar = draw(st.booleans())
        plot = {
            "radar": draw(_radar),
            "time": NOON,
            "lat": 48.0,
            "lon": 11.0,
            "range_m": draw(_num(0.0, 600_000.0)) if polar else None,
            "azimuth_deg": draw(_num(0.0, 359.9999999)) if polar else None,
        }
    callsign = draw(st.none() | st.text("ABCDEFXYZ0123456789 ", min_size=1, max_size=8))
    if callsign is not None and not callsign.strip():
        callsign = None
    status = draw(st.sampled_from(["confirmed", "coasting", "ended"]))
    lat = draw(_num(40.0, 57.0))
    return SystemTrackMessage.from_state(
        time=draw(_num(NOON - 43_200.0, NOON + 43_199.99)),
        x_m=draw(_num(-2e6, 2e6)),
        y_m=draw(_num(-2e6, 2e6)),
        vx_mps=draw(_num(-300.0, 300.0)),
        vy_mps=draw(_num(-300.0, 300.0)),
        covariance=draw(_covariance()),
        climb_rate_fl_per_s=draw(st.none() | _num(-1.0, 1.0)),
        number=draw(st.integers(0, 65535)),
        lat=lat,
        lon=draw(_num(-179.0, 179.0)),
        flight_level=draw(st.none() | _num(-10.0, 500.0)),
        altitude_m=draw(st.none() | _num(-300.0, 15_000.0)),
        address=draw(st.none() | st.sampled_from(["4CA7A8", "000001", "FFFFFF", "3C6586"])),
        callsign=callsign,
        mode3a=draw(st.none() | st.integers(0, 0o7777).map(lambda c: f"{c:04o}")),
        mode3a_changed=draw(st.booleans()),
        first=draw(st.booleans()),
        sources=[
            {"radar": "25/11", "local_track": 1, "age_s": 0.0}
            for _ in range(draw(st.integers(1, 3)))
        ],
        status=status,
        last_plot=plot,
        ages={
            "psr": draw(_optional_age),
            "ssr": draw(_optional_age),
            "mode_s": draw(_optional_age),
            "adsb": draw(_optional_age),
        },
        duplicate_address=draw(st.booleans()),
        daps=[
            {"name": name, "value": draw(_num(*DAP_RANGES[name])), "age_s": draw(_num(0.0, 90.0))}
            for name in DAP_RANGES
            if draw(st.booleans())
        ],
    )


DAP_RANGES = {
    "magnetic_heading_deg": (0.0, 359.99),
    "indicated_airspeed_kt": (0.0, 500.0),
    "mach": (0.0, 1.2),
    "selected_altitude_ft": (0.0, 60_000.0),
    "baro_rate_fpm": (-8000.0, 8000.0),
    "inertial_rate_fpm": (-8000.0, 8000.0),
    "roll_deg": (-60.0, 60.0),
    "track_angle_rate_deg_s": (-8.0, 8.0),
    "true_track_deg": (0.0, 359.99),
    "ground_speed_kt": (0.0, 700.0),
}
"""Every DAP a system-track message may carry, over its plausible range."""


def test_daps_reach_i380_and_their_ages_i295() -> None:
    daps = [
        {"name": "ground_speed_kt", "value": 450.0, "age_s": 2.5},
        {"name": "roll_deg", "value": -20.0, "age_s": 2.5},
        {"name": "track_angle_rate_deg_s", "value": -1.5, "age_s": 2.5},
        {"name": "selected_altitude_ft", "value": 35_000.0, "age_s": 100.0},
    ]
    track = _plain(daps=daps)
    data = encode_system_tracks([track], SYSTEM)
    assert data == encode_system_tracks_generic([track], SYSTEM)
    (record,) = [r for e in decode_blocks(data) if isinstance(e, Block) for r in e.records]
    i380, i295 = record["380"], record["295"]
    assert i380["GS"] == pytest.approx(450.0 / 3600.0, abs=2**-14)
    assert i380["RAN"] == pytest.approx(-20.0, abs=0.01)
    assert i380["TAR"]["TI"] == 1 and i380["TAR"]["ROT"] == pytest.approx(-1.5)
    assert i380["SAL"]["ALT"] == pytest.approx(35_000.0, abs=25)
    assert i295["GSP"] == pytest.approx(2.5) and i295["SAL"] == pytest.approx(63.75)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_track(), min_size=1, max_size=40))
def test_fast_path_is_byte_identical_to_the_generic_codec(tracks: list[SystemTrackMessage]) -> None:
    fast = encode_system_tracks(tracks, SYSTEM)
    assert fast == encode_system_tracks_generic(tracks, SYSTEM)
    events = list(decode_blocks(fast))
    assert all(isinstance(e, Block) and e.cat == 62 for e in events), events
    decoded = [r for e in events if isinstance(e, Block) for r in e.records]
    assert [r["040"] for r in decoded] == [t.number for t in tracks]


@settings(max_examples=10, deadline=None)
@given(st.lists(_track(), min_size=1, max_size=20), st.integers(100, MAX_BLOCK_OCTETS))
def test_blocks_are_framed_alike(tracks: list[SystemTrackMessage], size: int) -> None:
    # A record with DAPs can be longer than a small block: both paths refuse it alike.
    try:
        fast = encode_system_tracks(tracks, SYSTEM, size)
    except ValueError as refused:
        with pytest.raises(ValueError) as generic_refused:
            encode_system_tracks_generic(tracks, SYSTEM, size)
        assert str(generic_refused.value) == str(refused)
        return
    assert fast == encode_system_tracks_generic(tracks, SYSTEM, size)


def _plain(**changes: object) -> SystemTrackMessage:
    fields: dict[str, Any] = {
        "time": NOON,
        "x_m": 1000.0,
        "y_m": -2000.0,
        "vx_mps": 200.0,
        "vy_mps": 10.0,
        "covariance": [[100.0, 0, 0, 0], [0, 100.0, 0, 0], [0, 0, 4.0, 0], [0, 0, 0, 4.0]],
        "number": 7,
        "lat": 48.5,
        "lon": 11.0,
        "flight_level": 350.0,
        "sources": [TrackSource(radar="25/11", local_track=1, age_s=0.0)],
        "status": "confirmed",
    }
    return SystemTrackMessage.from_state(**(fields | changes))


@pytest.mark.parametrize(
    ("field", "value"),
    [("x_m", 5e6), ("climb_rate_fl_per_s", 40.0), ("flight_level", 9000.0), ("number", 70000)],
)
def test_a_value_beyond_its_item_is_refused_alike(field: str, value: float) -> None:
    tracks = [_plain(), _plain(**{field: value}, validate=False)]
    with pytest.raises(EncodeError) as generic:
        encode_system_tracks_generic(tracks, SYSTEM)
    with pytest.raises(EncodeError) as fast:
        encode_system_tracks(tracks, SYSTEM)
    assert str(fast.value) == str(generic.value)


def _updates(tracks: list[SystemTrackMessage]) -> list[SystemUpdate]:
    """The tracks as one batch's updates, as the mapper hands them to the outputs."""
    batch = SystemBatch.of_values([SystemValues.of_message(t) for t in tracks])
    return [SystemUpdate(batch, k, t.number, b"") for k, t in enumerate(tracks)]


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.lists(_track(), min_size=1, max_size=8), min_size=1, max_size=6),
    st.integers(0, 12),
    st.integers(1, 10),
)
def test_records_encoded_ahead_give_the_blocks_of_the_period_end(
    batches: list[list[SystemTrackMessage]], numbers: int, chunk: int
) -> None:
    # Few numbers: tracks updated again after their record was encoded ahead.
    batches = [
        [t.model_copy(update={"number": t.number % (numbers + 1)}) for t in b] for b in batches
    ]
    period = PeriodRecords(SYSTEM, chunk)
    latest: dict[int, SystemTrackMessage] = {}
    for tracks in batches:
        period.update(_updates(tracks))
        latest.update((t.number, t) for t in tracks)
    expected = encode_system_tracks([latest[n] for n in sorted(latest)], SYSTEM)
    assert period.block() == expected
    assert period.block() == b""  # the next period starts empty


def test_a_chunk_beyond_its_items_is_refused_by_the_block_and_the_next_period_goes_on() -> None:
    period = PeriodRecords(SYSTEM, chunk=2)
    period.update(_updates([_plain(number=1), _plain(number=2, x_m=5e6, validate=False)]))
    period.update(_updates([_plain(number=3)]))
    with pytest.raises(EncodeError):
        period.block()
    period.update(_updates([_plain(number=4), _plain(number=5)]))
    assert period.block() == encode_system_tracks([_plain(number=4), _plain(number=5)], SYSTEM)
