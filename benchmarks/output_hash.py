"""One sha256 over every message a replay logs: the identity check of a change that must
not move the output (a speed-up, a refactoring, a process layout).

The recording is replayed with ``tracker-service replay --speed max --mcap-dir TMP`` (and
any further replay arguments, e.g. ``--workers 2``), then every message of the log's
files, in file order and in the order written, is hashed as its topic, a NUL, its data.
The log's ``service`` metadata and its file names are left out: they hold paths and the
wall clock. Prints the number of messages and the hex digest, then the count per topic
with ``--topics``.

    python benchmarks/output_hash.py recordings/three_sites.mcap
    python benchmarks/output_hash.py /tmp/scale15.mcap -- --workers 2

Run the same command on two trees (a ``git archive`` copy on ``PYTHONPATH`` for the
base, ``tracker_service.__file__`` checked) and compare the two lines.
"""

from __future__ import annotations

import argparse
import hashlib
import subprocess
import sys
import tempfile
from collections import Counter
from pathlib import Path

from mcap.reader import make_reader


def log_digest(directory: Path) -> tuple[int, str, Counter[str]]:
    """(messages, sha256 hex, messages per topic) over every MCAP file of a log directory."""
    digest = hashlib.sha256()
    topics: Counter[str] = Counter()
    count = 0
    for path in sorted(directory.rglob("*.mcap")):
        with path.open("rb") as stream:
            for _schema, channel, message in make_reader(stream).iter_messages(
                log_time_order=False
            ):
                digest.update(channel.topic.encode())
                digest.update(b"\0")
                digest.update(message.data)
                topics[channel.topic] += 1
                count += 1
    return count, digest.hexdigest(), topics


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--topics", action="store_true", help="also the count per topic")
    parser.add_argument("replay_args", nargs="*", help="after --: more replay arguments")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="output-hash-") as tmp:
        log = Path(tmp) / "log"
        command = [
            sys.executable,
            "-m",
            "tracker_service.cli",
            "replay",
            str(args.recording),
            "--speed",
            "max",
            "--mcap-dir",
            str(log),
            *args.replay_args,
        ]
        subprocess.run(command, check=True, stdout=subprocess.DEVNULL)
        count, hexdigest, topics = log_digest(log)
    print(count, hexdigest)
    if args.topics:
        for topic, n in sorted(topics.items()):
            print(f"  {topic}: {n}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
