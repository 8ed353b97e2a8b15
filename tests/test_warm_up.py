"""The warm-up (``tracker_service.service.warm_up``): every kernel a recording's data calls
is ready before a service listens, a warm-up that fails or is stopped costs nothing else,
and a real daemon binds its inputs, warms its core and its output process, and then takes
what arrived meanwhile."""

from __future__ import annotations

import json
import logging
import re
import subprocess
import sys
import textwrap
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import pytest

from tests.fault_tools import DaemonProcess, plot_block, send, write_config
from tracker_service.service import warm_up as warm_up_module
from tracker_service.service.config import load_service_config
from tracker_service.service.daemon import Daemon
from tracker_service.service.warm_up import warm_core, warm_up_input, warmed

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "config" / "example.toml"
DATA = REPO.parent / "shared" / "data" / "asterix"
RECORDINGS = [
    REPO / "recordings" / "three_sites.mcap",
    DATA / "reader_network" / "canalA.gps",  # CAT001, site monitors, a real clock
    DATA / "croatiacontrol" / "cat_034_048.pcap",
    DATA / "reader_network" / "068test_bds30.gps",
]
DATAGRAMS = 6000
"""Of each recording: canalA in full takes a minute."""

# In a process of its own: a pytest worker's kernels compiled by earlier tests would
# hide what the warm-up misses.
_MISSED = textwrap.dedent(
    """
    import itertools, json, sys
    from pathlib import Path
    from tracker_service.evaluation.assess import (
        DEFAULT_DAY_POSIX, _assumed_config, _capture_radars
    )
    import pickle
    from tracker_service.service.call_pickle import CallPickler
    from tracker_service.service.core import Outputs
    from tracker_service.service.replay import open_replay
    from tracker_service.service.warm_up import (
        OutputCalls, _CallRecorder, feed_core, signatures, warm_core, warm_outputs,
        warm_up_input,
    )
    from tracker_service.simulator.recording import is_mcap
    from tracker_service.fusion.state import PairEvidence
    from tracker_service.tracking.association.gate import scipy_trees_only

    paths = [Path(p) for p in sys.argv[2:]]
    configs = []
    for path in paths:
        if is_mcap(path):
            configs.append(open_replay(path).config)
        else:
            sources, periods, _ = _capture_radars(path)
            configs.append(_assumed_config(sources, periods))
    for remote in (False, True):
        warm_outputs(warm_core(warm_up_input(configs[0]), remote_radars=remote))
    before = signatures()
    missed = {}
    for path, config in zip(paths, configs):
        for remote in (False, True):  # one process; the fusion process's path
            replay = open_replay(path, config, DEFAULT_DAY_POSIX)
            datagrams = itertools.islice(replay.datagrams, int(sys.argv[1]))
            # The calls on the outputs as the output process takes them: through the
            # core's pickler, each made on Outputs after its trip.
            calls = OutputCalls(replay.config)
            feed_core(replay.config, datagrams, _CallRecorder(calls), remote)
            outputs, pickler = Outputs(replay.config), CallPickler()
            for call in calls.calls:
                method, args = pickle.loads(pickler.dumps(call))
                getattr(outputs, method)(*args)
            outputs.stop()
            after = signatures()
            for kernel, types in after.items():
                new = sorted(types - before.get(kernel, set()))
                if new:
                    missed[f"{path.name} ({'fusion' if remote else 'one'}): {kernel}"] = new
            before = after
    # The rare paths, forced: the gate's fallback to scipy's trees (two batches a
    # minute on scale, none in 6,000 datagrams here), the exchange evidence's sweep.
    replay = open_replay(paths[0], configs[0], DEFAULT_DAY_POSIX)
    with scipy_trees_only():
        datagrams = itertools.islice(replay.datagrams, int(sys.argv[1]))
        feed_core(replay.config, datagrams, _CallRecorder(OutputCalls(replay.config)))
    PairEvidence(compiled=True).sweep()
    for kernel, types in signatures().items():
        new = sorted(types - before.get(kernel, set()))
        if new:
            missed[f"{paths[0].name} (rare paths): {kernel}"] = new
    print(json.dumps(missed))
    """
)


