"""The outputs' batch JSON writers (``json_rows``, ``message_json``, ``updates``) against
the plain Python they stand for: pydantic-core's and ``json.dumps``'s number texts, an
f-string per slot kind, ``messages.iso_time``."""

from __future__ import annotations

import json

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic_core import to_json

from tracker_service.mcap_format import time_ns, times_ns
from tracker_service.outputs.json_rows import (
    HEX6,
    INTEGER,
    INTEGER_OR_NULL,
    JOIN,
    LITERAL,
    NUMBER,
    NUMBERS,
    OCTAL4,
    PART_OR_NULL,
    Literals,
    Numbers,
    Template,
    render,
)
from tracker_service.outputs.message_json import iso_times
from tracker_service.outputs.messages import iso_time
from tracker_service.outputs.updates import python_json_numbers

FLOATS = st.floats(allow_nan=True, allow_infinity=True, width=64)


@given(st.lists(FLOATS, max_size=40))
def test_numbers_are_the_models_texts(values: list[float]) -> None:
    numbers = Numbers.of(np.array(values, dtype=np.float64))
    data = numbers.data.tobytes()
    texts = [data[a:b] for a, b in zip(numbers.starts, numbers.ends, strict=True)]
    assert texts == [to_json(v, inf_nan_mode="null") for v in values]


@given(st.lists(FLOATS, max_size=40))
def test_python_numbers_are_json_dumps_texts(values: list[float]) -> None:
    assert python_json_numbers(values) == [json.dumps(v) for v in values]


@settings(max_examples=300, deadline=None)
@given(
    st.floats(0.0, 4e9)
    | st.integers(0, 4_000_000_000 * 2_000_000).map(lambda half_us: half_us / 2e6)
)
def test_iso_times_are_iso_time(posix: float) -> None:
    """Any time, and half microseconds (ties: rounded to even, as datetime does)."""
    assert iso_times(np.array([posix])) == [iso_time(posix)]


def _slot_text(kind: int, value: int, count: int, literals: list[bytes], parts: list[str]) -> str:
    """A slot as an f-string writes it: the reference of the compiled pass."""
    if kind == LITERAL:
        return literals[value].decode()
    if kind == INTEGER:
        return str(value)
    if kind == JOIN:
        return ",".join(parts[value : value + count])
    if value < 0:
        return "null"
    if kind == INTEGER_OR_NULL:
        return str(value)
    if kind == OCTAL4:
        return f'"{value:04o}"'
    if kind == HEX6:
        return f'"{value:06X}"'
    assert kind == PART_OR_NULL
    return parts[value]


@settings(max_examples=50, deadline=None)
@given(st.data())
def test_each_slot_kind_is_its_plain_python(data: st.DataObject) -> None:
    literals = Literals()
    words = [literals.string(w) for w in ("confirmed", 'a "quoted" word', "ünïcode", "")]
    numbers = data.draw(st.lists(FLOATS, min_size=1, max_size=10))
    texts = Numbers.of(np.array(numbers))
    part = Template.of('{"v":%s}', [INTEGER], literals)
    part_values = data.draw(st.lists(st.integers(-(2**40), 2**40), min_size=1, max_size=6))
    parts = render(part, np.array(part_values)[:, None], literals, texts)
    part_texts = [f'{{"v":{v}}}' for v in part_values]
    assert parts.rows() == [t.encode() for t in part_texts]
    kinds = [NUMBER, LITERAL, INTEGER, INTEGER_OR_NULL, OCTAL4, HEX6, JOIN, PART_OR_NULL, NUMBERS]
    template = Template.of("[" + ",".join(["%s"] * len(kinds)) + "]", kinds, literals)
    rows = data.draw(st.integers(0, 5))
    values = np.zeros((rows, len(kinds)), dtype=np.int64)
    counts = np.zeros_like(values)
    expected = []
    big = st.integers(-(2**62), 2**62)
    for r in range(rows):
        number = data.draw(st.integers(0, len(numbers) - 1))
        join = data.draw(st.integers(0, len(part_values)))
        run = data.draw(st.integers(0, len(numbers)))
        row = [
            number,
            data.draw(st.sampled_from(words)),
            data.draw(big),
            data.draw(big),
            data.draw(st.integers(-1, 2**15)),
            data.draw(st.integers(-1, 2**30)),
            data.draw(st.integers(0, len(part_values) - join)),
            data.draw(st.integers(-1, len(part_values) - 1)),
            data.draw(st.integers(0, len(numbers) - run)),
        ]
        values[r] = row
        counts[r, 6], counts[r, 8] = join, run
        pieces = [to_json(numbers[number], inf_nan_mode="null").decode()]
        pieces += [
            _slot_text(k, v, c, [literals[i] for i in range(len(literals))], part_texts)
            for k, v, c in zip(kinds[1:8], row[1:8], counts[r, 1:8], strict=True)
        ]
        pieces.append(
            ",".join(
                to_json(v, inf_nan_mode="null").decode() for v in numbers[row[8] : row[8] + run]
            )
        )
        expected.append(("[" + ",".join(pieces) + "]").encode())
    assert render(template, values, literals, texts, counts, parts).rows() == expected


@given(st.lists(st.floats(0.0, 4e9) | st.integers(0, 8 * 10**9).map(lambda n: n / 2e9)))
def test_times_ns_are_time_ns(times: list[float]) -> None:
    assert times_ns(np.array(times, dtype=np.float64)) == [time_ns(t) for t in times]
