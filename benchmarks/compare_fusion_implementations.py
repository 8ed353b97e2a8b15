"""The service's whole output with the compiled fuser against the numpy one: a recording
replayed through ``TrackerService`` (as ``tracker-service replay --speed max --mcap-dir``
runs it, no Zenoh) once per ``[fusion] implementation``, the two MCAP logs read back
message by message and compared: the same messages on the same topics in the same order,
every value other than a float equal, and the largest difference of the floats relative
to max(1, |value|).

    python benchmarks/compare_fusion_implementations.py recordings/three_sites.mcap
"""

from __future__ import annotations

import argparse
import contextlib
import math
import sys
import tempfile
from pathlib import Path
from typing import Any

from tracker_service.outputs.mcap_log import LoggedMessage, McapLog, read_log_messages
from tracker_service.service.core import TrackerService
from tracker_service.service.replay import open_replay


def replay(path: str, implementation: str, directory: Path) -> list[LoggedMessage]:
    """Every message the service logs for the recording, in file order."""
    source = open_replay(path)
    fusion = {**source.config.fusion, "implementation": implementation}
    config = source.config.model_copy(update={"fusion": fusion})
    with contextlib.closing(McapLog(directory)) as log:
        service = TrackerService(config, None, log)
        service.set_input_counters(source.counters)
        for name, datagram in source.datagrams:
            service.process(name, datagram)
        service.close()
        service.local.drain()
    return [m for f in sorted(directory.glob("*.mcap")) for m in read_log_messages(f)]


def differences(a: Any, b: Any, where: str, out: list[str]) -> float:
    """The largest relative float difference between a and b; other differences to out."""
    if isinstance(a, float) and isinstance(b, float):
        if math.isnan(a) and math.isnan(b):
            return 0.0
        return abs(a - b) / max(1.0, abs(a))
    if isinstance(a, dict) and isinstance(b, dict):
        if list(a) != list(b):
            out.append(f"{where}: keys {list(a)} != {list(b)}")
            return 0.0
        return max((differences(a[k], b[k], f"{where}.{k}", out) for k in a), default=0.0)
    if isinstance(a, list) and isinstance(b, list) and len(a) == len(b):
        return max(
            (
                differences(x, y, f"{where}[{i}]", out)
                for i, (x, y) in enumerate(zip(a, b, strict=True))
            ),
            default=0.0,
        )
    if a != b:
        out.append(f"{where}: {a!r} != {b!r}")
    return 0.0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    args = parser.parse_args()
    logs = {}
    for implementation in ("numpy", "compiled"):
        with tempfile.TemporaryDirectory(prefix="compare_fusion") as directory:
            logs[implementation] = replay(args.recording, implementation, Path(directory))
    reference, compiled = logs["numpy"], logs["compiled"]
    print(f"messages: numpy {len(reference)}, compiled {len(compiled)}")
    problems: list[str] = []
    worst: dict[str, float] = {}
    for i, (a, b) in enumerate(zip(reference, compiled, strict=False)):
        if (a.topic, a.schema, a.time) != (b.topic, b.schema, b.time):
            problems.append(f"message {i}: {a.topic} at {a.time} != {b.topic} at {b.time}")
            continue
        topic = a.topic.strip("/").split("/")[0]
        worst[topic] = max(worst.get(topic, 0.0), differences(a.data, b.data, a.topic, problems))
    for topic, value in sorted(worst.items()):
        print(f"{topic:24s} largest float difference (relative to max(1, |x|)): {value:.2e}")
    print(f"other differences: {len(problems)}")
    for line in problems[:20]:
        print("  " + line)
    sys.exit(1 if problems or len(reference) != len(compiled) else 0)


if __name__ == "__main__":
    main()
