"""Tests for asterix.containers: detection, every container path, robustness."""

from __future__ import annotations

import datetime as dt
import io
import json
import struct
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from asterix.containers import (
    FORMATS,
    ContainerError,
    Datagram,
    detect_format,
    read_datagrams,
    read_file,
    write_pcap,
)

DATA_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "asterix"

CAT048_BLOCK = bytes.fromhex("300008") + b"\x01\x02\x03\x04\x05"
CAT034_BLOCK = bytes.fromhex("220006") + b"\xaa\xbb\xcc"


def _real(relative: str) -> bytes:
    path = DATA_DIR / relative
    if not path.is_file():
        pytest.skip(f"sample data {path} is not available (shared data directory absent)")
    return path.read_bytes()


def _datagrams(items: list[Datagram | ContainerError]) -> list[Datagram]:
    return [item for item in items if isinstance(item, Datagram)]


def _errors(items: list[Datagram | ContainerError]) -> list[ContainerError]:
    return [item for item in items if isinstance(item, ContainerError)]


def _count_blocks(payload: bytes) -> int:
    count = pos = 0
    while pos < len(payload):
        length = int.from_bytes(payload[pos + 1 : pos + 3], "big")
        assert length >= 3
        pos += length
        count += 1
    assert pos == len(payload)
    return count


# ---------------------------------------------------------------------------
# Synthetic capture builders (independent of the module's own writer)
# ---------------------------------------------------------------------------


def ipv4_udp(
    payload: bytes,
    src: str = "10.0.0.1",
    dst: str = "232.1.1.1",
    sport: int = 4000,
    dport: int = 5000,
    *,
    proto: int = 17,
    frag: int = 0x4000,
    options: bytes = b"",
    udp_len: int | None = None,
) -> bytes:
    ihl = 5 + len(options) // 4
    udp = struct.pack(">HHHH", sport, dport, udp_len or 8 + len(payload), 0) + payload
    header = struct.pack(
        ">BBHHHBBH4s4s",
        0x40 | ihl,
        0,
        ihl * 4 + len(udp),
        1,
        frag,
        64,
        proto,
        0,
        bytes(int(x) for x in src.split(".")),
        bytes(int(x) for x in dst.split(".")),
    )
    return header + options + udp


def ethernet(ip: bytes, *, vlans: int = 0, ethertype: int = 0x0800) -> bytes:
    tags = b"".join(struct.pack(">HH", 0x8100, 100 + i) for i in range(vlans))
    return (
        b"\x01\x00\x5e\x01\x01\x01"
        + b"\x02\x00\x0a\x00\x00\x01"
        + tags
        + struct.pack(">H", ethertype)
        + ip
    )


def sll(ip: bytes) -> bytes:
    return struct.pack(">HHH8sH", 0, 1, 6, b"\x02\x00\x0a\x00\x00\x01\x00\x00", 0x0800) + ip


def sll2(ip: bytes) -> bytes:
    return struct.pack(">HHIHBB8s", 0x0800, 0, 2, 1, 0, 6, b"\x02" * 8) + ip


def pcap(
    frames: list[tuple[int, int, bytes]],
    *,
    link: int = 1,
    order: str = "<",
    nano: bool = False,
) -> bytes:
    magic = 0xA1B23C4D if nano else 0xA1B2C3D4
    out = struct.pack(order + "IHHiIII", magic, 2, 4, 0, 0, 65535, link)
    for sec, frac, frame in frames:
        out += struct.pack(order + "IIII", sec, frac, len(frame), len(frame)) + frame
    return out


def _pad4(raw: bytes) -> bytes:
    return raw + b"\x00" * (-len(raw) % 4)


def pcapng_block(order: str, block_type: int, body: bytes) -> bytes:
    body = _pad4(body)
    length = 12 + len(body)
    return struct.pack(order + "II", block_type, length) + body + struct.pack(order + "I", length)


