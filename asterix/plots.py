"""The plot-extraction path: CAT048 bytes straight to numpy columns for the tracker.

The general decoder builds a dict per item; a tracker fed with tens of radars needs only a
dozen fields per plot. This path walks each record once to find where the wanted items
start (stepping over the others by their size), then reads every column for all records
at once with numpy. Where each field sits (octet, shift, width, LSB) is derived from the
same specification model as the general decoder, so the values are identical to it.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix import spec
from asterix.codec import DecodeError, codec
from asterix.engine import (
    ICAO_CHARACTERS,
    PLAN_CACHE_LIMIT,
    Malformed,
    Skipper,
    field_layout,
    skipper,
)
from asterix.spec import Element, Extended, Group, Integer, Named, Quantity, Spare, String

CAT = 48


@dataclass(frozen=True)
class Column:
    """A plot column: an element of a CAT048 item, by item key and element path."""

    name: str
    item: str
    path: tuple[str, ...] = ()


COLUMNS = (
    Column("sac", "010", ("SAC",)),
    Column("sic", "010", ("SIC",)),
    Column("time_of_day", "140"),
    Column("typ", "020", ("TYP",)),
    Column("sim", "020", ("SIM",)),
    Column("spi", "020", ("SPI",)),
    Column("rab", "020", ("RAB",)),
    Column("tst", "020", ("TST",)),
    Column("rho", "040", ("RHO",)),
    Column("theta", "040", ("THETA",)),
    Column("mode3a", "070", ("MODE3A",)),
    Column("mode3a_invalid", "070", ("V",)),
    Column("mode3a_garbled", "070", ("G",)),
    Column("mode3a_smoothed", "070", ("L",)),
    Column("flight_level", "090", ("FL",)),
    Column("flight_level_invalid", "090", ("V",)),
    Column("flight_level_garbled", "090", ("G",)),
    Column("address", "220"),
    Column("track_number", "161", ("TRN",)),
    Column("height_3d", "110", ("3DH",)),
    Column("ground_speed", "200", ("GSP",)),
    Column("heading", "200", ("HDG",)),
)
"""Floats (NaN when absent) for quantities, integers (-1 when absent) for the rest.
``mode3a`` is the 12-bit code as an integer (print it with ``%04o``), ``address`` the
24-bit ICAO address. V bits keep the spec's sense: 1 = not validated."""


@dataclass(frozen=True)
class _Field:
    column: Column
    offset: int  # octet offset of the element's octets within the item
    octets: int
    shift: int
    bits: int
    extent: int  # extent index for extended items (present only when earlier FX bits set)
    lsb: float | None
    signed: bool


