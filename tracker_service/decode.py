"""``tracker-service decode``: every record of a capture as JSON lines, or a summary."""

from __future__ import annotations

import json
import sys
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

from asterix import DecodeError
from asterix.bds import decode_mb, infer_register
from asterix.codec import decode_blocks
from asterix.containers import ContainerError, Datagram, read_file
from tracker_service.ingest import DuplicateFilter
from tracker_service.simulator.recording import is_mcap, stream_datagrams

# The item holding each category's time of day, for the summary's time span (CAT001's
# I141 is truncated to 512 s: its CAT002 I030 gives the span).
TIME_OF_DAY_ITEM = {2: "030", 21: "073", 34: "030", 48: "140", 62: "070", 65: "030"}


@dataclass
class Summary:
    records: Counter[str] = field(default_factory=Counter)
    blocks: Counter[str] = field(default_factory=Counter)
    sources: Counter[str] = field(default_factory=Counter)
    datagrams: int = 0
    duplicate_datagrams: int = 0
    duplicate_records: int = 0
    unsupported_blocks: Counter[str] = field(default_factory=Counter)
    errors: Counter[str] = field(default_factory=Counter)
    capture_time: list[float] = field(default_factory=list)
    time_of_day: dict[str, list[float]] = field(default_factory=dict)

    def add_time(self, bucket: list[float], value: float) -> None:
        if bucket:
            bucket[0], bucket[1] = min(bucket[0], value), max(bucket[1], value)
        else:
            bucket.extend((value, value))

    def add_record(self, cat: int, items: dict[str, Any], duplicate: bool) -> None:
        key = f"{cat:03d}"
        self.records[key] += 1
        self.duplicate_records += duplicate
        source = items.get("010")
        if isinstance(source, dict):
            self.sources[f"{key} {source.get('SAC')}/{source.get('SIC')}"] += 1
        tod = items.get(TIME_OF_DAY_ITEM.get(cat, ""))
        if isinstance(tod, float):
            self.add_time(self.time_of_day.setdefault(key, []), tod)

    def as_json(self) -> dict[str, Any]:
        return {
            "datagrams": self.datagrams,
            "duplicate_datagrams": self.duplicate_datagrams,
            "blocks": dict(sorted(self.blocks.items())),
            "records": dict(sorted(self.records.items())),
            "duplicate_records": self.duplicate_records,
            "records_by_source": dict(sorted(self.sources.items())),
            "unsupported_blocks": dict(sorted(self.unsupported_blocks.items())),
            "capture_time": self.capture_time or None,
            "time_of_day": dict(sorted(self.time_of_day.items())),
            "errors": sum(self.errors.values()),
            "errors_by_reason": dict(self.errors.most_common(20)),
        }


def add_bds_fields(items: dict[str, Any]) -> None:
    """Name the fields of BDS 4,0/5,0/6,0 registers in I048/250 under the key "BDS".

    Registers sent by Comm-B broadcast carry BDS 0,0; their kind is inferred when only one
    of the three registers is plausible.
    """
    for entry in items.get("250", ()):
        mb, bds1, bds2 = int(entry["MBDATA"], 16), entry["BDS1"], entry["BDS2"]
        if (bds1, bds2) == (0, 0) and (register := infer_register(mb)) is not None:
            bds1, bds2 = (int(part) for part in register.split(","))
        fields = decode_mb(mb, bds1, bds2)
        if fields is not None:
            entry["BDS"] = fields


def _error_json(event: DecodeError | ContainerError) -> str:
    if isinstance(event, ContainerError):
        return json.dumps({"error": "container", "offset": event.offset, "reason": event.reason})
    return json.dumps(
        {
            "error": "decode",
            "offset": event.offset,
            "category": event.category,
            "reason": event.reason,
        }
    )


def read_datagrams(path: Path) -> Iterator[Datagram | ContainerError]:
    """Datagrams of a capture, or of an MCAP recording or service log (where offsets count
    datagrams; one cut short gives what it holds, then an error); a directory of the
    service's log files (as it rotates them) file after file, in name (time) order."""
    if path.is_dir():
        for file in sorted(path.glob("*.mcap")):
            yield from stream_datagrams(file)
        return
    if is_mcap(path):
        yield from stream_datagrams(path)
    else:
        yield from read_file(path)


def run_decode(path: Path, summary_only: bool, out: TextIO, err: TextIO, bds: bool = False) -> int:
    summary = Summary()
    duplicates = DuplicateFilter()
    block_number = 0
    write = out.write
    for unit in read_datagrams(path):
        if not isinstance(unit, Datagram):
            summary.errors[unit.reason.split(":")[0]] += 1
            err.write(_error_json(unit) + "\n")
            continue
        summary.datagrams += 1
        if unit.time is not None:
            summary.add_time(summary.capture_time, unit.time)
        duplicate = duplicates.is_duplicate(unit.payload, unit.time)
        summary.duplicate_datagrams += duplicate
        for event in decode_blocks(unit.payload, unit.offset):
            if isinstance(event, DecodeError):
                summary.errors[event.reason.split(":")[0]] += 1
                err.write(_error_json(event) + "\n")
                continue
            block_number += 1
            key = f"{event.cat:03d}"
            summary.blocks[key] += 1
            if not event.supported:
                summary.unsupported_blocks[key] += 1
                continue
            for index, items in enumerate(event.records):
                summary.add_record(event.cat, items, duplicate)
                if summary_only:
                    continue
                if bds and event.cat == 48:
                    add_bds_fields(items)
                record: dict[str, Any] = {
                    "cat": event.cat,
                    "block": block_number,
                    "record": index,
                    "time": unit.time,
                    "items": items,
                }
                if duplicate:
                    record["duplicate"] = True
                write(json.dumps(record) + "\n")
    if summary_only:
        json.dump(summary.as_json(), out, indent=2)
        out.write("\n")
    return 0


def main(path: str, summary_only: bool, bds: bool = False) -> int:
    file = Path(path)
    if file.is_dir() and not any(file.glob("*.mcap")):
        print(f"tracker-service decode: {path}: a directory without .mcap logs", file=sys.stderr)
        return 2
    if not file.is_file() and not file.is_dir():
        print(f"tracker-service decode: {path}: no such file", file=sys.stderr)
        return 2
    return run_decode(file, summary_only, sys.stdout, sys.stderr, bds)
