"""JSON written for a whole batch of rows at once: the outputs' messages without a Python
object, a dict or a writer call per message.

A message's JSON is a ``Template``: its text with a slot (``%s``) wherever a value goes,
and the kind of each slot. ``render`` fills a template for every row of a batch in one
compiled pass (numba, ``cache=True``) from an (N, slots) matrix of values:

- ``NUMBER``: a number's text, by index into ``Numbers``: a whole batch's numbers written
  by one call of pydantic-core's JSON writer (``to_json``, which the message models'
  ``model_dump_json`` uses: the same text, a non-finite number as null), split at its
  commas by position;
- ``LITERAL``: a text of the ``Literals`` table by its id (a status, a radar's JSON string,
  a callsign's, ``true``, ``null``);
- ``INTEGER``, ``INTEGER_OR_NULL``: an integer in decimal (a negative one null);
- ``OCTAL4``, ``HEX6``: a Mode 3/A code (``"1234"``) or a Mode S address (``"3C660C"``),
  a negative one null;
- ``JOIN``: rows of another rendering (``Rendered``: the sources of a track, its DAPs),
  ``counts`` of them from the index given, separated by commas (none: nothing);
- ``PART_OR_NULL``: one row of another rendering (a track's last plot), or null;
- ``NUMBERS``: ``counts`` numbers from the index given, separated by commas (a list of
  numbers: model probabilities).

The compiled pass copies bytes: every number is written by pydantic-core, every string by
``to_json`` when it enters the table, so the messages are byte for byte what the models
write (``tests/test_outputs_updates.py`` holds each message to its model's
``model_dump_json``). ``Rendered.rows()`` gives each row's bytes.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from pydantic_core import to_json

from tracker_service.numba_symbols import numba

__all__ = [
    "HEX6",
    "INTEGER",
    "INTEGER_OR_NULL",
    "JOIN",
    "LITERAL",
    "NUMBER",
    "NUMBERS",
    "OCTAL4",
    "PART_OR_NULL",
    "Literals",
    "Numbers",
    "Rendered",
    "Table",
    "Template",
    "render",
    "render_parts",
    "render_rows",
]

NUMBER = 0
LITERAL = 1
INTEGER = 2
INTEGER_OR_NULL = 3
OCTAL4 = 4
HEX6 = 5
JOIN = 6
PART_OR_NULL = 7
NUMBERS = 8

Bytes = npt.NDArray[np.uint8]
IntArray = npt.NDArray[np.int64]
Table = tuple[Bytes, IntArray, IntArray]
"""Texts one after another and where each starts and ends (``Literals.arrays``,
``Numbers.table``, ``Rendered.table``): what the compiled passes read."""


class Literals:
    """A table of JSON texts by id: a template's fixed pieces and the strings its slots
    name (statuses, radars, callsigns). ``add`` gives a text's id (the same text, the
    same id), appended to arrays that grow by doubling, which the renderer reads."""

    def __init__(self) -> None:
        self._ids: dict[bytes, int] = {}
        self._texts: list[bytes] = []
        self._data = np.zeros(1024, dtype=np.uint8)
        self._starts = np.zeros(64, dtype=np.int64)
        self._ends = np.zeros(64, dtype=np.int64)
        self._size = 0

    def __len__(self) -> int:
        return len(self._texts)

    def __getitem__(self, text_id: int) -> bytes:
        return self._texts[text_id]

    def add(self, text: bytes) -> int:
        known = self._ids.get(text)
        if known is not None:
            return known
        index = len(self._texts)
        if index == self._starts.size:
            self._starts = np.resize(self._starts, 2 * index)
            self._ends = np.resize(self._ends, 2 * index)
        end = self._size + len(text)
        if end > self._data.size:
            self._data = np.resize(self._data, max(2 * self._data.size, end))
        self._data[self._size : end] = np.frombuffer(text, dtype=np.uint8)
        self._starts[index], self._ends[index] = self._size, end
        self._size = end
        self._ids[text] = index
        self._texts.append(text)
        return index

    def string(self, text: str) -> int:
        """The id of ``text`` as a JSON string (pydantic-core's escaping)."""
        return self.add(to_json(text))

    def arrays(self) -> Table:
        """The texts one after another, and where each starts and ends."""
        n = len(self._texts)
        return self._data, self._starts[:n], self._ends[:n]


@dataclass(frozen=True)
class Rendered:
    """Texts one after another: rows written, numbers' texts (``Numbers``); text ``i`` is
    ``data[starts[i]:ends[i]]``."""

    data: Bytes
    starts: IntArray
    ends: IntArray

    @property
    def table(self) -> Table:
        return self.data, self.starts, self.ends

    @classmethod
    def empty(cls) -> Rendered:
        none = np.zeros(0, dtype=np.int64)
        return cls(np.zeros(1, dtype=np.uint8), none, none)

    def rows(self) -> list[bytes]:
        data = self.data.tobytes()
        return [data[a:b] for a, b in zip(self.starts.tolist(), self.ends.tolist(), strict=True)]


@dataclass(frozen=True)
class Numbers(Rendered):
    """Numbers' JSON texts, written at once: ``Numbers.of(values)``."""

    @classmethod
    def of(cls, values: npt.NDArray[np.float64]) -> Numbers:
        """``values`` (floats; NaN and infinities are null) as pydantic-core writes them,
        non-finite ones as null (``inf_nan_mode="null"``, the models' serialisation)."""
        if values.size == 0:
            empty = np.zeros(0, dtype=np.int64)
            return cls(np.zeros(1, dtype=np.uint8), empty, empty)
        return cls._split(to_json(values.ravel().tolist(), inf_nan_mode="null"))

    @classmethod
    def of_texts(cls, texts: Sequence[str]) -> Numbers:
        """Numbers' texts already written (``updates.python_json_numbers``)."""
        if not texts:
            return cls.of(np.zeros(0))
        return cls._split(("[" + ",".join(texts) + "]").encode())

    @classmethod
    def _split(cls, text: bytes) -> Numbers:
        data = np.frombuffer(text, dtype=np.uint8)
        # "[a,b,...]": numbers, and null, hold no comma.
        commas = np.flatnonzero(data == ord(","))
        starts = np.empty(commas.size + 1, dtype=np.int64)
        starts[0] = 1
        starts[1:] = commas + 1
        ends = np.empty_like(starts)
        ends[:-1] = commas
        ends[-1] = data.size - 1
        return cls(data, starts, ends)


@dataclass(frozen=True)
class Template:
    """A message's JSON with its slots: ``text`` split at each ``%s``, ``kinds`` the kind
    of each slot in order. ``ids`` are its fixed pieces' ids in ``literals``."""

    kinds: IntArray
    ids: IntArray

    @classmethod
    def of(cls, text: str, kinds: Sequence[int], literals: Literals) -> Template:
        pieces = text.split("%s")
        if len(pieces) != len(kinds) + 1:
            raise ValueError(f"{len(pieces) - 1} slots in the template, {len(kinds)} kinds")
        ids = [literals.add(piece.encode()) for piece in pieces]
        return cls(np.array(kinds, dtype=np.int64), np.array(ids, dtype=np.int64))

    @property
    def slots(self) -> int:
        return len(self.kinds)


def render(
    template: Template,
    values: IntArray,
    literals: Literals,
    numbers: Numbers,
    counts: IntArray | None = None,
    parts: Rendered | None = None,
) -> Rendered:
    """Every row of ``values`` (N, slots) through ``template``; ``counts`` (N, slots):
    how many rows of ``parts`` each ``JOIN`` slot takes."""
    if values.ndim != 2 or values.shape[1] != template.slots:
        raise ValueError(f"values of shape {values.shape} for {template.slots} slots")
    if counts is None:
        counts = np.zeros_like(values)
    parts = parts or Rendered.empty()
    data, starts, ends = render_rows(
        template.kinds,
        template.ids,
        np.ascontiguousarray(values, dtype=np.int64),
        np.ascontiguousarray(counts, dtype=np.int64),
        literals.arrays(),
        numbers.table,
        parts.table,
    )
    return Rendered(data, starts, ends)


@numba.njit(cache=True)
def _digits(value: int, base: int = 10) -> int:
    """How many digits ``value`` (>= 0) has in ``base``."""
    n = 1
    while value >= base:
        n += 1
        value //= base
    return n


@numba.njit(cache=True)
def _slot_size(kind: int, value: int, count: int, lit: Table, num: Table, part: Table) -> int:
    if kind == NUMBER:
        return int(num[2][value] - num[1][value])
    if kind == LITERAL:
        return int(lit[2][value] - lit[1][value])
    if kind == INTEGER:
        return _digits(value) if value >= 0 else 1 + _digits(-value)
    if kind == JOIN:
        return _joined_size(part, value, count)
    if kind == NUMBERS:
        return _joined_size(num, value, count)
    if value < 0:
        return 4  # null
    if kind == INTEGER_OR_NULL:
        return _digits(value)
    if kind == PART_OR_NULL:
        return int(part[2][value] - part[1][value])
    if kind == OCTAL4:
        return 2 + max(4, _digits(value, 8))
    return 2 + max(6, _digits(value, 16))


@numba.njit(cache=True)
def _copy(out: Bytes, pos: int, source: Table, index: int) -> int:
    """Text ``index`` of ``source`` into ``out`` at ``pos``; the position after it.
    Unsigned indices: no negative-index wrap-around to test at each byte (about 3x
    faster)."""
    data, start, end = source[0], source[1][index], source[2][index]
    at, i, stop = np.uint64(pos), np.uint64(start), np.uint64(end)
    while i < stop:
        out[at] = data[i]
        at += np.uint64(1)
        i += np.uint64(1)
    return int(pos + end - start)


@numba.njit(cache=True)
def _joined_size(source: Table, first: int, count: int) -> int:
    """The length of texts ``first`` to ``first + count`` of ``source`` joined by commas."""
    size = max(count - 1, 0)
    for i in range(first, first + count):
        size += int(source[2][i] - source[1][i])
    return size


@numba.njit(cache=True)
def _write_joined(out: Bytes, pos: int, source: Table, first: int, count: int) -> int:
    for i in range(first, first + count):
        if i > first:
            out[pos] = 44  # ","
            pos += 1
        pos = _copy(out, pos, source, i)
    return pos


@numba.njit(cache=True)
def _write_digits(out: Bytes, pos: int, value: int, base: int, width: int) -> int:
    """``value`` (>= 0) in ``base``, at least ``width`` digits (zeros first), upper case."""
    n = max(_digits(value, base), width)
    for i in range(n - 1, -1, -1):
        digit = value % base
        out[pos + i] = 48 + digit if digit < 10 else 55 + digit
        value //= base
    return pos + n


_NULL = np.frombuffer(b"null", dtype=np.uint8)


@numba.njit(cache=True)
def _write_slot(
    out: Bytes, pos: int, kind: int, value: int, count: int, lit: Table, num: Table, part: Table
) -> int:
    if kind == NUMBER:
        return _copy(out, pos, num, value)
    if kind == LITERAL:
        return _copy(out, pos, lit, value)
    if kind == INTEGER:
        if value < 0:
            out[pos] = 45  # "-"
            return _write_digits(out, pos + 1, -value, 10, 1)
        return _write_digits(out, pos, value, 10, 1)
    if kind == JOIN:
        return _write_joined(out, pos, part, value, count)
    if kind == NUMBERS:
        return _write_joined(out, pos, num, value, count)
    if value < 0:
        for i in range(4):
            out[pos + i] = _NULL[i]
        return pos + 4
    if kind == INTEGER_OR_NULL:
        return _write_digits(out, pos, value, 10, 1)
    if kind == PART_OR_NULL:
        return _copy(out, pos, part, value)
    out[pos] = 34  # '"'
    if kind == OCTAL4:
        pos = _write_digits(out, pos + 1, value, 8, 4)
    else:
        pos = _write_digits(out, pos + 1, value, 16, 6)
    out[pos] = 34
    return pos + 1


@numba.njit(cache=True)
def render_rows(
    kinds: IntArray,
    ids: IntArray,
    values: IntArray,
    counts: IntArray,
    lit: Table,
    num: Table,
    part: Table,
) -> Table:
    """The compiled pass of :func:`render` (for other kernels, which build the values
    themselves): the rows one after another, and where each starts and ends."""
    n, slots = values.shape
    fixed = 0
    for j in range(slots + 1):
        fixed += lit[2][ids[j]] - lit[1][ids[j]]
    starts = np.empty(n, dtype=np.int64)
    ends = np.empty(n, dtype=np.int64)
    total = 0
    for r in range(n):
        size = fixed
        for j in range(slots):
            kind, value = kinds[j], values[r, j]
            # Numbers and literals (most slots) here; the others by the helper.
            if kind == NUMBER:
                size += num[2][value] - num[1][value]
            elif kind == LITERAL:
                size += lit[2][value] - lit[1][value]
            else:
                size += _slot_size(kind, value, counts[r, j], lit, num, part)
        starts[r] = total
        total += size
        ends[r] = total
    out = np.empty(max(total, 1), dtype=np.uint8)
    for r in range(n):
        pos = starts[r]
        for j in range(slots):
            pos = _copy(out, pos, lit, ids[j])
            kind, value = kinds[j], values[r, j]
            if kind == NUMBER:
                pos = _copy(out, pos, num, value)
            elif kind == LITERAL:
                pos = _copy(out, pos, lit, value)
            else:
                pos = _write_slot(out, pos, kind, value, counts[r, j], lit, num, part)
        _copy(out, pos, lit, int(ids[slots]))
    return out, starts, ends


@numba.njit(cache=True)
def render_parts(
    kinds: IntArray, ids: IntArray, values: IntArray, counts: IntArray, lit: Table, num: Table
) -> Table:
    """:func:`render_rows` of a template without ``JOIN`` or ``PART_OR_NULL`` slots (the
    parts of another rendering, a message of numbers and literals)."""
    none = np.zeros(0, dtype=np.int64)
    return render_rows(kinds, ids, values, counts, lit, num, (np.zeros(1, np.uint8), none, none))
