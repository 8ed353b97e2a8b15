"""Issue 11 finding 10: health that means something, and a supervised output process.

Per radar (receiving, tracking, time sane) through the service core with real
datagrams; ``tracker-service health`` against a real daemon: ok, degraded with its
reasons, its output process SIGKILLed (restarted, reported; past the limit the daemon
exits 1 with one line), stale once the daemon is gone."""

from __future__ import annotations

import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest

from asterix.containers import Datagram
from tests.fault_tools import EXAMPLE, NO_I010, DaemonProcess, pids_alive, write_config
from tests.fault_tools import plot_block as block
from tracker_service.chain import Chain
from tracker_service.service.config import load_service_config
from tracker_service.service.core import CoreState, ServiceTimings, TrackerService
from tracker_service.service.memory import resident_mb
from tracker_service.tracking import LocalTracker, TrackerConfig

T0 = 1780300800.0
PERIODS = {"25_11": 10.0, "25_12": 8.0, "25_13": 5.0}


def core() -> TrackerService:
    return TrackerService(load_service_config(EXAMPLE), timings=ServiceTimings(status_s=1.0))


def scans(
    service: TrackerService,
    until: float,
    *,
    silent: dict[str, float] | None = None,
    clock_offset: dict[str, float] | None = None,
    start: float = T0,
) -> None:
    """One plot per antenna turn of each radar (an aircraft moving outbound) up to
    ``until`` s; a radar in ``silent`` sends nothing after that many seconds."""
    silent = silent or {}
    offsets = clock_offset or {}
    events = sorted(
        (k * period, name)
        for name, period in PERIODS.items()
        for k in range(int(until / period) + 1)
    )
    for number, (t, name) in enumerate(events):
        if t > silent.get(name, np.inf):
            continue
        sac, sic = (int(part) for part in name.split("_"))
        tod = (start + t + offsets.get(name, 0.0)) % 86400
        payload = block(sac, sic, tod, 30.0 + t * 0.05)
        service.process(name, Datagram(payload, number, start + t + 0.3, None, None))


def reasons(service: TrackerService) -> list[str]:
    return service.status().reasons


def radar_state(service: TrackerService, key: str) -> tuple[bool, bool, bool]:
    r = next(r for r in service.status().radars if r.radar == key)
    return r.receiving, r.tracking, r.time_sane


def test_a_silent_radar_makes_health_degraded_with_its_reason() -> None:
    service = core()
    scans(service, 100.0, silent={"25_12": 50.0})
    assert radar_state(service, "25/12") == (False, True, True)
    assert any(r.startswith("radar 25/12: silent for 52 s") for r in reasons(service))
    assert radar_state(service, "25/11") == (True, True, True)
    # The ADS-B feed of the configuration never sent anything either.
    assert "radar 25/50: nothing received in 100 s" in reasons(service)
    assert service.status().health == "degraded"


def test_a_clean_feed_is_ok() -> None:
    service = core()
    config = service.config.model_copy(update={"adsb": []})
    service = TrackerService(config, timings=ServiceTimings(status_s=1.0))
    scans(service, 60.0)
    assert reasons(service) == []
    assert service.status().health == "ok"


class DeadTracker(LocalTracker):
    """A local tracker that has stopped (a fault injected): it takes plots, updates
    nothing."""

    def process(self, plots: Any) -> npt.NDArray[Any]:
        return super().process(plots[:0])


def test_plots_that_update_no_track_make_tracking_false() -> None:
    service = core()
    chain = service.chain

    def make(source: str, config: TrackerConfig) -> LocalTracker:
        return DeadTracker(config) if source == "25/13" else LocalTracker(config)

    service.chain = Chain(chain.infos, chain.plane, {}, make_tracker=make, fusion=None, bias=None)
    scans(service, 60.0)
    assert radar_state(service, "25/13") == (True, False, True)
    assert radar_state(service, "25/11") == (True, True, True)
    assert any("radar 25/13: plots arrive but no local track" in r for r in reasons(service))


def test_a_radar_clock_ahead_or_behind_is_not_sane() -> None:
    service = core()
    scans(service, 60.0, clock_offset={"25_11": 7200.0, "25_13": -60.0})
    assert radar_state(service, "25/11")[2] is False
    assert radar_state(service, "25/13")[2] is False
    assert radar_state(service, "25/12")[2] is True
    lines = reasons(service)
    assert any(r.startswith("radar 25/11: plot times 7199.7 s after") for r in lines), lines
    assert any(r.startswith("radar 25/13: plots received 60.3 s after") for r in lines), lines