def pcapng_shb(order: str) -> bytes:
    body = struct.pack(order + "IHHq", 0x1A2B3C4D, 1, 0, -1)
    return pcapng_block(order, 0x0A0D0D0A, body)


def pcapng_idb(order: str, link: int, tsresol: int | None = None) -> bytes:
    body = struct.pack(order + "HHI", link, 0, 65535)
    if tsresol is not None:
        body += struct.pack(order + "HH", 9, 1) + _pad4(bytes([tsresol]))
        body += struct.pack(order + "HH", 0, 0)
    return pcapng_block(order, 1, body)


def pcapng_epb(order: str, iface: int, ticks: int, frame: bytes) -> bytes:
    body = struct.pack(
        order + "IIIII", iface, ticks >> 32, ticks & 0xFFFFFFFF, len(frame), len(frame)
    )
    return pcapng_block(order, 6, body + frame)


def pcapng_spb(order: str, frame: bytes) -> bytes:
    return pcapng_block(order, 3, struct.pack(order + "I", len(frame)) + frame)


def gps_file(blocks: list[tuple[bytes, int]], fill: int = 0xCD) -> bytes:
    out = bytes([fill]) * 2200
    for block, ticks in blocks:
        out += block + b"\x00" * 6 + ticks.to_bytes(3, "big") + b"\x00"
    return out


def final_frame(content: bytes, ticks: int = 0) -> bytes:
    length = 2 + 6 + len(content) + 4
    return (
        length.to_bytes(2, "big")
        + b"\x00\x00\x00"
        + ticks.to_bytes(3, "big")
        + content
        + (b"\xa5" * 4)
    )


# ---------------------------------------------------------------------------
# Real recordings
# ---------------------------------------------------------------------------

REAL_FORMATS = {
    "croatiacontrol/cat048.raw": ("raw", 1),
    "croatiacontrol/cat034.raw": ("raw", 1),
    "croatiacontrol/cat062cat065.raw": ("raw", 2),
    "croatiacontrol/cat21_re.ast": ("raw", 2),
    "croatiacontrol/cat_034_048.pcap": ("pcap", 100),
    "croatiacontrol/cat_062_065.pcap": ("pcap", 1),
    "croatiacontrol/parsegps.gps": ("gps", 15),
    "reader_network/068test_bds30.gps": ("gps", 2781),
    "reader_network/066test_filter.gps": ("gps", 3),
    "jade/final_frame_cat062_one_packet.ff": ("final", 1),
    "jade/final_frame_062_one_packet_sample2.FF": ("final", 1),
    "jasterix/cat048ed1.15.bin": ("raw", 1),
    "jasterix/cat048ed1.23.bin": ("raw", 1),
    "jasterix/cat034ed1.26.bin": ("raw", 1),
    "jasterix/cat062ed1.16.bin": ("raw", 1),
    "jasterix/cat021ed2.1.bin": ("raw", 1),
}


@pytest.mark.parametrize("relative", sorted(REAL_FORMATS))
def test_real_file_detected_and_unwrapped_cleanly(relative: str) -> None:
    data = _real(relative)
    fmt, count = REAL_FORMATS[relative]
    assert detect_format(data) == fmt
    items = list(read_file(DATA_DIR / relative))
    assert _errors(items) == []
    datagrams = _datagrams(items)
    assert len(datagrams) == count
    for datagram in datagrams:
        assert data[datagram.offset : datagram.offset + len(datagram.payload)] == datagram.payload
        _count_blocks(datagram.payload)


