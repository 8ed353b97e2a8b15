"""The plot-extraction path: CAT048 and CAT001 bytes straight to numpy columns for the tracker.

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

from asterix import daps, spec
from asterix.codec import DecodeError, codec
from asterix.engine import (
    ICAO_CHARACTERS,
    PLAN_CACHE_LIMIT,
    Malformed,
    Skipper,
    field_layout,
    icao_text,
    skipper,
)
from asterix.spec import Element, Extended, Group, Integer, Named, Quantity, Spare, String


@dataclass(frozen=True)
class Column:
    """A plot column: an element of an item, by item key and element path."""

    name: str
    item: str
    path: tuple[str, ...] = ()


# The items CAT048 and CAT001 share, in the same element paths.
_SOURCE = (Column("sac", "010", ("SAC",)), Column("sic", "010", ("SIC",)))
_FLAGS = tuple(Column(name, "020", (name.upper(),)) for name in ("sim", "spi", "rab", "tst"))
_POSITION_AND_CODE = (
    Column("rho", "040", ("RHO",)),
    Column("theta", "040", ("THETA",)),
    Column("mode3a", "070", ("MODE3A",)),
    Column("mode3a_invalid", "070", ("V",)),
    Column("mode3a_garbled", "070", ("G",)),
    Column("mode3a_smoothed", "070", ("L",)),
)
_LEVEL_VALIDITY = (
    Column("flight_level_invalid", "090", ("V",)),
    Column("flight_level_garbled", "090", ("G",)),
)
_VELOCITY = (Column("ground_speed", "200", ("GSP",)), Column("heading", "200", ("HDG",)))

COLUMNS: dict[int, tuple[Column, ...]] = {
    48: (
        *_SOURCE,
        Column("time_of_day", "140"),
        Column("typ", "020", ("TYP",)),
        *_FLAGS,
        *_POSITION_AND_CODE,
        Column("flight_level", "090", ("FL",)),
        *_LEVEL_VALIDITY,
        Column("address", "220"),
        Column("track_number", "161", ("TRN",)),
        Column("height_3d", "110", ("3DH",)),
        *_VELOCITY,
    ),
    # CAT001 says PSR/SSR/combined in SSRPSR, which has the values of CAT048 TYP 0-3; its
    # TYP says plot or track (a radar's own track: ``track_report``); its I141 is the time
    # of day truncated to 512 s (``ingest.PlotClock`` unrolls it).
    1: (
        *_SOURCE,
        Column("truncated_time", "141"),
        Column("typ", "020", ("SSRPSR",)),
        Column("track_report", "020", ("TYP",)),
        *_FLAGS,
        *_POSITION_AND_CODE,
        Column("flight_level", "090", ("HGT",)),
        *_LEVEL_VALIDITY,
        Column("track_number", "161"),
        *_VELOCITY,
    ),
}
"""The columns of each category's plots. Floats (NaN when absent) for quantities, integers
(-1 when absent) for the rest. ``mode3a`` is the 12-bit code as an integer (print it with
``%04o``), ``address`` the 24-bit ICAO address. V bits keep the spec's sense: 1 = not
validated. ``typ`` is CAT048 I020 TYP (CAT001: SSRPSR, the same values 0-3)."""
CATEGORIES = tuple(COLUMNS)


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


def _locate(cat: int, column: Column) -> _Field:
    """Where an element sits inside its item, from the specification model."""
    item = spec.category(cat).items[column.item]
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


_FIELDS = {cat: tuple(_locate(cat, c) for c in columns) for cat, columns in COLUMNS.items()}
_TEXT_ITEMS = {48: ("240", "RE", "250")}  # callsign, extended range and DAPs, read apart
_ITEMS = {
    cat: (*dict.fromkeys(c.item for c in columns), *_TEXT_ITEMS.get(cat, ()))
    for cat, columns in COLUMNS.items()
}
_SLOTS = {cat: {key: i + 1 for i, key in enumerate(items)} for cat, items in _ITEMS.items()}
"""Per category, the row slot of each wanted item's start; slot 0 holds the record offset."""


def _column_dtypes() -> list[tuple[str, Any]]:
    kinds: dict[str, Any] = {}
    for fields in _FIELDS.values():
        for f in fields:
            kind = np.float64 if f.lsb is not None else np.int32
            if kinds.setdefault(f.column.name, kind) is not kind:
                raise spec.SpecError(f"column {f.column.name} is a number in one category only")
    return list(kinds.items())


