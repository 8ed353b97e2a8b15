"""System tracks as ASTERIX CAT062 (SDPS track messages) and service status as CAT065.

Records are item dicts in the shape ``asterix.codec.decode_blocks`` returns, encoded by
the codec: what a decoder reads back equals these dicts to the items' LSBs. Quantities
beyond an item's range are capped at its maximum, which CAT062 defines as "maximum value
or above" for ages and accuracies.

Two encoders give the same bytes. ``encode_system_tracks`` (the service's path:
``encode_system_batch``, of the updates' columns, ``updates.SystemBatch``) quantises every
row of a batch at once with numpy and writes the records of each item layout as one byte
matrix, 6.5 times faster than the generic codec on a `scale` slice
(``benchmarks/bench_outputs.py``). ``encode_system_tracks_generic`` builds each record's
item dicts and encodes them with ``asterix.codec.encode_record``: the reference the fast
path is tested against, byte for byte. Both take their values from ``track_columns``, so
they differ only in the encoding. Items whose values are few and discrete (identity,
status bits, the sensor) are encoded by the codec's own item encoders and cached; only the
quantities are written here, with the items' LSBs and sizes read from the specification.
"""

from __future__ import annotations

from bisect import bisect_right
from collections.abc import Callable, Hashable, Mapping, Sequence
from dataclasses import dataclass
from fractions import Fraction
from functools import cache
from itertools import accumulate
from typing import Any, Literal, NamedTuple

import numpy as np
import numpy.typing as npt

from asterix import spec
from asterix.codec import codec, encode_block, encode_record
from asterix.engine import EncodeError, build_fspec
from tracker_service.geodesy.ellipsoid import meridian_radius_m, prime_vertical_radius_m
from tracker_service.geodesy.plane import SystemPlane
from tracker_service.outputs.messages import SystemTrackMessage
from tracker_service.outputs.sdps import SdpsIdentity
from tracker_service.outputs.updates import STATUSES, SystemBatch, SystemUpdate, SystemValues

__all__ = [
    "CAT062",
    "CAT065",
    "MAX_BLOCK_OCTETS",
    "PeriodRecords",
    "TrackColumns",
    "encode_cat065",
    "encode_system_batch",
    "encode_system_tracks",
    "encode_system_tracks_generic",
    "system_track_records",
    "track_columns",
]

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
CHUNK_TRACKS = 256
"""``PeriodRecords`` encodes the tracks waiting whenever this many wait: ~4 ms of CPU
each on ``artas`` at 4,000 tracks (~2.3 ms of numpy calls whatever the rows, ~7 us a
track), nine times a second, where the whole second's ~1,800 tracks at once took 16-19
ms (docs/benchmarks.md, "Session 16"). Smaller chunks would cost more in all: the fixed
part is paid per chunk."""

Cat065Kind = Literal["sdps_status", "end_of_batch", "service_status"]
_MESSAGE_TYPE: dict[Cat065Kind, int] = {"sdps_status": 1, "end_of_batch": 2, "service_status": 3}
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]


def encode_system_tracks(
    messages: Sequence[SystemTrackMessage],
    config: SdpsIdentity,
    max_block_octets: int = MAX_BLOCK_OCTETS,
) -> bytes:
    """CAT062 data blocks of the messages, in order, each block at most
    ``max_block_octets`` long (ValueError if one record alone is longer)."""
    if not messages:
        return b""
    batch = SystemBatch.of_values([SystemValues.of_message(m) for m in messages])
    return encode_system_batch(batch, config, max_block_octets)


def encode_system_batch(
    batch: SystemBatch,
    config: SdpsIdentity,
    max_block_octets: int = MAX_BLOCK_OCTETS,
) -> bytes:
    """As :func:`encode_system_tracks`, of the messages' values column by column
    (``updates.SystemBatch``), as the service keeps them."""
    if not len(batch):
        return b""
    return _framed(*_fast_records(track_columns(batch, config), config), max_block_octets)


class PeriodRecords:
    """CAT062's periodic block (``core.Outputs.publish_cat062``): the system tracks updated
    since the last block, each by its latest update, in track-number order, with their
    records encoded ahead. Whenever ``chunk`` tracks wait, their latest updates are
    encoded at once (``encode_system_batch``'s records, cut per track), so that the block
    at the period's end encodes fewer than ``chunk`` and joins the rest: the period's work
    spread over its batches rather than one pause of the caller at its end, which grew
    with the picture. A record depends on its own row alone, so the blocks are those of
    the period's latest updates encoded at its end; a track updated again after its
    record was made is encoded again. A chunk that does not encode (a value beyond its
    item's range) is left to the block, which raises it as the encoding
    at the end did, and the period's tracks go with it."""

    def __init__(
        self,
        config: SdpsIdentity,
        chunk: int = CHUNK_TRACKS,
        max_block_octets: int = MAX_BLOCK_OCTETS,
    ) -> None:
        self.config = config
        self.chunk = chunk
        self.max_block_octets = max_block_octets
        self._waiting: dict[int, SystemUpdate] = {}
        """Each track's latest update not yet encoded."""
        self._records: dict[int, bytes] = {}
        self._ahead = True
        """False once a chunk failed: the rest of the period waits for the block."""

    def update(self, updates: Sequence[SystemUpdate]) -> None:
        waiting = self._waiting
        for update in updates:
            waiting[update.number] = update
        if self._ahead and len(waiting) >= self.chunk:
            try:
                self._records.update(self._encoded(waiting))
            except EncodeError:  # the block encodes them again and raises it
                self._ahead = False
            else:
                waiting.clear()

    def block(self) -> bytes:
        """The period's records framed in blocks (b"" when no track was updated); the next
        period starts empty, whatever this raises."""
        records, waiting = self._records, self._waiting
        self._records, self._waiting, self._ahead = {}, {}, True
        if waiting:
            records.update(self._encoded(waiting))
        ordered = [records[number] for number in sorted(records)]
        if not ordered:
            return b""
        return _framed(
            b"".join(ordered), list(accumulate(map(len, ordered))), self.max_block_octets
        )

    def _encoded(self, waiting: Mapping[int, SystemUpdate]) -> dict[int, bytes]:
        updates = list(waiting.values())
        batch = SystemBatch.gather([(u.batch, u.index) for u in updates])
        data, ends = _fast_records(track_columns(batch, self.config), self.config)
        return {
            update.number: data[start:end]
            for update, start, end in zip(updates, [0, *ends[:-1]], ends, strict=True)
        }


