"""The MCAP log's batch path (``_ChunkAccess``) writes the bytes mcap-python's own
``Writer.add_message`` writes, message by message: the same files, chunk for chunk."""

from __future__ import annotations

import random
from pathlib import Path

import pytest
from mcap.reader import make_reader

from tracker_service.outputs import mcap_log
from tracker_service.outputs.mcap_log import McapLog, _ChunkAccess
from tracker_service.outputs.messages import LocalTrackMessage, SystemTrackMessage

T0 = 1_700_000_000.25


def _write(directory: Path, seed: int) -> list[Path]:
    """A seeded mix of batches on three channels, with messages of 1 B to 3 kB, chunks of
    4 kB (so that batches straddle chunk ends) and files rotated by size."""
    rng = random.Random(seed)
    log = McapLog(directory, rotate_size_mb=0.05, chunk_size=4096, flush_interval_s=1e9)
    with log:
        for batch in range(120):
            now = T0 + batch * 0.37
            payloads = [
                bytes(rng.randrange(256) for _ in range(rng.choice((1, 40, 300, 3000))))
                for _ in range(rng.randrange(0, 25))
            ]
            topic = rng.choice(("/system_tracks", "/local_tracks/1_1", "/local_tracks/1_2"))
            model = SystemTrackMessage if topic == "/system_tracks" else LocalTrackMessage
            log.log_json_many(topic, model, payloads, now)
            if rng.random() < 0.3:
                # A second schema, with a log time before the batch's.
                fix = b'{"latitude":48.0}'
                log.log_encoded("/foxglove/tracks", "foxglove.LocationFix", dict, fix, now - 0.5)
    return log.files


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_batch_path_writes_add_messages_bytes(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, seed: int
) -> None:
    fast = _write(tmp_path / "fast", seed)
    # The reference: every message through Writer.add_message.
    monkeypatch.setattr(mcap_log._ChunkAccess, "of", staticmethod(lambda writer: None))
    plain = _write(tmp_path / "plain", seed)
    assert len(fast) == len(plain) > 1
    for a, b in zip(fast, plain, strict=True):
        assert a.read_bytes() == b.read_bytes()
    with fast[0].open("rb") as stream:
        reader = make_reader(stream)
        summary = reader.get_summary()
        assert summary is not None and summary.statistics is not None
        assert summary.statistics.message_count == sum(1 for _ in reader.iter_messages())
        assert len(summary.chunk_indexes) > 1


def test_access_needs_mcap_pythons_writer_state(tmp_path: Path) -> None:
    """The writer of the pinned mcap release gives its state; any other object none."""
    with McapLog(tmp_path) as log:
        log.log_json_many("/system_tracks", SystemTrackMessage, [b"{}"], T0)
        file = log._file
        assert file is not None
        assert _ChunkAccess.of(file.writer) is not None
    assert _ChunkAccess.of(object()) is None  # type: ignore[arg-type]
