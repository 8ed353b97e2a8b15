"""A pure ASTERIX codec: categories 001, 002, 021, 034, 048, 062 and 065, generated from
their structured specifications (CAT001 with its two UAPs, plot and track). It knows
nothing of tracking.

- ``decode_blocks(data)`` yields ``Block`` (records as dicts of items) and ``DecodeError``
  events; it never raises on bad bytes.
- ``encode_record(cat, items)`` / ``encode_block(cat, records)`` build bytes from values.
- ``asterix.containers`` unwraps captures (pcap, pcapng, GPS, final format, hex, raw).
- ``asterix.plots`` extracts CAT048 and CAT001 plots into numpy arrays for the tracker.
- ``asterix.columns`` reads chosen elements of any category's records into numpy columns
  (the plot path's walk; ``ColumnReader`` for one category's blocks, e.g. CAT021).
- ``asterix.bds`` decodes Mode S registers 4,0, 5,0 and 6,0.
"""

from asterix.codec import (
    SUPPORTED_CATEGORIES,
    Block,
    DecodeError,
    codec,
    decode_blocks,
    encode_block,
    encode_record,
)
from asterix.engine import EncodeError

__all__ = [
    "SUPPORTED_CATEGORIES",
    "Block",
    "DecodeError",
    "EncodeError",
    "codec",
    "decode_blocks",
    "encode_block",
    "encode_record",
]