def test_a_lagging_chain_is_degraded() -> None:
    service = core()
    scans(service, 20.0)
    service.local.set_core_state(CoreState(lag_s=12.5))
    assert "the chain is 12.5 s behind the wall clock" in reasons(service)


def health(file: Path, max_age: float = 30.0) -> tuple[int, str]:
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "tracker_service.cli",
            "health",
            "--file",
            str(file),
            "--max-age",
            str(max_age),
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    return done.returncode, done.stdout + done.stderr


@pytest.mark.slow
def test_health_exit_codes_and_a_supervised_output_process(tmp_path: Path) -> None:
    # 2 s antenna periods: the statuses at 0 and 5 s are "ok" (a radar is silent after
    # 6 s), time enough for `health` to start on a loaded machine.
    config, _ = write_config(tmp_path, log=False, periods_s=2.0, system={"max_output_restarts": 1})
    daemon = DaemonProcess(config, tmp_path / "health")
    try:
        # Its first status comes at once: nothing expected yet.
        code, text = health(daemon.health)
        assert code == 0, text
        # Nothing arrives for three antenna periods (ADS-B: 10 s): degraded, each named.
        daemon.wait_status(lambda s: len(s["reasons"]) == 4)
        code, text = health(daemon.health)
        assert code == 2, text
        assert "radar 25/11: nothing received in" in text

        # Its processes' memory, as the host sees it.
        first = daemon.output_process()
        memory = daemon.status()["memory_mb"]
        assert set(memory) == {"core", "outputs"}
        assert memory["core"] == pytest.approx(resident_mb(daemon.process.pid), rel=0.2)
        assert memory["outputs"] == pytest.approx(resident_mb(first), rel=0.2)
        # How busy its loops were since the last status: the core and the output process
        # wait for data nearly all the time here.
        busy = daemon.wait_status(lambda s: set(s["busy"]) == {"core", "outputs"})["busy"]
        assert all(0.0 <= share < 0.5 for share in busy.values()), busy

        # The output process killed: the core restarts it and says so.
        subprocess.run(["kill", "-KILL", str(first)], check=True)
        status = daemon.wait_status(
            lambda s: any(o["name"] == "output_process" for o in s["outputs"])
        )
        supervised = next(o for o in status["outputs"] if o["name"] == "output_process")
        assert supervised["restarts"] == 1 and supervised["last_error"] == "exit code -9"
        code, text = health(daemon.health)
        assert code == 2 and "output process restarted (exit code -9)" in text, text
        assert daemon.process.poll() is None
        second = daemon.output_process()
        assert second != first and not pids_alive([first])

        # Killed once more than max_output_restarts: the daemon gives up, one line, 1.
        subprocess.run(["kill", "-KILL", str(second)], check=True)
        assert daemon.process.wait(timeout=30.0) == 1, daemon.log()
        daemon.close()
        errors = [line for line in daemon.lines if line.startswith("tracker-service run:")]
        assert len(errors) == 1 and "giving up" in errors[0], daemon.log()
        assert "Traceback" not in daemon.log()
        # Gone: the health file goes stale.
        time.sleep(1.5)
        code, text = health(daemon.health, max_age=1.0)
        assert code == 1 and "is the daemon running?" in text, text
    finally:
        if daemon.process.poll() is None:
            daemon.process.send_signal(signal.SIGKILL)
        daemon.close()


def test_reason_lines_of_the_checks_with_the_chain_reach_the_status() -> None:
    """``TrackerService.core_reasons``: where checks that run with the chain (time
    sanity, test targets) say why a radar is degraded."""

    class Checked(TrackerService):
        def core_reasons(self) -> tuple[str, ...]:
            return ("radar 25/11: a check with the chain failed",)

    config = load_service_config(EXAMPLE)
    service = Checked(config.model_copy(update={"adsb": []}), timings=ServiceTimings(status_s=1.0))
    scans(service, 30.0)
    assert reasons(service) == ["radar 25/11: a check with the chain failed"]
    assert service.status().health == "degraded"


def test_datagrams_before_the_first_plots_are_no_tracker_stall() -> None:
    """Tracks need a few scans to form from the first tracked plots, whatever arrived on
    the input before (hostile datagrams, service messages)."""
    config = load_service_config(EXAMPLE)
    service = TrackerService(
        config.model_copy(update={"adsb": []}), timings=ServiceTimings(status_s=1.0)
    )
    for k in range(60):
        service.process("25_11", Datagram(NO_I010, k, T0 + k, None, None))
    scans(service, 5.0, start=T0 + 60.0)
    assert reasons(service) == []
