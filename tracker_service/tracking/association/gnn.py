"""Global nearest neighbour: the one-to-one assignment of least total cost."""

from __future__ import annotations

from tracker_service.tracking.associate import global_nearest_neighbour
from tracker_service.tracking.association.base import WeightedPairs
from tracker_service.tracking.association.gate import GatedPairs
from tracker_service.tracking.config import TrackerConfig


class GlobalNearestNeighbour:
    """Each track takes at most one plot and each plot goes to at most one track, the
    sum of the pairs' costs (-2 log likelihood, identity included) least."""

    def __init__(self, config: TrackerConfig) -> None:
        self.config = config

    def associate(self, pairs: GatedPairs) -> WeightedPairs:
        return WeightedPairs.hard(global_nearest_neighbour(pairs.track, pairs.plot, pairs.cost))
