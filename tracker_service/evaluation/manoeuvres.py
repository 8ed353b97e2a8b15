"""Turn onsets from the truth, and how soon and how well local tracks follow them.

Definitions (docs/fusion.md, "Mode S DAPs"):

- Turn rate of the truth: between consecutive truth snapshots, the change of the true
  velocity's direction in the system plane over their interval (counter-clockwise
  positive). An aircraft turns where |rate| > ``TURNING_DEG_S``.
- Turn onset: the start of a turning run that follows at least ``STRAIGHT_BEFORE_S`` of
  straight flight. Within its first interval the onset is placed where the interval's
  mean rate says the turn began: t_k + (1 - rate_k / rate_k+1) (a constant-rate turn
  starting mid-interval). The turn ends where the run ends.
- Manoeuvre detection delay: for a turn onset at t0 of an aircraft with a confirmed local
  track (a confirmed update from one of its plots within two scan periods before t0),
  the time from t0 to the first confirmed update from a plot at or after t0 where the
  track's probability of the turn models turning the same way is at least 0.5. A turn
  the track never shows so before it ends counts as missed (not in the delay).
- Across-track RMS during turns: over confirmed updates from plots of an aircraft while
  its truth turns (t0 <= t <= end), the RMS of the error across the true velocity.
- False turn alarms: the share of confirmed updates in straight flight (no turn within
  ``STRAIGHT_BEFORE_S``) where the turn models' probability is at least 0.5.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.metrics import (
    LocalMetrics,
    PlotOrigins,
    Truth,
    associate_updates,
)
from tracker_service.tracking.plots import FloatArray

TURNING_DEG_S = 0.3
STRAIGHT_BEFORE_S = 20.0
DETECTED_PROBABILITY = 0.5
CONFIRMED = 1


@dataclass(frozen=True)
class Turn:
    aircraft: int
    onset: float
    end: float
    sign: int  # +1 counter-clockwise (left), -1 clockwise (right)


def truth_turn_rates(truth: Truth) -> FloatArray:
    """(T - 1, A) rad/s: each snapshot interval's turn rate (counter-clockwise)."""
    angle = np.arctan2(truth.vy, truth.vx)
    d = (np.diff(angle, axis=0) + np.pi) % (2.0 * np.pi) - np.pi
    return np.asarray(d / np.diff(truth.times)[:, None])


def turns(truth: Truth) -> list[Turn]:
    """Every turn onset of every aircraft (module docstring)."""
    rate = truth_turn_rates(truth)
    turning = np.abs(rate) > np.radians(TURNING_DEG_S)
    times = truth.times
    out = []
    for a in range(truth.n_aircraft):
        known = np.isfinite(rate[:, a])
        k = 0
        n = len(times) - 1
        straight_since = None
        while k < n:
            if not known[k]:
                straight_since = None
            elif not turning[k, a]:
                if straight_since is None:
                    straight_since = times[k]
            else:
                start = k
                while k + 1 < n and turning[k + 1, a] and known[k + 1]:
                    k += 1
                if straight_since is not None and times[start] - straight_since >= (
                    STRAIGHT_BEFORE_S
                ):
                    full = rate[min(start + 1, k), a]
                    part = rate[start, a]
                    frac = float(np.clip(1.0 - part / full, 0.0, 1.0)) if full else 0.0
                    onset = times[start] + frac * (times[start + 1] - times[start])
                    out.append(Turn(a, float(onset), float(times[k + 1]), int(np.sign(part))))
                straight_since = None
            k += 1
    return out


@dataclass
class ManoeuvreMetrics:
    turn_onsets: int
    """Onsets with a confirmed track at the onset (the others are not scored)."""
    detection_delay_mean_s: float | None
    detection_delay_median_s: float | None
    detection_delay_p95_s: float | None
    missed_turns: int
    across_track_rms_in_turns_m: float | None
    position_rms_in_turns_m: float | None
    updates_in_turns: int
    false_turn_alarm_rate: float | None

    def as_json(self) -> dict[str, Any]:
        return asdict(self)


def manoeuvre_metrics(
    updates: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    local: LocalMetrics,
    turn_rates_rad_s: FloatArray,
    period_s: float,
    gate_m: float = 1000.0,
) -> ManoeuvreMetrics:
    """The module docstring's metrics for one radar's local tracks. ``turn_rates_rad_s``:
    the IMM's models' rates (0 for CV), counter-clockwise, in model order."""
    found = turns(truth)
    labels = associate_updates(updates, origins, truth, gate_m)
    scored = (updates["status"] == CONFIRMED) & (updates["plot_id"] >= 0) & (labels >= 0)
    mu = np.asarray(updates["model_probabilities"], dtype=np.float64)
    left = mu[:, turn_rates_rad_s > 0].sum(axis=1)
    right = mu[:, turn_rates_rad_s < 0].sum(axis=1)
    times = np.asarray(updates["time"], dtype=np.float64)
    delays: list[float] = []
    missed = 0
    onsets = 0
    by_aircraft: dict[int, npt.NDArray[np.intp]] = {}
    for a in np.unique(labels[scored]).tolist():
        by_aircraft[a] = np.flatnonzero(scored & (labels == a))
    for turn in found:
        rows = by_aircraft.get(turn.aircraft)
        if rows is None:
            continue
        t = times[rows]
        before = (t < turn.onset) & (t >= turn.onset - 2.0 * period_s)
        if not before.any():
            continue
        onsets += 1
        during = rows[(t >= turn.onset) & (t <= turn.end)]
        shown = (left if turn.sign > 0 else right)[during] >= DETECTED_PROBABILITY
        if shown.any():
            delays.append(float(times[during][np.argmax(shown)] - turn.onset))
        else:
            missed += 1

    errors = local.errors
    across_rms = position_rms = None
    n_in_turns = 0
    false_rate = None
    if errors is not None and len(errors.time):
        in_turn = np.zeros(len(errors.time), dtype=bool)
        for turn in found:
            mine = errors.aircraft == turn.aircraft
            in_turn |= mine & (errors.time >= turn.onset) & (errors.time <= turn.end)
        n_in_turns = int(in_turn.sum())
        if n_in_turns:
            across_rms = float(np.sqrt(np.mean(errors.across[in_turn] ** 2)))
            position_rms = float(
                np.sqrt(np.mean(errors.dx[in_turn] ** 2 + errors.dy[in_turn] ** 2))
            )
    rows = np.flatnonzero(scored)
    near_turn = np.zeros(len(rows), dtype=bool)
    for turn in found:
        near_turn |= (
            (labels[rows] == turn.aircraft)
            & (times[rows] >= turn.onset - STRAIGHT_BEFORE_S)
            & (times[rows] <= turn.end + STRAIGHT_BEFORE_S)
        )
    straight = rows[~near_turn]
    if len(straight):
        false_rate = float(np.mean((left + right)[straight] >= DETECTED_PROBABILITY))
    d = np.asarray(delays)
    return ManoeuvreMetrics(
        turn_onsets=onsets,
        detection_delay_mean_s=float(d.mean()) if len(d) else None,
        detection_delay_median_s=float(np.median(d)) if len(d) else None,
        detection_delay_p95_s=float(np.percentile(d, 95)) if len(d) else None,
        missed_turns=missed,
        across_track_rms_in_turns_m=across_rms,
        position_rms_in_turns_m=position_rms,
        updates_in_turns=n_in_turns,
        false_turn_alarm_rate=false_rate,
    )
