"""Unwrap recorded ASTERIX captures into datagrams.

A recording wraps ASTERIX data blocks in some container: a network capture
(pcap, pcapng), a recorder format (GPS v1, Final Format), a hex text dump, or
nothing at all (raw). The container is detected from the content only, because
recordings are routinely renamed and extensions such as ``.ast`` or ``.bin``
are used for several of these formats.

Readers never raise on malformed input: every unit that cannot be unwrapped
becomes a :class:`ContainerError` and reading resumes at the next unit where the
format allows it. Payloads are copies of their slice of the input, made one at a
time as the reader advances.

:func:`read_file` streams: the file is memory-mapped, the format is judged from its
first MiB, and the pages behind the reader are handed back to the kernel as it goes,
so that a capture of any size is read in a bounded amount of memory (the largest unit
of the file, a hex line for instance, and a window of pages).
"""

from __future__ import annotations

import ipaddress
import mmap
import os
import re
import struct
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO, cast

__all__ = [
    "FORMATS",
    "ContainerError",
    "Datagram",
    "detect_format",
    "read_datagrams",
    "read_file",
    "write_pcap",
]

FORMATS: tuple[str, ...] = ("pcap", "pcapng", "gps", "final", "hex", "raw")


@dataclass(frozen=True, slots=True)
class Datagram:
    """One unit of ASTERIX data as it was received or recorded.

    ``payload`` holds one or more ASTERIX data blocks; the containers do not
    validate it beyond what their own framing requires, so the codec remains
    the single judge of block and record validity.

    ``offset`` is where the payload starts in the input (for hex text: where
    its line starts). ``time`` is the capture time in POSIX seconds for
    pcap/pcapng (None for pcapng simple packet blocks, which carry none), the
    recorded reception time of day in seconds for GPS, and None otherwise;
    see the Final Format notes for why that format gives None. ``source`` and
    ``destination`` are the UDP (ip, port) pairs for pcap/pcapng, else None.
    """

    payload: bytes
    offset: int
    time: float | None
    source: tuple[str, int] | None
    destination: tuple[str, int] | None


@dataclass(frozen=True, slots=True)
class ContainerError:
    """A unit of the container that could not be unwrapped."""

    offset: int
    reason: str


_Item = Datagram | ContainerError

_U16BE = struct.Struct(">H")


def _u16(data: bytes, pos: int) -> int:
    return (data[pos] << 8) | data[pos + 1]


# ---------------------------------------------------------------------------
# Shared helpers for data block chains
# ---------------------------------------------------------------------------


def _plausible_unit_end(data: bytes, pos: int, end: int, gap: int) -> int:
    """End of a plausible ``[data block][gap bytes]`` unit at ``pos``, or -1.

    Stricter than what the readers accept in sequence (CAT 0 and empty blocks
    are refused here) because it is used to pick a restart point out of
    garbage, where false positives are the main risk.
    """
    if pos + 3 > end or data[pos] == 0:
        return -1
    length = (data[pos + 1] << 8) | data[pos + 2]
    if length < 4:
        return -1
    unit_end = pos + length + gap
    return unit_end if unit_end <= end else -1


def _resync(data: bytes, start: int, end: int, gap: int) -> int | None:
    """First offset >= ``start`` where a believable chain of data blocks begins.

    A chain is believable when it reaches the end of the data exactly or when
    three plausible headers follow each other. Each candidate costs O(1), so a
    scan is linear in the skipped length.
    """
    for pos in range(start, end - 2):
        first = _plausible_unit_end(data, pos, end, gap)
        if first < 0:
            continue
        if first == end:
            return pos
        second = _plausible_unit_end(data, first, end, gap)
        if second < 0:
            continue
        if second == end or _plausible_unit_end(data, second, end, gap) >= 0:
            return pos
    return None


def _is_block_chain(data: bytes, start: int, end: int) -> bool:
    """Whether ``data[start:end]`` is exactly a non-empty sequence of data blocks."""
    if start >= end:
        return False
    pos = start
    while pos < end:
        if pos + 3 > end or data[pos] == 0:
            return False
        length = (data[pos + 1] << 8) | data[pos + 2]
        if length < 3:
            return False
        pos += length
    return pos == end


