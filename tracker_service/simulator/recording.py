"""Simulation recordings: the simulator's output side, and the reader of MCAP recordings.

The suffix of the output file chooses what is kept (see ``docs/recording-format.md``):

- ``.mcap``: the datagrams of every source and the truth (aircraft states, the origin of
  every CAT048 record, the radars' systematic errors and coverage), JSON on MCAP channels;
- ``.pcap``: the datagrams only, as Ethernet/IPv4/UDP frames to each source's group;
- ``.raw`` / ``.ast``: the datagrams' bytes concatenated (data blocks only);
- ``.hex``: one datagram per line as lower-case hex bytes separated by spaces.

Every writer is deterministic: the same calls give the same bytes. Nothing reads the
clock; times are the simulated reception times the simulator passes.
"""

from __future__ import annotations

import io
import ipaddress
import json
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Annotated, Any, Literal, NamedTuple

from mcap.exceptions import EndOfFile, McapError
from mcap.reader import make_reader
from mcap.records import Channel, Message
from mcap.stream_reader import StreamReader
from pydantic import BaseModel, ConfigDict, Field
from pydantic_core import to_jsonable_python

from asterix.containers import ContainerError, Datagram, detect_format, write_pcap
from tracker_service.closing import Closing
from tracker_service.mcap_format import (
    MCAP_LIBRARY,
    NS_PER_S,
    json_schema,
    schema_name,
    start_mcap,
    time_ns,
)

__all__ = [
    "FORMAT_NAME",
    "FORMAT_VERSION",
    "MCAP_LIBRARY",
    "MESSAGE_MODELS",
    "SUFFIXES",
    "AircraftState",
    "AsterixDatagram",
    "PlotOrigin",
    "RecordedDatagram",
    "Recording",
    "RecordingWriter",
    "TruthAircraft",
    "TruthBiases",
    "TruthCoverage",
    "TruthPlots",
    "asterix_topic",
    "json_schema",
    "open_writer",
    "read_recording",
    "schema_name",
]

FORMAT_NAME = "tracker-service simulation"
FORMAT_VERSION = "1"

_CHUNK_SIZE = 1024 * 1024

SUFFIXES: tuple[str, ...] = (".mcap", ".pcap", ".raw", ".ast", ".hex")

TRUTH_AIRCRAFT = "/truth/aircraft"
TRUTH_PLOTS = "/truth/plots"
TRUTH_BIASES = "/truth/biases"
TRUTH_COVERAGE = "/truth/coverage"
_ASTERIX_PREFIX = "/asterix/"

_MAX_SEQUENCE = 2**32  # MCAP message sequence numbers are uint32
_MAX_UDP_PAYLOAD = 65535 - 20 - 8

_OCTET = r"(?:25[0-5]|2[0-4][0-9]|1[0-9]{2}|[1-9]?[0-9])"
# Canonical decimal only ("25/11", never "025/011"): the channel topic is made from it,
# and two spellings of one source would split its datagrams over two channels.
SOURCE_PATTERN = rf"^{_OCTET}/{_OCTET}$"
_ENDPOINT_PATTERN = r"^[0-9]{1,3}(?:\.[0-9]{1,3}){3}:[0-9]{1,5}$"
_SOURCE_RE = re.compile(SOURCE_PATTERN)


# ---------------------------------------------------------------------------
# Message models: one per channel kind; their JSON schemas are the MCAP schemas
# ---------------------------------------------------------------------------


class _Message(BaseModel):
    # A recording format is a contract: a field the schema does not name is a bug to report
    # when writing, not to discover when evaluating. JSON has no NaN or infinity.
    # Serialization schemas list defaulted fields as required too: the file always has them.
    model_config = ConfigDict(
        extra="forbid", allow_inf_nan=False, json_schema_serialization_defaults_required=True
    )


Source = Annotated[
    str,
    Field(
        pattern=SOURCE_PATTERN,
        description='The source\'s SAC/SIC in decimal, e.g. "25/11".',
    ),
]


