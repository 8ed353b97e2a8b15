"""One generic engine that turns the declarative model of ``asterix.spec`` into code.

For every item of a category it writes the Python source of a decoder
``(buf, pos, end) -> (value, new_pos)`` and an encoder ``value -> bytes``, and compiles
them once. Generated straight-line code (one ``int.from_bytes`` per octet run, shifts and
masks per element, LSB products as float literals) is several times faster than walking
the model at run time, and there is still one place where structure is interpreted: here.
``CompiledCategory.source`` holds the generated code of a category, for reading and debugging.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from fractions import Fraction
from typing import Any

from asterix import spec
from asterix.spec import (
    Bds,
    Compound,
    Content,
    Element,
    Explicit,
    Extended,
    Group,
    Integer,
    Named,
    Quantity,
    Raw,
    Repetitive,
    Spare,
    String,
    Table,
    Variation,
)

Decoder = Callable[[bytes, int, int], tuple[Any, int]]
Encoder = Callable[[Any], bytes]

# A bound on per-FSPEC caches: real feeds use a few dozen FSPECs, random input many more.
PLAN_CACHE_LIMIT = 4096


class Malformed(Exception):
    """Raised by generated decoders; ``offset`` is where in the buffer the trouble is."""

    def __init__(self, offset: int, reason: str) -> None:
        super().__init__(reason)
        self.offset = offset
        self.reason = reason


class EncodeError(ValueError):
    pass


# --- helpers the generated code calls ---------------------------------------------------

ICAO_CHARACTERS = "@ABCDEFGHIJKLMNOPQRSTUVWXYZ[\\]^_ !\"#$%&'()*+,-./0123456789:;<=>?"
# The 6-bit code is the low six bits of IA-5 (ICAO Annex 10): A-Z, space, 0-9 are the
# valid characters. The other codes decode to the remaining characters of the same
# IA-5 columns, so that nothing is lost and a garbled callsign re-encodes to its bytes.
_ICAO_CODE = {c: i for i, c in enumerate(ICAO_CHARACTERS)}


def _short(pos: int, need: int, end: int) -> Malformed:
    return Malformed(pos, f"item needs {need} octets, {max(end - pos, 0)} left")


# Two characters per look-up: a callsign is four look-ups instead of eight.
_ICAO_PAIRS = tuple(a + b for a in ICAO_CHARACTERS for b in ICAO_CHARACTERS)


def icao_text(raw: int, chars: int) -> str:
    """The text of ``chars`` ICAO 6-bit characters held in ``raw``."""
    if chars % 2:
        return "".join(ICAO_CHARACTERS[(raw >> (6 * (chars - 1 - i))) & 63] for i in range(chars))
    return "".join(_ICAO_PAIRS[(raw >> (12 * i)) & 4095] for i in range(chars // 2 - 1, -1, -1))


def _icao_raw(text: str, chars: int) -> int:
    text = text.ljust(chars)
    if len(text) != chars:
        raise EncodeError(f"{text!r} is longer than {chars} characters")
    raw = 0
    for c in text:
        code = _ICAO_CODE.get(c)
        if code is None:
            raise EncodeError(f"{c!r} is not an ICAO 6-bit character")
        raw = (raw << 6) | code
    return raw


def _octal_digits(bits: int) -> list[int]:
    """Digit widths, most significant first: 3-bit groups, a short one last (Mode 1: 3+2)."""
    widths = [3] * (bits // 3)
    if bits % 3:
        widths.append(bits % 3)
    return widths


def _octal(raw: int, bits: int) -> str:
    out = []
    shift = bits
    for width in _octal_digits(bits):
        shift -= width
        out.append(str((raw >> shift) & ((1 << width) - 1)))
    return "".join(out)


def _octal_raw(text: str, bits: int) -> int:
    widths = _octal_digits(bits)
    if not isinstance(text, str) or len(text) != len(widths):
        raise EncodeError(f"{text!r} is not a {len(widths)}-digit octal code")
    raw = 0
    for digit, width in zip(text, widths, strict=True):
        value = ord(digit) - 48
        if not 0 <= value < (1 << width):
            raise EncodeError(f"{text!r} is not a valid octal code")
        raw = (raw << width) | value
    return raw


def _ascii(raw: int, chars: int) -> str:
    return raw.to_bytes(chars, "big").decode("latin-1")


def _ascii_raw(text: str, chars: int) -> int:
    data = text.encode("latin-1")
    if len(data) > chars:
        raise EncodeError(f"{text!r} is longer than {chars} characters")
    return int.from_bytes(data.ljust(chars, b" "), "big")


def _int_raw(value: Any, bits: int, signed: bool, where: str) -> int:
    if isinstance(value, float) and value.is_integer():
        value = int(value)
    if isinstance(value, bool) or not isinstance(value, int):
        raise EncodeError(f"{where}: {value!r} is not an integer")
    low, high = (-(1 << (bits - 1)), (1 << (bits - 1)) - 1) if signed else (0, (1 << bits) - 1)
    if not low <= value <= high:
        raise EncodeError(f"{where}: {value} is outside {low}..{high}")
    return value & ((1 << bits) - 1)


def _quantity_raw(value: Any, lsb: float, bits: int, signed: bool, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise EncodeError(f"{where}: {value!r} is not a finite number")
    return _int_raw(round(value / lsb), bits, signed, where)


def _hex_raw(value: Any, bits: int, where: str) -> int:
    if isinstance(value, str):
        try:
            value = int(value, 16)
        except ValueError:
            raise EncodeError(f"{where}: {value!r} is not hex") from None
    return _int_raw(value, bits, False, where)


def _check_keys(value: Any, allowed: frozenset[str], where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise EncodeError(f"{where}: expected an object, got {value!r}")
    unknown = value.keys() - allowed
    if unknown:
        raise EncodeError(f"{where}: unknown field(s) {sorted(unknown)}; allowed {sorted(allowed)}")
    return value


def _hex_bytes(value: Any, where: str) -> bytes:
    try:
        return bytes.fromhex(value)
    except (TypeError, ValueError):
        raise EncodeError(f"{where}: {value!r} is not hex text") from None


# --- code generation --------------------------------------------------------------------


@dataclass
class _Writer:
    """Accumulates generated functions and the constants they refer to."""

    lines: list[str] = field(default_factory=list)
    constants: dict[str, Any] = field(default_factory=dict)
    counter: int = 0

    def name(self, stem: str) -> str:
        self.counter += 1
        return f"{stem}_{self.counter}"

    def const(self, value: Any, stem: str = "k") -> str:
        key = self.name(stem)
        self.constants[key] = value
        return key

    def function(self, header: str, body: list[str]) -> None:
        self.lines.append(f"def {header}:")
        self.lines.extend("    " + line for line in body)
        self.lines.append("")


@dataclass(frozen=True)
class _Leaf:
    """An element of a fixed-size bit structure: its place and how to read it."""

    path: tuple[str, ...]
    shift: int
    bits: int
    content: Content


def _lsb_literal(lsb: Fraction) -> str:
    return repr(float(lsb))


def _decode_expr(raw: str, leaf: _Leaf, siblings: dict[str, str]) -> str:
    """Python expression giving a leaf's value from the expression of its raw bits."""
    content, bits = leaf.content, leaf.bits
    if isinstance(content, Table | Integer) and not (
        isinstance(content, Integer) and content.signed
    ):
        return raw
    if isinstance(content, Integer):  # signed
        half = 1 << (bits - 1)
        return f"(({raw}) ^ {half}) - {half}"
    if isinstance(content, Raw):
        return f"'%0{content.hex_digits}X' % ({raw})" if content.hex_digits else raw
    if isinstance(content, Quantity):
        if content.signed:
            half = 1 << (bits - 1)
            return f"((({raw}) ^ {half}) - {half}) * {_lsb_literal(content.lsb)}"
        return f"({raw}) * {_lsb_literal(content.lsb)}"
    if isinstance(content, String):
        if content.kind == "octal":
            # Whole 3-bit digits are plain octal; Mode 1 (3 + 2 bits) needs the helper.
            return f"'%0{bits // 3}o' % ({raw})" if bits % 3 == 0 else f"_octal({raw}, {bits})"
        if content.kind == "icao":
            return f"_icao({raw}, {bits // 6})"
        return f"_ascii({raw}, {bits // 8})"
    if isinstance(content, Bds):
        return f"'%0{bits // 4}X' % ({raw})"
    # Case: the selector is a sibling element decoded from the same octets.
    selector = siblings.get(content.selector[-1])
    if selector is None:
        raise spec.SpecError(f"case selector {'/'.join(content.selector)} is not a sibling")
    expr = _decode_expr(raw, _Leaf(leaf.path, leaf.shift, bits, content.default), siblings)
    for value, chosen in reversed(content.cases):
        chosen_expr = _decode_expr(raw, _Leaf(leaf.path, leaf.shift, bits, chosen), siblings)
        expr = f"({chosen_expr} if ({selector}) == {value} else {expr})"
    return expr


