"""The `tracker-service decode` command, run as users run it: a subprocess."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO, shared_file

DEMO = REPO / "recordings" / "three_sites.mcap"


def _decode(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tracker_service.cli", "decode", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=False,
    )


def test_records_print_in_file_order_with_the_contract_shape() -> None:
    result = _decode(str(shared_file("croatiacontrol/cat_034_048.pcap")))
    assert result.returncode == 0 and result.stderr == ""
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == 34 + 128
    first = lines[0]
    assert set(first) == {"cat", "block", "record", "time", "items"}
    assert first["cat"] == 48 and first["block"] == 1 and first["record"] == 0
    assert abs(first["time"] - 1462433756.50891) < 1e-6
    items = first["items"]
    assert items["010"] == {"SAC": 25, "SIC": 201}
    assert items["140"] == 27354.6015625
    assert items["040"] == {"RHO": 197.68359375, "THETA": 340.13671875}
    assert items["070"]["MODE3A"] == "1000" and items["220"] == "3C660C"
    assert items["240"] == "DLH65A  " and items["250"][0]["MBDATA"] == "C0780031BC0000"
    # The redundant LAN repeats every datagram: exactly half the records are duplicates.
    duplicates = [line for line in lines if line.get("duplicate")]
    assert len(duplicates) == (34 + 128) // 2
    assert all(line["duplicate"] is True for line in duplicates)
    blocks = [line["block"] for line in lines]
    assert blocks == sorted(blocks)


def test_summary_counts_categories_sources_duplicates_and_time() -> None:
    result = _decode(str(DEMO), "--summary")
    assert result.returncode == 0
    summary = json.loads(result.stdout)
    assert set(summary["records"]) == {"021", "034", "048"}
    assert {"048 25/11", "048 25/12", "048 25/13", "021 25/50"} <= set(summary["records_by_source"])
    # Mosnik (25/11) sends on two LANs: each of its datagrams comes twice.
    assert 0 < summary["duplicate_datagrams"] < summary["datagrams"] / 2
    assert summary["errors"] == 0
    assert summary["time_of_day"]["048"][0] >= 36000.0  # the scenario starts at 10:00 UTC


def test_errors_go_to_stderr_as_json_and_do_not_change_the_exit_code(tmp_path: Path) -> None:
    good = bytes.fromhex(
        "300030fdf70219c9356d4da0c5aff1e0020005283c660c10c236d4182001c078"
        "0031bc0000400deb07b9582e410020f5"
    )
    broken = bytearray(good)
    broken[3] = 0xFF  # FSPEC claims items the block does not hold
    capture = tmp_path / "capture.hex"
    capture.write_text(f"{good.hex(' ')}\n{bytes(broken).hex(' ')}\n{good.hex(' ')}\n")
    result = _decode(str(capture))
    assert result.returncode == 0
    assert len(result.stdout.splitlines()) == 2  # the broken datagram yields no record
    errors = [json.loads(line) for line in result.stderr.splitlines()]
    assert len(errors) == 1
    assert errors[0]["error"] == "decode" and errors[0]["category"] == 48
    assert errors[0]["offset"] > 0 and errors[0]["reason"]


def test_missing_file_is_a_clear_error() -> None:
    result = _decode("no/such/file.pcap")
    assert result.returncode == 2
    assert "no such file" in result.stderr


def test_bds_option_names_the_register_fields() -> None:
    result = _decode(str(shared_file("jasterix/cat048ed1.15.bin")), "--bds")
    (record,) = [json.loads(line) for line in result.stdout.splitlines()]
    registers = [entry["BDS"]["register"] for entry in record["items"]["250"]]
    assert registers == ["6,0", "5,0", "4,0"]
    assert record["items"]["250"][1]["BDS"]["ground_speed_kt"] == 460


def test_summary_of_a_cat001_radar() -> None:
    result = _decode(str(shared_file("reader_network/canalA.gps")), "--summary")
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    assert summary["records"] == {"001": 30651, "002": 716}
    assert summary["records_by_source"] == {"001 20/130": 30651, "002 20/130": 716}
    assert summary["unsupported_blocks"] == {} and summary["errors"] == 0
    # CAT001 I141 is truncated: the radar's time span is its CAT002 I030's.
    first, last = summary["time_of_day"]["002"]
    assert 66431.0 < first < last < 69302.0
