"""The fuser's two tables: the local tracks seen so far, and the system tracks.

The local-track table holds one row per radar and local track number, with the latest
state and the system track it feeds, found by a sorted key index; the system-track table
is indexed by the system track number (1..``MAX_SYSTEM_NUMBER``). Both are held column by column
(``Columns``).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion.arrays import (
    is_member,
    kernel_indices,
    last_of_each,
    marked_numbers,
    rank_within,
)
from tracker_service.fusion.messages import MAX_SOURCES, MAX_SYSTEM_NUMBER
from tracker_service.resident_arrays import resident_zeros
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray
from tracker_service.tracking.tracker import CONFIRMED as LOCAL_CONFIRMED
from tracker_service.tracking.tracker import DELETED as LOCAL_DELETED

KEY_SHIFT = 32
"""Local-track key: radar << KEY_SHIFT | local track number."""


STORED = (
    "status",
    "address",
    "mode3a",
    "fl",
    "rate",
    "t_fl",
    "t",
    "x",
    "P",
    "extra",
    "mu",
    "plot_id",
    "t_plot",
)
"""The local table's fields ``store`` writes, in the order its kernel takes them."""


def local_dtype(n_models: int) -> np.dtype[Any]:
    return np.dtype(
        [
            ("key", np.int64),
            ("radar", np.int64),
            ("number", np.int64),
            ("system", np.int64),  # 0: none
            ("status", np.int8),
            ("alive", np.bool_),
            ("t", np.float64),  # time of the state
            ("x", np.float64, (4,)),
            ("P", np.float64, (4, 4)),
            ("extra", np.float64, (2, 2)),  # residual-bias covariance of the latest plot
            ("plot_id", np.int64),
            ("t_plot", np.float64),
            ("fl", np.float64),
            ("rate", np.float64),
            ("t_fl", np.float64),
            ("address", np.int64),
            ("mode3a", np.int64),
            ("fails", np.int64),
            ("nis_mean", np.float64),  # consistency test: mean distance to its system track
            ("nis_n", np.int64),  # updates in that mean since it joined
            ("t_founder", np.float64),  # first time it could have founded a system track
            ("mu", np.float64, (n_models,)),  # its model probabilities (0: not known)
        ]
    )


def system_dtype(n_models: int, n_radars: int) -> np.dtype[Any]:
    return np.dtype(
        [
            ("alive", np.bool_),
            ("t", np.float64),  # time of x, P, M: the latest output (or filter) state
            ("x", np.float64, (4,)),
            # "plots": the error's covariance without the residual biases, which enter
            # through M and B (fusion/consider.py); "tracks": the whole covariance, M = 0.
            ("P", np.float64, (4, 4)),
            ("M", np.float64, (n_radars, 4, 2)),  # sensitivity to each radar's bias
            ("B", np.float64, (n_radars, 2, 2)),  # each radar's latest residual bias cov.
            ("t_plot", np.float64),  # latest plot of any of its local tracks
            ("freed_at", np.float64),
            ("born", np.float64),
            ("address", np.int64),
            ("mode3a", np.int64),
            ("solo", np.bool_),  # fed by its founding local track alone so far
            ("founder_radar", np.int64),
            ("orphaned", np.float64),  # when its last local track ended (NaN: fed)
            ("t_row", np.float64),  # its latest row's time
            ("row_interval", np.float64),  # between its latest two rows
            ("fl", np.float64),  # its latest row's flight level (NaN: unknown) and rate
            ("rate", np.float64),
            ("t_fl", np.float64),
            ("mx", np.float64, (n_models, 4)),  # "plots" method: the IMM's models
            ("mP", np.float64, (n_models, 4, 4)),
            ("mu", np.float64, (n_models,)),
            ("mM", np.float64, (n_models, n_radars, 4, 2)),
            # The compiled pre-selection's terms of the above (``nearby.refresh``): the
            # models' combined state and covariance entries, M's norms, B's largest trace.
            ("moments", np.float64, (7,)),
            ("sensitivity", np.float64, (2,)),
            ("largest_bias", np.float64),
        ]
    )


