"""``FixedTargets``' detection (``fixed_targets._detect``, the numpy reference) as one
compiled pass per batch: the same candidates, sums and verdicts, to the bit.

A radar's batch is a few dozen plots and the reference spends most of its time in the
set-up of its ~80 numpy calls. Here every step runs in the reference's order of
operations (the least-squares sums added plot by plot, as ``np.add.at`` adds them; the
candidates kept sorted by a stable sort of their identity), so that the candidate table
and the verdicts are identical; ``tests/test_fixed_targets.py`` holds the two to it on
drawn and recorded batches.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tracker_service.compiled_arrays import maximum, median
from tracker_service.numba_symbols import numba

__all__ = ["SETTINGS", "classify", "detect"]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

SETTINGS = (
    "period_s",
    "fixed_memory_s",
    "stale_s",
    "halo2",
    "min_radius_m",
    "gate_sigmas",
    "slowest_m_s",
    "reach_m_s",
    "moving_steps",
    "monitor_min_plots",
    "min_plots",
    "min_duration_s",
    "monitor_max_speed_m_s",
    "max_speed_m_s",
    "monitor_speed_sigmas",
    "speed_sigmas",
)
"""The kernels' ``settings`` tuple, in this order: ``FixedTargetConfig`` for one radar
(its antenna period, the memories in seconds, the halo squared, the speeds in m/s, the
counts as floats; ``FixedTargets`` builds it)."""


# The columns of ``fixed_targets._Candidates.values``.
N, T0, X0, Y0, LAST, ST, SX, SY, STT, STX, STY, VAR, MOVES = range(13)
N_FIELDS = 13
CODE_KEY = 1 << 24
NO_KEY = -1
"""As ``fixed_targets``' identity keys."""


@numba.njit(cache=True, error_model="numpy")
def _stable_order(key: IntArray, live: IntArray) -> IntArray:  # pragma: no cover - compiled
    """``live[np.argsort(key[live], kind="stable")]`` without sorting the whole table:
    the table is its previous sorted candidates followed by those the last batch added,
    so its longest ordered prefix is merged with the rest, sorted (ties: prefix first,
    as a stable sort keeps them)."""
    m = live.shape[0]
    p = 1 if m else 0
    while p < m and key[live[p]] >= key[live[p - 1]]:
        p += 1
    rest = live[p:][np.argsort(key[live[p:]], kind="mergesort")]
    order = np.empty(m, np.int64)
    a = 0
    b = 0
    for j in range(m):
        if b >= rest.shape[0] or (a < p and key[live[a]] <= key[rest[b]]):
            order[j] = live[a]
            a += 1
        else:
            order[j] = rest[b]
            b += 1
    return order


@numba.njit(cache=True, error_model="numpy", inline="always")
def _speed_bound(v: FloatArray, sigmas: float) -> float:  # pragma: no cover - compiled
    """``_Candidates.speed_bound`` of one candidate's row ``v``."""
    n = v[N]
    st = v[ST]
    s_tt = v[STT] - st**2 / n
    vx = (v[STX] - st * v[SX] / n) / s_tt
    vy = (v[STY] - st * v[SY] / n) / s_tt
    sigma_v = np.sqrt(v[VAR] / n / s_tt)
    bound = np.hypot(vx, vy) + sigmas * sigma_v
    return bound if s_tt > 1e-6 else np.inf


@numba.njit(cache=True, error_model="numpy")
def classify(
    t: FloatArray,
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    address: IntArray,
    mode3a: IntArray,
    code_valid: BoolArray,
    eligible: BoolArray,
    monitor_codes: IntArray,
    unkeyed_codes: IntArray,
    key: IntArray,
    values: FloatArray,
    fixed: BoolArray,
    settings: tuple[float, ...],
) -> tuple[BoolArray, IntArray, FloatArray, BoolArray]:  # pragma: no cover - compiled
    """``FixedTargets.classify``'s detection over a table's plots: each plot's identity
    (``identity_keys``: its address, else its usable code unless shared or an emergency;
    a site monitor's code counts even garbled) and whether it wears a site-monitor code,
    then ``detect`` of the ``eligible`` plots with an identity. Returns, per plot,
    whether it is taken as fixed, and the candidates' new table."""
    n = t.shape[0]
    keys = np.empty(n, np.int64)
    monitor = np.zeros(n, np.bool_)
    rows = np.empty(n, np.int64)
    k = 0
    for i in range(n):
        code = mode3a[i]
        for c in monitor_codes:
            if code >= 0 and code == c:
                monitor[i] = True
        usable = (code_valid[i] or monitor[i]) and code >= 0
        for c in unkeyed_codes:
            if code == c:
                usable = False
        keys[i] = address[i] if address[i] >= 0 else (CODE_KEY + code if usable else NO_KEY)
        if eligible[i] and keys[i] != NO_KEY:
            rows[k] = i
            k += 1
    rows = rows[:k]
    taken = np.zeros(n, np.bool_)
    if not k:
        return taken, key, values, fixed
    found, new_key, new_values, new_fixed = detect(
        t[rows],
        x[rows],
        y[rows],
        r[rows],
        keys[rows],
        monitor[rows],
        key,
        values,
        fixed,
        settings,
    )
    for j in range(k):
        taken[rows[j]] = found[j]
    return taken, new_key, new_values, new_fixed


