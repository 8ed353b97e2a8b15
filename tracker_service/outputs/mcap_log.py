"""The service's MCAP log: raw datagrams and every message.

JSON messages with JSON schemas, as the simulator's recordings (``docs/recording-format.md``):
a channel per topic, a schema per pydantic model (``tracker_service.<Model>``), log and
publish times in POSIX nanoseconds. The Foxglove map's channels are logged into it too
(``foxglove_sink.py``).

Files rotate by size or by the span of their log times, named
``<name>_<first log time, UTC>_<sequence>.mcap``. Chunks are small and each one reaches
the operating system as soon as it is complete, so a process killed with SIGKILL leaves
a file whose complete chunks :func:`read_log_messages` reads; ``close`` writes the
summary and footer that indexed readers need.

A write that fails (a full disk: ENOSPC) is cut off the file again, so that the file ends
with whole records, and the file is closed at once with a data-end record and a footer
(no summary: readers then read it from the start, ``mcap.reader.make_reader`` included).
The room for that ending is kept aside in a small reserve file beside the logs, released
at the failure. The error is raised to the caller (the service's ``IsolatedSink``, which
reports it and retries); the next write starts a new file once the reserve can be taken
again, i.e. once the disk has room.
"""

from __future__ import annotations

import contextlib
import json
import logging
import math
import os
import struct
import sys
import time as clock
from array import array
from bisect import bisect_right
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from io import BytesIO
from itertools import accumulate, chain, repeat
from operator import sub
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from mcap._chunk_builder import ChunkBuilder
from mcap.data_stream import RecordBuilder
from mcap.exceptions import EndOfFile
from mcap.opcode import Opcode
from mcap.records import (
    Channel,
    DataEnd,
    Footer,
    Message,
    MessageIndex,
    Metadata,
    Schema,
    Statistics,
)
from mcap.stream_reader import StreamReader
from mcap.writer import MCAP0_MAGIC, Writer
from pydantic import BaseModel, ConfigDict, Field
from pydantic_core import to_json

from asterix.containers import Datagram
from tracker_service.closing import Closing
from tracker_service.mcap_format import json_schema, schema_name, start_mcap, time_ns, times_ns

__all__ = [
    "LoggedDatagram",
    "LoggedMessage",
    "McapLog",
    "datagram_topic",
    "read_log_messages",
    "read_log_metadata",
]

log = logging.getLogger(__name__)

MCAP_LIBRARY = "tracker-service log 1"
_NS_PER_S = 1_000_000_000
_MAX_SEQUENCE = 2**32


