"""Simulation recordings: every output format written and read back, determinism, errors."""

from __future__ import annotations

import datetime as dt
import json
import re
import zlib
from decimal import ROUND_HALF_EVEN, Decimal, localcontext
from pathlib import Path
from typing import Any

import pytest
import zstandard
from hypothesis import given
from hypothesis import strategies as st
from mcap.reader import make_reader
from mcap.records import Chunk
from mcap.stream_reader import StreamReader
from mcap.writer import Writer
from pydantic import BaseModel

from asterix.codec import encode_block
from asterix.containers import Datagram, read_file
from tracker_service.simulator import recording
from tracker_service.simulator.recording import (
    FORMAT_NAME,
    FORMAT_VERSION,
    MCAP_LIBRARY,
    MESSAGE_MODELS,
    AsterixDatagram,
    RecordingWriter,
    TruthAircraft,
    TruthBiases,
    TruthCoverage,
    TruthPlots,
    json_schema,
    open_writer,
    read_recording,
    schema_name,
)

REPO = Path(__file__).resolve().parents[1]
T0 = 1767268800.0  # 2026-01-01T12:00:00Z

RADAR = "25/11"
ADSB = "25/200"
RADAR_SRC = ("10.0.0.1", 50011)
RADAR_A = ("232.1.1.11", 8600)
RADAR_B = ("232.1.2.11", 8600)
ADSB_SRC = ("10.0.0.2", 50200)
ADSB_DST = ("232.1.2.1", 8621)

CAT048 = encode_block(
    48,
    [
        {"010": {"SAC": 25, "SIC": 11}, "140": 43200.0},
        {"010": {"SAC": 25, "SIC": 11}, "140": 43200.0078125},
    ],
)
CAT034 = encode_block(34, [{"010": {"SAC": 25, "SIC": 11}, "000": 2}])
CAT021 = encode_block(21, [{"010": {"SAC": 25, "SIC": 200}}])

METADATA: dict[str, Any] = {
    "scenario": {
        "name": "two sources",
        "start": dt.datetime(2026, 1, 1, 12, tzinfo=dt.UTC),  # as model_dump() leaves it
        "duration_s": 10.0,
    },
    "seed": 7,
    "radars": [RADAR],
}
# What the "scenario" metadata record holds: JSON, the datetime as ISO 8601 text.
STORED_METADATA: dict[str, Any] = {
    "radars": [RADAR],
    "scenario": {"duration_s": 10.0, "name": "two sources", "start": "2026-01-01T12:00:00Z"},
    "seed": 7,
}
TRUTH_MODELS: dict[str, type[BaseModel]] = {
    "/truth/aircraft": TruthAircraft,
    "/truth/plots": TruthPlots,
    "/truth/biases": TruthBiases,
    "/truth/coverage": TruthCoverage,
}


def _aircraft(index: int, t: float) -> dict[str, Any]:
    return {
        "index": index,
        "address": "3C660C" if index == 0 else None,
        "callsign": "DLH4AB" if index == 0 else None,
        "mode3a": "1000" if index == 0 else None,
        "lat": 50.0 + 0.01 * t,
        "lon": 8.5,
        "h_msl_m": 10_000.0,
        "fl": 330.0,
        "vel_east_mps": 0.0,
        "vel_north_mps": 230.0,
        "vel_up_mps": -0.5,
        "heading_deg": 0.0,
        "ground_speed_mps": 230.0,
    }


def _plot(kind: str, aircraft: int | None, t: float, **extra: Any) -> dict[str, Any]:
    seen = aircraft is not None
    return {
        "kind": kind,
        "aircraft": aircraft,
        "detection_time": t,
        "true_range_m": 92_600.0 if seen else None,
        "true_azimuth_deg": 45.25 if seen else None,
        "true_fl": 330.0 if seen else None,
        **extra,
    }


BIASES = {
    "range_offset_m": 35.0,
    "range_gain": 1e-4,
    "azimuth_deg": -0.08,
    "time_s": 0.012,
    "psr_range_offset_m": -20.0,
    "psr_range_gain": 0.0,
    "psr_azimuth_deg": 0.1,
}

