"""What the messages of a system track need from its earlier ones, as arrays indexed by
track number, and the compiled pass that takes a batch of the fuser's rows through it.

A system-track message repeats the track's last plot while no plot updates it, gives the
age of each sensor type's last detection and of each Mode S DAP, keeps the callsign while
the address stays, says whether the Mode 3/A code changed and whether another live track
carries the same address. ``MessageMapper.system`` (the per-message path, a dict and
models per track) is the reference; ``SystemState.step`` does the same, row by row in the
batch's order, in one compiled loop (numba, ``cache=True``) over the batch and the
per-track arrays, and gives each row's values as arrays (``StepResult``), from which the
messages are written for the whole batch (``json_rows``) and CAT062 and the map read.

The live tracks' addresses are counted in a small open-addressing table (address -> live
tracks holding it), rebuilt from the per-track arrays when it fills up, so that it holds
the live addresses only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba

__all__ = ["DAPS", "SENSORS", "StepInput", "StepResult", "SystemState"]

SENSORS = 4
"""PSR, SSR, Mode S, ADS-B: ``SystemTrackMessage.ages``."""
DAPS = 10
"""``messages.DAP_NAMES``."""
PLOT_FIELDS = 5
"""A last plot's time, lat, lon, range (m) and azimuth (deg); NaN: absent."""

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

_EMPTY = -1


@dataclass(frozen=True)
class StepInput:
    """A batch for :meth:`SystemState.step`: the fuser's rows and the plots they name.

    Per row: ``number``, ``time``, ``ended``, ``address`` and ``mode3a`` (-1 none),
    ``plot_id`` and ``fresh`` (the row's plot, which updates the track when fresh and in
    the plot arrays), ``radar`` (the id its last plot is to name), ``n_sources``,
    ``local_time`` (each source's local track's latest update, NaN when unknown: the
    source's age is then 0). Per plot: ``plot_ids``, ``plot_time``, ``plot_callsign``
    (an id, -1 none), ``plot_type`` (I048/020 TYP, an index of ``sensors``: for each
    type, bit i set when it is a detection of ``SENSORS`` type i), ``plot_daps`` (the
    DAPs, NaN where absent), ``plot_position`` (``PLOT_FIELDS``)."""

    number: IntArray
    time: FloatArray
    ended: BoolArray
    address: IntArray
    mode3a: IntArray
    plot_id: IntArray
    fresh: BoolArray
    radar: IntArray
    n_sources: IntArray
    local_time: FloatArray
    plot_ids: IntArray
    plot_time: FloatArray
    plot_callsign: IntArray
    plot_type: IntArray
    sensors: IntArray
    plot_daps: FloatArray
    plot_position: FloatArray


@dataclass(frozen=True)
class StepResult:
    """Each row's values that follow from its track's history: ``first``,
    ``mode3a_changed``, ``duplicate_address``, ``callsign`` (id, -1 none), ``ages``
    (seconds, NaN: never), ``source_ages``, ``plot_radar`` (-1: no last plot) and
    ``plot_position`` (``PLOT_FIELDS``), ``has_dap``, ``dap_value``, ``dap_age``."""

    first: BoolArray
    mode3a_changed: BoolArray
    duplicate_address: BoolArray
    callsign: IntArray
    ages: FloatArray
    source_ages: FloatArray
    plot_radar: IntArray
    plot_position: FloatArray
    has_dap: BoolArray
    dap_value: FloatArray
    dap_age: FloatArray


