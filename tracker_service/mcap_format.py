"""The MCAP conventions shared by the simulator's recordings and the service's logs: one
writer configuration, JSON schemas of the pydantic message models, exact log times."""

from __future__ import annotations

import math
from typing import IO, Any

import numpy as np
import numpy.typing as npt
from mcap.writer import CompressionType, IndexType, Writer
from pydantic import BaseModel

# The MCAP header's library string. Fixed rather than mcap-python's default (which holds
# its version) so that upgrading mcap alone does not change the bytes of a file.
MCAP_LIBRARY = "tracker-service recording 1"
JSON_SCHEMA_DIALECT = "https://json-schema.org/draft/2020-12/schema"
NS_PER_S = 1_000_000_000
MAX_LOG_TIME = 2**64 - 1


def schema_name(model: type[BaseModel]) -> str:
    """The name of the model's MCAP schema record."""
    return f"tracker_service.{model.__name__}"


def json_schema(model: type[BaseModel]) -> dict[str, Any]:
    """The JSON Schema (draft 2020-12) of a message model, as stored in the MCAP schema."""
    # Serialization mode: the schema describes the JSON in the file, where every field
    # (psr_only included) is always written.
    return {"$schema": JSON_SCHEMA_DIALECT, **model.model_json_schema(mode="serialization")}


def start_mcap(stream: IO[bytes], chunk_size: int) -> Writer:
    """An MCAP writer on ``stream``, started: zstd chunks, every index, statistics, CRCs.
    Every option spelled out: the defaults of a later mcap release must not change the
    bytes. zstd is applied at mcap-python's fixed level (zstandard's default, 3)."""
    writer = Writer(
        stream,
        chunk_size=chunk_size,
        compression=CompressionType.ZSTD,
        index_types=IndexType.ALL,
        repeat_channels=True,
        repeat_schemas=True,
        use_chunking=True,
        use_statistics=True,
        use_summary_offsets=True,
        enable_crcs=True,
        enable_data_crcs=True,
    )
    writer.start(profile="", library=MCAP_LIBRARY)
    return writer


def time_ns(time: float) -> int:
    """POSIX seconds to integer nanoseconds, exact to the float's own resolution."""
    if not math.isfinite(time) or time < 0:
        raise ValueError(f"time {time!r} must be finite POSIX seconds >= 0")
    # time * 1e9 in floating point would lose up to 128 ns at today's epoch times; the
    # fractional part of a float is exact, so split it off first.
    whole = math.floor(time)
    ns = whole * NS_PER_S + round((time - whole) * NS_PER_S)
    if ns > MAX_LOG_TIME:
        raise ValueError(f"time {time!r} is past what MCAP log times can hold")
    return ns


def times_ns(times: npt.NDArray[np.float64]) -> list[int]:
    """:func:`time_ns` of each time, over the array at once (the same integers: the
    fraction split off first, rounded half to even as ``round`` does)."""
    if not (np.isfinite(times).all() and (times >= 0).all()):
        return [time_ns(t) for t in times.tolist()]  # raises for the first bad one
    whole = np.floor(times)
    ns: list[int] = (
        whole.astype(np.int64) * NS_PER_S + np.rint((times - whole) * NS_PER_S).astype(np.int64)
    ).tolist()
    return ns
