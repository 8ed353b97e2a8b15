"""What every associator returns: weighted pairs."""

from __future__ import annotations

from dataclasses import dataclass, field
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
    all_ones: bool = field(default=False, init=False)
    """Known to weigh every pair 1 (made by ``hard``), without looking; not an argument,
    so that no caller can claim it of weights that are not all 1."""

    @classmethod
    def hard(cls, pair: IntArray) -> WeightedPairs:
        pairs = cls(pair, np.ones(pair.size))
        object.__setattr__(pairs, "all_ones", True)  # frozen: set once, here
        return pairs

    @property
    def is_hard(self) -> bool:
        """Every weight 1: each kept pair is an outright assignment."""
        return self.all_ones or bool(np.all(self.weight == 1.0))


class Associator(Protocol):
    """Stone Soup's data associator: from the gated pairs of one batch to weighted pairs."""

    def associate(self, pairs: GatedPairs) -> WeightedPairs: ...
