"""Mode S downlinked aircraft parameters (DAPs) in the horizontal tracker.

Two steps, one on each side of the plot batch:

- ``plot_daps`` (radar stage, at conversion): the decoded registers of each plot
  (``asterix.daps`` columns) checked for plausibility (an implausible value is dropped,
  NaN, and its plot counted, never trusted), and BDS 5,0 turned into what the filter
  uses: the velocity over ground in the system plane (ground speed along the true track
  angle, true north turned into the plane's grid north by the grid convergence and scaled
  by the plane's scale factor: ``SystemPlane.jacobian``) and the turn rate in the plane's
  sense (counter-clockwise positive, as the IMM's turn models): the track angle rate where
  the aircraft reports it, else the coordinated-turn rate g tan(roll) / V.
- ``DapUpdate`` (local tracker): the turn rate as evidence for the turn models, model
  j's predicted probability times N(omega_dap; omega_j, sigma_omega^2), applied to the
  prediction of each (track, plot) pair *before* the gate (``turn_prior``), so that the
  gate, the assignment and the position update all see the turn the plot's register
  reports; then, after the position update, the velocity as a second, sequential
  measurement of every model (H = [0 I2], Joseph form), whose likelihoods update the
  model probabilities as the position's do. A roll or a track angle rate announces a turn
  one or two scans before the positions bend. (Applied after the position update, the
  evidence came too late for the gate: a track whose earlier registers said "straight"
  had its turn models near zero and its velocity pinned by the DAP velocity, and the
  first plot of a sharp turn, itself reporting 47 deg of roll, fell out of the gate of the
  straight prediction: the track was lost and a new one started two scans later, the
  extra local tracks on three_sites.)

The velocity's noise is honest about what the register is: ground speed to 2 kt steps
(and the aircraft's own error), the track angle to 0.18 deg, and its age: a register the
transponder updated up to ``dap_latency_s`` before the interrogation lags a turn by
omega * age across the track: the velocity is turned on by the reported turn over the
mean age (tau / 2) and the rest counted as noise (uniform age: (V omega tau)^2 / 12).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy.plane import SystemPlane
from tracker_service.tracking import imm
from tracker_service.tracking.config import KNOT_M_S, TrackerConfig
from tracker_service.tracking.models import ModelSet
from tracker_service.tracking.plots import (
    DAP_FIELDS,
    DAP_SELECTED_ALTITUDE,
    DAP_TURN_RATE,
    DAP_VELOCITY,
    DAP_VERTICAL_RATE,
    BoolArray,
    FloatArray,
    PlotArrays,
)

G0 = 9.80665
FT_MIN_M_S = 0.3048 / 60.0

_DERIVED = ("selected_altitude_ft", "dap_vx", "dap_vy", "dap_turn_rate_rad_s")
"""The DAP columns ``plot_daps`` makes (MCP else FMS altitude; the plane velocity and
turn rate); the others are copied from the decoded registers as they are."""
_COPIED = tuple(name for name in DAP_FIELDS if name not in _DERIVED)

# Plausible ranges of a civil aircraft's registers: beyond them the value is a wrong
# register (BDS1/BDS2 mislabelled), a corrupted reply or a faulty avionics source.
_LIMITS = {
    "roll_deg": 60.0,  # |roll|: airliners bank 25-30 deg; Doc 9871 allows +-90
    "ground_speed_kt": 700.0,
    "track_angle_rate_deg_s": 8.0,  # |rate|: a rate-one turn is 3 deg/s
    "indicated_airspeed_kt": 500.0,
    "mach": 1.2,
    "baro_rate_fpm": 8000.0,
    "inertial_rate_fpm": 8000.0,
    "selected_altitude_ft": 60000.0,
}
MAX_WIND_KT = 250.0
"""|ground speed - true airspeed| beyond this is no wind but a wrong value."""
MAX_RATE_ROLL_DISAGREEMENT_DEG_S = 2.0
"""A track angle rate and a roll angle of one register that disagree by more than this
(as a coordinated turn) say nothing reliable of the turn."""
MIN_TURN_SPEED_KT = 60.0
"""Below this the coordinated-turn rate from the roll is not used (g tan(roll) / V)."""


def plot_daps(
    raw: npt.NDArray[Any],
    plane: SystemPlane,
    lat_deg: FloatArray,
    lon_deg: FloatArray,
    height_m: FloatArray,
) -> tuple[dict[str, npt.NDArray[Any]], BoolArray]:
    """The DAP columns of one batch of plot rows (``asterix.plots`` rows with the
    ``asterix.daps`` columns), ``dap_flags`` among them, and per plot whether some DAP
    was implausible (dropped)."""
    n = len(raw)
    out = {name: np.array(raw[name], dtype=np.float64) for name in _COPIED}
    mcp = np.asarray(raw["selected_altitude_mcp_ft"], dtype=np.float64)
    out["selected_altitude_ft"] = np.where(
        np.isfinite(mcp), mcp, np.asarray(raw["selected_altitude_fms_ft"], dtype=np.float64)
    )
    implausible = np.zeros(n, dtype=bool)
    for name, limit in _LIMITS.items():
        bad = np.abs(out[name]) > limit
        if bad.any():
            out[name][bad] = np.nan
            implausible |= bad
    gs_kt = out["ground_speed_kt"]
    tas_kt = np.asarray(raw["true_airspeed_kt"], dtype=np.float64)
    windy = np.abs(gs_kt - tas_kt) > MAX_WIND_KT  # NaN compares false
    rate_rad, roll_rate = _turn_rates(out["track_angle_rate_deg_s"], out["roll_deg"], gs_kt)
    disagree = np.abs(rate_rad - roll_rate) > np.radians(MAX_RATE_ROLL_DISAGREEMENT_DEG_S)
    out["ground_speed_kt"][windy] = np.nan
    out["roll_deg"][disagree] = np.nan
    out["track_angle_rate_deg_s"][disagree] = np.nan
    implausible |= windy | disagree
    rate_rad, roll_rate = _turn_rates(out["track_angle_rate_deg_s"], out["roll_deg"], gs_kt)
    out["dap_turn_rate_rad_s"] = np.where(np.isfinite(rate_rad), rate_rad, roll_rate)
    speed = out["ground_speed_kt"] * KNOT_M_S
    gs_kt = out["ground_speed_kt"]
    vx = np.full(n, np.nan)
    vy = np.full(n, np.nan)
    track = out["true_track_deg"]
    has = np.flatnonzero(np.isfinite(gs_kt) & np.isfinite(track))
    if len(has):
        psi = np.radians(track[has])
        east, north = speed[has] * np.sin(psi), speed[has] * np.cos(psi)
        jac = plane.jacobian(lat_deg[has], lon_deg[has], height_m[has])[..., :2]
        vx[has] = jac[:, 0, 0] * east + jac[:, 0, 1] * north
        vy[has] = jac[:, 1, 0] * east + jac[:, 1, 1] * north
    out["dap_vx"], out["dap_vy"] = vx, vy
    flags = np.where(np.isfinite(vx), DAP_VELOCITY, 0)
    flags |= np.where(np.isfinite(out["dap_turn_rate_rad_s"]), DAP_TURN_RATE, 0)
    vertical_rate = np.isfinite(out["baro_rate_fpm"]) | np.isfinite(out["inertial_rate_fpm"])
    flags |= np.where(vertical_rate, DAP_VERTICAL_RATE, 0)
    flags |= np.where(np.isfinite(out["selected_altitude_ft"]), DAP_SELECTED_ALTITUDE, 0)
    out["dap_flags"] = flags.astype(np.uint8)
    return out, implausible


def _turn_rates(
    rate_deg_s: FloatArray, roll_deg: FloatArray, gs_kt: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The plane turn rates (rad/s, counter-clockwise) of a track angle rate and of a roll
    angle (coordinated turn). BDS 5,0 angles are clockwise: a right turn, right wing
    down, is positive."""
    speed = gs_kt * KNOT_M_S
    with np.errstate(divide="ignore", invalid="ignore"):
        roll_rate = np.where(
            gs_kt >= MIN_TURN_SPEED_KT, -G0 * np.tan(np.radians(roll_deg)) / speed, np.nan
        )
    return -np.radians(rate_deg_s), roll_rate


