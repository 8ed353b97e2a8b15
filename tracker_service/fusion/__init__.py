"""System tracking: local tracks of several radars to one system track per aircraft.

``SystemTracker.process`` takes one radar's batch of local-track updates (``tracking.
track_update_dtype``) and returns system-track rows (``SYSTEM_UPDATE_DTYPE``); association
by a chi-square test with identity bonuses and global nearest neighbour, then either ML
fusion of the local tracks (``ml``) or a filter per system track updated by their plots
(``FusionConfig.method``). ``SystemTracker.references`` gives the bias estimator
predictions a plot has not updated.
"""

from tracker_service.fusion.config import FusionConfig
from tracker_service.fusion.messages import (
    COASTING,
    CONFIRMED,
    ENDED,
    MAX_SOURCES,
    SYSTEM_UPDATE_DTYPE,
    TENTATIVE,
)
from tracker_service.fusion.ml import ml_fuse
from tracker_service.fusion.tracker import FusionStats, References, SystemTracker

__all__ = [
    "COASTING",
    "CONFIRMED",
    "ENDED",
    "MAX_SOURCES",
    "SYSTEM_UPDATE_DTYPE",
    "TENTATIVE",
    "FusionConfig",
    "FusionStats",
    "References",
    "SystemTracker",
    "ml_fuse",
]
