"""The vertical filter: flight level and climb rate, a 2-state CV filter per track on Mode C.

Kept apart from the horizontal IMM because Mode C is pressure altitude with its own
quantisation and its own failures (garbling), and a plot without a valid flight level
still updates the horizontal track.
"""

from __future__ import annotations

import numpy as np

from tracker_service.tracking.config import TrackerConfig
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

MODE_S_TYP_MIN = 4


def measurement_variance(
    flight_level: FloatArray, typ: IntArray, config: TrackerConfig
) -> FloatArray:
    """Uniform quantisation noise, step^2 / 12: 25 ft for Mode S or any level that is not a
    whole FL (it cannot come from 100 ft Gillham code), 100 ft otherwise."""
    mode_s = typ >= MODE_S_TYP_MIN
    if mode_s.all():  # the usual batch: no level to inspect
        return np.full(typ.shape, config.fl_step_mode_s * config.fl_step_mode_s / 12.0)
    fine = mode_s | (np.abs(flight_level - np.round(flight_level)) > 1e-6)
    step = np.where(fine, config.fl_step_mode_s, config.fl_step_mode_c)
    return np.asarray(step * step / 12.0, dtype=np.float64)


def predict(
    fl: FloatArray, rate: FloatArray, P: FloatArray, dt: FloatArray, q: float
) -> tuple[FloatArray, FloatArray, FloatArray]:
    t = np.abs(dt)
    fl_p = fl + rate * dt
    p00 = P[:, 0, 0] + 2.0 * dt * P[:, 0, 1] + dt * dt * P[:, 1, 1] + q * t**3 / 3.0
    p01 = P[:, 0, 1] + dt * P[:, 1, 1] + q * dt * t / 2.0
    p11 = P[:, 1, 1] + q * t
    # Filled in place through the flat view (cheaper than nested np.stack): the two
    # off-diagonal entries are one slice.
    pp = np.empty((fl.shape[0], 4))
    pp[:, 0] = p00
    pp[:, 1:3] = p01[:, None]
    pp[:, 3] = p11
    return fl_p, rate.copy(), pp.reshape(-1, 2, 2)


def update(
    fl: FloatArray,
    rate: FloatArray,
    P: FloatArray,
    z: FloatArray,
    r: FloatArray,
    gate: float,
) -> tuple[FloatArray, FloatArray, FloatArray, BoolArray]:
    """Scalar Joseph update of predicted states; also says which plots pass the gate."""
    y = z - fl
    s = P[:, 0, 0] + r
    k = P[:, :, 0] / s[:, None]
    # I - K H, written entry by entry: cheaper than copying a broadcast identity.
    flat = np.zeros((P.shape[0], 4))
    flat[:, ::3] = 1.0  # the diagonal of the flat 2x2
    ikh = flat.reshape(P.shape)
    ikh[:, :, 0] -= k
    p_new = ikh @ P @ np.swapaxes(ikh, 1, 2) + r[:, None, None] * k[:, :, None] * k[:, None, :]
    return fl + k[:, 0] * y, rate + k[:, 1] * y, p_new, y * y / s <= gate
