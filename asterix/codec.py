"""Data blocks and records: decoding with error events, and encoding from values.

A data block is ``CAT (1) | LEN (2, big-endian, counts these 3) | records``; a record is
``FSPEC | items in UAP order``. Decoding never raises on bad bytes: a malformed record
ends its block with a ``DecodeError`` event (the rest of the block cannot be framed), and
the next block is read as usual.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from functools import cache
from typing import Any

from asterix import spec
from asterix.engine import (
    PLAN_CACHE_LIMIT,
    CompiledCategory,
    Decoder,
    EncodeError,
    Malformed,
    build_fspec,
    compile_category,
    new_items,
)

SUPPORTED_CATEGORIES = tuple(sorted(spec.SPEC_FILES))


@dataclass(frozen=True, slots=True)
class DecodeError:
    """A decode-error event: where (offset in the input), which category, and why."""

    offset: int
    category: int | None
    reason: str


@dataclass(frozen=True, slots=True)
class Block:
    """One data block; ``supported`` is False for categories this codec does not know."""

    cat: int
    offset: int
    records: list[dict[str, Any]]
    supported: bool = True


Plan = tuple[tuple[str, Decoder], ...]


def _fspec_end(b: bytes, p: int, end: int, limit_octets: int) -> int:
    """Position just past the FX-chained FSPEC at ``p``."""
    q = p
    limit = min(end, p + limit_octets)
    while True:
        if q >= limit:
            raise Malformed(p, "FSPEC runs past the UAP or the block")
        if not b[q] & 1:
            return q + 1
        q += 1


class CategoryCodec:
    """Record decoder and encoder of one category edition (with one UAP)."""

    def __init__(self, compiled: CompiledCategory) -> None:
        self.compiled = compiled
        self.number = compiled.number
        self.uaps = compiled.uaps or (compiled.uap,)
        self.uap = self.uaps[0]
        self.fspec_limit = max((len(uap) + 6) // 7 for uap in self.uaps)
        self.uap_positions = tuple(
            {slot[0]: i for i, slot in enumerate(uap) if slot is not None} for uap in self.uaps
        )
        self.positions = self.uap_positions[0]
        self._plans: dict[bytes, Plan] = {}

    def _plan(
        self, fspec: bytes, offset: int, uap: int = 0, first_frn: int = 0, last_frn: int = 1 << 16
    ) -> Plan:
        """The items an FSPEC names in a UAP, FRNs ``first_frn`` to ``last_frn`` (0-based)."""
        plan = []
        slots = self.uaps[uap]
        for i, octet in enumerate(fspec):
            for bit in range(7):
                if octet & (0x80 >> bit):
                    frn = i * 7 + bit
                    if not first_frn <= frn <= last_frn:
                        continue
                    slot = slots[frn] if frn < len(slots) else None
                    if slot is None:
                        raise Malformed(offset, f"FSPEC names undefined FRN {frn + 1}")
                    plan.append((slot[0], slot[1]))
        if not plan and not first_frn:
            raise Malformed(offset, "empty FSPEC")
        return tuple(plan)

    def decode_record(self, b: bytes, p: int, end: int) -> tuple[dict[str, Any], int]:
        """Decode the record at ``p``; returns its items and the position after it."""
        q = _fspec_end(b, p, end, self.fspec_limit)
        fspec = b[p:q]
        plan = self._plans.get(fspec)
        if plan is None:
            plan = self._plan(fspec, p)
            if len(self._plans) < PLAN_CACHE_LIMIT:
                self._plans[fspec] = plan
        items = new_items(fspec)
        for name, decode in plan:
            items[name], q = decode(b, q, end)
        return items, q

    def uap_of(self, items: Mapping[str, Any]) -> int:
        """The UAP (index into ``uaps``) the items are encoded with."""
        return 0

    def encode_record(self, items: Mapping[str, Any]) -> bytes:
        uap = self.uap_of(items)
        slots, positions = self.uaps[uap], self.uap_positions[uap]
        unknown = items.keys() - positions.keys()
        if unknown:
            raise EncodeError(
                f"CAT{self.number:03d}: unknown item(s) {sorted(unknown)}; "
                f"the UAP has {sorted(positions)}"
            )
        indices = sorted(positions[k] for k in items)
        parts = [build_fspec(indices, 0, getattr(items, "fspec_octets", 0))]
        for i in indices:
            slot = slots[i]
            assert slot is not None
            try:
                parts.append(slot[2](items[slot[0]]))
            except EncodeError as exc:
                raise EncodeError(f"CAT{self.number:03d} {exc}") from None
        return b"".join(parts)


class SelectedUapCodec(CategoryCodec):
    """A category with several UAPs, chosen per record by the value of an element of one
    item (``spec.UapSelector``). The spec guarantees that the UAPs agree up to that item:
    a record's items are read with the first UAP up to it, then with the one it selects."""

    def __init__(self, compiled: CompiledCategory) -> None:
        super().__init__(compiled)
        selector = compiled.spec.uap_selector
        assert selector is not None
        self.selector = selector
        names = [name for name, _ in compiled.spec.uaps]
        self._uap_of_value = {value: names.index(name) for value, name in selector.cases}
        self._selector_frn = compiled.spec.uap.index(selector.item)
        self._where = f"I{self.number:03d}/{'/'.join((selector.item, *selector.element))}"
        self._prefixes: dict[bytes, Plan] = {}
        self._rests: dict[tuple[bytes, int], Plan] = {}

    def _selector_value(self, items: Mapping[str, Any]) -> Any:
        value: Any = items.get(self.selector.item)
        for name in self.selector.element:
            value = value.get(name) if isinstance(value, dict) else None
        return value

    def _prefix(self, fspec: bytes, p: int) -> Plan:
        octet, bit = divmod(self._selector_frn, 7)
        if octet >= len(fspec) or not fspec[octet] & (0x80 >> bit):
            raise Malformed(p, f"no I{self.number:03d}/{self.selector.item}, which selects the UAP")
        plan = self._plan(fspec, p, 0, 0, self._selector_frn)
        if len(self._prefixes) < PLAN_CACHE_LIMIT:
            self._prefixes[fspec] = plan
        return plan

    def _rest(self, fspec: bytes, uap: int, p: int) -> Plan:
        plan = self._plan(fspec, p, uap, self._selector_frn + 1)
        if len(self._rests) < PLAN_CACHE_LIMIT:
            self._rests[fspec, uap] = plan
        return plan

    def decode_record(self, b: bytes, p: int, end: int) -> tuple[dict[str, Any], int]:
        q = _fspec_end(b, p, end, self.fspec_limit)
        fspec = b[p:q]
        items = new_items(fspec)
        for name, decode in self._prefixes.get(fspec) or self._prefix(fspec, p):
            items[name], q = decode(b, q, end)
        value = self._selector_value(items)
        uap = self._uap_of_value.get(value)
        if uap is None:
            raise Malformed(p, f"{self._where} = {value!r} selects no UAP")
        for name, decode in self._rests.get((fspec, uap)) or self._rest(fspec, uap, p):
            items[name], q = decode(b, q, end)
        return items, q

    def uap_of(self, items: Mapping[str, Any]) -> int:
        value = self._selector_value(items)
        uap = self._uap_of_value.get(value)
        if uap is None:
            raise EncodeError(
                f"CAT{self.number:03d}: {self._where} is {value!r}; it must be one of "
                f"{sorted(self._uap_of_value)} to select the UAP"
            )
        return uap


