"""Vertical-tracking metrics of local tracks against the truth (``evaluate --json``'s
"vertical"): the climb rate in steady climbs and descents and in level flight, and how
soon a level-off shows in the track.

The truth's climb rate is that of its pressure altitude (``/truth/aircraft`` "fl", the
Mode C the aircraft reports, sampled at the truth rate): what ``climb_rate_fpm`` means.
A moment is in a *steady* climb or descent when the truth's rate has been the same
(within ``SAME_RATE_FPM``) for ``steady_after_s`` and stays so for ``STEADY_AHEAD_S``: the
onset is the IMM's to detect, not a steady state. A *level-off* is a change from a rate
above ``level_fpm`` to level flight held for ``LEVEL_HELD_S``; its delay is the time from
it to the first confirmed update of the aircraft's track after which every update in the
next ``LEVEL_HELD_S`` says less than ``level_fpm``.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.metrics import PlotOrigins, Truth, associate_updates

FloatArray = npt.NDArray[np.float64]
FPM_PER_FL_S = 6000.0
SAME_RATE_FPM = 20.0
STEADY_AHEAD_S = 5.0
LEVEL_HELD_S = 60.0
CONFIRMED = 1


def truth_rates(truth: Truth) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Per truth interval (T-1, A): the climb rate (ft/min) and how long it has held
    before the interval's start and will hold after its end (s)."""
    dt = np.diff(truth.times)[:, None]
    rate = np.diff(truth.fl, axis=0) / dt * FPM_PER_FL_S
    n, a = rate.shape
    held_before = np.zeros((n, a))
    held_after = np.zeros((n, a))
    same = np.abs(np.diff(rate, axis=0)) <= SAME_RATE_FPM  # (n-1, a): k and k+1 alike
    for k in range(1, n):
        held_before[k] = np.where(same[k - 1], held_before[k - 1] + dt[k - 1, 0], 0.0)
    for k in range(n - 2, -1, -1):
        held_after[k] = np.where(same[k], held_after[k + 1] + dt[k + 1, 0], 0.0)
    return rate, held_before, held_after


def vertical_metrics(
    updates: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    *,
    gate_m: float = 1000.0,
    steady_after_s: float = 30.0,
    level_fpm: float = 300.0,
) -> dict[str, float | int | None]:
    """One radar's vertical metrics (see the module docstring)."""
    empty: dict[str, float | int | None] = {
        "climb_rate_rms_fpm_steady": None,
        "climb_rate_p95_fpm_steady": None,
        "climb_rate_max_fpm_steady": None,
        "steady_updates": 0,
        "climb_rate_rms_fpm_level": None,
        "level_offs": 0,
        "level_off_delay_mean_s": None,
        "level_off_delay_max_s": None,
    }
    if len(truth.times) < 3 or len(updates) == 0:
        return empty
    labels = associate_updates(updates, origins, truth, gate_m)
    keep = (
        (updates["status"] == CONFIRMED)
        & (updates["plot_id"] >= 0)
        & (labels >= 0)
        & np.isfinite(updates["climb_rate_fl_per_s"])
    )
    u = updates[keep]
    a = labels[keep]
    t = np.asarray(u["time"], dtype=np.float64)
    rate = np.asarray(u["climb_rate_fl_per_s"], dtype=np.float64) * FPM_PER_FL_S
    true_rate, before, after = truth_rates(truth)
    k = np.clip(np.searchsorted(truth.times, t, side="right") - 1, 0, len(truth.times) - 2)
    inside = (t >= truth.times[0]) & (t <= truth.times[-1]) & (a < truth.n_aircraft)
    a_safe = np.where(inside, a, 0)
    truth_now = np.where(inside, true_rate[k, a_safe], np.nan)
    since = t - truth.times[k] + before[k, a_safe]
    ahead = truth.times[k + 1] - t + after[k, a_safe]
    error = rate - truth_now
    moving = np.abs(truth_now) > level_fpm
    steady = inside & moving & (since >= steady_after_s) & (ahead >= STEADY_AHEAD_S)
    level = inside & (np.abs(truth_now) < 1.0) & (since >= steady_after_s)
    out = dict(empty)
    if steady.any():
        e = np.abs(error[steady])
        out["climb_rate_rms_fpm_steady"] = float(np.sqrt(np.mean(e * e)))
        out["climb_rate_p95_fpm_steady"] = float(np.percentile(e, 95))
        out["climb_rate_max_fpm_steady"] = float(e.max())
        out["steady_updates"] = int(steady.sum())
    if level.any():
        out["climb_rate_rms_fpm_level"] = float(np.sqrt(np.mean(error[level] ** 2)))
    delays = _level_off_delays(truth, true_rate, after, t, a, rate, level_fpm)
    out["level_offs"] = len(delays)
    if delays:
        out["level_off_delay_mean_s"] = float(np.mean(delays))
        out["level_off_delay_max_s"] = float(np.max(delays))
    return out


def _level_off_delays(
    truth: Truth,
    true_rate: FloatArray,
    after: FloatArray,
    t: FloatArray,
    a: npt.NDArray[np.int64],
    rate: FloatArray,
    level_fpm: float,
) -> list[float]:
    """Per level-off the aircraft's track saw (updates on both sides), its delay."""
    climbing = np.abs(true_rate) > level_fpm
    level = np.abs(true_rate) < 1.0
    # Interval k climbing, k+1 level and held: the level-off at times[k + 1].
    event = climbing[:-1] & level[1:] & (after[1:] + np.diff(truth.times)[1:, None] >= LEVEL_HELD_S)
    delays = []
    for k, aircraft in zip(*np.nonzero(event), strict=True):
        at = float(truth.times[k + 1])
        mine = a == aircraft
        window = mine & (t > at - 30.0) & (t <= at + LEVEL_HELD_S + 60.0)
        times, rates = t[window], rate[window]
        if not (times < at).any() or not (times > at + LEVEL_HELD_S).any():
            continue
        late = times >= at
        for i in np.flatnonzero(late):
            ahead = (times >= times[i]) & (times <= times[i] + LEVEL_HELD_S)
            if np.all(np.abs(rates[ahead]) < level_fpm):
                delays.append(float(times[i] - at))
                break
    return delays
