"""``TimeSanity.check``'s arithmetic (the numpy reference) as one compiled pass per batch:
the plots' times on their radar's timeline, the implausible ones, and the batch's pieces
of evidence (its offset from reception, its usual phase against THETA), the same values
to the bit. The radar's evidence (``_Timeline``'s deques), the logging and the re-basing
stay in ``TimeSanity``; ``tests/test_time_sanity.py`` holds the two to each other.
"""

from __future__ import annotations

import math

import numpy as np
import numpy.typing as npt

from tracker_service.compiled_arrays import median
from tracker_service.numba_symbols import numba

__all__ = ["judge_times"]

FloatArray = npt.NDArray[np.float64]
BoolArray = npt.NDArray[np.bool_]
I140, AZIMUTH, RECEPTION = 0, 1, 2
"""``ingest.TimeSource`` values."""
DAY_S = 86400.0


@numba.njit(cache=True, error_model="numpy")
def _upper_median(values: FloatArray, toward: float, use_toward: bool) -> float:  # pragma: no cover
    """``time_sanity._median``: the upper middle value, or of two middle ones the one
    nearer ``toward``."""
    ordered = np.sort(values)
    n = ordered.shape[0]
    upper = ordered[n // 2]
    if not use_toward or n % 2:
        return float(upper)
    lower = ordered[n // 2 - 1]
    return float(lower if abs(lower - toward) < abs(upper - toward) else upper)


@numba.njit(cache=True, error_model="numpy", inline="always")
def _nearest(time: float, reference: float, step: float) -> float:  # pragma: no cover
    return float(time + step * np.round((reference - time) / step))


@numba.njit(cache=True, error_model="numpy", inline="always")
def _wrap(turns: float) -> float:  # pragma: no cover - compiled
    return float(turns - np.round(turns))


@numba.njit(cache=True, error_model="numpy")
def judge_times(
    times_in: FloatArray,
    sources: npt.NDArray[np.int8],
    theta_deg: FloatArray,
    received: float,
    history: FloatArray,
    phases: FloatArray,
    phases_kept: int,
    period: float,
    north_posix: float,
    latency_s: float,
    plausible_periods: float,
    max_offset_s: float,
    azimuth_tolerance: float,
) -> tuple[FloatArray, BoolArray, float, float, float]:  # pragma: no cover - compiled
    """The batch's times and implausible plots (``TimeSanity.check`` before its logging
    and re-basing), the offset it judged them by, and the evidence to keep: its offset
    from reception (NaN: none) and its phase against THETA (NaN: none). ``history``: the
    radar's offsets so far; ``phases``: its phases, of which the last ``phases_kept``
    stay beside the new one."""
    n = times_in.shape[0]
    times = times_in.copy()
    n_stamped = 0
    for i in range(n):
        if sources[i] == I140:
            n_stamped += 1
    has_prior = history.shape[0] > 0
    prior = _upper_median(history, 0.0, False) if has_prior else 0.0
    if has_prior and n_stamped:
        for i in range(n):
            if sources[i] == I140:
                times[i] = _nearest(times[i], received + prior, DAY_S)
    plot_offsets = np.empty(n_stamped)
    k = 0
    for i in range(n):
        if sources[i] == I140:
            plot_offsets[k] = times[i] - received
            k += 1
    m = history.shape[0]
    if n_stamped and m >= 2:
        # This datagram is one piece of evidence beside the others.
        pooled = np.empty(m + 1)
        pooled[:m] = history
        pooled[m] = _upper_median(plot_offsets, 0.0, False)
        offset = _upper_median(pooled, 0.0, False)
    elif n_stamped:
        pooled = np.empty(m + n_stamped)
        pooled[:m] = history
        pooled[m:] = plot_offsets
        offset = _upper_median(pooled, 0.0, True)
    else:
        offset = prior
    expected = received + offset
    rebase_azimuth = abs(offset) > max_offset_s
    for i in range(n):
        if sources[i] == I140 and not has_prior:
            times[i] = _nearest(times[i], expected, DAY_S)
        elif sources[i] == RECEPTION:
            times[i] = expected
        elif sources[i] == AZIMUTH and rebase_azimuth:
            times[i] = _nearest(times[i], expected, period)
    implausible = np.empty(n, np.bool_)
    limit = latency_s + plausible_periods * period
    recent = np.zeros(n, np.bool_)
    n_recent = 0
    for i in range(n):
        implausible[i] = abs(times[i] - expected) > limit
        judged = sources[i] == I140 and not implausible[i]
        near = abs(times[i] - north_posix) <= 2.0 * period and np.isfinite(theta_deg[i])
        if judged and near:
            recent[i] = True
            n_recent += 1
    new_phase = math.nan
    if n_recent:
        # _off_azimuth: the plots' phase against THETA beside the radar's usual one.
        phase = np.empty(n_recent)
        k = 0
        for i in range(n):
            if recent[i]:
                phase[k] = _wrap((times[i] - north_posix) / period - theta_deg[i] / 360.0)
                k += 1
        new_phase = median(phase)
        kept = phases[phases.shape[0] - phases_kept :]
        usual_of = np.empty(phases_kept + 1)
        usual_of[:phases_kept] = kept
        usual_of[phases_kept] = new_phase
        usual = median(usual_of)
        k = 0
        for i in range(n):
            if recent[i]:
                if abs(_wrap(phase[k] - usual)) > azimuth_tolerance:
                    implausible[i] = True
                k += 1
    new_offset = math.nan
    if n_stamped:
        n_plausible = 0
        for i in range(n):
            if sources[i] == I140 and not implausible[i]:
                n_plausible += 1
        evidence = np.empty(n_plausible if n_plausible else n_stamped)
        k = 0
        for i in range(n):
            if sources[i] == I140 and (not implausible[i] or not n_plausible):
                evidence[k] = times[i] - received
                k += 1
        new_offset = _upper_median(evidence, 0.0, False)
    return times, implausible, offset, new_offset, new_phase