class AsterixDatagram(_Message):
    """One UDP datagram of ASTERIX data as the receiver got it. Its reception time is the
    message's log time (and publish time), in nanoseconds since the POSIX epoch."""

    source: Source
    lan: Literal["A", "B"] = Field(
        description='The LAN it came in on; "B" is the redundant copy of a dual-LAN source.'
    )
    src: str = Field(
        pattern=_ENDPOINT_PATTERN, description='Sender IPv4 address and UDP port, "ip:port".'
    )
    dst: str = Field(
        pattern=_ENDPOINT_PATTERN,
        description='Destination (the multicast group) IPv4 address and UDP port, "ip:port".',
    )
    payload: str = Field(
        pattern=r"^(?:[0-9a-f]{2})+$",
        description="The UDP payload: one or more ASTERIX data blocks, lower-case hex, "
        "two digits per byte, no separators.",
    )


class AircraftState(_Message):
    """The true state of one aircraft."""

    index: int = Field(
        ge=0,
        description="The aircraft's index in the simulation, fixed for the whole run; "
        "/truth/plots and /truth/coverage refer to aircraft by it.",
    )
    address: str | None = Field(
        pattern=r"^[0-9A-Fa-f]{6}$",
        description="ICAO 24-bit address, 6 hex digits; null without one.",
    )
    callsign: str | None = Field(
        max_length=8, description="Callsign (aircraft identification); null without one."
    )
    mode3a: str | None = Field(
        pattern=r"^[0-7]{4}$",
        description="Mode 3/A code replied at that time, 4 octal digits; null without one.",
    )
    lat: float = Field(ge=-90.0, le=90.0, description="WGS-84 latitude, degrees.")
    lon: float = Field(ge=-180.0, le=180.0, description="WGS-84 longitude, degrees.")
    h_msl_m: float = Field(description="Geometric height above mean sea level, metres.")
    fl: float = Field(
        description="Pressure altitude in flight levels (hundreds of feet), what Mode C "
        "reports; differs from h_msl_m when QNH or temperature are not standard."
    )
    vel_east_mps: float = Field(description="Velocity towards the east, m/s.")
    vel_north_mps: float = Field(description="Velocity towards the north, m/s.")
    vel_up_mps: float = Field(description="Vertical velocity, positive up, m/s.")
    heading_deg: float = Field(
        ge=0.0, le=360.0, description="Heading, degrees clockwise from true north."
    )
    ground_speed_mps: float = Field(ge=0.0, description="Speed over the ground, m/s.")


class TruthAircraft(_Message):
    """A snapshot of every aircraft of the simulation, at the truth rate of the scenario."""

    time: float = Field(ge=0.0, description="Time of the snapshot, POSIX seconds.")
    aircraft: list[AircraftState] = Field(description="Every aircraft, one entry each.")


class PlotOrigin(_Message):
    """What one CAT048 record (or CAT021 report of an ADS-B station) is."""

    kind: Literal["aircraft", "clutter", "reflection", "split", "field_monitor", "adsb"] = Field(
        description="aircraft: a detection of an aircraft; clutter: a false plot from "
        "nothing; reflection: a false plot of an aircraft seen by way of a reflector; "
        "split: an extra plot split from an aircraft's detection; field_monitor: the "
        "radar's fixed test transponder; adsb: an ADS-B report of an aircraft (CAT021)."
    )
    aircraft: int | None = Field(
        ge=0,
        description="Index of the aircraft at the origin (see /truth/aircraft); null when "
        "none (clutter, field monitor).",
    )
    detection_time: float = Field(
        ge=0.0,
        description="When the beam saw it, POSIX seconds (true time, without the radar's "
        "time-stamp error).",
    )
    true_range_m: float | None = Field(
        ge=0.0,
        description="True slant range from the radar at detection_time, metres, before "
        "noise and systematic errors; null when there is no such truth.",
    )
    true_azimuth_deg: float | None = Field(
        ge=0.0,
        le=360.0,
        description="True azimuth from the radar at detection_time, degrees clockwise from "
        "true north, before noise and systematic errors; null when there is no such truth.",
    )
    true_fl: float | None = Field(
        description="True pressure altitude in flight levels (hundreds of feet); null when "
        "there is none."
    )
    psr_only: bool | None = Field(
        default=None,
        description="True when only the primary radar saw it (no SSR or Mode S reply); "
        "null when not stated.",
    )


class TruthPlots(_Message):
    """The origin of every CAT048 record of one datagram of a radar."""

    source: Source
    time: float = Field(ge=0.0, description="Reception time of the datagram, POSIX seconds.")
    sequence: int = Field(
        ge=0,
        description="Which datagram of the source: 0-based count of its datagrams on LAN A "
        "(the MCAP sequence of that LAN A message on its /asterix channel, modulo 2^32).",
    )
    records: list[PlotOrigin] = Field(
        description="One entry per CAT048 record of the datagram, in record order."
    )