class LoggedDatagram(BaseModel):
    """One datagram as an input received it; the reception time is also the log time."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)

    input: str = Field(description="The input (radar feed) it came in on.")
    time: float = Field(ge=0.0, description="Reception time, POSIX seconds.")
    src: str | None = Field(description='Sender "ip:port"; null when unknown.')
    dst: str | None = Field(description='Destination (group or local address) "ip:port".')
    payload: str = Field(
        pattern=r"^(?:[0-9a-f]{2})*$",
        description="The UDP payload, lower-case hex, two digits per byte.",
    )


def datagram_topic(input_name: str) -> str:
    return f"/datagrams/{input_name}"


def _endpoint(endpoint: tuple[str, int] | None) -> str | None:
    return None if endpoint is None else f"{endpoint[0]}:{endpoint[1]}"


class _Spool:
    """The file under an MCAP writer: what the writer writes waits here, and reaches the
    file at ``flush``, which the log calls between the writer's calls, when the writer has
    written whole records only. A write that fails is cut off the file again, so the file
    always ends with whole records."""

    def __init__(self, fd: int) -> None:
        self.fd = fd
        self.committed = 0
        """Bytes in the file, all of them whole records."""
        self._pending = bytearray()

    def write(self, data: bytes) -> int:
        self._pending += data
        return len(data)

    def tell(self) -> int:
        return self.committed + len(self._pending)

    def flush(self) -> bool:
        """Writes what is pending; whether there was something to write. On an error the
        pending bytes are lost, the file is as before, and the error is raised."""
        if not self._pending:
            return False
        view = memoryview(self._pending)
        written = 0
        try:
            while written < len(view):
                written += os.write(self.fd, view[written:])
        except OSError:
            view.release()
            self._pending.clear()
            self.cut()
            raise
        view.release()
        self.committed += written
        self._pending.clear()
        return True

    def cut(self) -> None:
        """Back to the last whole record (what a partial write added goes)."""
        with contextlib.suppress(OSError):
            os.ftruncate(self.fd, self.committed)
            os.lseek(self.fd, self.committed, os.SEEK_SET)


def _ending() -> bytes:
    """Data end, a footer without summary, and the closing magic: a complete MCAP file
    after whole records."""
    builder = RecordBuilder()
    DataEnd(data_section_crc=0).write(builder)
    Footer(summary_start=0, summary_offset_start=0, summary_crc=0).write(builder)
    # mcap-python leaves end() unannotated.
    return bytes(builder.end()) + MCAP0_MAGIC  # type: ignore[no-untyped-call]


_ENDING_BYTES = len(_ending())


class _Reserve:
    """Room on the log's file system for closing a file when the disk is full: a file of
    ``size`` bytes, allocated beside the logs, given back at a failure and taken again
    before the next log file starts."""

    def __init__(self, path: Path, size: int) -> None:
        self.path = path
        self.size = size

    def take(self) -> None:
        """Raises OSError (ENOSPC) when the file system has not the room."""
        if self.path.exists() and self.path.stat().st_size >= self.size:
            return
        fd = os.open(self.path, os.O_WRONLY | os.O_CREAT, 0o644)
        try:
            os.posix_fallocate(fd, 0, self.size)
        except OSError:
            os.close(fd)
            self.release()
            raise
        os.close(fd)

    def release(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


@dataclass
class _File:
    path: Path
    stream: _Spool
    writer: Writer
    start_ns: int
    schemas: dict[str, int] = field(default_factory=dict)
    channels: dict[str, tuple[int, str]] = field(default_factory=dict)
    """topic -> (channel id, schema name)."""
    sequences: dict[int, int] = field(default_factory=dict)
    messages: int = 0
    unwritten: int = 0
    """Messages handed to the writer that are not in the file yet (the chunk in progress)."""
    chunk: _ChunkAccess | None = None
    """The writer's chunk in progress, reached directly (None: through ``add_message``)."""


