"""The declarative model of an ASTERIX category, read from the structured specification text.

The specification files under ``asterix/specs`` are byte-for-byte copies of
zoranbosnjak/asterix-specs (BSD-3, see ``specs/LICENSE``). This module parses that
textual format into frozen dataclasses; ``asterix.engine`` turns them into decoders and
encoders. Nothing here knows about bytes: it only describes structure, sizes and units.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, replace
from fractions import Fraction
from functools import cache
from importlib import resources
from typing import Literal

# --- element contents -------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Raw:
    """An uninterpreted bit field; ``hex_digits`` > 0 asks for upper-case hex text."""

    hex_digits: int = 0


@dataclass(frozen=True, slots=True)
class Table:
    entries: tuple[tuple[int, str], ...]


@dataclass(frozen=True, slots=True)
class Integer:
    signed: bool


@dataclass(frozen=True, slots=True)
class Quantity:
    signed: bool
    lsb: Fraction
    unit: str


@dataclass(frozen=True, slots=True)
class String:
    kind: Literal["octal", "ascii", "icao"]


@dataclass(frozen=True, slots=True)
class Bds:
    """Mode S register content (MB data, with its BDS address when ``register`` is None)."""

    register: str | None


@dataclass(frozen=True, slots=True)
class Case:
    """Content chosen by the value of another element of the same item, e.g. 150/IM."""

    selector: tuple[str, ...]
    cases: tuple[tuple[int, Content], ...]
    default: Content


Content = Raw | Table | Integer | Quantity | String | Bds | Case

# --- variations ---------------------------------------------------------------------------


@dataclass(frozen=True, slots=True)
class Element:
    bits: int
    content: Content


@dataclass(frozen=True, slots=True)
class Spare:
    bits: int


@dataclass(frozen=True, slots=True)
class Named:
    """A named sub-field of a group, extended, compound or top-level item."""

    name: str
    title: str
    variation: Variation


@dataclass(frozen=True, slots=True)
class Group:
    fields: tuple[Named | Spare, ...]


@dataclass(frozen=True, slots=True)
class Extended:
    """Octet-aligned extents; every extent but possibly the last ends with an FX bit."""

    extents: tuple[tuple[Named | Spare, ...], ...]
    last_has_fx: bool


@dataclass(frozen=True, slots=True)
class Repetitive:
    """``counter_octets`` = 0 means FX-terminated repetition (FX bit after each element)."""

    counter_octets: int
    variation: Variation


@dataclass(frozen=True, slots=True)
class Explicit:
    kind: Literal["re", "sp", ""]


@dataclass(frozen=True, slots=True)
class Compound:
    """``fspec_octets`` = 0 means an FX-chained FSPEC; otherwise a fixed-size one."""

    fspec_octets: int
    slots: tuple[Named | None, ...]


Variation = Element | Group | Extended | Repetitive | Explicit | Compound


RFS = "RFS"
"""The UAP slot of Random Field Sequencing ("rfs" in the spec): items named by FRN, in any
order, after the ordinary ones."""

Uap = tuple[str | None, ...]


@dataclass(frozen=True, slots=True)
class UapSelector:
    """How a record of a multi-UAP category says which UAP it follows: the value of an
    element of one of its items (CAT001: I020 TYP, 0 plot, 1 track)."""

    item: str
    element: tuple[str, ...]
    cases: tuple[tuple[int, str], ...]


@dataclass(frozen=True, slots=True)
class Category:
    number: int
    title: str
    edition: str
    items: dict[str, Named]
    uap: Uap
    """The UAP; for a multi-UAP category, the first of ``uaps``."""
    expansion: Compound | None = None  # the Reserved Expansion Field, from a "ref" file
    uaps: tuple[tuple[str, Uap], ...] = ()
    """Every UAP by name (one, unnamed, for most categories)."""
    uap_selector: UapSelector | None = None
    """None for a category with one UAP."""


# --- parser -----------------------------------------------------------------------------

_TEXT_BLOCKS = frozenset({"definition", "description", "remark", "preamble"})
_NAMED = re.compile(r'^(\S+) "(.*)"$')


class SpecError(ValueError):
    pass


@dataclass(slots=True)
class _Line:
    indent: int
    text: str
    number: int


def _lines(text: str) -> list[_Line]:
    out = []
    for number, raw in enumerate(text.splitlines(), 1):
        stripped = raw.strip()
        if stripped:
            out.append(_Line(len(raw) - len(raw.lstrip(" ")), stripped, number))
    return out


class _Parser:
    def __init__(self, text: str) -> None:
        self.lines = _lines(text)
        self.pos = 0

    def peek(self) -> _Line | None:
        return self.lines[self.pos] if self.pos < len(self.lines) else None

    def take(self) -> _Line:
        line = self.lines[self.pos]
        self.pos += 1
        return line

    def children(self, parent_indent: int) -> list[_Line]:
        """Consume and return every line indented deeper than ``parent_indent``."""
        start = self.pos
        while self.pos < len(self.lines) and self.lines[self.pos].indent > parent_indent:
            self.pos += 1
        return self.lines[start : self.pos]

    def fail(self, line: _Line, why: str) -> SpecError:
        return SpecError(f"line {line.number}: {why}: {line.text!r}")

    # A named field: NAME "title", then optional text blocks, then its variation.
    def named(self) -> Named:
        head = self.take()
        match = _NAMED.match(head.text)
        if not match:
            raise self.fail(head, 'expected NAME "title"')
        variation: Variation | None = None
        while (line := self.peek()) is not None and line.indent > head.indent:
            if line.text in _TEXT_BLOCKS:
                self.take()
                self.children(line.indent)
            elif variation is None:
                variation = self.variation()
            else:
                raise self.fail(line, "unexpected line after the variation")
        if variation is None:
            raise self.fail(head, "field without a variation")
        return Named(match.group(1), match.group(2), variation)

    def fields(self, parent_indent: int, separators: bool) -> list[Named | Spare | None]:
        """Fields of a group/extended/compound; ``None`` marks a '-' separator line."""
        out: list[Named | Spare | None] = []
        while (line := self.peek()) is not None and line.indent > parent_indent:
            if line.text == "-" and separators:
                self.take()
                out.append(None)
            elif line.text.startswith("spare "):
                self.take()
                out.append(Spare(int(line.text.split()[1])))
            else:
                out.append(self.named())
        return out

    def variation(self) -> Variation:
        line = self.take()
        words = line.text.split()
        kind = words[0]
        if kind == "element":
            content_line = self.take()
            return Element(int(words[1]), self.content(content_line))
        if kind == "group":
            fields = self.fields(line.indent, separators=False)
            return Group(tuple(f for f in fields if f is not None))
        if kind == "extended":
            return self.extended(line)
        if kind == "repetitive":
            counter = 0 if words[1] == "fx" else int(words[1])
            return Repetitive(counter, self.variation())
        if kind == "explicit":
            explicit_kind = words[1] if len(words) > 1 else ""
            if explicit_kind not in ("re", "sp", ""):
                raise self.fail(line, "unknown explicit kind")
            return Explicit(explicit_kind)  # type: ignore[arg-type]
        if kind == "compound":
            fspec = int(words[1]) if len(words) > 1 else 0
            slots = self.fields(line.indent, separators=True)
            if any(isinstance(s, Spare) for s in slots):
                raise self.fail(line, "spare inside a compound")
            return Compound(fspec, tuple(s for s in slots if not isinstance(s, Spare)))
        raise self.fail(line, "unknown variation")

    def extended(self, line: _Line) -> Extended:
        extents: list[tuple[Named | Spare, ...]] = []
        current: list[Named | Spare] = []
        for field in self.fields(line.indent, separators=True):
            if field is None:
                extents.append(tuple(current))
                current = []
            else:
                current.append(field)
        last_has_fx = not current
        if current:
            extents.append(tuple(current))
        for i, extent in enumerate(extents):
            bits = sum(_bits(f) for f in extent) + (1 if i < len(extents) - 1 or last_has_fx else 0)
            if bits % 8:
                raise self.fail(line, f"extent {i} is {bits} bits, not whole octets")
        return Extended(tuple(extents), last_has_fx)

    def content(self, line: _Line) -> Content:
        words = line.text.split()
        kind = words[0]
        if kind == "raw":
            return Raw()
        if kind == "table":
            entries = []
            for entry in self.children(line.indent):
                key, _, meaning = entry.text.partition(":")
                entries.append((int(key), meaning.strip()))
            return Table(tuple(entries))
        if kind in ("unsigned", "signed"):
            signed = kind == "signed"
            if words[1] == "integer":
                return Integer(signed)
            if words[1] == "quantity":
                match = re.match(r'^(\S+) "([^"]*)"', " ".join(words[2:]))
                if not match:
                    raise self.fail(line, "bad quantity")
                return Quantity(signed, _lsb(match.group(1)), match.group(2))
        if kind == "string" and words[1] in ("octal", "ascii", "icao"):
            return String(words[1])  # type: ignore[arg-type]
        if kind == "bds":
            return Bds(words[1] if len(words) > 1 else None)
        if kind == "case":
            cases: list[tuple[int, Content]] = []
            default: Content = Raw()
            while (label := self.peek()) is not None and label.indent > line.indent:
                self.take()
                chosen = self.content(self.take())
                if label.text == "default:":
                    default = chosen
                else:
                    cases.append((int(label.text.rstrip(":")), chosen))
            return Case(tuple(words[1].split("/")), tuple(cases), default)
        raise self.fail(line, "unknown element content")


def _lsb(text: str) -> Fraction:
    """LSB notations of the spec: '25', '0.25', '1/128', '360/2^16', '1/2^8'."""
    numerator, _, denominator = text.partition("/")
    value = Fraction(numerator)
    if denominator:
        base, _, power = denominator.partition("^")
        value /= Fraction(base) ** int(power or "1")
    return value


def _bits(field: Named | Spare | Variation) -> int:
    """Size of a fixed-size field in bits (groups, elements, spares)."""
    if isinstance(field, Spare):
        return field.bits
    if isinstance(field, Named):
        return _bits(field.variation)
    if isinstance(field, Element):
        return field.bits
    if isinstance(field, Group):
        return sum(_bits(f) for f in field.fields)
    raise SpecError(f"{type(field).__name__} has no fixed size")


def fixed_bits(variation: Variation) -> int | None:
    """Bits of a fixed-size variation, None for variable-size ones."""
    if isinstance(variation, Element | Group):
        return _bits(variation)
    return None


def parse_category(text: str) -> Category:
    parser = _Parser(text)
    header = parser.take()
    match = re.match(r'^asterix (\d+) "(.*)"$', header.text)
    if not match:
        raise parser.fail(header, 'expected: asterix NNN "title"')
    number, title = int(match.group(1)), match.group(2)
    edition = ""
    items: dict[str, Named] = {}
    uaps: list[tuple[str, Uap]] = []
    selector: UapSelector | None = None
    while (line := parser.peek()) is not None:
        parser.take()
        if line.text.startswith("edition "):
            edition = line.text.split()[1]
        elif line.text.startswith("date ") or line.text in _TEXT_BLOCKS:
            parser.children(line.indent)
        elif line.text == "items":
            while (item := parser.peek()) is not None and item.indent > line.indent:
                named = parser.named()
                items[named.name] = named
        elif line.text == "uap":
            uaps = [("", _uap(parser.children(line.indent)))]
        elif line.text == "uaps":
            uaps, selector = _uaps(parser, line)
        else:
            raise parser.fail(line, "unexpected top-level line")
    if not uaps:
        raise SpecError(f"category {number} has no UAP")
    for uap_name, uap in uaps:
        for name in uap:
            if name is not None and name != RFS and name not in items:
                raise SpecError(f"UAP {uap_name or number} names unknown item {name}")
    if selector is not None:
        _check_selector(selector, items, dict(uaps))
    return Category(
        number,
        title,
        edition,
        _with_display_hints(items),
        uaps[0][1],
        uaps=tuple(uaps),
        uap_selector=selector,
    )


def _uap(lines: list[_Line]) -> Uap:
    return tuple(None if u.text == "-" else RFS if u.text == "rfs" else u.text for u in lines)


def _uaps(parser: _Parser, head: _Line) -> tuple[list[tuple[str, Uap]], UapSelector]:
    """A "uaps" block: its "variations" (named UAPs) and the "case ITEM/ELEMENT" choosing them."""
    uaps: list[tuple[str, Uap]] = []
    selector: UapSelector | None = None
    while (line := parser.peek()) is not None and line.indent > head.indent:
        parser.take()
        if line.text == "variations":
            while (name := parser.peek()) is not None and name.indent > line.indent:
                parser.take()
                uaps.append((name.text, _uap(parser.children(name.indent))))
        elif line.text.startswith("case "):
            item, *element = line.text.split()[1].split("/")
            cases = []
            for entry in parser.children(line.indent):
                value, _, uap_name = entry.text.partition(":")
                cases.append((int(value), uap_name.strip()))
            selector = UapSelector(item, tuple(element), tuple(cases))
        else:
            raise parser.fail(line, "expected 'variations' or 'case' in 'uaps'")
    if not uaps or selector is None:
        raise parser.fail(head, "'uaps' needs its variations and the case selecting them")
    return uaps, selector


def _check_selector(selector: UapSelector, items: dict[str, Named], uaps: dict[str, Uap]) -> None:
    """The engine reads the selecting item before it knows the UAP: that item, and every
    slot before it, must be the same in every UAP."""
    if selector.item not in items:
        raise SpecError(f"UAP selector names unknown item {selector.item}")
    for _, uap_name in selector.cases:
        if uap_name not in uaps:
            raise SpecError(f"UAP selector names unknown UAP {uap_name}")
    first = next(iter(uaps.values()))
    if selector.item not in first:
        raise SpecError(f"UAP selector item {selector.item} is not in every UAP")
    prefix = first[: first.index(selector.item) + 1]
    for name, uap in uaps.items():
        if uap[: len(prefix)] != prefix:
            raise SpecError(f"UAP {name} does not start as the others up to {selector.item}")


def parse_expansion(text: str) -> tuple[int, str, Compound]:
    """A Reserved Expansion Field file: returns (category, edition, its compound)."""
    parser = _Parser(text)
    header = parser.take()
    match = re.match(r'^ref (\d+) "(.*)"$', header.text)
    if not match:
        raise parser.fail(header, 'expected: ref NNN "title"')
    edition = ""
    compound: Variation | None = None
    while (line := parser.peek()) is not None:
        if line.text.startswith("edition "):
            edition = line.text.split()[1]
            parser.take()
        elif line.text.startswith("date "):
            parser.take()
        else:
            compound = parser.variation()
    if not isinstance(compound, Compound):
        raise SpecError("a ref file must hold one compound")
    hinted = _with_display_hints({"RE": Named("RE", "", compound)})["RE"].variation
    assert isinstance(hinted, Compound)
    return int(match.group(1)), edition, hinted


# --- display hints ----------------------------------------------------------------------
# The spec marks aircraft addresses and Mode S data as plain "raw" bits; users read them as
# hex everywhere (ICAO 24-bit address, MB data), so such raw elements print as hex text.


def _hint(name: str, title: str, element: Element) -> Element:
    if not isinstance(element.content, Raw):
        return element
    text = f"{name} {title}".lower()
    if element.bits == 24 and "address" in text:
        return Element(24, Raw(hex_digits=6))
    if element.bits == 56 and ("mb" in name.lower() or "comm b" in text or "mode s" in text):
        return Element(56, Raw(hex_digits=14))
    return element


def _hinted(named: Named, outer_title: str) -> Named:
    return Named(named.name, named.title, _hinted_variation(named.variation, named, outer_title))


def _hinted_variation(variation: Variation, owner: Named, outer_title: str) -> Variation:
    title = f"{outer_title} {owner.title}"
    if isinstance(variation, Element):
        return _hint(owner.name, title, variation)

    def sub(f: Named | Spare) -> Named | Spare:
        return f if isinstance(f, Spare) else _hinted(f, title)

    if isinstance(variation, Group):
        return Group(tuple(sub(f) for f in variation.fields))
    if isinstance(variation, Extended):
        return Extended(
            tuple(tuple(sub(f) for f in ext) for ext in variation.extents), variation.last_has_fx
        )
    if isinstance(variation, Repetitive):
        return Repetitive(
            variation.counter_octets, _hinted_variation(variation.variation, owner, outer_title)
        )
    if isinstance(variation, Compound):
        return Compound(
            variation.fspec_octets,
            tuple(None if s is None else _hinted(s, title) for s in variation.slots),
        )
    return variation


def _with_display_hints(items: dict[str, Named]) -> dict[str, Named]:
    return {key: _hinted(named, "") for key, named in items.items()}


# --- the bundled editions ---------------------------------------------------------------

SPEC_FILES: dict[int, tuple[str, str | None]] = {
    1: ("cat001_cat-1.4.ast", None),
    2: ("cat002_cat-1.2.ast", None),
    21: ("cat021_cat-2.7.ast", "cat021_ref-1.5.ast"),
    34: ("cat034_cat-1.29.ast", None),
    48: ("cat048_cat-1.32.ast", "cat048_ref-1.13.ast"),
    62: ("cat062_cat-1.21.ast", "cat062_ref-1.3.ast"),
    63: ("cat063_cat-1.7.ast", None),
    65: ("cat065_cat-1.6.ast", None),
}


def _read(name: str) -> str:
    return resources.files("asterix").joinpath("specs", name).read_text(encoding="utf-8")


@cache
def category(number: int) -> Category:
    """The bundled edition of a category, with its Reserved Expansion Field when defined."""
    try:
        cat_file, ref_file = SPEC_FILES[number]
    except KeyError:
        raise KeyError(f"category {number} is not supported") from None
    spec = parse_category(_read(cat_file))
    if ref_file is not None:
        ref_cat, _, expansion = parse_expansion(_read(ref_file))
        if ref_cat != number:
            raise SpecError(f"{ref_file} is for category {ref_cat}")
        spec = replace(spec, expansion=expansion)
    return spec