def _skip_note(bad: int, restart: int | None, end: int) -> str:
    if restart is None:
        return f"; no further data found, {end - bad} bytes skipped to the end"
    return f"; resynchronised at offset {restart} after skipping {restart - bad} bytes"


# ---------------------------------------------------------------------------
# raw
# ---------------------------------------------------------------------------


def _read_raw(data: bytes) -> Iterator[_Item]:
    end = len(data)
    pos = 0
    while pos < end:
        if end - pos < 3:
            yield ContainerError(pos, f"{end - pos} trailing bytes, too short for a block header")
            return
        length = (data[pos + 1] << 8) | data[pos + 2]
        if 3 <= length <= end - pos:
            yield Datagram(data[pos : pos + length], pos, None, None, None)
            pos += length
            continue
        if length < 3:
            reason = f"impossible data block length {length}"
        else:
            reason = f"data block length {length} runs past the end of the data"
        restart = _resync(data, pos + 1, end, 0)
        yield ContainerError(pos, reason + _skip_note(pos, restart, end))
        if restart is None:
            return
        pos = restart


# ---------------------------------------------------------------------------
# GPS v1
# ---------------------------------------------------------------------------

_GPS_HEADER = 2200
_GPS_POST = 10


def _read_gps(data: bytes) -> Iterator[_Item]:
    end = len(data)
    if end < _GPS_HEADER:
        yield ContainerError(0, f"{end} bytes, shorter than the {_GPS_HEADER}-byte GPS header")
        return
    pos = _GPS_HEADER
    while pos < end:
        if end - pos < 3:
            yield ContainerError(pos, f"{end - pos} trailing bytes, too short for a block header")
            return
        length = (data[pos + 1] << 8) | data[pos + 2]
        unit_end = pos + length + _GPS_POST
        if length >= 3 and unit_end <= end:
            # The post bytes 6..8 are a big-endian 24-bit count of 1/128 s:
            # Croatia Control's GPS reader decodes them so, and on
            # 068test_bds30.gps this time trails I048/140 of every CAT048 block
            # by 0.16-0.23 s (1830 blocks), i.e. it is the reception time.
            post = unit_end - _GPS_POST
            ticks = (data[post + 6] << 16) | (data[post + 7] << 8) | data[post + 8]
            yield Datagram(data[pos : pos + length], pos, ticks / 128.0, None, None)
            pos = unit_end
            continue
        if length < 3:
            reason = f"impossible data block length {length}"
        elif pos + length > end:
            reason = f"data block length {length} runs past the end of the data"
        else:
            reason = "data block is not followed by the 10 GPS post bytes"
        restart = _resync(data, pos + 1, end, _GPS_POST)
        yield ContainerError(pos, reason + _skip_note(pos, restart, end))
        if restart is None:
            return
        pos = restart


def _looks_like_gps(data: bytes) -> bool:
    if len(data) <= _GPS_HEADER:
        return False
    header = data[:_GPS_HEADER]
    if header.count(header[0]) != _GPS_HEADER:
        return False
    return _plausible_unit_end(data, _GPS_HEADER, len(data), _GPS_POST) >= 0


# ---------------------------------------------------------------------------
# Final Format
# ---------------------------------------------------------------------------

_FF_HEADER = 8  # LEN(2) + 6 header bytes
_FF_TRAILER = b"\xa5\xa5\xa5\xa5"
_FF_MIN_FRAME = _FF_HEADER + 3 + len(_FF_TRAILER)

# Header bytes after LEN: board, line, recording day, then a 24-bit time.
# Croatia Control's reader and JADE's documentation both give that layout and
# a 10 ms unit. The samples are consistent with the unit (both header times are
# whole seconds: 60356.00 s and 57563.00 s) but not with UTC: the CAT062 I070
# of the same frames is 53081.82 s and 28973.30 s, i.e. offsets of +7274.18 s
# and +28589.70 s that no single clock convention explains. It is still what the
# recorder wrote as the reception time, so Datagram.time carries it as is: a
# replay paces by it, and nothing takes it for the time of measurement.
_FF_TIME_UNIT = 0.01


def _final_frame_end(data: bytes, pos: int, end: int) -> int:
    """End of a Final Format frame at ``pos`` whose LEN and trailer agree, or -1."""
    if pos + 2 > end:
        return -1
    length = _u16(data, pos)
    frame_end = pos + length
    if length < _FF_MIN_FRAME or frame_end > end:
        return -1
    if data[frame_end - 4 : frame_end] != _FF_TRAILER:
        return -1
    return frame_end


