"""CAT001 (two UAPs, plot and track, chosen by I020 TYP) and CAT002, beyond the oracle.

The real recording (canalA.gps, checked record by record in test_conformance) holds plot
records only; the track UAP, Random Field Sequencing and the errors are checked here with
bytes written out by hand from the specification's UAP tables.
"""

from __future__ import annotations

import numpy as np
import pytest

from asterix import Block, DecodeError, EncodeError, decode_blocks, encode_block, spec
from asterix.codec import SelectedUapCodec, codec
from asterix.plots import extract_plots
from tests.conftest import shared_file

PLOT = {
    "010": {"SAC": 20, "SIC": 130},
    "020": {"TYP": 0, "SIM": 0, "SSRPSR": 3, "ANT": 0, "SPI": 0, "RAB": 0},
    "040": {"RHO": 100.5, "THETA": 90.0},
}


def _decode(block: bytes) -> list[Block | DecodeError]:
    return list(decode_blocks(block))


def test_the_category_has_two_uaps_chosen_by_i020_typ() -> None:
    category = spec.category(1)
    assert [name for name, _ in category.uaps] == ["plot", "track"]
    assert category.uap_selector == spec.UapSelector("020", ("TYP",), ((0, "plot"), (1, "track")))
    assert isinstance(codec(1), SelectedUapCodec)
    assert not isinstance(codec(48), SelectedUapCodec)


def test_a_plot_record_follows_the_plot_uap() -> None:
    # Plot UAP: FRN 1 010, 2 020, 3 040 -> FSPEC 1110 0000.
    block = encode_block(1, [PLOT])
    assert block == bytes.fromhex("01000b e0 1482 30 3240 4000".replace(" ", ""))
    (event,) = _decode(block)
    assert isinstance(event, Block) and event.records == [PLOT]


def test_a_track_record_follows_the_track_uap() -> None:
    # Track UAP: FRN 1 010, 2 020, 3 161, 4 040, 5 042, 6 200, then FRN 13 170.
    track = {
        "010": {"SAC": 20, "SIC": 130},
        "020": {"TYP": 1, "SIM": 0, "SSRPSR": 2, "ANT": 0, "SPI": 0, "RAB": 0},
        "161": 513,
        "040": {"RHO": 1.0, "THETA": 180.0},
        "042": {"X": -1.0, "Y": 0.5},
        "200": {"GSP": 0.0625, "HDG": 270.0},
        "170": {"CON": 0, "RAD": 1, "MAN": 0, "DOU": 0, "RDPC": 0, "GHO": 0},
    }
    block = encode_block(1, [track])
    fspec = "fd04"  # FRN 1-6 and FX, then FRN 13 (0x04 of the second octet)
    body = "1482 a0 0201 0080 8000 ffc0 0020 0400 c000 40"
    assert block.hex() == f"010017{fspec}{body.replace(' ', '')}"
    (event,) = _decode(block)
    assert isinstance(event, Block) and event.records == [track]


def test_a_plot_cannot_carry_a_track_item() -> None:
    with pytest.raises(EncodeError, match=r"unknown item\(s\) \['161'\]"):
        encode_block(1, [{**PLOT, "161": 5}])


def test_without_typ_the_uap_is_unknown() -> None:
    with pytest.raises(EncodeError, match="I001/020/TYP is None"):
        encode_block(1, [{"010": {"SAC": 1, "SIC": 2}}])
    # FSPEC 1000 0000: I010 only, no I020 to select the UAP.
    events = _decode(bytes.fromhex("0100068001 02"))
    assert isinstance(events[-1], DecodeError)
    assert "no I001/020, which selects the UAP" in events[-1].reason


def test_an_frn_the_selected_uap_leaves_undefined_is_an_error() -> None:
    # FRN 16 is a spare slot of the plot UAP (an item of the track UAP).
    plot = encode_block(1, [PLOT])
    fspec = bytes([0xE1, 0x01, 0x40])  # FRN 1-3, FX, FX, FRN 16
    body = fspec + plot[4:] + b"\x00"
    events = _decode(b"\x01" + (len(body) + 3).to_bytes(2) + body)
    assert isinstance(events[-1], DecodeError) and "undefined FRN 16" in events[-1].reason


def test_random_field_sequencing_round_trips() -> None:
    # Plot UAP FRN 21 is RFS: count, then (FRN, item) pairs; here I141 (FRN 7).
    record = {**PLOT, "RFS": [{"141": 2.0}]}
    block = encode_block(1, [record])
    assert block.hex().endswith("0107" + "0100")
    (event,) = _decode(block)
    assert isinstance(event, Block) and event.records == [record]
    with pytest.raises(EncodeError, match="no item of the UAP"):
        encode_block(1, [{**PLOT, "RFS": [{"161": 1}]}])


def test_cat002_sector_crossing_of_the_filter_recording() -> None:
    """The CAT002 block of 066test_filter.gps (which its oracle leaves out), by hand:
    02 000C | F4 | 08 03 | 02 | 30 | 00 78 58 | 40."""
    from asterix.containers import read_file

    found = []
    for unit in read_file(shared_file("reader_network/066test_filter.gps")):
        for event in decode_blocks(unit.payload):
            if isinstance(event, Block) and event.cat == 2:
                found += event.records
                assert encode_block(2, event.records) == unit.payload[event.offset :][:12]
    assert found == [
        {
            "010": {"SAC": 8, "SIC": 3},
            "000": 2,  # sector crossing
            "020": 48 * 360 / 256,
            "030": 0x7858 / 128,
            "050": [0x40 >> 1],
        }
    ]


def test_plot_path_reads_both_uaps_and_keeps_the_input_order() -> None:
    track = {
        "010": {"SAC": 20, "SIC": 130},
        "020": {"TYP": 1, "SIM": 0, "SSRPSR": 1, "ANT": 0, "SPI": 0, "RAB": 0},
        "161": 77,
        "040": {"RHO": 12.0, "THETA": 45.0},
        "200": {"GSP": 0.0625, "HDG": 90.0},
        "141": 511.5,
    }
    cat048 = {
        "010": {"SAC": 1, "SIC": 2},
        "140": 100.0,
        "020": {"TYP": 2, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0},
        "040": {"RHO": 10.0, "THETA": 1.0},
    }
    payload = encode_block(1, [PLOT]) + encode_block(48, [cat048]) + encode_block(1, [track])
    batch = extract_plots(payload, 1000)
    assert batch.errors == []
    plots = batch.plots
    assert plots["category"].tolist() == [1, 48, 1]
    assert plots["offset"].tolist() == sorted(plots["offset"].tolist())
    assert plots["track_report"].tolist() == [0, -1, 1]
    assert plots["typ"].tolist() == [3, 2, 1]  # SSRPSR for CAT001
    assert plots["rho"].tolist() == [100.5, 10.0, 12.0]
    assert plots["track_number"].tolist() == [-1, -1, 77]
    assert plots["ground_speed"][2] == 0.0625 and plots["heading"][2] == 90.0
    assert plots["truncated_time"][2] == 511.5 and np.isnan(plots["truncated_time"][1])
    assert np.isnan(plots["time_of_day"][[0, 2]]).all() and plots["time_of_day"][1] == 100.0


def test_plot_path_reports_a_record_whose_uap_has_no_such_item() -> None:
    body = bytes([0xE1, 0x01, 0x40]) + encode_block(1, [PLOT])[4:] + b"\x00"
    batch = extract_plots(b"\x01" + (len(body) + 3).to_bytes(2) + body)
    assert len(batch.plots) == 0
    assert [e.category for e in batch.errors] == [1]
