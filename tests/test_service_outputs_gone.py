"""Outputs gone for good stop the service; they are no datagram's fault.

The core counts and skips a datagram (or a radar batch) whose processing raises, and goes
on: one bad input loses nothing else. An output process that died once too often is not
such a case: its ``OutputProcessFailed`` must reach the replay or the daemon, which stop
with one line, instead of being logged with a traceback as a datagram that "could not be
processed" (a killed output process in a replay showed both, depending on which call
found it dead first). A real output process, killed with SIGKILL."""

from __future__ import annotations

import logging
import multiprocessing
import os
import signal

import pytest

from tests.fault_tools import EXAMPLE, plot_block
from tracker_service.service.command import OutputProcess, OutputProcessFailed
from tracker_service.service.config import load_service_config
from tracker_service.service.core import TrackerService, build_radar_stage

T0 = 1780300800.0  # 2026-06-01T08:00:00Z


def test_a_dead_output_process_stops_a_radar_batch_instead_of_skipping_it(
    caplog: pytest.LogCaptureFixture,
) -> None:
    config = load_service_config(EXAMPLE)
    stage = build_radar_stage(config)  # the fusion role's input: radar batches
    with OutputProcess(config, None, zenoh=False, supervised=False) as outputs:
        core = TrackerService(config, outputs=outputs)
        first = stage.feed(plot_block(25, 12, T0 % 86400), T0, 0)
        core.process_batch(first[0])
        (process,) = [p for p in multiprocessing.active_children() if p.name == "tracker-outputs"]
        assert process.pid is not None
        os.kill(process.pid, signal.SIGKILL)
        process.join(timeout=10)
        second = stage.feed(plot_block(25, 12, (T0 + 1) % 86400), T0 + 1, 1)
        with caplog.at_level(logging.WARNING), pytest.raises(OutputProcessFailed):
            core.process_batch(second[0])
    assert "could not be processed" not in caplog.text
