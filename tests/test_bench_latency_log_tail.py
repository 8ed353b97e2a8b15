"""benchmarks/bench_latency.py's log tail: a service process that dies during a run leaves
the last lines of its log to say why (a 30-minute run's log is not kept whole)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "benchmarks"))
from bench_latency import LogTail

DYING = """
import sys
print("starting", file=sys.stderr)
print("fusion: taking batches", file=sys.stderr, flush=True)
for k in range(100):
    print(f"line {k}", file=sys.stderr)
print("Traceback: the reason it died", file=sys.stderr)
sys.exit(3)
"""


def test_a_dead_process_leaves_its_last_lines() -> None:
    process = subprocess.Popen([sys.executable, "-c", DYING], stderr=subprocess.PIPE, text=True)
    assert process.stderr is not None
    tail = LogTail(process.stderr, "fusion: taking")
    assert process.wait(timeout=30) == 3
    lines = tail.text().splitlines()
    assert len(lines) == LogTail.LINES
    assert lines[-1] == "Traceback: the reason it died"
    assert lines[0] == f"line {101 - LogTail.LINES}"


def test_a_process_that_never_says_ready_is_read_to_its_end() -> None:
    process = subprocess.Popen(
        [sys.executable, "-c", "import sys; print('bad config', file=sys.stderr); sys.exit(2)"],
        stderr=subprocess.PIPE,
        text=True,
    )
    assert process.stderr is not None
    tail = LogTail(process.stderr, "fusion: taking")
    assert process.wait(timeout=30) == 2
    assert tail.text() == "bad config\n"
