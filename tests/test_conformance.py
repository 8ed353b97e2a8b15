"""Every record of the real recordings against the independent decoder, and round trips.

The oracle files (../shared/data/asterix/oracle-full and oracle/) were produced by
libasterix 0.36.3 and cross-checked against two more decoders (see SOURCES.md there).
"""

from __future__ import annotations

import json
from collections.abc import Iterator
from typing import Any

import numpy as np
import pytest

from asterix import Block, DecodeError, decode_blocks, encode_block
from asterix.containers import Datagram, read_file
from asterix.plots import extract_plots
from tests.asterix_oracle import differences
from tests.conftest import shared_file

RECORDINGS = [
    "croatiacontrol/cat048.raw",
    "croatiacontrol/cat034.raw",
    "croatiacontrol/cat062cat065.raw",
    "croatiacontrol/cat21_re.ast",
    "croatiacontrol/cat_034_048.pcap",
    "croatiacontrol/cat_062_065.pcap",
    "croatiacontrol/parsegps.gps",
    "reader_network/068test_bds30.gps",
    "reader_network/066test_filter.gps",
    "reader_network/canalA.gps",
    "jade/final_frame_cat062_one_packet.ff",
    "jade/final_frame_062_one_packet_sample2.FF",
    "jasterix/cat021ed2.1.bin",
    "jasterix/cat034ed1.26.bin",
    "jasterix/cat048ed1.15.bin",
    "jasterix/cat048ed1.23.bin",
    "jasterix/cat062ed1.16.bin",
]
CAT048_RECORDINGS = [
    "croatiacontrol/cat048.raw",
    "croatiacontrol/cat_034_048.pcap",
    "croatiacontrol/parsegps.gps",
    "reader_network/068test_bds30.gps",
    "reader_network/066test_filter.gps",
    "jasterix/cat048ed1.15.bin",
    "jasterix/cat048ed1.23.bin",
]
ORACLE_CATEGORIES = {21, 34, 48, 62, 65}
EXTRA_ORACLE_CATEGORIES = {"reader_network/canalA.gps": {1, 2}}
"""Categories the oracle holds for one file only (SOURCES.md, oracle-full)."""


def _blocks(relative: str) -> Iterator[tuple[Datagram, Block | DecodeError]]:
    for unit in read_file(shared_file(relative)):
        assert isinstance(unit, Datagram), unit
        for event in decode_blocks(unit.payload, unit.offset):
            yield unit, event


def _records(relative: str) -> list[dict[str, Any]]:
    out = []
    categories = ORACLE_CATEGORIES | EXTRA_ORACLE_CATEGORIES.get(relative, set())
    for block, (_, event) in enumerate(_blocks(relative), 1):
        assert isinstance(event, Block), event
        if event.cat in categories:
            out += [
                {"cat": event.cat, "block": block, "record": i, "items": items}
                for i, items in enumerate(event.records)
            ]
    return out


def _oracle(relative: str, suffix: str) -> list[dict[str, Any]]:
    name = relative.split("/")[-1]
    folder = "oracle-full" if suffix == ".jsonl" else "oracle"
    path = shared_file(f"{folder}/{name}{suffix}")
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.parametrize("relative", RECORDINGS)
def test_every_item_matches_the_oracle(relative: str) -> None:
    oracle = _oracle(relative, ".jsonl")
    ours = _records(relative)
    assert len(ours) == len(oracle)
    problems = []
    for expected, got in zip(oracle, ours, strict=True):
        assert (got["cat"], got["block"], got["record"]) == (
            expected["cat"],
            expected["block"],
            expected["record"],
        )
        diff = differences(expected["items"], got["items"])
        if diff:
            problems.append((expected["block"], expected["record"], diff[:4]))
    assert not problems, problems[:5]


def _key_fields(items: dict[str, Any]) -> dict[str, Any]:
    """Our decoded items in the field names of the CAT048 key-field oracle."""
    out: dict[str, Any] = {}
    flat = {
        "010": {"SAC": "SAC", "SIC": "SIC"},
        "020": {k: f"I020_{k}" for k in ("TYP", "SIM", "RDP", "SPI", "RAB")},
        "040": {"RHO": "RHO_NM", "THETA": "THETA_deg"},
        "070": {"V": "I070_V", "G": "I070_G", "L": "I070_L", "MODE3A": "Mode3A"},
        "090": {"V": "I090_V", "G": "I090_G", "FL": "FL"},
        "042": {"X": "X_NM", "Y": "Y_NM"},
        "161": {"TRN": "TrackNumber"},
        "200": {"HDG": "HDG_deg"},
        "170": {k: f"I170_{k}" for k in ("CNF", "RAD", "DOU", "MAH", "CDM")},
        "230": {k: f"I230_{k}" for k in ("COM", "STAT", "SI", "MSSC", "ARC", "AIC", "B1A", "B1B")},
    }
    for item, names in flat.items():
        for element, key in names.items():
            if item in items and element in items[item]:
                out[key] = items[item][element]
    if "140" in items:
        out["ToD_s"] = items["140"]
    if "200" in items:
        out["GS_kt"] = items["200"]["GSP"] * 3600
    if "220" in items:
        out["ACAddr"] = items["220"]
    if "110" in items:
        out["Height3D_ft"] = items["110"]["3DH"]
    if "250" in items:
        out["BDS"] = [f"{r['BDS1']:X}{r['BDS2']:X}" for r in items["250"]]
        out["MB_hex"] = [r["MBDATA"] for r in items["250"]]
    out["items"] = list(items)
    return out


