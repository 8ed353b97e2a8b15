"""Chosen elements of a category's records as numpy columns, without a dict per item.

The general decoder builds a dict per item; a consumer of a dozen fields of many records
(the plot path, ``asterix.plots``; ADS-B reports, ``ColumnReader``) walks each record
once to find where the wanted items start, stepping over the others by their size, then
reads every field for all records at once with numpy. Where each field sits (octet,
shift, width, LSB) is derived from the same specification model as the general decoder,
so the values are identical to it.
"""

from __future__ import annotations

from array import array
from collections.abc import Callable, MutableMapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix import spec
from asterix.codec import Block, DecodeError, codec, decode_blocks
from asterix.engine import PLAN_CACHE_LIMIT, Malformed, Skipper, field_layout, skipper
from asterix.spec import Element, Extended, Group, Integer, Named, Quantity, Raw, Spare, String

__all__ = [
    "PADDING",
    "Column",
    "ColumnReader",
    "Columns",
    "Field",
    "Layout",
    "Walker",
    "item_slots",
    "layout",
    "locate",
    "read_columns",
    "walk",
]


@dataclass(frozen=True)
class Column:
    """A column: an element of an item, by item key and element path."""

    name: str
    item: str
    path: tuple[str, ...] = ()


@dataclass(frozen=True)
class Field:
    column: Column
    offset: int  # octet offset of the element's octets within the item
    octets: int
    shift: int
    bits: int
    extent: int  # extent index for extended items (present only when earlier FX bits set)
    lsb: float | None
    signed: bool
    text_base: int | None
    """The general decoder gives this element as text in this base (octal codes, 8; raw
    hex digits, 16); None: as a number."""


def locate(cat: int, column: Column) -> Field:
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
) -> Field:
    assert isinstance(f.variation, Element)
    content = f.variation.content
    if isinstance(content, String) and content.kind != "octal":
        raise ValueError(f"{column}: text columns are not supported")
    lsb = float(content.lsb) if isinstance(content, Quantity) else None
    signed = isinstance(content, Quantity | Integer) and content.signed
    text_base = (
        8
        if isinstance(content, String)
        else 16
        if isinstance(content, Raw) and content.hex_digits
        else None
    )
    return Field(column, offset, octets, shift, bits, extent, lsb, signed, text_base)


def item_slots(columns: tuple[Column, ...], extra: tuple[str, ...] = ()) -> dict[str, int]:
    """The row slot of each wanted item's start (the columns' items, then ``extra`` items
    read apart); slot 0 holds the record's offset."""
    items = (*dict.fromkeys(c.item for c in columns), *extra)
    return {key: i + 1 for i, key in enumerate(items)}


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