def _final_resync(data: bytes, start: int, end: int) -> int | None:
    """Next offset >= ``start`` where a believable frame begins.

    An intact frame always follows the trailer of the one before, so only the
    positions just after an A5A5A5A5 run are candidates; ``bytes.find`` keeps
    the scan linear.
    """
    search = max(start - 4, 0)
    while True:
        hit = data.find(_FF_TRAILER, search)
        if hit < 0:
            return None
        candidate = hit + 4
        if candidate >= start and _final_frame_end(data, candidate, end) >= 0:
            first = candidate + _FF_HEADER
            if data[first] != 0 and ((data[first + 1] << 8) | data[first + 2]) >= 3:
                return candidate
        search = hit + 1


def _read_final(data: bytes) -> Iterator[_Item]:
    end = len(data)
    pos = 0
    while pos < end:
        frame_end = _final_frame_end(data, pos, end)
        if frame_end >= 0:
            received = int.from_bytes(data[pos + 5 : pos + 8]) * _FF_TIME_UNIT
            yield Datagram(
                data[pos + _FF_HEADER : frame_end - 4], pos + _FF_HEADER, received, None, None
            )
            pos = frame_end
            continue
        if end - pos < 2:
            reason = f"{end - pos} trailing byte, too short for a frame length"
        else:
            length = _u16(data, pos)
            if length < _FF_MIN_FRAME:
                reason = f"impossible frame length {length}"
            elif pos + length > end:
                reason = f"frame length {length} runs past the end of the data"
            else:
                reason = "frame does not end with the A5A5A5A5 trailer"
        restart = _final_resync(data, pos + 1, end)
        yield ContainerError(pos, reason + _skip_note(pos, restart, end))
        if restart is None:
            return
        pos = restart


def _looks_like_final(data: bytes) -> bool:
    frame_end = _final_frame_end(data, 0, len(data))
    return frame_end >= 0 and _is_block_chain(data, _FF_HEADER, frame_end - 4)


# ---------------------------------------------------------------------------
# hex text
# ---------------------------------------------------------------------------

# Tokens are hex runs, optionally 0x-prefixed, separated by blanks, commas or
# semicolons. A colon is deliberately not a separator: "0000: 30 00 ..." is an
# offset-prefixed dump and must not silently turn its offset into data. The line is
# walked token by token: a regex over the whole line (a repeated group) would hold
# backtracking state for every character, about 110 bytes each.
_HEX_TOKEN = re.compile(rb"(0[xX])?([0-9A-Fa-f]+)(?:[ \t,;]+|$)")
_TEXT_CONTROL = re.compile(rb"[\x00-\x08\x0e-\x1f\x7f]")
_HEX_SAMPLE_LINES = 1000


_HEX_BLANKS = b" \t\r\n\v\f"
_HEX_PLAIN = b"0123456789abcdefABCDEF \t"


def _hex_lines(data: bytes) -> Iterator[tuple[int, int, bytes]]:
    """(line number, line offset, content) of each line that carries data; the content
    (up to a ``#`` comment, without surrounding blanks) is the only copy made."""
    end = len(data)
    pos = 0
    number = 0
    while pos < end:
        number += 1
        newline = data.find(b"\n", pos)
        line_end = end if newline < 0 else newline
        comment = data.find(b"#", pos, line_end)
        stop = line_end if comment < 0 else comment
        first = pos
        while first < stop and data[first] in _HEX_BLANKS:
            first += 1
        while stop > first and data[stop - 1] in _HEX_BLANKS:
            stop -= 1
        if stop > first:
            yield number, pos, bytes(data[first:stop])
        pos = line_end + 1


def _is_hex_text(content: bytes) -> bool:
    """Whether a line is hex tokens and separators (runs of odd length included: the
    reader then says which line is not hex bytes)."""
    if not content.translate(None, _HEX_PLAIN):
        return True
    pos, end = 0, len(content)
    while pos < end:
        match = _HEX_TOKEN.match(content, pos)
        if match is None:
            return False
        pos = match.end()
    return True


