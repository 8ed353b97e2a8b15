"""The Cramer-Rao bound on each radar's clock drift in a scenario (issue 14, docs/fusion.md
"Clock drift").

Two sources of clock information, from the simulator's own geometry and noise models (not
the tracker's), for each radar and seed:

- **ADS-B against the radar's plots.** A plot stamped t + b(t), b = b0 + d (t - t0), sits
  where the aircraft was at t; the ADS-B reference moved to the stamp along its velocity
  says where it was at t + b: the residual in (range, azimuth) is -zdot b, zdot the true
  range and azimuth rates. The Fisher information of (range offset, range gain, azimuth
  offset, b0, d) sums J^T R^-1 J over every detection of an ADS-B aircraft (the plot noise
  plus the reference's NACp noise in R); the drift's bound is the (d, d) element of its
  inverse. Radar detections are counted with Pd = 1 (an upper bound on the information).
- **The radar's own clock against reception.** Every CAT034 message carries the station's
  time of the beam crossing its sector boundary (I030) and leaves a fixed processing
  delay later with a jitter (the simulator: uniform over 20 ms); reception - I030 =
  delay - b(t): a line in t with an unknown intercept (the delay) and slope -d. The bound
  on d from n messages of jitter sigma_j over the run is sigma_j / sqrt(sum (t - mean)^2).

    .venv/bin/python benchmarks/clock_bound.py config/scenarios/clock_drift.toml --seeds 1 2 3 4 5
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from tracker_service.adsb import NACP_EPU_M, SIGMA_PER_EPU
from tracker_service.simulator import geometry
from tracker_service.simulator.radar import RadarModel
from tracker_service.simulator.run import _streams
from tracker_service.simulator.scenario import NM, Scenario, load_scenario
from tracker_service.simulator.trajectories import build_truth

SERVICE_JITTER_S = 0.02 / math.sqrt(12.0)
"""The simulator's CAT034 send jitter (uniform over 20 ms, simulator/radar.py emissions)."""
RATE_STEP_S = 0.5