def encode_system_tracks_generic(
    messages: Sequence[SystemTrackMessage],
    config: SdpsIdentity,
    max_block_octets: int = MAX_BLOCK_OCTETS,
) -> bytes:
    """The same bytes as :func:`encode_system_tracks`, each record's item dicts through the
    generic codec (about 60 us a record): the reference of the fast path."""
    if not messages:
        return b""
    records = [encode_record(CAT062, r) for r in system_track_records(messages, config)]
    return _blocks(records, max_block_octets)


def _blocks(records: Sequence[bytes], max_block_octets: int) -> bytes:
    """The records framed as encode_block frames them, as many a block as fit."""
    return _framed(b"".join(records), list(accumulate(map(len, records))), max_block_octets)


def _framed(data: bytes, ends: list[int], max_block_octets: int) -> bytes:
    """Records one after another in ``data``, each ending at its entry of ``ends``,
    framed as :func:`_blocks` frames them: each block the records up to the one that
    would take it past ``max_block_octets``, found by bisection (a block a step, not a
    record)."""
    room = max_block_octets - 3
    sizes = np.diff(ends, prepend=0)
    if len(sizes) and sizes.max() > room:
        size = int(sizes[sizes > room][0])
        raise ValueError(
            f"a CAT062 record of {size} octets does not fit a block of {max_block_octets}"
        )
    blocks: list[bytes] = []
    start, first = 0, 0
    while first < len(ends) or not blocks:
        stop = bisect_right(ends, start + room, lo=first)
        end = ends[stop - 1] if stop > first else start
        blocks.append(bytes([CAT062]) + (end - start + 3).to_bytes(2) + data[start:end])
        start, first = end, stop
    return b"".join(blocks)


@dataclass(frozen=True)
class TrackColumns:
    """The CAT062 values of a batch of system tracks, one entry per track, in the items'
    units (NaN or None where an optional value is absent)."""

    time_of_day: FloatArray
    lat: FloatArray
    lon: FloatArray
    x: FloatArray
    y: FloatArray
    vx: FloatArray
    """I185: on the target's own east and north."""
    vy: FloatArray
    number: IntArray
    mode3a: IntArray
    """-1: none."""
    mode3a_changed: BoolArray
    callsign: list[str | None]
    address: IntArray
    """-1: none."""
    status: IntArray
    """(N, 10): the I080 flags of ``_STATUS_FLAGS``, then AFF and DUPM."""
    ages: FloatArray
    """(N, 4): PSR, SSR, MDS, ES ages, capped."""
    flight_level: FloatArray
    altitude_fl: FloatArray
    climb_rate_fpm: FloatArray
    apc: FloatArray
    """(N, 2): X, Y."""
    cov: FloatArray
    apw: FloatArray
    """(N, 2): LAT, LON."""
    atv: FloatArray
    """(N, 2): X, Y."""
    sensor: IntArray
    """(N, 2): SAC, SIC of the last plot's radar; -1: none."""
    rho_nm: FloatArray
    theta_deg: FloatArray
    has_dap: BoolArray
    """(N, DAPs): which Mode S DAPs each track has, by ``messages.DAP_NAMES``."""
    dap_value: FloatArray
    dap_age: FloatArray

    def __len__(self) -> int:
        return len(self.number)