class Walker:
    """Finds where the wanted items (``slots``, as ``item_slots`` gives them) of each
    record of one category start, stepping over the others."""

    def __init__(self, cat: int, slots: dict[str, int]) -> None:
        self.cat = cat
        category = codec(cat)
        self.fspec_limit = category.fspec_limit
        self.blank = [-1] * (len(slots) + 1)
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
        self.selector: tuple[int, Field, dict[int, int]] | None = None
        if selector is not None:
            frn = spec.category(cat).uap.index(selector.item)
            names = [name for name, _ in spec.category(cat).uaps]
            located = locate(cat, Column("", selector.item, selector.element))
            if located.extent or any(
                s is not None and s[2] is not None for s in self.uaps[0][:frn]
            ):
                raise spec.SpecError(
                    f"CAT{cat:03d}: the column path needs the UAP selector in a "
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


def walk(
    b: bytes,
    rows: dict[int, array[int]],
    errors: list[DecodeError],
    walker_of: Callable[[int], Walker | None],
) -> None:
    """Every record of the categories ``walker_of`` gives a walker for: its offset and
    where its wanted items start, appended to ``rows`` of its category. One loop for all
    blocks and records: real feeds send many small blocks, and a call per block would cost
    as much as its records."""
    pos, size = 0, len(b)
    current = -1
    walker: Walker | None = None
    while pos < size:
        if size - pos < 3:
            errors.append(DecodeError(pos, None, "stray octets after the last block"))
            return
        cat, end = b[pos], pos + int.from_bytes(b[pos + 1 : pos + 3])
        if end - pos < 3 or end > size:
            errors.append(DecodeError(pos, cat, "block length does not fit"))
            return
        if cat != current:
            current, walker = cat, walker_of(cat)
            if walker is not None:
                out = rows.setdefault(cat, array("q"))
                blank, plans, fspec_limit = walker.blank, walker.plans, walker.fspec_limit
                selections = walker.selections if walker.selector is not None else None
        if walker is None:
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


@dataclass(frozen=True)
class Layout:
    """Every column of one category at once: per field its item's slot, its octets'
    offset, the shift and mask of its bits in the big-endian word of ``read`` octets from
    its start (the octets past its own shifted out), the sign bit's value of the signed
    ones (0 for the others), and whether it sits in an extent; the float fields with their
    LSBs."""

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


def layout(fields: tuple[Field, ...], slots: dict[str, int]) -> Layout:
    read = 4 if max(f.octets for f in fields) <= 4 else 8
    floats = [k for k, f in enumerate(fields) if f.lsb is not None]
    ints = [k for k, f in enumerate(fields) if f.lsb is None]
    return Layout(
        slots=np.array([slots[f.column.item] for f in fields], np.int64),
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


PADDING = b"\0" * 8
"""Octets after the data, so that a word read at a field near its end stays inside."""

Columns = MutableMapping[str, Any] | npt.NDArray[Any]
"""Where columns are written by name: a dict of arrays, or a structured array's fields."""


def read_columns(
    out: Columns, buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64], layout: Layout
) -> None:
    """Every field of the records (``starts``: per record, where each item starts) into
    ``out``: all fields at once, a few array operations whatever their number. ``buf`` is
    the data with ``PADDING`` after it. Floats are NaN and integers -1 when absent."""
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
        out[name] = floats[:, k]
    for k, name in enumerate(layout.int_names):
        out[name] = ints[:, k]


class ColumnReader:
    """The ``columns`` of every record of one data block of category ``cat``, floats
    (NaN when absent) for quantities, integers (-1 when absent) for the rest; codes and
    raw hex items as their integers. A block the walk cannot take whole (a malformed
    record, RFS, a cut block) is read by the general decoder instead, whose records up to
    its first malformed one are the columns: the same values either way."""

    def __init__(self, cat: int, columns: tuple[Column, ...]) -> None:
        self.cat = cat
        self.fields = tuple(locate(cat, c) for c in columns)
        slots = item_slots(columns)
        self.width = len(slots) + 1
        self.walker = Walker(cat, slots)
        self.layout = layout(self.fields, slots)

    def _walker_of(self, cat: int) -> Walker | None:
        return self.walker if cat == self.cat else None

    def read(self, block: bytes) -> dict[str, npt.NDArray[Any]]:
        """The columns of one data block of the category (its header included)."""
        rows: dict[int, array[int]] = {self.cat: array("q")}
        errors: list[DecodeError] = []
        walk(block, rows, errors, self._walker_of)
        if errors:
            return self.read_decoded(block)
        starts = np.frombuffer(rows[self.cat], dtype=np.int64).reshape(-1, self.width)
        out: dict[str, npt.NDArray[Any]] = {}
        read_columns(out, np.frombuffer(block + PADDING, dtype=np.uint8), starts, self.layout)
        return out

    def read_decoded(self, block: bytes) -> dict[str, npt.NDArray[Any]]:
        """The same columns from the general decoder's records of the block."""
        records = [
            items
            for event in decode_blocks(block)
            if isinstance(event, Block) and event.cat == self.cat
            for items in event.records
        ]
        out: dict[str, npt.NDArray[Any]] = {}
        for f in self.fields:
            values = [_element(items, f) for items in records]
            if f.lsb is None:
                out[f.column.name] = np.array([-1 if v is None else v for v in values], np.int64)
            else:
                out[f.column.name] = np.array(
                    [np.nan if v is None else v for v in values], np.float64
                )
        return out


def _element(items: dict[str, Any], f: Field) -> Any:
    """One element of a decoded record as ``read_columns`` reads it; None when absent."""
    value = items.get(f.column.item)
    for name in f.column.path:
        value = value.get(name) if isinstance(value, dict) else None
    if isinstance(value, str) and f.text_base is not None:
        return int(value, f.text_base)
    return value
