"""The ``tracker-service`` command: one entry point, one subcommand per job."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="tracker-service",
        description="ASTERIX-fed multiradar tracker service.",
    )
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    decode = commands.add_parser(
        "decode",
        help="decode a capture (pcap, pcapng, GPS, final format, raw, hex) to JSON lines",
        description="Print one JSON object per ASTERIX record, in file order; decode errors "
        "go to stderr as JSON lines. The container format is detected from the content.",
    )
    decode.add_argument("path", help="the capture file")
    decode.add_argument(
        "--summary",
        action="store_true",
        help="decode everything but print only counts, duplicates, time span and errors",
    )
    decode.add_argument(
        "--bds",
        action="store_true",
        help='add the named fields of Mode S BDS 4,0/5,0/6,0 registers to I048/250 ("BDS")',
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    if args.command == "decode":
        from tracker_service.decode import main as decode_main

        try:
            return decode_main(args.path, args.summary, args.bds)
        except BrokenPipeError:
            # `decode ... | head` closes the pipe early; that is not an error.
            sys.stderr.close()
            return 0
    return 2


if __name__ == "__main__":
    sys.exit(main())