class McapLog(Closing):
    """Writes the log into ``directory``, one file at a time.

    A file is closed and the next one started when it reaches ``rotate_size_mb`` or when
    a message's log time is ``rotate_duration_s`` past the file's first. ``chunk_size``
    bounds what a SIGKILL can lose (with the last ``flush_interval_s`` seconds of wall
    clock time, after which a partial chunk is written out anyway), and what a full disk
    can (the chunk whose write failed).

    ``reserve_bytes`` are kept aside in ``.<name>.reserve`` for closing a file on a full
    disk; ``lost`` counts the messages that a failed write took with it.
    """

    def __init__(
        self,
        directory: str | Path,
        rotate_size_mb: float = 256.0,
        rotate_duration_s: float = 3600.0,
        chunk_size: int = 64 * 1024,
        *,
        name: str = "tracker",
        flush_interval_s: float = 1.0,
        metadata: Mapping[str, Mapping[str, str]] | None = None,
        reserve_bytes: int = 64 * 1024,
    ) -> None:
        if rotate_size_mb <= 0 or rotate_duration_s <= 0 or chunk_size <= 0:
            raise ValueError("rotate_size_mb, rotate_duration_s and chunk_size must be positive")
        if reserve_bytes < _ENDING_BYTES:
            raise ValueError(f"reserve_bytes must be at least {_ENDING_BYTES}")
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)
        self.name = name
        self._reserve = _Reserve(self.directory / f".{name}.reserve", reserve_bytes)
        self.lost = 0
        """Messages lost with writes that failed (a full disk), since start."""
        self._rotate_bytes = int(rotate_size_mb * 1024 * 1024)
        self._rotate_ns = round(rotate_duration_s * _NS_PER_S)
        self._chunk_size = chunk_size
        self._flush_interval_s = flush_interval_s
        self._metadata = {k: dict(v) for k, v in (metadata or {}).items()}
        self._last_flush = clock.monotonic()
        self._file: _File | None = None
        self._closed = False
        self.files: list[Path] = []
        """Every file started, in order."""

    def log_datagram(self, datagram: Datagram, input_name: str = "udp") -> None:
        """A received datagram, on ``/datagrams/<input_name>``; its time is required."""
        time = datagram.time
        if time is None:
            raise ValueError("a logged datagram needs its reception time")
        fields = {
            "input": input_name,
            "time": time,
            "src": _endpoint(datagram.source),
            "dst": _endpoint(datagram.destination),
            "payload": datagram.payload.hex(),
        }
        if not (math.isfinite(time) and time >= 0.0):
            LoggedDatagram.model_validate(fields)  # raises, saying what is wrong
        # ``LoggedDatagram``'s JSON, by the writer its model_dump_json uses, without
        # validating the hex payload against its pattern (a few us a kB; it holds by
        # construction).
        self.log_json(datagram_topic(input_name), LoggedDatagram, to_json(fields), time)

    def log(self, topic: str, model: BaseModel, time: float) -> None:
        """A message on ``topic``, whose schema is its model's; ``time`` (POSIX seconds)
        is its log and publish time."""
        self.log_json(topic, type(model), model.model_dump_json().encode(), time)

    def log_json(self, topic: str, model_type: type[BaseModel], data: bytes, time: float) -> None:
        """As :meth:`log`, for a message already serialised (``model_dump_json``), so that
        the service serialises each message once for Zenoh and the log."""
        self._write(
            topic, schema_name(model_type), lambda: json_schema(model_type), [(data, time_ns(time))]
        )

    def log_json_many(
        self, topic: str, model_type: type[BaseModel], payloads: Sequence[bytes], time: float
    ) -> None:
        """As :meth:`log_json` for each payload, all at ``time``: the channel looked up
        once for the batch."""
        log_time = time_ns(time)
        self._write(
            topic,
            schema_name(model_type),
            lambda: json_schema(model_type),
            [(data, log_time) for data in payloads],
        )

    def log_encoded(
        self,
        topic: str,
        schema: str,
        schema_of: Callable[[], dict[str, Any]],
        data: bytes,
        time: float,
    ) -> None:
        """A message already encoded as JSON, on ``topic`` with the JSON schema named
        ``schema`` (``schema_of`` gives it the first time a file needs it): Foxglove's
        well-known schemas (``foxglove_sink.py``)."""
        self._write(topic, schema, schema_of, [(data, time_ns(time))])

    def log_encoded_many(
        self,
        topic: str,
        schema: str,
        schema_of: Callable[[], dict[str, Any]],
        messages: Sequence[tuple[bytes, float]],
    ) -> None:
        """As :meth:`log_encoded` for each (data, time), in order: the channel looked up
        once."""
        datas = [data for data, _ in messages]
        times = times_ns(np.array([time for _, time in messages], dtype=np.float64))
        self._write(topic, schema, schema_of, list(zip(datas, times, strict=True)))

    def _write(
        self,
        topic: str,
        schema: str,
        schema_of: Callable[[], dict[str, Any]],
        messages: Sequence[tuple[bytes, int]],
    ) -> None:
        """``messages``: (data, log time in ns) each, on one topic."""
        if self._closed:
            raise ValueError("the log is closed")
        if not messages:
            return
        file = self._file_for(messages[0][1])
        try:
            self._add(file, topic, schema, schema_of, messages)
        except OSError:
            self._abandon(file)
            raise

    def _add(
        self,
        file: _File,
        topic: str,
        schema: str,
        schema_of: Callable[[], dict[str, Any]],
        messages: Sequence[tuple[bytes, int]],
    ) -> None:
        known = file.channels.get(topic)
        if known is None:
            schema_id = file.schemas.get(schema)
            if schema_id is None:
                text = json.dumps(schema_of(), separators=(",", ":")).encode()
                schema_id = file.writer.register_schema(schema, "jsonschema", text)
                file.schemas[schema] = schema_id
            known = (file.writer.register_channel(topic, "json", schema_id), schema)
            file.channels[topic] = known
        channel, channel_schema = known
        if channel_schema != schema:
            raise ValueError(f"topic {topic!r} carries {channel_schema}, not {schema}")
        sequence = file.sequences.get(channel, 0)
        if file.chunk is None:
            sequence = _add_one_by_one(file, channel, messages, sequence)
        else:
            sequence = file.chunk.add_messages(file, channel, messages, sequence)
        file.sequences[channel] = sequence
        if clock.monotonic() - self._last_flush >= self._flush_interval_s:
            # mcap-python leaves flush() unannotated.
            file.writer.flush()  # type: ignore[no-untyped-call]
            self._last_flush = clock.monotonic()
            if file.stream.flush():
                file.unwritten = 0

    def _file_for(self, log_time: int) -> _File:
        file = self._file
        if file is not None and (
            file.stream.tell() >= self._rotate_bytes or log_time - file.start_ns >= self._rotate_ns
        ):
            self._finish()
            file = None
        if file is None:
            file = self._file = self._start(log_time)
        return file

    def _start(self, log_time: int) -> _File:
        started = datetime.fromtimestamp(log_time / _NS_PER_S, UTC)
        stamp = started.strftime("%Y%m%dT%H%M%S") + f"{started.microsecond // 1000:03d}Z"
        sequence = len(self.files)
        path = self.directory / f"{self.name}_{stamp}_{sequence:04d}.mcap"
        while path.exists():
            # A replay of the same data into the same directory starts at the same time.
            sequence += 1
            path = self.directory / f"{self.name}_{stamp}_{sequence:04d}.mcap"
        # Room to close the file with, before there is a file: on a disk still full, the
        # attempt leaves nothing behind.
        self._reserve.take()
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o644)
        stream = _Spool(fd)
        try:
            writer = start_mcap(stream, self._chunk_size)  # type: ignore[arg-type]
            # Each file carries the metadata, right after its header: a file alone, even
            # one cut short by a kill, says what produced it.
            for metadata_name, values in self._metadata.items():
                writer.add_metadata(metadata_name, values)
            stream.flush()
        except BaseException:
            os.close(fd)
            path.unlink()
            raise
        self.files.append(path)
        return _File(path, stream, writer, log_time, chunk=_ChunkAccess.of(writer))

    def flush(self) -> None:
        """Writes the chunk in progress out now (a quiet feed would otherwise hold it)."""
        file = self._file
        if file is not None:
            try:
                # mcap-python leaves flush() unannotated.
                file.writer.flush()  # type: ignore[no-untyped-call]
                file.stream.flush()
            except OSError:
                self._abandon(file)
                raise
            file.unwritten = 0
            self._last_flush = clock.monotonic()

    def _finish(self) -> None:
        file, self._file = self._file, None
        if file is None:
            return
        try:
            # mcap-python leaves finish() unannotated.
            file.writer.finish()  # type: ignore[no-untyped-call]
            file.stream.flush()
        except OSError:
            self._file = file
            self._abandon(file)
            raise
        os.close(file.stream.fd)

    def _abandon(self, file: _File) -> None:
        """After a failed write: the file, which ends with whole records, gets the ending
        that makes it a complete MCAP file, in the room of the reserve, and is closed; the
        next write starts a new one. A file that holds no message yet goes."""
        self._file = None
        self.lost += file.unwritten
        stream = file.stream
        stream.cut()
        self._reserve.release()
        try:
            os.write(stream.fd, _ending())
        except OSError:
            # No room even so: the file ends with whole records, which every streaming
            # reader (read_log_messages) reads up to the failure.
            stream.cut()
        os.close(stream.fd)
        if file.messages == 0:
            with contextlib.suppress(OSError):
                file.path.unlink()
                self.files.remove(file.path)

    def close(self) -> None:
        """Finishes the current file (summary, footer) and gives the reserve back; later
        calls do nothing. On a full disk the file is closed without its summary, and
        the error logged rather than raised."""
        if not self._closed:
            self._closed = True
            try:
                self._finish()
            except OSError as exc:
                # A full disk at the end: the file is closed all the same (without its
                # summary, with what reached it); nothing is left to retry.
                log.error(
                    "%s: closed without its summary (%s); %d messages lost with the last write",
                    self.files[-1] if self.files else self.directory,
                    exc.strerror or exc,
                    self.lost,
                )
            finally:
                self._reserve.release()


