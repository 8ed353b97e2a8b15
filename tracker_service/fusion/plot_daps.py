"""Mode S DAPs in the fuser's plot filter (``estimator_plots``), the local tracker's
model (``tracking.daps``) with the radars' residual biases considered.

After a round's position updates (compiled or numpy: this step is numpy for both, so the
two stay the same to rounding), each system track whose plot carries a BDS 5,0 velocity
takes it as a second measurement of every model, H = [0 I2], with the local tracker's
noise (``DapUpdate.velocity_covariance``: speed, track angle, the register's age) and
gate (chi-square ``dap_velocity_gate`` on the combined state, bias share included), and
its reported turn rate weighs the model probabilities (``tracking.daps.turn_evidence``:
after the position update here, the same posterior as before it, since the fuser gates
local tracks, not plots).

The velocity is over the ground, free of the radars' range, azimuth and time biases, so
in the consider form (``consider.py``) its sensitivity to radar l's bias is that of the
state's velocity alone, G_l = H M_l:

    S = H P H^T + R + sum_l G_l B_l G_l^T,   X = P H^T + sum_l M_l B_l G_l^T,
    K = X S^-1,  x += K y,  P = Joseph(P, K, R; H),  M_l -= K G_l.

This is what lets a system track fed by a radar whose position plots carry a bias use the
velocity without drawing the bias into it: the velocity pulls the state's velocity, not
its position's bias share.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.fusion import consider
from tracker_service.fusion.state import FusionState
from tracker_service.tracking import imm
from tracker_service.tracking.daps import DapUpdate, aged_velocity, turn_evidence
from tracker_service.tracking.plots import DAP_TURN_RATE, DAP_VELOCITY, FloatArray, PlotArrays

VELOCITY_ROWS = slice(2, 4)


def apply(state: FusionState, daps: DapUpdate, numbers: npt.NDArray[Any], p: PlotArrays) -> None:
    """The DAPs of plots ``p`` into the system tracks ``numbers`` (one plot each, the
    round's position updates already made), in the table; counted in ``daps.counts``
    (the fuser's stats)."""
    flags = p.rows["dap_flags"]
    has_v = np.flatnonzero((flags & DAP_VELOCITY) != 0)
    has_w = np.flatnonzero((flags & DAP_TURN_RATE) != 0)
    if has_v.size == 0 and has_w.size == 0:
        return
    sys = state.sys
    touched = np.union1d(has_v, has_w)
    n = numbers[touched]
    x, P, M, mu = sys["mx"][n], sys["mP"][n], sys["mM"][n], sys["mu"][n]
    B = sys["B"][n]
    rows = np.flatnonzero(np.isin(touched, has_v))
    if rows.size:
        plot_rows = touched[rows]
        z = aged_velocity(p, plot_rows, daps.noise.latency_s)
        r = daps.velocity_covariance(p, plot_rows)
        ok = _in_gate(x[rows], P[rows], M[rows], mu[rows], B[rows], z, r, daps.noise.velocity_gate)
        daps.counts.dap_velocity_gated_out += int(np.count_nonzero(~ok))
        rows, z, r = rows[ok], z[ok], r[ok]
    if rows.size:
        x[rows], P[rows], M[rows], mu[rows] = velocity_update(
            x[rows], P[rows], M[rows], mu[rows], B[rows], z, r
        )
        daps.counts.dap_velocity_updates += int(rows.size)
    w_rows = np.flatnonzero(np.isin(touched, has_w))
    if w_rows.size:
        mu[w_rows] = turn_evidence(
            mu[w_rows],
            p.rows["dap_turn_rate_rad_s"][touched[w_rows]],
            daps.turn_rates,
            daps.noise.turn_rate_sigma_rad_s,
        )
        daps.counts.dap_turn_evidence += int(w_rows.size)
    xc, pc = imm.combine(x, P, mu)
    sys["mx"][n], sys["mP"][n], sys["mM"][n], sys["mu"][n] = x, P, M, mu
    sys["x"][n], sys["P"][n] = xc, pc
    sys["M"][n] = consider.combine(M, mu)


def _in_gate(
    x: FloatArray,
    P: FloatArray,
    M: FloatArray,
    mu: FloatArray,
    B: FloatArray,
    z: FloatArray,
    R: FloatArray,
    gate: float,
) -> npt.NDArray[np.bool_]:
    """Whether each velocity is within ``gate`` (chi-square, 2 dof) of its track's
    combined velocity, the residual biases' share of its covariance included: beyond, it
    is another aircraft's register (a shared address) or a fault, not a measurement."""
    xc, pc = imm.combine(x, P, mu)
    pc = pc + consider.bias_share(consider.combine(M, mu), B)
    y = z - xc[:, VELOCITY_ROWS]
    s_inv, _ = imm.inv2(pc[:, VELOCITY_ROWS, VELOCITY_ROWS] + R)
    return np.asarray(np.einsum("ka,kab,kb->k", y, s_inv, y) <= gate)


def velocity_update(
    x: FloatArray,
    P: FloatArray,
    M: FloatArray,
    mu: FloatArray,
    B: FloatArray,
    z: FloatArray,
    R: FloatArray,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Every model (x (k, m, 4), P, sensitivities M (k, m, radars, 4, 2)) updated with a
    bias-free velocity z (k, 2), R (k, 2, 2), the residual biases B (k, radars, 2, 2)
    considered (module docstring); the model probabilities times each model's likelihood."""
    g = M[..., VELOCITY_ROWS, :]  # (k, m, radars, 2, 2)
    bg = B[:, None] @ np.swapaxes(g, -1, -2)
    s = P[..., VELOCITY_ROWS, VELOCITY_ROWS] + R[:, None] + (g @ bg).sum(axis=2)
    cross = P[..., :, VELOCITY_ROWS] + (M @ bg).sum(axis=2)
    s_inv, det = imm.inv2(s)
    k_gain = cross @ s_inv
    y = z[:, None, :] - x[..., VELOCITY_ROWS]
    x_new = x + np.einsum("kmab,kmb->kma", k_gain, y)
    ikh = np.broadcast_to(np.eye(4), P.shape).copy()
    ikh[..., :, VELOCITY_ROWS] -= k_gain
    kr = k_gain @ R[:, None] @ np.swapaxes(k_gain, -1, -2)
    p_new = ikh @ P @ np.swapaxes(ikh, -1, -2) + kr
    p_new = 0.5 * (p_new + np.swapaxes(p_new, -1, -2))
    m_new = M - k_gain[:, :, None] @ g
    return x_new, p_new, m_new, imm.model_probabilities(mu, y, s_inv, det)
