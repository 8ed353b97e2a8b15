"""``tracker-service health --container``: what a container engine reads (0 healthy, 1
unhealthy), from the daemon's own status written into a real file; and the image's
health command as the Dockerfile gives it."""

from __future__ import annotations

import json
import os
import re
import shlex
import time
from pathlib import Path

import pytest

from tracker_service.cli import main
from tracker_service.outputs.messages import RadarStatus, StatusMessage

REPO = Path(__file__).resolve().parents[1]
NOW = 1_780_000_000.0


def radar(key: str, last: float | None, receiving: bool) -> RadarStatus:
    return RadarStatus(
        radar=key,
        plots_per_second=0.0,
        decode_errors=0,
        duplicates=0,
        drops=0,
        last_reception_time=last,
        receiving=receiving,
    )


def write(
    path: Path, radars: list[RadarStatus], lag: float | None = None, uptime: float = 600.0
) -> None:
    reasons = [f"radar {r.radar}: silent" for r in radars if not r.receiving]
    status = StatusMessage(
        time=NOW,
        uptime_s=uptime,
        health="degraded" if reasons or (lag or 0) > 5 else "ok",
        reasons=reasons,
        radars=radars,
        lag_s=lag,
    )
    path.write_text(status.model_dump_json(), encoding="utf-8")


def check(path: Path, *extra: str) -> int:
    return main(["health", "--file", str(path), "--container", *extra])


def test_every_radar_silent_for_long_is_unhealthy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    health = tmp_path / "health"
    write(health, [radar("25/11", NOW - 120, False), radar("25/12", NOW - 90, False)])
    assert check(health) == 1
    assert "every radar silent for 90 s" in capsys.readouterr().err
    # ... but not for as long as the check allows.
    assert check(health, "--silent-for", "100") == 0


def test_one_radar_silent_is_degraded_but_healthy(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    health = tmp_path / "health"
    write(health, [radar("25/11", NOW - 120, False), radar("25/12", NOW - 1, True)])
    assert check(health) == 0
    out = capsys.readouterr().out
    assert "healthy but degraded" in out and "radar 25/11: silent" in out
    # The plain check still says degraded (exit 2): for an operator, not a container.
    assert main(["health", "--file", str(health)]) == 2


def test_nothing_received_since_start(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    health = tmp_path / "health"
    write(health, [radar("25/11", None, False)], uptime=20.0)
    assert check(health) == 0  # starting: the feeds may take a while
    write(health, [radar("25/11", None, False)], uptime=75.0)
    assert check(health) == 1
    assert "silent since start" in capsys.readouterr().err


def test_a_chain_behind_is_unhealthy(tmp_path: Path) -> None:
    health = tmp_path / "health"
    write(health, [radar("25/11", NOW - 1, True)], lag=45.0)
    assert check(health) == 1
    assert check(health, "--behind", "60") == 0


def test_a_stale_status_is_unhealthy(tmp_path: Path) -> None:
    health = tmp_path / "health"
    write(health, [radar("25/11", NOW - 1, True)])
    old = time.time() - 120
    os.utime(health, (old, old))
    assert check(health, "--max-age", "30") == 1
    (tmp_path / "garbage").write_text("{", encoding="utf-8")
    assert check(tmp_path / "garbage") == 1
    assert check(tmp_path / "missing") == 1


def test_the_dockerfile_health_command_runs(tmp_path: Path) -> None:
    """The HEALTHCHECK's command line, as the image runs it, against a real file."""
    text = (REPO / "Dockerfile").read_text(encoding="utf-8")
    found = re.search(
        r"HEALTHCHECK[^\n]*\\\n\s*CMD (\[.*?\])\n", text.replace("\\\n         ", ""), re.S
    )
    assert found, "no HEALTHCHECK ... CMD [...] in the Dockerfile"
    argv = json.loads(found.group(1))
    assert argv[:2] == ["tracker-service", "health"] and "--container" in argv
    health = tmp_path / "health"
    write(health, [radar("25/11", NOW - 1, True)])
    file_at = argv.index("--file") + 1
    # The image's path, here a temporary one.
    argv[file_at] = str(health)
    assert main(argv[1:]) == 0, shlex.join(argv)
    write(health, [radar("25/11", NOW - 300, False)])
    assert main(argv[1:]) == 1
    # The health file the check reads is the one the daemon is told to write.
    cmd = re.search(r"^CMD (\[.*?\])$", text.replace("\\\n     ", ""), re.M | re.S)
    assert cmd and "/tmp/tracker-health" in cmd.group(1)
