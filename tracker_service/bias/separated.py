"""Variant 3, the fully separated s filter: one small filter per radar, batched.

G_s = P_s C^T, S = C P_s C^T + R + reference_P, nu = y - reference_xy - C s. The
reference is a position this plot has not updated (other radars' bias-corrected tracks, a
field monitor, ADS-B); its covariance belongs in S. A batch of one radar is one update:
the noises are independent given s, so the stacked update reduces to the information
form (``information_update``), O(n) in the batch and vectorised.

Measured weakness: each radar's filter treats the other radars' estimates in its
references as independent noise, so without an absolute reference (ADS-B, field monitor)
its sigma is too small (errors of 3-10 sigma on traffic alone); the macro and coupled
filters stay honest there."""

from __future__ import annotations

import numpy as np

from tracker_service.bias.common import AIRCRAFT, BiasFilterBase, information_update
from tracker_service.bias.config import N_BIAS, TIME, BiasConfig
from tracker_service.bias.kernels import gate_statistics
from tracker_service.bias.observations import BiasObservations
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray


class SeparatedBiasFilter(BiasFilterBase):
    times_from_traffic = False
    """See ``free``: only ADS-B moves a separated filter's clock."""
    reads_contributors = False

    def __init__(self, config: BiasConfig, n_radars: int) -> None:
        super().__init__(config, n_radars)
        # Per radar its 4 biases, then its extra clock states (``bias.clock``).
        s, P = self.prior()
        nb, n = N_BIAS * n_radars, self.n_state
        extra = self.clock.n_extra
        self._s = np.zeros((n_radars, n))
        self._P = np.zeros((n_radars, n, n))
        self._s[:, :N_BIAS] = s[:nb].reshape(n_radars, N_BIAS)
        self._s[:, N_BIAS:] = s[nb:].reshape(n_radars, extra)
        variance = np.diag(P)
        self._P[:, np.arange(N_BIAS), np.arange(N_BIAS)] = variance[:nb].reshape(n_radars, N_BIAS)
        self._P[:, np.arange(N_BIAS, n), np.arange(N_BIAS, n)] = variance[nb:].reshape(
            n_radars, extra
        )
        self._time = np.full(n_radars, np.nan)
        self._offset, self._extra = self.clock.indices(1)
        self._observable: tuple[bytes, BoolArray, FloatArray] | None = None
        """``_free_and_walk``'s inputs and results (read-only)."""

    def bias_state(self) -> tuple[FloatArray, FloatArray]:
        return self._s[:, :N_BIAS], self._P[:, :N_BIAS, :N_BIAS]

    def clock_state(self) -> tuple[FloatArray, FloatArray]:
        return self._s[:, N_BIAS:], self._P[:, N_BIAS:, N_BIAS:]

    def free(self) -> BoolArray:
        """As the base, but a radar's time offset only once it has its own clock reference.

        Separate filters cannot represent that only relative time offsets are observable
        from traffic: each radar's filter, trusting the others' estimates, wanders with the
        unobservable common offset and drags azimuth along (measured: 7-25 sigma errors).
        So traffic never updates the time offset here; ADS-B (or the macro and coupled
        filters) does.
        """
        free = super().free()
        free[:, TIME] &= self._clock_seen
        return free

    def update_reception(self, radar: int, evidence: FloatArray) -> None:
        """See ``BiasFilterBase.update_reception``: each message in time order, once the
        radar's time offset is estimated (``free``)."""
        if not self.clock.reception or not len(evidence) or not self.free()[radar, TIME]:
            return
        delay = N_BIAS + self.clock.n_extra - 1
        walk = self.state_walk_rate()[radar]
        s, P = self._s[radar], self._P[radar]
        for stamp, received in evidence[np.argsort(evidence[:, 0])].tolist():
            if np.isfinite(self._time[radar]):
                dt = stamp - self._time[radar]
                P += np.diag(walk * abs(dt))
                self.clock.predict(s, P, dt, self._offset, self._extra, np.ones(1, dtype=bool))
            self._time[radar] = stamp
            used = self.clock.reception_update(s, P, TIME, delay, received - stamp)
            self.reception_used[radar] += used
            self.reception_rejected[radar] += not used

    def _process(self, obs: BiasObservations) -> None:
        free, walk = self._free_and_walk()
        first = int(obs.radar[0])
        if (obs.radar == first).all():  # one radar's batch (the central stage's)
            self._update_radar(first, obs, free[first], walk[first])
            return
        for radar in np.unique(obs.radar):
            r = int(radar)
            self._update_radar(r, obs.subset(obs.radar == radar), free[r], walk[r])

    def _free_and_walk(self) -> tuple[BoolArray, FloatArray]:
        """``state_free`` and ``state_walk_rate`` (a few dozen array operations, every
        batch), made again only when what the data have shown (``free``'s inputs: the
        radars seen in traffic, with an absolute reference, with a clock reference)
        changed, which after the first minutes it no longer does."""
        seen = self._traffic_seen.tobytes() + self._absolute_seen.tobytes()
        seen += self._clock_seen.tobytes()
        if self._observable is None or self._observable[0] != seen:
            free_now = self.free()
            free, walk = self.state_free(free_now), self.state_walk_rate(free_now)
            free.flags.writeable = walk.flags.writeable = False
            self._observable = (seen, free, walk)
        return self._observable[1], self._observable[2]

    def _update_radar(
        self, radar: int, obs: BiasObservations, free: BoolArray, walk: FloatArray
    ) -> None:
        end = float(obs.time[-1])
        if np.isfinite(self._time[radar]):
            dt = end - self._time[radar]
            self._P[radar] += np.diag(walk * abs(dt))
            s, P, moving = self._s[radar], self._P[radar], free[TIME : TIME + 1]
            self.clock.predict(s, P, dt, self._offset, self._extra, moving)
        self._time[radar] = end
        traffic = obs.kind == AIRCRAFT
        no_time = free.copy()
        no_time[TIME] = False
        no_time[N_BIAS:] = False
        for rows, mask in ((~traffic, free), (traffic, no_time)):
            if mask.any() and rows.any():
                self._batch(radar, obs, np.flatnonzero(rows), mask)

    def _batch(self, radar: int, obs: BiasObservations, rows: IntArray, free: BoolArray) -> None:
        """One update with the observations ``rows`` (the fields it reads gathered, not a
        ``subset`` of all fifteen)."""
        s, P = self._s[radar], self._P[radar]
        plot_c = obs.C[rows]
        # The extra clock states enter no plot: zero columns.
        C = np.concatenate([plot_c, np.zeros((rows.size, 2, self.clock.n_extra))], axis=2)
        nu = obs.y[rows] - obs.reference_xy[rows] - C @ s
        noise = obs.R[rows] + obs.reference_P[rows]
        accepted = gate_statistics(plot_c, P, noise, nu) <= self.config.outlier_gate
        # Every row is this radar's: its counts without a bincount.
        taken = int(np.count_nonzero(accepted))
        self.n_used[radar] += taken
        self.n_rejected[radar] += rows.size - taken
        if taken < rows.size:  # usually none is out: no copies
            C, noise, nu = C[accepted], noise[accepted], nu[accepted]
        weight = np.linalg.inv(noise)
        info = np.einsum("nki,nkl,nlj->ij", C, weight, C)
        score = np.einsum("nki,nkl,nl->i", C, weight, nu)
        information_update(s, P, info, score, free)


def gate_statistics_reference(
    C: FloatArray, P: FloatArray, noise: FloatArray, nu: FloatArray
) -> FloatArray:
    """``kernels.gate_statistics`` in numpy (what ``_batch`` computed before): nu^T S^-1 nu
    with S = noise + C P C^T, C (n, 2, k) against P's leading k x k block."""
    k = C.shape[2]
    S = noise + C @ P[:k, :k] @ C.mT
    statistics: FloatArray = np.einsum("ni,ni->n", nu, np.linalg.solve(S, nu[..., None])[..., 0])
    return statistics
