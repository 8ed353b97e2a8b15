"""Properties of the codec over the whole specification, and robustness against bad bytes.

Values are generated from the same specification model the codec is built from, for every
item of every category, so encoders of items that no sample recording holds are exercised
too. The fuzz tests throw random and mutated records at the decoder and the plot path.
"""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from asterix import (
    SUPPORTED_CATEGORIES,
    Block,
    DecodeError,
    EncodeError,
    decode_blocks,
    encode_block,
    encode_record,
    spec,
)
from asterix.engine import ICAO_CHARACTERS
from asterix.plots import extract_plots
from asterix.spec import (
    Bds,
    Case,
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


def _content(content: Content, bits: int, siblings: dict[str, Any]) -> st.SearchStrategy[Any]:
    if isinstance(content, Case):
        # The selector sibling is drawn first; pick the content it selects.
        chosen = dict(content.cases).get(siblings.get(content.selector[-1], -1), content.default)
        return _content(chosen, bits, siblings)
    if isinstance(content, Quantity | Integer) and content.signed:
        raw = st.integers(-(1 << (bits - 1)), (1 << (bits - 1)) - 1)
    else:
        raw = st.integers(0, (1 << bits) - 1)
    if isinstance(content, Quantity):
        lsb = float(content.lsb)
        return raw.map(lambda r: r * lsb)
    if isinstance(content, Raw) and content.hex_digits:
        return raw.map(lambda r: f"{r:0{content.hex_digits}X}")
    if isinstance(content, Bds):
        return raw.map(lambda r: f"{r:0{bits // 4}X}")
    if isinstance(content, String):
        if content.kind == "icao":
            return st.text(alphabet=ICAO_CHARACTERS, min_size=bits // 6, max_size=bits // 6)
        if content.kind == "ascii":
            return st.text(
                alphabet=st.characters(max_codepoint=255), min_size=bits // 8, max_size=bits // 8
            )
        digits = [3] * (bits // 3) + ([bits % 3] if bits % 3 else [])
        return st.tuples(*(st.integers(0, (1 << w) - 1) for w in digits)).map(
            lambda ds: "".join(str(d) for d in ds)
        )
    assert isinstance(content, Raw | Table | Integer)
    return raw


@st.composite
def _fields(draw: st.DrawFn, fields: tuple[Named | Spare, ...]) -> dict[str, Any]:
    value: dict[str, Any] = {}
    for f in fields:
        if isinstance(f, Named):
            value[f.name] = draw(_variation(f.variation, value))
    return value


def _variation(variation: Variation, siblings: dict[str, Any] | None = None) -> Any:
    if isinstance(variation, Element):
        return _content(variation.content, variation.bits, siblings or {})
    if isinstance(variation, Group):
        return _fields(variation.fields)
    if isinstance(variation, Extended):
        return st.integers(1, len(variation.extents)).flatmap(
            lambda n: _fields(tuple(f for ext in variation.extents[:n] for f in ext))
        )
    if isinstance(variation, Repetitive):
        return st.lists(
            _variation(variation.variation),
            min_size=0 if variation.counter_octets else 1,
            max_size=3,
        )
    if isinstance(variation, Compound):
        present = [s for s in variation.slots if s is not None]
        return st.lists(st.sampled_from(present), unique=True, min_size=1, max_size=4).flatmap(
            lambda chosen: st.fixed_dictionaries({s.name: _variation(s.variation) for s in chosen})
        )
    assert isinstance(variation, Explicit)
    return st.binary(min_size=0, max_size=8).map(lambda b: b.hex().upper())


def _same(a: Any, b: Any) -> bool:
    if isinstance(a, float) or isinstance(b, float):
        return math.isclose(a, b, rel_tol=1e-12, abs_tol=1e-12)
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(map(_same, a, b))
    return bool(a == b)


@st.composite
def _record(draw: st.DrawFn, cat: int) -> dict[str, Any]:
    category = spec.category(cat)
    uap_name, uap = draw(st.sampled_from(category.uaps))
    keys = [k for k in uap if k is not None and k not in ("RE", spec.RFS)]
    chosen = draw(st.lists(st.sampled_from(keys), unique=True, min_size=1, max_size=8))
    record = {k: draw(_variation(category.items[k].variation)) for k in chosen}
    selector = category.uap_selector
    if selector is not None:
        # The record says which UAP it follows (CAT001: I020 TYP).
        (element,) = selector.element
        item = record.setdefault(
            selector.item, draw(_variation(category.items[selector.item].variation))
        )
        item[element] = next(value for value, name in selector.cases if name == uap_name)
    return record


@pytest.mark.parametrize("cat", SUPPORTED_CATEGORIES)
@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.data())
def test_any_valid_record_round_trips(cat: int, data: st.DataObject) -> None:
    record = data.draw(_record(cat))
    try:
        block = encode_block(cat, [record])
    except EncodeError as exc:
        # SP and RE payloads are free hex; any other refusal is a bug.
        pytest.fail(f"valid record refused: {exc}")
    (event,) = list(decode_blocks(block))
    assert isinstance(event, Block)
    (decoded,) = event.records
    assert _same(record, decoded), (record, decoded)
    assert encode_block(cat, event.records) == block


@pytest.mark.parametrize(
    "cat", [c for c in SUPPORTED_CATEGORIES if spec.category(c).expansion is not None]
)
@settings(max_examples=60, deadline=None)
@given(data=st.data())
def test_reserved_expansion_round_trips(cat: int, data: st.DataObject) -> None:
    expansion = spec.category(cat).expansion
    assert expansion is not None
    value = data.draw(_variation(expansion))
    block = encode_block(cat, [{"010": {"SAC": 1, "SIC": 2}, "RE": value}])
    (event,) = list(decode_blocks(block))
    assert isinstance(event, Block)
    assert _same(event.records[0]["RE"], value)


def test_encoder_names_the_field_and_the_limit() -> None:
    with pytest.raises(EncodeError, match=r"I048/040/RHO: .* outside"):
        encode_record(48, {"040": {"RHO": 300.0, "THETA": 0.0}})
    with pytest.raises(EncodeError, match=r"unknown field\(s\) \['RHOO'\]"):
        encode_record(48, {"040": {"RHOO": 3.0}})
    with pytest.raises(EncodeError, match=r"unknown item\(s\) \['999'\]"):
        encode_record(48, {"999": 1})
    with pytest.raises(EncodeError, match="octal"):
        encode_record(48, {"070": {"MODE3A": "7800"}})


def test_callsign_with_invalid_characters_survives_a_round_trip() -> None:
    # The raw I240 of 068test_bds30.gps: six-bit codes outside A-Z, 0-9 and space.
    raw = bytes.fromhex("82CA33ADB2C1")
    record = {"010": {"SAC": 20, "SIC": 4}, "240": "@" * 8}
    block = bytearray(encode_block(48, [record]))
    block[-6:] = raw
    (event,) = list(decode_blocks(bytes(block)))
    assert isinstance(event, Block)
    assert encode_block(48, event.records) == bytes(block)


# --- robustness ---------------------------------------------------------------------------

_SEED_RECORDS = {
    1: {
        "010": {"SAC": 20, "SIC": 130},
        "020": {"TYP": 0, "SSRPSR": 2},
        "040": {"RHO": 5.28125, "THETA": 175.8},
        "070": {"MODE3A": "2270"},
        "090": {"HGT": 221.0},
        "130": [6],
        "141": 383.578125,
        "RFS": [{"131": -70.0}],
    },
    2: {"010": {"SAC": 20, "SIC": 130}, "000": 1, "030": 66433.6328125, "041": 4.0},
    48: {
        "010": {"SAC": 25, "SIC": 201},
        "140": 27354.6015625,
        "020": {"TYP": 5, "TST": 0},
        "040": {"RHO": 197.68359375, "THETA": 340.13671875},
        "070": {"MODE3A": "1000"},
        "090": {"FL": 330.0},
        "130": {"SRL": 0.5, "SAM": -70.0},
        "220": "3C660C",
        "240": "DLH65A  ",
        "250": [{"MBDATA": "C0780031BC0000", "BDS1": 4, "BDS2": 0}],
        "161": {"TRN": 3563},
        "200": {"GSP": 0.12, "HDG": 124.0},
        "170": {"CNF": 0},
        "030": [1, 3],
        "RE": {"ERR": 300.0},
        "SP": "0102",
    },
    34: {
        "010": {"SAC": 25, "SIC": 14},
        "000": 2,
        "030": 29906.3359375,
        "020": 90.0,
        "050": {"COM": {"NOGO": 0}, "SSR": {"ANT": 0}},
    },
    62: {
        "010": {"SAC": 25, "SIC": 100},
        "015": 4,
        "070": 30911.66,
        "040": 4980,
        "105": {"LAT": 44.7, "LON": 13.0},
        "080": {"MON": 0, "CST": 1},
        "380": {"ADR": "3C660C", "ID": "DLH65A  "},
        "340": {"SID": {"SAC": 25, "SIC": 13}},
    },
    65: {"010": {"SAC": 25, "SIC": 100}, "000": 2, "015": 4, "030": 30913.0546875},
    21: {
        "010": {"SAC": 0, "SIC": 1},
        "040": {"ATP": 0, "GBS": 1},
        "080": "3C660C",
        "130": {"LAT": 61.4, "LON": -7.8},
        "170": "DLH65A  ",
        "RE": {"SGV": {"STP": 1}},
    },
}
_CAT001_TRACK = {
    "010": {"SAC": 20, "SIC": 130},
    "020": {"TYP": 1, "SSRPSR": 3, "TST": 0},
    "161": 77,
    "040": {"RHO": 100.5, "THETA": 12.0},
    "200": {"GSP": 0.1, "HDG": 45.0},
    "170": {"CON": 0, "TRE": 0},
}
_SEED = b"".join(
    encode_block(cat, [rec, rec]) for cat, rec in _SEED_RECORDS.items()
) + encode_block(1, [_CAT001_TRACK])


def _check_decoder_survives(data: bytes) -> None:
    total = 0
    for event in decode_blocks(data):
        if isinstance(event, DecodeError):
            assert 0 <= event.offset <= len(data)
            assert event.reason
        else:
            total += len(event.records)
    # Every record takes at least two octets (an FSPEC and an item).
    assert total <= len(data) // 2
    batch = extract_plots(data)
    assert len(batch.plots) <= len(data) // 2


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=600))
def test_random_bytes_never_crash_the_decoder(data: bytes) -> None:
    _check_decoder_survives(data)