def _parse_hex_line(content: bytes) -> bytes | None:
    # The common dump, digits and blanks only: bytes.fromhex reads it at C speed and, as
    # the token rules below, refuses a run of odd length.
    if not content.translate(None, _HEX_PLAIN):
        try:
            return bytes.fromhex(content.decode("ascii"))
        except ValueError:
            return None
    out = bytearray()
    pos, end = 0, len(content)
    while pos < end:
        match = _HEX_TOKEN.match(content, pos)
        if match is None:
            return None
        digits = match.group(2)
        if len(digits) % 2:
            # "0x5" is unambiguous; a bare odd run is not (which nibble is missing?).
            if match.group(1) is None:
                return None
            digits = b"0" + digits
        out += bytes.fromhex(digits.decode("ascii"))
        pos = match.end()
    return bytes(out)


def _read_hex(data: bytes) -> Iterator[_Item]:
    for number, offset, content in _hex_lines(data):
        payload = _parse_hex_line(content)
        if payload is None:
            yield ContainerError(offset, f"line {number} is not hex bytes")
        else:
            yield Datagram(payload, offset, None, None, None)


def _looks_like_hex(data: bytes) -> bool:
    if not data.isascii() or _TEXT_CONTROL.search(data) is not None:
        return False
    good = total = 0
    for _number, _offset, content in _hex_lines(data):
        total += 1
        good += _is_hex_text(content)
        if total >= _HEX_SAMPLE_LINES:
            break
    return good > 0 and 2 * good > total


# ---------------------------------------------------------------------------
# Link layer -> IPv4 -> UDP, shared by pcap and pcapng
# ---------------------------------------------------------------------------

_LINK_NULL = 0
_LINK_ETHERNET = 1
_LINK_RAW = 101
_LINK_LOOP = 108
_LINK_SLL = 113
_LINK_IPV4 = 228
_LINK_SLL2 = 276
_SUPPORTED_LINKS = frozenset(
    {_LINK_NULL, _LINK_ETHERNET, _LINK_RAW, _LINK_LOOP, _LINK_SLL, _LINK_IPV4, _LINK_SLL2}
)
_ETHERTYPE_IPV4 = 0x0800
_VLAN_TPIDS = frozenset({0x8100, 0x88A8, 0x9100})
_IPPROTO_UDP = 17


def _after_ethertype(data: bytes, field: int, end: int) -> int | str | None:
    """IPv4 header offset given the offset of an EtherType field.

    Returns None for traffic that is simply not IPv4, and a reason string for a
    header that is cut short.
    """
    if field + 2 > end:
        return "truncated link-layer header"
    ethertype = _u16(data, field)
    # Q-in-Q captures stack several tags; each costs 4 bytes, so the loop is
    # bounded by the frame length.
    while ethertype in _VLAN_TPIDS:
        field += 4
        if field + 2 > end:
            return "truncated 802.1Q VLAN tag"
        ethertype = _u16(data, field)
    return field + 2 if ethertype == _ETHERTYPE_IPV4 else None


def _ipv4_start(data: bytes, start: int, end: int, link: int) -> int | str | None:
    size = end - start
    if link == _LINK_ETHERNET:
        if size < 14:
            return "truncated Ethernet header"
        return _after_ethertype(data, start + 12, end)
    if link == _LINK_SLL:
        if size < 16:
            return "truncated Linux cooked (SLL) header"
        return _after_ethertype(data, start + 14, end)
    if link == _LINK_SLL2:
        if size < 20:
            return "truncated Linux cooked (SLL2) header"
        protocol = _u16(data, start)
        return start + 20 if protocol == _ETHERTYPE_IPV4 else None
    if link == _LINK_RAW:
        # DLT_RAW also carries IPv6, which is not an error, just not ours.
        if size >= 1 and data[start] >> 4 == 6:
            return None
        return start
    if link == _LINK_IPV4:
        return start
    if link in (_LINK_NULL, _LINK_LOOP):
        if size < 4:
            return "truncated loopback header"
        family = data[start : start + 4]
        # NULL stores AF_INET in the writer's byte order, which the file does
        # not record; LOOP always uses network order. AF_INET is 2 everywhere.
        accepted = (
            (b"\x00\x00\x00\x02", b"\x02\x00\x00\x00")
            if link == _LINK_NULL
            else (b"\x00\x00\x00\x02",)
        )
        return start + 4 if family in accepted else None
    return f"unsupported link type {link}"


