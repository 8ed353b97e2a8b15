"""ADS-B ground stations: CAT021 reports of equipped aircraft (a surveillance source and a
reference for biases); an aircraft's ``adsb_offset_nm`` spoofs its positions.

ADS-B positions come from the aircraft's GNSS, so they carry no radar bias; their noise
follows the navigation accuracy category (NACp: the 95 % horizontal error bound) and
they reach the ground after a latency. Time of applicability is exact (GNSS time).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from asterix import encode_record
from tracker_service.adsb import NACP_EPU_M, SIGMA_PER_EPU
from tracker_service.simulator import geometry
from tracker_service.simulator.radar import (
    FT,
    Emission,
    pack_datagrams,
    wrapped_angle,
    wrapped_time_of_day,
)
from tracker_service.simulator.scenario import NM, AdsbStation, Scenario
from tracker_service.simulator.trajectories import Truth

EARTH_M_PER_DEG = 111_320.0


def adsb_emissions(
    station: AdsbStation,
    scenario: Scenario,
    truth: Truth,
    duration_s: float,
    start_tod: float,
    rng: np.random.Generator,
) -> list[Emission]:
    site = geometry.RadarSite(station.lat, station.lon, station.alt_m)
    equipped = np.array(
        [i for i, ident in enumerate(truth.identities) if ident.adsb], dtype=np.int64
    )
    times = np.arange(0.0, duration_s, station.report_interval_s)
    out: list[Emission] = []
    if len(equipped) == 0:
        return out
    for t in times:
        # Aircraft report at their own pace: spread them over the interval.
        when = t + rng.uniform(0.0, station.report_interval_s, len(equipped))
        alive = truth.alive(equipped, when) & (when < duration_s)
        aircraft, when = equipped[alive], when[alive]
        if len(aircraft) == 0:
            continue
        state = truth.state_at(aircraft, when)
        h_ell = state.h_msl + geometry.geoid_undulation_m(state.lat, state.lon)
        x, y, z = geometry.geodetic_to_ecef(state.lat, state.lon, h_ell)
        rho, _, _ = geometry.measure(site, x, y, z)
        seen = (rho <= station.range_nm * NM) & geometry.line_of_sight(site, x, y, z)
        records: list[tuple[bytes, dict[str, Any]]] = []
        for j in np.flatnonzero(seen):
            a = int(aircraft[j])
            identity = truth.identities[a]
            sigma = NACP_EPU_M[identity.nacp] * SIGMA_PER_EPU
            east, north = identity.adsb_offset_m
            lat = float(state.lat[j]) + (north + rng.normal(0.0, sigma)) / EARTH_M_PER_DEG
            lon = float(state.lon[j]) + (east + rng.normal(0.0, sigma)) / (
                EARTH_M_PER_DEG * np.cos(np.radians(float(state.lat[j])))
            )
            applicable = wrapped_time_of_day(start_tod + float(when[j]))
            received = wrapped_time_of_day(start_tod + float(when[j]) + station.latency_s)
            pressure_ft = float(
                geometry.pressure_altitude_ft(
                    float(state.h_msl[j]),
                    scenario.atmosphere.qnh_hpa,
                    scenario.atmosphere.temperature_offset_k,
                )
            )
            item = {
                "010": {"SAC": station.sac, "SIC": station.sic},
                "040": {"ATP": 1, "ARC": 1, "RC": 0, "RAB": 0},
                "161": {"TRNUM": a % 4096},
                "015": 1,
                "071": applicable,
                "131": {"LAT": lat, "LON": lon},
                "073": received,
                "080": identity.address,
                "090": {"NUCRNACV": 2, "NUCPNIC": 8, "NICBARO": 1, "SIL": 3, "NACP": identity.nacp},
                "210": {"VNS": 0, "VN": 2, "LTT": 2},
                "140": float(h_ell[j]) / FT,
                "145": pressure_ft / 100.0,
                "160": {
                    "RE": 0,
                    "GS": float(state.ground_speed_mps[j]) / NM,
                    "TA": wrapped_angle(float(state.heading_deg[j]), 360 / 65536),
                },
            }
            if identity.callsign:
                item["170"] = identity.callsign.ljust(8)
            origin = {
                "kind": "adsb",
                "aircraft": a,
                "detection_time": float(when[j]),
                "true_range_m": None,
                "true_azimuth_deg": None,
                "true_fl": None,
            }
            records.append((encode_record(21, item), origin))
        out.extend(pack_datagrams(21, records, t + station.report_interval_s + station.latency_s))
    return out