class SystemState:
    """The per-track arrays (grown with the largest track number met) and the address
    table; see the module docstring."""

    def __init__(self, capacity: int = 1024) -> None:
        self.live = np.zeros(capacity, dtype=np.bool_)
        self.address = np.full(capacity, -1, dtype=np.int64)
        self.mode3a = np.full(capacity, -1, dtype=np.int64)
        self.callsign = np.full(capacity, -1, dtype=np.int64)
        self.sensor_time = np.full((capacity, SENSORS), np.nan)
        self.has_dap = np.zeros((capacity, DAPS), dtype=np.bool_)
        self.dap_value = np.full((capacity, DAPS), np.nan)
        self.dap_time = np.full((capacity, DAPS), np.nan)
        self.plot_radar = np.full(capacity, -1, dtype=np.int64)
        self.plot_position = np.full((capacity, PLOT_FIELDS), np.nan)
        self._keys = np.full(64, _EMPTY, dtype=np.int64)
        self._counts = np.zeros(64, dtype=np.int64)
        self._used = 0

    def end_all(self) -> None:
        self.live[:] = False
        self._rebuild_addresses(64)

    def step(self, batch: StepInput) -> StepResult:
        """The batch's rows in order, each as the per-message path takes it."""
        n = batch.number.size
        if n and int(batch.number.max()) >= self.live.size:
            self._grow(int(batch.number.max()) + 1)
        # Room for every row's address as a new key, at most half full.
        if 2 * (self._used + n) > self._keys.size:
            self._rebuild_addresses(self._keys.size)
        width = batch.local_time.shape[1]
        result = StepResult(
            first=np.empty(n, dtype=np.bool_),
            mode3a_changed=np.empty(n, dtype=np.bool_),
            duplicate_address=np.empty(n, dtype=np.bool_),
            callsign=np.empty(n, dtype=np.int64),
            ages=np.empty((n, SENSORS)),
            source_ages=np.full((n, width), np.nan),
            plot_radar=np.empty(n, dtype=np.int64),
            plot_position=np.empty((n, PLOT_FIELDS)),
            has_dap=np.empty((n, DAPS), dtype=np.bool_),
            dap_value=np.empty((n, DAPS)),
            dap_age=np.empty((n, DAPS)),
        )
        self._used = _step(
            batch.number,
            batch.time,
            batch.ended,
            batch.address,
            batch.mode3a,
            batch.plot_id,
            batch.fresh,
            batch.radar,
            batch.n_sources,
            batch.local_time,
            batch.plot_ids,
            batch.plot_time,
            batch.plot_callsign,
            batch.plot_type,
            batch.sensors,
            batch.plot_daps,
            batch.plot_position,
            self.live,
            self.address,
            self.mode3a,
            self.callsign,
            self.sensor_time,
            self.has_dap,
            self.dap_value,
            self.dap_time,
            self.plot_radar,
            self.plot_position,
            self._keys,
            self._counts,
            self._used,
            result.first,
            result.mode3a_changed,
            result.duplicate_address,
            result.callsign,
            result.ages,
            result.source_ages,
            result.plot_radar,
            result.plot_position,
            result.has_dap,
            result.dap_value,
            result.dap_age,
        )
        return result

    def _grow(self, needed: int) -> None:
        size = max(needed, 2 * self.live.size)
        grown = self.live.size
        for name, fill in (
            ("live", False),
            ("address", -1),
            ("mode3a", -1),
            ("callsign", -1),
            ("sensor_time", np.nan),
            ("has_dap", False),
            ("dap_value", np.nan),
            ("dap_time", np.nan),
            ("plot_radar", -1),
            ("plot_position", np.nan),
        ):
            old = getattr(self, name)
            new = np.full((size, *old.shape[1:]), fill, dtype=old.dtype)
            new[:grown] = old
            setattr(self, name, new)

    def _rebuild_addresses(self, size: int) -> None:
        """The address table again from the live tracks, at least ``size`` slots and at
        most a quarter full (keys whose count fell to 0 are dropped)."""
        held = self.address[self.live & (self.address >= 0)]
        keys, counts = np.unique(held, return_counts=True)
        size = max(size, 64)
        while 4 * (keys.size + 1) > size:
            size *= 2
        self._keys = np.full(size, _EMPTY, dtype=np.int64)
        self._counts = np.zeros(size, dtype=np.int64)
        for key, count in zip(keys.tolist(), counts.tolist(), strict=True):
            _add(self._keys, self._counts, key, count)
        self._used = int(keys.size)


@numba.njit(cache=True)
def _slot(keys: IntArray, key: int) -> int:
    """The slot of ``key`` in the table, or the empty slot where it would go."""
    mask = int(keys.size - 1)
    # Fibonacci hashing; signed arithmetic from here on (numba makes uint64 + int64 a float).
    spread = (np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)) >> np.uint64(32)
    slot = int(np.int64(spread & np.uint64(mask)))
    while keys[slot] != _EMPTY and keys[slot] != key:
        slot = (slot + 1) & mask
    return slot


@numba.njit(cache=True)
def _add(keys: IntArray, counts: IntArray, key: int, delta: int) -> int:
    """Adds ``delta`` to the count of ``key``; 1 when the key is new, else 0."""
    slot = _slot(keys, key)
    new = 0
    if keys[slot] == _EMPTY:
        keys[slot] = key
        new = 1
    counts[slot] += delta
    return new


