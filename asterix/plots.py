"""The plot-extraction path: CAT048 and CAT001 bytes straight to numpy columns for the tracker.

The general decoder builds a dict per item; a tracker fed with tens of radars needs only a
dozen fields per plot. This path walks each record once to find where the wanted items
start (stepping over the others by their size), then reads every column for all records
at once with numpy (``asterix.columns``): the values are identical to the general
decoder's.
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix import daps, spec
from asterix.codec import DecodeError, codec
from asterix.columns import (
    PADDING,
    Column,
    Walker,
    item_slots,
    layout,
    locate,
    read_columns,
    walk,
)
from asterix.engine import ICAO_CHARACTERS, icao_text

# The items CAT048 and CAT001 share, in the same element paths.
_SOURCE = (Column("sac", "010", ("SAC",)), Column("sic", "010", ("SIC",)))
_FLAGS = tuple(Column(name, "020", (name.upper(),)) for name in ("sim", "spi", "rab", "tst"))
_POSITION_AND_CODE = (
    Column("rho", "040", ("RHO",)),
    Column("theta", "040", ("THETA",)),
    Column("mode3a", "070", ("MODE3A",)),
    Column("mode3a_invalid", "070", ("V",)),
    Column("mode3a_garbled", "070", ("G",)),
    Column("mode3a_smoothed", "070", ("L",)),
)
_LEVEL_VALIDITY = (
    Column("flight_level_invalid", "090", ("V",)),
    Column("flight_level_garbled", "090", ("G",)),
)
_VELOCITY = (Column("ground_speed", "200", ("GSP",)), Column("heading", "200", ("HDG",)))

COLUMNS: dict[int, tuple[Column, ...]] = {
    48: (
        *_SOURCE,
        Column("time_of_day", "140"),
        Column("typ", "020", ("TYP",)),
        *_FLAGS,
        *_POSITION_AND_CODE,
        Column("flight_level", "090", ("FL",)),
        *_LEVEL_VALIDITY,
        Column("address", "220"),
        Column("track_number", "161", ("TRN",)),
        Column("height_3d", "110", ("3DH",)),
        *_VELOCITY,
    ),
    # CAT001 says PSR/SSR/combined in SSRPSR, which has the values of CAT048 TYP 0-3; its
    # TYP says plot or track (a radar's own track: ``track_report``); its I141 is the time
    # of day truncated to 512 s (``ingest.PlotClock`` unrolls it).
    1: (
        *_SOURCE,
        Column("truncated_time", "141"),
        Column("typ", "020", ("SSRPSR",)),
        Column("track_report", "020", ("TYP",)),
        *_FLAGS,
        *_POSITION_AND_CODE,
        Column("flight_level", "090", ("HGT",)),
        *_LEVEL_VALIDITY,
        Column("track_number", "161"),
        *_VELOCITY,
    ),
}
"""The columns of each category's plots. Floats (NaN when absent) for quantities, integers
(-1 when absent) for the rest. ``mode3a`` is the 12-bit code as an integer (print it with
``%04o``), ``address`` the 24-bit ICAO address. V bits keep the spec's sense: 1 = not
validated. ``typ`` is CAT048 I020 TYP (CAT001: SSRPSR, the same values 0-3)."""
CATEGORIES = tuple(COLUMNS)


_FIELDS = {cat: tuple(locate(cat, c) for c in columns) for cat, columns in COLUMNS.items()}
_TEXT_ITEMS = {48: ("240", "RE", "250")}  # callsign, extended range and DAPs, read apart
_SLOTS = {cat: item_slots(columns, _TEXT_ITEMS.get(cat, ())) for cat, columns in COLUMNS.items()}
"""Per category, the row slot of each wanted item's start; slot 0 holds the record offset."""