def track_columns(batch: SystemBatch, config: SdpsIdentity) -> TrackColumns:
    """The CAT062 values of a batch of system-track updates, over the whole batch at once."""
    lat, lon = batch.lat, batch.lon
    plane_velocity = np.column_stack((batch.vx, batch.vy))
    # I185's axes are the target's own east and north, not the system plane's: undo the
    # plane's convergence and scale at each target (2-3 deg at 300 km from the centre).
    jacobian = _plane(config).jacobian(lat, lon)[:, :, :2]
    local_velocity = np.asarray(
        np.linalg.solve(jacobian, plane_velocity[:, :, None])[:, :, 0], dtype=np.float64
    )
    p = batch.covariance.reshape(-1, 4, 4)
    sx = np.sqrt(np.maximum(p[:, 0, 0], 0.0))
    sy = np.sqrt(np.maximum(p[:, 1, 1], 0.0))
    # Note 2 of I062/500: sign(Cov(X,Y)) * sqrt(|Cov(X,Y)|).
    cov = np.copysign(np.minimum(np.sqrt(np.abs(p[:, 0, 1])), COV_MAX_M), p[:, 0, 1])
    north_m = meridian_radius_m(lat)
    east_m = prime_vertical_radius_m(lat) * np.maximum(np.cos(np.radians(lat)), 1e-9)
    radars = np.full((len(batch.radar_names) + 1, 2), -1, dtype=np.int64)  # the last: none
    for radar in np.unique(batch.plot_radar[batch.plot_radar >= 0]).tolist():
        radars[radar] = _sac_sic(batch.radar_names[radar])
    sensor = radars[batch.plot_radar]
    status = np.column_stack(
        (
            batch.n_sources == 1,
            batch.status == STATUSES.index("ended"),
            batch.first,
            batch.status == STATUSES.index("coasting"),
            # A sensor type that never updated the track is "older than any threshold".
            np.isnan(batch.ages),
            batch.adsb_inconsistent,
            batch.duplicate_address,
        )
    ).astype(np.int64)
    names = batch.names
    return TrackColumns(
        time_of_day=_time_of_day(batch.time),
        lat=lat,
        lon=(lon + 180.0) % 360.0 - 180.0,
        x=batch.x,
        y=batch.y,
        vx=local_velocity[:, 0],
        vy=local_velocity[:, 1],
        number=batch.number,
        mode3a=batch.mode3a,
        mode3a_changed=batch.mode3a_changed,
        callsign=[None if i < 0 else names[i] for i in batch.callsign.tolist()],
        address=batch.address,
        status=status,
        ages=np.minimum(batch.ages, AGE_MAX_S),
        flight_level=batch.flight_level,
        # I135 holds barometric altitude in FL units; QNH=1 says it is above sea level.
        altitude_fl=batch.altitude_m / 0.3048 / 100.0,
        climb_rate_fpm=batch.climb_rate_fpm,
        apc=np.minimum(np.stack([sx, sy], axis=1), APC_MAX_M),
        cov=cov,
        apw=np.minimum(
            np.stack([np.degrees(sy / north_m), np.degrees(sx / east_m)], axis=1), APW_MAX_DEG
        ),
        atv=np.minimum(
            np.sqrt(np.maximum(np.stack([p[:, 2, 2], p[:, 3, 3]], axis=1), 0.0)), ATV_MAX_MPS
        ),
        sensor=sensor,
        rho_nm=np.minimum(batch.plot_range / NM, RHO_MAX_NM),
        theta_deg=_wrapped(batch.plot_azimuth, AZIMUTH_LSB, 65536),
        has_dap=batch.has_dap,
        dap_value=batch.dap_value,
        dap_age=batch.dap_age,
    )


@cache
def _sac_sic(radar: str) -> tuple[int, int]:
    sac, sic = radar.split("/")
    return int(sac), int(sic)


def system_track_records(
    messages: Sequence[SystemTrackMessage], config: SdpsIdentity
) -> list[dict[str, Any]]:
    """The CAT062 item dicts of the messages (decoded shape)."""
    if not messages:
        return []
    batch = SystemBatch.of_values([SystemValues.of_message(m) for m in messages])
    columns = track_columns(batch, config)
    return [_record(columns, k, config) for k in range(len(columns))]


