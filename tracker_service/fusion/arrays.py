"""Index helpers over the fuser's arrays: groups, ranks and lookups without Python loops."""

from __future__ import annotations

import numpy as np

from tracker_service.fusion.messages import MAX_SYSTEM_NUMBER
from tracker_service.tracking.plots import BoolArray, IntArray


def kernel_indices(indices: IntArray) -> IntArray:
    """Row indices as the compiled kernels (fusion/kernels.py) take them: contiguous int64."""
    return np.ascontiguousarray(indices, dtype=np.int64)


def last_of_each(keys: IntArray) -> IntArray:
    """Index of the last occurrence of each distinct key (sorted by key)."""
    _, first_reversed = np.unique(keys[::-1], return_index=True)
    return keys.size - 1 - first_reversed


def rank_within(group: IntArray) -> IntArray:
    """0, 1, ... in order of appearance among the equal values of ``group``."""
    order = np.argsort(group, kind="stable")
    sorted_group = group[order]
    start = np.searchsorted(sorted_group, sorted_group, side="left")
    rank = np.empty(group.size, dtype=np.int64)
    rank[order] = np.arange(group.size) - start
    return rank


def positions(ids: IntArray, wanted: IntArray) -> IntArray:
    """Index in ``ids`` of each wanted id (-1: absent)."""
    if ids.size == 0:
        return np.full(wanted.shape, -1, dtype=np.int64)
    order = np.argsort(ids, kind="stable")
    pos = np.minimum(np.searchsorted(ids[order], wanted), ids.size - 1)
    return np.where(ids[order][pos] == wanted, order[pos], -1)


def is_member(values: IntArray, members: IntArray) -> BoolArray:
    """``np.isin(values, members)`` by binary search in the sorted members: for a table's
    column against a batch's few values, where ``np.isin`` makes a pass over the column
    per member (or sorts both)."""
    if members.size == 0:
        return np.zeros(values.shape, dtype=bool)
    ordered = np.sort(members)
    at = np.minimum(np.searchsorted(ordered, values), ordered.size - 1)
    return np.asarray(ordered[at] == values, dtype=bool)


def among(values: IntArray, members: IntArray) -> BoolArray:
    """``is_member(values, members)`` for a few values against many members (a batch's
    identities against every live system track's): the members looked up among the
    sorted distinct values, where ``is_member`` sorts the members."""
    distinct, inverse = np.unique(values, return_inverse=True)
    if distinct.size == 0 or members.size == 0:
        return np.zeros(values.shape, dtype=bool)
    at = np.minimum(np.searchsorted(distinct, members), distinct.size - 1)
    found = np.zeros(distinct.size, dtype=bool)
    found[at[distinct[at] == members]] = True
    return np.asarray(found[inverse.reshape(values.shape)], dtype=bool)


def marked_numbers(numbers: IntArray) -> BoolArray:
    """A table of every system-track number (0..MAX_SYSTEM_NUMBER), true at ``numbers``:
    indexed by a column of numbers, ``is_member(column, numbers)`` in one gather (a
    search per row of the local-track table cost more)."""
    marked = np.zeros(MAX_SYSTEM_NUMBER + 1, dtype=bool)
    marked[numbers] = True
    return marked


def numbers_in(numbers: IntArray) -> IntArray:
    """The distinct values of ``numbers`` (system-track numbers, 0..MAX_SYSTEM_NUMBER)
    in ascending order, as ``np.unique`` gives them, by marking a table of every number
    rather than sorting (a batch's exchange test takes those of every fed local track)."""
    return np.flatnonzero(marked_numbers(numbers))


def first_where(mask: BoolArray) -> IntArray:
    """Column of the first true entry per row (0 when none)."""
    return np.asarray(np.argmax(mask, axis=1), dtype=np.int64)


def compact_slots(slots: IntArray, keep: BoolArray) -> IntArray:
    """The kept slots moved to the front of each row, order kept, -1 after them."""
    order = np.argsort(~keep, axis=1, kind="stable")
    out = np.take_along_axis(np.where(keep, slots, -1), order, axis=1)
    return out
