"""The messages between the radar stage and the central stage, and their binary encoding.

A radar stage (``radar_stage.RadarStage``) turns one datagram of a radar into a
``RadarBatch``: the radar's plots as it sent them (no bias correction: the radar stage
knows nothing of fusion), the bias Jacobian of every plot and of every local-track
update, and its local-track updates. The central stage (``central_stage.CentralStage``)
applies the bias correction of the moment to them, so the result does not depend on
when a batch crosses the network: only on the order the central stage takes them in.

On Zenoh a message is one payload (docs/stage-messages.md)::

    magic  b"TSM1"                 4 bytes
    kind   u8                      MessageKind
    count  u16 little-endian       number of sections
    count x section:
        name    u8 length + UTF-8  e.g. "meta", "0/plots"
        length  u32 little-endian  bytes of the array that follows
        array   .npy format v1/v2  (numpy's own: a header with the dtype, shape and
                                   order as a Python literal, then the raw bytes);
                                   read with allow_pickle=False: no object arrays

Every array is a plain or structured numpy array, so a reader in any language with an
.npy reader takes it. Scalars travel as a one-row structured array ``meta``; ``None``
is NaN.
"""

from __future__ import annotations

import io
import itertools
import math
import re
import struct
from dataclasses import dataclass, field, fields
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.bias.reception import no_evidence
from tracker_service.inputs.udp import InputCounters
from tracker_service.loop_load import LoopTotals
from tracker_service.sources import SourceCounts
from tracker_service.time_sanity import TimeReport

__all__ = [
    "MAGIC",
    "DatagramResult",
    "MessageKind",
    "RadarBatch",
    "StageMessageError",
    "decode_message",
    "encode_message",
]

MAGIC = b"TSM1"
_HEAD = struct.Struct("<4sBH")
_LENGTH = struct.Struct("<I")
FloatArray = npt.NDArray[np.float64]


class MessageKind(IntEnum):
    DATAGRAM_RESULT = 1
    """What a radar stage made of one datagram it owns (``DatagramResult``)."""
    LIVE_TRACKS = 2
    """A radar stage's live local tracks, the answer to the central stage's query at its
    start (a ``DatagramResult`` whose batches hold local tracks and no plots)."""
    END_OF_INPUT = 3
    """A replay worker has read its whole input (``meta`` only: its last order)."""


class StageMessageError(ValueError):
    """A payload that is not a stage message (wrong magic, cut short, bad array)."""


@dataclass
class RadarBatch:
    """One radar's part of one datagram, as its radar stage made it."""

    source: str
    received: float
    """Reception time (POSIX s) of the datagram."""
    order: int
    """The datagram's position in its input (replay: the stream index; live: the
    reception time in microseconds): the central stage's merge key."""
    plots: npt.NDArray[Any]
    """Every plot of the datagram (``radar_stage.RAW_PLOT_DTYPE``), uncorrected."""
    tracked: npt.NDArray[Any]
    """The local tracker's batch (``tracking.PLOT_DTYPE``): the tracked plots, uncorrected."""
    jacobian: FloatArray
    """(n_plots, 2, 4): d(x, y)/d[range offset, gain, azimuth, time] of each plot (the
    time column, which needs a velocity, 0)."""
    monitor_xy: FloatArray
    """(n_plots, 2): the surveyed position of each field monitor or surveyed fixed
    transponder, NaN for the others."""
    local: npt.NDArray[Any]
    """The local tracker's updates (``tracking.track_update_dtype``), uncorrected."""
    local_jacobian: FloatArray
    """(n_local, 2, 4): the bias Jacobian at each update's position."""
    time: TimeReport
    effective_offset_s: float | None
    """The radar's data time minus reception after re-basing (``TimeSanity``), for the
    central stage's consensus of the radars' time."""
    incarnation: int = 0
    """Which start of its radar stage made it: a restarted stage's track numbers are new
    tracks to the central stage."""
    snapshot: bool = False
    """Live tracks with their estimates as pseudo-plots (``RadarStage.live_tracks``), not
    measurements: fused, never a bias observation."""
    clock_evidence: FloatArray = field(default_factory=no_evidence)
    """(n, 2): the radar's CAT034 messages since its last batch, [radar time, reception]
    (``bias.reception``): clock observations for the bias estimator."""