def test_real_pcap_times_and_addresses() -> None:
    _real("croatiacontrol/cat_034_048.pcap")
    datagrams = _datagrams(list(read_file(DATA_DIR / "croatiacontrol/cat_034_048.pcap")))
    assert len(datagrams) == 100
    times = [d.time for d in datagrams]
    assert all(t is not None for t in times)
    first = dt.datetime.fromtimestamp(min(t for t in times if t is not None), dt.UTC)
    last = dt.datetime.fromtimestamp(max(t for t in times if t is not None), dt.UTC)
    assert first >= dt.datetime(2016, 5, 5, 7, 35, 56, 500000, tzinfo=dt.UTC)
    assert last <= dt.datetime(2016, 5, 5, 7, 35, 56, 960000, tzinfo=dt.UTC)
    sources = {d.source[0] for d in datagrams if d.source}
    assert sources == {"10.17.58.183", "10.17.58.184"}
    for d in datagrams:
        assert d.source is not None and d.destination is not None
        group = "232.1.1." if d.source[0] == "10.17.58.183" else "232.2.1."
        assert d.destination[0].startswith(group)
    assert sum(_count_blocks(d.payload) for d in datagrams) == 120
    # Each payload is sent once per redundant LAN.
    assert len({d.payload for d in datagrams}) == 50
    assert datagrams[0].payload == _real("croatiacontrol/cat048.raw")


def test_real_gps_times_follow_i048_140() -> None:
    _real("reader_network/068test_bds30.gps")
    oracle = DATA_DIR / "oracle-full" / "068test_bds30.gps.jsonl"
    datagrams = _datagrams(list(read_file(DATA_DIR / "reader_network/068test_bds30.gps")))
    assert len(datagrams) == 2781
    assert datagrams[0].time == pytest.approx(30015.6, abs=0.5)
    assert datagrams[-1].time == pytest.approx(34756.3, abs=2.0)
    if not oracle.is_file():
        pytest.skip(f"oracle {oracle} is not available")
    tod: dict[int, float] = {}
    with oracle.open() as lines:
        for line in lines:
            record = json.loads(line)
            if record["cat"] == 48 and "140" in record["items"]:
                tod.setdefault(record["block"], record["items"]["140"])
    assert len(tod) == 1830
    for block, seconds in tod.items():
        received = datagrams[block - 1].time
        assert received is not None
        # Reception follows detection by a fraction of a second.
        assert 0.0 < received - seconds < 0.5


def test_real_parsegps_times() -> None:
    datagrams = _datagrams(list(read_datagrams(_real("croatiacontrol/parsegps.gps"))))
    assert len(datagrams) == 15
    assert Counter(d.payload[0] for d in datagrams) == {48: 12, 34: 3}
    times = [d.time for d in datagrams if d.time is not None]
    assert len(times) == 15
    assert min(times) >= 1.48 and max(times) <= 13.0


def test_real_final_format() -> None:
    data = _real("jade/final_frame_062_one_packet_sample2.FF")
    (datagram,) = list(read_datagrams(data))
    assert isinstance(datagram, Datagram)
    assert datagram.offset == 8
    assert datagram.payload == data[8:-4]
    assert [datagram.payload[0], _count_blocks(datagram.payload)] == [62, 2]
    # The recorder's 24-bit clock in 10 ms units (board, line, day come before it).
    assert datagram.time == 57563.0
    one = _real("jade/final_frame_cat062_one_packet.ff")
    (single,) = _datagrams(list(read_datagrams(one)))
    assert single.payload[0] == 62 and len(single.payload) == 58
    assert single.time == 60356.0


# ---------------------------------------------------------------------------
# raw
# ---------------------------------------------------------------------------


def test_raw_blocks_and_offsets() -> None:
    data = CAT048_BLOCK + CAT034_BLOCK + CAT048_BLOCK
    items = list(read_datagrams(data, "raw"))
    assert [(d.offset, d.payload) for d in _datagrams(items)] == [
        (0, CAT048_BLOCK),
        (8, CAT034_BLOCK),
        (14, CAT048_BLOCK),
    ]
    assert all(d.time is None and d.source is None for d in _datagrams(items))