@settings(max_examples=400, deadline=None)
@given(st.binary(max_size=400).map(lambda b: bytes([48]) + (len(b) + 3).to_bytes(2) + b))
def test_random_cat048_blocks_never_crash_the_decoder(data: bytes) -> None:
    _check_decoder_survives(data)


@settings(max_examples=600, deadline=None)
@given(
    st.lists(
        st.tuples(st.integers(0, len(_SEED) - 1), st.integers(0, 255)), min_size=1, max_size=8
    ),
    st.integers(0, len(_SEED)),
)
def test_mutated_records_never_crash_the_decoder(
    mutations: list[tuple[int, int]], cut: int
) -> None:
    data = bytearray(_SEED)
    for position, value in mutations:
        data[position] = value
    _check_decoder_survives(bytes(data[:cut]))
    _check_decoder_survives(bytes(data))


def test_a_bad_record_ends_its_block_and_the_next_block_is_read() -> None:
    good = encode_block(48, [_SEED_RECORDS[48]])
    bad = bytearray(good)
    bad[3:5] = b"\xff\xff"  # an FSPEC that runs on and names items the block cannot hold
    events = list(decode_blocks(bytes(bad) + good + bytes([99, 0, 4, 0]) + good))
    kinds = [type(e).__name__ for e in events]
    assert kinds == ["Block", "DecodeError", "Block", "Block", "Block"]
    assert isinstance(events[1], DecodeError) and events[1].category == 48
    assert isinstance(events[3], Block) and not events[3].supported and events[3].cat == 99
    assert isinstance(events[4], Block) and len(events[4].records) == 1