def _add_one_by_one(
    file: _File, channel: int, messages: Sequence[tuple[bytes, int]], sequence: int
) -> int:
    """``messages`` through mcap-python's ``Writer.add_message``, one call each; the
    sequence number after them."""
    add, stream = file.writer.add_message, file.stream
    for data, log_time in messages:
        add(
            channel_id=channel,
            log_time=log_time,
            data=data,
            publish_time=log_time,
            sequence=sequence % _MAX_SEQUENCE,
        )
        sequence += 1
        file.messages += 1
        file.unwritten += 1
        # Cheap when nothing is pending; when the writer has just completed a chunk,
        # this hands it to the operating system, where it survives the process.
        if stream.flush():
            # The writer writes a chunk out whole: nothing is left behind in it.
            file.unwritten = 0
    return sequence


_MESSAGE_HEADER = struct.Struct("<BQHIQQ")
"""A Message record's opcode and length, then its channel id, sequence, log and publish
times (the MCAP specification's layout, as ``mcap.records.Message.write`` writes it)."""
_MESSAGE_FIELDS_BYTES = _MESSAGE_HEADER.size - 9
_MESSAGE_HEADER_BYTES = _MESSAGE_HEADER.size
_MESSAGE_OPCODE = int(Opcode.MESSAGE)


