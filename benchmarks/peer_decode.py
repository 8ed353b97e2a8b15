"""Decode a CAT048 stream with one peer decoder and time it; run by that peer's venv python.

    python peer_decode.py {libasterix|asterix_decoder} STREAM_FILE REPEATS

Prints one JSON line: {"peer", "version", "method", "records", "seconds": [...]}.

Both peers install the import name ``asterix`` (as does our codec), so bench_codec.py runs
this script with each peer's own virtual environment, in isolated mode (``python -I``) so
that the repository's ``asterix`` package can never be imported instead.

Only the decode is timed: reading the file, importing the peer and a warm-up decode of the
stream's first blocks (which also checks that no record came back empty) are not.
"""

from __future__ import annotations

import argparse
import importlib
import importlib.metadata
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

CAT = 48
Decoder = Callable[..., int]  # (data, sink=None) -> records; decoded records go to sink
# The warm-up decodes this much of the stream (whole blocks). The stream is a ~100 KB unit
# of real recordings repeated, so this covers every distinct record at least once.
WARMUP_BYTES = 256 * 1024
# asterix_decoder: data blocks per parse_with_offset() call. Its throughput falls as calls
# get larger (a whole-stream parse() is superlinear in the records it returns), and is best
# at one block per call, so the peer is measured at its best; see docs/benchmarks.md.
DEC_BLOCKS_PER_CALL = 1


def block_prefix(data: bytes, limit: int) -> bytes:
    """The longest run of whole data blocks at the start of ``data`` within ``limit`` octets."""
    pos = 0
    while pos + 3 <= len(data):
        end = pos + int.from_bytes(data[pos + 1 : pos + 3])
        if end > limit and pos > 0:
            break
        pos = end
    return data[:pos]


# --- libasterix -------------------------------------------------------------------------


def libasterix_decoder(parse_only: bool = False) -> tuple[Decoder, str]:
    """A full decode with libasterix: every item of every record to Python values.

    libasterix parses in two public steps, RawDatablock.parse() and then the category's
    ``cv_uap.parse()``, which builds a tree of item objects that still hold raw bits: the
    values are computed only when asked for (``as_quantity()``, ``as_string()``, ...). So
    parsing alone is not a decode; the walk below forces it, converting every element of
    every present item, subitem, extension and repetition to its Python value, and parses
    the Reserved Expansion field with REF 048 1.13 and walks it the same way. Spares are
    left out, as our codec does. The result per record is a dict shaped like ours.
    """
    # Imported by name: a type checker run from the repository would resolve ``asterix`` to
    # our codec, which has neither module.
    base: Any = importlib.import_module("asterix.base")
    gen: Any = importlib.import_module("asterix.generated")

    spec = gen.Cat_048_1_32
    ref = gen.Ref_048_1_13
    bits_from_bytes = base.Bits.from_bytes
    raw_parse = base.RawDatablock.parse
    uap_parse = spec.cv_uap.parse
    ref_parse = ref.cv_expansion.parse
    item_cls = base.Item

    # One handler per variation class, made on first sight: the dispatch is done once per
    # class, not once per value, so the walk adds as little as possible to libasterix's cost.
    handlers: dict[type, Callable[[Any], Any]] = {}

    def value(var: Any) -> Any:
        handler = handlers.get(type(var))
        if handler is None:
            handler = handlers[type(var)] = make_handler(type(var))
        return handler(var)

    def nonspare(nsp: Any) -> Any:
        # The CAT048 1.32 and REF 048 1.13 specs have no context-dependent rules, so every
        # NonSpare has a statically known variation (checked in make_handler's callers).
        return value(nsp.variation)

    def make_handler(cls: type) -> Callable[[Any], Any]:
        if issubclass(cls, base.Element):
            content = cls.cv_rule.cv_content  # type: ignore[attr-defined]
            if issubclass(content, base.ContentQuantity):
                return lambda v: v.content.as_quantity()
            if issubclass(content, base.ContentString):
                return lambda v: v.content.as_string()
            if issubclass(content, base.ContentInteger):
                return lambda v: v.content.as_integer()
            # Table, raw and BDS contents are unsigned integers.
            return lambda v: v.content.as_uint()
        if issubclass(cls, base.Group):
            return lambda v: {
                i.arg.cv_name: nonspare(i.arg) for i in v.arg if isinstance(i, item_cls)
            }
        if issubclass(cls, base.Extended):
            return lambda v: {
                i.arg.cv_name: nonspare(i.arg)
                for part in v.arg
                for i in part
                if isinstance(i, item_cls)
            }
        if issubclass(cls, base.Repetitive):
            return lambda v: [value(x) for x in v.get_list()]
        if issubclass(cls, base.Compound):
            return lambda v: {name: nonspare(nsp) for name, nsp in v.arg.items()}
        if issubclass(cls, base.Explicit):
            if cls.cv_explicit_type is base.ReservedExpansion:  # type: ignore[attr-defined]
                return expansion
            return lambda v: v.get_bytes()
        raise TypeError(f"unexpected libasterix variation {cls.__mro__}")

    def expansion(v: Any) -> Any:
        parsed = ref_parse(bits_from_bytes(v.get_bytes()))
        if isinstance(parsed, ValueError):
            raise parsed
        return {name: nonspare(nsp) for name, nsp in parsed[0].arg.items()}

    def decode(data: bytes, sink: list[Any] | None = None) -> int:
        count, pos, size = 0, 0, len(data)
        while pos < size:
            # One data block at a time, as datagrams arrive: libasterix's Bits slices its
            # buffer from an offset to the buffer's end to read a value, and
            # RawDatablock.parse recurses once per block, so it cannot take a whole
            # stream in one buffer; a block per buffer is its best case.
            end = pos + int.from_bytes(data[pos + 1 : pos + 3])
            blocks = raw_parse(bits_from_bytes(data[pos:end]))
            pos = end
            if isinstance(blocks, ValueError):
                raise blocks
            for block in blocks:
                if block.get_category() != CAT:
                    continue
                records = uap_parse(block.get_raw_records())
                if isinstance(records, ValueError):
                    raise records
                for record in () if parse_only else records:
                    items = record.items_regular
                    decoded = {name: nonspare(nsp) for name, nsp in items.items()}
                    if not decoded:
                        raise ValueError("libasterix returned an empty record")
                    if sink is not None:
                        sink.append(decoded)
                count += len(records)
        return count

    # No context-dependent rule anywhere in the two specs: nonspare() relies on it.
    for nsp in spec.cv_record.cv_items_dict.values():
        assert issubclass(nsp.cv_rule, base.RuleVariationContextFree), nsp

    method = "RawDatablock.parse + Cat_048_1_32.cv_uap.parse, one block at a time"
    if parse_only:
        method += ", no value converted (parse only: NOT a full decode)"
    else:
        method += ", then every element of every item converted to its value (RE too)"
    return decode, method