def _locate(column: Column) -> _Field:
    """Where an element sits inside its item, from the specification model."""
    item = spec.category(CAT).items[column.item]
    variation = item.variation
    if isinstance(variation, Extended):
        offset = 0
        for index, extent in enumerate(variation.extents):
            fields: tuple[Named | Spare, ...] = (*extent, Spare(1))
            octets = sum(_bits(f) for f in fields) // 8
            for f, shift, bits in field_layout(fields, octets * 8):
                if f.name == column.path[0]:
                    return _field(column, offset, octets, shift, bits, index, f)
            offset += octets
        raise KeyError(column)
    total = spec.fixed_bits(variation)
    assert total is not None
    if not column.path:
        return _field(column, 0, total // 8, 0, total, 0, item)
    fields = variation.fields if isinstance(variation, Group) else ()
    for f, shift, bits in field_layout(fields, total):
        if f.name == column.path[0]:
            return _field(column, 0, total // 8, shift, bits, 0, f)
    raise KeyError(column)


def _bits(f: Named | Spare) -> int:
    bits = f.bits if isinstance(f, Spare) else spec.fixed_bits(f.variation)
    assert bits is not None
    return bits


def _field(
    column: Column, offset: int, octets: int, shift: int, bits: int, extent: int, f: Named
) -> _Field:
    assert isinstance(f.variation, Element)
    content = f.variation.content
    if isinstance(content, String) and content.kind != "octal":
        raise ValueError(f"{column}: text columns are not supported")
    lsb = float(content.lsb) if isinstance(content, Quantity) else None
    signed = isinstance(content, Quantity | Integer) and content.signed
    return _Field(column, offset, octets, shift, bits, extent, lsb, signed)


_FIELDS = tuple(_locate(c) for c in COLUMNS)
_ITEMS = (*dict.fromkeys(c.item for c in COLUMNS), "240", "RE")
_SLOT = {key: i + 1 for i, key in enumerate(_ITEMS)}  # slot 0 holds the record offset

PLOT_DTYPE = np.dtype(
    [("offset", np.int64)]
    + [(f.column.name, np.float64 if f.lsb is not None else np.int32) for f in _FIELDS]
    + [("callsign", "U8"), ("extended_range", np.bool_)]
)


@dataclass
class PlotBatch:
    """Plots of one input: one row per CAT048 record, and the decode errors met."""

    plots: npt.NDArray[Any]
    errors: list[DecodeError]


_Step = tuple[int, int, Skipper | None]


class _Walker:
    """Finds where the wanted items of each record start, stepping over the others."""

    def __init__(self) -> None:
        category = codec(CAT)
        self.uap = category.uap
        self.fspec_limit = category.fspec_limit
        self.steps: list[tuple[int, int, Skipper | None]] = []
        for slot in self.uap:
            if slot is None:
                self.steps.append((-1, 0, None))
                continue
            step = skipper(spec.category(CAT).items[slot[0]].variation)
            size, fn = (step, None) if isinstance(step, int) else (0, step)
            self.steps.append((_SLOT.get(slot[0], -1), size, fn))
        self.plans: dict[bytes, tuple[_Step, ...]] = {}

    def plan(self, fspec: bytes, p: int) -> tuple[_Step, ...]:
        plan = []
        for i, octet in enumerate(fspec):
            for bit in range(7):
                if octet & (0x80 >> bit):
                    frn = i * 7 + bit
                    if frn >= len(self.uap) or self.uap[frn] is None:
                        raise Malformed(p, f"FSPEC names undefined FRN {frn + 1}")
                    plan.append(self.steps[frn])
        if not plan:
            raise Malformed(p, "empty FSPEC")
        if len(self.plans) < PLAN_CACHE_LIMIT:
            self.plans[fspec] = tuple(plan)
        return tuple(plan)

    def walk(self, b: bytes, offset: int, rows: array[int], errors: list[DecodeError]) -> None:
        blank = [-1] * (len(_ITEMS) + 1)
        pos, size = 0, len(b)
        plans, fspec_limit = self.plans, self.fspec_limit
        while pos < size:
            if size - pos < 3:
                errors.append(DecodeError(offset + pos, None, "stray octets after the last block"))
                return
            cat, end = b[pos], pos + int.from_bytes(b[pos + 1 : pos + 3])
            if end - pos < 3 or end > size:
                errors.append(DecodeError(offset + pos, cat, "block length does not fit"))
                return
            if cat != CAT:
                pos = end
                continue
            p = pos + 3
            try:
                while p < end:
                    q, limit = p, min(end, p + fspec_limit)
                    while q < limit and b[q] & 1:
                        q += 1
                    if q >= limit:
                        raise Malformed(p, "FSPEC runs past the UAP or the block")
                    q += 1
                    fspec = b[p:q]
                    plan = plans.get(fspec) or self.plan(fspec, p)
                    row = blank.copy()
                    row[0] = p
                    for slot, step, fn in plan:
                        if slot >= 0:
                            row[slot] = q
                        q = q + step if fn is None else fn(b, q, end)
                    if q > end:
                        raise Malformed(p, "record runs past its block")
                    rows.extend(row)
                    p = q
            except Malformed as exc:
                errors.append(DecodeError(offset + exc.offset, cat, exc.reason))
            pos = end


_WALKER: _Walker | None = None


def extract_plots(data: bytes, offset: int = 0) -> PlotBatch:
    """Plots of every CAT048 record in a run of data blocks (other categories skipped).

    ``offset`` is added to the reported positions (record offsets and errors).
    """
    global _WALKER
    if _WALKER is None:
        _WALKER = _Walker()
    rows: array[int] = array("q")
    errors: list[DecodeError] = []
    _WALKER.walk(data, 0, rows, errors)
    starts = np.frombuffer(rows, dtype=np.int64).reshape(-1, len(_ITEMS) + 1)
    buf = np.frombuffer(data, dtype=np.uint8)
    plots = np.zeros(len(starts), dtype=PLOT_DTYPE)
    plots["offset"] = starts[:, 0] + offset
    for f in _FIELDS:
        plots[f.column.name] = _column(buf, starts[:, _SLOT[f.column.item]], f)
    plots["callsign"] = _callsigns(buf, starts[:, _SLOT["240"]])
    _apply_extended_range(data, plots, starts[:, 0], starts[:, _SLOT["RE"]])
    return PlotBatch(plots, [_shifted(e, offset) for e in errors])


def _shifted(error: DecodeError, offset: int) -> DecodeError:
    return DecodeError(error.offset + offset, error.category, error.reason)


def _octets(buf: npt.NDArray[np.uint8], at: npt.NDArray[np.int64], count: int) -> Any:
    value = np.zeros(len(at), dtype=np.uint64)
    for i in range(count):
        value = (value << np.uint64(8)) | buf[at + i]
    return value


def _column(buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64], f: _Field) -> Any:
    present = starts >= 0
    at = starts[present] + f.offset
    if f.extent:
        # An extent is there only when the FX bit closing the one before it is set.
        fx_set = (buf[at - 1] & 1).astype(bool)
        present[np.flatnonzero(present)[~fx_set]] = False
        at = at[fx_set]
    raw = (_octets(buf, at, f.octets) >> np.uint64(f.shift)) & np.uint64((1 << f.bits) - 1)
    values = raw.astype(np.int64)
    if f.signed:
        half = 1 << (f.bits - 1)
        values = (values ^ half) - half
    if f.lsb is not None:
        out = np.full(len(starts), np.nan)
        out[present] = values * f.lsb
        return out
    out_int = np.full(len(starts), -1, dtype=np.int64)
    out_int[present] = values
    return out_int


_ICAO_TABLE = np.array(list(ICAO_CHARACTERS))


def _callsigns(buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]) -> Any:
    out = np.full(len(starts), "", dtype="U8")
    present = starts >= 0
    if present.any():
        raw = _octets(buf, starts[present], 6)
        shifts = np.arange(42, -1, -6, dtype=np.uint64)
        codes = (raw[:, None] >> shifts) & np.uint64(63)
        out[present] = np.ascontiguousarray(_ICAO_TABLE[codes]).view("U8")[:, 0]
    return out


def _apply_extended_range(
    data: bytes, plots: npt.NDArray[Any], records: npt.NDArray[np.int64], re: npt.NDArray[np.int64]
) -> None:
    """Beyond 256 NM the range is in the RE field (REF ERR); rare, so decode those fully."""
    for row in np.flatnonzero(re >= 0):
        items, _ = codec(CAT).decode_record(data, int(records[row]), len(data))
        expansion = items.get("RE")
        if isinstance(expansion, dict) and "ERR" in expansion:
            plots["rho"][row] = expansion["ERR"]
            plots["extended_range"][row] = True
