"""The plot path's walk over blocks and records (``asterix.plots._walk``, its plans in
runs of fixed-size items): a damaged block after the plots is still reported, and the
plots of a real capture are the general decoder's."""

from __future__ import annotations

import numpy as np

from asterix.codec import Block, decode_blocks
from asterix.containers import Datagram, read_file
from asterix.plots import extract_plots
from tests.conftest import shared_file


def test_a_cut_block_after_the_plots_is_reported() -> None:
    path = shared_file("croatiacontrol/cat_034_048.pcap")
    checked = 0
    for unit in read_file(path):
        if not isinstance(unit, Datagram) or unit.payload[0] != 48:
            continue
        first = int.from_bytes(unit.payload[1:3])
        if first >= len(unit.payload) - 3:
            continue  # one block only
        last = 0
        while last + int.from_bytes(unit.payload[last + 1 : last + 3]) < len(unit.payload):
            last += int.from_bytes(unit.payload[last + 1 : last + 3])
        cut = extract_plots(unit.payload[:-1])
        assert [(e.offset, e.reason) for e in cut.errors] == [(last, "block length does not fit")]
        whole = extract_plots(unit.payload)
        assert not whole.errors
        assert cut.plots.tobytes() == whole.plots[: len(cut.plots)].tobytes()
        checked += 1
    assert checked > 10


def test_the_walk_finds_the_items_the_general_decoder_finds() -> None:
    path = shared_file("croatiacontrol/cat_034_048.pcap")
    rows = 0
    for unit in read_file(path):
        if not isinstance(unit, Datagram):
            continue
        plots = extract_plots(unit.payload).plots
        records = [
            items
            for event in decode_blocks(unit.payload)
            if isinstance(event, Block) and event.cat == 48
            for items in event.records
        ]
        assert len(plots) == len(records)
        for row, items in zip(plots, records, strict=True):
            assert row["sac"] == items["010"]["SAC"] and row["sic"] == items["010"]["SIC"]
            if "040" in items:
                assert np.isclose(row["rho"], items["040"]["RHO"])
                assert np.isclose(row["theta"], items["040"]["THETA"])
            if "220" in items:
                assert row["address"] == int(str(items["220"]), 16)
            if "140" in items:
                assert row["time_of_day"] == items["140"]
        rows += len(plots)
    assert rows > 100