# --- asterix_decoder ----------------------------------------------------------------------

# Keys that asterix_decoder puts in every record dict besides the items (I010, I140, ...).
_DEC_META = {"category", "len", "crc", "ts", "hexdata"}


def asterix_decoder_decoder() -> tuple[Decoder, str]:
    """A full decode with asterix_decoder: its C++ parser builds a dict per record.

    Each record comes back as a dict with one nested dict per item and a ``{"val": ...}``
    per field, every field of every item converted to a Python value (verbose=False
    leaves out the descriptions and meanings, which our codec does not produce either).
    """
    parse_with_offset = importlib.import_module("asterix").parse_with_offset

    def decode(data: bytes, sink: list[Any] | None = None) -> int:
        count, offset, size = 0, 0, len(data)
        while offset < size:
            records, after = parse_with_offset(data, offset, DEC_BLOCKS_PER_CALL, verbose=False)
            if after <= offset:
                raise ValueError(f"asterix_decoder stopped at offset {offset}")
            count += len(records)
            offset = after
            if sink is not None:
                sink.extend(records)
        return count

    method = (
        f"asterix.parse_with_offset(data, offset, {DEC_BLOCKS_PER_CALL}, verbose=False) "
        "over the whole stream: a list of dicts, every field of every item as a value"
    )
    return decode, method


def check_decoder_records(records: list[Any]) -> None:
    """asterix_decoder fails silently on records it cannot parse (item-less dicts)."""
    for record in records:
        if record.get("category") == CAT and not record.keys() - _DEC_META:
            raise ValueError("asterix_decoder returned a record without items")


# --- main ---------------------------------------------------------------------------------

PEERS = ("libasterix", "asterix_decoder")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("peer", choices=PEERS)
    parser.add_argument("stream", type=Path, help="concatenated CAT048 data blocks")
    parser.add_argument("repeats", type=int, help="timed decodes of the whole stream")
    parser.add_argument(
        "--parse-only",
        action="store_true",
        help="libasterix: parse records without converting any value (for reference only)",
    )
    parser.add_argument(
        "--dump",
        type=int,
        default=0,
        metavar="N",
        help="print the first N decoded records (JSON) to stderr, to see what is produced",
    )
    args = parser.parse_args(argv)
    if args.parse_only and args.peer != "libasterix":
        parser.error("--parse-only is for libasterix only")

    import asterix

    repo_codec = Path(__file__).resolve().parents[1] / "asterix"
    if Path(asterix.__file__).resolve().parent == repo_codec:
        parser.error("imported the repository's asterix package, not the peer's venv")

    if args.peer == "libasterix":
        decode, method = libasterix_decoder(args.parse_only)
    else:
        decode, method = asterix_decoder_decoder()
    data = args.stream.read_bytes()

    warm: list[Any] = []
    decode(block_prefix(data, WARMUP_BYTES), warm)
    if args.peer == "asterix_decoder":
        check_decoder_records(warm)
    for record in warm[: args.dump]:
        print(json.dumps(record, default=repr), file=sys.stderr)

    seconds: list[float] = []
    records = 0
    for _ in range(args.repeats):
        start = time.perf_counter()
        records = decode(data)
        seconds.append(time.perf_counter() - start)

    result = {
        "peer": args.peer,
        "version": importlib.metadata.version(args.peer),
        "method": method,
        "records": records,
        "seconds": seconds,
    }
    print(json.dumps(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
