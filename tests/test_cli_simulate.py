"""`tracker-service simulate`, run as users run it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

THREE_SITES = REPO / "config" / "scenarios" / "three_sites.toml"


def _run(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "tracker_service.cli", *args],
        capture_output=True,
        text=True,
        cwd=REPO,
        check=False,
    )


def test_same_seed_same_bytes_and_the_capture_decodes_cleanly(tmp_path: Path) -> None:
    first, second = tmp_path / "a.pcap", tmp_path / "b.pcap"
    for out in (first, second):
        result = _run("simulate", str(THREE_SITES), "-o", str(out), "--duration", "40")
        assert result.returncode == 0, result.stderr
    assert first.read_bytes() == second.read_bytes()
    other = tmp_path / "c.pcap"
    assert (
        _run(
            "simulate", str(THREE_SITES), "-o", str(other), "--duration", "40", "--seed", "5"
        ).returncode
        == 0
    )
    assert other.read_bytes() != first.read_bytes()
    summary = json.loads(_run("decode", str(first), "--summary").stdout)
    assert summary["errors"] == 0
    assert {"048 25/11", "048 25/12", "048 25/13", "034 25/11", "021 25/50"} <= set(
        summary["records_by_source"]
    )


def test_a_wrong_scenario_names_the_field_and_what_is_allowed(tmp_path: Path) -> None:
    text = THREE_SITES.read_text().replace("antenna_period_s = 8.0", "antenna_period_s = -8.0")
    bad = tmp_path / "bad.toml"
    bad.write_text(text.replace("sigma_range_m = 40.0", "sigma_range_m = 40.0\ncolour = 1"))
    result = _run("simulate", str(bad), "-o", str(tmp_path / "x.mcap"))
    assert result.returncode == 2
    assert "radars.1.antenna_period_s = -8.0: Input should be greater than 0.5" in result.stderr
    assert "radars.0.colour = 1: Extra inputs are not permitted" in result.stderr
    assert not (tmp_path / "x.mcap").exists()


def test_an_unknown_output_suffix_is_refused(tmp_path: Path) -> None:
    result = _run("simulate", str(THREE_SITES), "-o", str(tmp_path / "x.txt"), "--duration", "5")
    assert result.returncode == 2
    assert ".mcap" in result.stderr and ".pcap" in result.stderr
