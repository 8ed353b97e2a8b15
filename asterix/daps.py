"""Mode S downlinked aircraft parameters (DAPs) of I048/250 as plot columns.

The plot path (``asterix.plots``) reads each record's I048/250 repetitions and decodes the
registers the tracker uses, BDS 4,0, 5,0 and 6,0, into float columns (NaN when the
register is absent, its status bit 0, or the radar did not identify the register: BDS1 =
BDS2 = 0 is left to ``bds.infer_register`` in the general decoder). The bit positions,
signs and LSBs come from ``bds.LAYOUTS``, the same table as the general decoder's, so
the values are identical to ``bds.decode_mb``. Two forms, as in ``asterix.plots``: one
record at a time (small datagrams) and over arrays (large ones).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.bds import LAYOUTS, MB_BITS

_REGISTERS = {"4,0": 0x40, "5,0": 0x50, "6,0": 0x60}
"""The registers read, by their BDS1/BDS2 octet."""

_COLUMN_OF_FIELD = {
    "selected_altitude_mcp_ft": "selected_altitude_mcp_ft",
    "selected_altitude_fms_ft": "selected_altitude_fms_ft",
    "roll_deg": "roll_deg",
    "track_angle_deg": "true_track_deg",
    "ground_speed_kt": "ground_speed_kt",
    "track_angle_rate_deg_s": "track_angle_rate_deg_s",
    "true_airspeed_kt": "true_airspeed_kt",
    "magnetic_heading_deg": "magnetic_heading_deg",
    "indicated_airspeed_kt": "indicated_airspeed_kt",
    "mach": "mach",
    "baro_vertical_rate_ft_min": "baro_rate_fpm",
    "inertial_vertical_rate_ft_min": "inertial_rate_fpm",
}
"""Register field -> plot column. BDS 5,0 "track angle" is the true track angle."""

DAP_COLUMNS = tuple(_COLUMN_OF_FIELD.values())
"""The DAP columns every CAT048 plot row carries (floats, NaN when absent)."""


@dataclass(frozen=True)
class _DapField:
    column: int  # index in DAP_COLUMNS
    status_shift: int
    value_shift: int
    mask: int
    sign_shift: int  # -1: unsigned
    span: int  # 2 ** (sign + value bits), for two's complement
    wraps: bool
    lsb: float


def _shift(first: int, width: int) -> int:
    return MB_BITS - first - width + 1


def _fields() -> dict[int, tuple[_DapField, ...]]:
    by_code = {}
    for register, code in _REGISTERS.items():
        fields = []
        for f in LAYOUTS[register].fields:
            if f.name not in _COLUMN_OF_FIELD:
                continue
            signed = f.sign_bit is not None
            fields.append(
                _DapField(
                    column=DAP_COLUMNS.index(_COLUMN_OF_FIELD[f.name]),
                    status_shift=_shift(f.status_bit, 1),
                    value_shift=_shift(f.first_bit, f.width),
                    mask=(1 << f.width) - 1,
                    sign_shift=_shift(f.sign_bit, 1) if f.sign_bit is not None else -1,
                    span=1 << (f.width + signed),
                    wraps=f.wraps_360,
                    lsb=float(f.lsb),
                )
            )
            assert f.offset == 0, "DAP fields used here have no offset"
        by_code[code] = tuple(fields)
    return by_code


_FIELDS = _fields()


def decode_record(data: bytes, at: int, out: list[Any], first: int) -> None:
    """The DAPs of one record's I048/250 starting at ``at`` (its repetition octet), into
    ``out[first + i]`` for DAP column i. A later repetition of a register wins."""
    for k in range(data[at]):
        p = at + 1 + 8 * k
        fields = _FIELDS.get(data[p + 7])
        if fields is None:
            continue
        mb = int.from_bytes(data[p : p + 7])
        for f in fields:
            if not (mb >> f.status_shift) & 1:
                continue
            steps = (mb >> f.value_shift) & f.mask
            if f.sign_shift >= 0 and (mb >> f.sign_shift) & 1:
                steps += f.span >> 1
                if not f.wraps:
                    steps -= f.span
            out[first + f.column] = steps * f.lsb


@dataclass(frozen=True)
class _Register:
    """The fields of one register as arrays (``_DapField`` by field), for all at once."""

    columns: npt.NDArray[np.intp]
    status_shifts: npt.NDArray[np.uint64]
    value_shifts: npt.NDArray[np.uint64]
    masks: npt.NDArray[np.uint64]
    sign_shifts: npt.NDArray[np.uint64]
    signed: npt.NDArray[np.int64]
    negative_steps: npt.NDArray[np.int64]
    """What a set sign bit adds to the steps: half the span, less the span unless the
    field wraps (an angle over 360 degrees)."""
    lsbs: npt.NDArray[np.float64]


def _register(fields: tuple[_DapField, ...]) -> _Register:
    return _Register(
        columns=np.array([f.column for f in fields], np.intp),
        status_shifts=np.array([f.status_shift for f in fields], np.uint64),
        value_shifts=np.array([f.value_shift for f in fields], np.uint64),
        masks=np.array([f.mask for f in fields], np.uint64),
        sign_shifts=np.array([max(f.sign_shift, 0) for f in fields], np.uint64),
        signed=np.array([f.sign_shift >= 0 for f in fields], np.int64),
        negative_steps=np.array(
            [(f.span >> 1) - (0 if f.wraps else f.span) for f in fields], np.int64
        ),
        lsbs=np.array([f.lsb for f in fields], np.float64),
    )


_REGISTER_ARRAYS = {code: _register(fields) for code, fields in _FIELDS.items()}


def decode_columns(
    buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]
) -> dict[str, npt.NDArray[np.float64]]:
    """The DAP columns of records whose I048/250 start at ``starts`` (-1: absent): every
    repetition of every record at once, each register's fields at once. A later
    repetition of a register wins, as in ``decode_record``."""
    n = len(starts)
    out = np.full((len(DAP_COLUMNS), n), np.nan)
    rows = np.flatnonzero(starts >= 0)
    if len(rows):
        at = starts[rows]
        reps = buf[at].astype(np.int64)
        total = int(reps.sum())
        # One entry per repetition, by record and then repetition.
        record = np.repeat(rows, reps)
        before = np.repeat(np.cumsum(reps) - reps, reps)
        first = np.repeat(at + 1, reps) + 8 * (np.arange(total) - before)
        code = buf[first + 7]
        # The 56 MB bits: the big-endian word of the repetition's 8 octets, less its code.
        mb = buf[first[:, None] + np.arange(8)].view(">u8")[:, 0] >> np.uint64(8)
        for register_code, register in _REGISTER_ARRAYS.items():
            sel = np.flatnonzero(code == register_code)
            if not sel.size:
                continue
            m = mb[sel][:, None]
            status = ((m >> register.status_shifts) & np.uint64(1)).astype(bool)
            steps = ((m >> register.value_shifts) & register.masks).astype(np.int64)
            negative = ((m >> register.sign_shifts) & np.uint64(1)).astype(np.int64)
            steps += negative * register.signed * register.negative_steps
            r, f = np.nonzero(status)
            out[register.columns[f], record[sel][r]] = steps[r, f] * register.lsbs[f]
    return dict(zip(DAP_COLUMNS, out, strict=True))