# The datagrams (source, time, lan, src, dst, payload) and truth (topic, time, message) of
# a small run; ORDER says how they interleave.
DATAGRAMS = [
    (RADAR, T0 + 0.0123456789, "A", RADAR_SRC, RADAR_A, CAT048),
    (RADAR, T0 + 0.0127456789, "B", RADAR_SRC, RADAR_B, CAT048),
    (ADSB, T0 + 0.3, "A", ADSB_SRC, ADSB_DST, CAT021),
    (RADAR, T0 + 4.1, "A", RADAR_SRC, RADAR_A, CAT048 + CAT034),
    (RADAR, T0 + 4.1004, "B", RADAR_SRC, RADAR_B, CAT048 + CAT034),
]
TRUTH: list[tuple[str, float, dict[str, Any]]] = [
    ("/truth/aircraft", T0, {"time": T0, "aircraft": [_aircraft(0, 0.0), _aircraft(1, 0.0)]}),
    ("/truth/biases", T0, {"source": RADAR, "time": T0, **BIASES}),
    (
        "/truth/plots",
        T0 + 0.0123456789,
        {
            "source": RADAR,
            "time": T0 + 0.0123456789,
            "sequence": 0,
            "records": [
                _plot("aircraft", 0, T0 - 0.5, psr_only=False),
                _plot("clutter", None, T0 - 0.4),
            ],
        },
    ),
    ("/truth/aircraft", T0 + 1.0, {"time": T0 + 1.0, "aircraft": [_aircraft(0, 1.0)]}),
    (
        "/truth/coverage",
        T0 + 4.0,
        {"source": RADAR, "time": T0 + 4.0, "scan": 0, "aircraft": [0, 1]},
    ),
    (
        "/truth/plots",
        T0 + 4.1,
        {
            "source": RADAR,
            "time": T0 + 4.1,
            "sequence": 1,
            "records": [_plot("aircraft", 1, T0 + 3.9, psr_only=True), _plot("split", 1, T0 + 3.9)],
        },
    ),
]


# The order of the calls, T for the next of TRUTH and D for the next of DATAGRAMS: aircraft
# and biases at T0, radar datagram 0 (LAN A, B), its plot origins, ADS-B, aircraft at T0 + 1,
# coverage of scan 0, radar datagram 1 (LAN A, B), its plot origins.
ORDER = "TTDDTDTTDDT"


def _calls() -> list[tuple[str, Any]]:
    """("D", datagram) or ("T", (topic, time, message)) in the order of ORDER."""
    datagrams, truth = iter(DATAGRAMS), iter(TRUTH)
    return [(kind, next(datagrams) if kind == "D" else next(truth)) for kind in ORDER]


def _simulate(writer: RecordingWriter) -> None:
    """The calls a small run makes, in reception-time order."""
    for kind, call in _calls():
        if kind == "D":
            source, t, lan, src, dst, payload = call
            writer.datagram(source, t, payload, lan, src, dst)
            continue
        topic, _t, message = call
        args = dict(message)
        if topic == "/truth/aircraft":
            writer.truth(args["time"], args["aircraft"])
        elif topic == "/truth/biases":
            source, t = args.pop("source"), args.pop("time")
            writer.biases(source, t, args)
        elif topic == "/truth/plots":
            writer.plot_origins(args["source"], args["time"], args["sequence"], args["records"])
        else:
            writer.coverage(args["source"], args["time"], args["scan"], args["aircraft"])


def _write(path: Path, metadata: dict[str, Any] | None = None) -> Path:
    with open_writer(path, METADATA if metadata is None else metadata) as writer:
        _simulate(writer)
    return path


def _ns(t: float) -> int:
    """Exact nanoseconds of a float time, rounded half to even."""
    with localcontext() as context:
        context.prec = 100
        return int((Decimal(t) * 10**9).quantize(Decimal(1), rounding=ROUND_HALF_EVEN))


def _stored(message: dict[str, Any]) -> dict[str, Any]:
    """A truth message as the file holds it: psr_only is always written."""
    if "records" not in message:
        return message
    records = [{"psr_only": None, **r} for r in message["records"]]
    return {**message, "records": records}


# ---------------------------------------------------------------------------
# A JSON Schema checker for the keywords pydantic emits, strict about the rest, so that
# the schemas are checked as documents and every message is checked against its schema.
# ---------------------------------------------------------------------------

_KEYWORDS = {
    "$schema", "$defs", "$ref", "title", "description", "default", "type", "properties",
    "required", "additionalProperties", "items", "anyOf", "enum", "pattern", "minimum",
    "maximum", "maxLength",
}  # fmt: skip
_TYPES = {"object", "array", "string", "number", "integer", "boolean", "null"}


