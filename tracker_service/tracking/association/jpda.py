"""Joint probabilistic data association, without coalescence (JPDA*).

Over each cluster of tracks that share gated plots, the feasible joint events (each plot
to at most one track or to clutter, each track at most one plot) are weighted by the
product of their pairs' likelihood ratios against clutter (Pd times the Gaussian density
of the innovation times the identity ratio, over the clutter density: the clutter map's at
the plot, or the configured constant) and 1 - Pd for each
missed track, then normalised; a pair's weight is the sum over the events holding it.

Coalescence: two tracks close together, each with its plot, get from plain JPDA the two
permutations of the plots with nearly equal weights, and both move to the middle. Blom
and Bloem's JPDA* keeps, among the events that detect the same tracks with the same
plots, only the most likely permutation: the tracks keep their own plots and stay apart.

Exact enumeration for small clusters; beyond ``jpda_max_events`` feasible events, the
``jpda_k_best`` most likely events by Murty's ranking of assignments.

``TrackerConfig.implementation`` chooses the code: "compiled" (``association.kernels``,
numba: one call per batch) or "numpy" (the methods here, the reference); the same weights
to rounding (tests/test_association_kernels.py).
"""

from __future__ import annotations

import heapq
import itertools
import math

import numpy as np
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tracker_service.tracking.association import kernels
from tracker_service.tracking.association.base import WeightedPairs
from tracker_service.tracking.association.gate import GatedPairs
from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import FloatArray, IntArray

FORBIDDEN = 1.0e12
"""Cost of a cell no event may use in Murty's ranking (a finite stand-in for infinity)."""
MIN_WEIGHT = 1.0e-6
"""Pairs below this probability are dropped: they would not move a state."""

Event = tuple[int, ...]
"""A joint event of a cluster: for each of its tracks, the cluster plot it takes or -1."""


class JointProbabilisticDataAssociation:
    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        pd = config.detection_probability
        self.log_miss = math.log(1.0 - pd)
        self.log_pd = math.log(pd)
        self.log_pd_over_clutter = math.log(pd) - math.log(config.clutter_density_per_km2 * 1e-6)
        self._compiled = config.implementation == "compiled"

    def associate(self, pairs: GatedPairs) -> WeightedPairs:
        if pairs.clutter_density is None:
            score = pairs.log_likelihood + self.log_pd_over_clutter
        else:
            # The clutter map's density at each plot: a plot in a dense cell is more
            # likely nobody's, and weighs less for any track.
            score = pairs.log_likelihood + self.log_pd - np.log(pairs.clutter_density)
        if self._compiled:
            weight = kernels.jpda_weights(
                np.ascontiguousarray(pairs.track, dtype=np.int64),
                np.ascontiguousarray(pairs.plot, dtype=np.int64),
                np.ascontiguousarray(score, dtype=np.float64),
                self.log_miss,
                self.config.jpda_max_events,
                self.config.jpda_k_best,
            )
        else:
            weight = self._weights(pairs, score)
        keep = np.flatnonzero(weight >= MIN_WEIGHT)
        return WeightedPairs(keep, weight[keep])

    def _weights(self, pairs: GatedPairs, score: FloatArray) -> FloatArray:
        """The weight of every pair (the reference of ``kernels.jpda_weights``)."""
        _, t_idx = np.unique(pairs.track, return_inverse=True)
        _, p_idx = np.unique(pairs.plot, return_inverse=True)
        nt, npl = int(t_idx.max()) + 1, int(p_idx.max()) + 1
        lone = (np.bincount(t_idx)[t_idx] == 1) & (np.bincount(p_idx)[p_idx] == 1)
        weight = np.empty(len(pairs))
        # A lone pair: the plot is the track's or clutter, the track detected or not.
        weight[lone] = 1.0 / (1.0 + np.exp(self.log_miss - score[lone]))
        rest = np.flatnonzero(~lone)
        if rest.size:
            graph = coo_matrix(
                (np.ones(rest.size), (t_idx[rest], nt + p_idx[rest])), shape=(nt + npl,) * 2
            )
            _, label = connected_components(graph, directed=False)
            cluster = label[t_idx[rest]]
            order = np.argsort(cluster, kind="stable")
            bounds = np.flatnonzero(np.diff(cluster[order])) + 1
            for members in np.split(rest[order], bounds):
                weight[members] = self._cluster(t_idx[members], p_idx[members], score[members])
        return weight

    def _cluster(self, tracks: IntArray, plots: IntArray, score: FloatArray) -> FloatArray:
        """The marginal probability of each pair of one cluster."""
        _, ti = np.unique(tracks, return_inverse=True)
        _, pj = np.unique(plots, return_inverse=True)
        n_tracks, n_plots = int(ti.max()) + 1, int(pj.max()) + 1
        ratio = np.full((n_tracks, n_plots), -np.inf)
        ratio[ti, pj] = score
        options = np.bincount(ti, minlength=n_tracks) + 1
        if float(np.prod(options.astype(np.float64))) <= self.config.jpda_max_events:
            events = list(_enumerate(ratio))
        else:
            events = _k_best(ratio, self.log_miss, self.config.jpda_k_best)
        log_w: dict[tuple[frozenset[int], frozenset[int]], tuple[float, Event]] = {}
        for event in events:
            # JPDA*: of the events detecting the same tracks with the same plots, the
            # most likely permutation only.
            key = (
                frozenset(i for i, j in enumerate(event) if j >= 0),
                frozenset(j for j in event if j >= 0),
            )
            w = sum(ratio[i, j] if j >= 0 else self.log_miss for i, j in enumerate(event))
            if key not in log_w or w > log_w[key][0]:
                log_w[key] = (w, event)
        kept = list(log_w.values())
        w = np.array([v for v, _ in kept])
        w = np.exp(w - w.max())
        w /= w.sum()
        marginal = np.zeros((n_tracks, n_plots))
        for probability, (_, event) in zip(w.tolist(), kept, strict=True):
            for i, j in enumerate(event):
                if j >= 0:
                    marginal[i, j] += probability
        return np.asarray(marginal[ti, pj])