PLOT_DTYPE = np.dtype(
    [
        ("offset", np.int64),
        ("category", np.uint8),
        *_column_dtypes(),
        ("callsign", "U8"),
        ("extended_range", np.bool_),
        *((name, np.float64) for name in daps.DAP_COLUMNS),
    ]
)


@dataclass
class PlotBatch:
    """Plots of one input: one row per CAT048 or CAT001 record, in input order, and the
    decode errors met."""

    plots: npt.NDArray[Any]
    errors: list[DecodeError]


_Step = tuple[int, int, Skipper | None]
_Segment = tuple[tuple[tuple[int, int], ...], int, Skipper | None]
"""A run of fixed-size items and the variable-size one that may close it: the wanted
items' (slot, octets from the run's start), the run's size, the closing item's skipper."""
_Plan = tuple[_Segment, ...]


@dataclass(frozen=True)
class _Selection:
    """The plans of one FSPEC in a multi-UAP category, by the value of the selector (read
    ``at`` octets after the FSPEC: the items before it are fixed-size)."""

    at: int
    by_value: dict[int, _Plan]


class _Walker:
    """Finds where the wanted items of each record of one category start, stepping over
    the others."""

    def __init__(self, cat: int) -> None:
        self.cat = cat
        category = codec(cat)
        self.fspec_limit = category.fspec_limit
        slots = _SLOTS[cat]
        self.blank = [-1] * (len(_ITEMS[cat]) + 1)
        self.uaps: list[list[_Step | None]] = []
        for uap in category.uaps:
            steps: list[_Step | None] = []
            for slot in uap:
                if slot is None or slot[0] == spec.RFS:
                    steps.append(None)  # RFS records are left to the general decoder
                    continue
                step = skipper(spec.category(cat).items[slot[0]].variation)
                size, fn = (step, None) if isinstance(step, int) else (0, step)
                steps.append((slots.get(slot[0], -1), size, fn))
            self.uaps.append(steps)
        self.plans: dict[bytes, _Plan] = {}
        self.selections: dict[bytes, _Selection] = {}
        selector = spec.category(cat).uap_selector
        self.selector: tuple[int, _Field, dict[int, int]] | None = None
        if selector is not None:
            frn = spec.category(cat).uap.index(selector.item)
            names = [name for name, _ in spec.category(cat).uaps]
            located = _locate(cat, Column("", selector.item, selector.element))
            if located.extent or any(
                s is not None and s[2] is not None for s in self.uaps[0][:frn]
            ):
                raise spec.SpecError(
                    f"CAT{cat:03d}: the plot path needs the UAP selector in a "
                    "first extent after fixed-size items"
                )
            cases = {value: names.index(name) for value, name in selector.cases}
            self.selector = (frn, located, cases)

    def _steps(self, fspec: bytes, p: int, uap: int) -> _Plan:
        plan = []
        steps = self.uaps[uap]
        for i, octet in enumerate(fspec):
            for bit in range(7):
                if octet & (0x80 >> bit):
                    frn = i * 7 + bit
                    step = steps[frn] if frn < len(steps) else None
                    if step is None:
                        raise Malformed(p, f"FSPEC names undefined FRN {frn + 1} (or RFS)")
                    plan.append(step)
        if not plan:
            raise Malformed(p, "empty FSPEC")
        return _segments(plan)

    def plan(self, fspec: bytes, p: int) -> _Plan:
        """The steps of an FSPEC (single-UAP categories)."""
        found = self._steps(fspec, p, 0)
        if len(self.plans) < PLAN_CACHE_LIMIT:
            self.plans[fspec] = found
        return found

    def selection(self, fspec: bytes, p: int) -> _Selection:
        """The steps of an FSPEC in each UAP, by selector value (multi-UAP categories)."""
        assert self.selector is not None
        frn, _, cases = self.selector
        octet, bit = divmod(frn, 7)
        if octet >= len(fspec) or not fspec[octet] & (0x80 >> bit):
            raise Malformed(p, f"no I{self.cat:03d} item selecting the UAP")
        at = sum(
            step[1]
            for i, step in enumerate(self.uaps[0][:frn])
            if step is not None and fspec[i // 7] & (0x80 >> (i % 7))
        )
        by_value = {}
        for value, uap in cases.items():
            try:
                by_value[value] = self._steps(fspec, p, uap)
            except Malformed:
                continue  # an FSPEC that is wrong for this UAP: an error when selected
        found = _Selection(at, by_value)
        if len(self.selections) < PLAN_CACHE_LIMIT:
            self.selections[fspec] = found
        return found

    def select(self, b: bytes, q: int, p: int, selection: _Selection) -> _Plan:
        """The steps of the UAP the record at ``p`` (items from ``q``) selects."""
        assert self.selector is not None
        _, f, _ = self.selector
        at = q + selection.at + f.offset
        value = (int.from_bytes(b[at : at + f.octets]) >> f.shift) & ((1 << f.bits) - 1)
        plan = selection.by_value.get(value)
        if plan is None:
            raise Malformed(p, f"FSPEC names items the UAP selected by {value} does not have")
        return plan


def _segments(steps: list[_Step]) -> _Plan:
    """A record's steps (slot, size, skipper) as runs of fixed-size items each closed by a
    variable-size one (or the record's end): one addition per run instead of per item."""
    segments: list[_Segment] = []
    assignments: list[tuple[int, int]] = []
    size = 0
    for slot, step, fn in steps:
        if slot >= 0:
            assignments.append((slot, size))
        if fn is None:
            size += step
            continue
        segments.append((tuple(assignments), size, fn))
        assignments, size = [], 0
    if assignments or size or not segments:
        segments.append((tuple(assignments), size, None))
    return tuple(segments)


_WALKERS: dict[int, _Walker] = {}


def _walker(cat: int) -> _Walker:
    walker = _WALKERS.get(cat)
    if walker is None:
        walker = _WALKERS[cat] = _Walker(cat)
    return walker


def _walk(b: bytes, rows: dict[int, array[int]], errors: list[DecodeError]) -> None:
    """Every record of the plot categories: its offset and where its wanted items start,
    appended to ``rows`` of its category. One loop for all blocks and records: real feeds
    send many small blocks, and a call per block would cost as much as its records."""
    pos, size = 0, len(b)
    current = -1
    while pos < size:
        if size - pos < 3:
            errors.append(DecodeError(pos, None, "stray octets after the last block"))
            return
        cat, end = b[pos], pos + int.from_bytes(b[pos + 1 : pos + 3])
        if end - pos < 3 or end > size:
            errors.append(DecodeError(pos, cat, "block length does not fit"))
            return
        if cat not in COLUMNS:
            pos = end
            continue
        if cat != current:
            current, walker = cat, _walker(cat)
            out = rows.setdefault(cat, array("q"))
            blank, plans, fspec_limit = walker.blank, walker.plans, walker.fspec_limit
            selections = walker.selections if walker.selector is not None else None
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
                if selections is None:
                    plan = plans.get(fspec) or walker.plan(fspec, p)
                else:
                    selection = selections.get(fspec) or walker.selection(fspec, p)
                    plan = walker.select(b, q, p, selection)
                row = blank.copy()
                row[0] = p
                for assignments, run, fn in plan:
                    for slot, offset in assignments:
                        row[slot] = q + offset
                    q += run
                    if fn is not None:
                        q = fn(b, q, end)
                if q > end:
                    raise Malformed(p, "record runs past its block")
                out.extend(row)
                p = q
        except Malformed as exc:
            errors.append(DecodeError(exc.offset, cat, exc.reason))
        pos = end


def extract_plots(data: bytes, offset: int = 0) -> PlotBatch:
    """Plots of every CAT048 and CAT001 record in a run of data blocks (other categories
    skipped), in input order.

    ``offset`` is added to the reported positions (record offsets and errors).
    """
    rows: dict[int, array[int]] = {}
    errors: list[DecodeError] = []
    _walk(data, rows, errors)
    buf = np.frombuffer(data, dtype=np.uint8)
    parts = [_plots(cat, data, buf, found) for cat, found in rows.items()]
    if not parts:
        plots = np.zeros(0, dtype=PLOT_DTYPE)
    elif len(parts) == 1:
        plots = parts[0]
    else:  # only odd feeds mix CAT001 and CAT048 in one datagram
        plots = np.concatenate(parts)
        plots = plots[np.argsort(plots["offset"], kind="stable")]
    if offset:
        plots["offset"] += offset
    return PlotBatch(plots, [_shifted(e, offset) for e in errors])


def _blank() -> Any:
    """A plot row with every column absent: NaN, -1, "" and False."""
    row = np.zeros(1, dtype=PLOT_DTYPE)
    for name in PLOT_DTYPE.names or ():
        if PLOT_DTYPE[name] == np.float64:
            row[name] = np.nan
        elif PLOT_DTYPE[name] == np.int32:
            row[name] = -1
    return row[0]


_BLANK = _blank()
_FIRST_DAP_COLUMN = (PLOT_DTYPE.names or ()).index(daps.DAP_COLUMNS[0])
_BLANK_VALUES = tuple(_BLANK.tolist())
_BLANK_ROW = np.array([_BLANK], dtype=PLOT_DTYPE).view(np.dtype((np.void, PLOT_DTYPE.itemsize)))
"""The blank row as opaque bytes: repeated, the rows a batch starts from (the columns its
category never fills stay NaN, -1, "" or False)."""
SMALL_BATCH = 14
"""Up to this many records of a category, a datagram's plots are read record by record in
Python: numpy's per-call cost outweighs its per-row gain. Measured crossover (every field
at once, ``_read_columns``): 12-16 records of CAT048. Many CAT001 radars send one plot a
datagram."""
_ROW_FIELDS = {
    cat: tuple(
        (
            (PLOT_DTYPE.names or ()).index(f.column.name),
            _SLOTS[cat][f.column.item],
            f.offset,
            f.octets,
            f.shift,
            (1 << f.bits) - 1,
            1 << (f.bits - 1) if f.signed else 0,
            f.lsb,
            f.extent > 0,
        )
        for f in fields
    )
    for cat, fields in _FIELDS.items()
}


@dataclass(frozen=True)
class _Layout:
    """Every column of one category at once: per field (one per ``_FIELDS`` entry) its
    item's slot, its octets' offset, the shift and mask of its bits in the big-endian
    word of ``read`` octets from its start (the octets past its own shifted out), the
    sign bit's value of the signed ones (0 for the others), and whether it sits in an
    extent; the float fields with their LSBs."""

    slots: npt.NDArray[np.int64]
    offsets: npt.NDArray[np.int64]
    word: np.dtype[Any]
    shifts: npt.NDArray[np.uint64]
    masks: npt.NDArray[np.uint64]
    halves: npt.NDArray[np.int64]
    extended: npt.NDArray[np.bool_]
    float_fields: npt.NDArray[np.intp]
    lsbs: npt.NDArray[np.float64]
    float_names: tuple[str, ...]
    int_fields: npt.NDArray[np.intp]
    int_names: tuple[str, ...]


def _layout(cat: int) -> _Layout:
    fields = _FIELDS[cat]
    read = 4 if max(f.octets for f in fields) <= 4 else 8
    floats = [k for k, f in enumerate(fields) if f.lsb is not None]
    ints = [k for k, f in enumerate(fields) if f.lsb is None]
    return _Layout(
        slots=np.array([_SLOTS[cat][f.column.item] for f in fields], np.int64),
        offsets=np.array([f.offset for f in fields], np.int64),
        word=np.dtype(f">u{read}"),
        shifts=np.array([f.shift + 8 * (read - f.octets) for f in fields], np.uint64),
        masks=np.array([(1 << f.bits) - 1 for f in fields], np.uint64),
        halves=np.array([1 << (f.bits - 1) if f.signed else 0 for f in fields], np.int64),
        extended=np.array([f.extent > 0 for f in fields], np.bool_),
        float_fields=np.array(floats, np.intp),
        lsbs=np.array([fields[k].lsb for k in floats], np.float64),
        float_names=tuple(fields[k].column.name for k in floats),
        int_fields=np.array(ints, np.intp),
        int_names=tuple(fields[k].column.name for k in ints),
    )


_LAYOUTS = {cat: _layout(cat) for cat in _FIELDS}


_PADDING = b"\0" * 8
"""Octets after a datagram, so that a word read at a field near its end stays inside."""


def _plots(cat: int, data: bytes, buf: npt.NDArray[np.uint8], rows: array[int]) -> Any:
    slots = _SLOTS[cat]
    starts = np.frombuffer(rows, dtype=np.int64).reshape(-1, len(_ITEMS[cat]) + 1)
    if len(starts) <= SMALL_BATCH:
        plots = _plots_by_record(cat, data, starts.tolist())
    else:
        plots = np.repeat(_BLANK_ROW, len(starts)).view(PLOT_DTYPE)
        plots["offset"] = starts[:, 0]
        plots["category"] = cat
        padded = np.frombuffer(data + _PADDING, dtype=np.uint8)
        _read_columns(plots, padded, starts, _LAYOUTS[cat])
        if "240" in slots:
            plots["callsign"] = _callsigns(padded, starts[:, slots["240"]])
        if "250" in slots:
            for name, values in daps.decode_columns(buf, starts[:, slots["250"]]).items():
                plots[name] = values
    if "RE" in slots:
        _apply_extended_range(data, plots, starts[:, 0], starts[:, slots["RE"]])
    return plots


def _read_columns(
    plots: npt.NDArray[Any],
    buf: npt.NDArray[np.uint8],
    starts: npt.NDArray[np.int64],
    layout: _Layout,
) -> None:
    """Every field of the records (``starts``: per record, where each item starts) into
    ``plots``: all fields at once, a few array operations whatever their number. ``buf``
    is the data with ``_PADDING`` after it."""
    item_starts = starts[:, layout.slots]
    present = item_starts >= 0
    # An absent item's fields read the octets at -1 (the padding) or 0: masked below.
    at = item_starts + layout.offsets
    read = layout.word.itemsize
    octets = buf[at[:, :, None] + np.arange(read)]
    word = octets.view(layout.word)[:, :, 0].astype(np.uint64)
    values = ((word >> layout.shifts) & layout.masks).astype(np.int64)
    values = (values ^ layout.halves) - layout.halves
    if layout.extended.any():
        # An extent is there only when the FX bit closing the one before it is set.
        fx_set = (buf[at - 1] & 1).astype(bool)
        present &= fx_set | ~layout.extended
    floats = np.where(
        present[:, layout.float_fields], values[:, layout.float_fields] * layout.lsbs, np.nan
    )
    ints = np.where(present[:, layout.int_fields], values[:, layout.int_fields], -1)
    for k, name in enumerate(layout.float_names):
        plots[name] = floats[:, k]
    for k, name in enumerate(layout.int_names):
        plots[name] = ints[:, k]


def _plots_by_record(cat: int, data: bytes, starts: list[list[int]]) -> Any:
    """The same columns as ``_read_columns`` and ``_callsigns`` give, one record at a time."""
    callsign = _SLOTS[cat].get("240", -1)
    callsign_column = (PLOT_DTYPE.names or ()).index("callsign")
    dap_slot = _SLOTS[cat].get("250", -1)
    out = []
    for row in starts:
        values = list(_BLANK_VALUES)
        values[0], values[1] = row[0], cat
        for column, slot, offset, octets, shift, mask, half, lsb, extended in _ROW_FIELDS[cat]:
            at = row[slot]
            if at < 0:
                continue
            at += offset
            if extended and not data[at - 1] & 1:
                continue  # the extent is not there
            raw = (int.from_bytes(data[at : at + octets]) >> shift) & mask
            if half and raw >= half:
                raw -= half << 1
            values[column] = raw if lsb is None else raw * lsb
        if callsign >= 0 and row[callsign] >= 0:
            at = row[callsign]
            values[callsign_column] = icao_text(int.from_bytes(data[at : at + 6]), 8)
        if dap_slot >= 0 and row[dap_slot] >= 0:
            daps.decode_record(data, row[dap_slot], values, _FIRST_DAP_COLUMN)
        out.append(tuple(values))
    return np.array(out, dtype=PLOT_DTYPE)


def _shifted(error: DecodeError, offset: int) -> DecodeError:
    return DecodeError(error.offset + offset, error.category, error.reason)


_ICAO_TABLE = np.array(list(ICAO_CHARACTERS))


def _callsigns(buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]) -> Any:
    out = np.full(len(starts), "", dtype="U8")
    present = starts >= 0
    if present.any():
        # Six octets, from the big-endian word of eight (``buf`` padded after the data).
        raw = buf[starts[present][:, None] + np.arange(8)].view(">u8")[:, 0] >> np.uint64(16)
        shifts = np.arange(42, -1, -6, dtype=np.uint64)
        codes = (raw[:, None] >> shifts) & np.uint64(63)
        out[present] = np.ascontiguousarray(_ICAO_TABLE[codes]).view("U8")[:, 0]
    return out


def _apply_extended_range(
    data: bytes, plots: npt.NDArray[Any], records: npt.NDArray[np.int64], re: npt.NDArray[np.int64]
) -> None:
    """Beyond 256 NM the CAT048 range is in the RE field (REF ERR); rare, so decode those
    fully."""
    for row in np.flatnonzero(re >= 0):
        items, _ = codec(48).decode_record(data, int(records[row]), len(data))
        expansion = items.get("RE")
        if isinstance(expansion, dict) and "ERR" in expansion:
            plots["rho"][row] = expansion["ERR"]
            plots["extended_range"][row] = True
