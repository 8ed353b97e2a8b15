"""The fuser's output: one row per system track touched by a batch."""

from __future__ import annotations

import numpy as np

TENTATIVE, CONFIRMED, COASTING, ENDED = 0, 1, 2, 3
"""System-track statuses: TENTATIVE is not used by the fuser (only confirmed local tracks
create system tracks); COASTING: no fresh plot in the row; ENDED: the track's last row."""

MAX_SOURCES = 8
MAX_SYSTEM_NUMBER = 8191
"""System track numbers are 1..MAX_SYSTEM_NUMBER (CAT062's I062/040 holds 16 bits). A
number waits ``FusionConfig.number_reuse_delay_s`` (300 s) after its track ended, so the
numbers must cover the live tracks and those ended within the delay: at ARTAS-class
load (``artas``: 4,000 aircraft, some 2 tracks ending a second) about 4,600, and 4,095
ran out 90 s into the scenario; new aircraft then went without a system track until
numbers came free, five minutes later, in bursts (docs/benchmarks.md, "Session 15")."""

SYSTEM_UPDATE_DTYPE = np.dtype(
    [
        ("system_number", np.int64),
        ("time", np.float64),
        ("x", np.float64),
        ("y", np.float64),
        ("vx", np.float64),
        ("vy", np.float64),
        ("P", np.float64, (16,)),
        ("flight_level", np.float64),
        ("climb_rate_fl_per_s", np.float64),
        ("status", np.int8),
        ("fresh", np.bool_),
        ("radar", np.int16),
        ("plot_id", np.int64),
        ("address", np.int64),
        ("mode3a", np.int64),
        ("n_sources", np.int16),
        ("local_radars", np.int16, (MAX_SOURCES,)),
        ("local_numbers", np.int64, (MAX_SOURCES,)),
        ("local_plot_ids", np.int64, (MAX_SOURCES,)),
        ("adsb_inconsistent", np.bool_),
    ]
)
"""The state [x, y, vx, vy] in the system plane with P the flattened 4x4; flight level NaN
when unknown; radar: whose batch produced the row; plot_id: that radar's plot in the row
(-1 none); address, mode3a -1 when unknown; the local tracks that fed the row (ARTAS's
track-related information), most recent first, -1 in unused slots; adsb_inconsistent:
the ADS-B reports of its address disagree with its radars (fusion/adsb_source.py)."""
