"""The radar stage's batches: what they hold, their binary encoding, and the central
stage's correction of them (tracker_service.stage_messages, radar_stage, central_stage)."""

from __future__ import annotations

import io
import math
import struct
from pathlib import Path

import numpy as np
import pytest

from tracker_service.central_stage import corrected
from tracker_service.chain import Chain, RadarStage
from tracker_service.geodesy import convert_plots
from tracker_service.inputs.udp import InputCounters
from tracker_service.loop_load import LoopTotals
from tracker_service.service.core import build_chain, build_radar_stage, config_from_recording
from tracker_service.simulator.recording import read_recording
from tracker_service.stage_messages import (
    _HEAD,
    MAGIC,
    DatagramResult,
    MessageKind,
    StageMessageError,
    _npy,
    _section,
    decode_message,
    encode_message,
    read_npy,
)

RECORDING = Path(__file__).resolve().parents[1] / "recordings" / "three_sites.mcap"


@pytest.fixture(scope="module")
def results() -> tuple[Chain, list[DatagramResult]]:
    """The first 400 datagrams of three_sites through a chain's radar stage."""
    recording = read_recording(RECORDING)
    chain = build_chain(config_from_recording(recording.metadata))
    stage = chain.radar_stage
    assert isinstance(stage, RadarStage)
    out = []
    for order, datagram in enumerate(recording.datagrams()):
        if order == 400:
            break
        batches = stage.feed(datagram.payload, datagram.time, order)
        out.append(
            DatagramResult(
                order, datagram.time, batches, stage.stats.decode_errors, stage.admission.counts
            )
        )
    return chain, out


def test_every_batch_survives_its_encoding_bit_for_bit(
    results: tuple[Chain, list[DatagramResult]],
) -> None:
    _, found = results
    batches = [b for r in found for b in r.batches]
    assert sum(len(b.local) for b in batches) > 100
    assert sum(len(b.clock_evidence) for b in batches) > 20  # CAT034 stamps, reception
    for result in found:
        payload = encode_message(result)
        assert payload[:4] == MAGIC
        back = decode_message(payload)
        assert (back.order, back.received, back.kind) == (
            result.order,
            result.received,
            result.kind,
        )
        assert back.sources == result.sources and back.decode_errors == result.decode_errors
        for mine, theirs in zip(result.batches, back.batches, strict=True):
            assert theirs.source == mine.source and theirs.time == mine.time
            assert theirs.effective_offset_s == mine.effective_offset_s
            names = ("plots", "tracked", "jacobian", "monitor_xy", "local", "local_jacobian")
            for name in (*names, "clock_evidence"):
                a, b = getattr(mine, name), getattr(theirs, name)
                assert a.dtype == b.dtype and a.shape == b.shape
                assert a.tobytes() == b.tobytes(), name


def test_each_section_is_a_plain_npy_array_readable_without_pickle(
    results: tuple[Chain, list[DatagramResult]],
) -> None:
    _, found = results
    result = next(r for r in found if r.batches)
    payload = encode_message(result)
    magic, kind, count = struct.unpack_from("<4sBH", payload)
    assert (magic, kind) == (MAGIC, MessageKind.DATAGRAM_RESULT)
    pos, names = 7, []
    for _ in range(count):
        size = payload[pos]
        names.append(payload[pos + 1 : pos + 1 + size].decode())
        pos += 1 + size
        (length,) = struct.unpack_from("<I", payload, pos)
        pos += 4
        array = np.load(io.BytesIO(payload[pos : pos + length]), allow_pickle=False)
        assert array.dtype.hasobject is False
        pos += length
    assert pos == len(payload)
    assert names[:3] == ["meta", "0/meta", "0/plots"]


