"""Track-oriented multiple-hypothesis tracking (MHT), on the ambiguous clusters only.

Where a cluster of tracks that share gated plots has more than one feasible assignment of
close likelihood (the second best within ``mht_ambiguity_llr`` of the best), a hard choice
now may be the wrong one, and GNN would keep it for good. There, each track keeps a tree
of branches (``Branch``: its IMM state given one history of plots, and the log-likelihood
ratio of that history against clutter) and the cluster keeps its most likely global
hypotheses (one branch per track, no plot used twice). Each batch:

- every leaf branch of the cluster is gated against the batch (the tracker's ``Gate``);
- each global hypothesis is extended by Murty's ranking of its assignments of tracks to
  plots or to a miss (``jpda._k_best``); a child branch scores log(Pd N(y; 0, S) /
  lambda) (identity ratio included, as in JPDA: a matching Mode S address or validated
  code weighs in) or log(1 - Pd) for a miss; branches with the same parent and the same
  plot are one node, shared by the hypotheses holding it;
- pruning: hypotheses further than ``mht_prune_llr`` below the best go, at most
  ``mht_max_hypotheses`` stay, and N-scan pruning fixes every decision older than
  ``mht_n_scan`` - 1/2 antenna periods to the best hypothesis's (N = 1 would be GNN with a
  miss option; N >= 2 defers each choice by at least one scan);
- a cluster down to one hypothesis dissolves: its tracks go back to GNN.

Elsewhere (lone pairs, clear clusters, clusters of more than ``mht_max_cluster_tracks``
tracks) the assignment is GNN's, so the cost stays that of GNN on open traffic.

Publishing in real time: every batch, the tracks of a cluster take the states of the best
global hypothesis's leaves. When a later batch makes another hypothesis the best (a
revision), the track numbers stay (a track is a tree root: its branches are all its
own), and the state of each revised track (position, velocity, covariance, model
probabilities, identity) is replaced by its branch's; the corrected state goes out with
that track's next update. What was already published (past rows, the plots counted as
hits in the M-of-N window, the vertical filter's levels) is not rewritten.

The clutter density lambda (per m^2, per plot) is a function of the plots
(``clutter_density``): a constant from ``clutter_density_per_km2`` by default, where a
per-radar clutter map can be plugged in.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tracker_service.tracking import imm
from tracker_service.tracking.associate import global_nearest_neighbour
from tracker_service.tracking.association.base import WeightedPairs
from tracker_service.tracking.association.gate import Gate, GatedPairs
from tracker_service.tracking.association.jpda import _k_best
from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import FloatArray, IntArray, PlotArrays

ClutterDensity = Callable[[PlotArrays], FloatArray]
"""Density per m^2 of the plots that are nobody's (clutter, new targets), per plot."""


def constant_clutter_density(density_per_km2: float) -> ClutterDensity:
    def density(p: PlotArrays) -> FloatArray:
        return np.full(len(p), density_per_km2 * 1e-6)

    return density


@dataclass(eq=False)
class Branch:
    """A node of a track's hypothesis tree: the track's IMM state after one history of
    plots. ``decided_at`` is the time of the plot (or of the batch, for a miss) whose
    choice made the node; ``plot_id`` -1 for a miss or a root."""

    x: FloatArray
    P: FloatArray
    mu: FloatArray
    xc: FloatArray
    Pc: FloatArray
    t: float
    address: int
    mode3a: int
    decided_at: float
    plot_id: int = -1
    parent: Branch | None = None

    def anchor(self, cutoff: float) -> Branch:
        """The newest node of this history decided before ``cutoff``: what N-scan pruning
        holds fixed (the root when the whole history is newer)."""
        node = self
        while node.parent is not None and node.decided_at >= cutoff:
            node = node.parent
        return node

    def descends_from(self, other: Branch) -> bool:
        node: Branch | None = self
        while node is not None:
            if node is other:
                return True
            node = node.parent
        return False


@dataclass(frozen=True)
class Hypothesis:
    """A global hypothesis of a cluster: one leaf per track (in the cluster's order), its
    log-likelihood ratio against every plot being clutter."""

    score: float
    leaves: tuple[Branch, ...]