@dataclass(frozen=True)
class DapNoise:
    """The measurement noise of the DAPs (``TrackerConfig`` ``dap_*`` fields)."""

    speed_sigma_m_s: float
    track_sigma_rad: float
    latency_s: float
    turn_rate_sigma_rad_s: float
    velocity_gate: float

    @staticmethod
    def from_config(config: TrackerConfig) -> DapNoise:
        return DapNoise(
            speed_sigma_m_s=config.dap_speed_sigma_m_s,
            track_sigma_rad=float(np.radians(config.dap_track_sigma_deg)),
            latency_s=config.dap_latency_s,
            turn_rate_sigma_rad_s=float(np.radians(config.dap_turn_rate_sigma_deg_s)),
            velocity_gate=config.dap_velocity_gate,
        )


class DapCounts(Protocol):
    """Where the DAP step counts (``tracker.TrackerStats``)."""

    dap_velocity_updates: int
    dap_turn_evidence: int
    dap_velocity_gated_out: int
    """Velocities that disagreed with their track beyond ``dap_velocity_gate``: not used."""


@dataclass
class _Counts:
    dap_velocity_updates: int = 0
    dap_turn_evidence: int = 0
    dap_velocity_gated_out: int = 0


class DapUpdate:
    """The DAP step after the IMM's position update (module docstring)."""

    def __init__(
        self, config: TrackerConfig, models: ModelSet, counts: DapCounts | None = None
    ) -> None:
        self.noise = DapNoise.from_config(config)
        self.turn_rates = models.turn_rates_rad_s
        self.counts: DapCounts = _Counts() if counts is None else counts

    def velocity_covariance(self, p: PlotArrays, rows: npt.NDArray[np.intp]) -> FloatArray:
        """(k, 2, 2): along- and across-track variances turned onto the plane's axes."""
        noise = self.noise
        vx, vy = p.rows["dap_vx"][rows], p.rows["dap_vy"][rows]
        speed = np.hypot(vx, vy)
        omega = np.nan_to_num(p.rows["dap_turn_rate_rad_s"][rows])
        along = np.full(len(rows), noise.speed_sigma_m_s**2)
        # The age, uniform over [0, latency], less its mean (``apply`` turns the velocity
        # on by the mean): variance latency^2 / 12 of the turn's lag.
        lag = speed * omega * noise.latency_s
        across = (speed * noise.track_sigma_rad) ** 2 + lag**2 / 12.0
        ux = np.where(speed > 0, vx / np.maximum(speed, 1e-9), 1.0)
        uy = np.where(speed > 0, vy / np.maximum(speed, 1e-9), 0.0)
        r = np.empty((len(rows), 2, 2))
        r[:, 0, 0] = along * ux * ux + across * uy * uy
        r[:, 1, 1] = along * uy * uy + across * ux * ux
        r[:, 0, 1] = r[:, 1, 0] = (along - across) * ux * uy
        return r

    def turn_prior(
        self,
        pred: imm.ImmPrediction,
        nis: FloatArray,
        p: PlotArrays,
        plots: npt.NDArray[np.intp],
    ) -> tuple[imm.ImmPrediction, FloatArray]:
        """``pred`` (each pair's IMM prediction to the time of its plot ``plots``, indices
        into ``p``) with the predicted model probabilities times the likelihood of the
        plot's reported turn rate, and the NIS the gate compares with its threshold: the
        smaller of ``nis`` (the plain prediction's) and the weighed combination's. The
        register is the aircraft's at the plot's time, so it weighs the models of that
        time, before the positions do, and opens the gate to a turn it reports; it must
        not close the gate on "straight", which a register up to ``dap_latency_s`` old
        reports in the first second of a turn. The assignment keeps the plain test's
        cost, so that plots both tests take go where they went before."""
        rates = p.rows["dap_turn_rate_rad_s"][plots]
        has_w = np.flatnonzero((p.rows["dap_flags"][plots] & DAP_TURN_RATE) != 0)
        if has_w.size == 0:
            return pred, nis
        c = pred.c.copy()
        c[has_w] = turn_evidence(
            c[has_w], rates[has_w], self.turn_rates, self.noise.turn_rate_sigma_rad_s
        )
        self.counts.dap_turn_evidence += int(has_w.size)
        x_comb, p_comb = pred.x_comb.copy(), pred.P_comb.copy()
        x_comb[has_w], p_comb[has_w] = imm.combine(pred.x[has_w], pred.P[has_w], c[has_w])
        weighed = imm.ImmPrediction(pred.x, pred.P, c, x_comb, p_comb)
        z = np.column_stack([p.x[plots[has_w]], p.y[plots[has_w]]])
        nis_w, _ = imm.innovation_test(weighed.take(has_w), z, p.R[plots[has_w]])
        gate_nis = nis.copy()
        gate_nis[has_w] = np.minimum(nis[has_w], nis_w)
        return weighed, gate_nis

    def apply(self, step: imm.ImmUpdate, p: PlotArrays) -> imm.ImmUpdate:
        """``step`` (the IMM after the position update of tracks whose plots are ``p``,
        from predictions that ``turn_prior`` weighed) with each plot's DAP velocity
        applied; ``step`` itself when no plot has one."""
        x, P, mu = step.x, step.P, step.mu
        has_v = (p.rows["dap_flags"] & DAP_VELOCITY) != 0
        if not has_v.any():
            return step
        x, P, mu = x.copy(), P.copy(), mu.copy()
        rows = np.flatnonzero(has_v)
        if len(rows):
            z = aged_velocity(p, rows, self.noise.latency_s)
            r = self.velocity_covariance(p, rows)
            # Gate on the combined estimate: a velocity far from its track is another
            # aircraft's register (a shared address) or a fault, not a measurement. The
            # mixture the positions give, without the turn rate's weight (``turn_prior``):
            # concentrated on the reported turn's model, whose rate a register up to
            # 1.3 s old lags, it gated out good velocities in turns (turns seed 1:
            # across-track RMS in turns 31 -> 38 m).
            mu_gate = mu[rows]
            w = (p.rows["dap_flags"][rows] & DAP_TURN_RATE) != 0
            if w.any():
                mu_gate = mu_gate.copy()
                mu_gate[w] = turn_evidence(
                    mu_gate[w],
                    p.rows["dap_turn_rate_rad_s"][rows[w]],
                    self.turn_rates,
                    self.noise.turn_rate_sigma_rad_s,
                    inverse=True,
                )
            xc = np.einsum("km,kma->ka", mu_gate, x[rows])
            _, pc = imm.combine(x[rows], P[rows], mu_gate)
            y = z - xc[:, 2:]
            s_inv, _ = imm.inv2(pc[:, 2:, 2:] + r)
            nis = np.einsum("ka,kab,kb->k", y, s_inv, y)
            ok = nis <= self.noise.velocity_gate
            self.counts.dap_velocity_gated_out += int(np.count_nonzero(~ok))
            rows, z, r = rows[ok], z[ok], r[ok]
        if len(rows):
            xv, pv, muv = velocity_update(x[rows], P[rows], mu[rows], z, r)
            x[rows], P[rows], mu[rows] = xv, pv, muv
            self.counts.dap_velocity_updates += len(rows)
        xc, pc = imm.combine(x, P, mu)
        return imm.ImmUpdate(x, P, mu, xc, pc)