class TruthBiases(_Message):
    """A radar's true systematic errors at a time, measured minus true:
    rho_measured = (1 + range_gain) rho + range_offset_m; theta_measured = theta +
    azimuth_deg; I140 = true time + time_s. The psr_ fields apply to PSR-only plots."""

    source: Source
    time: float = Field(ge=0.0, description="Time the values hold at, POSIX seconds.")
    range_offset_m: float = Field(description="Range offset, metres.")
    range_gain: float = Field(description="Range gain g, dimensionless (1e-4 = 0.1 m/km).")
    azimuth_deg: float = Field(description="Azimuth offset, degrees (clockwise positive).")
    time_s: float = Field(description="Time-stamp (I140) error, seconds.")
    psr_range_offset_m: float = Field(description="PSR-only plots: range offset, metres.")
    psr_range_gain: float = Field(description="PSR-only plots: range gain, dimensionless.")
    psr_azimuth_deg: float = Field(description="PSR-only plots: azimuth offset, degrees.")


class TruthCoverage(_Message):
    """The aircraft within a radar's coverage during one antenna scan."""

    source: Source
    time: float = Field(ge=0.0, description="Time of the scan, POSIX seconds.")
    scan: int = Field(ge=0, description="0-based count of the radar's antenna scans.")
    aircraft: list[Annotated[int, Field(ge=0)]] = Field(
        description="Indices of the aircraft in coverage (see /truth/aircraft)."
    )


MESSAGE_MODELS: tuple[type[BaseModel], ...] = (
    AsterixDatagram,
    TruthAircraft,
    TruthPlots,
    TruthBiases,
    TruthCoverage,
)

_TRUTH_CHANNELS: tuple[tuple[str, type[BaseModel]], ...] = (
    (TRUTH_AIRCRAFT, TruthAircraft),
    (TRUTH_PLOTS, TruthPlots),
    (TRUTH_BIASES, TruthBiases),
    (TRUTH_COVERAGE, TruthCoverage),
)


def asterix_topic(source: str) -> str:
    """The channel of a source's datagrams: "25/11" -> "/asterix/25_11"."""
    _check_source(source)
    sac, sic = source.split("/")
    return f"{_ASTERIX_PREFIX}{sac}_{sic}"


# ---------------------------------------------------------------------------
# Argument checks shared by the writers
# ---------------------------------------------------------------------------


def _check_source(source: str) -> None:
    if not isinstance(source, str) or _SOURCE_RE.fullmatch(source) is None:
        raise ValueError(f"source {source!r} must be SAC/SIC in decimal, e.g. '25/11'")


def _endpoint_text(endpoint: tuple[str, int], role: str) -> str:
    try:
        ip, port = endpoint
        address = ipaddress.IPv4Address(ip)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{role} {endpoint!r} must be (IPv4 address, port): {exc}") from None
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 0xFFFF:
        raise ValueError(f"{role} port {port!r} must be an integer in 0..65535")
    return f"{address}:{port}"


def _parse_endpoint(text: str) -> tuple[str, int]:
    ip, _, port = text.rpartition(":")
    return ip, int(port)


def _check_datagram(
    source: str,
    time: float,
    payload: bytes,
    lan: str,
    src: tuple[str, int],
    dst: tuple[str, int],
) -> tuple[int, str, str]:
    """Checks what every format needs; returns (log time ns, src text, dst text)."""
    _check_source(source)
    if lan not in ("A", "B"):
        raise ValueError(f"lan {lan!r} must be 'A' or 'B'")
    if not 0 < len(payload) <= _MAX_UDP_PAYLOAD:
        # An empty line of a .hex file or nothing in a .raw one would vanish on reading.
        raise ValueError(
            f"a datagram payload needs 1..{_MAX_UDP_PAYLOAD} bytes, not {len(payload)}"
        )
    return time_ns(time), _endpoint_text(src, "src"), _endpoint_text(dst, "dst")


# ---------------------------------------------------------------------------
# Writers
# ---------------------------------------------------------------------------


