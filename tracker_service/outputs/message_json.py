"""The JSON of a batch's track messages, written from its columns (``json_rows``): one
template per message type, filled for every update of the batch at once, byte for byte
what the models' ``model_dump_json`` writes (``LocalTrackMessage``,
``SystemTrackMessage``: ``tests/test_outputs_updates.py``).

A batch costs two calls: pydantic-core's JSON writer over every number of the batch
(``json_rows.Numbers``, in the order the kernel takes them), then one compiled pass that
lays the templates out (the slots' values, the sources, DAPs, last plots and ISO times of
each row) and writes the rows. The outputs' batches are small (a radar's datagram: about
20 local and 25 system updates on `scale`), so the work per batch outside the compiled
code is kept to a few calls.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba
from tracker_service.outputs.json_rows import (
    HEX6,
    INTEGER,
    INTEGER_OR_NULL,
    JOIN,
    LITERAL,
    NUMBER,
    NUMBERS,
    OCTAL4,
    PART_OR_NULL,
    Literals,
    Numbers,
    Rendered,
    Table,
    Template,
    render_parts,
    render_rows,
)
from tracker_service.outputs.messages import DAP_NAMES
from tracker_service.outputs.updates import STATUSES, SystemBatch

__all__ = ["MessageWriter", "iso_times"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]
Bytes = npt.NDArray[np.uint8]

_COVARIANCE = "[[%s,%s,%s,%s],[%s,%s,%s,%s],[%s,%s,%s,%s],[%s,%s,%s,%s]]"
_LOCAL = (
    '{"radar":%s,"number":%s,"time":%s,"x_m":%s,"y_m":%s,"vx_mps":%s,"vy_mps":%s,'
    f'"covariance":{_COVARIANCE},"flight_level":%s,"climb_rate_fpm":%s,"status":%s,'
    '"plot_id":%s,"mode3a":%s,"address":%s,"model_probabilities":[%s]}'
)
_LOCAL_KINDS = (LITERAL, INTEGER, *(NUMBER,) * 23, LITERAL, INTEGER_OR_NULL, OCTAL4, HEX6, NUMBERS)
_LOCAL_NUMBERS = 23
"""time, x, y, vx, vy, the 16 of the covariance, flight level, climb rate (ft/min)."""
_SYSTEM = (
    '{"number":%s,"time":%s,"time_iso":%s,"lat":%s,"lon":%s,"altitude_m":%s,'
    '"flight_level":%s,"x_m":%s,"y_m":%s,"vx_mps":%s,"vy_mps":%s,"ground_speed_mps":%s,'
    f'"track_angle_deg":%s,"climb_rate_fpm":%s,"covariance":{_COVARIANCE},'
    '"position_sigma_m":%s,"address":%s,"callsign":%s,"mode3a":%s,"mode3a_changed":%s,'
    '"first":%s,"sources":[%s],"status":%s,"last_plot":%s,'
    '"ages":{"psr":%s,"ssr":%s,"mode_s":%s,"adsb":%s},"duplicate_address":%s,'
    '"adsb_inconsistent":%s,"daps":[%s]}'
)
_STATE = 29
"""A system update's state numbers, in the template's order: time, lat, lon, altitude,
flight level, x, y, vx, vy, ground speed, track angle, climb rate, the 16 of the
covariance, position sigma."""
_SYSTEM_KINDS = (
    INTEGER,
    NUMBER,
    PART_OR_NULL,
    *(NUMBER,) * (_STATE - 1),
    HEX6,
    LITERAL,
    OCTAL4,
    LITERAL,
    LITERAL,
    JOIN,
    LITERAL,
    PART_OR_NULL,
    *(NUMBER,) * 4,
    LITERAL,
    LITERAL,
    JOIN,
)
_SOURCE = '{"radar":%s,"local_track":%s,"age_s":%s,"plot_id":%s}'
_SOURCE_KINDS = (LITERAL, INTEGER, NUMBER, INTEGER_OR_NULL)
_DAP = '{"name":%s,"value":%s,"age_s":%s}'
_DAP_KINDS = (LITERAL, NUMBER, NUMBER)
_LAST_PLOT = '{"radar":%s,"time":%s,"lat":%s,"lon":%s,"range_m":%s,"azimuth_deg":%s}'
_LAST_PLOT_KINDS = (LITERAL, *(NUMBER,) * 5)
_ISO_LENGTH = 27
"""2026-06-01T10:00:00.500000Z"""


def iso_times(posix: FloatArray) -> list[str]:
    """``messages.iso_time`` of each time, by the compiled writer (unquoted)."""
    data, starts, ends = _iso_rows(np.ascontiguousarray(posix, dtype=np.float64))
    text = data.tobytes().decode()
    return [text[a + 1 : b - 1] for a, b in zip(starts.tolist(), ends.tolist(), strict=True)]


class MessageWriter:
    """Writes the messages of batches; keeps the texts they share (``Literals``)."""

    def __init__(self) -> None:
        literals = self.literals = Literals()
        self._local = Template.of(_LOCAL, _LOCAL_KINDS, literals)
        self._system = Template.of(_SYSTEM, _SYSTEM_KINDS, literals)
        self._source = Template.of(_SOURCE, _SOURCE_KINDS, literals)
        self._dap = Template.of(_DAP, _DAP_KINDS, literals)
        self._last_plot = Template.of(_LAST_PLOT, _LAST_PLOT_KINDS, literals)
        # Literal ids the kernels write: null, false and true, the statuses, DAP names.
        self._words = np.array(
            [
                literals.add(b"null"),
                literals.add(b"false"),
                literals.add(b"true"),
                *(literals.string(s) for s in STATUSES),
            ],
            dtype=np.int64,
        )
        self._local_statuses = np.array(
            [literals.string(s) for s in ("tentative", "confirmed", "coasting", "deleted")],
            dtype=np.int64,
        )
        self._dap_names = np.array([literals.string(name) for name in DAP_NAMES], dtype=np.int64)

    def local(
        self,
        radar: int,
        number: IntArray,
        numbers: FloatArray,
        status: IntArray,
        plot_id: IntArray,
        mode3a: IntArray,
        address: IntArray,
        probabilities: FloatArray,
    ) -> list[bytes]:
        """Local-track messages: ``radar`` the literal id of the radar's JSON string,
        ``numbers`` (N, 23) as ``_LOCAL`` takes them, ``probabilities`` (N, models)."""
        texts = Numbers.of(np.concatenate((numbers, probabilities), axis=1))
        data, starts, ends = _local_rows(
            self._local.kinds,
            self._local.ids,
            self.literals.arrays(),
            texts.table,
            radar,
            number,
            self._local_statuses[status],
            plot_id,
            mode3a,
            address,
            probabilities.shape[1],
        )
        return Rendered(data, starts, ends).rows()

    def system(
        self,
        batch: SystemBatch,
        radar_literals: IntArray,
        sigma: FloatArray,
        local_numbers: IntArray,
        local_plot_ids: IntArray,
        source_ages: FloatArray,
        plot_position: FloatArray,
    ) -> list[bytes]:
        """System-track messages: ``batch`` the updates' values, ``radar_literals`` the
        literal id of each of its ``radar_names``' JSON string, ``sigma`` the position
        sigmas, ``local_numbers``, ``local_plot_ids`` and ``source_ages`` of the sources
        (the first ``n_sources`` of each row), ``plot_position`` the last plots' time, lat,
        lon, range and azimuth; the callsigns' ids are their JSON strings' literal ids."""
        b = batch
        texts = Numbers.of(
            _system_numbers(
                b.time,
                b.lat,
                b.lon,
                b.altitude_m,
                b.flight_level,
                b.x,
                b.y,
                b.vx,
                b.vy,
                b.ground_speed,
                b.track_angle,
                b.climb_rate_fpm,
                b.covariance,
                sigma,
                b.n_sources,
                source_ages,
                b.ages,
                b.has_dap,
                b.dap_value,
                b.dap_age,
                b.plot_radar,
                plot_position,
            )
        )
        main, source, dap, plot = self._system, self._source, self._dap, self._last_plot
        data, starts, ends = _system_rows(
            main.kinds,
            source.kinds,
            dap.kinds,
            plot.kinds,
            main.ids,
            source.ids,
            dap.ids,
            plot.ids,
            self.literals.arrays(),
            texts.table,
            self._words,
            self._dap_names,
            radar_literals,
            b.number,
            b.time,
            b.address,
            b.callsign,
            b.mode3a,
            b.mode3a_changed,
            b.first,
            b.duplicate_address,
            b.adsb_inconsistent,
            b.status,
            b.n_sources,
            b.source_radar,
            local_numbers,
            local_plot_ids,
            b.has_dap,
            b.plot_radar,
        )
        return Rendered(data, starts, ends).rows()


@numba.njit(cache=True)
def _local_rows(
    kinds: IntArray,
    ids: IntArray,
    lit: Table,
    num: Table,
    radar: int,
    number: IntArray,
    status: IntArray,
    plot_id: IntArray,
    mode3a: IntArray,
    address: IntArray,
    models: int,
) -> Table:
    n = number.size
    width = _LOCAL_NUMBERS + models
    values = np.empty((n, kinds.size), dtype=np.int64)
    counts = np.zeros((n, kinds.size), dtype=np.int64)
    for k in range(n):
        values[k, 0] = radar
        values[k, 1] = number[k]
        for j in range(_LOCAL_NUMBERS):
            values[k, 2 + j] = k * width + j
        values[k, 25] = status[k]
        values[k, 26] = plot_id[k]
        values[k, 27] = mode3a[k]
        values[k, 28] = address[k]
        values[k, 29] = k * width + _LOCAL_NUMBERS
        counts[k, 29] = models
    return render_parts(kinds, ids, values, counts, lit, num)


@numba.njit(cache=True)
def _system_numbers(
    time: FloatArray,
    lat: FloatArray,
    lon: FloatArray,
    altitude: FloatArray,
    flight_level: FloatArray,
    x: FloatArray,
    y: FloatArray,
    vx: FloatArray,
    vy: FloatArray,
    speed: FloatArray,
    angle: FloatArray,
    climb: FloatArray,
    covariance: FloatArray,
    sigma: FloatArray,
    n_sources: IntArray,
    source_ages: FloatArray,
    ages: FloatArray,
    has_dap: BoolArray,
    dap_value: FloatArray,
    dap_age: FloatArray,
    plot_radar: IntArray,
    plot_position: FloatArray,
) -> FloatArray:
    """Every number of a batch's system messages, in the order ``_system_rows`` reads
    them: the states (``_STATE`` a row), the sources' ages, the sensor ages (4 a row),
    the DAPs' values and ages, the last plots' (5 each)."""
    n = time.size
    size = n * (_STATE + 4) + n_sources.sum() + 2 * has_dap.sum() + 5 * (plot_radar >= 0).sum()
    out = np.empty(size, dtype=np.float64)
    i = 0
    for k in range(n):
        for value in (
            time[k],
            lat[k],
            lon[k],
            altitude[k],
            flight_level[k],
            x[k],
            y[k],
            vx[k],
            vy[k],
            speed[k],
            angle[k],
            climb[k],
        ):
            out[i] = value
            i += 1
        for j in range(16):
            out[i] = covariance[k, j]
            i += 1
        out[i] = sigma[k]
        i += 1
    for k in range(n):
        for j in range(n_sources[k]):
            out[i] = source_ages[k, j]
            i += 1
    for k in range(n):
        for j in range(4):
            out[i] = ages[k, j]
            i += 1
    for k in range(n):
        for d in range(has_dap.shape[1]):
            if has_dap[k, d]:
                out[i] = dap_value[k, d]
                out[i + 1] = dap_age[k, d]
                i += 2
    for k in range(n):
        if plot_radar[k] >= 0:
            for j in range(5):
                out[i] = plot_position[k, j]
                i += 1
    return out


@numba.njit(cache=True)
def _system_rows(
    kinds: IntArray,
    source_kinds: IntArray,
    dap_kinds: IntArray,
    plot_kinds: IntArray,
    ids: IntArray,
    source_ids: IntArray,
    dap_ids: IntArray,
    plot_ids: IntArray,
    lit: Table,
    num: Table,
    words: IntArray,
    dap_names: IntArray,
    radar_literals: IntArray,
    number: IntArray,
    time: FloatArray,
    address: IntArray,
    callsign: IntArray,
    mode3a: IntArray,
    changed: BoolArray,
    first: BoolArray,
    duplicate: BoolArray,
    adsb: BoolArray,
    status: IntArray,
    n_sources: IntArray,
    source_radar: IntArray,
    local_numbers: IntArray,
    local_plot_ids: IntArray,
    has_dap: BoolArray,
    plot_radar: IntArray,
) -> Table:
    n = number.size
    null, false = words[0], words[1]
    sources = n_sources.sum()
    daps = has_dap.sum()
    plots = (plot_radar >= 0).sum()
    # The numbers' blocks (``_system_numbers``).
    at_sources = n * _STATE
    at_ages = at_sources + sources
    at_daps = at_ages + 4 * n
    at_plots = at_daps + 2 * daps
    # The rows' parts, one rendering: sources, DAPs, last plots, ISO times.
    source_values = np.empty((sources, 4), dtype=np.int64)
    i = 0
    for k in range(n):
        for j in range(n_sources[k]):
            source_values[i, 0] = radar_literals[source_radar[k, j]]
            source_values[i, 1] = local_numbers[k, j]
            source_values[i, 2] = at_sources + i
            source_values[i, 3] = local_plot_ids[k, j]
            i += 1
    dap_values = np.empty((daps, 3), dtype=np.int64)
    i = 0
    for k in range(n):
        for d in range(has_dap.shape[1]):
            if has_dap[k, d]:
                dap_values[i, 0] = dap_names[d]
                dap_values[i, 1] = at_daps + 2 * i
                dap_values[i, 2] = at_daps + 2 * i + 1
                i += 1
    plot_values = np.empty((plots, 6), dtype=np.int64)
    i = 0
    for k in range(n):
        if plot_radar[k] >= 0:
            plot_values[i, 0] = radar_literals[plot_radar[k]]
            for j in range(5):
                plot_values[i, 1 + j] = at_plots + 5 * i + j
            i += 1
    iso = _iso_rows(time)
    parts = (
        render_parts(
            source_kinds, source_ids, source_values, np.zeros_like(source_values), lit, num
        ),
        render_parts(dap_kinds, dap_ids, dap_values, np.zeros_like(dap_values), lit, num),
        render_parts(plot_kinds, plot_ids, plot_values, np.zeros_like(plot_values), lit, num),
        iso,
    )
    part = _joined(parts)
    values = np.empty((n, kinds.size), dtype=np.int64)
    counts = np.zeros((n, kinds.size), dtype=np.int64)
    first_source, first_dap, next_plot = 0, 0, 0
    at_iso = sources + daps + plots
    column = 2 + _STATE
    for k in range(n):
        values[k, 0] = number[k]
        values[k, 1] = k * _STATE
        values[k, 2] = at_iso + k
        for j in range(1, _STATE):
            values[k, 2 + j] = k * _STATE + j
        values[k, column] = address[k]
        values[k, column + 1] = callsign[k] if callsign[k] >= 0 else null
        values[k, column + 2] = mode3a[k]
        values[k, column + 3] = false + changed[k]
        values[k, column + 4] = false + first[k]
        values[k, column + 5] = first_source
        counts[k, column + 5] = n_sources[k]
        first_source += n_sources[k]
        values[k, column + 6] = words[3 + status[k]]
        if plot_radar[k] >= 0:
            values[k, column + 7] = sources + daps + next_plot
            next_plot += 1
        else:
            values[k, column + 7] = -1
        for j in range(4):
            values[k, column + 8 + j] = at_ages + 4 * k + j
        values[k, column + 12] = false + duplicate[k]
        values[k, column + 13] = false + adsb[k]
        row_daps = has_dap[k].sum()
        values[k, column + 14] = sources + first_dap
        counts[k, column + 14] = row_daps
        first_dap += row_daps
    return render_rows(kinds, ids, values, counts, lit, num, part)


@numba.njit(cache=True)
def _joined(parts: tuple[Table, ...]) -> Table:
    """Renderings one after another, their rows numbered on in that order."""
    size, rows = 0, 0
    for data, starts, _ in parts:
        size += data.size
        rows += starts.size
    out = np.empty(max(size, 1), dtype=np.uint8)
    out_starts = np.empty(rows, dtype=np.int64)
    out_ends = np.empty(rows, dtype=np.int64)
    offset, row = 0, 0
    for data, starts, ends in parts:
        out[offset : offset + data.size] = data
        for i in range(starts.size):
            out_starts[row] = starts[i] + offset
            out_ends[row] = ends[i] + offset
            row += 1
        offset += data.size
    return out, out_starts, out_ends


@numba.njit(cache=True)
def _civil(days: int) -> tuple[int, int, int]:
    """Year, month, day of a day number since 1970-01-01 (proleptic Gregorian; H.
    Hinnant's ``civil_from_days``)."""
    z = days + 719468
    era = (z if z >= 0 else z - 146096) // 146097
    doe = z - era * 146097
    yoe = (doe - doe // 1460 + doe // 36524 - doe // 146096) // 365
    doy = doe - (365 * yoe + yoe // 4 - yoe // 100)
    mp = (5 * doy + 2) // 153
    day = doy - (153 * mp + 2) // 5 + 1
    month = mp + 3 if mp < 10 else mp - 9
    return yoe + era * 400 + (1 if month <= 2 else 0), month, day


@numba.njit(cache=True)
def _put(out: Bytes, pos: int, value: int, width: int) -> int:
    for i in range(width - 1, -1, -1):
        out[pos + i] = 48 + value % 10
        value //= 10
    return pos + width


@numba.njit(cache=True)
def _iso_rows(posix: FloatArray) -> Table:
    """``"2026-06-01T10:00:00.500000Z"`` (quoted) of each time: the microseconds of the
    fractional part rounded half to even, as ``datetime.fromtimestamp`` rounds them."""
    n = posix.size
    out = np.empty(max(n * (_ISO_LENGTH + 2), 1), dtype=np.uint8)
    starts = np.empty(n, dtype=np.int64)
    ends = np.empty(n, dtype=np.int64)
    for k in range(n):
        whole = np.floor(posix[k])
        micro = int(np.rint((posix[k] - whole) * 1e6))
        seconds = int(whole)
        if micro >= 1_000_000:
            micro -= 1_000_000
            seconds += 1
        days = seconds // 86400
        of_day = seconds - days * 86400
        year, month, day = _civil(days)
        pos = k * (_ISO_LENGTH + 2)
        starts[k] = pos
        out[pos] = 34  # '"'
        pos = _put(out, pos + 1, year, 4)
        out[pos] = 45  # "-"
        pos = _put(out, pos + 1, month, 2)
        out[pos] = 45
        pos = _put(out, pos + 1, day, 2)
        out[pos] = 84  # "T"
        pos = _put(out, pos + 1, of_day // 3600, 2)
        out[pos] = 58  # ":"
        pos = _put(out, pos + 1, of_day // 60 % 60, 2)
        out[pos] = 58
        pos = _put(out, pos + 1, of_day % 60, 2)
        out[pos] = 46  # "."
        pos = _put(out, pos + 1, micro, 6)
        out[pos] = 90  # "Z"
        out[pos + 1] = 34
        ends[k] = pos + 2
    return out, starts, ends
