"""The clock part of a radar's bias state: time offset, drift and drift rate.

With ``BiasConfig.clock_states`` = n, each radar's time error is the offset (the bias
vector's TIME component) and n - 1 extra states after the bias components of the filter's
state: the drift d (s/s) and the drift rate a (s/s^2). Between two times dt apart

    offset += d dt + a dt^2 / 2,   d += a dt,

and every clock state takes a random walk of variance Q0 dt (DOMAIN.md section 6, the UWB
thesis: the process noise scaled by the time step). The filters work on states divided by
their prior sigma, so the transition's coefficients carry the ratio of the scales.

A plot's position depends on the offset at its time alone: the extra states enter no
observation matrix, only the transition; they become observable through the offset's
change over time (ADS-B pins the offset absolutely; traffic only relative to the other
radars, as for the offset itself).

With ``reception_clock`` (and a drift state), one more extra state per radar, last: the
mean transmission delay c of its CAT034 messages (constant, a slow walk). A message
stamped T (I030, the radar's clock) at a sector boundary crossed at true time t = T - b(t)
is received at t + c + e, e the delay's jitter, so reception - T = c - b(t) + e: the
offset's change, and so the drift, to the receiving host's clock (``reception_update``).
ADS-B alone gives the drift to 0.1-0.27 s/h in 10 minutes on clock_drift.toml (its
Cramer-Rao bound, ``benchmarks/clock_bound.py``: a plot gives the offset to 0.3-0.5 s);
the CAT034 stamps, at 10 ms of jitter, to a few ms/h. The delay is not published: it is
the receiver's business, not the radar's bias.
"""

from __future__ import annotations

import numpy as np

from tracker_service.bias.config import N_BIAS, TIME, BiasConfig
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

RECEPTION_GATE = 10.83
"""Chi-square gate (1 dof, 99.9 %) of a CAT034 message's delay residual: a message held
in a queue is late, never early, and is dropped."""


class ClockModel:
    """The extra clock states' scales, walks and transition (see the module docstring)."""

    def __init__(self, config: BiasConfig) -> None:
        self.n_clock = config.clock_states - 1
        """The published extra states: drift (and drift rate)."""
        self.reception = config.reception_clock and self.n_clock > 0
        self.n_extra = self.n_clock + int(self.reception)
        """Extra states per radar in the filters' layout: the published ones, then the
        reception delay with ``reception``."""
        self.offset_scale = float(config.prior_sigma()[TIME])
        scale, walk = config.clock_prior_sigma(), config.clock_walk_sigma()
        if self.reception:
            scale = np.append(scale, config.prior_sigma_reception_delay_s)
            walk = np.append(walk, config.walk_sigma_reception_delay_s)
        self.scale = scale
        self.walk_var = (walk / self.scale) ** 2
        self.jitter_var = config.reception_jitter_s**2
        self.gate = RECEPTION_GATE

    def indices(
        self, n_radars: int, bias_start: int = 0, extra_start: int | None = None
    ) -> tuple[IntArray, IntArray]:
        """Where each radar's offset (L,) and extra states (L, n_extra) sit in a joint
        state whose bias blocks of 4 start at ``bias_start`` and whose extra clock
        states (radar by radar) start at ``extra_start`` (default: after the biases)."""
        if extra_start is None:
            extra_start = bias_start + N_BIAS * n_radars
        offset = bias_start + N_BIAS * np.arange(n_radars) + TIME
        extra = extra_start + self.n_extra * np.arange(n_radars)[:, None] + np.arange(self.n_extra)
        return offset.astype(np.int64), extra.astype(np.int64)

    def predict(
        self,
        x: FloatArray,
        P: FloatArray,
        dt: float,
        offset: IntArray,
        extra: IntArray,
        moving: BoolArray,
    ) -> None:
        """Apply the transition over dt in place to the radars ``moving`` (L,) (those whose
        time error is estimated; the others keep their prior, uncoupled). F P F^T is done
        as row operations then the same column operations."""
        if self.n_clock == 0 or dt == 0.0 or not moving.any():
            return
        off = offset[moving]
        ext = extra[moving]
        steps = self._steps(dt)
        # Highest derivative last: each row first takes the others' old values.
        for target, source, coefficient in steps:
            rows_t = off if target < 0 else ext[:, target]
            rows_s = ext[:, source]
            x[rows_t] += coefficient * x[rows_s]
            P[rows_t, :] += coefficient * P[rows_s, :]
        for target, source, coefficient in steps:
            rows_t = off if target < 0 else ext[:, target]
            rows_s = ext[:, source]
            P[:, rows_t] += coefficient * P[:, rows_s]

    def _steps(self, dt: float) -> list[tuple[int, int, float]]:
        """(target, source, coefficient) of the scaled transition, target -1 the offset,
        in the order that reads only values not yet updated."""
        steps = [(-1, 0, dt * self.scale[0] / self.offset_scale)]
        if self.n_clock == 2:
            steps.append((-1, 1, 0.5 * dt * dt * self.scale[1] / self.offset_scale))
            steps.append((0, 1, dt * self.scale[1] / self.scale[0]))
        return steps

    def reception_update(
        self, x: FloatArray, P: FloatArray, offset: int, delay: int, observed: float
    ) -> bool:
        """One CAT034 message, ``observed`` = reception - I030 (s) at the state's time, in
        place on a radar's scaled state (x, P) whose offset and delay sit at ``offset`` and
        ``delay``; False (nothing changed) when the residual is out of the gate."""
        h = np.zeros(len(x))
        h[offset] = -self.offset_scale
        h[delay] = self.scale[-1]
        g = P @ h
        innovation_var = float(h @ g) + self.jitter_var
        residual = observed - float(h @ x)
        if residual * residual > self.gate * innovation_var:
            return False
        gain = g / innovation_var
        x += gain * residual
        P -= np.outer(gain, g)
        P[:] = 0.5 * (P + P.T)
        return True