def _column_dtypes() -> list[tuple[str, Any]]:
    kinds: dict[str, Any] = {}
    for fields in _FIELDS.values():
        for f in fields:
            kind = np.float64 if f.lsb is not None else np.int32
            if kinds.setdefault(f.column.name, kind) is not kind:
                raise spec.SpecError(f"column {f.column.name} is a number in one category only")
    return list(kinds.items())


PLOT_DTYPE = np.dtype(
    [
        ("offset", np.int64),
        ("category", np.uint8),
        *_column_dtypes(),
        ("callsign", "U8"),
        ("extended_range", np.bool_),
        *((name, np.float64) for name in daps.DAP_COLUMNS),
    ]
)


@dataclass
class PlotBatch:
    """Plots of one input: one row per CAT048 or CAT001 record, in input order, and the
    decode errors met."""

    plots: npt.NDArray[Any]
    errors: list[DecodeError]


_WALKERS: dict[int, Walker] = {}


def _walker(cat: int) -> Walker | None:
    """The walker of a plot category (made at its first use), None for other categories."""
    walker = _WALKERS.get(cat)
    if walker is None and cat in COLUMNS:
        walker = _WALKERS[cat] = Walker(cat, _SLOTS[cat])
    return walker


def extract_plots(data: bytes, offset: int = 0) -> PlotBatch:
    """Plots of every CAT048 and CAT001 record in a run of data blocks (other categories
    skipped), in input order.

    ``offset`` is added to the reported positions (record offsets and errors).
    """
    rows: dict[int, array[int]] = {}
    errors: list[DecodeError] = []
    walk(data, rows, errors, _walker)
    buf = np.frombuffer(data, dtype=np.uint8)
    parts = [_plots(cat, data, buf, found) for cat, found in rows.items()]
    if not parts:
        plots = np.zeros(0, dtype=PLOT_DTYPE)
    elif len(parts) == 1:
        plots = parts[0]
    else:  # only odd feeds mix CAT001 and CAT048 in one datagram
        plots = np.concatenate(parts)
        plots = plots[np.argsort(plots["offset"], kind="stable")]
    if offset:
        plots["offset"] += offset
    return PlotBatch(plots, [_shifted(e, offset) for e in errors])


def _blank() -> Any:
    """A plot row with every column absent: NaN, -1, "" and False."""
    row = np.zeros(1, dtype=PLOT_DTYPE)
    for name in PLOT_DTYPE.names or ():
        if PLOT_DTYPE[name] == np.float64:
            row[name] = np.nan
        elif PLOT_DTYPE[name] == np.int32:
            row[name] = -1
    return row[0]


_BLANK = _blank()
_FIRST_DAP_COLUMN = (PLOT_DTYPE.names or ()).index(daps.DAP_COLUMNS[0])
_BLANK_VALUES = tuple(_BLANK.tolist())
_BLANK_ROW = np.array([_BLANK], dtype=PLOT_DTYPE).view(np.dtype((np.void, PLOT_DTYPE.itemsize)))
"""The blank row as opaque bytes: repeated, the rows a batch starts from (the columns its
category never fills stay NaN, -1, "" or False)."""
SMALL_BATCH = 14
"""Up to this many records of a category, a datagram's plots are read record by record in
Python: numpy's per-call cost outweighs its per-row gain. Measured crossover (every field
at once, ``read_columns``): 12-16 records of CAT048. Many CAT001 radars send one plot a
datagram."""
_ROW_FIELDS = {
    cat: tuple(
        (
            (PLOT_DTYPE.names or ()).index(f.column.name),
            _SLOTS[cat][f.column.item],
            f.offset,
            f.octets,
            f.shift,
            (1 << f.bits) - 1,
            1 << (f.bits - 1) if f.signed else 0,
            f.lsb,
            f.extent > 0,
        )
        for f in fields
    )
    for cat, fields in _FIELDS.items()
}


_LAYOUTS = {cat: layout(fields, _SLOTS[cat]) for cat, fields in _FIELDS.items()}