def test_raw_resynchronises_after_garbage() -> None:
    garbage = b"\x00\x00\x01\xff"
    data = CAT048_BLOCK + garbage + CAT034_BLOCK + CAT048_BLOCK + CAT034_BLOCK
    items = list(read_datagrams(data, "raw"))
    assert isinstance(items[1], ContainerError)
    assert items[1].offset == 8
    assert "resynchronised at offset 12" in items[1].reason
    assert [d.offset for d in _datagrams(items)] == [0, 12, 18, 26]


def test_raw_length_past_end_and_trailing_bytes() -> None:
    data = CAT048_BLOCK + b"\x30\x10\x00\x01"
    items = list(read_datagrams(data, "raw"))
    assert len(_datagrams(items)) == 1
    (error,) = _errors(items)
    assert error.offset == 8 and "past the end" in error.reason
    items = list(read_datagrams(CAT048_BLOCK + b"\x30\x00", "raw"))
    assert _errors(items) == [ContainerError(8, _errors(items)[0].reason)]
    assert "trailing" in _errors(items)[0].reason


def test_raw_resync_is_linear() -> None:
    data = b"\x00" * 2_000_000 + CAT048_BLOCK * 3
    start = time.perf_counter()
    items = list(read_datagrams(data, "raw"))
    assert time.perf_counter() - start < 10
    assert len(_errors(items)) == 1
    assert [d.offset for d in _datagrams(items)] == [2_000_000, 2_000_008, 2_000_016]


# ---------------------------------------------------------------------------
# GPS
# ---------------------------------------------------------------------------


def test_gps_synthetic_both_fills() -> None:
    for fill in (0xCD, 0x20):
        data = gps_file([(CAT048_BLOCK, 128 * 100 + 64), (CAT034_BLOCK, 128 * 101)], fill)
        assert detect_format(data) == "gps"
        datagrams = _datagrams(list(read_datagrams(data)))
        assert [(d.offset, d.payload, d.time) for d in datagrams] == [
            (2200, CAT048_BLOCK, 100.5),
            (2218, CAT034_BLOCK, 101.0),
        ]


def test_gps_errors() -> None:
    data = gps_file([(CAT048_BLOCK, 1), (CAT034_BLOCK, 2), (CAT048_BLOCK, 3)])
    # Corrupt the second block's length, then cut the last post bytes.
    broken = bytearray(data)
    broken[2218 + 1 : 2218 + 3] = b"\x00\x01"
    items = list(read_datagrams(bytes(broken[:-3]), "gps"))
    errors = _errors(items)
    assert [d.offset for d in _datagrams(items)] == [2200]
    assert errors[0].offset == 2218
    assert list(read_datagrams(b"\xcd" * 100, "gps")) == [
        ContainerError(0, "100 bytes, shorter than the 2200-byte GPS header")
    ]


def test_gps_resync_skips_to_next_block() -> None:
    blocks = [(CAT048_BLOCK, i) for i in range(5)]
    data = bytearray(gps_file(blocks))
    data[2200 + 18 + 1] = 0xFF  # second unit claims a huge length
    items = list(read_datagrams(bytes(data), "gps"))
    assert [d.time for d in _datagrams(items)] == [0 / 128, 2 / 128, 3 / 128, 4 / 128]
    assert len(_errors(items)) == 1


# ---------------------------------------------------------------------------
# Final Format
# ---------------------------------------------------------------------------


def test_final_synthetic_frames_and_resync() -> None:
    frames = [final_frame(CAT048_BLOCK + CAT034_BLOCK, 100), final_frame(CAT034_BLOCK, 200)]
    data = b"".join(frames)
    assert detect_format(data) == "final"
    datagrams = _datagrams(list(read_datagrams(data)))
    assert [(d.offset, d.payload) for d in datagrams] == [
        (8, CAT048_BLOCK + CAT034_BLOCK),
        (len(frames[0]) + 8, CAT034_BLOCK),
    ]
    corrupt = bytearray(frames[0] + frames[0] + frames[1])
    corrupt[len(frames[0]) + 1] ^= 0x40  # second frame's LEN no longer meets its trailer
    items = list(read_datagrams(bytes(corrupt), "final"))
    assert [type(i).__name__ for i in items] == ["Datagram", "ContainerError", "Datagram"]
    assert items[2].offset == 2 * len(frames[0]) + 8