class Columns(dict[str, npt.NDArray[Any]]):
    """A table of ``dtype``'s fields held column by column: ``table[name]`` a field (a
    contiguous array: a scan of one field of 20,000 local tracks reads 160 kB, where a
    field view of the packed rows touches a cache line per row, about a hundred times
    slower), ``table[name] = value`` written into it in place; ``take`` and ``put``
    the rows. A dictionary of the columns, so that a field's read is the dictionary's
    own lookup (the fuser reads some 150 fields a batch: a method call each cost more)."""

    def __init__(self, dtype: np.dtype[Any], columns: dict[str, npt.NDArray[Any]]) -> None:
        super().__init__(columns)
        self.dtype = dtype

    @classmethod
    def zeros(cls, size: int, dtype: np.dtype[Any]) -> Columns:
        names = dtype.names or ()
        return cls(
            dtype,
            {n: resident_zeros((size, *dtype[n].shape), dtype[n].base) for n in names},
        )

    @property
    def shape(self) -> tuple[int]:
        return (len(self),)

    def __len__(self) -> int:
        """The number of rows."""
        return len(next(iter(self.values())))

    def __setitem__(self, key: str, value: Any) -> None:
        self[key][...] = value

    def __reduce__(self) -> tuple[Any, ...]:
        """Copied and pickled as its dtype and columns (a dictionary's items would be
        set back through ``__setitem__``, which writes into columns that exist)."""
        return (Columns, (self.dtype, dict(self)))

    def take(self, rows: slice | npt.NDArray[Any]) -> Columns:
        """The rows (a slice: views of the columns; an index: copies)."""
        return Columns(self.dtype, {n: c[rows] for n, c in self.items()})

    def put(self, rows: slice | npt.NDArray[Any], other: Columns) -> None:
        """``other``'s rows written into the rows ``rows``."""
        for name, column in self.items():
            column[rows] = other[name]


class Head:
    """The first ``n`` rows of a ``Columns`` table, a field at a time: each field asked
    for is a view of its column's first rows (a ``Columns`` slice makes views of every
    column, twenty-odd, for the field or two a caller reads)."""

    __slots__ = ("_columns", "_n")

    def __init__(self, table: Columns, n: int) -> None:
        self._columns = table
        self._n = n

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, name: str) -> npt.NDArray[Any]:
        return self._columns[name][: self._n]

    def __setitem__(self, name: str, value: Any) -> None:
        self._columns[name][: self._n] = value


def new_system_table(n_models: int, n_radars: int) -> Columns:
    """Column by column (``Columns``): a row holds every radar's sensitivities, about
    10 kB, so that a field view of packed rows would touch a page per row."""
    table = Columns.zeros(MAX_SYSTEM_NUMBER + 1, system_dtype(n_models, n_radars))
    table["freed_at"] = -np.inf
    table["orphaned"] = np.nan
    return table


FRESH = {
    "alive": True,
    "t": np.nan,  # no state yet
    "t_plot": -np.inf,
    "t_founder": np.nan,
    "fl": np.nan,
    "address": -1,
    "mode3a": -1,
}
"""A new local track's fields (the others zero)."""


LOCAL_ROWS = 8 * (MAX_SYSTEM_NUMBER + 1)
"""``LocalTrackTable``'s rows from the start: the system table's capacity at four local
tracks a system track, twice over for the deleted rows ``compact`` leaves until they
are half the table (65,536 rows, 24 MB with five models). Grown by doubling at the
traffic's peak, the table took its memory in steps well into a service's life (on
``artas``, 32,768 -> 65,536 rows in the 16th minute, 24 MB copied within one batch);
allocated at once it is resident from the start, as the system table is."""