def _plots(cat: int, data: bytes, buf: npt.NDArray[np.uint8], rows: array[int]) -> Any:
    slots = _SLOTS[cat]
    starts = np.frombuffer(rows, dtype=np.int64).reshape(-1, len(slots) + 1)
    if len(starts) <= SMALL_BATCH:
        plots = _plots_by_record(cat, data, starts.tolist())
    else:
        plots = np.repeat(_BLANK_ROW, len(starts)).view(PLOT_DTYPE)
        plots["offset"] = starts[:, 0]
        plots["category"] = cat
        padded = np.frombuffer(data + PADDING, dtype=np.uint8)
        read_columns(plots, padded, starts, _LAYOUTS[cat])
        if "240" in slots:
            plots["callsign"] = _callsigns(padded, starts[:, slots["240"]])
        if "250" in slots:
            for name, values in daps.decode_columns(buf, starts[:, slots["250"]]).items():
                plots[name] = values
    if "RE" in slots:
        _apply_extended_range(data, plots, starts[:, 0], starts[:, slots["RE"]])
    return plots


def _plots_by_record(cat: int, data: bytes, starts: list[list[int]]) -> Any:
    """The same columns as ``read_columns`` and ``_callsigns`` give, one record at a time."""
    callsign = _SLOTS[cat].get("240", -1)
    callsign_column = (PLOT_DTYPE.names or ()).index("callsign")
    dap_slot = _SLOTS[cat].get("250", -1)
    out = []
    for row in starts:
        values = list(_BLANK_VALUES)
        values[0], values[1] = row[0], cat
        for column, slot, offset, octets, shift, mask, half, lsb, extended in _ROW_FIELDS[cat]:
            at = row[slot]
            if at < 0:
                continue
            at += offset
            if extended and not data[at - 1] & 1:
                continue  # the extent is not there
            raw = (int.from_bytes(data[at : at + octets]) >> shift) & mask
            if half and raw >= half:
                raw -= half << 1
            values[column] = raw if lsb is None else raw * lsb
        if callsign >= 0 and row[callsign] >= 0:
            at = row[callsign]
            values[callsign_column] = icao_text(int.from_bytes(data[at : at + 6]), 8)
        if dap_slot >= 0 and row[dap_slot] >= 0:
            daps.decode_record(data, row[dap_slot], values, _FIRST_DAP_COLUMN)
        out.append(tuple(values))
    return np.array(out, dtype=PLOT_DTYPE)


def _shifted(error: DecodeError, offset: int) -> DecodeError:
    return DecodeError(error.offset + offset, error.category, error.reason)


_ICAO_TABLE = np.array(list(ICAO_CHARACTERS))


def _callsigns(buf: npt.NDArray[np.uint8], starts: npt.NDArray[np.int64]) -> Any:
    out = np.full(len(starts), "", dtype="U8")
    present = starts >= 0
    if present.any():
        # Six octets, from the big-endian word of eight (``buf`` padded after the data).
        raw = buf[starts[present][:, None] + np.arange(8)].view(">u8")[:, 0] >> np.uint64(16)
        shifts = np.arange(42, -1, -6, dtype=np.uint64)
        codes = (raw[:, None] >> shifts) & np.uint64(63)
        out[present] = np.ascontiguousarray(_ICAO_TABLE[codes]).view("U8")[:, 0]
    return out


def _apply_extended_range(
    data: bytes, plots: npt.NDArray[Any], records: npt.NDArray[np.int64], re: npt.NDArray[np.int64]
) -> None:
    """Beyond 256 NM the CAT048 range is in the RE field (REF ERR); rare, so decode those
    fully."""
    for row in np.flatnonzero(re >= 0):
        items, _ = codec(48).decode_record(data, int(records[row]), len(data))
        expansion = items.get("RE")
        if isinstance(expansion, dict) and "ERR" in expansion:
            plots["rho"][row] = expansion["ERR"]
            plots["extended_range"][row] = True