class RecordingWriter(Closing):
    """What the simulator calls, in the order of reception times.

    The base class keeps nothing, so it is also the writer of a run without output;
    each format overrides what it keeps. Use as a context manager, or call ``close``.
    """

    def __init__(self) -> None:
        self._closed = False

    def datagram(
        self,
        source: str,
        time: float,
        payload: bytes,
        lan: str,
        src: tuple[str, int],
        dst: tuple[str, int],
    ) -> None:
        """One datagram as received: ``source`` "SAC/SIC", ``time`` its reception time in
        POSIX seconds, ``lan`` "A" or "B" (the dual-LAN copy is a second call with "B")."""
        self._check_open()

    def truth(self, time: float, aircraft: list[dict[str, Any]]) -> None:
        """A snapshot of every aircraft (fields of :class:`AircraftState`)."""
        self._check_open()

    def plot_origins(
        self, source: str, time: float, sequence: int, records: list[dict[str, Any]]
    ) -> None:
        """What each CAT048 record of the source's datagram number ``sequence`` is (0-based
        count of its LAN A datagrams): one dict (:class:`PlotOrigin`) per record, in order."""
        self._check_open()

    def biases(self, source: str, time: float, values: dict[str, float]) -> None:
        """The radar's true systematic errors (fields of :class:`TruthBiases`) at ``time``."""
        self._check_open()

    def coverage(self, source: str, time: float, scan: int, aircraft: list[int]) -> None:
        """Indices of the aircraft in the radar's coverage during antenna scan ``scan``."""
        self._check_open()

    def close(self) -> None:
        """Finishes the file; later calls do nothing."""
        self._closed = True

    def _check_open(self) -> None:
        if self._closed:
            raise ValueError("the recording is closed")


class _StreamWriter(RecordingWriter):
    """A format that keeps datagrams only, written as they come."""

    def __init__(self, path: Path) -> None:
        super().__init__()
        self._stream: IO[bytes] = open(path, "wb")  # noqa: SIM115 - closed by close()

    def datagram(
        self,
        source: str,
        time: float,
        payload: bytes,
        lan: str,
        src: tuple[str, int],
        dst: tuple[str, int],
    ) -> None:
        self._check_open()
        _check_datagram(source, time, payload, lan, src, dst)
        self._stream.write(self._encode(time, bytes(payload), src, dst))

    def _encode(
        self, time: float, payload: bytes, src: tuple[str, int], dst: tuple[str, int]
    ) -> bytes:
        raise NotImplementedError

    def close(self) -> None:
        if not self._closed:
            self._stream.close()
        super().close()


class _RawWriter(_StreamWriter):
    def _encode(
        self, time: float, payload: bytes, src: tuple[str, int], dst: tuple[str, int]
    ) -> bytes:
        return payload


class _HexWriter(_StreamWriter):
    def _encode(
        self, time: float, payload: bytes, src: tuple[str, int], dst: tuple[str, int]
    ) -> bytes:
        return payload.hex(" ").encode("ascii") + b"\n"


def _pcap_bytes(datagrams: list[tuple[float, tuple[str, int], tuple[str, int], bytes]]) -> bytes:
    buffer = io.BytesIO()
    write_pcap(buffer, datagrams)
    return buffer.getvalue()


class _PcapWriter(_StreamWriter):
    """Classic pcap through ``asterix.containers.write_pcap``, one packet per call.

    ``write_pcap`` pulls from an iterable while the simulator pushes, so each packet is
    encoded alone and the global header it repeats is cut off. The price: every IP
    identification field is 0, which is what the Don't Fragment flag allows (RFC 6864),
    against buffering a whole run in memory until ``close``.
    """

    def __init__(self, path: Path) -> None:
        super().__init__(path)
        header = _pcap_bytes([])
        self._header_size = len(header)
        self._stream.write(header)

    def _encode(
        self, time: float, payload: bytes, src: tuple[str, int], dst: tuple[str, int]
    ) -> bytes:
        return _pcap_bytes([(time, src, dst, payload)])[self._header_size :]


def _metadata_json(metadata: dict[str, Any]) -> str:
    try:
        # to_jsonable_python turns what model_dump() leaves as Python objects (datetime,
        # Path, enums, models) into JSON values, so the simulator may pass either dump mode.
        return json.dumps(to_jsonable_python(metadata), sort_keys=True, allow_nan=False)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"the recording metadata cannot be written as JSON: {exc}") from None


