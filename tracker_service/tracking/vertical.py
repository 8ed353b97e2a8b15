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
    fine = (typ >= MODE_S_TYP_MIN) | (np.abs(flight_level - np.round(flight_level)) > 1e-6)
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
    pp = np.empty((fl.shape[0], 2, 2))  # filled in place: cheaper than nested np.stack
    pp[:, 0, 0] = p00
    pp[:, 0, 1] = pp[:, 1, 0] = p01
    pp[:, 1, 1] = p11
    return fl_p, rate.copy(), pp


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
    ikh = np.zeros(P.shape)
    ikh[:, 0, 0] = ikh[:, 1, 1] = 1.0
    ikh[:, :, 0] -= k
    p_new = ikh @ P @ np.swapaxes(ikh, 1, 2) + r[:, None, None] * k[:, :, None] * k[:, None, :]
    return fl + k[:, 0] * y, rate + k[:, 1] * y, p_new, y * y / s <= gate
