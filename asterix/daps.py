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


def decode_columns(
    buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]
) -> dict[str, npt.NDArray[np.float64]]:
    """The DAP columns of records whose I048/250 start at ``starts`` (-1: absent)."""
    n = len(starts)
    out = {name: np.full(n, np.nan) for name in DAP_COLUMNS}
    rows = np.flatnonzero(starts >= 0)
    if not len(rows):
        return out
    at = starts[rows]
    reps = buf[at].astype(np.int64)
    for k in range(int(reps.max(initial=0))):
        has = reps > k
        r, p = rows[has], at[has] + 1 + 8 * k
        code = buf[p + 7]
        mb = np.zeros(len(p), dtype=np.uint64)
        for i in range(7):
            mb = (mb << np.uint64(8)) | buf[p + i]
        for register_code, fields in _FIELDS.items():
            sel = code == register_code
            if not sel.any():
                continue
            m, target = mb[sel], r[sel]
            for f in fields:
                status = ((m >> np.uint64(f.status_shift)) & np.uint64(1)).astype(bool)
                steps = ((m >> np.uint64(f.value_shift)) & np.uint64(f.mask)).astype(np.int64)
                if f.sign_shift >= 0:
                    negative = ((m >> np.uint64(f.sign_shift)) & np.uint64(1)).astype(np.int64)
                    steps += negative * ((f.span >> 1) - (0 if f.wraps else f.span))
                out[DAP_COLUMNS[f.column]][target[status]] = steps[status] * f.lsb
    return out