class _McapWriter(RecordingWriter):
    """Everything, as JSON messages on MCAP channels (docs/recording-format.md)."""

    def __init__(self, path: Path, metadata: dict[str, Any]) -> None:
        super().__init__()
        # Before opening the file: bad metadata must not leave an empty recording behind.
        scenario = _metadata_json(metadata)
        self._stream: IO[bytes] = open(path, "wb")  # noqa: SIM115 - closed by close()
        try:
            self._writer = start_mcap(self._stream, _CHUNK_SIZE)
            self._writer.add_metadata("scenario", {"json": scenario})
            self._writer.add_metadata("format", {"name": FORMAT_NAME, "version": FORMAT_VERSION})
            self._schemas: dict[type[BaseModel], int] = {
                model: self._writer.register_schema(
                    name=schema_name(model),
                    encoding="jsonschema",
                    data=json.dumps(json_schema(model), separators=(",", ":")).encode(),
                )
                for model in MESSAGE_MODELS
            }
            # Truth channels exist from the start, even when a run never fills one, so that
            # a reader can tell "none happened" from "not recorded".
            self._channels: dict[str, int] = {
                topic: self._writer.register_channel(topic, "json", self._schemas[model])
                for topic, model in _TRUTH_CHANNELS
            }
        except BaseException:
            self._stream.close()
            raise
        self._sequences: dict[tuple[str, str], int] = {}

    def _add(self, key: tuple[str, str], channel: int, log_time: int, message: BaseModel) -> None:
        sequence = self._sequences.get(key, 0)
        self._sequences[key] = sequence + 1
        self._writer.add_message(
            channel_id=channel,
            log_time=log_time,
            data=message.model_dump_json().encode(),
            publish_time=log_time,
            sequence=sequence % _MAX_SEQUENCE,
        )

    def datagram(
        self,
        source: str,
        time: float,
        payload: bytes,
        lan: str,
        src: tuple[str, int],
        dst: tuple[str, int],
    ) -> None:
        self._check_open()
        log_time, src_text, dst_text = _check_datagram(source, time, payload, lan, src, dst)
        topic = asterix_topic(source)
        channel = self._channels.get(topic)
        if channel is None:
            channel = self._writer.register_channel(
                topic, "json", self._schemas[AsterixDatagram], {"source": source}
            )
            self._channels[topic] = channel
        message = AsterixDatagram.model_validate(
            {
                "source": source,
                "lan": lan,
                "src": src_text,
                "dst": dst_text,
                "payload": bytes(payload).hex(),
            }
        )
        # Counted per LAN, so that a LAN A message's sequence is the datagram number
        # /truth/plots refers to.
        self._add((topic, lan), channel, log_time, message)

    def truth(self, time: float, aircraft: list[dict[str, Any]]) -> None:
        self._check_open()
        message = TruthAircraft.model_validate({"time": time, "aircraft": aircraft})
        self._add_truth(TRUTH_AIRCRAFT, time, message)

    def plot_origins(
        self, source: str, time: float, sequence: int, records: list[dict[str, Any]]
    ) -> None:
        self._check_open()
        message = TruthPlots.model_validate(
            {"source": source, "time": time, "sequence": sequence, "records": records}
        )
        self._add_truth(TRUTH_PLOTS, time, message)

    def biases(self, source: str, time: float, values: dict[str, float]) -> None:
        self._check_open()
        clash = {"source", "time"} & values.keys()
        if clash:
            raise ValueError(f"biases values must not hold {sorted(clash)}: they are arguments")
        message = TruthBiases.model_validate({"source": source, "time": time, **values})
        self._add_truth(TRUTH_BIASES, time, message)

    def coverage(self, source: str, time: float, scan: int, aircraft: list[int]) -> None:
        self._check_open()
        message = TruthCoverage.model_validate(
            {"source": source, "time": time, "scan": scan, "aircraft": aircraft}
        )
        self._add_truth(TRUTH_COVERAGE, time, message)

    def _add_truth(self, topic: str, time: float, message: BaseModel) -> None:
        self._add((topic, ""), self._channels[topic], time_ns(time), message)

    def close(self) -> None:
        if not self._closed:
            try:
                # mcap-python leaves finish() unannotated.
                self._writer.finish()  # type: ignore[no-untyped-call]
            finally:
                self._stream.close()
        super().close()