@dataclass
class DatagramResult:
    """A radar stage's answer for one datagram: its batches, and its running counts
    (the central stage's status shows them as the one-process chain's)."""

    order: int
    received: float
    batches: list[RadarBatch] = field(default_factory=list)
    decode_errors: int = 0
    """Cumulative, since the stage started."""
    sources: SourceCounts = field(default_factory=SourceCounts)
    """Cumulative source admission counts."""
    kind: MessageKind = MessageKind.DATAGRAM_RESULT
    inputs: dict[str, InputCounters] = field(default_factory=dict)
    """A radar process's input counters by input name ("25_11"), cumulative, on some
    of its watermarks: the fusion process's status shows them as the daemon's own."""
    resident_mb: float | None = None
    """A radar process's resident memory (MB), on the watermarks that carry its
    counters: the fusion process's status shows it (``memory_mb``)."""
    loop: LoopTotals | None = None
    """A radar process's loop's seconds since it started and those it was busy, on the
    same watermarks: the fusion process's status shows its busy share (``busy``)."""


_META = np.dtype(
    [
        ("order", np.int64),
        ("received", np.float64),
        ("decode_errors", np.int64),
        ("no_source", np.int64),
        ("unknown_dropped", np.int64),
        ("unknown_sources_dropped", np.int64),
        ("batches", np.int32),
    ]
)
_BATCH_META = np.dtype(
    [
        ("source", "U16"),
        ("received", np.float64),
        ("order", np.int64),
        ("incarnation", np.int64),
        ("snapshot", np.bool_),
        ("effective_offset_s", np.float64),
        ("time_base", "U16"),
        ("offset_s", np.float64),
        ("offset_reported", np.bool_),
        ("out_of_step_s", np.float64),
        ("implausible", np.int64),
        ("clock_resyncs", np.int64),
        ("last_clock_jump_s", np.float64),
        ("last_clock_jump_at", np.float64),
        ("out_of_line_plots", np.int64),
    ]
)
_BATCH_ARRAYS = ("plots", "tracked", "jacobian", "monitor_xy", "local", "local_jacobian")
_INPUT_COUNTS = tuple(f.name for f in fields(InputCounters) if f.name != "last_reception")
"""``InputCounters``' counts, in its order: every one crosses, none is listed twice."""
_INPUTS = np.dtype(
    [("name", "U32"), *((name, np.int64) for name in _INPUT_COUNTS), ("last_reception", np.float64)]
)


def _inputs_array(inputs: dict[str, InputCounters]) -> npt.NDArray[Any]:
    rows = np.zeros(len(inputs), dtype=_INPUTS)
    for row, (name, counters) in zip(rows, inputs.items(), strict=True):
        row["name"] = name
        for count in _INPUT_COUNTS:
            row[count] = getattr(counters, count)
        row["last_reception"] = _nan(counters.last_reception)
    return rows


def _inputs_dict(rows: npt.NDArray[Any]) -> dict[str, InputCounters]:
    return {
        str(row["name"]): InputCounters(
            **{count: int(row[count]) for count in _INPUT_COUNTS},
            last_reception=_none(row["last_reception"]),
        )
        for row in rows
    }


def _nan(value: float | None) -> float:
    return math.nan if value is None else float(value)


def _none(value: Any) -> float | None:
    number = float(value)
    return None if math.isnan(number) else number


_npy_written: dict[tuple[np.dtype[Any], tuple[int, ...]], bytes] = {}
"""Per dtype and shape: the .npy header numpy's writer made for it the first time."""


def _npy(array: npt.NDArray[Any]) -> list[bytes]:
    """``np.lib.format.write_array(..., allow_pickle=False)`` of ``array`` in C order, as
    parts to join: the same bytes, but numpy's header (its dtype's description and a
    Python literal, ~90 us for a structured dtype: most of a message's encoding) made
    once per dtype and shape; the body is the array's memory, as numpy writes it."""
    array = np.ascontiguousarray(array)
    key = (array.dtype, array.shape)
    header = _npy_written.get(key)
    if header is None:
        out = io.BytesIO()
        np.lib.format.write_array(out, array, allow_pickle=False)  # its checks, once
        data = out.getvalue()
        if len(_npy_written) < MAX_NPY_HEADERS:
            _npy_written[key] = data[: len(data) - array.nbytes]
        return [data]
    return [header, array.tobytes()]


_NPY_MAGIC = b"\x93NUMPY"
_NPY_HEADER_LENGTH = {1: struct.Struct("<H"), 2: struct.Struct("<I")}
_NPY_SHAPE = re.compile(rb"'shape': \(([0-9, ]*)\)")
_npy_layouts: dict[bytes, tuple[np.dtype[Any], bool]] = {}
"""Per .npy header without its shape (and the padding that follows the shape's length):
the dtype and the order, as numpy's own reader parsed them the first time."""
MAX_NPY_LAYOUTS = 256
"""Layouts remembered at most: a peer that sends ever new dtypes costs a parse each,
not memory."""
_npy_headers: dict[bytes, tuple[np.dtype[Any], bool, tuple[int, ...]]] = {}
"""Per whole .npy header (the shape in it): its layout and its shape. A batch's arrays
come in a few dozen row counts: after the first minute each header is one look-up."""
MAX_NPY_HEADERS = 4096


