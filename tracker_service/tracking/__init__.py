"""Per-radar local tracking: plots in the system plane to local tracks.

Stone Soup's separation, over numpy arrays of tracks: models (``models``: CV and
fixed-rate coordinated turns with F(T), Q(T) per plot), predictor and updater (``imm``:
IMM mixing, Joseph-form updates; ``vertical``: flight level and climb rate), associator
(``associate``: k-d tree pre-selection, chi-square gate, global nearest neighbour),
initiator (``initiate``: two-point), confirmation and deletion (``tracker``: M of N, misses
counted on the antenna period). ``LocalTracker.process`` runs them on one batch of plots.
"""

from tracker_service.tracking.config import SHARED_MODE3A_CODES, TrackerConfig
from tracker_service.tracking.models import ModelSet, ct_transition, cv_transition
from tracker_service.tracking.plots import PLOT_DTYPE, PlotArrays, as_plot_arrays
from tracker_service.tracking.tracker import (
    COASTING,
    CONFIRMED,
    DELETED,
    TENTATIVE,
    LocalTracker,
    TrackerStats,
    track_update_dtype,
)

__all__ = [
    "COASTING",
    "CONFIRMED",
    "DELETED",
    "PLOT_DTYPE",
    "SHARED_MODE3A_CODES",
    "TENTATIVE",
    "LocalTracker",
    "ModelSet",
    "PlotArrays",
    "TrackerConfig",
    "TrackerStats",
    "as_plot_arrays",
    "ct_transition",
    "cv_transition",
    "track_update_dtype",
]