def _check_schema_document(schema: dict[str, Any], root: dict[str, Any]) -> None:
    assert isinstance(schema, dict)
    assert set(schema) <= _KEYWORDS, set(schema) - _KEYWORDS
    if "type" in schema:
        assert schema["type"] in _TYPES
    if "$ref" in schema:
        match = re.fullmatch(r"#/\$defs/(\w+)", schema["$ref"])
        assert match is not None and match.group(1) in root.get("$defs", {})
    for sub in schema.get("$defs", {}).values():
        _check_schema_document(sub, root)
    for sub in schema.get("properties", {}).values():
        _check_schema_document(sub, root)
    for sub in schema.get("anyOf", []):
        _check_schema_document(sub, root)
    if "items" in schema:
        _check_schema_document(schema["items"], root)
    if "required" in schema:
        assert set(schema["required"]) <= set(schema["properties"])


def _conforms(value: Any, schema: dict[str, Any], root: dict[str, Any]) -> bool:
    if "$ref" in schema:
        return _conforms(value, root["$defs"][schema["$ref"].rsplit("/", 1)[1]], root)
    if "anyOf" in schema:
        return any(_conforms(value, sub, root) for sub in schema["anyOf"])
    kind = schema.get("type")
    checks = {
        "object": lambda v: isinstance(v, dict),
        "array": lambda v: isinstance(v, list),
        "string": lambda v: isinstance(v, str),
        "number": lambda v: isinstance(v, int | float) and not isinstance(v, bool),
        "integer": lambda v: isinstance(v, int) and not isinstance(v, bool),
        "boolean": lambda v: isinstance(v, bool),
        "null": lambda v: v is None,
    }
    if kind is not None and not checks[kind](value):
        return False
    if "enum" in schema and value not in schema["enum"]:
        return False
    if "pattern" in schema and re.search(schema["pattern"], value) is None:
        return False
    if "maxLength" in schema and len(value) > schema["maxLength"]:
        return False
    if "minimum" in schema and value < schema["minimum"]:
        return False
    if "maximum" in schema and value > schema["maximum"]:
        return False
    if kind == "array":
        return all(_conforms(item, schema["items"], root) for item in value)
    if kind == "object":
        properties = schema.get("properties", {})
        if not set(schema.get("required", [])) <= set(value):
            return False
        if schema.get("additionalProperties") is False and not set(value) <= set(properties):
            return False
        return all(_conforms(value[k], properties[k], root) for k in value if k in properties)
    return True


# ---------------------------------------------------------------------------
# MCAP
# ---------------------------------------------------------------------------


def test_mcap_reads_back_through_read_recording(tmp_path: Path) -> None:
    rec = read_recording(_write(tmp_path / "run.mcap"))

    assert rec.metadata == STORED_METADATA
    assert rec.sources == [RADAR, ADSB]
    got = [tuple(d) for d in rec.datagrams()]
    # Times come back exactly: nanoseconds hold a float of today's epoch without loss.
    assert got == [(s, t, lan, src, dst, p) for s, t, lan, src, dst, p in DATAGRAMS]
    assert [d.payload for d in rec.datagrams([ADSB])] == [CAT021]
    for topic in TRUTH_MODELS:
        expected = [_stored(message) for t, _time, message in TRUTH if t == topic]
        assert list(rec.messages(topic)) == expected, topic