class _PackedIndex(MessageIndex):
    """A chunk's message index of one channel, written as ``MessageIndex.write`` writes it
    (channel, length, then each (log time, offset), little-endian), its entries kept
    flat in an array written whole rather than two writes each."""

    def __init__(self, channel_id: int) -> None:
        super().__init__(channel_id, [])
        self.flat = array("Q")

    def extend(self, times: Iterable[int], offsets: Iterable[int]) -> None:
        self.flat.extend(chain.from_iterable(zip(times, offsets, strict=True)))

    def write(self, stream: RecordBuilder) -> None:
        stream.start_record(Opcode.MESSAGE_INDEX)
        stream.write2(self.channel_id)
        stream.write4(len(self.flat) * 8)
        flat = self.flat
        if sys.byteorder == "big":
            flat = array("Q", flat)
            flat.byteswap()
        stream.write(flat.tobytes())
        # mcap-python leaves finish_record() unannotated.
        stream.finish_record()  # type: ignore[no-untyped-call]


@dataclass(frozen=True, slots=True)
class _ChunkAccess:
    """What ``Writer.add_message`` updates for a message, reached directly: the file's
    statistics and the chunk in progress (its records, message index, times), and the
    writer's own chunk completion. A batch of messages then costs a struct pack and two
    buffer writes each instead of about twenty Python calls (mcap-python's record
    objects, its per-field packing, the record length patched by a seek), with the same
    bytes (``tests/test_outputs_mcap_chunks.py`` holds the two paths' files equal).

    The attributes are mcap-python's private ones (1.6, as ``constraints.txt`` pins);
    :meth:`of` gives None for a writer without them, whose messages then go through
    ``add_message``."""

    statistics: Statistics
    builder: ChunkBuilder
    chunk_size: int
    finish_chunk: Callable[[], None]

    @staticmethod
    def of(writer: Writer) -> _ChunkAccess | None:
        state = getattr(writer, "__dict__", {})
        statistics = state.get("_Writer__statistics")
        builder = state.get("_Writer__chunk_builder")
        chunk_size = state.get("_Writer__chunk_size")
        finish_chunk = getattr(writer, "_Writer__finalize_chunk", None)
        if (
            type(statistics) is not Statistics
            or type(builder) is not ChunkBuilder
            or not isinstance(chunk_size, int)
            or not callable(finish_chunk)
            or not isinstance(getattr(builder.record_writer, "_buffer", None), BytesIO)
        ):
            return None
        return _ChunkAccess(statistics, builder, chunk_size, finish_chunk)

    def add_messages(
        self, file: _File, channel: int, messages: Sequence[tuple[bytes, int]], sequence: int
    ) -> int:
        """As :func:`_add_one_by_one`, the same bytes; the sequence number after them."""
        statistics, builder = self.statistics, self.builder
        n = len(messages)
        times = [log_time for _, log_time in messages]
        # The file's statistics are written at its end only: a batch updates them once.
        first, last = min(times), max(times)
        if statistics.message_count == 0:
            statistics.message_start_time = first
        else:
            statistics.message_start_time = min(first, statistics.message_start_time)
        statistics.message_end_time = max(last, statistics.message_end_time)
        statistics.channel_message_counts[channel] += n
        statistics.message_count += n
        stream, chunk_size = file.stream, self.chunk_size
        datas = [data for data, _ in messages]
        sizes = [_MESSAGE_HEADER_BYTES + len(data) for data in datas]
        start = 0
        while start < n:
            # The messages up to the one that takes the chunk past its size (as
            # add_message: the chunk is complete once it holds more than its size; one at
            # least), written with one call.
            buffer = builder.record_writer._buffer
            offsets = list(accumulate(sizes[start:], initial=buffer.tell()))
            past = bisect_right(offsets, chunk_size)
            full = past < len(offsets)
            stop = start + max(past, 1) if full else n
            k = stop - start
            run = times[start:stop]
            earliest, latest = min(run), max(run)
            if builder.num_messages == 0 or earliest < builder.message_start_time:
                builder.message_start_time = earliest
            builder.message_end_time = max(latest, builder.message_end_time)
            index = builder.message_indices.get(channel)
            if index is None:
                index = builder.message_indices[channel] = _PackedIndex(channel)
            assert isinstance(index, _PackedIndex)  # the batch path's own, on its channels
            index.extend(run, offsets[:k])
            builder.num_messages += k
            records: list[bytes] = [b""] * (2 * k)
            numbers: Iterable[int] = range(sequence, sequence + k)
            if sequence + k > _MAX_SEQUENCE:
                numbers = (i % _MAX_SEQUENCE for i in numbers)
            records[0::2] = map(
                _MESSAGE_HEADER.pack,
                repeat(Opcode.MESSAGE, k),
                map(sub, sizes[start:stop], repeat(9, k)),
                repeat(channel, k),
                numbers,
                run,
                run,
            )
            records[1::2] = datas[start:stop]
            buffer.write(b"".join(records))
            sequence += k
            file.messages += k
            file.unwritten += k
            start = stop
            if full:
                self.finish_chunk()
                # The chunk out whole to the operating system, where it survives the process.
                if stream.flush():
                    file.unwritten = 0
        return sequence