def test_final_bad_trailer_detection() -> None:
    frame = bytearray(final_frame(CAT048_BLOCK))
    frame[-1] = 0
    assert detect_format(bytes(frame)) == "raw"
    (error,) = list(read_datagrams(bytes(frame), "final"))
    assert isinstance(error, ContainerError)
    assert error.offset == 0 and "trailer" in error.reason


# ---------------------------------------------------------------------------
# hex
# ---------------------------------------------------------------------------

HEX_TEXT = (
    b"# captured by hand\n"
    b"30 00 08 01 02 03 04 05\n"
    b"\n"
    b"0x22, 0x00, 0x06, 0xaa, 0xbb, 0xCC\r\n"
    b"  # indented comment\n"
    b"3000080102 03040 5\n"
    b"300008 0102030405  # trailing comment\n"
    b"not hex at all\n"
)


def test_hex_styles_offsets_and_errors() -> None:
    assert detect_format(HEX_TEXT) == "hex"
    items = list(read_datagrams(HEX_TEXT))
    lines = HEX_TEXT.split(b"\n")
    offsets = [sum(len(line) + 1 for line in lines[:i]) for i in range(len(lines))]
    assert items == [
        Datagram(CAT048_BLOCK, offsets[1], None, None, None),
        Datagram(CAT034_BLOCK, offsets[3], None, None, None),
        ContainerError(offsets[5], "line 6 is not hex bytes"),
        Datagram(CAT048_BLOCK, offsets[6], None, None, None),
        ContainerError(offsets[7], "line 8 is not hex bytes"),
    ]


def test_hex_offset_prefixed_dump_is_not_silently_misread() -> None:
    items = list(read_datagrams(b"0000: 30 00 08\n", "hex"))
    assert items == [ContainerError(0, "line 1 is not hex bytes")]


def test_binary_is_not_hex() -> None:
    assert detect_format(CAT048_BLOCK) == "raw"
    assert detect_format(b"hello world\nthis is prose\n") == "raw"


# ---------------------------------------------------------------------------
# pcap and pcapng link layers
# ---------------------------------------------------------------------------


def _single(data: bytes, fmt: str | None = None) -> Datagram:
    items = list(read_datagrams(data, fmt))
    assert _errors(items) == []
    (datagram,) = _datagrams(items)
    assert data[datagram.offset : datagram.offset + len(datagram.payload)] == datagram.payload
    return datagram


def test_pcap_ethernet_vlan_and_ip_options() -> None:
    ip = ipv4_udp(CAT048_BLOCK, options=b"\x01\x01\x01\x00")
    data = pcap([(1_600_000_000, 250_000, ethernet(ip, vlans=2) + b"\x00" * 6)])
    datagram = _single(data)
    assert datagram.payload == CAT048_BLOCK
    assert datagram.time == pytest.approx(1_600_000_000.25)
    assert datagram.source == ("10.0.0.1", 4000)
    assert datagram.destination == ("232.1.1.1", 5000)


@pytest.mark.parametrize(
    ("link", "wrap"),
    [
        (113, sll),
        (276, sll2),
        (101, lambda ip: ip),
        (228, lambda ip: ip),
        (0, lambda ip: b"\x02\x00\x00\x00" + ip),
        (108, lambda ip: b"\x00\x00\x00\x02" + ip),
    ],
)
def test_pcap_other_link_types(link: int, wrap: Callable[[bytes], bytes]) -> None:
    frame = wrap(ipv4_udp(CAT034_BLOCK, src="192.168.1.2", sport=1, dport=2))
    datagram = _single(pcap([(10, 5, frame)], link=link))
    assert datagram.payload == CAT034_BLOCK
    assert datagram.source == ("192.168.1.2", 1)


