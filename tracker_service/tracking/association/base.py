"""What every associator returns: weighted pairs."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from tracker_service.tracking.association.gate import GatedPairs
from tracker_service.tracking.plots import FloatArray, IntArray


@dataclass(frozen=True)
class WeightedPairs:
    """The pairs an associator keeps (indices into its ``GatedPairs``) and each one's
    association probability. A track's weights sum to at most 1; the rest is the
    probability that none of its gated plots is its own (a missed detection). Global
    nearest neighbour keeps one pair per track and per plot, each of weight 1."""

    pair: IntArray
    weight: FloatArray
    all_ones: bool = False
    """Known to weigh every pair 1 (``hard``), without looking."""

    @classmethod
    def hard(cls, pair: IntArray) -> WeightedPairs:
        return cls(pair, np.ones(pair.size), all_ones=True)

    @property
    def is_hard(self) -> bool:
        """Every weight 1: each kept pair is an outright assignment."""
        return self.all_ones or bool(np.all(self.weight == 1.0))


class Associator(Protocol):
    """Stone Soup's data associator: from the gated pairs of one batch to weighted pairs."""

    def associate(self, pairs: GatedPairs) -> WeightedPairs: ...