def test_mcap_reads_back_through_the_mcap_library(tmp_path: Path) -> None:
    path = _write(tmp_path / "run.mcap")
    with open(path, "rb") as stream:
        reader = make_reader(stream, validate_crcs=True)
        header = reader.get_header()
        assert (header.profile, header.library) == ("", MCAP_LIBRARY)
        assert [(m.name, m.metadata) for m in reader.iter_metadata()] == [
            ("scenario", {"json": json.dumps(STORED_METADATA, sort_keys=True)}),
            ("format", {"name": FORMAT_NAME, "version": FORMAT_VERSION}),
        ]
        summary = reader.get_summary()
        assert summary is not None

        schemas = {s.id: s for s in summary.schemas.values()}
        assert sorted(s.name for s in schemas.values()) == sorted(
            schema_name(m) for m in MESSAGE_MODELS
        )
        for schema in schemas.values():
            assert schema.encoding == "jsonschema"
            document = json.loads(schema.data)
            assert document["$schema"] == "https://json-schema.org/draft/2020-12/schema"
            assert document["type"] == "object"
            _check_schema_document(document, document)

        channels = {c.topic: c for c in summary.channels.values()}
        by_source = {"/asterix/25_11": RADAR, "/asterix/25_200": ADSB}
        assert set(channels) == {
            "/truth/aircraft", "/truth/plots", "/truth/biases", "/truth/coverage", *by_source
        }  # fmt: skip
        for topic, channel in channels.items():
            assert channel.message_encoding == "json"
            model = AsterixDatagram if topic.startswith("/asterix/") else TRUTH_MODELS[topic]
            assert schemas[channel.schema_id].name == schema_name(model)
        for topic, source in by_source.items():
            assert channels[topic].metadata == {"source": source}

        statistics = summary.statistics
        assert statistics is not None
        per_topic = {
            summary.channels[i].topic: n for i, n in statistics.channel_message_counts.items()
        }
        assert per_topic == {
            "/asterix/25_11": 4, "/asterix/25_200": 1, "/truth/aircraft": 2, "/truth/plots": 2,
            "/truth/biases": 1, "/truth/coverage": 1,
        }  # fmt: skip
        assert statistics.message_start_time == _ns(T0)
        assert statistics.message_end_time == _ns(T0 + 4.1004)

        # File order is call order; every message conforms to its channel's schema.
        seen = []
        for used, channel, message in reader.iter_messages(log_time_order=False):
            assert used is not None
            assert message.publish_time == message.log_time
            document = json.loads(used.data)
            body = json.loads(message.data)
            assert _conforms(body, document, document), (channel.topic, body)
            seen.append((channel.topic, message.log_time, message.sequence, body))

    expected = []
    counts: dict[tuple[str, str], int] = {}
    for kind, call in _calls():
        if kind == "D":
            source, t, lan, src, dst, payload = call
            topic, key = "/asterix/" + source.replace("/", "_"), lan
            body = {
                "source": source,
                "lan": lan,
                "src": f"{src[0]}:{src[1]}",
                "dst": f"{dst[0]}:{dst[1]}",
                "payload": payload.hex(),
            }
        else:
            topic, t, message = call
            key, body = "", _stored(message)
        n = counts.get((topic, key), 0)
        counts[topic, key] = n + 1
        expected.append((topic, _ns(t), n, body))
    assert seen == expected
    # LAN A sequence numbers are the datagram numbers /truth/plots refers to.
    plots = [body["sequence"] for topic, _t, _n, body in seen if topic == "/truth/plots"]
    lan_a = [n for topic, _t, n, body in seen if topic == "/asterix/25_11" and body["lan"] == "A"]
    assert plots == lan_a == [0, 1]


def test_mcap_chunks_are_zstd_at_level_3(tmp_path: Path) -> None:
    # mcap-python does not take a level; pin the one it uses, as the format doc states it.
    path = _write(tmp_path / "run.mcap")
    with open(path, "rb") as stream:
        records = list(StreamReader(stream, emit_chunks=True).records)
    chunks = [r for r in records if isinstance(r, Chunk)]
    assert chunks
    for chunk in chunks:
        assert chunk.compression == "zstd"
        raw = zstandard.ZstdDecompressor().decompress(chunk.data, chunk.uncompressed_size)
        assert zlib.crc32(raw) == chunk.uncompressed_crc
        assert zstandard.ZstdCompressor(level=3).compress(raw) == chunk.data


def test_an_empty_mcap_recording_still_has_every_truth_channel(tmp_path: Path) -> None:
    path = tmp_path / "empty.mcap"
    open_writer(path, {}).close()
    rec = read_recording(path)
    assert rec.metadata == {}
    assert set(rec.topics) == {
        "/truth/aircraft",
        "/truth/plots",
        "/truth/biases",
        "/truth/coverage",
    }
    assert list(rec.datagrams()) == []
    assert list(rec.messages("/truth/plots")) == []