def polar_rates(model: RadarModel, aircraft: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(n, 2) true d(slant range)/dt (m/s) and d(azimuth)/dt (rad/s), central differences."""
    ahead = model._measure(aircraft, t + RATE_STEP_S, horizon=False)
    behind = model._measure(aircraft, t - RATE_STEP_S, horizon=False)
    range_rate = (ahead["rho"] - behind["rho"]) / (2 * RATE_STEP_S)
    turn = (ahead["azimuth"] - behind["azimuth"] + 180.0) % 360.0 - 180.0
    return np.column_stack([range_rate, np.radians(turn) / (2 * RATE_STEP_S)])


def adsb_bound(model: RadarModel, scenario: Scenario, duration: float) -> dict[str, float]:
    """Drift bound (s/h) from ADS-B-referenced plots, with the other biases estimated
    jointly and with them known; the number of plots used."""
    aircraft, t, m = model.detections()
    identities = model.truth.identities
    equipped = np.array([identities[int(a)].adsb for a in aircraft], dtype=bool)
    covered = np.zeros_like(equipped)
    for station in scenario.adsb_stations:
        site = geometry.RadarSite(station.lat, station.lon, station.alt_m)
        state = model.truth.state_at(aircraft, t)
        x, y, z = geometry.geodetic_to_ecef(
            state.lat, state.lon, state.h_msl + geometry.geoid_undulation_m(state.lat, state.lon)
        )
        rho, _, _ = geometry.measure(site, x, y, z)
        covered |= (rho <= station.range_nm * NM) & geometry.line_of_sight(site, x, y, z)
    use = equipped & covered & np.isfinite(m["rho"])
    aircraft, t = aircraft[use], t[use]
    rho = m["rho"][use]
    elevation = np.radians(m["elevation"][use])
    rates = polar_rates(model, aircraft, t)
    ok = np.isfinite(rates).all(axis=1)
    aircraft, t, rho, elevation, rates = aircraft[ok], t[ok], rho[ok], elevation[ok], rates[ok]
    sigma_ref = np.array([NACP_EPU_M[identities[int(a)].nacp] * SIGMA_PER_EPU for a in aircraft])
    ground = rho * np.cos(elevation)
    r = model.radar
    var_range = r.sigma_range_m**2 + (sigma_ref * np.cos(elevation)) ** 2
    var_azimuth = math.radians(r.sigma_azimuth_deg) ** 2 + (sigma_ref / ground) ** 2
    tau = t - duration / 2.0
    # Jacobian rows per plot: range row, azimuth row, over (b_r, g, b_theta, b0, d).
    n = len(t)
    jac = np.zeros((n, 2, 5))
    jac[:, 0, 0] = 1.0
    jac[:, 0, 1] = rho
    jac[:, 1, 2] = 1.0
    jac[:, :, 3] = -rates
    jac[:, :, 4] = -rates * tau[:, None]
    weights = np.stack([1.0 / var_range, 1.0 / var_azimuth], axis=1)
    info = np.einsum("nki,nk,nkj->ij", jac, weights, jac)
    joint = math.sqrt(np.linalg.inv(info)[4, 4]) * 3600.0
    clock_only = math.sqrt(np.linalg.inv(info[3:, 3:])[1, 1]) * 3600.0
    along = np.hypot(rates[:, 0], rates[:, 1] * ground)
    per_plot = np.sqrt(
        1.0 / np.maximum(rates[:, 0] ** 2 / var_range + rates[:, 1] ** 2 / var_azimuth, 1e-30)
    )
    return {
        "plots": float(n),
        "aircraft": float(len(set(aircraft.tolist()))),
        "speed_mps": float(np.median(along)),
        "per_plot_offset_s": float(np.median(per_plot)),
        "drift_sigma_s_per_h": joint,
        "drift_sigma_clock_only_s_per_h": clock_only,
    }


def reception_bound(model: RadarModel, duration: float) -> dict[str, float]:
    """Drift bound (s/h) from the station's CAT034 time stamps against reception."""
    n = int(duration / model.sector_s)
    t = np.arange(n) * model.sector_s
    spread = float(np.sum((t - t.mean()) ** 2))
    sigma = SERVICE_JITTER_S / math.sqrt(spread) * 3600.0
    return {"messages": float(n), "drift_sigma_s_per_h": sigma}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenario", type=Path)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--duration", type=float, default=None)
    args = parser.parse_args()
    scenario = load_scenario(args.scenario)
    duration = scenario.duration_s if args.duration is None else args.duration
    print(
        "seed radar truth_s/h | adsb: aircraft plots speed_m/s offset_per_plot_s "
        "sigma_d_joint sigma_d_clock_only (s/h, % of truth) | reception: messages sigma_d"
    )
    for seed in args.seeds:
        rngs = _streams(seed, 1 + len(scenario.radars) + len(scenario.adsb_stations))
        truth = build_truth(scenario, rngs[0], duration)
        for radar, rng in zip(scenario.radars, rngs[1:], strict=False):
            model = RadarModel(radar, scenario, truth, duration, rng, no_bias=False)
            drift = radar.bias.time_drift_s_per_h
            a = adsb_bound(model, scenario, duration)
            rec = reception_bound(model, duration)
            share = 100.0 * a["drift_sigma_s_per_h"] / abs(drift) if drift else math.inf
            print(
                f"{seed} {radar.key} {drift:+.2f} | {a['aircraft']:.0f} {a['plots']:.0f} "
                f"{a['speed_mps']:.0f} {a['per_plot_offset_s']:.2f} "
                f"{a['drift_sigma_s_per_h']:.3f} ({share:.0f} %) "
                f"{a['drift_sigma_clock_only_s_per_h']:.3f} | {rec['messages']:.0f} "
                f"{rec['drift_sigma_s_per_h'] * 1000:.1f} ms/h"
            )


if __name__ == "__main__":
    main()
