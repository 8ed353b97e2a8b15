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


class CategoryCodec:
    """Record decoder and encoder of one category edition."""

    def __init__(self, compiled: CompiledCategory) -> None:
        self.compiled = compiled
        self.number = compiled.number
        self.uap = compiled.uap
        self.fspec_limit = (len(self.uap) + 6) // 7
        self.positions = {slot[0]: i for i, slot in enumerate(self.uap) if slot is not None}
        self._plans: dict[bytes, tuple[tuple[str, Decoder], ...]] = {}

    def _plan(self, fspec: bytes, offset: int) -> tuple[tuple[str, Decoder], ...]:
        plan = []
        for i, octet in enumerate(fspec):
            for bit in range(7):
                if octet & (0x80 >> bit):
                    frn = i * 7 + bit
                    slot = self.uap[frn] if frn < len(self.uap) else None
                    if slot is None:
                        raise Malformed(offset, f"FSPEC names undefined FRN {frn + 1}")
                    plan.append((slot[0], slot[1]))
        if not plan:
            raise Malformed(offset, "empty FSPEC")
        if len(self._plans) < PLAN_CACHE_LIMIT:
            self._plans[fspec] = tuple(plan)
        return tuple(plan)

    def decode_record(self, b: bytes, p: int, end: int) -> tuple[dict[str, Any], int]:
        """Decode the record at ``p``; returns its items and the position after it."""
        q = p
        limit = min(end, p + self.fspec_limit)
        while True:
            if q >= limit:
                raise Malformed(p, "FSPEC runs past the UAP or the block")
            if not b[q] & 1:
                break
            q += 1
        q += 1
        fspec = b[p:q]
        plan = self._plans.get(fspec) or self._plan(fspec, p)
        items = new_items(fspec)
        for name, decode in plan:
            items[name], q = decode(b, q, end)
        return items, q

    def encode_record(self, items: Mapping[str, Any]) -> bytes:
        unknown = items.keys() - self.positions.keys()
        if unknown:
            raise EncodeError(
                f"CAT{self.number:03d}: unknown item(s) {sorted(unknown)}; "
                f"the UAP has {sorted(self.positions)}"
            )
        indices = sorted(self.positions[k] for k in items)
        parts = [build_fspec(indices, 0, getattr(items, "fspec_octets", 0))]
        for i in indices:
            slot = self.uap[i]
            assert slot is not None
            try:
                parts.append(slot[2](items[slot[0]]))
            except EncodeError as exc:
                raise EncodeError(f"CAT{self.number:03d} {exc}") from None
        return b"".join(parts)


@cache
def codec(cat: int) -> CategoryCodec:
    """The codec of a supported category (KeyError for others)."""
    return CategoryCodec(compile_category(spec.category(cat)))


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