@pytest.mark.slow
def test_no_kernel_compiles_on_the_data_of_any_recording_after_the_warm_up() -> None:
    """What the warm-up scenario reaches covers what real radars' data calls, in one
    process and in the fusion process's path (its radar batches encoded and decoded),
    and in the output process (the calls pickled as the core sends them), and on the
    paths that data takes too rarely to be met here, forced: after it, not one kernel
    meets argument types it was not compiled (or loaded) for. Before, the initiation
    kernel met a fourth layout of its columns, the picture's address table its first
    growth and the fuser its first compaction only on live data, and on ``scale`` the
    gate's fallback to scipy's trees and the exchange evidence's sweep."""
    paths = [p for p in RECORDINGS if p.exists()]  # the real ones when ../shared is there
    done = subprocess.run(
        [sys.executable, "-c", _MISSED, str(DATAGRAMS), *map(str, paths)],
        capture_output=True,
        text=True,
        timeout=600,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    missed = json.loads(done.stdout.splitlines()[-1])
    assert missed == {}, json.dumps(missed, indent=1)


def test_a_warm_up_that_fails_is_logged_and_the_service_goes_on(
    caplog: pytest.LogCaptureFixture,
) -> None:
    def broken() -> int:
        raise OSError("no space left on device")

    with caplog.at_level(logging.INFO, logger="tracker_service.service.warm_up"):
        assert warmed("core", broken) is None
    failed = [r for r in caplog.records if r.levelno == logging.ERROR]
    assert len(failed) == 1
    assert "warm-up of the core failed: its kernels compile at their first call" in (
        failed[0].getMessage()
    )
    assert "no space left on device" in caplog.text


def test_the_throwaway_stages_say_nothing_that_reads_as_the_service(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """Their summary at their end, the faults the scenario plants: kept to errors."""
    with caplog.at_level(logging.INFO):
        calls = warmed("core", lambda: warm_core(warm_up_input()))
    assert calls is not None and calls.calls
    said = {r.name for r in caplog.records}
    assert said == {"tracker_service.service.warm_up"}, caplog.text


def test_the_rest_of_the_process_logs_as_before_during_a_warm_up(
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The inputs' threads receive while the process warms up: their warnings stay; the
    warm-up's own thread is kept to errors, and to nothing after it."""
    inputs = logging.getLogger("tracker_service.inputs.udp")

    def warm() -> bool:
        inputs.warning("a stage's warning")
        inputs.error("a stage's error")
        other = threading.Thread(target=inputs.warning, args=("an input's warning",))
        other.start()
        other.join()
        return True

    with caplog.at_level(logging.INFO):
        assert warmed("core", warm)
        inputs.warning("after the warm-up")
    said = [r.getMessage() for r in caplog.records if r.name == inputs.name]
    assert said == ["a stage's error", "an input's warning", "after the warm-up"]


class _StopAfter(threading.Event):
    """A stop request that comes while the warm-up is under way: at the ``n``-th look."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.looks, self.n = 0, n

    def is_set(self) -> bool:
        self.looks += 1
        if self.looks >= self.n:
            self.set()
        return super().is_set()


@pytest.mark.parametrize("looks", [1, 500, 0])
def test_a_stop_during_the_warm_up_ends_the_daemon_before_it_opens_its_log(
    tmp_path: Path, looks: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    """At the first datagram, mid-way, or (0) after the last, as the core's outputs warm
    up: the daemon returns 0 without starting its output process or opening its log."""
    config_path, _ = write_config(tmp_path)
    config = load_service_config(config_path)
    stop = _StopAfter(looks or 10**9)
    if looks == 0:
        original = warm_up_module.warm_outputs

        def outputs_then_stop(calls: Any) -> None:
            original(calls)
            stop.set()

        monkeypatch.setattr(warm_up_module, "warm_outputs", outputs_then_stop)
    assert Daemon(config).run(stop) == 0
    assert stop.looks >= (looks or 2)
    assert not (tmp_path / "logs").exists()  # no log opened: it ended before its start


@contextmanager
def _fed_during_warm_up(
    tmp_path: Path, max_behind_s: float
) -> Iterator[tuple[DaemonProcess, float]]:
    """A daemon sent five plots of 25/11 (timed from the moment returned) while its core
    warms up, once it runs; stopped cleanly after."""
    config, ports = write_config(tmp_path, log=False, system={"max_behind_s": max_behind_s})
    daemon = DaemonProcess(config, tmp_path / "health", wait="warming up the core")
    try:
        now = time.time()
        send(ports["25/11"], [plot_block(25, 11, (now + k * 0.01) % 86400.0) for k in range(5)])
        daemon.wait_for("running: publishing")
        yield daemon, now
    finally:
        assert daemon.stop() == 0, daemon.log()
        daemon.close()


def test_a_daemon_binds_its_inputs_then_warms_up_and_keeps_what_arrived_meanwhile(
    tmp_path: Path,
) -> None:
    """A port in use must be the one line at once, so the inputs are bound first; the
    datagrams sent during the warm-up wait in their queues and are taken after it."""
    # Kept however long the warm-up takes on a loaded machine (10 s by default).
    with _fed_during_warm_up(tmp_path, 120.0) as (daemon, now):
        lines = daemon.log().splitlines()

        def first(text: str, process: str = "MainProcess") -> int:
            return next(i for i, line in enumerate(lines) if text in line and process in line)

        listening = first("listening on")
        core = first("warm-up of the core:")
        outputs = first("warm-up of the outputs:", "tracker-outputs")
        running = first("running: publishing")
        assert listening < core < outputs < running
        # On this machine's cache every kernel is there: loaded, not compiled.
        assert "kernels 0 compiled" in lines[core], lines[core]
        assert "kernels 0 compiled" in lines[outputs], lines[outputs]
        assert not [line for line in lines[:running] if "WARNING" in line or "ERROR" in line]
        radar = daemon.wait_status(
            lambda s: any(r["radar"] == "25/11" and r["last_plot_time"] for r in s["radars"])
        )
        mosnik = next(r for r in radar["radars"] if r["radar"] == "25/11")
        # The plots sent during the warm-up (their own times), none dropped.
        assert mosnik["drops"] == 0 and abs(mosnik["last_plot_time"] - (now + 0.04)) < 0.01


def test_what_waited_too_long_through_the_warm_up_is_its_drop_not_the_chains(
    tmp_path: Path,
) -> None:
    """With ``max_behind_s`` shorter than the warm-up, the datagrams sent during it are
    shed when their turn comes, counted as ``warm_up``: no "overloaded", no lag."""
    with _fed_during_warm_up(tmp_path, 0.5) as (daemon, _):
        status = daemon.wait_status(
            lambda s: any(r["drop_causes"].get("warm_up") for r in s["radars"])
        )
        mosnik = next(r for r in status["radars"] if r["radar"] == "25/11")
        assert mosnik["drop_causes"] == {"warm_up": 5}, mosnik
        assert mosnik["last_plot_time"] is None
        assert not [r for r in status["reasons"] if "overloaded" in r or "behind" in r]
        assert (status["lag_s"] or 0.0) < 0.5


def test_warm_up_false_starts_at_once(tmp_path: Path) -> None:
    config, _ = write_config(tmp_path, log=False, system={"warm_up": "false"})
    daemon = DaemonProcess(config, tmp_path / "health")
    try:
        assert "warm" not in daemon.log()
    finally:
        assert daemon.stop() == 0, daemon.log()
        daemon.close()


def test_the_warm_up_command_says_what_it_compiled_and_where_the_cache_is() -> None:
    """On this machine's cache (filled by the tests before): every kernel loaded, none
    compiled; the cache named. (An empty cache takes two minutes to fill: measured by
    hand, docs/benchmarks.md.)"""
    done = subprocess.run(
        [sys.executable, "-m", "tracker_service.cli", "warm-up", "--config", str(EXAMPLE)],
        capture_output=True,
        text=True,
        timeout=300,
        cwd=REPO,
    )
    assert done.returncode == 0, done.stderr
    counts = re.fullmatch(
        r"kernels (\d+) compiled, (\d+) from numba's cache in [\d.]+ s; numba's cache: (.+)",
        done.stdout.strip(),
    )
    assert counts is not None, done.stdout
    assert int(counts[1]) + int(counts[2]) >= 60
    assert "__pycache__" in counts[3] or "numba" in counts[3]
