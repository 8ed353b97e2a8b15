"""benchmarks/bench_latency.py's timeline: what tells a live run's lag apart as the chain's
work, the host's or the sender's (docs/benchmarks.md, "Session 15")."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_latency import HOST_FIELDS, Sample, attribute_lag, take_sample, timeline_rows

BURN_S = 0.5
BURNER = f"""
import sys, time
sys.stdin.readline()
start = time.process_time()
while time.process_time() - start < {BURN_S}:
    pass
print("done", flush=True)
time.sleep(60)
"""


@pytest.mark.skipif(not Path("/proc/stat").exists(), reason="Linux /proc")
def test_a_sample_sees_a_real_process_burn_its_cpu() -> None:
    worker = subprocess.Popen(
        [sys.executable, "-c", BURNER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        time.sleep(1.0)  # its start-up, before the first sample
        before = take_sample({worker.pid: "worker"})
        assert worker.stdin is not None and worker.stdout is not None
        worker.stdin.write("go\n")
        worker.stdin.flush()
        assert worker.stdout.readline().strip() == "done"
        after = take_sample({worker.pid: "worker"})
    finally:
        worker.kill()
        worker.wait()
    # Its own CPU, to the clock tick.
    assert after.cpu["worker"] - before.cpu["worker"] == pytest.approx(BURN_S, abs=0.05)
    busy = sum(after.host[k] - before.host[k] for k in ("user", "nice", "system"))
    assert busy * 0.01 >= BURN_S - 0.05
    assert after.host["steal"] >= before.host["steal"]
    assert after.rss_mb > 1.0
    assert "bench" in after.cpu
    assert 0.0 < after.probe_s < 0.5


def test_timeline_rows_are_shares_of_a_core_and_the_windows_own_sends() -> None:
    ticks = dict.fromkeys(HOST_FIELDS, 0)
    wall0 = 100.0
    # The first sample before the sending, the last after its last datagram.
    samples = [
        Sample(at=98.0, host=ticks, cpu={"fusion": 0.0}, rss_mb=1.0, probe_s=0.003),
        Sample(at=100.0, host=ticks, cpu={"fusion": 1.0, "bench": 5.0}, rss_mb=1.0, probe_s=0.003),
        Sample(
            at=102.0,
            host={**ticks, "user": 300, "system": 20, "steal": 40, "iowait": 10},
            cpu={"fusion": 2.5, "fusion+": 1.0, "bench": 5.2},
            rss_mb=1.0,
            probe_s=0.004,
        ),
        Sample(at=104.0, host=ticks, cpu={"fusion": 2.5}, rss_mb=1.0, probe_s=0.003),
    ]
    sent = np.array([0.0, 0.5, 1.9, 2.0])
    late = np.array([0.001, 0.250, 0.002, 0.0])
    lags = [(-1.0, 9.0), (1.0, 0.5), (1.5, 1.25), (2.5, 7.0)]
    latencies = np.array([[0.1, 10.0], [1.0, 30.0], [1.9, 20.0], [3.0, 99.0]])
    rows = timeline_rows(samples, wall0, (sent, late), lags, latencies)
    assert [(r["t0"], r["t1"]) for r in rows] == [(0.0, 2.0)]
    (row,) = rows
    assert row["cpu fusion"] == pytest.approx(0.75)
    assert row["cpu fusion+"] == pytest.approx(0.5)  # a child new since the sample before
    assert row["cpu bench"] == pytest.approx(0.1)
    assert row["host busy"] == pytest.approx(1.6)
    assert row["host steal"] == pytest.approx(0.2)
    assert row["host iowait"] == pytest.approx(0.05)
    assert row["probe ms"] == pytest.approx(4.0)
    assert row["datagrams"] == 3
    assert row["late max ms"] == pytest.approx(250.0)
    assert row["lag max s"] == 1.25
    assert row["latency p50 ms"] == 20.0


def test_attribute_lag_sets_the_lagging_windows_against_the_others() -> None:
    rows = [
        {"lag max s": 0.1, "cpu fusion": 0.5, "host steal": 0.0, "late max ms": 1.0},
        {"lag max s": 2.0, "cpu fusion": 0.9, "host steal": 0.4, "late max ms": 3.0},
        {"lag max s": 0.2, "cpu fusion": 0.7, "host steal": 0.0, "late max ms": 2.0},
    ]
    text = attribute_lag(rows)
    assert text.startswith("timeline: 1 of 3 windows with a lag of 1 s or more")
    assert "cpu fusion 0.9 / 0.6" in text
    assert "host steal 0.4 / 0" in text
    assert "late max ms 3 / 1.5" in text