@dataclass(eq=False)
class Cluster:
    numbers: list[int]
    """Track numbers, the order of every hypothesis's leaves."""
    hypotheses: list[Hypothesis]
    """Best first."""
    published: dict[int, Branch] = field(default_factory=dict)
    """The leaf each track's row holds now."""


@dataclass(frozen=True)
class HypothesisDecision:
    """What the tracker applies for one batch.

    ``gnn``: the pairs (indices into the batch's ``GatedPairs``) left to GNN, of the
    tracks outside every cluster, and ``hard`` the ones it assigned. ``rows``, ``plots``
    and ``detected``: the clusters' tracks that the best hypothesis detects in this
    batch, their plots and their new leaves. ``revised_rows`` and ``revised``: tracks
    whose state a revision changed without a plot of this batch."""

    gnn: IntArray
    hard: IntArray
    rows: IntArray
    plots: IntArray
    detected: list[Branch]
    revised_rows: IntArray
    revised: list[Branch]


def branch_states(branches: list[Branch]) -> imm.ImmUpdate:
    """The states of some branches, stacked as an IMM update."""
    return imm.ImmUpdate(
        np.stack([b.x for b in branches]),
        np.stack([b.P for b in branches]),
        np.stack([b.mu for b in branches]),
        np.stack([b.xc for b in branches]),
        np.stack([b.Pc for b in branches]),
    )


@dataclass
class HypothesisStats:
    clusters_formed: int = 0
    cluster_steps: int = 0
    revisions: int = 0
    """Tracks whose published history a later batch changed."""
    most_hypotheses: int = 0


@dataclass(frozen=True)
class _Candidates:
    """The gated plots of one branch in this batch: batch plot indices, scores, and
    where the pair's prediction lies (``source`` 0: the leaves' gate, 1: the batch's)."""

    plots: IntArray
    scores: FloatArray
    source: int
    index: IntArray


_EMPTY = np.zeros(0, dtype=np.int64)
_NONE = _Candidates(np.zeros(0, np.int64), np.zeros(0), 0, np.zeros(0, np.int64))