def _ip_text(data: bytes, pos: int) -> str:
    return f"{data[pos]}.{data[pos + 1]}.{data[pos + 2]}.{data[pos + 3]}"


def _decode_frame(data: bytes, start: int, end: int, link: int, time: float | None) -> _Item | None:
    """Unwrap one captured frame ``data[start:end]`` down to its UDP payload.

    Returns None for frames that are legitimately something else (ARP, IPv6,
    TCP, ...) or carry an empty UDP payload: captures are full of those and
    reporting each would drown the real errors.
    """
    ip = _ipv4_start(data, start, end, link)
    if ip is None:
        return None
    if isinstance(ip, str):
        return ContainerError(start, ip)
    if end - ip < 20:
        return ContainerError(start, "truncated IPv4 header")
    version_ihl = data[ip]
    if version_ihl >> 4 != 4:
        return ContainerError(start, f"IP version {version_ihl >> 4} where IPv4 was expected")
    header_len = (version_ihl & 0x0F) * 4
    if header_len < 20:
        return ContainerError(start, f"impossible IPv4 header length {header_len}")
    if ip + header_len > end:
        return ContainerError(start, "truncated IPv4 options")
    total_len = _u16(data, ip + 2)
    if total_len == 0:
        # Segmentation offload leaves the total length zero in captures taken
        # on the sending host; the captured length is the best we have.
        total_len = end - ip
    elif total_len < header_len:
        return ContainerError(start, f"IPv4 total length {total_len} below its header length")
    if data[ip + 9] != _IPPROTO_UDP:
        return None
    if _u16(data, ip + 6) & 0x3FFF:
        return ContainerError(start, "IP fragment not reassembled")
    # Ethernet pads short frames, so the IP length, not the frame, bounds UDP.
    ip_end = min(ip + total_len, end)
    udp = ip + header_len
    if ip_end - udp < 8:
        return ContainerError(start, "truncated UDP header")
    udp_len = _u16(data, udp + 4)
    if udp_len < 8:
        return ContainerError(start, f"impossible UDP length {udp_len}")
    if udp + udp_len > ip_end:
        return ContainerError(
            start, f"UDP payload truncated: {ip_end - udp - 8} of {udp_len - 8} bytes captured"
        )
    if udp_len == 8:
        return None
    ports = struct.unpack_from(">HH", data, udp)
    return Datagram(
        data[udp + 8 : udp + udp_len],
        udp + 8,
        time,
        (_ip_text(data, ip + 12), ports[0]),
        (_ip_text(data, ip + 16), ports[1]),
    )


# ---------------------------------------------------------------------------
# pcap
# ---------------------------------------------------------------------------

# magic as read little-endian -> (byte order, fraction units per second)
_PCAP_MAGICS: dict[bytes, tuple[str, int]] = {
    b"\xd4\xc3\xb2\xa1": ("<", 1_000_000),
    b"\xa1\xb2\xc3\xd4": (">", 1_000_000),
    b"\x4d\x3c\xb2\xa1": ("<", 1_000_000_000),
    b"\xa1\xb2\x3c\x4d": (">", 1_000_000_000),
}


def _read_pcap(data: bytes) -> Iterator[_Item]:
    end = len(data)
    kind = _PCAP_MAGICS.get(data[:4])
    if kind is None:
        yield ContainerError(0, "not a pcap magic number")
        return
    if end < 24:
        yield ContainerError(0, "truncated pcap file header")
        return
    order, units = kind
    # The upper bits of the link type field carry FCS information, not the type.
    link = struct.unpack_from(order + "I", data, 20)[0] & 0xFFFF
    if link not in _SUPPORTED_LINKS:
        yield ContainerError(20, f"unsupported link type {link}; no packet can be read")
        return
    record = struct.Struct(order + "IIII")
    pos = 24
    while pos < end:
        if end - pos < 16:
            yield ContainerError(pos, "truncated pcap record header")
            return
        ts_sec, ts_frac, captured, _original = record.unpack_from(data, pos)
        start = pos + 16
        if captured > end - start:
            # The next record header can only be found through this length,
            # so nothing after it can be trusted.
            yield ContainerError(
                pos, f"pcap record of {captured} bytes runs past the end of the file"
            )
            return
        item = _decode_frame(data, start, start + captured, link, ts_sec + ts_frac / units)
        if item is not None:
            yield item
        pos = start + captured