class LoggedMessage(NamedTuple):
    topic: str
    time: float
    """Log time, POSIX seconds."""
    schema: str
    data: dict[str, Any]


def read_log_messages(path: str | Path) -> Iterator[LoggedMessage]:
    """Every message of a log file in file order, up to the end of its last complete
    chunk: also reads a file whose writer was killed before it could close it.

    A closed file can be read with ``mcap.reader.make_reader`` too (indexed, in time
    order); a truncated one has no footer for it to start from.
    """
    with open(path, "rb") as stream:
        schemas: dict[int, Schema] = {}
        channels: dict[int, Channel] = {}
        records = StreamReader(stream, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except (StopIteration, EndOfFile):
                # EndOfFile: the file stops inside a record, where the writer was killed.
                return
            except Exception as exc:
                # Damage (a CRC, a corrupt chunk): what came before is what can be had.
                log.warning(
                    "%s: unreadable from byte %d on (%s: %s); the messages before it are read",
                    path,
                    stream.tell(),
                    type(exc).__name__,
                    exc,
                )
                return
            if isinstance(record, Schema):
                schemas[record.id] = record
            elif isinstance(record, Channel):
                channels[record.id] = record
            elif isinstance(record, Message):
                channel = channels[record.channel_id]
                yield LoggedMessage(
                    channel.topic,
                    record.log_time / _NS_PER_S,
                    schemas[channel.schema_id].name,
                    json.loads(record.data),
                )


def read_log_metadata(path: str | Path) -> dict[str, dict[str, str]]:
    """The metadata records of a log file (name -> key/value map), read from its start, so
    that a file whose writer was killed gives them too."""
    found: dict[str, dict[str, str]] = {}
    with open(path, "rb") as stream:
        try:
            for record in StreamReader(stream, validate_crcs=True).records:
                if isinstance(record, Metadata):
                    found[record.name] = dict(record.metadata)
                elif isinstance(record, Message):
                    # McapLog writes its metadata before any message.
                    break
        except Exception:
            # Cut short or damaged: the metadata found before counts.
            pass
    return found