def aged_velocity(p: PlotArrays, rows: npt.NDArray[np.intp], latency_s: float) -> FloatArray:
    """(k, 2): the DAP velocities turned on by the reported turn over the register's mean
    age (half ``latency_s``): in a turn the register lags the aircraft by that much."""
    vx, vy = p.rows["dap_vx"][rows], p.rows["dap_vy"][rows]
    angle = np.nan_to_num(p.rows["dap_turn_rate_rad_s"][rows]) * (0.5 * latency_s)
    c, s = np.cos(angle), np.sin(angle)
    return np.column_stack([c * vx - s * vy, s * vx + c * vy])


def velocity_update(
    x: FloatArray, P: FloatArray, mu: FloatArray, z: FloatArray, R: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Every model updated with a velocity measurement z (k, 2), R (k, 2, 2): H = [0 I2],
    Joseph form, and the model probabilities times each model's likelihood of it."""
    y = z[:, None, :] - x[:, :, 2:]
    s = P[:, :, 2:, 2:] + R[:, None]
    s_inv, det = imm.inv2(s)
    k_gain = P[:, :, :, 2:] @ s_inv
    x_new = x + np.einsum("kmab,kmb->kma", k_gain, y)
    ikh = np.broadcast_to(np.eye(4), P.shape).copy()
    ikh[..., :, 2:] -= k_gain
    p_new = ikh @ P @ np.swapaxes(ikh, -1, -2) + k_gain @ R[:, None] @ np.swapaxes(k_gain, -1, -2)
    p_new = 0.5 * (p_new + np.swapaxes(p_new, -1, -2))
    return x_new, p_new, imm.model_probabilities(mu, y, s_inv, det)


def turn_evidence(
    mu: FloatArray,
    omega: FloatArray,
    turn_rates: FloatArray,
    sigma: float,
    *,
    inverse: bool = False,
) -> FloatArray:
    """Model probabilities (k, M) times the likelihood of a reported turn rate omega (k,)
    under each model's fixed rate, N(omega; omega_j, sigma^2), normalised; divided by it
    when ``inverse`` (the probabilities before that evidence)."""
    d = (omega[:, None] - turn_rates[None, :]) / sigma
    sign = -1.0 if inverse else 1.0
    log_post = np.log(np.maximum(mu, imm.TINY)) - sign * 0.5 * d * d
    log_post -= log_post.max(axis=1, keepdims=True)
    out = np.exp(log_post)
    out /= out.sum(axis=1, keepdims=True)
    return np.asarray(out)