class LocalTrackTable:
    """``rows[:n]``: every local track seen and not yet compacted away (``alive`` false
    once deleted). ``rows`` may be replaced when it grows (beyond ``capacity`` rows):
    read it afresh, never keep it across a call that may create rows."""

    def __init__(
        self, n_models: int, n_radars: int, compiled: bool = False, capacity: int = LOCAL_ROWS
    ) -> None:
        self.n_models = n_models
        self.compiled = compiled
        """``slots`` by its compiled kernel (``fusion/kernels.py``): the same rows."""
        self.rows = Columns.zeros(capacity, local_dtype(n_models))
        self.n = 0
        self.removed = 0
        """Rows of ``rows[:n]`` removed (not alive) since the last compaction."""
        self._index_keys = np.zeros(0, dtype=np.int64)
        self._index_rows = np.zeros(0, dtype=np.int64)
        # Compiled: the rows feeding each system track, a singly linked list per track
        # (``kernels.assign_feeders``), kept by ``feed``, which every writer of the
        # column ``system`` calls, so that ``slots`` needs no pass over the table.
        self._feeder_head = np.full(MAX_SYSTEM_NUMBER + 1, -1, dtype=np.int64)
        self._feeder_next = np.full(self.rows.shape[0], -1, dtype=np.int64)
        # Compiled: the confirmed live rows feeding a system track, counted per radar
        # (rows 0..n_radars-1; the last row: all radars) and system track (columns
        # 1..MAX_SYSTEM_NUMBER; column 0: all tracks), kept by ``feed``, ``store`` and
        # ``relink``, the writers of the columns ``system`` and ``status`` (a row leaves
        # by ``remove``'s ``feed``), so that the exchange test's sets of the tracks they
        # feed need no pass over the table (``kernels.feeding_sets``).
        self._confirmed_feeders = np.zeros((n_radars + 1, MAX_SYSTEM_NUMBER + 1), dtype=np.int64)

    @property
    def used(self) -> Head:
        """The rows in use (views, field by field)."""
        return Head(self.rows, self.n)

    def find(self, radar: int, u: npt.NDArray[Any], create: bool = True) -> IntArray:
        """Row of each update's local track (-1: unknown, and not created: a deleted
        track never seen before, or ``create`` false)."""
        if self.compiled:
            from tracker_service.fusion.kernels import lookup_rows

            keys, rows = lookup_rows(self._index_keys, self._index_rows, radar, u["track_number"])
        else:
            keys = (np.int64(radar) << KEY_SHIFT) | u["track_number"].astype(np.int64)
            rows = self._lookup(keys)
        missing = (rows < 0) & (u["status"] != LOCAL_DELETED)
        if create and missing.any():
            new_keys, first, new_row = np.unique(
                keys[missing], return_index=True, return_inverse=True
            )
            start = self._grow(new_keys.size)
            end = start + new_keys.size
            columns = self.rows
            for name in columns.dtype.names or ():
                columns[name][start:end] = FRESH.get(name, 0)
            columns["key"][start:end] = new_keys
            columns["radar"][start:end] = radar
            columns["number"][start:end] = u["track_number"][missing][first]
            # Into the index where they sort (the keys of the live rows are distinct):
            # the index ``reindex`` would build, without sorting every live key again.
            at = np.searchsorted(self._index_keys, new_keys)
            self._index_keys = np.insert(self._index_keys, at, new_keys)
            self._index_rows = np.insert(
                self._index_rows, at, np.arange(start, end, dtype=np.int64)
            )
            rows[missing] = start + new_row.reshape(-1)
        return rows

    def _lookup(self, keys: IntArray) -> IntArray:
        pos = np.searchsorted(self._index_keys, keys)
        pos = np.minimum(pos, max(self._index_keys.size - 1, 0))
        if self._index_keys.size == 0:
            return np.full(keys.shape, -1, dtype=np.int64)
        return np.where(self._index_keys[pos] == keys, self._index_rows[pos], -1)

    def _grow(self, k: int) -> int:
        start = self.n
        if start + k > self.rows.shape[0]:
            grown = Columns.zeros(max(2 * self.rows.shape[0], start + k), self.rows.dtype)
            grown.put(slice(0, start), self.rows.take(slice(0, start)))
            self.rows = grown
            next_row = np.full(grown.shape[0], -1, dtype=np.int64)
            next_row[:start] = self._feeder_next[:start]
            self._feeder_next = next_row
        self.n = start + k
        return start

    def reindex(self) -> None:
        loc = self.used
        live = np.flatnonzero(loc["alive"])
        order = np.argsort(loc["key"][live])
        self._index_keys = loc["key"][live][order]
        self._index_rows = live[order]

    def feed(self, rows: IntArray, numbers: IntArray | int) -> None:
        """Local rows ``rows`` feed system tracks ``numbers`` (0: none), written in order
        (a row given twice ends with its last): the one writer of the column ``system``
        (compiled, the lists of each track's feeders kept with it)."""
        if rows.size == 0:
            return
        if not self.compiled:
            self.rows["system"][rows] = numbers
            return
        from tracker_service.fusion.kernels import assign_feeders

        assign_feeders(
            kernel_indices(rows),
            kernel_indices(np.broadcast_to(np.asarray(numbers, dtype=np.int64), rows.shape)),
            self.rows["system"],
            self._feeder_head,
            self._feeder_next,
            self.rows["status"],
            *self._counted_columns(),
        )

    def _counted_columns(self) -> tuple[BoolArray, IntArray, int, IntArray]:
        """What the kernels that keep ``confirmed_feeders`` read besides the columns
        ``system`` and ``status``."""
        loc = self.rows
        return loc["alive"], loc["radar"], LOCAL_CONFIRMED, self._confirmed_feeders

    def radar_feeders(self, numbers: IntArray, radar: int) -> IntArray:
        """The live rows of ``radar`` feeding one of the system tracks ``numbers`` (which
        may repeat; 0, no track, names none), ascending; compiled: from the lists of the
        tracks' feeders, where the numpy path passes over the table."""
        loc = self.used
        if self.compiled:
            from tracker_service.fusion.kernels import radar_feeders

            return radar_feeders(
                kernel_indices(numbers),
                self._feeder_head,
                self._feeder_next,
                loc["alive"],
                loc["radar"],
                radar,
            )
        marked = marked_numbers(numbers)
        marked[0] = False
        return np.flatnonzero(loc["alive"] & (loc["radar"] == radar) & marked[loc["system"]])

    def feeder_lists(self) -> tuple[IntArray, IntArray]:
        """Compiled: the lists of each system track's feeders (``kernels.assign_feeders``),
        the first row of each track's list and each row's next, -1 ending a list."""
        return self._feeder_head, self._feeder_next

    def confirmed_feeders(self) -> IntArray:
        """Compiled: the confirmed live rows feeding each system track, counted per radar
        and track (n_radars + 1, MAX_SYSTEM_NUMBER + 1): row L all radars', column 0
        all tracks'."""
        return self._confirmed_feeders

    def relink(self) -> None:
        """The lists of feeders and the counts of confirmed feeders built afresh from the
        columns (after rows moved, or a test wrote them)."""
        if self.compiled:
            from tracker_service.fusion.kernels import link_feeders

            link_feeders(
                self.rows["system"][: self.n],
                self._feeder_head,
                self._feeder_next,
                self.rows["status"],
                *self._counted_columns(),
            )

    def remove(self, rows: IntArray) -> None:
        """Deleted local tracks (distinct rows) leave their system tracks and the index."""
        if rows.size:
            self.removed += int(np.count_nonzero(self.rows["alive"][rows]))
            self.feed(rows, 0)  # while alive: counted out of the confirmed feeders
            self.rows["alive"][rows] = False
            kept = ~is_member(self._index_rows, rows)
            self._index_keys = self._index_keys[kept]
            self._index_rows = self._index_rows[kept]

    def compact(self) -> None:
        """Drop deleted local tracks once they are half the table (rows move: reindex);
        counted as they are removed (a count over the table cost a pass a batch)."""
        if self.removed * 2 <= self.n:
            return
        alive = self.rows["alive"][: self.n]
        self.removed = 0
        survivors = self.rows.take(np.flatnonzero(alive))
        self.n = survivors.shape[0]
        self.rows.put(slice(0, self.n), survivors)
        self.reindex()
        self.relink()

    def store(
        self, rows: IntArray, u: npt.NDArray[Any], extra: FloatArray, has_plot: BoolArray
    ) -> None:
        """The latest row of each local track: its status and identity; the latest row
        with a plot (or any row of a track without state yet): its state."""
        loc = self.rows
        if self.compiled:
            from tracker_service.fusion.kernels import store_updates

            store_updates(
                rows,
                u,
                extra,
                has_plot,
                u.dtype["model_probabilities"].shape == (self.n_models,),
                loc["system"],
                *self._counted_columns(),
                *(loc[name] for name in STORED),
            )
            return
        last = last_of_each(rows)
        r, v = rows[last], u[last]
        loc["status"][r] = v["status"]
        loc["address"][r] = np.where(v["address"] >= 0, v["address"], loc["address"][r])
        loc["mode3a"][r] = np.where(v["mode3a"] >= 0, v["mode3a"], loc["mode3a"][r])
        with_fl = np.isfinite(v["flight_level"])
        loc["fl"][r[with_fl]] = v["flight_level"][with_fl]
        loc["rate"][r[with_fl]] = np.nan_to_num(v["climb_rate_fl_per_s"][with_fl])
        loc["t_fl"][r[with_fl]] = v["time"][with_fl]
        stateless = np.isnan(loc["t"][rows])
        sel = np.flatnonzero(has_plot | stateless)
        last = sel[last_of_each(rows[sel])]
        r, v = rows[last], u[last]
        loc["t"][r] = v["time"]
        loc["x"][r] = np.column_stack([v["x"], v["y"], v["vx"], v["vy"]])
        loc["P"][r] = v["P"].reshape(-1, 4, 4)
        loc["extra"][r] = extra[last]
        if v.dtype["model_probabilities"].shape == (self.n_models,):
            # The local trackers' IMM is the plot filter's (both TrackerConfig's model
            # set): a system track founded by a local track starts in its models.
            loc["mu"][r] = v["model_probabilities"]
        plotted = has_plot[last]
        loc["plot_id"][r[plotted]] = v["plot_id"][plotted]
        loc["t_plot"][r[plotted]] = v["time"][plotted]

    def slots(self, numbers: IntArray, max_sources: int) -> IntArray:
        """Local rows feeding each system track (rows of ``numbers``, which may repeat),
        most recent plot first, at most ``max_sources``, -1 padding: (k, MAX_SOURCES)."""
        loc = self.used
        k = numbers.size
        if self.compiled:
            from tracker_service.fusion.kernels import feeder_slots

            return feeder_slots(
                numbers,
                self._feeder_head,
                self._feeder_next,
                loc["system"],
                loc["alive"],
                loc["t_plot"],
                max_sources,
                MAX_SOURCES,
            )
        slots = np.full((k, MAX_SOURCES), -1, dtype=np.int64)
        unique, inverse = np.unique(numbers, return_inverse=True)
        feeding = np.flatnonzero(loc["alive"] & np.isin(loc["system"], unique))
        if feeding.size == 0 or k == 0:
            return slots
        group = np.searchsorted(unique, loc["system"][feeding])
        order = np.lexsort((-loc["t_plot"][feeding], group))
        feeding, group = feeding[order], group[order]
        rank = rank_within(group)
        keep = rank < max_sources
        per_unique = np.full((unique.size, MAX_SOURCES), -1, dtype=np.int64)
        per_unique[group[keep], rank[keep]] = feeding[keep]
        slots[:] = per_unique[inverse.reshape(-1)]
        return slots