def read_npy(data: memoryview) -> npt.NDArray[Any]:
    """``np.lib.format.read_array(..., allow_pickle=False)`` of one section, the same
    array, but each header layout parsed once: numpy parses a header (a Python literal)
    with ``ast.literal_eval`` at every call, which was a third of the main process's CPU
    in a replay with workers. Only the shape, digits and commas, is read at each new
    header; a header seen before is looked up whole."""
    header = None
    if data[:6] == _NPY_MAGIC and data[6] in _NPY_HEADER_LENGTH:
        length = _NPY_HEADER_LENGTH[data[6]]
        start = 8 + length.size
        if len(data) >= start:
            (size,) = length.unpack_from(data, 8)
            header = bytes(data[start : start + size])
            body = data[start + size :]
    if header is None:
        return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)  # says why
    known = _npy_headers.get(header)
    if known is None:
        match = _NPY_SHAPE.search(header)
        if match is None:
            return np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)  # says why
        layout_key = (header[: match.start(1)] + header[match.end(1) :]).rstrip()
        layout = _npy_layouts.get(layout_key)
        if layout is None:
            # numpy's reader, with its checks (no object arrays), once for this layout.
            array = np.lib.format.read_array(io.BytesIO(data), allow_pickle=False)
            if len(_npy_layouts) < MAX_NPY_LAYOUTS:
                fortran = b"'fortran_order': True" in header
                _npy_layouts[layout_key] = (array.dtype, fortran)
            return array
        shape = tuple(int(n) for n in match.group(1).split(b",") if n.strip())
        known = (*layout, shape)
        if len(_npy_headers) < MAX_NPY_HEADERS:
            _npy_headers[header] = known
    dtype, fortran, shape = known
    count = math.prod(shape)
    size = count * dtype.itemsize
    if len(body) < size:
        raise ValueError(f"{len(body)} bytes for {count} items of {dtype.itemsize} bytes")
    # Writable, as numpy's; copied as bytes: a structured copy goes field by field (see
    # ``small_arrays.row_bytes``). numpy's allocation is aligned for any dtype.
    array = np.frombuffer(body, dtype=np.uint8, count=size).copy().view(dtype)
    if fortran:
        return array.reshape(shape[::-1]).transpose()
    return array.reshape(shape)


def _section(name: str, array: npt.NDArray[Any]) -> list[bytes]:
    """A section's parts, to join with the message's others."""
    label = name.encode()
    data = _npy(array)
    return [bytes([len(label)]), label, _LENGTH.pack(sum(map(len, data))), *data]


def _batch_meta(batch: RadarBatch) -> npt.NDArray[Any]:
    meta = np.zeros(1, dtype=_BATCH_META)
    t = batch.time
    meta[0] = (
        batch.source,
        batch.received,
        batch.order,
        batch.incarnation,
        batch.snapshot,
        _nan(batch.effective_offset_s),
        t.time_base,
        _nan(t.offset_s),
        t.offset_reported,
        _nan(t.out_of_step_s),
        t.implausible,
        t.clock_resyncs,
        t.last_clock_jump_s,
        t.last_clock_jump_at,
        t.out_of_line_plots,
    )
    return meta


def encode_message(result: DatagramResult) -> bytes:
    """The payload of ``result`` (see the module docstring)."""
    meta = np.zeros(1, dtype=_META)
    counts = result.sources
    meta[0] = (
        result.order,
        result.received,
        result.decode_errors,
        counts.no_source,
        counts.unknown_dropped,
        counts.unknown_sources_dropped,
        len(result.batches),
    )
    sections = [_section("meta", meta)]
    for k, batch in enumerate(result.batches):
        sections.append(_section(f"{k}/meta", _batch_meta(batch)))
        sections.extend(_section(f"{k}/{name}", getattr(batch, name)) for name in _BATCH_ARRAYS)
        sections.append(_section(f"{k}/clock_evidence", batch.clock_evidence))
    if result.inputs:
        sections.append(_section("inputs", _inputs_array(result.inputs)))
    if result.resident_mb is not None:
        sections.append(_section("memory", np.array([result.resident_mb])))
    if result.loop is not None:
        sections.append(_section("load", np.array([result.loop.elapsed_s, result.loop.busy_s])))
    head = _HEAD.pack(MAGIC, int(result.kind), len(sections))
    return b"".join([head, *itertools.chain.from_iterable(sections)])


