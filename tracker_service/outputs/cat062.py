"""System tracks as ASTERIX CAT062 (SDPS track messages) and service status as CAT065.

Records are item dicts in the shape ``asterix.codec.decode_blocks`` returns, encoded by
the codec: what a decoder reads back equals these dicts to the items' LSBs. Quantities
beyond an item's range are capped at its maximum, which CAT062 defines as "maximum value
or above" for ages and accuracies.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from functools import cache
from typing import Any, Literal

import numpy as np

from asterix.codec import encode_block, encode_record
from tracker_service.geodesy.ellipsoid import meridian_radius_m, prime_vertical_radius_m
from tracker_service.geodesy.plane import SystemPlane
from tracker_service.outputs.messages import SystemTrackMessage
from tracker_service.service.config import SystemConfig

CAT062 = 62
CAT065 = 65
MAX_BLOCK_OCTETS = 1400
"""One block per Ethernet frame (1500 octets less IP/UDP headers), for tools that read
CAT062 from UDP as well as from Zenoh."""

NM = 1852.0
SECONDS_PER_DAY = 86_400
TIME_LSB = 1.0 / 128.0
AZIMUTH_LSB = 360.0 / 65536.0
AGE_MAX_S = 255 / 4
APC_MAX_M = 65535 / 2
COV_MAX_M = 32767 / 2
APW_MAX_DEG = 65535 * 180.0 / 2**25
ATV_MAX_MPS = 255 / 4
RHO_MAX_NM = 65535 / 256

Cat065Kind = Literal["sdps_status", "end_of_batch", "service_status"]
_MESSAGE_TYPE: dict[Cat065Kind, int] = {"sdps_status": 1, "end_of_batch": 2, "service_status": 3}


def encode_system_tracks(
    messages: Sequence[SystemTrackMessage],
    config: SystemConfig,
    max_block_octets: int = MAX_BLOCK_OCTETS,
) -> bytes:
    """CAT062 data blocks of the messages, in order, each block at most
    ``max_block_octets`` long (ValueError if one record alone is longer)."""
    if not messages:
        return b""
    # Each record is encoded once and the blocks framed here, as encode_block frames
    # them: encoding is most of the cost (about 60 us per record), so not twice.
    blocks: list[bytes] = []
    group: list[bytes] = []
    size = 3
    for record in system_track_records(messages, config):
        encoded = encode_record(CAT062, record)
        if len(encoded) + 3 > max_block_octets:
            raise ValueError(
                f"a CAT062 record of {len(encoded)} octets does not fit a block of "
                f"{max_block_octets}"
            )
        if size + len(encoded) > max_block_octets:
            blocks.append(_block(group, size))
            group, size = [], 3
        group.append(encoded)
        size += len(encoded)
    blocks.append(_block(group, size))
    return b"".join(blocks)


def _block(records: list[bytes], size: int) -> bytes:
    return bytes([CAT062]) + size.to_bytes(2) + b"".join(records)


def system_track_records(
    messages: Sequence[SystemTrackMessage], config: SystemConfig
) -> list[dict[str, Any]]:
    """The CAT062 item dicts of the messages (decoded shape)."""
    if not messages:
        return []
    lat = np.array([m.lat for m in messages])
    lon = np.array([m.lon for m in messages])
    plane_velocity = np.array([[m.vx_mps, m.vy_mps] for m in messages])
    # I185's axes are the target's own east and north, not the system plane's: undo the
    # plane's convergence and scale at each target (2-3 deg at 300 km from the centre).
    jacobian = _plane(config).jacobian(lat, lon)[:, :, :2]
    local_velocity = np.linalg.solve(jacobian, plane_velocity[:, :, None])[:, :, 0]
    return [
        _record(m, config, float(v[0]), float(v[1]))
        for m, v in zip(messages, local_velocity, strict=True)
    ]


def encode_cat065(
    kind: Cat065Kind,
    time: float,
    batch_number: int,
    config: SystemConfig,
    *,
    degraded: bool = False,
    overload: bool = False,
    report: int | None = None,
) -> bytes:
    """One CAT065 block: SDPS status (I040 from ``degraded`` and ``overload``), end of
    batch, or a service status report (I050 ``report``, a code of the CAT065 table,
    e.g. 1 service degradation, 2 degradation ended)."""
    record: dict[str, Any] = {
        "010": {"SAC": config.sac, "SIC": config.sic},
        "000": _MESSAGE_TYPE[kind],
        "015": config.service_id,
        "030": _time_of_day(time),
        "020": batch_number % 256,
    }
    if kind == "sdps_status":
        record["040"] = {
            "NOGO": int(degraded),
            "OVL": int(overload),
            "TSV": 0,
            "PSS": 0,
            "STTN": 0,
        }
    elif kind == "service_status":
        if report is None:
            raise ValueError("a CAT065 service status message needs its report code (I050)")
        record["050"] = report
    return encode_block(CAT065, [record])


@cache
def _plane(config: SystemConfig) -> SystemPlane:
    return SystemPlane(config.centre_lat, config.centre_lon, config.projection)


def _record(m: SystemTrackMessage, config: SystemConfig, vx: float, vy: float) -> dict[str, Any]:
    items: dict[str, Any] = {
        "010": {"SAC": config.sac, "SIC": config.sic},
        "015": config.service_id,
        "070": _time_of_day(m.time),
        "105": {"LAT": m.lat, "LON": (m.lon + 180.0) % 360.0 - 180.0},
        "100": {"X": m.x_m, "Y": m.y_m},
        "185": {"VX": vx, "VY": vy},
    }
    if m.mode3a is not None:
        items["060"] = {"V": 0, "G": 0, "CH": int(m.mode3a_changed), "MODE3A": m.mode3a}
    if m.callsign is not None:
        items["245"] = {"STI": 0, "CHR": m.callsign}
    if m.address is not None or m.callsign is not None:
        # The spec prefers I380/ID to I245 for a downlinked callsign: send both.
        adr = {} if m.address is None else {"ADR": m.address}
        items["380"] = adr | ({} if m.callsign is None else {"ID": m.callsign})
    items["040"] = m.number
    items["080"] = _status(m)
    ages = _ages(m)
    if ages:
        items["290"] = ages
    if m.flight_level is not None:
        items["136"] = m.flight_level
    if m.altitude_m is not None:
        # I135 holds barometric altitude in FL units; QNH=1 says it is above sea level.
        items["135"] = {"QNH": 1, "CTB": m.altitude_m / 0.3048 / 100.0}
    if m.climb_rate_fpm is not None:
        items["220"] = m.climb_rate_fpm
    items["500"] = _accuracies(m)
    if m.last_plot is not None:
        items["340"] = _measured(m)
    return items


def _status(m: SystemTrackMessage) -> dict[str, int]:
    """I080 up to its fourth extent (CST), to the sixth when DUPM is set."""
    ages = m.ages
    status = {
        "MON": int(len(m.sources) == 1),
        "SPI": 0,
        "MRH": 0,
        "SRC": 0,
        "CNF": 0,
        "SIM": 0,
        "TSE": int(m.status == "ended"),
        "TSB": int(m.first),
        "FPC": 0,
        "AFF": 0,
        "STP": 0,
        # No complementary (e.g. flight-plan) service: every track is the background one.
        "KOS": 1,
        "AMA": 0,
        "MD4": 0,
        "ME": 0,
        "MI": 0,
        "MD5": 0,
        "CST": int(m.status == "coasting"),
        # A sensor type that never updated the track is "older than any threshold".
        "PSR": int(ages.psr is None),
        "SSR": int(ages.ssr is None),
        "MDS": int(ages.mode_s is None),
        "ADS": int(ages.adsb is None),
        "SUC": 0,
        "AAC": 0,
    }
    if m.duplicate_address:
        status |= {"SDS": 0, "EMS": 0, "PFT": 0, "FPLT": 0}
        status |= {"DUPT": 0, "DUPF": 0, "DUPM": 1, "SFC": 0, "IDD": 0, "IEC": 0, "MLAT": 0}
    return status


def _ages(m: SystemTrackMessage) -> dict[str, float]:
    pairs = (
        ("PSR", m.ages.psr),
        ("SSR", m.ages.ssr),
        ("MDS", m.ages.mode_s),
        ("ES", m.ages.adsb),
    )
    return {name: min(age, AGE_MAX_S) for name, age in pairs if age is not None}


def _accuracies(m: SystemTrackMessage) -> dict[str, Any]:
    p = m.covariance
    sx, sy = math.sqrt(max(p[0][0], 0.0)), math.sqrt(max(p[1][1], 0.0))
    # Note 2 of I062/500: sign(Cov(X,Y)) * sqrt(|Cov(X,Y)|).
    cov = math.copysign(min(math.sqrt(abs(p[0][1])), COV_MAX_M), p[0][1])
    north_m = float(meridian_radius_m(m.lat))
    east_m = float(prime_vertical_radius_m(m.lat)) * max(math.cos(math.radians(m.lat)), 1e-9)
    return {
        "APC": {"X": min(sx, APC_MAX_M), "Y": min(sy, APC_MAX_M)},
        "COV": cov,
        "APW": {
            "LAT": min(math.degrees(sy / north_m), APW_MAX_DEG),
            "LON": min(math.degrees(sx / east_m), APW_MAX_DEG),
        },
        "ATV": {
            "X": min(math.sqrt(max(p[2][2], 0.0)), ATV_MAX_MPS),
            "Y": min(math.sqrt(max(p[3][3], 0.0)), ATV_MAX_MPS),
        },
    }


def _measured(m: SystemTrackMessage) -> dict[str, Any]:
    plot = m.last_plot
    assert plot is not None
    sac, sic = (int(part) for part in plot.radar.split("/"))
    measured: dict[str, Any] = {"SID": {"SAC": sac, "SIC": sic}}
    if plot.range_m is not None and plot.azimuth_deg is not None:
        measured["POS"] = {
            "RHO": min(plot.range_m / NM, RHO_MAX_NM),
            "THETA": _wrapped(plot.azimuth_deg, AZIMUTH_LSB, 65536),
        }
    return measured


def _time_of_day(posix: float) -> float:
    """Seconds since UTC midnight at the item's 1/128 s LSB (0 again at midnight)."""
    return _wrapped(posix, TIME_LSB, SECONDS_PER_DAY * 128)


def _wrapped(value: float, lsb: float, modulus: int) -> float:
    """``value`` rounded to ``lsb`` and wrapped: a value that rounds up to the modulus is 0,
    where the encoder would otherwise overflow the item."""
    return (round(value / lsb) % modulus) * lsb
