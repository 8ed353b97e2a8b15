"""Decode throughput: our codec against libasterix and asterix_decoder on one CAT048 stream.

    bash benchmarks/setup_peers.sh && python benchmarks/bench_codec.py [--records N]
        [--repeats R] [--peer-records M] [--json]

The stream is built from the real CAT048 recordings in shared/data/asterix (data blocks kept
intact, CAT048 blocks only), repeated to about N records and written to a temporary file.
Then, in one run and R times each, interleaved so that machine noise hits all alike:

- ours, full decode: ``decode_blocks`` (every item of every record to Python dicts);
- ours, plot extraction: ``asterix.plots.extract_plots`` (one numpy row per record);
- libasterix, full decode, and asterix_decoder, full decode: peer_decode.py run by each
  peer's own venv python (both peers install the import name ``asterix``, like ours).

Prints the machine, records/s medians and the ratios against their targets (ours full /
libasterix >= 3, ours plots / asterix_decoder >= 2); ``--json`` prints the same as JSON.
What each peer's decode does, and why it is a full decode: docs/benchmarks.md.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
sys.path.insert(0, str(REPO))  # the repository's codec, also when not pip-installed

from peer_decode import block_prefix  # noqa: E402  (beside this script; stdlib only)

from asterix import Block, DecodeError, decode_blocks  # noqa: E402

DATA = REPO.parent / "shared/data/asterix"
VENVS = HERE / ".venvs"
PEER_SCRIPT = HERE / "peer_decode.py"
PEERS = ("libasterix", "asterix_decoder")
CAT = 48
GPS_HEADER = 2200
GPS_TRAILER = 10
WARMUP_BYTES = 256 * 1024  # as in peer_decode.py: covers the ~100 KB unit of the stream

RAW_FILES = ("croatiacontrol/cat048.raw", "jasterix/cat048ed1.15.bin")
# asterix_decoder 0.7.11 (CAT048 1.21) silently turns this record (an I020 extension and an
# RE field) into 3 item-less records, so it would break the record-count check; it is 1
# record in ~1,960 of the unit, and our codec and libasterix decode it.
EXCLUDED = {"jasterix/cat048ed1.23.bin": "asterix_decoder 0.7.11 mis-parses it silently"}

TARGETS = {
    "ours_full/libasterix": 3.0,
    "ours_plots/asterix_decoder": 2.0,
}


# --- the stream -------------------------------------------------------------------------


def split_blocks(payload: bytes, where: str) -> list[bytes]:
    """The data blocks of a payload that must be a chain of whole blocks."""
    blocks, pos = [], 0
    while pos < len(payload):
        end = pos + int.from_bytes(payload[pos + 1 : pos + 3])
        if end - pos < 3 or end > len(payload):
            raise ValueError(f"{where}: bad data block at octet {pos}")
        blocks.append(payload[pos:end])
        pos = end
    return blocks


def pcap_payloads(data: bytes, where: str) -> Iterator[bytes]:
    """UDP payloads of a classic little-endian pcap of Ethernet/IPv4/UDP frames."""
    if data[:4] != b"\xd4\xc3\xb2\xa1" or int.from_bytes(data[20:24], "little") != 1:
        raise ValueError(f"{where}: not a little-endian Ethernet pcap")
    pos = 24
    while pos + 16 <= len(data):
        captured = int.from_bytes(data[pos + 8 : pos + 12], "little")
        frame = data[pos + 16 : pos + 16 + captured]
        pos += 16 + captured
        ip = 14
        ethertype = int.from_bytes(frame[12:14])
        if ethertype == 0x8100:  # one VLAN tag
            ip, ethertype = 18, int.from_bytes(frame[16:18])
        if ethertype != 0x0800 or frame[ip + 9] != 17:
            continue
        if int.from_bytes(frame[ip + 6 : ip + 8]) & 0x3FFF:
            raise ValueError(f"{where}: fragmented IPv4 datagram")
        udp = ip + (frame[ip] & 0x0F) * 4
        length = int.from_bytes(frame[udp + 4 : udp + 6])
        yield frame[udp + 8 : udp + length]


def gps_blocks(data: bytes, where: str) -> Iterator[bytes]:
    """Blocks of a GPS v1 recording: a 2200-octet header, then [block][10 octets] repeated."""
    pos = GPS_HEADER
    while pos < len(data):
        end = pos + int.from_bytes(data[pos + 1 : pos + 3])
        if end - pos < 3 or end + GPS_TRAILER > len(data):
            raise ValueError(f"{where}: bad GPS item at octet {pos}")
        yield data[pos:end]
        pos = end + GPS_TRAILER


def source_blocks() -> dict[str, list[bytes]]:
    """The CAT048 data blocks of each source recording, in file order."""
    sources: dict[str, list[bytes]] = {}
    name = "croatiacontrol/cat_034_048.pcap"
    sources[name] = [
        b
        for payload in pcap_payloads((DATA / name).read_bytes(), name)
        for b in split_blocks(payload, name)
    ]
    name = "reader_network/068test_bds30.gps"
    sources[name] = list(gps_blocks((DATA / name).read_bytes(), name))
    for name in RAW_FILES:
        sources[name] = split_blocks((DATA / name).read_bytes(), name)
    return {k: [b for b in v if b[0] == CAT] for k, v in sources.items()}


def records_in(block: bytes) -> int:
    """Records of one block by our codec, which must decode it without error."""
    count = 0
    for ev in decode_blocks(block):
        if isinstance(ev, DecodeError):
            raise ValueError(f"our codec rejects a source block: {ev}")
        count += len(ev.records)
    return count


@dataclass
class Stream:
    path: Path
    records: int
    octets: int
    blocks: int


@dataclass
class Unit:
    """The source blocks, in order, with the records of each."""

    blocks: list[bytes] = field(default_factory=list)
    counts: list[int] = field(default_factory=list)
    by_source: dict[str, tuple[int, int]] = field(default_factory=dict)  # blocks, records

    def write(self, path: Path, records: int) -> Stream:
        """The unit repeated, whole blocks only, until at least ``records`` records."""
        total = octets = blocks = 0
        with path.open("wb") as out:
            while total < records:
                for block, count in zip(self.blocks, self.counts, strict=True):
                    out.write(block)
                    total += count
                    octets += len(block)
                    blocks += 1
                    if total >= records:
                        break
        return Stream(path, total, octets, blocks)


def build_unit() -> Unit:
    unit = Unit()
    for name, blocks in source_blocks().items():
        counts = [records_in(b) for b in blocks]
        unit.blocks += blocks
        unit.counts += counts
        unit.by_source[name] = (len(blocks), sum(counts))
    return unit


# --- the machine ---------------------------------------------------------------------------


def machine() -> dict[str, Any]:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    try:
        import numpy

        numpy_version = numpy.__version__
    except ImportError:
        numpy_version = "not installed"
    return {
        "cpu": cpu,
        "cores": os.cpu_count(),
        "python": platform.python_version(),
        "numpy": numpy_version,
        # Set on some machines for old OpenBLAS builds; no BLAS runs in this benchmark.
        "OPENBLAS_CORETYPE": os.environ.get("OPENBLAS_CORETYPE"),
    }


# --- the measurements ---------------------------------------------------------------------


@dataclass
class Result:
    name: str
    label: str
    stream_records: int
    method: str = ""
    version: str = ""
    seconds: list[float] = field(default_factory=list)
    pending: str = ""

    @property
    def rates(self) -> list[float]:
        return [self.stream_records / s for s in self.seconds]

    @property
    def median_rate(self) -> float | None:
        return statistics.median(self.rates) if self.seconds else None

    def as_json(self) -> dict[str, Any]:
        return {
            "label": self.label,
            "version": self.version,
            "method": self.method,
            "records": self.stream_records,
            "seconds": self.seconds,
            "median_seconds": statistics.median(self.seconds) if self.seconds else None,
            "median_records_per_s": self.median_rate,
            "pending": self.pending or None,
        }


def ours_full(data: bytes) -> int:
    return sum(len(ev.records) for ev in decode_blocks(data) if isinstance(ev, Block))


def load_plots() -> Callable[[bytes], Any] | str:
    """extract_plots, or why it is pending (the module is being written concurrently)."""
    try:
        from asterix.plots import extract_plots
    except ImportError as exc:
        return f"asterix.plots.extract_plots not importable yet ({exc})"
    return extract_plots


def timed(fn: Callable[[bytes], int], data: bytes) -> tuple[int, float]:
    start = time.perf_counter()
    records = fn(data)
    return records, time.perf_counter() - start


def run_peer(peer: str, stream: Path) -> dict[str, Any]:
    """One timed decode of the stream by a peer, in its own venv (isolated mode)."""
    python = VENVS / peer / "bin/python"
    if not python.exists():
        raise SystemExit(f"{python} missing: run `bash benchmarks/setup_peers.sh` first")
    done = subprocess.run(
        [str(python), "-I", str(PEER_SCRIPT), peer, str(stream), "1"],
        capture_output=True,
        text=True,
        check=False,
    )
    if done.returncode != 0:
        raise SystemExit(f"{peer} failed:\n{done.stderr}")
    result: dict[str, Any] = json.loads(done.stdout.strip().splitlines()[-1])
    return result


def measure(
    streams: dict[str, Stream], repeats: int, peers: list[str], log: Callable[[str], None]
) -> dict[str, Result]:
    ours = streams["ours"]
    data = ours.path.read_bytes()
    results = {
        "ours_full": Result("ours_full", "ours, full decode (decode_blocks)", ours.records),
        "ours_plots": Result("ours_plots", "ours, plot extraction (extract_plots)", ours.records),
    }
    for peer in peers:
        results[peer] = Result(peer, f"{peer}, full decode", streams[peer].records)
    results["ours_full"].method = "sum(len(ev.records) for ev in decode_blocks(data) if Block)"
    results["ours_plots"].method = "extract_plots(data).plots (numpy structured array)"

    plots = load_plots()
    if isinstance(plots, str):
        results["ours_plots"].pending = plots
        log(f"ours, plot extraction: pending: {plots}")
    extract = None if isinstance(plots, str) else plots

    def plot_rows(buf: bytes) -> int:
        assert extract is not None
        batch = extract(buf)
        if batch.errors:
            raise SystemExit(f"extract_plots reported errors: {batch.errors[:3]}")
        return len(batch.plots)

    # Warm-up, untimed: builds our per-category decoders and plot walker (the peers warm up
    # the same way in peer_decode.py).
    warm = block_prefix(data, WARMUP_BYTES)
    ours_full(warm)
    if extract is not None:
        plot_rows(warm)

    for rep in range(1, repeats + 1):
        # Interleaved: each repetition runs every decoder once, in the same order.
        records, seconds = timed(ours_full, data)
        check(records, ours.records, "ours, full decode")
        results["ours_full"].seconds.append(seconds)
        log(f"[{rep}/{repeats}] ours full      {records / seconds:12,.0f} records/s")
        if extract is not None:
            records, seconds = timed(plot_rows, data)
            check(records, ours.records, "ours, plot extraction")
            results["ours_plots"].seconds.append(seconds)
            log(f"[{rep}/{repeats}] ours plots     {records / seconds:12,.0f} records/s")
        for peer in peers:
            out = run_peer(peer, streams[peer].path)
            check(out["records"], streams[peer].records, peer)
            result = results[peer]
            result.seconds += out["seconds"]
            result.version, result.method = out["version"], out["method"]
            rate = out["records"] / out["seconds"][0]
            log(f"[{rep}/{repeats}] {peer:<15}{rate:12,.0f} records/s")
    return results


def check(got: int, want: int, who: str) -> None:
    if got != want:
        raise SystemExit(f"{who}: decoded {got} records, our codec counts {want}")


def ratios(results: dict[str, Result]) -> dict[str, float | None]:
    def ratio(a: str, b: str) -> float | None:
        ra = results[a].median_rate if a in results else None
        rb = results[b].median_rate if b in results else None
        return ra / rb if ra is not None and rb else None

    return {
        "ours_full/libasterix": ratio("ours_full", "libasterix"),
        "ours_plots/asterix_decoder": ratio("ours_plots", "asterix_decoder"),
        "ours_full/asterix_decoder": ratio("ours_full", "asterix_decoder"),
        "ours_plots/libasterix": ratio("ours_plots", "libasterix"),
        "ours_plots/ours_full": ratio("ours_plots", "ours_full"),
    }


# --- the report ---------------------------------------------------------------------------


def table(
    info: dict[str, Any],
    unit: Unit,
    streams: dict[str, Stream],
    results: dict[str, Result],
    ratio_values: dict[str, float | None],
    repeats: int,
) -> str:
    lines = [
        f"machine: {info['cpu']}, {info['cores']} cores, Python {info['python']}, "
        f"numpy {info['numpy']}",
        "OPENBLAS_CORETYPE: "
        + (
            f"set ({info['OPENBLAS_CORETYPE']})"
            if info["OPENBLAS_CORETYPE"] is not None
            else "not set"
        )
        + " (no BLAS runs here: it does not matter for this benchmark)",
        "stream unit (CAT048 blocks per source, repeated): "
        + ", ".join(f"{k} {b} blocks/{r} records" for k, (b, r) in unit.by_source.items()),
        f"excluded: {', '.join(f'{k} ({v})' for k, v in EXCLUDED.items())}",
    ]
    for name, s in streams.items():
        lines.append(
            f"stream for {name}: {s.records:,} records, {s.blocks:,} blocks, {s.octets:,} octets"
        )
    lines += [
        "",
        f"median of {repeats} repetitions, interleaved",
        f"{'decoder':<42}{'version':>9}{'records':>11}{'median s':>11}{'records/s':>13}",
    ]
    for r in results.values():
        if r.pending:
            lines.append(f"{r.label:<42}{'':>9}{'':>11}{'':>11}{'pending':>13}")
            continue
        median_s = statistics.median(r.seconds)
        rate = r.median_rate or 0.0
        lines.append(
            f"{r.label:<42}{r.version or 'repo':>9}{r.stream_records:>11,}"
            f"{median_s:>11.3f}{rate:>13,.0f}"
        )
    lines += ["", "ratios of median records/s"]
    for name, value in ratio_values.items():
        target = TARGETS.get(name)
        # None: plot extraction pending, or a peer left out with --skip.
        shown = "n/a" if value is None else f"{value:.2f}x"
        verdict = ""
        if target is not None:
            verdict = f"  target >= {target:g}: " + (
                "not measured" if value is None else "met" if value >= target else "NOT MET"
            )
        lines.append(f"  {name:<30}{shown:>10}{verdict}")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--records", type=int, default=1_000_000, help="records in the stream (about)"
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed repetitions of each")
    parser.add_argument(
        "--peer-records",
        type=int,
        default=None,
        help="records for the slow pure-Python peer, libasterix (default: --records); "
        "meant for when one of its runs would take over ~3 min; rates stay comparable",
    )
    parser.add_argument(
        "--skip", action="append", choices=PEERS, default=[], help="leave a peer out"
    )
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    args = parser.parse_args(argv)
    peers = [p for p in PEERS if p not in args.skip]

    def log(message: str) -> None:
        print(message, file=sys.stderr if args.json else sys.stdout, flush=True)

    info = machine()
    unit = build_unit()
    with tempfile.TemporaryDirectory(prefix="bench_codec_") as tmp:
        streams = {"ours": unit.write(Path(tmp) / "stream.ast", args.records)}
        for peer in peers:
            streams[peer] = streams["ours"]
        fewer = args.peer_records
        if fewer is not None and fewer < streams["ours"].records and "libasterix" in peers:
            # A prefix of the same stream (whole blocks): the same content, fewer times.
            streams["libasterix"] = unit.write(Path(tmp) / "prefix.ast", fewer)
        for name, s in streams.items():
            log(f"stream for {name}: {s.records:,} records, {s.octets:,} octets")
        results = measure(streams, args.repeats, peers, log)

    ratio_values = ratios(results)
    if args.json:
        report = {
            "machine": info,
            "repeats": args.repeats,
            "unit": {k: {"blocks": b, "records": r} for k, (b, r) in unit.by_source.items()},
            "excluded": EXCLUDED,
            "streams": {
                k: {"records": s.records, "blocks": s.blocks, "octets": s.octets}
                for k, s in streams.items()
            },
            "results": {k: r.as_json() for k, r in results.items()},
            "ratios": ratio_values,
            "targets": TARGETS,
        }
        print(json.dumps(report, indent=2))
    else:
        print()
        print(table(info, unit, streams, results, ratio_values, args.repeats))
    return 0


if __name__ == "__main__":
    sys.exit(main())