@pytest.mark.parametrize(
    ("damage", "reason"),
    [
        (lambda p: p[:5], "shorter than"),
        (lambda p: b"JSON" + p[4:], "magic"),
        (lambda p: p[:4] + b"\x09" + p[5:], "unknown message kind"),
        (lambda p: p[: len(p) // 2], "cut short|announced"),
    ],
)
def test_a_damaged_payload_is_an_error_that_says_what(
    results: tuple[Chain, list[DatagramResult]], damage: object, reason: str
) -> None:
    _, found = results
    payload = encode_message(next(r for r in found if r.batches))
    with pytest.raises(StageMessageError, match=reason):
        decode_message(damage(payload))  # type: ignore[operator]


def test_the_radar_stage_sends_plots_as_received_and_the_centre_corrects_them(
    results: tuple[Chain, list[DatagramResult]],
) -> None:
    """First-order correction through the Jacobian against an exact conversion of the
    corrected range and azimuth: within a metre or two for a large bias (150 m, 0.15 deg:
    the second order, rho dtheta^2 / 2, is 0.7 m at 200 km), against plot errors of
    tens of metres."""
    chain, found = results
    stage = chain.radar_stage
    assert isinstance(stage, RadarStage)
    batch = next(b for r in found for b in r.batches if len(b.tracked) > 5)
    state = stage.radars[batch.source]
    bias = np.array([150.0, 2e-4, np.radians(0.15), 0.1])
    plots = batch.plots
    tracked = plots["use"] == 0
    fixed = corrected(batch.tracked, batch.jacobian[tracked], bias)

    rho = (plots["rho_m"][tracked] - bias[0]) / (1 + bias[1])
    theta = plots["theta_deg"][tracked] - np.degrees(bias[2])
    n = int(tracked.sum())
    height = np.full(n, 9000.0)
    exact = convert_plots(
        state.info.site,
        state.plane,
        rho,
        theta,
        height,
        np.full(n, 100.0),
        np.full(n, 50.0),
        np.full(n, 0.07),
    )
    raw = convert_plots(
        state.info.site,
        state.plane,
        plots["rho_m"][tracked],
        plots["theta_deg"][tracked],
        height,
        np.full(n, 100.0),
        np.full(n, 50.0),
        np.full(n, 0.07),
    )
    # The batch's own heights differ from 9000 m: compare the shifts, not the positions.
    shift = np.column_stack([fixed["x"] - batch.tracked["x"], fixed["y"] - batch.tracked["y"]])
    exact_shift = np.column_stack([exact.x - raw.x, exact.y - raw.y])
    assert np.abs(shift).max() > 100.0
    assert np.abs(shift - exact_shift).max() < 2.0
    assert np.abs(shift - exact_shift).max() < 0.005 * np.abs(exact_shift).max()
    assert np.allclose(fixed["time"], batch.tracked["time"] - bias[3])


def test_a_restarted_radar_stage_replaces_its_predecessors_tracks_in_the_fuser() -> None:
    """A new incarnation's local tracks are new tracks, numbered after the old ones, and
    the old ones are deleted in the fuser (else the new ones found duplicates)."""
    recording = read_recording(RECORDING)
    config = config_from_recording(recording.metadata)
    chain = build_chain(config)
    datagrams = list(recording.datagrams())
    for datagram in datagrams[:900]:
        chain.feed(datagram.payload, datagram.time)
    fuser = chain.fuser
    assert fuser is not None
    radar = chain.sources.index("25/13")

    def live() -> set[int]:
        loc = fuser.state.local.used
        return set(loc["number"][loc["alive"] & (loc["radar"] == radar)].tolist())

    before = live()
    assert len(before) > 10
    chain.radar_stage = build_radar_stage(config, incarnation=1)
    for datagram in datagrams[900:1100]:
        chain.feed(datagram.payload, datagram.time)
    after = live()
    assert after and min(after) > max(before)


def _npy_bytes(array: np.ndarray, allow_pickle: bool = False) -> memoryview:
    out = io.BytesIO()
    np.lib.format.write_array(out, array, allow_pickle=allow_pickle)
    return memoryview(out.getvalue())


# Arrays of every layout a section meets: (id, array).
_SECTIONS = [
    ("3-d", np.arange(24.0).reshape(2, 3, 4)),
    ("fortran", np.asfortranarray(np.arange(12).reshape(3, 4))),
    ("empty structured", np.zeros(0, dtype=[("a", "<f8"), ("b", "U16")])),
    ("0-d", np.array(3.5)),
    ("long shape", np.array([(1, "25/11")] * 1000, dtype=[("n", "<i8"), ("s", "U16")])),
]


@pytest.mark.parametrize("array", [a for _, a in _SECTIONS], ids=[name for name, _ in _SECTIONS])
def test_a_section_read_with_its_layout_remembered_is_numpys_array(array: np.ndarray) -> None:
    for rows in (array, array[..., :1] if array.ndim else array):
        # Twice: the first read parses the layout (numpy's reader), the second uses it.
        for _ in range(2):
            mine = read_npy(_npy_bytes(rows))
            theirs = np.lib.format.read_array(io.BytesIO(_npy_bytes(rows)), allow_pickle=False)
            assert mine.dtype == theirs.dtype and mine.shape == theirs.shape
            assert mine.flags.f_contiguous == theirs.flags.f_contiguous
            assert mine.flags.writeable
            assert mine.tobytes(order="A") == theirs.tobytes(order="A")


# A view of some fields of a wider row: a dtype with gaps between its fields.
_GAPPED = np.zeros(3, dtype=[("a", "<f8"), ("R", "<f8", (2, 2)), ("b", "U8")])[["a", "b"]]


@pytest.mark.parametrize(
    "array",
    [a for _, a in _SECTIONS] + [_GAPPED],
    ids=[name for name, _ in _SECTIONS] + ["fields with gaps"],
)
def test_a_section_written_with_its_header_remembered_is_numpys_bytes(array: np.ndarray) -> None:
    for rows in (array, array[..., :1] if array.ndim else array):
        # Twice: the first write is numpy's (its header kept), the second uses the header.
        for _ in range(2):
            theirs = _npy_bytes(np.ascontiguousarray(rows)).tobytes()
            assert b"".join(_npy(rows)) == theirs


def test_a_section_cut_short_or_of_objects_is_refused() -> None:
    data = _npy_bytes(np.arange(100.0))
    read_npy(data)  # its layout remembered
    with pytest.raises(ValueError):
        read_npy(data[:-8])
    with pytest.raises(ValueError, match="pickle"):
        read_npy(_npy_bytes(np.array([1, None], dtype=object), allow_pickle=True))


def test_a_radar_process_input_counters_and_memory_cross_on_its_watermark() -> None:
    inputs = {
        "25_11": InputCounters(received=12, delivered=9, duplicates=3, behind_dropped=2),
        "25_12": InputCounters(kernel_drops=4, last_reception=1.78e9 + 0.25),
    }
    beat = decode_message(encode_message(DatagramResult(7, 7e-6, inputs=inputs, resident_mb=412.5)))
    assert beat.inputs == inputs and beat.batches == [] and beat.resident_mb == 412.5
    bare = decode_message(encode_message(DatagramResult(7, 7e-6)))
    assert bare.inputs == {} and bare.resident_mb is None
    for impossible in (-1.0, math.nan, math.inf):
        forged = decode_message(encode_message(DatagramResult(7, 7e-6, resident_mb=impossible)))
        assert forged.resident_mb is None
    # A section of another shape is refused, not half read.
    payload = encode_message(DatagramResult(7, 7e-6, inputs=inputs))
    wrong = payload.replace(b"'behind_dropped'", b"'behind_droppes'")
    with pytest.raises(StageMessageError, match="incomplete"):
        decode_message(wrong)


def test_a_radar_process_loop_totals_cross_on_its_watermark() -> None:
    beat = decode_message(encode_message(DatagramResult(7, 7e-6, loop=LoopTotals(12.5, 3.25))))
    assert beat.loop == LoopTotals(12.5, 3.25)
    assert decode_message(encode_message(DatagramResult(7, 7e-6))).loop is None
    # Figures no loop has are dropped, not the message (the status would refuse them).
    for elapsed, busy in ((1.0, 2.0), (1.0, -0.5), (math.nan, 0.0), (math.inf, 1.0)):
        forged = DatagramResult(7, 7e-6, loop=LoopTotals(elapsed, busy))
        assert decode_message(encode_message(forged)).loop is None
    # A section of another shape refuses the message with the decoder's error (it raised
    # a TypeError past the fusion loop's handling), not half read.
    payload = encode_message(DatagramResult(7, 7e-6))
    magic, kind, count = _HEAD.unpack_from(payload)
    bent = b"".join(_section("load", np.zeros((2, 2))))
    with pytest.raises(StageMessageError, match="incomplete"):
        decode_message(_HEAD.pack(magic, kind, count + 1) + payload[_HEAD.size :] + bent)