def _encode_expr(value: str, leaf: _Leaf, siblings: dict[str, str], where: str) -> str:
    """Python expression giving a leaf's raw bits from the expression of its value."""
    content, bits = leaf.content, leaf.bits
    w = repr(where)
    if isinstance(content, Table | Raw) and not (isinstance(content, Raw) and content.hex_digits):
        return f"_int_raw({value}, {bits}, False, {w})"
    if isinstance(content, Integer):
        return f"_int_raw({value}, {bits}, {content.signed}, {w})"
    if isinstance(content, Raw | Bds):
        return f"_hex_raw({value}, {bits}, {w})"
    if isinstance(content, Quantity):
        return f"_quantity_raw({value}, {_lsb_literal(content.lsb)}, {bits}, {content.signed}, {w})"
    if isinstance(content, String):
        if content.kind == "octal":
            return f"_octal_raw({value}, {bits})"
        if content.kind == "icao":
            return f"_icao_raw({value}, {bits // 6})"
        return f"_ascii_raw({value}, {bits // 8})"
    selector = siblings.get(content.selector[-1])
    if selector is None:
        raise spec.SpecError(f"case selector {'/'.join(content.selector)} is not a sibling")
    expr = _encode_expr(value, _Leaf(leaf.path, leaf.shift, bits, content.default), siblings, where)
    for case_value, chosen in reversed(content.cases):
        chosen_expr = _encode_expr(
            value, _Leaf(leaf.path, leaf.shift, bits, chosen), siblings, where
        )
        expr = f"({chosen_expr} if ({selector}) == {case_value} else {expr})"
    return expr


