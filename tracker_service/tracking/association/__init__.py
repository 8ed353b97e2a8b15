"""Association of a batch of plots to the local tracks: one gate, one associator chosen by
name in the configuration (``TrackerConfig.association``), one update path.

- ``gate``: candidate (track, plot) pairs with their likelihoods, identity included (Stone
  Soup's hypothesiser);
- an ``Associator`` (Stone Soup's data associator) turns them into weighted pairs:
  ``gnn`` (global nearest neighbour, weight 1) or ``jpda`` (joint probabilistic data
  association without coalescence, JPDA*) or ``mht`` (track-oriented multiple
  hypotheses on the ambiguous clusters, GNN elsewhere: it keeps hypotheses across
  batches, so the tracker calls its ``decide``);
- ``update``: the IMM update of each track from its weighted pairs.
"""

from collections.abc import Callable

from tracker_service.tracking.association.base import Associator, WeightedPairs
from tracker_service.tracking.association.gate import Gate, GatedPairs, GateResult
from tracker_service.tracking.association.gnn import GlobalNearestNeighbour
from tracker_service.tracking.association.jpda import JointProbabilisticDataAssociation
from tracker_service.tracking.association.mht import MultipleHypothesisTracking
from tracker_service.tracking.association.update import WeightedUpdate, weighted_update
from tracker_service.tracking.config import ASSOCIATION_METHODS, TrackerConfig

_METHODS: dict[str, Callable[[TrackerConfig], Associator]] = {
    "gnn": GlobalNearestNeighbour,
    "jpda": JointProbabilisticDataAssociation,
    "mht": MultipleHypothesisTracking,
}
assert set(_METHODS) == set(ASSOCIATION_METHODS)


def make_associator(config: TrackerConfig) -> Associator:
    """The associator ``config.association`` names."""
    return _METHODS[config.association](config)


__all__ = [
    "Associator",
    "Gate",
    "GateResult",
    "GatedPairs",
    "GlobalNearestNeighbour",
    "JointProbabilisticDataAssociation",
    "MultipleHypothesisTracking",
    "WeightedPairs",
    "WeightedUpdate",
    "make_associator",
    "weighted_update",
]
