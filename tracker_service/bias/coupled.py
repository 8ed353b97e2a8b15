"""Variant 1, the full coupled filter: every aircraft and every radar's bias in one state.

State [s_1 .. s_L | x_1 .. x_N], x_a = [x, y, vx, vy] (CV), with all cross-covariances:
one filter per aircraft that each update the shared s would count the same information
many times. A traffic plot of aircraft a by radar l measures x_a's position plus C s_l;
fixed references (field monitor, ADS-B) measure C s_l against reference_xy. Cost is the
square of the state per plot: the reference on small scenarios, refused beyond
``max_coupled_states``.
"""

from __future__ import annotations

import numpy as np

from tracker_service.bias.common import (
    BiasFilterBase,
    joint_blocks,
    joint_clock_blocks,
    split_update,
)
from tracker_service.bias.config import N_BIAS, BiasConfig
from tracker_service.bias.observations import BiasObservations, ObservationKind
from tracker_service.tracking.plots import FloatArray, IntArray


class CoupledSizeError(ValueError):
    """The joint state would exceed ``BiasConfig.max_coupled_states``."""


class CoupledBiasFilter(BiasFilterBase):
    def __init__(self, config: BiasConfig, n_radars: int) -> None:
        super().__init__(config, n_radars)
        self._n_bias = n_radars * self.n_state
        if self._n_bias > config.max_coupled_states:
            raise CoupledSizeError(
                f"coupled filter: {n_radars} radars need {self._n_bias} states, above "
                f"max_coupled_states={config.max_coupled_states}"
            )
        self._x, self._P = self.prior()
        self._time = np.nan
        self._slot: dict[int, int] = {}
        self._last: dict[int, float] = {}
        self._position = np.zeros(0, dtype=np.int64)

    @property
    def n_aircraft(self) -> int:
        return len(self._slot)

    def bias_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_blocks(self._x, self._P, self.n_radars)

    def clock_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_clock_blocks(self, self._x, self._P)

    def _process(self, obs: BiasObservations) -> None:
        self._drop_silent(float(obs.time[0]))
        free_bias = self.joint_free()
        counted = np.ones(len(obs), dtype=bool)
        accepted = np.zeros(len(obs), dtype=bool)
        traffic = (obs.kind == ObservationKind.AIRCRAFT) & (obs.group >= 0)
        gate = self.config.outlier_gate
        for i in range(len(obs)):
            t = float(obs.time[i])
            self._predict(t)
            radar = int(obs.radar[i])
            block = slice(N_BIAS * radar, N_BIAS * (radar + 1))
            C = obs.C[i]
            if traffic[i]:
                group = int(obs.group[i])
                if group not in self._slot:
                    self._add(group, obs, i)
                    self._last[group] = t
                    counted[i] = False
                    continue
                pos = slice(self._slot[group], self._slot[group] + 2)
                G = self._P[:, pos] + self._P[:, block] @ C.T
                S = G[pos] + C @ G[block] + obs.R[i]
                nu = obs.y[i] - self._x[pos] - C @ self._x[block]
            else:
                G = self._P[:, block] @ C.T
                S = C @ G[block] + obs.R[i] + obs.reference_P[i]
                nu = obs.y[i] - obs.reference_xy[i] - C @ self._x[block]
            free = np.ones(len(self._x), dtype=bool)
            free[: self._n_bias] = free_bias
            accepted[i] = split_update(self._x, self._P, G, S, nu, free, gate)
            if traffic[i] and accepted[i]:
                # Only accepted plots keep an aircraft alive: one started on a gross outlier
                # gets no plot through its gate and is restarted after the timeout.
                self._last[int(obs.group[i])] = t
        self.count(obs.radar[counted], accepted[counted])

    def _predict(self, t: float) -> None:
        if not np.isfinite(self._time):
            self._time = t
        dt = t - self._time
        if dt == 0.0:
            return
        self._time = t
        P, pos = self._P, self._position
        vel = pos + 2
        self._x[pos] += dt * self._x[vel]
        P[pos, :] += dt * P[vel, :]
        P[:, pos] += dt * P[:, vel]
        q, h = self.config.coupled_accel_sigma**2, abs(dt)
        P[pos, pos] += q * h**3 / 3.0
        P[pos, vel] += q * h**2 / 2.0
        P[vel, pos] += q * h**2 / 2.0
        P[vel, vel] += q * h
        self.predict_joint(self._x, self._P, dt)

    def _add(self, group: int, obs: BiasObservations, i: int) -> None:
        """A new aircraft from its first plot: position y - C s, whose error -C (s_hat - s)
        + w is correlated with everything s_hat is; velocity from reference_v."""
        n = len(self._x)
        if n + 4 > self.config.max_coupled_states:
            raise CoupledSizeError(
                f"coupled filter: aircraft {group} would make {n + 4} states, above "
                f"max_coupled_states={self.config.max_coupled_states} "
                f"({self.n_aircraft} aircraft, {self.n_radars} radars); use the separated "
                "filter for scenarios this large"
            )
        radar = int(obs.radar[i])
        block = slice(N_BIAS * radar, N_BIAS * (radar + 1))
        C = obs.C[i]
        P = np.zeros((n + 4, n + 4))
        P[:n, :n] = self._P
        cross = -C @ self._P[block, :]
        P[n : n + 2, :n] = cross
        P[:n, n : n + 2] = cross.T
        P[n : n + 2, n : n + 2] = C @ self._P[block, block] @ C.T + obs.R[i]
        P[n + 2 : n + 4, n + 2 : n + 4] = np.eye(2) * self.config.coupled_velocity_sigma**2
        position = obs.y[i] - C @ self._x[block]
        self._x = np.concatenate([self._x, position, obs.reference_v[i]])
        self._P = P
        self._slot[group] = n
        self._reindex()

    def _drop_silent(self, now: float) -> None:
        silent = [g for g, t in self._last.items() if now - t > self.config.coupled_timeout_s]
        if not silent:
            return
        gone = np.concatenate([np.arange(self._slot[g], self._slot[g] + 4) for g in silent])
        self._x = np.delete(self._x, gone)
        self._P = np.delete(np.delete(self._P, gone, axis=0), gone, axis=1)
        for g in silent:
            del self._last[g]
        order = sorted(self._slot, key=self._slot.__getitem__)
        kept = [g for g in order if g not in silent]
        self._slot = {g: self._n_bias + 4 * k for k, g in enumerate(kept)}
        self._reindex()

    def _reindex(self) -> None:
        slots: IntArray = np.array(sorted(self._slot.values()), dtype=np.int64)
        self._position = (slots[:, None] + np.arange(2)).reshape(-1)