def _enumerate(ratio: FloatArray) -> itertools.chain[Event]:
    """Every feasible joint event of a cluster (its pairs' ``ratio`` finite)."""
    n_tracks = ratio.shape[0]
    choices = [[-1, *np.flatnonzero(np.isfinite(ratio[i])).tolist()] for i in range(n_tracks)]

    def extend(i: int, used: frozenset[int], head: Event) -> itertools.chain[Event]:
        if i == n_tracks:
            return itertools.chain((head,))
        return itertools.chain.from_iterable(
            extend(i + 1, used | {j} if j >= 0 else used, (*head, j))
            for j in choices[i]
            if j < 0 or j not in used
        )

    return extend(0, frozenset(), ())


def _k_best(ratio: FloatArray, log_miss: float, k: int) -> list[Event]:
    """The ``k`` most likely joint events, by Murty's ranking of the assignments of the
    tracks to the plots or to one miss column each."""
    n_tracks, n_plots = ratio.shape
    cost = np.full((n_tracks, n_plots + n_tracks), FORBIDDEN)
    cost[:, :n_plots] = np.where(np.isfinite(ratio), -ratio, FORBIDDEN)
    cost[np.arange(n_tracks), n_plots + np.arange(n_tracks)] = -log_miss
    tie = itertools.count()

    def solve(c: FloatArray) -> tuple[float, IntArray] | None:
        rows, cols = linear_sum_assignment(c)
        chosen = c[rows, cols]
        if np.any(chosen >= FORBIDDEN):
            return None
        return float(chosen.sum()), cols

    first = solve(cost)
    assert first is not None  # every track may miss: always feasible
    heap = [(first[0], next(tie), first[1], cost)]
    events: list[Event] = []
    while heap and len(events) < k:
        _, _, cols, c = heapq.heappop(heap)
        events.append(tuple(int(j) if j < n_plots else -1 for j in cols.tolist()))
        fixed = c.copy()
        for i in range(n_tracks):
            child = fixed.copy()
            child[i, cols[i]] = FORBIDDEN
            solved = solve(child)
            if solved is not None:
                heapq.heappush(heap, (solved[0], next(tie), solved[1], child))
            keep = fixed[i, cols[i]]
            fixed[i, :] = FORBIDDEN
            fixed[:, cols[i]] = FORBIDDEN
            fixed[i, cols[i]] = keep
    return events