def test_the_reader_sorts_by_log_time_and_keeps_call_order_on_ties(tmp_path: Path) -> None:
    path = tmp_path / "late.mcap"
    with open_writer(path, {}) as writer:
        # Coverage stamped at the start of a scan but told at its end, after datagrams.
        writer.datagram(RADAR, T0 + 1.0, CAT048, "A", RADAR_SRC, RADAR_A)
        writer.datagram(RADAR, T0 + 1.0, CAT034, "B", RADAR_SRC, RADAR_B)
        writer.coverage(RADAR, T0 + 4.0, 1, [])
        writer.coverage(RADAR, T0, 0, [0])
        writer.datagram(RADAR, T0 + 0.5, CAT021, "A", RADAR_SRC, RADAR_A)
    rec = read_recording(path)
    assert [(d.time, d.lan, d.payload) for d in rec.datagrams()] == [
        (T0 + 0.5, "A", CAT021),
        (T0 + 1.0, "A", CAT048),
        (T0 + 1.0, "B", CAT034),
    ]
    assert [m["scan"] for m in rec.messages("/truth/coverage")] == [0, 1]


@given(st.floats(min_value=0.0, max_value=2.0**34, allow_nan=False, allow_infinity=False))
def test_time_to_nanoseconds_is_exact(t: float) -> None:
    ns = recording.time_ns(t)
    assert ns == _ns(t)
    if t >= 2.0**23:  # floats more than 1 ns apart from there: the float itself comes back
        assert ns / 10**9 == t


# ---------------------------------------------------------------------------
# Datagram-only formats
# ---------------------------------------------------------------------------


def _datagrams(path: Path) -> list[Datagram]:
    items = list(read_file(path))
    assert all(isinstance(i, Datagram) for i in items), items
    return [i for i in items if isinstance(i, Datagram)]


def test_pcap_holds_both_lans_with_times_and_addresses(tmp_path: Path) -> None:
    got = _datagrams(_write(tmp_path / "run.pcap"))
    assert [(d.payload, d.source, d.destination) for d in got] == [
        (p, src, dst) for _s, _t, _lan, src, dst, p in DATAGRAMS
    ]
    for datagram, (_s, t, *_rest) in zip(got, DATAGRAMS, strict=True):
        assert datagram.time == pytest.approx(t, abs=0.5e-6)


@pytest.mark.parametrize("suffix", [".raw", ".ast"])
def test_raw_holds_the_data_blocks_of_both_lans(tmp_path: Path, suffix: str) -> None:
    path = _write(tmp_path / f"run{suffix}")
    payloads = [p for *_rest, p in DATAGRAMS]
    assert path.read_bytes() == b"".join(payloads)
    got = _datagrams(path)
    # A raw reader sees blocks, not datagrams: the two-block datagrams come back split.
    assert [d.payload for d in got] == [CAT048, CAT048, CAT021, CAT048, CAT034, CAT048, CAT034]
    assert {d.time for d in got} == {None}


def test_hex_holds_one_datagram_per_line(tmp_path: Path) -> None:
    path = _write(tmp_path / "run.hex")
    lines = path.read_text(encoding="ascii").splitlines()
    assert lines[0] == CAT048.hex(" ")
    assert lines[0].startswith("30 00 ")
    assert all(re.fullmatch(r"[0-9a-f]{2}( [0-9a-f]{2})*", line) for line in lines)
    assert [d.payload for d in _datagrams(path)] == [p for *_rest, p in DATAGRAMS]


@pytest.mark.parametrize("suffix", [".mcap", ".pcap", ".raw", ".ast", ".hex", ".MCAP"])
def test_the_same_calls_give_the_same_bytes(tmp_path: Path, suffix: str) -> None:
    first = _write(tmp_path / f"first{suffix}").read_bytes()
    second = _write(tmp_path / f"second{suffix}").read_bytes()
    assert first == second


# ---------------------------------------------------------------------------
# Errors
# ---------------------------------------------------------------------------


@pytest.mark.parametrize("name", ["run.txt", "run.pcapng", "run"])
def test_an_unknown_suffix_names_the_allowed_ones(tmp_path: Path, name: str) -> None:
    with pytest.raises(ValueError, match=r"unknown recording suffix .*\.mcap, \.pcap, \.raw"):
        open_writer(tmp_path / name, {})
    assert not (tmp_path / name).exists()