def open_writer(path: str | Path, metadata: dict[str, Any]) -> RecordingWriter:
    """A writer for ``path``, its format chosen by the suffix (see :data:`SUFFIXES`).

    ``metadata`` (the scenario's dump, seed, ...) goes into an MCAP recording; the other
    formats keep the datagrams only, both LANs' copies, as a capture would hold them.
    """
    file = Path(path)
    suffix = file.suffix.lower()
    if suffix == ".mcap":
        return _McapWriter(file, metadata)
    if suffix == ".pcap":
        return _PcapWriter(file)
    if suffix in (".raw", ".ast"):
        return _RawWriter(file)
    if suffix == ".hex":
        return _HexWriter(file)
    raise ValueError(
        f"{file}: unknown recording suffix {file.suffix or '(none)'!r}; "
        f"use one of {', '.join(SUFFIXES)}"
    )


# ---------------------------------------------------------------------------
# Reader
# ---------------------------------------------------------------------------

_MCAP_MAGIC = b"\x89MCAP0\r\n"
_SNIFF_SIZE = 64 * 1024


def is_mcap(path: str | Path) -> bool:
    """Whether the file is an MCAP recording (by its magic bytes, not its name)."""
    with Path(path).open("rb") as stream:
        return stream.read(len(_MCAP_MAGIC)) == _MCAP_MAGIC


class RecordedDatagram(NamedTuple):
    source: str
    """SAC/SIC, e.g. "25/11"."""
    time: float
    """Reception time, POSIX seconds."""
    lan: str
    """"A" or "B"."""
    src: tuple[str, int]
    dst: tuple[str, int]
    payload: bytes


@dataclass(frozen=True)
class Recording:
    """An MCAP recording; each iteration reads the file anew, so memory stays small."""

    metadata: dict[str, Any]
    """The "scenario" metadata record, parsed."""
    path: Path
    topics: tuple[str, ...]
    """Every channel's topic, in the order of the file's channel ids."""

    @property
    def sources(self) -> list[str]:
        """The sources with at least one datagram, as "SAC/SIC", sorted by (SAC, SIC)."""
        found = [
            topic.removeprefix(_ASTERIX_PREFIX).split("_")
            for topic in self.topics
            if topic.startswith(_ASTERIX_PREFIX)
        ]
        return [f"{sac}/{sic}" for sac, sic in sorted(found, key=lambda p: (int(p[0]), int(p[1])))]

    def datagrams(self, sources: Iterable[str] | None = None) -> Iterator[RecordedDatagram]:
        """Every datagram (of ``sources`` only, when given), in log-time order; ties keep
        the file's order, which is the order the simulator wrote them in."""
        if sources is None:
            topics = [t for t in self.topics if t.startswith(_ASTERIX_PREFIX)]
        else:
            wanted = [asterix_topic(source) for source in sources]
            missing = [t for t in wanted if t not in self.topics]
            if missing:
                raise ValueError(
                    f"{self.path}: no datagrams of {missing}; its sources are {self.sources}"
                )
            topics = wanted
        for log_time, doc in self._iter(topics):
            yield RecordedDatagram(
                source=doc["source"],
                # int / int is correctly rounded, so the writer's float comes back exactly.
                time=log_time / NS_PER_S,
                lan=doc["lan"],
                src=_parse_endpoint(doc["src"]),
                dst=_parse_endpoint(doc["dst"]),
                payload=bytes.fromhex(doc["payload"]),
            )

    def messages(self, topic: str) -> Iterator[dict[str, Any]]:
        """The parsed JSON messages of one channel (e.g. "/truth/plots"), in log-time order."""
        if topic not in self.topics:
            raise ValueError(f"{self.path}: no channel {topic!r}; it has {list(self.topics)}")
        for _log_time, doc in self._iter([topic]):
            yield doc

    def _iter(self, topics: list[str]) -> Iterator[tuple[int, dict[str, Any]]]:
        if not topics:
            # mcap reads an empty topic list as "no filter".
            return
        with open(self.path, "rb") as stream:
            reader = make_reader(stream, validate_crcs=True)
            for _schema, _channel, message in reader.iter_messages(
                topics=topics, log_time_order=True
            ):
                yield message.log_time, json.loads(message.data)