# ---------------------------------------------------------------------------
# pcapng
# ---------------------------------------------------------------------------

_PCAPNG_SHB = b"\x0a\x0d\x0d\x0a"
_PCAPNG_IDB = 1
_PCAPNG_OPB = 2
_PCAPNG_SPB = 3
_PCAPNG_EPB = 6
_BOM_LITTLE = b"\x4d\x3c\x2b\x1a"
_BOM_BIG = b"\x1a\x2b\x3c\x4d"


@dataclass(frozen=True, slots=True)
class _Interface:
    link: int
    units: int  # timestamp ticks per second
    offset: int  # if_tsoffset, seconds


def _parse_idb(data: bytes, pos: int, block_end: int, order: str) -> _Interface:
    link = struct.unpack_from(order + "H", data, pos + 8)[0]
    resolution = 6
    ts_offset = 0
    option = pos + 16
    options_end = block_end - 4
    while option + 4 <= options_end:
        code, length = struct.unpack_from(order + "HH", data, option)
        value = option + 4
        if code == 0 or value + length > options_end:
            break
        if code == 9 and length >= 1:
            resolution = data[value]
        elif code == 14 and length >= 8:
            ts_offset = struct.unpack_from(order + "q", data, value)[0]
        option = value + ((length + 3) & ~3)
    # if_tsresol: high bit set means a negative power of 2, else of 10.
    units = 2 ** (resolution & 0x7F) if resolution & 0x80 else 10**resolution
    return _Interface(link, units, ts_offset)


def _read_pcapng(data: bytes) -> Iterator[_Item]:
    end = len(data)
    order: str | None = None
    interfaces: list[_Interface] = []
    pos = 0
    while pos < end:
        if end - pos < 12:
            yield ContainerError(pos, "truncated pcapng block header")
            return
        if data[pos : pos + 4] == _PCAPNG_SHB:
            # The block type reads the same in both byte orders; the byte-order
            # magic tells how to read everything else in the section.
            bom = data[pos + 8 : pos + 12]
            if bom == _BOM_LITTLE:
                order = "<"
            elif bom == _BOM_BIG:
                order = ">"
            else:
                yield ContainerError(pos, "bad pcapng byte-order magic")
                return
            interfaces = []
        elif order is None:
            yield ContainerError(pos, "pcapng data does not start with a section header")
            return
        block_type, block_len = struct.unpack_from(order + "II", data, pos)
        if block_len < 12 or block_len % 4 or block_len > end - pos:
            yield ContainerError(pos, f"impossible pcapng block length {block_len}")
            return
        block_end = pos + block_len
        if struct.unpack_from(order + "I", data, block_end - 4)[0] != block_len:
            yield ContainerError(pos, "pcapng block lengths at start and end differ")
            pos = block_end
            continue
        if block_type == _PCAPNG_IDB:
            if block_len < 20:
                yield ContainerError(pos, "truncated interface description block")
            else:
                interface = _parse_idb(data, pos, block_end, order)
                if interface.link not in _SUPPORTED_LINKS:
                    yield ContainerError(
                        pos,
                        f"unsupported link type {interface.link} on interface "
                        f"{len(interfaces)}; its packets are skipped",
                    )
                interfaces.append(interface)
        elif block_type in (_PCAPNG_EPB, _PCAPNG_OPB, _PCAPNG_SPB):
            item = _pcapng_packet(data, pos, block_end, block_type, order, interfaces)
            if item is not None:
                yield item
        pos = block_end


