"""Variant 2, the "macro" s filter: the joint bias of all L radars (4L), one plot at a time.

The system track's prediction is a fusion of the contributing radars' bias-corrected plots,
so its error holds -F_x^-1 F_s (s - s_hat): H = -(F_x^T F_x)^-1 F_x^T F_s P_s (with F_x
square and invertible, -F_x^-1 F_s P_s) approximates C_x P_xs and couples the radars:
G_s = P_s C_s^T + H^T, S = P_x + C_s P_s C_s^T + H C_s^T + C_s H^T + R, residual
y - prediction_xy - C_s s. Blom's C_x P_x C_x^T is the prediction's covariance with the
bias share E P_s E^T (E = F_x^-1 F_s) in it; the x filter ignores bias uncertainty, so
prediction_P lacks it and it is added here (without it S can turn indefinite while P_s is
still large, and the filter diverged in the tests). Fixed references (field monitor,
ADS-B) have no contributors: H = 0 and the residual is taken against reference_xy with reference_P.
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
from tracker_service.bias.observations import (
    BiasObservations,
    ObservationKind,
    masked_information,
)
from tracker_service.tracking.plots import FloatArray


def prediction_sensitivity(obs: BiasObservations) -> FloatArray:
    """E = F_x^-1 F_s (N, 2, 4L): how the fused prediction moves with the radars' biases."""
    weight = masked_information(obs.contributor_R, obs.contributors)
    f_x = weight.sum(axis=1)
    has = obs.contributors.any(axis=1)
    f_x[~has] = np.eye(2)
    f_s = weight @ obs.contributor_C
    e = np.linalg.solve(f_x[:, None], f_s)
    return e.transpose(0, 2, 1, 3).reshape(len(obs), 2, obs.n_radars * N_BIAS)


class MacroBiasFilter(BiasFilterBase):
    def __init__(self, config: BiasConfig, n_radars: int) -> None:
        super().__init__(config, n_radars)
        self._s, self._P = self.prior()
        self._time = np.nan

    def bias_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_blocks(self._s, self._P, self.n_radars)

    def clock_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_clock_blocks(self, self._s, self._P)

    def _process(self, obs: BiasObservations) -> None:
        free = self.joint_free()
        nb = N_BIAS * self.n_radars
        if not free.any():
            return
        traffic = (obs.kind == ObservationKind.AIRCRAFT)[:, None]
        e = np.where(traffic[..., None], prediction_sensitivity(obs), 0.0)
        target = np.where(traffic, obs.prediction_xy, obs.reference_xy)
        target_p = np.where(traffic[..., None], obs.prediction_P, obs.reference_P)
        nu_base = obs.y - target
        accepted = np.zeros(len(obs), dtype=bool)
        s, P = self._s, self._P
        for i in range(len(obs)):
            t = float(obs.time[i])
            if np.isfinite(self._time):
                self.predict_joint(s, P, t - self._time)
            self._time = t
            block = slice(N_BIAS * obs.radar[i], N_BIAS * (obs.radar[i] + 1))
            C = obs.C[i]
            H = -e[i] @ P[:nb]
            G = P[:, block] @ C.T + H.T
            HC = H[:, block] @ C.T
            S = target_p[i] - H[:, :nb] @ e[i].T + C @ P[block, block] @ C.T + HC + HC.T + obs.R[i]
            nu = nu_base[i] - C @ s[block]
            accepted[i] = split_update(s, P, G, S, nu, free, self.config.outlier_gate)
        self.count(obs.radar, accepted)