@pytest.mark.parametrize("relative", CAT048_RECORDINGS)
def test_cat048_key_fields_match_the_oracle(relative: str) -> None:
    oracle = _oracle(relative, ".cat048.libasterix.jsonl")
    ours = [r for r in _records(relative) if r["cat"] == 48]
    assert len(ours) == len(oracle)
    for expected, got in zip(oracle, ours, strict=True):
        fields = _key_fields(got["items"])
        for key, value in expected.items():
            if key in ("block", "rec"):
                continue
            if key == "Callsign":
                raw = bytes.fromhex(expected["I240_hex"])
                assert got["items"]["240"] == _icao_reference(raw), (got, expected)
                continue
            if key == "I240_hex":
                continue
            if key == "ACAddr":
                assert int(fields[key], 16) == int(value, 16)
                continue
            assert differences(value, fields[key]) == [], (key, expected, got)
        assert (got["block"], got["record"]) == (expected["block"], expected["rec"])


def _icao_reference(raw: bytes) -> str:
    """ICAO Annex 10 6-bit characters, written out independently of the codec's table."""
    value = int.from_bytes(raw)
    chars = []
    for shift in range(42, -1, -6):
        code = (value >> shift) & 63
        chars.append(chr(code + 64) if code < 32 else chr(code))
    return "".join(chars)


@pytest.mark.parametrize("relative", RECORDINGS)
def test_every_block_re_encodes_to_identical_bytes(relative: str) -> None:
    blocks = 0
    for unit, event in _blocks(relative):
        assert isinstance(event, Block)
        if not event.supported:
            continue
        start = event.offset - unit.offset
        original = unit.payload[start : start + int.from_bytes(unit.payload[start + 1 : start + 3])]
        assert encode_block(event.cat, event.records) == original
        blocks += 1
    assert blocks > 0


def test_dual_lan_capture_identifies_duplicate_payloads() -> None:
    payloads = [
        u.payload
        for u in read_file(shared_file("croatiacontrol/cat_034_048.pcap"))
        if isinstance(u, Datagram)
    ]
    assert len(payloads) == 100 and len(set(payloads)) == 50


@pytest.mark.parametrize("relative", [*CAT048_RECORDINGS, "reader_network/canalA.gps"])
def test_plot_extraction_gives_the_general_decoders_values(relative: str) -> None:
    plots = 0
    units = [u.payload for u in read_file(shared_file(relative)) if isinstance(u, Datagram)]
    # canalA's 28,645 datagrams are all alike (one plot record each): 10 minutes of them.
    units = units[:6000]
    # Datagrams joined by the hundred: canalA sends one plot a datagram, 28,645 of them.
    for start in range(0, len(units), 100):
        payload = b"".join(units[start : start + 100])
        batch = extract_plots(payload)
        assert batch.errors == []
        records = [
            (event.cat, items)
            for event in decode_blocks(payload)
            if isinstance(event, Block) and event.cat in (1, 48)
            for items in event.records
        ]
        assert len(batch.plots) == len(records)
        for plot, (cat, items) in zip(batch.plots, records, strict=True):
            assert plot["category"] == cat
            _assert_plot_matches(plot, items, cat)
        plots += len(records)
        # Datagram by datagram, small batches are read record by record: the same values.
        singles = [extract_plots(u).plots for u in units[start : start + 100]]
        one_by_one = np.concatenate(singles)
        for name in one_by_one.dtype.names or ():
            if name != "offset":
                np.testing.assert_array_equal(one_by_one[name], batch.plots[name], name)
    assert plots > 0


def _assert_plot_matches(plot: Any, items: dict[str, Any], cat: int) -> None:
    def same(column: str, value: Any) -> None:
        got = plot[column].item()
        if value is None:
            assert np.isnan(got) if isinstance(got, float) else got == -1, column
        else:
            assert got == value, (column, got, value)

    def element(item: str, name: str) -> Any:
        return items[item][name] if item in items and name in items[item] else None

    same("sac", element("010", "SAC"))
    same("sic", element("010", "SIC"))
    cat001 = cat == 1
    same("time_of_day", None if cat001 else items.get("140"))
    same("truncated_time", items.get("141") if cat001 else None)
    # CAT001 says PSR/SSR/combined in SSRPSR (CAT048 TYP 0-3) and plot/track in TYP.
    same("typ", element("020", "SSRPSR" if cat001 else "TYP"))
    same("track_report", element("020", "TYP") if cat001 else None)
    for column, name in (("sim", "SIM"), ("spi", "SPI"), ("rab", "RAB"), ("tst", "TST")):
        same(column, element("020", name))
    extended = items.get("RE", {}).get("ERR") if isinstance(items.get("RE"), dict) else None
    same("rho", extended if extended is not None else element("040", "RHO"))
    assert plot["extended_range"] == (extended is not None)
    same("theta", element("040", "THETA"))
    code = element("070", "MODE3A")
    same("mode3a", None if code is None else int(code, 8))
    same("mode3a_invalid", element("070", "V"))
    same("mode3a_garbled", element("070", "G"))
    same("mode3a_smoothed", element("070", "L"))
    same("flight_level", element("090", "HGT" if cat001 else "FL"))
    same("flight_level_invalid", element("090", "V"))
    same("flight_level_garbled", element("090", "G"))
    same("address", int(items["220"], 16) if "220" in items else None)
    same("track_number", items.get("161") if cat001 else element("161", "TRN"))
    same("height_3d", element("110", "3DH"))
    same("ground_speed", element("200", "GSP"))
    same("heading", element("200", "HDG"))
    assert plot["callsign"] == items.get("240", "")