def _pcapng_packet(
    data: bytes,
    pos: int,
    block_end: int,
    block_type: int,
    order: str,
    interfaces: list[_Interface],
) -> _Item | None:
    body_end = block_end - 4
    time: float | None
    if block_type == _PCAPNG_SPB:
        if body_end - pos < 12:
            return ContainerError(pos, "truncated simple packet block")
        index = 0
        original = struct.unpack_from(order + "I", data, pos + 8)[0]
        start = pos + 12
        captured = min(original, body_end - start)
    else:
        if body_end - pos < 28:
            return ContainerError(pos, "truncated packet block")
        if block_type == _PCAPNG_EPB:
            index = struct.unpack_from(order + "I", data, pos + 8)[0]
        else:
            index = struct.unpack_from(order + "H", data, pos + 8)[0]
        ts_high, ts_low, captured = struct.unpack_from(order + "III", data, pos + 12)
        start = pos + 28
        if captured > body_end - start:
            return ContainerError(pos, f"captured length {captured} exceeds its block")
    if index >= len(interfaces):
        return ContainerError(pos, f"packet refers to undeclared interface {index}")
    interface = interfaces[index]
    if interface.link not in _SUPPORTED_LINKS:
        return None
    if block_type == _PCAPNG_SPB:
        # Simple packet blocks carry no timestamp at all.
        time = None
    else:
        # Integer division keeps nanosecond ticks exact up to float rounding.
        time = ((ts_high << 32) | ts_low) / interface.units + interface.offset
    return _decode_frame(data, start, start + captured, interface.link, time)


# ---------------------------------------------------------------------------
# Detection and public entry points
# ---------------------------------------------------------------------------

_READERS = {
    "pcap": _read_pcap,
    "pcapng": _read_pcapng,
    "gps": _read_gps,
    "final": _read_final,
    "hex": _read_hex,
    "raw": _read_raw,
}


def detect_format(data: bytes) -> str:
    """Name of the container format of ``data``, judged from its content."""
    data = bytes(data)
    if data[:4] in _PCAP_MAGICS:
        return "pcap"
    if data[:4] == _PCAPNG_SHB:
        return "pcapng"
    if _looks_like_gps(data):
        return "gps"
    if _looks_like_final(data):
        return "final"
    if _looks_like_hex(data):
        return "hex"
    return "raw"


def read_datagrams(data: bytes, fmt: str | None = None) -> Iterator[Datagram | ContainerError]:
    """Datagrams and container errors of ``data``, in file order.

    ``fmt`` overrides detection. An unknown ``fmt`` raises ValueError at call
    time; nothing else raises, whatever the input.
    """
    if fmt is not None and fmt not in _READERS:
        raise ValueError(f"unknown container format {fmt!r}; expected one of {FORMATS}")
    # A bytearray or memoryview could change under the reader's feet.
    data = bytes(data)
    return _READERS[fmt or detect_format(data)](data)


def read_file(
    path: str | os.PathLike[str], fmt: str | None = None
) -> Iterator[Datagram | ContainerError]:
    """Like :func:`read_datagrams` on the content of the file at ``path``."""
    if fmt is not None and fmt not in _READERS:
        raise ValueError(f"unknown container format {fmt!r}; expected one of {FORMATS}")
    return _read_mapped(Path(path), fmt)


_DETECT_BYTES = 1 << 20
"""The start of a file that its format is judged from."""
_RELEASE_BYTES = 4 << 20
"""Pages this far behind the reader go back to the kernel."""


def _head(mapped: mmap.mmap) -> bytes:
    """The start of a file to judge its format from, ending where a hex dump's line (or,
    in one long line, a token) ends, so that a cut token does not look like bad text."""
    head = mapped[:_DETECT_BYTES]
    if len(mapped) <= len(head):
        return head
    cut = head.rfind(b"\n")
    if cut < 0:
        cut = max(head.rfind(b" "), head.rfind(b"\t"), head.rfind(b","), head.rfind(b";"))
    return head[: cut + 1] if cut >= 0 else head