def _sections(payload: bytes) -> tuple[MessageKind, dict[str, npt.NDArray[Any]]]:
    view = memoryview(payload)
    if len(view) < _HEAD.size:
        raise StageMessageError(f"{len(view)} bytes: shorter than a stage message header")
    magic, kind, count = _HEAD.unpack_from(view)
    if magic != MAGIC:
        raise StageMessageError(f"magic {bytes(magic)!r}, not {MAGIC!r}")
    try:
        message_kind = MessageKind(kind)
    except ValueError:
        raise StageMessageError(f"unknown message kind {kind}") from None
    pos = _HEAD.size
    arrays: dict[str, npt.NDArray[Any]] = {}
    for _ in range(count):
        if pos >= len(view):
            raise StageMessageError(f"cut short at byte {pos}")
        size = view[pos]
        name = bytes(view[pos + 1 : pos + 1 + size]).decode()
        pos += 1 + size
        if pos + _LENGTH.size > len(view):
            raise StageMessageError(f"section {name!r} cut short")
        (length,) = _LENGTH.unpack_from(view, pos)
        pos += _LENGTH.size
        if pos + length > len(view):
            raise StageMessageError(f"section {name!r}: {length} bytes announced, fewer left")
        try:
            arrays[name] = read_npy(view[pos : pos + length])
        except ValueError as exc:
            raise StageMessageError(f"section {name!r}: {exc}") from None
        pos += length
    return message_kind, arrays


def decode_message(payload: bytes) -> DatagramResult:
    """The message of ``payload``; ``StageMessageError`` when it is none."""
    kind, arrays = _sections(payload)
    try:
        meta = arrays["meta"][0]
        batches = []
        for k in range(int(meta["batches"])):
            # The row as Python values at once: a structured scalar's field costs
            # as much as a small array's.
            row = arrays[f"{k}/meta"][0]
            m = dict(zip(row.dtype.names or (), row.item(), strict=True))
            report = TimeReport(
                source=str(m["source"]),
                time_base=str(m["time_base"]),  # type: ignore[arg-type]
                offset_s=_none(m["offset_s"]),
                offset_reported=bool(m["offset_reported"]),
                out_of_step_s=_none(m["out_of_step_s"]),
                implausible=int(m["implausible"]),
                clock_resyncs=int(m["clock_resyncs"]),
                last_clock_jump_s=float(m["last_clock_jump_s"]),
                last_clock_jump_at=float(m["last_clock_jump_at"]),
                out_of_line_plots=int(m["out_of_line_plots"]),
            )
            parts = {name: arrays[f"{k}/{name}"] for name in _BATCH_ARRAYS}
            batches.append(
                RadarBatch(
                    source=str(m["source"]),
                    received=float(m["received"]),
                    order=int(m["order"]),
                    time=report,
                    effective_offset_s=_none(m["effective_offset_s"]),
                    incarnation=int(m["incarnation"]),
                    snapshot=bool(m["snapshot"]),
                    clock_evidence=arrays.get(f"{k}/clock_evidence", no_evidence()),
                    **parts,
                )
            )
        inputs = _inputs_dict(arrays["inputs"]) if "inputs" in arrays else {}
        memory = float(arrays["memory"][0]) if "memory" in arrays else None
        if memory is not None and not 0.0 <= memory < math.inf:
            # A figure no process has is dropped, not the batches beside it (the status,
            # whose model refuses it, would fail on every beat after).
            memory = None
        loop = _loop_totals(arrays["load"]) if "load" in arrays else None
    except (KeyError, IndexError, TypeError, ValueError) as exc:
        raise StageMessageError(f"incomplete message: {exc!r}") from None
    return DatagramResult(
        order=int(meta["order"]),
        received=float(meta["received"]),
        batches=batches,
        decode_errors=int(meta["decode_errors"]),
        sources=SourceCounts(
            no_source=int(meta["no_source"]),
            unknown_dropped=int(meta["unknown_dropped"]),
            unknown_sources_dropped=int(meta["unknown_sources_dropped"]),
        ),
        kind=kind,
        inputs=inputs,
        resident_mb=memory,
        loop=loop,
    )


def _loop_totals(values: npt.NDArray[Any]) -> LoopTotals | None:
    """A radar process's loop totals; None for figures no loop has (the status's model
    would refuse a share outside 0-1 on every beat after), not the message."""
    elapsed, busy = (float(v) for v in values[:2])
    if not 0.0 <= busy <= elapsed < math.inf:
        return None
    return LoopTotals(elapsed, busy)