def read_recording(path: str | Path) -> Recording:
    """Opens an MCAP recording written by :func:`open_writer`.

    Raises ValueError for anything else: other captures hold datagrams only and are read
    with ``asterix.containers.read_file``.
    """
    file = Path(path)
    with open(file, "rb") as stream:
        head = stream.read(_SNIFF_SIZE)
        if not head.startswith(_MCAP_MAGIC):
            raise ValueError(
                f"{file} is not an MCAP recording (its content looks like "
                f"{detect_format(head)}); read the datagrams of other captures with "
                "asterix.containers.read_file"
            )
        stream.seek(0)
        try:
            reader = make_reader(stream, validate_crcs=True)
            summary = reader.get_summary()
            records = {record.name: record.metadata for record in reader.iter_metadata()}
        # OSError: a file too short for a footer makes the reader seek before its start.
        except (McapError, EOFError, ValueError, OSError) as exc:
            raise ValueError(
                f"{file}: unreadable MCAP ({exc}); was the recording closed?"
            ) from None
    if summary is None:
        raise ValueError(f"{file}: the MCAP has no summary; was the recording closed?")
    fmt = records.get("format", {})
    if fmt.get("name") != FORMAT_NAME or fmt.get("version") != FORMAT_VERSION:
        raise ValueError(
            f"{file}: not a {FORMAT_NAME!r} recording of version {FORMAT_VERSION} "
            f"(its format metadata is {fmt or 'missing'})"
        )
    if "scenario" not in records or "json" not in records["scenario"]:
        raise ValueError(f"{file}: the 'scenario' metadata record is missing")
    metadata = json.loads(records["scenario"]["json"])
    topics = tuple(summary.channels[i].topic for i in sorted(summary.channels))
    return Recording(metadata=metadata, path=file, topics=topics)


_LOG_DATAGRAM_PREFIX = "/datagrams/"


def _endpoint_or_none(text: object) -> tuple[str, int] | None:
    return _parse_endpoint(text) if isinstance(text, str) else None


def stream_datagrams(path: str | Path) -> Iterator[Datagram | ContainerError]:
    """The datagrams of an MCAP file, a simulator recording (``/asterix/*``) or a log of the
    service (``/datagrams/*``), read from its start in file order (which is their
    reception order) with one chunk in memory at a time.

    Nothing raises for what the file holds: a file cut short (a writer killed, a disk
    full), cut inside its header or damaged gives the datagrams before the damage and
    then a ``ContainerError`` saying where and why reading stopped; a message that is not
    a datagram record is a ``ContainerError`` too, and reading goes on. ``offset`` counts
    the datagrams; an error's offset is the byte where reading stopped."""
    number = 0
    with open(path, "rb") as stream:
        channels: dict[int, Channel] = {}
        records = StreamReader(stream, validate_crcs=True).records
        while True:
            try:
                record = next(records)
            except StopIteration:
                return
            except EndOfFile:
                yield ContainerError(
                    stream.tell(),
                    "MCAP file ends inside a record (cut short: was its writer killed?); "
                    f"{number} datagrams read before",
                )
                return
            # McapError: bad magic, CRC, record; the others: whatever a damaged length or
            # compressed chunk makes the reader or its decompressor raise.
            except Exception as exc:
                yield ContainerError(
                    stream.tell(),
                    f"MCAP unreadable from here ({type(exc).__name__}: {exc}); "
                    f"{number} datagrams read before",
                )
                return
            if isinstance(record, Channel):
                channels[record.id] = record
                continue
            if not isinstance(record, Message):
                continue
            channel = channels.get(record.channel_id)
            if channel is None or not channel.topic.startswith(
                (_ASTERIX_PREFIX, _LOG_DATAGRAM_PREFIX)
            ):
                continue
            try:
                doc = json.loads(record.data)
                payload = bytes.fromhex(doc["payload"])
                # A log's reception time is its "time" exactly; a recording's is the log
                # time (int / int is correctly rounded).
                received = float(doc["time"]) if "time" in doc else record.log_time / NS_PER_S
                datagram = Datagram(
                    payload,
                    number,
                    received,
                    _endpoint_or_none(doc.get("src")),
                    _endpoint_or_none(doc.get("dst")),
                )
            except (ValueError, KeyError, TypeError) as exc:
                yield ContainerError(
                    number, f"message on {channel.topic} is not a datagram record ({exc})"
                )
                continue
            number += 1
            yield datagram