def field_layout(fields: tuple[Named | Spare, ...], total: int) -> Iterator[tuple[Named, int, int]]:
    """(field, shift, bits) of each named field of a fixed run of ``total`` bits."""
    offset = 0
    for f in fields:
        bits = spec.fixed_bits(f.variation) if isinstance(f, Named) else f.bits
        if bits is None:
            raise spec.SpecError(f"{f} inside a fixed-size structure")
        if isinstance(f, Named):
            yield f, total - offset - bits, bits
        offset += bits


def _fixed_fields(variation: Variation, name: str) -> tuple[Named | Spare, ...]:
    """A fixed-size variation seen as a list of fields (an element is one unnamed field)."""
    if isinstance(variation, Group):
        return variation.fields
    return (Named(name, "", variation),)


class _Generator:
    def __init__(self) -> None:
        self.w = _Writer()

    # Fixed-size structures: one integer holds all bits; each element is a shift and mask.

    def fixed_value(self, fields: tuple[Named | Spare, ...], total: int, n: str, path: str) -> str:
        """Expression building the decoded value of a run of fields held in integer ``n``."""
        siblings: dict[str, str] = {}
        parts = []
        for f, shift, bits in field_layout(fields, total):
            raw = f"({n} >> {shift}) & {(1 << bits) - 1}" if shift else f"{n} & {(1 << bits) - 1}"
            if isinstance(f.variation, Group):
                expr = self.fixed_value(f.variation.fields, bits, f"({raw})", f"{path}/{f.name}")
            else:
                assert isinstance(f.variation, Element)
                leaf = _Leaf((f.name,), shift, bits, f.variation.content)
                expr = _decode_expr(raw, leaf, siblings)
                siblings[f.name] = raw
            parts.append(f"{f.name!r}: {expr}")
        return "{" + ", ".join(parts) + "}"

    def fixed_raw(
        self, fields: tuple[Named | Spare, ...], total: int, v: str, path: str, target: str = "n"
    ) -> list[str]:
        """Statements OR-ing into ``target`` the raw bits of the fields held in dict ``v``."""
        layout = list(field_layout(fields, total))
        allowed = self.w.const(frozenset(f.name for f, _, _ in layout), "keys")
        body = [f"{v} = _check_keys({v}, {allowed}, {path!r})"]
        siblings = {f.name: f"{v}.get({f.name!r}, 0)" for f, _, _ in layout}
        for f, shift, bits in layout:
            placed = f" << {shift}" if shift else ""
            if isinstance(f.variation, Group):
                sub = self.w.name("g")
                body += [
                    f"{sub} = {v}.get({f.name!r})",
                    f"if {sub} is not None:",
                    f"    n_{sub} = 0",
                ]
                inner = self.fixed_raw(
                    f.variation.fields, bits, sub, f"{path}/{f.name}", f"n_{sub}"
                )
                body += ["    " + line for line in inner]
                body.append(f"    {target} |= n_{sub}{placed}")
            else:
                leaf = _Leaf((f.name,), shift, bits, _element(f).content)
                expr = _encode_expr("val", leaf, siblings, f"{path}/{f.name}")
                body += [
                    f"val = {v}.get({f.name!r})",
                    f"if val is not None: {target} |= {expr}{placed}",
                ]
        return body

    def read_int(self, octets: int) -> str:
        return "b[p]" if octets == 1 else f"int.from_bytes(b[p:p + {octets}])"

    def fixed_decoder(self, fields: tuple[Named | Spare, ...], bits: int, path: str) -> str:
        octets = bits // 8
        fn = self.w.name("d")
        if len(fields) == 1 and isinstance(fields[0], Named) and fields[0].name == "_":
            leaf = _Leaf(("_",), 0, bits, _element(fields[0]).content)
            value = _decode_expr("n", leaf, {})
        else:
            value = self.fixed_value(fields, bits, "n", path)
        self.w.function(
            f"{fn}(b, p, end)",
            [
                f"if p + {octets} > end: raise _short(p, {octets}, end)",
                f"n = {self.read_int(octets)}",
                f"return {value}, p + {octets}",
            ],
        )
        return fn

    def fixed_encoder(self, fields: tuple[Named | Spare, ...], bits: int, path: str) -> str:
        fn = self.w.name("e")
        if len(fields) == 1 and isinstance(fields[0], Named) and fields[0].name == "_":
            leaf = _Leaf(("_",), 0, bits, _element(fields[0]).content)
            body = [f"n = {_encode_expr('v', leaf, {}, path)}"]
        else:
            body = ["n = 0", *self.fixed_raw(fields, bits, "v", path)]
        body.append(f"return n.to_bytes({bits // 8})")
        self.w.function(f"{fn}(v)", body)
        return fn

    # Variable-size structures.

    def coders(self, variation: Variation, path: str) -> tuple[str, str]:
        """Names of the generated (decoder, encoder) of a variation."""
        bits = spec.fixed_bits(variation)
        if bits is not None:
            if bits % 8:
                raise spec.SpecError(f"{path} is {bits} bits, not whole octets")
            fields = _fixed_fields(variation, "_")
            return self.fixed_decoder(fields, bits, path), self.fixed_encoder(fields, bits, path)
        if isinstance(variation, Extended):
            return self.extended(variation, path)
        if isinstance(variation, Repetitive):
            return self.repetitive(variation, path)
        if isinstance(variation, Compound):
            return self.compound(variation, path)
        if isinstance(variation, Explicit):
            return self.explicit(variation, path)
        raise spec.SpecError(f"{path}: cannot generate {type(variation).__name__}")

    def extended(self, variation: Extended, path: str) -> tuple[str, str]:
        dec, enc = self.w.name("d"), self.w.name("e")
        body = ["v = {}"]
        enc_body = [
            f"v = _check_keys(v, {self.w.const(_extended_names(variation), 'keys')}, {path!r})",
            "out = []",
        ]
        indent = ""
        count = len(variation.extents)
        for i, extent in enumerate(variation.extents):
            has_fx = i < count - 1 or variation.last_has_fx
            bits = sum(
                spec.fixed_bits(f.variation) or 0 if isinstance(f, Named) else f.bits
                for f in extent
            ) + (1 if has_fx else 0)
            octets = bits // 8
            fields = (*extent, Spare(1)) if has_fx else extent
            body += [
                f"{indent}if p + {octets} > end: raise _short(p, {octets}, end)",
                f"{indent}n = {self.read_int(octets)}",
                f"{indent}v.update({self.fixed_value(fields, bits, 'n', path)})",
                f"{indent}p += {octets}",
            ]
            names = tuple(f.name for f in extent if isinstance(f, Named))
            later = _extended_names(Extended(variation.extents[i + 1 :], True))
            enc_body.append(f"part = {{k: v[k] for k in {names!r} if k in v}}")
            enc_body.append("n = 0")
            enc_body += self.fixed_raw(fields, bits, "part", path)
            if has_fx:
                enc_body.append(f"more = not v.keys().isdisjoint({self.w.const(later, 'keys')})")
                enc_body.append(f"out.append((n | more).to_bytes({octets}))")
                enc_body.append("if not more: return b''.join(out)")
                if i == count - 1:
                    reason = repr(f"FX set in the last extent of {path}")
                    body.append(f"{indent}if n & 1: raise Malformed(p - 1, {reason})")
                else:
                    body.append(f"{indent}if n & 1:")
                    indent += "    "
            else:
                enc_body.append(f"out.append(n.to_bytes({octets}))")
        body.append("return v, p")
        enc_body.append("return b''.join(out)")
        self.w.function(f"{dec}(b, p, end)", body)
        self.w.function(f"{enc}(v)", enc_body)
        return dec, enc

    def repetitive(self, variation: Repetitive, path: str) -> tuple[str, str]:
        inner = variation.variation
        bits = spec.fixed_bits(inner)
        if bits is None:
            raise spec.SpecError(f"{path}: repetition of a variable-size structure")
        fields = _fixed_fields(inner, "_")
        single = not isinstance(inner, Group)
        dec, enc = self.w.name("d"), self.w.name("e")
        if variation.counter_octets:
            octets, c = bits // 8, variation.counter_octets
            value = (
                _decode_expr("n", _Leaf(("_",), 0, bits, _element(fields[0]).content), {})
                if single
                else self.fixed_value(fields, bits, "n", path)
            )
            self.w.function(
                f"{dec}(b, p, end)",
                [
                    f"if p + {c} > end: raise _short(p, {c}, end)",
                    f"k = {self.read_int(c)}",
                    f"p += {c}",
                    f"if p + k * {octets} > end: raise _short(p, k * {octets}, end)",
                    "out = []",
                    "for _ in range(k):",
                    f"    n = {self.read_int(octets)}",
                    f"    out.append({value})",
                    f"    p += {octets}",
                    "return out, p",
                ],
            )
            item_enc = self.fixed_encoder(fields, bits, path)
            self.w.function(
                f"{enc}(v)",
                [
                    "if not isinstance(v, list):",
                    f"    raise EncodeError({path!r} + ': expected a list')",
                    f"return len(v).to_bytes({c}) + b''.join({item_enc}(x) for x in v)",
                ],
            )
            return dec, enc
        # FX-terminated: each element is followed by its FX bit.
        total = bits + 1
        if total % 8:
            raise spec.SpecError(f"{path}: FX repetition of {bits} bits")
        octets = total // 8
        if single:
            leaf = _Leaf(("_",), 1, bits, _element(fields[0]).content)
            value = _decode_expr("n >> 1", leaf, {})
            raw_body = [f"n = {_encode_expr('x', leaf, {}, path)} << 1"]
        else:
            value = self.fixed_value((*fields, Spare(1)), total, "n", path)
            raw_body = ["n = 0", *self.fixed_raw((*fields, Spare(1)), total, "x", path)]
            # fixed_raw rebinds its dict variable; the FX loop below only needs n.
        self.w.function(
            f"{dec}(b, p, end)",
            [
                "out = []",
                "while True:",
                f"    if p + {octets} > end: raise _short(p, {octets}, end)",
                f"    n = {self.read_int(octets)}",
                f"    out.append({value})",
                f"    p += {octets}",
                "    if not n & 1: return out, p",
            ],
        )
        self.w.function(
            f"{enc}(v)",
            [
                "if not isinstance(v, list) or not v:",
                f"    raise EncodeError({path!r} + ': expected a non-empty list')",
                "out = []",
                "for i, x in enumerate(v):",
                *("    " + line for line in raw_body),
                f"    out.append((n | (i < len(v) - 1)).to_bytes({octets}))",
                "return b''.join(out)",
            ],
        )
        return dec, enc

    def compound(self, variation: Compound, path: str) -> tuple[str, str]:
        slots: list[tuple[str, str, str] | None] = []
        for slot in variation.slots:
            if slot is None:
                slots.append(None)
            else:
                d, e = self.coders(slot.variation, f"{path}/{slot.name}")
                slots.append((slot.name, d, e))
        table = self.w.const(tuple(slots), "slots")
        plans = self.w.const({}, "plans")
        dec, enc = self.w.name("d"), self.w.name("e")
        fixed = variation.fspec_octets
        self.w.function(
            f"{dec}(b, p, end)",
            [f"return _decode_compound(b, p, end, {table}, {fixed}, {path!r}, {plans})"],
        )
        self.w.function(f"{enc}(v)", [f"return _encode_compound(v, {table}, {fixed}, {path!r})"])
        return dec, enc

    def explicit(self, variation: Explicit, path: str) -> tuple[str, str]:
        dec, enc = self.w.name("d"), self.w.name("e")
        content = self.w.const(None, "expansion")
        self.w.function(
            f"{dec}(b, p, end)",
            [
                "if p >= end: raise _short(p, 1, end)",
                "n = b[p]",
                "if n < 1 or p + n > end:",
                f"    raise Malformed(p, f'explicit length {{n}} of {path} does not fit')",
                f"return _decode_explicit(b, p + 1, p + n, {content}), p + n",
            ],
        )
        self.w.function(f"{enc}(v)", [f"return _encode_explicit(v, {content}, {path!r})"])
        return dec, enc


