"""The fuser's input built by hand for its association tests (test_fusion_exchange,
test_fusion_reassociation, test_association_fuser_joins): one radar's batch of confirmed,
primary-only local-track updates of aircraft flying east, with their plots, and the
system track a local track feeds."""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import SystemTracker
from tracker_service.tracking import CONFIRMED, PLOT_DTYPE, LocalTracker


def east_batch(
    numbers: list[int],
    t: float,
    x: npt.ArrayLike,
    y: npt.ArrayLike,
    sigma: float,
    first_id: int,
    speed: float,
) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """Local-track updates ``numbers`` at time t and positions (x, y) (scalars or one per
    track), steady filters (position ``sigma``, speed 3 m/s) flying east at ``speed``, each
    with its plot (ids from ``first_id``)."""
    k = len(numbers)
    u = np.zeros(k, dtype=LocalTracker().output_dtype)
    u["track_number"], u["time"], u["status"] = numbers, t, CONFIRMED
    u["plot_id"] = np.arange(first_id, first_id + k)
    u["x"], u["y"] = x, y
    u["vx"], u["vy"] = speed, 0.0
    u["P"] = np.diag([sigma**2, sigma**2, 9.0, 9.0]).reshape(16)
    u["flight_level"] = u["climb_rate_fl_per_s"] = np.nan
    u["mode3a"] = u["address"] = -1
    u["model_probabilities"][:, 0] = 1.0
    p = np.zeros(k, dtype=PLOT_DTYPE)
    p["time"], p["x"], p["y"], p["plot_id"] = t, u["x"], u["y"], u["plot_id"]
    p["R"] = np.diag([sigma**2, sigma**2])
    p["flight_level"], p["mode3a"], p["address"], p["typ"] = np.nan, -1, -1, 1
    return u, p


def system_of(fuser: SystemTracker, radar: int, number: int) -> int:
    """The system track that radar's local track ``number`` feeds (0: none)."""
    u = np.zeros(1, dtype=LocalTracker().output_dtype)
    u["track_number"], u["status"] = number, CONFIRMED
    row = int(fuser.state.local.find(radar, u, create=False)[0])
    return int(fuser.state.local.rows["system"][row])