@numba.njit(cache=True)
def _count(keys: IntArray, counts: IntArray, key: int) -> int:
    slot = _slot(keys, key)
    return int(counts[slot]) if keys[slot] == key else 0


@numba.njit(cache=True)
def _age(now: float, then: float) -> float:
    """``max(now - then, 0.0)`` as Python has it (NaN stays NaN)."""
    age = now - then
    if age < 0.0:
        return 0.0
    return age


@numba.njit(cache=True)
def _step(
    number: IntArray,
    time: FloatArray,
    ended: BoolArray,
    address: IntArray,
    mode3a: IntArray,
    plot_id: IntArray,
    fresh: BoolArray,
    radar: IntArray,
    n_sources: IntArray,
    local_time: FloatArray,
    plot_ids: IntArray,
    plot_time: FloatArray,
    plot_callsign: IntArray,
    plot_type: IntArray,
    sensors: IntArray,
    plot_daps: FloatArray,
    plot_position: FloatArray,
    live: BoolArray,
    track_address: IntArray,
    track_mode3a: IntArray,
    track_callsign: IntArray,
    sensor_time: FloatArray,
    has_dap: BoolArray,
    dap_value: FloatArray,
    dap_time: FloatArray,
    track_plot_radar: IntArray,
    track_plot: FloatArray,
    keys: IntArray,
    counts: IntArray,
    used: int,
    out_first: BoolArray,
    out_changed: BoolArray,
    out_duplicate: BoolArray,
    out_callsign: IntArray,
    out_ages: FloatArray,
    out_source_ages: FloatArray,
    out_plot_radar: IntArray,
    out_plot: FloatArray,
    out_has_dap: BoolArray,
    out_dap_value: FloatArray,
    out_dap_age: FloatArray,
) -> int:
    for k in range(number.size):
        t, now = number[k], time[k]
        previous = live[t]
        if not previous:
            sensor_time[t, :] = np.nan
            has_dap[t, :] = False
            track_plot_radar[t] = -1
            track_plot[t, :] = np.nan
        # The row's fresh plot among the batch's (a few dozen: a scan; the last of an id,
        # as a dict of the ids keeps it).
        p = -1
        if fresh[k]:
            for i in range(plot_ids.size - 1, -1, -1):
                if plot_ids[i] == plot_id[k]:
                    p = i
                    break
        callsign = -1
        if p >= 0:
            callsign = plot_callsign[p]
            at = plot_time[p]
            for d in range(has_dap.shape[1]):
                value = plot_daps[p, d]
                if np.isfinite(value):
                    has_dap[t, d] = True
                    dap_value[t, d] = value
                    dap_time[t, d] = at
            typ = plot_type[p]
            bits = sensors[typ] if 0 <= typ < sensors.size else 0
            for s in range(sensor_time.shape[1]):
                if bits >> s & 1:
                    sensor_time[t, s] = at
            track_plot_radar[t] = radar[k]
            track_plot[t, :] = plot_position[p, :]
        a, code = address[k], mode3a[k]
        # The plot's callsign; without one, the track's own while its address stays.
        if callsign < 0 and previous and track_address[t] == a:
            callsign = track_callsign[t]
        out_first[k] = not previous
        out_changed[k] = previous and track_mode3a[t] >= 0 and track_mode3a[t] != code
        if previous and track_address[t] >= 0:
            _add(keys, counts, track_address[t], -1)
        out_duplicate[k] = a >= 0 and _count(keys, counts, a) > 0
        out_callsign[k] = callsign
        for s in range(sensor_time.shape[1]):
            out_ages[k, s] = _age(now, sensor_time[t, s])
        for i in range(n_sources[k]):
            then = local_time[k, i]
            out_source_ages[k, i] = _age(now, now if np.isnan(then) else then)
        out_plot_radar[k] = track_plot_radar[t]
        out_plot[k, :] = track_plot[t, :]
        for d in range(has_dap.shape[1]):
            out_has_dap[k, d] = has_dap[t, d]
            out_dap_value[k, d] = dap_value[t, d]
            out_dap_age[k, d] = _age(now, dap_time[t, d])
        if ended[k]:
            live[t] = False
        else:
            live[t] = True
            track_address[t], track_mode3a[t], track_callsign[t] = a, code, callsign
            if a >= 0:
                used += _add(keys, counts, a, 1)
    return used