def test_read_recording_refuses_other_files(tmp_path: Path) -> None:
    pcap = _write(tmp_path / "run.pcap")
    with pytest.raises(ValueError, match=r"not an MCAP recording .*looks like pcap.*read_file"):
        read_recording(pcap)
    whole = _write(tmp_path / "run.mcap").read_bytes()
    for size in (8, 200, len(whole) - 1):
        truncated = tmp_path / f"truncated{size}.mcap"
        truncated.write_bytes(whole[:size])
        with pytest.raises(ValueError, match="was the recording closed"):
            read_recording(truncated)
    other = tmp_path / "other.mcap"
    with open(other, "wb") as stream:
        writer = Writer(stream)
        writer.start()
        writer.add_metadata("scenario", {"json": "{}"})
        writer.finish()  # type: ignore[no-untyped-call]
    with pytest.raises(ValueError, match="format metadata is missing"):
        read_recording(other)


def test_metadata_that_is_not_json_fails_before_any_file_exists(tmp_path: Path) -> None:
    path = tmp_path / "run.mcap"
    with pytest.raises(ValueError, match="cannot be written as JSON"):
        open_writer(path, {"sigma": float("nan")})
    assert not path.exists()


@pytest.mark.parametrize("suffix", [".mcap", ".pcap", ".raw", ".hex"])
@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"source": "025/11"}, "SAC/SIC"),
        ({"source": "256/1"}, "SAC/SIC"),
        ({"lan": "C"}, "lan"),
        ({"time": float("nan")}, "time"),
        ({"time": -1.0}, "time"),
        ({"payload": b""}, "payload"),
        ({"dst": ("232.1.1", 8600)}, "dst"),
        ({"src": ("10.0.0.1", 70000)}, "port"),
    ],
)
def test_bad_datagram_arguments_raise_in_every_format(
    tmp_path: Path, suffix: str, change: dict[str, Any], message: str
) -> None:
    args: dict[str, Any] = {
        "source": RADAR,
        "time": T0,
        "payload": CAT048,
        "lan": "A",
        "src": RADAR_SRC,
        "dst": RADAR_A,
    }
    with (
        open_writer(tmp_path / f"run{suffix}", {}) as writer,
        pytest.raises(ValueError, match=message),
    ):
        writer.datagram(**{**args, **change})


@pytest.mark.parametrize(
    "call",
    [
        lambda w: w.truth(T0, [{**_aircraft(0, 0.0), "speed_kt": 400.0}]),  # unknown field
        lambda w: w.truth(T0, [{**_aircraft(0, 0.0), "mode3a": "7800"}]),  # not octal
        lambda w: w.truth(T0, [{**_aircraft(0, 0.0), "lat": float("inf")}]),
        lambda w: w.plot_origins(RADAR, T0, 0, [_plot("ghost", None, T0)]),
        lambda w: w.plot_origins(RADAR, T0, -1, []),
        lambda w: w.biases(RADAR, T0, {k: v for k, v in BIASES.items() if k != "time_s"}),
        lambda w: w.biases(RADAR, T0, {**BIASES, "time": T0}),
        lambda w: w.coverage("25-11", T0, 0, [1]),
        lambda w: w.coverage(RADAR, T0, 0, [-1]),
    ],
)
def test_bad_truth_raises(tmp_path: Path, call: Any) -> None:
    with open_writer(tmp_path / "run.mcap", {}) as writer, pytest.raises(ValueError):
        call(writer)


def test_a_closed_writer_refuses_more(tmp_path: Path) -> None:
    writer = open_writer(tmp_path / "run.hex", {})
    writer.close()
    writer.close()  # twice is fine
    with pytest.raises(ValueError, match="closed"):
        writer.datagram(RADAR, T0, CAT048, "A", RADAR_SRC, RADAR_A)


def test_read_recording_names_unknown_channels_and_sources(tmp_path: Path) -> None:
    rec = read_recording(_write(tmp_path / "run.mcap"))
    with pytest.raises(ValueError, match=r"no channel '/truth/plot'"):
        list(rec.messages("/truth/plot"))
    with pytest.raises(ValueError, match=r"no datagrams of .*25_12.*25/11"):
        list(rec.datagrams(["25/12"]))


# ---------------------------------------------------------------------------
# The format document
# ---------------------------------------------------------------------------


def test_the_format_document_holds_every_schema_as_written() -> None:
    text = (REPO / "docs" / "recording-format.md").read_text(encoding="utf-8")
    for model in MESSAGE_MODELS:
        block = f"```json\n{json.dumps(json_schema(model), indent=2)}\n```"
        assert block in text, f"docs/recording-format.md: the {model.__name__} schema is stale"
        assert schema_name(model) in text