@cache
def codec(cat: int) -> CategoryCodec:
    """The codec of a supported category (KeyError for others)."""
    compiled = compile_category(spec.category(cat))
    if compiled.spec.uap_selector is not None:
        return SelectedUapCodec(compiled)
    return CategoryCodec(compiled)


def decode_blocks(data: bytes, offset: int = 0) -> Iterator[Block | DecodeError]:
    """Decode the data blocks of one datagram (or any run of blocks).

    ``offset`` is added to every reported position, so events point into the whole input.
    """
    pos, size = 0, len(data)
    while pos < size:
        if size - pos < 3:
            yield DecodeError(offset + pos, None, f"{size - pos} stray octets after the last block")
            return
        cat = data[pos]
        length = int.from_bytes(data[pos + 1 : pos + 3])
        if length < 3 or pos + length > size:
            yield DecodeError(
                offset + pos,
                cat,
                f"block length {length} does not fit the {size - pos} octets left",
            )
            return
        end = pos + length
        if cat not in spec.SPEC_FILES:
            yield Block(cat, offset + pos, [], supported=False)
            pos = end
            continue
        category = codec(cat)
        records: list[dict[str, Any]] = []
        p = pos + 3
        error: DecodeError | None = None
        if p == end:
            error = DecodeError(offset + pos, cat, "block holds no record")
        while p < end:
            try:
                items, p = category.decode_record(data, p, end)
            except Malformed as exc:
                error = DecodeError(
                    offset + exc.offset, cat, f"record {len(records)}: {exc.reason}"
                )
                break
            records.append(items)
        yield Block(cat, offset + pos, records)
        if error is not None:
            yield error
        pos = end


def encode_record(cat: int, items: Mapping[str, Any]) -> bytes:
    return codec(cat).encode_record(items)


def encode_block(cat: int, records: Iterable[Mapping[str, Any]]) -> bytes:
    """One data block of the given records (EncodeError when it would exceed 65535 octets)."""
    body = b"".join(encode_record(cat, r) for r in records)
    length = len(body) + 3
    if length > 0xFFFF:
        raise EncodeError(f"a CAT{cat:03d} block of {length} octets exceeds 65535")
    return bytes([cat]) + length.to_bytes(2) + body