def _read_mapped(path: Path, fmt: str | None) -> Iterator[Datagram | ContainerError]:
    with open(path, "rb") as stream:
        if os.fstat(stream.fileno()).st_size == 0:
            yield from read_datagrams(b"", fmt)
            return
        with mmap.mmap(stream.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
            reader = _READERS[fmt or detect_format(_head(mapped))]
            # A mapped file does for the readers what bytes do: indexing, slices (copied
            # out as bytes), find, struct.unpack_from.
            released = 0
            for item in reader(cast(bytes, mapped)):
                yield item
                # The readers only move forward (a resynchronisation looks a few bytes
                # back at most), and a page given back is read again if touched.
                behind = item.offset - _RELEASE_BYTES
                if behind - released >= _RELEASE_BYTES:
                    behind -= behind % mmap.PAGESIZE
                    mapped.madvise(mmap.MADV_DONTNEED, released, behind - released)
                    released = behind


# ---------------------------------------------------------------------------
# pcap writer
# ---------------------------------------------------------------------------

_MAX_UDP_PAYLOAD = 65535 - 20 - 8


def _inet_checksum(chunk: bytes) -> int:
    if len(chunk) % 2:
        chunk += b"\x00"
    total: int = sum(struct.unpack(f">{len(chunk) // 2}H", chunk))
    while total >> 16:
        total = (total & 0xFFFF) + (total >> 16)
    return ~total & 0xFFFF


def _mac_for(ip: bytes, *, destination: bool) -> bytes:
    if destination and 224 <= ip[0] <= 239:
        # RFC 1112 mapping, so that switches and Wireshark see real multicast.
        return bytes((0x01, 0x00, 0x5E, ip[1] & 0x7F, ip[2], ip[3]))
    if destination and ip == b"\xff\xff\xff\xff":
        return b"\xff" * 6
    # Locally administered unicast address derived from the IP, stable per host.
    return b"\x02\x00" + ip


def _udp_frame(
    source: tuple[str, int], destination: tuple[str, int], payload: bytes, ident: int
) -> bytes:
    if len(payload) > _MAX_UDP_PAYLOAD:
        raise ValueError(f"UDP payload of {len(payload)} bytes exceeds {_MAX_UDP_PAYLOAD}")
    src_ip = ipaddress.IPv4Address(source[0]).packed
    dst_ip = ipaddress.IPv4Address(destination[0]).packed
    for port in (source[1], destination[1]):
        if not 0 <= port <= 0xFFFF:
            raise ValueError(f"port {port} out of range")
    udp_len = 8 + len(payload)
    pseudo = src_ip + dst_ip + struct.pack(">BBH", 0, _IPPROTO_UDP, udp_len)
    udp_header = struct.pack(">HHHH", source[1], destination[1], udp_len, 0)
    checksum = _inet_checksum(pseudo + udp_header + payload) or 0xFFFF
    udp_header = udp_header[:6] + _U16BE.pack(checksum)
    ip_header = struct.pack(
        ">BBHHHBBH4s4s",
        0x45,
        0,
        20 + udp_len,
        ident,
        0x4000,  # don't fragment: readers do not reassemble
        64,
        _IPPROTO_UDP,
        0,
        src_ip,
        dst_ip,
    )
    ip_header = ip_header[:10] + _U16BE.pack(_inet_checksum(ip_header)) + ip_header[12:]
    ethernet = (
        _mac_for(dst_ip, destination=True)
        + _mac_for(src_ip, destination=False)
        + _U16BE.pack(_ETHERTYPE_IPV4)
    )
    return ethernet + ip_header + udp_header + payload


def write_pcap(
    path_or_file: str | os.PathLike[str] | BinaryIO,
    datagrams: Iterable[tuple[float, tuple[str, int], tuple[str, int], bytes]],
) -> int:
    """Write ``(time, (src ip, port), (dst ip, port), payload)`` as a classic pcap.

    The capture is little-endian, microsecond, Ethernet/IPv4/UDP: the most
    widely readable variant. Returns the number of packets written. Raises
    ValueError for a time, address, port or payload that cannot be encoded.
    """
    if isinstance(path_or_file, (str, os.PathLike)):
        with open(path_or_file, "wb") as stream:
            return _write_pcap_stream(stream, datagrams)
    return _write_pcap_stream(path_or_file, datagrams)


def _write_pcap_stream(
    stream: BinaryIO,
    datagrams: Iterable[tuple[float, tuple[str, int], tuple[str, int], bytes]],
) -> int:
    stream.write(struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 262144, _LINK_ETHERNET))
    count = 0
    for time, source, destination, payload in datagrams:
        micros = round(time * 1_000_000)
        seconds, fraction = divmod(micros, 1_000_000)
        if not 0 <= seconds <= 0xFFFFFFFF:
            raise ValueError(f"time {time} cannot be stored in a pcap timestamp")
        frame = _udp_frame(source, destination, bytes(payload), count & 0xFFFF)
        stream.write(struct.pack("<IIII", seconds, fraction, len(frame), len(frame)))
        stream.write(frame)
        count += 1
    return count