def encode_cat065(
    kind: Cat065Kind,
    time: float,
    batch_number: int,
    config: SdpsIdentity,
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
        "030": float(_time_of_day(np.array([time]))[0]),
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
def _plane(config: SdpsIdentity) -> SystemPlane:
    return SystemPlane(config.centre_lat, config.centre_lon, config.projection)


_AGE_NAMES = ("PSR", "SSR", "MDS", "ES")
_STATUS_FLAGS = ("MON", "TSE", "TSB", "CST", "PSR", "SSR", "MDS", "ADS")
"""The I080 flags that vary; the others are 0, KOS 1."""


def _present(value: float) -> bool:
    return value == value  # not NaN


def _record(c: TrackColumns, k: int, config: SdpsIdentity) -> dict[str, Any]:
    items: dict[str, Any] = {
        "010": {"SAC": config.sac, "SIC": config.sic},
        "015": config.service_id,
        "070": float(c.time_of_day[k]),
        "105": {"LAT": float(c.lat[k]), "LON": float(c.lon[k])},
        "100": {"X": float(c.x[k]), "Y": float(c.y[k])},
        "185": {"VX": float(c.vx[k]), "VY": float(c.vy[k])},
    }
    mode3a, callsign, address = _octal(int(c.mode3a[k])), c.callsign[k], _hex(int(c.address[k]))
    if mode3a is not None:
        items["060"] = {"V": 0, "G": 0, "CH": int(c.mode3a_changed[k]), "MODE3A": mode3a}
    if callsign is not None:
        items["245"] = {"STI": 0, "CHR": callsign}
    daps = {
        name: (float(c.dap_value[k, d]), float(c.dap_age[k, d]))
        for d, name in enumerate(_DAP_SUBFIELDS)
        if c.has_dap[k, d]
    }
    if address is not None or callsign is not None or daps:
        items["380"] = _aircraft_derived(address, callsign, daps)
    if daps:
        items["295"] = _dap_ages(daps)
    items["040"] = int(c.number[k])
    items["080"] = _status(tuple(c.status[k].tolist()))
    ages = {n: float(a) for n, a in zip(_AGE_NAMES, c.ages[k], strict=True) if _present(a)}
    if ages:
        items["290"] = ages
    if _present(c.flight_level[k]):
        items["136"] = float(c.flight_level[k])
    if _present(c.altitude_fl[k]):
        items["135"] = {"QNH": 1, "CTB": float(c.altitude_fl[k])}
    if _present(c.climb_rate_fpm[k]):
        items["220"] = float(c.climb_rate_fpm[k])
    items["500"] = {
        "APC": {"X": float(c.apc[k, 0]), "Y": float(c.apc[k, 1])},
        "COV": float(c.cov[k]),
        "APW": {"LAT": float(c.apw[k, 0]), "LON": float(c.apw[k, 1])},
        "ATV": {"X": float(c.atv[k, 0]), "Y": float(c.atv[k, 1])},
    }
    sac, sic = c.sensor[k].tolist()
    if sac >= 0:
        items["340"] = _measured((sac, sic), float(c.rho_nm[k]), float(c.theta_deg[k]))
    return items


def _octal(code: int) -> str | None:
    return None if code < 0 else f"{code:04o}"


def _hex(address: int) -> str | None:
    return None if address < 0 else f"{address:06X}"


def _aircraft_derived(
    address: str | None, callsign: str | None, daps: Mapping[str, tuple[float, float]]
) -> dict[str, Any]:
    # The spec prefers I380/ID to I245 for a downlinked callsign: send both.
    adr = {} if address is None else {"ADR": address}
    out = adr | ({} if callsign is None else {"ID": callsign})
    for name, (subfield, _, value_of) in _DAP_SUBFIELDS.items():
        if name in daps:
            out[subfield] = value_of(daps[name][0])
    return out


def _turn(rate_deg_s: Any) -> dict[str, Any]:
    """I380/TAR of a turn rate, or of an array of them (TI then an array)."""
    # BDS 5,0 and I380/TAR both count a right turn positive; TI says which way.
    straight = np.abs(rate_deg_s) < 0.125  # half the ROT step
    ti = np.where(straight, 3, np.where(rate_deg_s > 0, 2, 1))
    return {"TI": ti if np.ndim(ti) else int(ti), "ROT": rate_deg_s}


_DAP_SUBFIELDS: dict[str, tuple[str, str, Callable[[Any], Any]]] = {
    # message DAP name: (I380 subfield, I295 subfield, I380 value)
    "magnetic_heading_deg": ("MHG", "MHG", lambda v: v % 360.0),
    "indicated_airspeed_kt": ("IAR", "IAR", lambda v: v),
    "mach": ("MAC", "MAC", lambda v: v),
    "selected_altitude_ft": ("SAL", "SAL", lambda v: {"SAS": 0, "SRC": 0, "ALT": v}),
    "baro_rate_fpm": ("BVR", "BVR", lambda v: v),
    "inertial_rate_fpm": ("GVR", "GVR", lambda v: v),
    "roll_deg": ("RAN", "RAN", lambda v: v),
    "track_angle_rate_deg_s": ("TAR", "TAR", _turn),
    "true_track_deg": ("TAN", "TAN", lambda v: v % 360.0),
    "ground_speed_kt": ("GS", "GSP", lambda v: v / 3600.0),  # NM/s
}
"""The DAPs of the system-track messages in I380 and their ages in I295, in
``messages.DAP_NAMES`` order; each I380 value of a DAP's value, or of an array of them. The
inertial vertical rate goes to GVR (geometric vertical rate): the nearest the item has."""
_DAP_INDEX = {name: d for d, name in enumerate(_DAP_SUBFIELDS)}


def _dap_ages(daps: Mapping[str, tuple[float, float]]) -> dict[str, float]:
    return {
        age: min(daps[name][1], AGE_MAX_S)
        for name, (_, age, _) in _DAP_SUBFIELDS.items()
        if name in daps
    }


def _status(flags: tuple[int, ...]) -> dict[str, int]:
    """I080 up to its fourth extent (CST), to the sixth when DUPM is set."""
    mon, tse, tsb, cst, psr, ssr, mds, ads, aff, dupm = flags
    status = {
        "MON": mon,
        "SPI": 0,
        "MRH": 0,
        "SRC": 0,
        "CNF": 0,
        "SIM": 0,
        "TSE": tse,
        "TSB": tsb,
        "FPC": 0,
        "AFF": aff,
        "STP": 0,
        # No complementary (e.g. flight-plan) service: every track is the background one.
        "KOS": 1,
        "AMA": 0,
        "MD4": 0,
        "ME": 0,
        "MI": 0,
        "MD5": 0,
        "CST": cst,
        "PSR": psr,
        "SSR": ssr,
        "MDS": mds,
        "ADS": ads,
        "SUC": 0,
        "AAC": 0,
    }
    if dupm:
        status |= {"SDS": 0, "EMS": 0, "PFT": 0, "FPLT": 0}
        status |= {"DUPT": 0, "DUPF": 0, "DUPM": 1, "SFC": 0, "IDD": 0, "IEC": 0, "MLAT": 0}
    return status


def _measured(sensor: tuple[int, int], rho_nm: float, theta_deg: float) -> dict[str, Any]:
    measured: dict[str, Any] = {"SID": {"SAC": sensor[0], "SIC": sensor[1]}}
    if _present(rho_nm) and _present(theta_deg):
        measured["POS"] = {"RHO": rho_nm, "THETA": theta_deg}
    return measured


def _time_of_day(posix: FloatArray) -> FloatArray:
    """Seconds since UTC midnight at the item's 1/128 s LSB (0 again at midnight)."""
    return _wrapped(posix, TIME_LSB, SECONDS_PER_DAY * 128)


def _wrapped(value: FloatArray, lsb: float, modulus: int) -> FloatArray:
    """``value`` rounded to ``lsb`` and wrapped: a value that rounds up to the modulus is 0,
    where the encoder would otherwise overflow the item."""
    # np.rint rounds half to even, as the codec's round() does.
    return (np.rint(value / lsb) % modulus) * lsb


# --- the fast path ------------------------------------------------------------------------

_CODEC = codec(CAT062)
_CODEC_SPEC = _CODEC.compiled.spec
_POSITIONS = _CODEC.uap_positions[0]
_ITEM_ENCODERS: dict[str, Callable[[Any], bytes]] = {
    slot[0]: slot[2] for slot in _CODEC.uap if slot is not None
}


@dataclass(frozen=True)
class _Quantity:
    """One quantity element of the specification: its LSB and raw width."""

    lsb: float
    bits: int
    signed: bool

    def raw(self, values: FloatArray) -> IntArray | None:
        """The raw values as the codec rounds them (half to even), two's complement in
        ``bits``; None when one is beyond the element's range (the codec raises then)."""
        with np.errstate(invalid="ignore"):
            scaled = np.rint(values / self.lsb)
        low, high = (
            (-(1 << (self.bits - 1)), (1 << (self.bits - 1)) - 1)
            if self.signed
            else (0, (1 << self.bits) - 1)
        )
        if not bool(np.all((scaled >= low) & (scaled <= high))):
            return None
        return scaled.astype(np.int64) & ((1 << self.bits) - 1)


def _named(variation: spec.Variation, path: Sequence[str]) -> spec.Variation:
    for name in path:
        if isinstance(variation, spec.Group):
            fields = variation.fields
        elif isinstance(variation, spec.Compound):
            fields = tuple(s for s in variation.slots if s is not None)
        else:
            raise TypeError(f"{name}: not a group or compound")
        variation = next(
            f for f in fields if isinstance(f, spec.Named) and f.name == name
        ).variation
    return variation


def _quantity(item: str, *path: str) -> _Quantity:
    """The quantity at ``path`` inside CAT062 item ``item``, from the specification."""
    element = _named(_CODEC_SPEC.items[item].variation, path)
    assert isinstance(element, spec.Element) and isinstance(element.content, spec.Quantity)
    lsb: Fraction = element.content.lsb
    return _Quantity(float(lsb), element.bits, element.content.signed)


def _subfield_fspec(item: str, names: Sequence[str]) -> bytes:
    """The FSPEC of compound ``item`` naming ``names``, as the codec builds it."""
    compound = _CODEC_SPEC.items[item].variation
    assert isinstance(compound, spec.Compound)
    slots = _slot_names(item)
    return build_fspec(sorted(slots.index(n) for n in names), compound.fspec_octets)


def _slot_names(item: str) -> list[str | None]:
    """The subfield names of compound ``item`` in FSPEC order (None: an unused slot)."""
    compound = _CODEC_SPEC.items[item].variation
    assert isinstance(compound, spec.Compound)
    return [None if s is None else s.name for s in compound.slots]


_Q070 = _quantity("070")
_Q105 = (_quantity("105", "LAT"), _quantity("105", "LON"))
_Q100 = (_quantity("100", "X"), _quantity("100", "Y"))
_Q185 = (_quantity("185", "VX"), _quantity("185", "VY"))
_Q290 = tuple(_quantity("290", name) for name in _AGE_NAMES)
_Q136 = _quantity("136")
_Q135 = _quantity("135", "CTB")
_Q220 = _quantity("220")
_Q500_APC = (_quantity("500", "APC", "X"), _quantity("500", "APC", "Y"))
_Q500_COV = _quantity("500", "COV")
_Q500_APW = (_quantity("500", "APW", "LAT"), _quantity("500", "APW", "LON"))
_Q500_ATV = (_quantity("500", "ATV", "X"), _quantity("500", "ATV", "Y"))
_Q340_POS = (_quantity("340", "POS", "RHO"), _quantity("340", "POS", "THETA"))
_FSPEC_500 = _subfield_fspec("500", ("APC", "COV", "APW", "ATV"))
_I380_SLOTS = _slot_names("380")
_I295_SLOTS = _slot_names("295")
_Q380 = {
    subfield: _quantity("380", subfield)
    for subfield, _, _ in _DAP_SUBFIELDS.values()
    if subfield not in ("SAL", "TAR")
}
_Q380_SAL = _quantity("380", "SAL", "ALT")
_Q380_ROT = _quantity("380", "TAR", "ROT")
_Q295 = {age: _quantity("295", age) for _, age, _ in _DAP_SUBFIELDS.values()}
_QNH_SET = int.from_bytes(_ITEM_ENCODERS["135"]({"QNH": 1, "CTB": 0.0}))
_NUMBER_MAX = (1 << 16) - 1


class _OutOfRange(Exception):
    """A value beyond its element's range: the generic encoder says which."""


def _bytes(raw: IntArray, octets: int) -> npt.NDArray[np.uint8]:
    """Each raw value big-endian in ``octets`` octets: shape (N, octets)."""
    shifts = np.arange(8 * (octets - 1), -1, -8, dtype=np.int64)
    return ((raw[:, None] >> shifts) & 0xFF).astype(np.uint8)


def _quantised(quantity: _Quantity, values: FloatArray) -> IntArray:
    raw = quantity.raw(values)
    if raw is None:
        raise _OutOfRange
    return raw


def _constant(data: bytes, n: int) -> npt.NDArray[np.uint8]:
    return np.broadcast_to(np.frombuffer(data, dtype=np.uint8), (n, len(data)))


@cache
def _mode3a_bytes(code: int, changed: bool) -> bytes:
    return _ITEM_ENCODERS["060"]({"V": 0, "G": 0, "CH": int(changed), "MODE3A": _octal(code)})


@cache
def _callsign_bytes(callsign: str) -> bytes:
    return _ITEM_ENCODERS["245"]({"STI": 0, "CHR": callsign})


@cache
def _aircraft_derived_bytes(address: str | None, callsign: str | None) -> bytes:
    return _ITEM_ENCODERS["380"](_aircraft_derived(address, callsign, {}))


@cache
def _identity_subfields(address: int, callsign: str | None) -> bytes:
    """I380's ADR and ID subfields (its first two) without the FSPEC; ``address`` -1:
    none."""
    adr = _hex(address)
    names = [n for n, v in (("ADR", adr), ("ID", callsign)) if v is not None]
    return _aircraft_derived_bytes(adr, callsign)[len(_subfield_fspec("380", names)) :]


@cache
def _status_bytes(flags: tuple[int, ...]) -> bytes:
    return _ITEM_ENCODERS["080"](_status(flags))


@cache
def _source_bytes(config: SdpsIdentity) -> tuple[bytes, bytes]:
    return (
        _ITEM_ENCODERS["010"]({"SAC": config.sac, "SIC": config.sic}),
        _ITEM_ENCODERS["015"](config.service_id),
    )


class _Part(NamedTuple):
    """One part of every row's record: its octets, (N, width), and which of them the row
    has, (N, width) or (N, 1) (a part of one size that a row has or has not)."""

    octets: npt.NDArray[np.uint8]
    present: BoolArray


def _fixed(octets: npt.NDArray[np.uint8], present: BoolArray | None = None) -> _Part:
    n = len(octets)
    return _Part(octets, np.ones((n, 1), dtype=bool) if present is None else present[:, None])


def _variable(keys: Sequence[Hashable | None], encode: Callable[[Any], bytes]) -> _Part:
    """A part whose octets follow from a key of the row (None: the row has none), encoded
    once per distinct key: a callsign, the identity subfields of I380."""
    table: dict[Hashable, int] = {}
    index = [-1 if key is None else table.setdefault(key, len(table)) for key in keys]
    return _looked_up(np.array(index, dtype=np.int64), [encode(key) for key in table])


def _coded(codes: IntArray, encode: Callable[[int], bytes]) -> _Part:
    """A part whose octets follow from an integer of the row, encoded once per distinct
    integer (b"": the row has none)."""
    unique, inverse = np.unique(codes, return_inverse=True)
    return _looked_up(inverse.astype(np.int64), [encode(code) for code in unique.tolist()])


def _flagged(flags: BoolArray, encode: Callable[[tuple[int, ...]], bytes]) -> _Part:
    """A part whose octets follow from flags of the row, (N, k): an FSPEC (which items or
    subfields the row has), I080's extents (its flags); encoded once per distinct set."""
    k = flags.shape[1]
    codes = flags.astype(np.int64) @ (1 << np.arange(k, dtype=np.int64))
    return _coded(codes, lambda code: _flags_encoded(encode, k, code))


@cache
def _flags_encoded(encode: Callable[[tuple[int, ...]], bytes], k: int, code: int) -> bytes:
    """``encode`` of the ``k`` flags that are the bits of ``code``: kept across batches (a
    few dozen sets a part), where each batch's distinct sets were encoded again."""
    return encode(tuple(code >> i & 1 for i in range(k)))


@cache
def _fspec_of(item: str, names: tuple[str, ...]) -> Callable[[tuple[int, ...]], bytes]:
    """The FSPEC of compound ``item`` (b"" for none) of flags for ``names``: one function
    a compound, so that ``_flags_encoded`` knows it again."""

    def fspec(flags: tuple[int, ...]) -> bytes:
        there = [name for name, flag in zip(names, flags, strict=True) if flag]
        return _subfield_fspec(item, there) if there else b""

    return fspec


@cache
def _record_fspec(positions: tuple[int, ...]) -> Callable[[tuple[int, ...]], bytes]:
    """The record's FSPEC of flags for the items at UAP ``positions``."""

    def fspec(flags: tuple[int, ...]) -> bytes:
        return build_fspec([p for p, there in zip(positions, flags, strict=True) if there], 0)

    return fspec


@cache
def _mode3a_code_bytes(code: int) -> bytes:
    """I060 of ``code``: the Mode 3/A code times 2 plus its change bit; -1: none (b"")."""
    return b"" if code < 0 else _mode3a_bytes(code >> 1, bool(code & 1))


def _looked_up(index: IntArray, encoded: list[bytes]) -> _Part:
    """Row k has ``encoded[index[k]]`` (-1: nothing)."""
    lengths = np.array([*map(len, encoded), 0], dtype=np.int64)
    width = int(lengths.max())
    # Most parts have one size (a callsign's 7 octets): no padding to make then.
    padded = encoded if (lengths[:-1] == width).all() else [e.ljust(width, b"\0") for e in encoded]
    rows = np.frombuffer(b"".join(padded) + bytes(width), dtype=np.uint8).reshape(
        len(encoded) + 1, width
    )
    # -1: the zero row at the end, of length 0.
    return _Part(rows[index], np.arange(width) < lengths[index][:, None])


def _quantities(
    quantity: _Quantity, values: FloatArray, octets: int, present: BoolArray | None = None
) -> _Part:
    """``values`` quantised (``_quantised``) big-endian in ``octets`` octets, over the rows
    ``present`` (None: all) only: an absent value is anything, NaN mostly."""
    if present is None:
        return _fixed(_bytes(_quantised(quantity, values), octets))
    raw = np.zeros(len(values), dtype=np.int64)
    rows = np.flatnonzero(present)
    if rows.size:
        raw[rows] = _quantised(quantity, values[rows])
    return _fixed(_bytes(raw, octets), present)


def _fast_records(c: TrackColumns, config: SdpsIdentity) -> tuple[bytes, list[int]]:
    """The records of every row one after another, and where each ends: byte for byte
    what ``encode_record`` makes of
    ``system_track_records``; a value beyond its item's range goes to the generic encoder,
    which raises ``EncodeError`` naming it, as before.

    Every row's record is a row of one octet matrix over all the rows, each item's parts
    in their columns in the record's order, with a mask of the octets each row has (its
    FSPEC, its optional items and subfields): the records are the masked octets in row
    order, cut at each row's size. Some 150 numpy calls for the whole batch, whatever
    its mix of items (a second's ~2,000 tracks on ``artas`` came in ~25 layouts of
    30 calls each)."""
    try:
        parts = _record_parts(c, config)
    except _OutOfRange:
        records = [encode_record(CAT062, _record(c, k, config)) for k in range(len(c))]
        return b"".join(records), list(accumulate(map(len, records)))
    octets = np.hstack([part.octets for part in parts])
    present = np.hstack([np.broadcast_to(p.present, p.octets.shape) for p in parts])
    return octets[present].tobytes(), np.cumsum(present.sum(axis=1)).tolist()


def _record_parts(c: TrackColumns, config: SdpsIdentity) -> list[_Part]:
    """The parts of every row's record in the record's order (``_fast_records``): the
    FSPEC, then each item's, in the UAP's order."""
    n = len(c)
    source, service = _source_bytes(config)
    has_mode3a = c.mode3a >= 0
    callsigns = c.callsign
    has_callsign = np.array([v is not None for v in callsigns], dtype=bool)
    has_address = c.address >= 0
    has_dap = c.has_dap
    has_daps: BoolArray = np.asarray(has_dap.any(axis=1), dtype=bool)
    has_age = ~np.isnan(c.ages)
    has_sensor = c.sensor[:, 0] >= 0
    has_pos = has_sensor & ~np.isnan(c.rho_nm) & ~np.isnan(c.theta_deg)
    items: dict[str, tuple[BoolArray | None, list[_Part]]] = {
        "010": (None, [_fixed(_constant(source, n))]),
        "015": (None, [_fixed(_constant(service, n))]),
        "070": (None, [_quantities(_Q070, c.time_of_day, 3)]),
        "105": (None, [_quantities(q, v, 4) for q, v in zip(_Q105, (c.lat, c.lon), strict=True)]),
        "100": (None, [_quantities(q, v, 3) for q, v in zip(_Q100, (c.x, c.y), strict=True)]),
        "185": (None, [_quantities(q, v, 2) for q, v in zip(_Q185, (c.vx, c.vy), strict=True)]),
    }
    items["060"] = (
        has_mode3a,
        [_coded(np.where(has_mode3a, c.mode3a * 2 + c.mode3a_changed, -1), _mode3a_code_bytes)],
    )
    items["245"] = (has_callsign, [_variable(callsigns, _callsign_bytes)])
    items["380"] = (
        has_address | has_callsign | has_daps,
        _aircraft_derived_parts(c, has_address, has_callsign),
    )
    items["295"] = (has_daps, _dap_age_parts(c))
    number = c.number
    if n and (number.min() < 0 or number.max() > _NUMBER_MAX):
        raise _OutOfRange
    items["040"] = (None, [_fixed(_bytes(number, 2))])
    items["080"] = (None, [_flagged(c.status.astype(bool), _status_bytes)])
    has_ages: BoolArray = np.asarray(has_age.any(axis=1), dtype=bool)
    items["290"] = (
        has_ages,
        [
            _flagged(has_age, _fspec_of("290", _AGE_NAMES)),
            *(_quantities(q, c.ages[:, i], 1, has_age[:, i]) for i, q in enumerate(_Q290)),
        ],
    )
    has_fl, has_alt = ~np.isnan(c.flight_level), ~np.isnan(c.altitude_fl)
    has_climb = ~np.isnan(c.climb_rate_fpm)
    items["136"] = (has_fl, [_quantities(_Q136, c.flight_level, 2, has_fl)])
    alt = _quantities(_Q135, c.altitude_fl, 2, has_alt)
    qnh = _bytes(np.full(n, _QNH_SET, dtype=np.int64), 2)
    items["135"] = (has_alt, [_fixed(alt.octets | qnh, has_alt)])
    items["220"] = (has_climb, [_quantities(_Q220, c.climb_rate_fpm, 2, has_climb)])
    items["500"] = (
        None,
        [
            _fixed(_constant(_FSPEC_500, n)),
            *(_quantities(q, c.apc[:, i], 2) for i, q in enumerate(_Q500_APC)),
            _quantities(_Q500_COV, c.cov, 2),
            *(_quantities(q, c.apw[:, i], 2) for i, q in enumerate(_Q500_APW)),
            *(_quantities(q, c.atv[:, i], 1) for i, q in enumerate(_Q500_ATV)),
        ],
    )
    sensors = c.sensor[has_sensor]
    if sensors.size and (sensors.min() < 0 or sensors.max() > 255):
        raise _OutOfRange
    items["340"] = (
        has_sensor,
        [
            _flagged(np.column_stack((has_sensor, has_pos)), _fspec_of("340", ("SID", "POS"))),
            _fixed(np.maximum(c.sensor, 0).astype(np.uint8), has_sensor),
            *(
                _quantities(q, v, 2, has_pos)
                for q, v in zip(_Q340_POS, (c.rho_nm, c.theta_deg), strict=True)
            ),
        ],
    )
    order = sorted(items, key=_POSITIONS.__getitem__)
    columns = []
    for item in order:
        there = items[item][0]
        columns.append(np.ones(n, dtype=bool) if there is None else there)
    present = np.column_stack(columns)
    positions = [_POSITIONS[item] for item in order]
    fspec = _flagged(present, _record_fspec(tuple(positions)))
    return [fspec, *(part for item in order for part in items[item][1])]


def _aircraft_derived_parts(
    c: TrackColumns, has_address: BoolArray, has_callsign: BoolArray
) -> list[_Part]:
    """I380 of every row: the FSPEC, the cached identity subfields, each DAP's subfield
    quantised over the rows that have it, in slot order."""
    dap_names = list(_DAP_SUBFIELDS)
    subfields = {name: _DAP_SUBFIELDS[name][0] for name in dap_names}
    has_dap = c.has_dap
    addresses = c.address.tolist()
    parts = [
        _flagged(
            np.column_stack((has_address, has_callsign, has_dap)),
            _fspec_of("380", ("ADR", "ID", *subfields.values())),
        ),
        _variable(
            [
                (address, callsign) if address >= 0 or callsign is not None else None
                for address, callsign in zip(addresses, c.callsign, strict=True)
            ],
            lambda key: _identity_subfields(*key),
        ),
    ]
    for name in sorted(dap_names, key=lambda d: _I380_SLOTS.index(subfields[d])):
        there = has_dap[:, _DAP_INDEX[name]]
        raw = np.zeros(len(c), dtype=np.int64)
        rows = np.flatnonzero(there)
        if rows.size:
            value = _DAP_SUBFIELDS[name][2](c.dap_value[rows, _DAP_INDEX[name]])
            if name == "selected_altitude_ft":  # SAS and SRC 0, ALT in the low 13 bits
                raw[rows] = _quantised(_Q380_SAL, value["ALT"])
            elif name == "track_angle_rate_deg_s":  # TI (2 bits), 6 spare, ROT (7), 1 spare
                turn = _quantised(_Q380_ROT, value["ROT"])
                raw[rows] = value["TI"].astype(np.int64) << 14 | turn << 1
            else:
                raw[rows] = _quantised(_Q380[subfields[name]], value)
        parts.append(_fixed(_bytes(raw, 2), there))
    return parts


def _dap_age_parts(c: TrackColumns) -> list[_Part]:
    """I295 of every row: the FSPEC and each DAP's age, in slot order."""
    ages = {_DAP_SUBFIELDS[name][1]: name for name in _DAP_SUBFIELDS}
    order = sorted(ages, key=_I295_SLOTS.index)
    has = [c.has_dap[:, _DAP_INDEX[ages[age]]] for age in order]
    parts = [_flagged(np.column_stack(has), _fspec_of("295", tuple(order)))]
    for age, there in zip(order, has, strict=True):
        values = np.minimum(c.dap_age[:, _DAP_INDEX[ages[age]]], AGE_MAX_S)
        parts.append(_quantities(_Q295[age], values, 1, there))
    return parts