def _element(f: Named | Spare) -> Element:
    assert isinstance(f, Named) and isinstance(f.variation, Element)
    return f.variation


def _extended_names(variation: Extended) -> frozenset[str]:
    return frozenset(f.name for ext in variation.extents for f in ext if isinstance(f, Named))


# --- runtime pieces the generated code calls for compound and explicit items -------------

Slot = tuple[str, Decoder, Encoder] | None


def _read_fspec(b: bytes, p: int, end: int, fixed: int, slots: int, path: str) -> int:
    """Position just past an FSPEC; bounded so that a run of FX bits cannot go on forever."""
    if fixed:
        if p + fixed > end:
            raise _short(p, fixed, end)
        return p + fixed
    limit = min(end, p + (slots + 6) // 7)
    q = p
    while True:
        if q >= limit:
            raise Malformed(p, f"FSPEC of {path} runs past its {(slots + 6) // 7} octets")
        if not b[q] & 1:
            return q + 1
        q += 1


def _fspec_slots(fspec: bytes, fixed: bool) -> Iterator[int]:
    bits_per_octet = 8 if fixed else 7
    for i, octet in enumerate(fspec):
        for bit in range(bits_per_octet):
            if octet & (0x80 >> bit):
                yield i * bits_per_octet + bit


CompoundPlan = tuple[tuple[str, Decoder], ...]


def _decode_compound(
    b: bytes,
    p: int,
    end: int,
    slots: tuple[Slot, ...],
    fixed: int,
    path: str,
    plans: dict[bytes, CompoundPlan],
) -> tuple[dict[str, Any], int]:
    q = _read_fspec(b, p, end, fixed, len(slots), path)
    fspec = b[p:q]
    plan = plans.get(fspec)
    if plan is None:
        steps = []
        for index in _fspec_slots(fspec, bool(fixed)):
            slot = slots[index] if index < len(slots) else None
            if slot is None:
                raise Malformed(p, f"{path}: FSPEC names undefined subfield {index + 1}")
            steps.append((slot[0], slot[1]))
        plan = tuple(steps)
        if len(plans) < PLAN_CACHE_LIMIT:
            plans[fspec] = plan
    value = {} if fixed else new_items(fspec)
    for name, decode in plan:
        value[name], q = decode(b, q, end)
    return value, q


class PaddedFspec(dict[str, Any]):
    """Items whose FSPEC ended in empty octets (legal, seen in real SDPS output).

    Their count is kept beside the items, so that re-encoding gives the same bytes; the
    value is still a plain mapping of items to everyone else (JSON included).
    """

    __slots__ = ("fspec_octets",)

    def __init__(self, fspec_octets: int) -> None:
        super().__init__()
        self.fspec_octets = fspec_octets


def new_items(fspec: bytes) -> dict[str, Any]:
    """The dict that receives the items named by an FX-chained FSPEC."""
    if len(fspec) > 1 and fspec[-1] == 0:
        return PaddedFspec(len(fspec))
    return {}


def build_fspec(indices: list[int], fixed: int, octets: int = 0) -> bytes:
    """An FSPEC with the given 0-based slots set: fixed-size, or FX-chained when fixed is 0;
    ``octets`` asks for at least that many FX-chained octets."""
    if fixed:
        fspec = bytearray(fixed)
        for i in indices:
            fspec[i // 8] |= 0x80 >> (i % 8)
        return bytes(fspec)
    octets = max(octets, (max(indices) // 7 + 1) if indices else 1)
    fspec = bytearray(octets)
    for i in indices:
        fspec[i // 7] |= 0x80 >> (i % 7)
    for i in range(octets - 1):
        fspec[i] |= 1
    return bytes(fspec)


def _encode_compound(v: Any, slots: tuple[Slot, ...], fixed: int, path: str) -> bytes:
    if not isinstance(v, dict):
        raise EncodeError(f"{path}: expected an object, got {v!r}")
    positions = {slot[0]: i for i, slot in enumerate(slots) if slot is not None}
    unknown = v.keys() - positions.keys()
    if unknown:
        raise EncodeError(f"{path}: unknown subfield(s) {sorted(unknown)}")
    indices = sorted(positions[k] for k in v)
    parts = [build_fspec(indices, fixed, getattr(v, "fspec_octets", 0))]
    for i in indices:
        slot = slots[i]
        assert slot is not None
        parts.append(slot[2](v[slot[0]]))
    return b"".join(parts)


@dataclass(frozen=True)
class _Expansion:
    """How an explicit item's content is read: a Reserved Expansion compound, or hex."""

    decode: Decoder | None
    encode: Encoder | None


def _decode_explicit(b: bytes, p: int, end: int, expansion: _Expansion | None) -> Any:
    if expansion is not None and expansion.decode is not None:
        try:
            value, q = expansion.decode(b, p, end)
        except Malformed:
            q = -1
        if q == end:
            return value
    # SP, or an RE of another edition than ours: keep the content, as hex text.
    return b[p:end].hex().upper()


def _encode_explicit(v: Any, expansion: _Expansion | None, path: str) -> bytes:
    if isinstance(v, str):
        content = _hex_bytes(v, path)
    elif expansion is not None and expansion.encode is not None:
        content = expansion.encode(v)
    else:
        raise EncodeError(f"{path}: expected hex text")
    if len(content) > 254:
        raise EncodeError(f"{path}: {len(content)} octets do not fit an explicit item")
    return bytes([len(content) + 1]) + content


# --- compiled categories ----------------------------------------------------------------


CompiledUap = tuple[tuple[str, Decoder, Encoder] | None, ...]


@dataclass(frozen=True)
class CompiledCategory:
    spec: spec.Category
    uap: CompiledUap
    """The first (for most categories the only) UAP."""
    source: str
    uaps: tuple[CompiledUap, ...] = ()
    """Every UAP, in the order of ``spec.uaps``."""

    @property
    def number(self) -> int:
        return self.spec.number


_RUNTIME = {
    "Malformed": Malformed,
    "EncodeError": EncodeError,
    "_short": _short,
    "_icao": icao_text,
    "_icao_raw": _icao_raw,
    "_octal": _octal,
    "_octal_raw": _octal_raw,
    "_ascii": _ascii,
    "_ascii_raw": _ascii_raw,
    "_int_raw": _int_raw,
    "_quantity_raw": _quantity_raw,
    "_hex_raw": _hex_raw,
    "_check_keys": _check_keys,
    "_decode_compound": _decode_compound,
    "_encode_compound": _encode_compound,
    "_decode_explicit": _decode_explicit,
    "_encode_explicit": _encode_explicit,
}


def compile_category(category: spec.Category) -> CompiledCategory:
    gen = _Generator()
    names: dict[str, tuple[str, str]] = {}
    for key, item in category.items.items():
        names[key] = gen.coders(item.variation, f"I{category.number:03d}/{key}")
    expansion_names = None
    if category.expansion is not None:
        expansion_names = gen.coders(category.expansion, f"I{category.number:03d}/RE")
    source = "\n".join(gen.w.lines)
    namespace: dict[str, Any] = dict(_RUNTIME)
    namespace.update(gen.w.constants)
    exec(compile(source, f"<asterix CAT{category.number:03d}>", "exec"), namespace)
    # Compound slot tables were stored as names; resolve them to the compiled functions.
    for key, value in gen.w.constants.items():
        if key.startswith("slots"):
            namespace[key] = tuple(
                None if s is None else (s[0], namespace[s[1]], namespace[s[2]]) for s in value
            )
        elif key.startswith("expansion"):
            namespace[key] = None
    re_expansion = (
        _Expansion(namespace[expansion_names[0]], namespace[expansion_names[1]])
        if expansion_names
        else None
    )
    for key, item in category.items.items():
        if isinstance(item.variation, Explicit) and item.variation.kind == "re":
            _rebind_expansion(namespace, names[key], re_expansion)
    uaps = []
    for _, keys in category.uaps or (("", category.uap),):
        slots: list[tuple[str, Decoder, Encoder] | None] = []
        for slot_key in keys:
            if slot_key is None:
                slots.append(None)
            elif slot_key == spec.RFS:
                slots.append((slot_key, *_rfs_coders(slots, f"I{category.number:03d}/RFS")))
            else:
                coders = names[slot_key]
                slots.append((slot_key, namespace[coders[0]], namespace[coders[1]]))
        uaps.append(tuple(slots))
    return CompiledCategory(category, uaps[0], source, tuple(uaps))


def _rfs_coders(
    uap: list[tuple[str, Decoder, Encoder] | None], path: str
) -> tuple[Decoder, Encoder]:
    """Random Field Sequencing: a count, then that many (FRN, item) pairs of the same UAP
    (``uap``, filled in by the caller). The value is a list of one-item objects, in order."""

    def slot_of(frn: int) -> tuple[str, Decoder, Encoder] | None:
        slot = uap[frn - 1] if 1 <= frn <= len(uap) else None
        return None if slot is None or slot[0] == spec.RFS else slot

    def decode(b: bytes, p: int, end: int) -> tuple[Any, int]:
        if p >= end:
            raise _short(p, 1, end)
        out, q = [], p + 1
        for _ in range(b[p]):
            if q >= end:
                raise _short(q, 1, end)
            slot = slot_of(b[q])
            if slot is None:
                raise Malformed(q, f"{path} names FRN {b[q]}, which is no item of the UAP")
            value, q = slot[1](b, q + 1, end)
            out.append({slot[0]: value})
        return out, q

    def encode(v: Any) -> bytes:
        if not isinstance(v, list) or len(v) > 255:
            raise EncodeError(f"{path}: expected a list of at most 255 {{item: value}} objects")
        frns = {slot[0]: i + 1 for i, slot in enumerate(uap) if slot is not None}
        parts = [bytes([len(v)])]
        for entry in v:
            if not isinstance(entry, dict) or len(entry) != 1:
                raise EncodeError(f"{path}: {entry!r} is not one {{item: value}} object")
            ((name, value),) = entry.items()
            slot = slot_of(frns.get(name, 0))
            if slot is None:
                raise EncodeError(f"{path}: {name!r} is no item of the UAP")
            parts += [bytes([frns[name]]), slot[2](value)]
        return b"".join(parts)

    return decode, encode


def _rebind_expansion(
    namespace: dict[str, Any], coder_names: tuple[str, str], expansion: _Expansion | None
) -> None:
    """Point the RE item's generated functions at the compiled expansion."""
    for fn_name in coder_names:
        fn = namespace[fn_name]
        for const in fn.__code__.co_names:
            if const.startswith("expansion"):
                namespace[const] = expansion


# --- skipping items without decoding them (the plot-extraction path) ---------------------

Skipper = Callable[[bytes, int, int], int]


def skipper(variation: Variation) -> int | Skipper:
    """How to step over an item: its size in octets when fixed, else a function of the bytes.

    The function returns the position after the item and raises Malformed when it does not
    fit before ``end``.
    """
    bits = spec.fixed_bits(variation)
    if bits is not None:
        return bits // 8
    if isinstance(variation, Extended):
        sizes = [(sum(_field_bits(f) for f in extent) + 1) // 8 for extent in variation.extents]
        if not variation.last_has_fx:
            sizes[-1] = sum(_field_bits(f) for f in variation.extents[-1]) // 8
        return _fx_chain_skipper(tuple(sizes), variation.last_has_fx, repeat=False)
    if isinstance(variation, Repetitive):
        inner = spec.fixed_bits(variation.variation)
        assert inner is not None
        if not variation.counter_octets:
            return _fx_chain_skipper(((inner + 1) // 8,), True, repeat=True)
        counter, size = variation.counter_octets, inner // 8

        def skip_repetitive(b: bytes, p: int, end: int) -> int:
            if p + counter > end:
                raise _short(p, counter, end)
            q = p + counter + int.from_bytes(b[p : p + counter]) * size
            if q > end:
                raise _short(p, q - p, end)
            return q

        return skip_repetitive
    if isinstance(variation, Explicit):
        return _skip_explicit
    if isinstance(variation, Compound):
        slots = tuple(None if s is None else skipper(s.variation) for s in variation.slots)
        fixed = variation.fspec_octets

        # Sizes of the subfields an FSPEC names, when all are fixed: the common case
        # (I048/130) then costs one dict look-up.
        fixed_sizes: dict[bytes, int] = {}

        def skip_compound(b: bytes, p: int, end: int) -> int:
            q = _read_fspec(b, p, end, fixed, len(slots), "compound")
            fspec = b[p:q]
            size = fixed_sizes.get(fspec)
            if size is not None:
                q += size
            else:
                start, variable = q, False
                for index in _fspec_slots(fspec, bool(fixed)):
                    step = slots[index] if index < len(slots) else None
                    if step is None:
                        raise Malformed(p, f"FSPEC names undefined subfield {index + 1}")
                    if isinstance(step, int):
                        q += step
                    else:
                        q, variable = step(b, q, end), True
                if not variable and len(fixed_sizes) < PLAN_CACHE_LIMIT:
                    fixed_sizes[fspec] = q - start
            if q > end:
                raise _short(p, q - p, end)
            return q

        return skip_compound
    raise spec.SpecError(f"cannot skip {type(variation).__name__}")


def _field_bits(f: Named | Spare) -> int:
    bits = f.bits if isinstance(f, Spare) else spec.fixed_bits(f.variation)
    assert bits is not None
    return bits


def _fx_chain_skipper(sizes: tuple[int, ...], last_has_fx: bool, repeat: bool) -> Skipper:
    """Units of the given sizes, each ending in an FX bit that says another follows.

    Extended items: the units are the extents, the last one may have no FX bit. FX
    repetition: one unit size, repeated while FX is set.
    """
    last = len(sizes) - 1

    def skip(b: bytes, p: int, end: int) -> int:
        q, unit = p, 0
        while True:
            q += sizes[min(unit, last)]
            if q > end:
                raise _short(p, q - p, end)
            if unit == last and not last_has_fx:
                return q
            if not b[q - 1] & 1:
                return q
            if unit == last and not repeat:
                raise Malformed(q - 1, "FX set in the last extent")
            unit += 1

    return skip


def _skip_explicit(b: bytes, p: int, end: int) -> int:
    if p >= end or b[p] < 1 or p + b[p] > end:
        raise Malformed(p, "explicit item does not fit")
    return p + b[p]