def test_pcap_big_endian_nanosecond() -> None:
    frame = ethernet(ipv4_udp(CAT048_BLOCK))
    data = pcap([(1_462_433_756, 508_910_123, frame)], order=">", nano=True)
    assert detect_format(data) == "pcap"
    datagram = _single(data)
    assert datagram.time == pytest.approx(1_462_433_756.508910123, abs=1e-6)


def test_pcap_skips_and_errors() -> None:
    frames = [
        ethernet(b"\x60" + b"\x00" * 39, ethertype=0x86DD),  # IPv6: skipped
        ethernet(b"\x00" * 28, ethertype=0x0806),  # ARP: skipped
        ethernet(ipv4_udp(CAT048_BLOCK, proto=6)),  # TCP: skipped
        ethernet(ipv4_udp(b"")),  # empty UDP: skipped
        ethernet(ipv4_udp(CAT048_BLOCK, frag=0x2000)),  # first fragment
        ethernet(ipv4_udp(CAT048_BLOCK, udp_len=200)),  # UDP longer than captured
        ethernet(ipv4_udp(CAT048_BLOCK))[:30],  # truncated IPv4
        b"\x01\x02",  # truncated Ethernet
        ethernet(ipv4_udp(CAT034_BLOCK)),
    ]
    items = list(read_datagrams(pcap([(1, 0, f) for f in frames])))
    reasons = [item.reason for item in _errors(items)]
    assert reasons[0] == "IP fragment not reassembled"
    assert "truncated" in reasons[1]
    assert reasons[2:] == ["truncated IPv4 header", "truncated Ethernet header"]
    assert [d.payload for d in _datagrams(items)] == [CAT034_BLOCK]


def test_pcap_truncated_record_and_unsupported_link() -> None:
    data = pcap([(1, 0, ethernet(ipv4_udp(CAT048_BLOCK)))] * 2)
    items = list(read_datagrams(data[:-5]))
    assert len(_datagrams(items)) == 1
    assert "past the end" in _errors(items)[0].reason
    items = list(read_datagrams(pcap([(1, 0, b"x" * 40)], link=147)))
    assert items == [ContainerError(20, "unsupported link type 147; no packet can be read")]
    assert list(read_datagrams(data[:10])) == [ContainerError(0, "truncated pcap file header")]


@pytest.mark.parametrize("order", ["<", ">"])
def test_pcapng_idb_epb_spb(order: str) -> None:
    frame = ethernet(ipv4_udp(CAT048_BLOCK, src="10.17.58.183", sport=20124))
    ticks_us = 1_462_433_756_508_910
    data = (
        pcapng_shb(order)
        + pcapng_idb(order, 1)  # default microseconds
        + pcapng_idb(order, 113, tsresol=9)  # nanoseconds
        + pcapng_idb(order, 1, tsresol=0x80 | 10)  # 2^-10 s
        + pcapng_block(order, 5, b"statistics")  # unknown to us: skipped
        + pcapng_epb(order, 0, ticks_us, frame)
        + pcapng_epb(order, 1, ticks_us * 1000 + 123, sll(ipv4_udp(CAT034_BLOCK)))
        + pcapng_epb(order, 2, 1024 * 5 + 512, frame)
        + pcapng_spb(order, frame)
        + pcapng_epb(order, 7, 0, frame)
    )
    assert detect_format(data) == "pcapng"
    items = list(read_datagrams(data))
    datagrams = _datagrams(items)
    assert [d.payload for d in datagrams] == [CAT048_BLOCK, CAT034_BLOCK] + [CAT048_BLOCK] * 2
    assert datagrams[0].time == pytest.approx(1_462_433_756.508910, abs=1e-6)
    assert datagrams[1].time == pytest.approx(1_462_433_756.508910123, abs=1e-6)
    assert datagrams[2].time == 5.5
    assert datagrams[3].time is None
    assert datagrams[0].source == ("10.17.58.183", 20124)
    for d in datagrams:
        assert data[d.offset : d.offset + len(d.payload)] == d.payload
    assert [e.reason for e in _errors(items)] == ["packet refers to undeclared interface 7"]


