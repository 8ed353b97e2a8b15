"""A simulation run: truth, every radar and ADS-B station, then the output in time order."""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from tracker_service.simulator import geometry
from tracker_service.simulator.adsb import adsb_emissions
from tracker_service.simulator.radar import Emission, RadarModel
from tracker_service.simulator.recording import RecordingWriter, open_writer
from tracker_service.simulator.scenario import Output, Scenario
from tracker_service.simulator.trajectories import Truth, build_truth

LAN_B_DELAY_S = 0.0003  # the second LAN's copy arrives a fraction of a millisecond later
# Kinds of output events; at equal times they are written in this order.
_LAN_A, _SCAN, _TRUTH, _LAN_B = range(4)


@dataclass
class SimulationSummary:
    aircraft: int
    datagrams: int
    plots: dict[str, int]
    seconds: float


@dataclass
class _Source:
    key: str
    src: tuple[str, int]
    output: Output
    dual_lan: bool
    emissions: list[Emission]


def _streams(seed: int, count: int) -> list[np.random.Generator]:
    """Independent random streams: adding a radar does not change the others' noise."""
    return [np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(count)]


def metadata(scenario: Scenario, seed: int, duration_s: float, no_bias: bool) -> dict[str, Any]:
    return {
        "scenario": scenario.model_dump(mode="json"),
        "seed": seed,
        "duration_s": duration_s,
        "no_bias": no_bias,
        "start_posix": scenario.start.timestamp(),
        "radars": {r.key: r.model_dump(mode="json") for r in scenario.radars},
        "adsb_stations": {s.key: s.model_dump(mode="json") for s in scenario.adsb_stations},
    }


def simulate(
    scenario: Scenario,
    out: str | Path,
    seed: int | None = None,
    duration_s: float | None = None,
    no_bias: bool = False,
) -> SimulationSummary:
    started = time.perf_counter()
    seed = scenario.seed if seed is None else seed
    duration = scenario.duration_s if duration_s is None else duration_s
    n_streams = 1 + len(scenario.radars) + len(scenario.adsb_stations)
    rngs = _streams(seed, n_streams)
    truth = build_truth(scenario, rngs[0], duration)
    start_tod = (
        scenario.start - scenario.start.replace(hour=0, minute=0, second=0, microsecond=0)
    ).total_seconds()
    sources: list[_Source] = []
    models: list[RadarModel] = []
    plot_counts: dict[str, int] = {}
    for radar, rng in zip(scenario.radars, rngs[1:], strict=False):
        model = RadarModel(radar, scenario, truth, duration, rng, no_bias)
        plots = model.plots()
        plot_counts[radar.key] = len(plots)
        models.append(model)
        sources.append(
            _Source(
                radar.key,
                (f"10.{radar.sac}.{radar.sic}.1", 30000 + radar.sic),
                radar.output,
                radar.dual_lan,
                model.emissions(plots),
            )
        )
    for station, rng in zip(scenario.adsb_stations, rngs[1 + len(scenario.radars) :], strict=True):
        key = station.key
        emissions = adsb_emissions(station, scenario, truth, duration, start_tod, rng)
        plot_counts[key] = sum(len(e.origins) for e in emissions)
        sources.append(
            _Source(
                key,
                (f"10.{station.sac}.{station.sic}.2", 30000 + station.sic),
                station.output,
                False,
                emissions,
            )
        )
    writer = open_writer(out, metadata(scenario, seed, duration, no_bias))
    try:
        datagrams = _write(writer, scenario, truth, models, sources, duration)
    finally:
        writer.close()
    return SimulationSummary(
        len(truth.identities), datagrams, plot_counts, time.perf_counter() - started
    )


def _write(
    writer: RecordingWriter,
    scenario: Scenario,
    truth: Truth,
    models: list[RadarModel],
    sources: list[_Source],
    duration: float,
) -> int:
    """Every output event, merged in time order (ties keep a fixed order: same bytes)."""
    epoch = scenario.start.timestamp()
    events: list[tuple[float, int, int, int]] = []  # (time, kind, source, index)
    for s, source in enumerate(sources):
        events += [(e.time, _LAN_A, s, i) for i, e in enumerate(source.emissions)]
        if source.dual_lan:
            events += [
                (e.time + LAN_B_DELAY_S, _LAN_B, s, i) for i, e in enumerate(source.emissions)
            ]
    for m, model in enumerate(models):
        events += [(k * model.period, _SCAN, m, k) for k in range(model.scans)]
    truth_step = 1.0 / scenario.truth_rate_hz
    events += [(k * truth_step, _TRUTH, 0, k) for k in range(math.ceil(duration / truth_step))]
    events.sort()
    sequence = [0] * len(sources)
    written = 0
    for t, kind, s, i in events:
        if kind in (_LAN_A, _LAN_B):
            source = sources[s]
            emission = source.emissions[i]
            if kind == _LAN_B:
                lan_b = (source.output.second_lan_group or source.output.group, source.output.port)
                writer.datagram(source.key, epoch + t, emission.payload, "B", source.src, lan_b)
                written += 1
                continue
            lan_a = (source.output.group, source.output.port)
            writer.datagram(source.key, epoch + t, emission.payload, "A", source.src, lan_a)
            if emission.origins:
                records = [
                    o | {"detection_time": epoch + o["detection_time"]} for o in emission.origins
                ]
                writer.plot_origins(source.key, epoch + t, sequence[s], records)
            sequence[s] += 1
            written += 1
        elif kind == _SCAN:
            model = models[s]
            key = model.radar.key
            writer.biases(key, epoch + t, _bias_values(model, i))
            writer.coverage(key, epoch + t, i, model.coverage[i])
        else:
            writer.truth(epoch + t, _truth_snapshot(truth, t, scenario))
    return written


def _bias_values(model: RadarModel, scan: int) -> dict[str, float]:
    b, p = model.bias, model.psr_bias
    return {
        "range_offset_m": float(b.range_offset_m[scan]),
        "range_gain": float(b.range_gain[scan]),
        "azimuth_deg": float(b.azimuth_deg[scan]),
        "time_s": float(b.time_s[scan]),
        "psr_range_offset_m": float(p.range_offset_m[scan]),
        "psr_range_gain": float(p.range_gain[scan]),
        "psr_azimuth_deg": float(p.azimuth_deg[scan]),
    }


def _truth_snapshot(truth: Truth, t: float, scenario: Scenario) -> list[dict[str, Any]]:
    aircraft = np.arange(len(truth.identities))
    when = np.full(len(aircraft), t)
    alive = truth.alive(aircraft, when)
    aircraft = aircraft[alive]
    state = truth.state_at(aircraft, when[alive])
    atmosphere = scenario.atmosphere
    fl = (
        geometry.pressure_altitude_ft(
            state.h_msl, atmosphere.qnh_hpa, atmosphere.temperature_offset_k
        )
        / 100.0
    )
    out = []
    for j, a in enumerate(aircraft):
        identity = truth.identities[int(a)]
        out.append(
            {
                "index": int(a),
                "address": identity.address,
                "callsign": identity.callsign or None,
                "mode3a": truth.mode3a_at(int(a), t),
                "lat": float(state.lat[j]),
                "lon": float(state.lon[j]),
                "h_msl_m": float(state.h_msl[j]),
                "fl": float(fl[j]),
                "vel_east_mps": float(state.vel_east[j]),
                "vel_north_mps": float(state.vel_north[j]),
                "vel_up_mps": float(state.vel_up[j]),
                "heading_deg": float(state.heading_deg[j]),
                "ground_speed_mps": float(state.ground_speed_mps[j]),
            }
        )
    return out
