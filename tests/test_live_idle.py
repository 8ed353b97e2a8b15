"""An idle daemon waits for data instead of polling its inputs: a real ``tracker-service
run`` process with its four UDP inputs configured and nothing sent, its CPU time read
from /proc. Polling every millisecond cost about 7 % of a core; waiting, well under 1 %
on a quiet machine, so the bound leaves room for a loaded CI machine."""

from __future__ import annotations

import os
import time
from pathlib import Path

from tests.fault_tools import DaemonProcess, write_config

SETTLE_S = 2.0
"""After ``running:``, the output process's start and the first status are left out."""
MEASURE_S = 5.0
MAX_CORE_SHARE = 0.05


def cpu_seconds(pid: int) -> float:
    """utime + stime of process ``pid`` (every thread), seconds."""
    fields = Path(f"/proc/{pid}/stat").read_text(encoding="ascii").rsplit(")", 1)[1].split()
    # After the command's closing parenthesis: state is field 3, utime 14, stime 15.
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def test_an_idle_daemon_stays_under_a_few_percent_of_a_core(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path, log=False)
    daemon = DaemonProcess(config, tmp_path / "health")
    try:
        time.sleep(SETTLE_S)
        pid = daemon.process.pid
        cpu, wall = cpu_seconds(pid), time.monotonic()
        time.sleep(MEASURE_S)
        share = (cpu_seconds(pid) - cpu) / (time.monotonic() - wall)
        assert daemon.process.poll() is None, daemon.log()
        assert share < MAX_CORE_SHARE, f"idle daemon at {share:.1%} of a core\n{daemon.log()}"
        # Still serving: status goes on while idle (data time follows the wall clock).
        daemon.wait_status(lambda s: s["uptime_s"] > SETTLE_S + MEASURE_S)
        assert daemon.stop() == 0, daemon.log()
    finally:
        daemon.close()