def test_pcapng_malformed_blocks() -> None:
    order = "<"
    good = pcapng_shb(order) + pcapng_idb(order, 1)
    frame = ethernet(ipv4_udp(CAT048_BLOCK))
    epb = bytearray(pcapng_epb(order, 0, 0, frame))
    epb[-4:] = b"\x00\x00\x00\x00"  # trailing length disagrees
    items = list(read_datagrams(good + bytes(epb) + pcapng_epb(order, 0, 0, frame)))
    assert [type(i).__name__ for i in items] == ["ContainerError", "Datagram"]
    items = list(read_datagrams(good + struct.pack("<II", 6, 4) + b"\x00" * 8))
    assert items == [ContainerError(len(good), "impossible pcapng block length 4")]
    bad_bom = bytearray(pcapng_shb(order))
    bad_bom[8:12] = b"\x00\x00\x00\x00"
    assert list(read_datagrams(bytes(bad_bom))) == [
        ContainerError(0, "bad pcapng byte-order magic")
    ]
    items = list(read_datagrams(pcapng_shb(order) + pcapng_idb(order, 147)))
    assert "unsupported link type 147" in _errors(items)[0].reason


# ---------------------------------------------------------------------------
# write_pcap
# ---------------------------------------------------------------------------


def _checksum_ok(chunk: bytes) -> bool:
    if len(chunk) % 2:
        chunk += b"\x00"
    total: int = sum(struct.unpack(f">{len(chunk) // 2}H", chunk))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return total == 0xFFFF


def test_write_pcap_round_trip(tmp_path: Path) -> None:
    packets = [
        (1_462_433_756.508910, ("10.17.58.183", 20124), ("232.1.1.31", 21131), CAT048_BLOCK),
        (1_462_433_756.999_999_7, ("10.17.58.184", 21124), ("10.0.0.9", 22131), CAT034_BLOCK),
        (5.0, ("127.0.0.1", 1), ("255.255.255.255", 2), CAT048_BLOCK + CAT034_BLOCK + b"\x00"),
    ]
    path = tmp_path / "out.pcap"
    assert write_pcap(path, packets) == 3
    data = path.read_bytes()
    assert detect_format(data) == "pcap"
    datagrams = _datagrams(list(read_file(str(path))))
    assert [(d.source, d.destination, d.payload) for d in datagrams] == [
        (p[1], p[2], p[3]) for p in packets
    ]
    for datagram, packet in zip(datagrams, packets, strict=True):
        assert datagram.time == pytest.approx(packet[0], abs=1e-6)
    # Multicast destination MAC follows RFC 1112.
    assert data[40:46] == bytes.fromhex("01005e01011f")
    # Header and UDP checksums verify.
    frame = data[40 : 40 + 14 + 20 + 8 + len(CAT048_BLOCK)]
    ip = frame[14:34]
    assert _checksum_ok(ip)
    pseudo = ip[12:20] + struct.pack(">BBH", 0, 17, 8 + len(CAT048_BLOCK))
    assert _checksum_ok(pseudo + frame[34:])

    stream = io.BytesIO()
    assert write_pcap(stream, packets) == 3
    assert stream.getvalue() == data


@pytest.mark.parametrize(
    "packet",
    [
        (-1.0, ("1.2.3.4", 1), ("1.2.3.4", 2), b"x"),
        (1.0, ("1.2.3", 1), ("1.2.3.4", 2), b"x"),
        (1.0, ("1.2.3.4", 70000), ("1.2.3.4", 2), b"x"),
        (1.0, ("1.2.3.4", 1), ("1.2.3.4", 2), b"x" * 70000),
    ],
)
def test_write_pcap_rejects_unencodable(
    packet: tuple[float, tuple[str, int], tuple[str, int], bytes],
) -> None:
    with pytest.raises(ValueError):
        write_pcap(io.BytesIO(), [packet])


