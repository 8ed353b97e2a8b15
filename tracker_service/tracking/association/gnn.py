"""Global nearest neighbour: the one-to-one assignment of least total cost."""

from __future__ import annotations

from tracker_service.tracking.associate import UNASSIGNABLE, global_nearest_neighbour
from tracker_service.tracking.association import kernels
from tracker_service.tracking.association.base import WeightedPairs
from tracker_service.tracking.association.gate import GatedPairs
from tracker_service.tracking.config import TrackerConfig


class GlobalNearestNeighbour:
    """Each track takes at most one plot and each plot goes to at most one track, the
    sum of the pairs' costs (-2 log likelihood, identity included) least."""

    def __init__(self, config: TrackerConfig) -> None:
        self.config = config
        self._compiled = config.implementation == "compiled"

    def associate(self, pairs: GatedPairs) -> WeightedPairs:
        if self._compiled:
            chosen = kernels.gnn_assignment(pairs.track, pairs.plot, pairs.cost, UNASSIGNABLE)
        else:
            chosen = global_nearest_neighbour(pairs.track, pairs.plot, pairs.cost)
        return WeightedPairs.hard(chosen)