class MultipleHypothesisTracking:
    """``association = "mht"``. Unlike the single-batch associators, it keeps hypotheses
    across batches, so the tracker calls ``decide`` (with the track table, its gate and
    its IMM) instead of ``associate``."""

    def __init__(
        self, config: TrackerConfig, clutter_density: ClutterDensity | None = None
    ) -> None:
        self.config = config
        pd = config.detection_probability
        self.log_pd = math.log(pd)
        self.log_miss = math.log(1.0 - pd)
        self.clutter_density = clutter_density or constant_clutter_density(
            config.clutter_density_per_km2
        )
        self.clusters: list[Cluster] = []
        self.stats = HypothesisStats()

    @property
    def clustered_numbers(self) -> IntArray:
        """The numbers of the tracks in a live cluster: their hypotheses still differ, so
        the table's state (the best hypothesis's) is not the whole story of them."""
        return np.array([num for c in self.clusters for num in c.numbers], dtype=np.int64)

    def associate(self, pairs: GatedPairs) -> WeightedPairs:
        """One batch on its own, without memory: GNN (the ``Associator`` protocol)."""
        return WeightedPairs.hard(global_nearest_neighbour(pairs.track, pairs.plot, pairs.cost))

    def decide(
        self,
        gate: Gate,
        imm_filter: imm.ImmFilter,
        cols: dict[str, npt.NDArray[Any]],
        n: int,
        p: PlotArrays,
        pairs: GatedPairs,
    ) -> HypothesisDecision:
        numbers = cols["number"][:n]
        row_of = self._forget_deleted(numbers)
        if not self.clusters and _all_lone(pairs, n, len(p)):
            # The usual batch: no cluster, no plot or track with a second candidate.
            everything = np.arange(len(pairs))
            return HypothesisDecision(
                everything, self.associate(pairs).pair, _EMPTY, _EMPTY, [], _EMPTY, []
            )
        clustered = np.zeros(n, dtype=bool)
        clustered[list(row_of.values())] = True
        free = ~clustered[pairs.track]
        log_clutter = np.log(self.clutter_density(p))
        score = pairs.log_likelihood + self.log_pd - log_clutter[pairs.plot]

        # The clusters' leaves, gated against the batch.
        leaves = list(
            {id(b): b for c in self.clusters for h in c.hypotheses for b in h.leaves}.values()
        )
        leaf_number = {id(b): num for c in self.clusters for h in c.hypotheses
                       for num, b in zip(c.numbers, h.leaves, strict=True)}  # fmt: skip
        leaf_pairs = gate(_branch_columns(leaves), len(leaves), p).pairs if leaves else None

        # Components of the graph of track rows and plots (a cluster's tracks linked).
        t_parts, p_parts = [pairs.track[free]], [n + pairs.plot[free]]
        leaf_cands: dict[int, _Candidates] = {}
        if leaf_pairs is not None:
            leaf_row = np.array([row_of[leaf_number[id(b)]] for b in leaves], dtype=np.int64)
            t_parts.append(leaf_row[leaf_pairs.track])
            p_parts.append(n + leaf_pairs.plot)
            leaf_score = leaf_pairs.log_likelihood + self.log_pd - log_clutter[leaf_pairs.plot]
            order = np.argsort(leaf_pairs.track, kind="stable")
            bounds = np.searchsorted(leaf_pairs.track[order], np.arange(len(leaves) + 1))
            for k, b in enumerate(leaves):
                idx = order[bounds[k] : bounds[k + 1]]
                if idx.size:
                    leaf_cands[id(b)] = _Candidates(leaf_pairs.plot[idx], leaf_score[idx], 0, idx)
        cluster_links = 0
        for c in self.clusters:
            rows = np.array([row_of[num] for num in c.numbers], dtype=np.int64)
            t_parts.append(rows[:1].repeat(rows.size - 1))
            p_parts.append(rows[1:])
            cluster_links += rows.size - 1
        t_all, p_all = np.concatenate(t_parts), np.concatenate(p_parts)
        size = n + len(p)
        graph = coo_matrix((np.ones(t_all.size), (t_all, p_all)), shape=(size, size))
        _, label = connected_components(graph, directed=False)

        # Components to branch: those holding a cluster with plots in this batch, and
        # the ambiguous free ones.
        with_plots = np.zeros(size, dtype=bool)
        with_plots[label[t_all[: t_all.size - cluster_links]]] = True
        branching = {c for c in label[list(row_of.values())].tolist() if with_plots[c]}
        free_idx = np.flatnonzero(free)
        comp_of_pair = label[pairs.track[free_idx]]
        shared = np.bincount(comp_of_pair, minlength=size)[comp_of_pair] > 1
        for comp in np.unique(comp_of_pair[shared]).tolist():
            if comp in branching:
                continue
            members = free_idx[comp_of_pair == comp]
            if self._ambiguous(pairs.track[members], pairs.plot[members], score[members]):
                branching.add(comp)
        tracks_in = np.bincount(label[:n], minlength=size)
        too_large = [c for c in branching if tracks_in[c] > self.config.mht_max_cluster_tracks]
        stepped = sorted(branching.difference(too_large))
        if too_large:
            # Too large to branch: its clusters end on their best hypotheses (what the
            # table holds already) and GNN takes the component.
            ending = set(numbers[np.isin(label[:n], too_large)].tolist())
            self.clusters = [c for c in self.clusters if c.numbers[0] not in ending]
        row_comp = label[:n][pairs.track]
        gnn_pairs = np.flatnonzero(
            (free & ~np.isin(row_comp, stepped)) | np.isin(row_comp, too_large)
        )
        rows_out: list[int] = []
        plots_out: list[int] = []
        detected: list[Branch] = []
        revised_rows: list[int] = []
        revised: list[Branch] = []
        for comp in stepped:
            comp_rows = np.flatnonzero(label[:n] == comp)
            cluster, root_cands = self._gather(comp_rows, row_of, cols, pairs, score)
            cands = {**leaf_cands, **root_cands}
            for number, leaf, plot in self._step(cluster, p, imm_filter, pairs, leaf_pairs, cands):
                row = int(np.searchsorted(numbers, number))
                if plot >= 0:
                    rows_out.append(row)
                    plots_out.append(plot)
                    detected.append(leaf)
                else:
                    revised_rows.append(row)
                    revised.append(leaf)
        hard = (
            gnn_pairs[
                global_nearest_neighbour(
                    pairs.track[gnn_pairs], pairs.plot[gnn_pairs], pairs.cost[gnn_pairs]
                )
            ]
            if gnn_pairs.size
            else _EMPTY
        )
        return HypothesisDecision(
            gnn=gnn_pairs,
            hard=hard,
            rows=np.array(rows_out, dtype=np.int64),
            plots=np.array(plots_out, dtype=np.int64),
            detected=detected,
            revised_rows=np.array(revised_rows, dtype=np.int64),
            revised=revised,
        )

    def _ambiguous(self, tracks: IntArray, plots: IntArray, score: FloatArray) -> bool:
        """Whether the two best assignments of a component are close."""
        _, ti = np.unique(tracks, return_inverse=True)
        _, pj = np.unique(plots, return_inverse=True)
        ratio = np.full((int(ti.max()) + 1, int(pj.max()) + 1), -np.inf)
        ratio[ti, pj] = score
        events = _k_best(ratio, self.log_miss, 2)
        if len(events) < 2:
            return False
        best, second = (self._event_score(ratio, e) for e in events)
        return best - second < self.config.mht_ambiguity_llr

    def _event_score(self, ratio: FloatArray, event: tuple[int, ...]) -> float:
        return float(sum(ratio[i, j] if j >= 0 else self.log_miss for i, j in enumerate(event)))

    def _forget_deleted(self, numbers: IntArray) -> dict[int, int]:
        """Drop the deleted tracks from the clusters (and the clusters left with one
        track or one hypothesis); the table row of every clustered track."""
        row_of: dict[int, int] = {}
        kept = []
        for c in self.clusters:
            rows = np.searchsorted(numbers, c.numbers)
            live = (rows < numbers.size) & (
                numbers[np.minimum(rows, numbers.size - 1)] == c.numbers
            )
            if numbers.size == 0 or not live.any():
                continue
            if not live.all():
                keep = np.flatnonzero(live).tolist()
                c.numbers = [c.numbers[i] for i in keep]
                best: dict[tuple[int, ...], Hypothesis] = {}
                for h in c.hypotheses:
                    leaves = tuple(h.leaves[i] for i in keep)
                    key = tuple(id(b) for b in leaves)
                    if key not in best or h.score > best[key].score:
                        best[key] = Hypothesis(h.score, leaves)
                c.hypotheses = sorted(best.values(), key=lambda h: -h.score)
                c.published = {k: v for k, v in c.published.items() if k in c.numbers}
                rows = rows[live]
            if len(c.hypotheses) < 2:
                continue
            kept.append(c)
            row_of.update(zip(c.numbers, rows.tolist(), strict=True))
        self.clusters = kept
        return row_of

    def _gather(
        self,
        comp_rows: IntArray,
        row_of: dict[int, int],
        cols: dict[str, npt.NDArray[Any]],
        pairs: GatedPairs,
        score: FloatArray,
    ) -> tuple[Cluster, dict[int, _Candidates]]:
        """One cluster of the tracks ``comp_rows``: the clusters among them merged (the
        product of their hypotheses, the best kept), the free tracks joining with one
        root branch each (their table state); the roots' gated plots."""
        members = set(cols["number"][comp_rows].tolist())
        merging = [c for c in self.clusters if c.numbers[0] in members]
        self.clusters = [c for c in self.clusters if c.numbers[0] not in members]
        limit = self.config.mht_max_hypotheses
        numbers: list[int] = []
        hypotheses = [Hypothesis(0.0, ())]
        published: dict[int, Branch] = {}
        for c in merging:
            numbers += c.numbers
            published.update(c.published)
            product = [
                Hypothesis(a.score + b.score, a.leaves + b.leaves)
                for a in hypotheses
                for b in c.hypotheses
            ]
            hypotheses = sorted(product, key=lambda h: -h.score)[:limit]
        clustered = set(row_of.values())
        roots: list[Branch] = []
        root_cands: dict[int, _Candidates] = {}
        for row in comp_rows.tolist():
            if row in clustered:
                continue
            root = Branch(
                x=cols["x"][row].copy(),
                P=cols["P"][row].copy(),
                mu=cols["mu"][row].copy(),
                xc=cols["xc"][row].copy(),
                Pc=cols["Pc"][row].copy(),
                t=float(cols["t"][row]),
                address=int(cols["address"][row]),
                mode3a=int(cols["mode3a"][row]),
                decided_at=float(cols["t"][row]),
            )
            number = int(cols["number"][row])
            numbers.append(number)
            roots.append(root)
            published[number] = root
            idx = np.flatnonzero(pairs.track == row)
            root_cands[id(root)] = _Candidates(pairs.plot[idx], score[idx], 1, idx)
        if not merging:
            self.stats.clusters_formed += 1
        root_leaves = tuple(roots)
        cluster = Cluster(
            numbers,
            [Hypothesis(h.score, h.leaves + root_leaves) for h in hypotheses],
            published,
        )
        return cluster, root_cands

    def _step(
        self,
        cluster: Cluster,
        p: PlotArrays,
        imm_filter: imm.ImmFilter,
        pairs: GatedPairs,
        leaf_pairs: GatedPairs | None,
        cands: dict[int, _Candidates],
    ) -> list[tuple[int, Branch, int]]:
        """Extend, prune and publish one cluster over this batch; the tracks whose
        published leaf changed: (number, leaf, its plot in the batch or -1)."""
        cfg = self.config
        self.stats.cluster_steps += 1
        n_tracks = len(cluster.numbers)
        observed = np.zeros(n_tracks, dtype=bool)
        for h in cluster.hypotheses:
            for i, b in enumerate(h.leaves):
                observed[i] |= id(b) in cands
        seen = np.flatnonzero(observed)
        if seen.size == 0:
            self._keep(cluster)
            return []
        local_plots = np.unique(np.concatenate([cands[id(b)].plots for h in cluster.hypotheses
                                                for b in h.leaves if id(b) in cands]))  # fmt: skip
        now = float(p.time[local_plots].max())
        cutoff = now - (cfg.mht_n_scan - 0.5) * cfg.scan_period_s

        # Every parent's best extensions.
        children: list[tuple[float, Hypothesis, tuple[int, ...]]] = []
        for h in cluster.hypotheses:
            ratio = np.full((seen.size, local_plots.size), -np.inf)
            for r, i in enumerate(seen.tolist()):
                c = cands.get(id(h.leaves[i]), _NONE)
                ratio[r, np.searchsorted(local_plots, c.plots)] = c.scores
            for event in _k_best(ratio, self.log_miss, cfg.mht_max_hypotheses):
                children.append((h.score + self._event_score(ratio, event), h, event))
        children.sort(key=lambda c: -c[0])
        best_score = children[0][0]
        children = [c for c in children if c[0] >= best_score - cfg.mht_prune_llr]
        children = children[: cfg.mht_max_hypotheses]
        # N-scan pruning: a new node is decided now, after the cutoff, so its anchor is
        # its parent's.
        anchors = [b.anchor(cutoff) for b in children[0][1].leaves]
        children = [
            c
            for c in children
            if all(b.anchor(cutoff) is a for b, a in zip(c[1].leaves, anchors, strict=True))
        ]

        # The new nodes: one per (parent, plot), shared by the hypotheses holding it.
        nodes: dict[tuple[int, int], Branch] = {}
        wanted: dict[tuple[int, int], tuple[Branch, int, int, int]] = {}
        for _, h, event in children:
            for r, i in enumerate(seen.tolist()):
                parent = h.leaves[i]
                j = int(local_plots[event[r]]) if event[r] >= 0 else -1
                key = (id(parent), j)
                if key in wanted or key in nodes:
                    continue
                if j < 0:
                    nodes[key] = Branch(
                        parent.x, parent.P, parent.mu, parent.xc, parent.Pc, parent.t,
                        parent.address, parent.mode3a, now, -1, parent,
                    )  # fmt: skip
                    continue
                c = cands[id(parent)]
                k = int(np.flatnonzero(c.plots == j)[0])
                wanted[key] = (parent, j, c.source, int(c.index[k]))
        for source, gated in ((0, leaf_pairs), (1, pairs)):
            keys = [key for key, w in wanted.items() if w[2] == source]
            if not keys:
                continue
            assert gated is not None
            index = np.array([wanted[key][3] for key in keys], dtype=np.int64)
            plot = np.array([wanted[key][1] for key in keys], dtype=np.int64)
            xy = np.column_stack([p.x[plot], p.y[plot]])
            up = imm_filter.update(gated.pred.take(index), xy, p.R[plot])
            for k, key in enumerate(keys):
                parent, j = wanted[key][0], wanted[key][1]
                address = int(p.address[j]) if p.address[j] >= 0 else parent.address
                code_ok = bool(p.mode3a_valid[j]) and p.mode3a[j] >= 0
                nodes[key] = Branch(
                    up.x[k], up.P[k], up.mu[k], up.x_comb[k], up.P_comb[k], float(p.time[j]),
                    address, int(p.mode3a[j]) if code_ok else parent.mode3a,
                    float(p.time[j]), int(p.plot_id[j]), parent,
                )  # fmt: skip
        plot_of = {id(b): key[1] for key, b in nodes.items()}
        hypotheses = []
        for s, h, event in children:
            leaves = list(h.leaves)
            for r, i in enumerate(seen.tolist()):
                j = int(local_plots[event[r]]) if event[r] >= 0 else -1
                leaves[i] = nodes[(id(h.leaves[i]), j)]
            hypotheses.append(Hypothesis(s, tuple(leaves)))
        for h in hypotheses:
            for b in h.leaves:
                b.anchor(cutoff).parent = None  # the fixed past: forgotten
        cluster.hypotheses = hypotheses
        self.stats.most_hypotheses = max(self.stats.most_hypotheses, len(hypotheses))

        changed = []
        for number, leaf in zip(cluster.numbers, hypotheses[0].leaves, strict=True):
            before = cluster.published.get(number)
            if leaf is before:
                continue
            if before is not None and not leaf.descends_from(before):
                self.stats.revisions += 1
            elif plot_of.get(id(leaf), -1) < 0:
                cluster.published[number] = leaf  # a miss after the published leaf
                continue
            cluster.published[number] = leaf
            changed.append((number, leaf, plot_of.get(id(leaf), -1)))
        self._keep(cluster)
        return changed

    def _keep(self, cluster: Cluster) -> None:
        """A cluster with one hypothesis left has nothing to defer: it dissolves."""
        if len(cluster.hypotheses) > 1 and len(cluster.numbers) > 0:
            self.clusters.append(cluster)


def _all_lone(pairs: GatedPairs, n_tracks: int, n_plots: int) -> bool:
    """Whether every pair's track and plot have no other candidate."""
    tracks = np.bincount(pairs.track, minlength=n_tracks)
    plots = np.bincount(pairs.plot, minlength=n_plots)
    return bool(tracks.max() <= 1 and plots.max() <= 1)


def _branch_columns(branches: list[Branch]) -> dict[str, npt.NDArray[Any]]:
    """The columns the gate reads, for some branches."""
    return {
        "x": np.stack([b.x for b in branches]),
        "P": np.stack([b.P for b in branches]),
        "mu": np.stack([b.mu for b in branches]),
        "xc": np.stack([b.xc for b in branches]),
        "Pc": np.stack([b.Pc for b in branches]),
        "t": np.array([b.t for b in branches]),
        "address": np.array([b.address for b in branches], dtype=np.int64),
        "mode3a": np.array([b.mode3a for b in branches], dtype=np.int64),
    }