# ---------------------------------------------------------------------------
# API contract and robustness
# ---------------------------------------------------------------------------


def test_unknown_format_raises_at_call_time(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="unknown container format"):
        read_datagrams(b"", "csv")
    with pytest.raises(ValueError, match="unknown container format"):
        read_file(tmp_path / "missing", "csv")


def test_empty_and_tiny_inputs() -> None:
    for fmt in (None, *FORMATS):
        for data in (b"", b"\x00", b"\xd4\xc3\xb2\xa1", b"\x0a\x0d\x0d\x0a"):
            list(read_datagrams(data, fmt))
    assert detect_format(b"") == "raw"
    assert list(read_datagrams(b"")) == []


def _check_invariants(data: bytes, fmt: str | None) -> None:
    total = 0
    for item in read_datagrams(data, fmt):
        assert isinstance(item, (Datagram, ContainerError))
        assert 0 <= item.offset <= len(data)
        if isinstance(item, Datagram):
            total += len(item.payload)
            if (fmt or detect_format(data)) != "hex":
                end = item.offset + len(item.payload)
                assert data[item.offset : end] == item.payload
    assert total <= len(data)


def _synthetic_corpus() -> list[bytes]:
    frame = ethernet(ipv4_udp(CAT048_BLOCK + CAT034_BLOCK))
    return [
        pcap([(1, 2, frame), (3, 4, sll(ipv4_udp(CAT034_BLOCK)))]),
        pcap([(1, 2, frame)], order=">", nano=True),
        pcapng_shb("<") + pcapng_idb("<", 1, 9) + pcapng_epb("<", 0, 99, frame),
        pcapng_shb(">") + pcapng_idb(">", 1) + pcapng_spb(">", frame),
        gps_file([(CAT048_BLOCK, 5), (CAT034_BLOCK, 6)], 0x20),
        final_frame(CAT048_BLOCK) + final_frame(CAT034_BLOCK + CAT048_BLOCK),
        HEX_TEXT,
        CAT048_BLOCK + CAT034_BLOCK,
    ]


def _real_corpus() -> list[bytes]:
    corpus = []
    for relative in sorted(REAL_FORMATS):
        path = DATA_DIR / relative
        # Keep the fuzz fast: the long GPS recording adds nothing the short ones lack.
        if path.is_file() and path.stat().st_size < 20_000:
            corpus.append(path.read_bytes())
    return corpus


CORPUS = _synthetic_corpus() + _real_corpus()


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=4096), st.sampled_from([None, *FORMATS]))
def test_fuzz_random_bytes(data: bytes, fmt: str | None) -> None:
    _check_invariants(data, fmt)


@settings(max_examples=300, deadline=None)
@given(
    st.sampled_from(CORPUS),
    st.lists(
        st.tuples(
            st.sampled_from(["set", "insert", "delete", "truncate"]),
            st.integers(min_value=0, max_value=1 << 20),
            st.integers(min_value=0, max_value=255),
        ),
        min_size=1,
        max_size=8,
    ),
    st.sampled_from([None, *FORMATS]),
)
def test_fuzz_mutated_files(
    original: bytes, mutations: list[tuple[str, int, int]], fmt: str | None
) -> None:
    data = bytearray(original)
    for kind, where, value in mutations:
        if not data:
            break
        pos = where % len(data)
        if kind == "set":
            data[pos] = value
        elif kind == "insert":
            data[pos:pos] = bytes([value]) * (1 + value % 4)
        elif kind == "delete":
            del data[pos : pos + 1 + value % 16]
        else:
            del data[pos:]
    _check_invariants(bytes(data), fmt)