@numba.njit(cache=True, error_model="numpy")
def detect(
    t: FloatArray,
    x: FloatArray,
    y: FloatArray,
    r: FloatArray,
    keys: IntArray,
    monitor: BoolArray,
    key: IntArray,
    values: FloatArray,
    fixed: BoolArray,
    settings: tuple[float, ...],
) -> tuple[BoolArray, IntArray, FloatArray, BoolArray]:  # pragma: no cover - compiled
    """``FixedTargets._detect`` of plots (time, x, y, R, identity key, wears a
    site-monitor code) against the candidates (``key``, ``values``, ``fixed``): per plot
    whether it is taken as fixed, and the candidates' new table."""
    (
        period_s, fixed_memory_s, stale_s, halo2, min_radius_m, gate_sigmas, slowest_m_s,
        reach_m_s, moving_steps, monitor_min_plots, min_plots, min_duration_s,
        monitor_max_speed_m_s, max_speed_m_s, monitor_speed_sigmas, speed_sigmas,
    ) = settings  # fmt: skip
    k = t.shape[0]
    sigma = np.empty(k)
    for i in range(k):
        a, b, d = r[i, 0, 0], r[i, 0, 1], r[i, 1, 1]
        half = 0.5 * (a + d)
        sigma[i] = np.sqrt(half + np.sqrt(maximum(0.25 * (a - d) ** 2 + b * b, 0.0)))
    now = median(t)
    # Forget the quiet candidates; the others sorted by identity (stably).
    live = np.empty(key.shape[0], np.int64)
    m = 0
    for c in range(key.shape[0]):
        memory = fixed_memory_s if fixed[c] else stale_s
        if values[c, LAST] >= now - memory:
            live[m] = c
            m += 1
    order = _stable_order(key, live[:m])
    # Room for one new candidate per plot.
    new_key = np.empty(m + k, np.int64)
    new_values = np.empty((m + k, N_FIELDS))
    new_fixed = np.empty(m + k, np.bool_)
    for j in range(m):
        o = order[j]
        new_key[j] = key[o]
        for f in range(N_FIELDS):
            new_values[j, f] = values[o, f]
        new_fixed[j] = fixed[o]
    sorted_keys = new_key[:m]
    rows = np.full(k, -1, np.int64)
    halo = np.zeros(k, np.bool_)
    moves = np.zeros(k)
    for i in range(k):
        first = np.searchsorted(sorted_keys, keys[i], "left")
        last = np.searchsorted(sorted_keys, keys[i], "right")
        radius = maximum(min_radius_m, gate_sigmas * sigma[i])
        best = np.inf
        best_slot = -1
        near = False
        steps = -np.inf
        for s in range(first, last):
            v = new_values[s]
            n = maximum(v[N], 1.0)
            mx = v[X0] + v[SX] / n
            my = v[Y0] + v[SY] / n
            d2 = (x[i] - mx) ** 2 + (y[i] - my) ** 2
            if new_fixed[s] and d2 <= halo2:
                near = True
            # np.argmin over the areas: the first of the smallest, NaN never inside.
            if d2 <= radius**2 and d2 < best:
                best = d2
                best_slot = s
            # _moves: a move from a previous scan's open candidate of its identity.
            dt = t[i] - v[LAST]
            slow = (slowest_m_s * dt) ** 2
            fast = (reach_m_s * dt) ** 2
            moved = not new_fixed[s] and dt >= 0.5 * period_s and d2 > slow and d2 <= fast
            step = v[MOVES] + 1.0 if moved else 0.0
            if step > steps:
                steps = step
        if last > first:
            halo[i] = near and monitor[i]
            inside = best_slot >= 0
            if inside:
                rows[i] = best_slot
            moves[i] = steps * (1.0 if monitor[i] and not inside else 0.0)
    # New candidates, one per plot outside every area of its identity.
    size = m
    for i in range(k):
        if rows[i] < 0:
            new_key[size] = keys[i]
            new_values[size] = 0.0
            new_values[size, T0] = t[i]
            new_values[size, LAST] = t[i]
            new_values[size, X0] = x[i]
            new_values[size, Y0] = y[i]
            new_fixed[size] = False
            new_values[size, MOVES] = moves[i]
            rows[i] = size
            size += 1
    # The sums, plot by plot (np.add.at's order when a candidate takes two plots).
    for i in range(k):
        v = new_values[rows[i]]
        dt = t[i] - v[T0]
        dx = x[i] - v[X0]
        dy = y[i] - v[Y0]
        v[N] += 1.0
        v[ST] += dt
        v[SX] += dx
        v[SY] += dy
        v[STT] += dt * dt
        v[STX] += dt * dx
        v[STY] += dt * dy
        v[VAR] += sigma[i] ** 2
        v[LAST] = maximum(v[LAST], t[i])
    stationary = np.empty(k, np.bool_)
    for i in range(k):
        v = new_values[rows[i]]
        mon = monitor[i]
        mover = mon and v[MOVES] >= moving_steps
        enough = v[N] >= (monitor_min_plots if mon else min_plots)
        enough = enough and v[LAST] - v[T0] >= (0.0 if mon else min_duration_s)
        bound = _speed_bound(v, monitor_speed_sigmas if mon else speed_sigmas)
        limit = monitor_max_speed_m_s if mon else max_speed_m_s
        stationary[i] = enough and bound <= limit and not mover
    for i in range(k):
        new_fixed[rows[i]] = stationary[i]
    fitted = np.zeros(k, np.bool_)
    for i in range(k):
        v = new_values[rows[i]]
        enough = v[N] >= monitor_min_plots and v[LAST] - v[T0] >= 0.5 * period_s
        if monitor[i] and not stationary[i] and enough:
            fitted[i] = _speed_bound(v, -monitor_speed_sigmas) > monitor_max_speed_m_s
    for i in range(k):
        if fitted[i]:
            new_values[rows[i], MOVES] = moving_steps
    taken = np.empty(k, np.bool_)
    for i in range(k):
        undecided = monitor[i] and new_values[rows[i], MOVES] < moving_steps
        taken[i] = stationary[i] or halo[i] or undecided
    return taken, new_key[:size], new_values[:size], new_fixed[:size]
