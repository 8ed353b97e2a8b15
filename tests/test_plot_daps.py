"""DAP columns of the plot path (asterix.daps): equal to the general BDS decoder's values,
on real records and on random MB data, by record and over arrays."""

from __future__ import annotations

import json
import random

import numpy as np
import pytest

from asterix import bds, daps
from asterix.codec import encode_block
from asterix.containers import Datagram, read_file
from asterix.plots import SMALL_BATCH, extract_plots
from tests.conftest import SHARED_DATA, shared_file

FIELD_OF_COLUMN = {column: field for field, column in daps._COLUMN_OF_FIELD.items()}


def expected_columns(registers: list[tuple[str, int]]) -> dict[str, float]:
    """What the general decoder says of one record's I250 (BDS, MB) repetitions."""
    out = {name: float("nan") for name in daps.DAP_COLUMNS}
    for code, mb in registers:
        values = bds.decode_mb(mb, int(code[0], 16), int(code[1], 16))
        for name in daps.DAP_COLUMNS:
            value = (values or {}).get(FIELD_OF_COLUMN[name])
            if value is not None:
                out[name] = float(value)  # type: ignore[arg-type]
    return out


@pytest.mark.parametrize(
    "relative",
    ["jasterix/cat048ed1.15.bin", "croatiacontrol/cat_034_048.pcap", "croatiacontrol/cat048.raw"],
)
def test_real_records_agree_with_the_bds_decoder(relative: str) -> None:
    path = shared_file(relative)
    oracle = SHARED_DATA / "oracle" / f"{path.name}.cat048.libasterix.jsonl"
    records = [json.loads(line) for line in oracle.read_text().splitlines()]
    payloads = [u.payload for u in read_file(path) if isinstance(u, Datagram)]
    plots = np.concatenate([extract_plots(p).plots for p in payloads])
    plots = plots[plots["category"] == 48]
    assert len(plots) == len(records)
    with_daps = 0
    for row, record in zip(plots, records, strict=True):
        registers = list(
            zip(
                record.get("BDS", []),
                map(lambda h: int(h, 16), record.get("MB_hex", [])),
                strict=True,
            )
        )
        want = expected_columns(registers)
        for name, value in want.items():
            assert row[name] == pytest.approx(value, nan_ok=True, abs=1e-9), name
        with_daps += any(np.isfinite(v) for v in want.values())
    assert with_daps > 0


def _record(registers: list[tuple[int, int]]) -> dict[str, object]:
    return {
        "010": {"SAC": 1, "SIC": 2},
        "140": 100.0,
        "020": {"TYP": 5, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0},
        "040": {"RHO": 50.0, "THETA": 10.0},
        "250": [{"MBDATA": f"{mb:014X}", "BDS1": c >> 4, "BDS2": c & 15} for c, mb in registers],
    }


@pytest.mark.parametrize("count", [3, SMALL_BATCH + 20])
def test_random_registers_by_record_and_by_array(count: int) -> None:
    rng = random.Random(count)
    codes = [0x40, 0x50, 0x60, 0x10, 0x00]
    records = [
        [(rng.choice(codes), rng.getrandbits(56)) for _ in range(rng.randint(0, 4))]
        for _ in range(count)
    ]
    block = encode_block(
        48,
        [_record(r) if r else {k: v for k, v in _record(r).items() if k != "250"} for r in records],
    )
    plots = extract_plots(block).plots
    for row, registers in zip(plots, records, strict=True):
        want = expected_columns([(f"{c:02X}", mb) for c, mb in registers])
        for name, value in want.items():
            assert row[name] == pytest.approx(value, nan_ok=True, abs=1e-9), name


def test_bds10_only_recording_has_no_daps() -> None:
    """068test_bds30.gps: every record's I250 is BDS 1,0 (data-link capability): no DAP."""
    path = shared_file("reader_network/068test_bds30.gps")
    payloads = [u.payload for u in read_file(path) if isinstance(u, Datagram)][:300]
    plots = extract_plots(b"".join(payloads)).plots
    assert len(plots) > 100
    for name in daps.DAP_COLUMNS:
        assert np.isnan(plots[name]).all()
