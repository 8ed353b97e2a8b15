"""A rotating radar station: when it sees each aircraft, what it measures, what it sends.

For every scan the beam sweeps 360 degrees; an aircraft is detected when the beam
crosses its azimuth (found by fixed-point iteration, since the aircraft moves while the
beam turns), and the plot carries that time plus the radar's time bias. Plots are
grouped per sector and sent when the beam leaves the sector, with CAT034 north markers
and sector crossings, as a real station does. Geometry comes from the simulator's own
``geometry`` module (pyproj), never from the tracker's conversions.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix import encode_block, encode_record
from asterix.bds import encode_bds40, encode_bds50, encode_bds60
from tracker_service.simulator import geometry
from tracker_service.simulator.cat001 import cat001_plot
from tracker_service.simulator.scenario import (
    NM,
    FieldMonitor,
    FixedTransponder,
    Radar,
    Scenario,
    SystematicErrors,
    TestTarget,
    Wandering,
)
from tracker_service.simulator.trajectories import Truth

FloatArray = npt.NDArray[Any]  # float64 arrays; numpy arithmetic widens the static type

MAX_DATAGRAM = 1472  # an Ethernet MTU less the IPv4 and UDP headers
PROCESSING_DELAY_S = 0.06  # from the end of a sector to the datagram leaving the station
FT = 0.3048
KT = 1852.0 / 3600.0
CLUTTER_PD = 0.9
ICAO_G = 9.80665
NEAR_COVERAGE_M = 20_000.0
"""An aircraft whose range at every scan's middle is this far beyond the radar's maximum
cannot be in coverage at a crossing (half a period from a middle: a few km at 1,200 kt)."""


@dataclass
class Plot:
    """One CAT048 record to send and what it really is."""

    detection_time: float  # scenario seconds, true
    sector: int  # absolute sector count since the scenario start
    record: dict[str, Any]
    origin: dict[str, Any]


@dataclass
class Emission:
    """A datagram leaving a station: reception time, payload, what its CAT048 records are."""

    time: float  # scenario seconds at reception
    payload: bytes
    origins: list[dict[str, Any]] = field(default_factory=list)


def wandering_series(
    error: Wandering, times: FloatArray, rng: np.random.Generator, scale: float = 1.0
) -> FloatArray:
    """A constant plus a random walk sampled at ``times`` (std grows as sqrt of hours)."""
    values = np.full(len(times), error.value * scale)
    if error.wander_per_sqrt_h > 0 and len(times) > 1:
        steps = np.sqrt(np.diff(times, prepend=times[0]) / 3600.0)
        values += np.cumsum(rng.normal(0.0, error.wander_per_sqrt_h * scale, len(times)) * steps)
    return values


@dataclass(frozen=True)
class BiasSeries:
    """A radar's systematic errors per scan (index = scan number)."""

    range_offset_m: FloatArray
    range_gain: FloatArray  # dimensionless g: rho_m = (1 + g) rho + offset
    azimuth_deg: FloatArray
    time_s: FloatArray

    @staticmethod
    def draw(
        errors: SystematicErrors, scan_times: FloatArray, rng: np.random.Generator, off: bool
    ) -> BiasSeries:
        if off:
            zero = np.zeros(len(scan_times))
            return BiasSeries(zero, zero, zero, zero)
        drift = errors.time_drift_s_per_h * scan_times / 3600.0
        return BiasSeries(
            wandering_series(errors.range_offset_m, scan_times, rng),
            wandering_series(errors.range_gain_m_per_nm, scan_times, rng, 1.0 / NM),
            wandering_series(errors.azimuth_offset_deg, scan_times, rng),
            wandering_series(errors.time_offset_s, scan_times, rng) + drift,
        )


class RadarModel:
    def __init__(
        self,
        radar: Radar,
        scenario: Scenario,
        truth: Truth,
        duration_s: float,
        rng: np.random.Generator,
        no_bias: bool,
    ) -> None:
        self.radar = radar
        self.scenario = scenario
        self.truth = truth
        self.rng = rng
        self.site = geometry.RadarSite(radar.lat, radar.lon, radar.alt_m)
        self.period = radar.antenna_period_s
        self.direction = 1.0 if radar.rotation == "clockwise" else -1.0
        self.scans = math.ceil(duration_s / self.period)
        self.duration = duration_s
        scan_times = np.arange(self.scans) * self.period
        self.bias = BiasSeries.draw(radar.bias, scan_times, rng, no_bias)
        self.psr_bias = (
            self.bias
            if radar.psr_bias is None
            else BiasSeries.draw(radar.psr_bias, scan_times, rng, no_bias)
        )
        self.start_tod = (
            scenario.start.hour * 3600
            + scenario.start.minute * 60
            + scenario.start.second
            + scenario.start.microsecond / 1e6
        )
        self.reflector_azimuths = rng.uniform(0.0, 360.0, 2)
        self.coverage: list[list[int]] = [[] for _ in range(self.scans)]

    # --- the beam -------------------------------------------------------------------------
    # The beam's azimuth is az0 + direction * 360 t / P. Sectors are fixed in azimuth,
    # 360/S wide and counted from north, so the north marker goes out when the beam really
    # crosses north whatever az0 is.

    @property
    def sector_s(self) -> float:
        return self.period / self.radar.sectors

    @property
    def first_north_s(self) -> float:
        """When the beam first points north."""
        turned = (self.direction * -self.radar.initial_azimuth_deg) % 360.0
        return turned / 360.0 * self.period

    def sector_of(self, t: FloatArray) -> npt.NDArray[np.int64]:
        """Sectors counted from the first north crossing (the one before it is -1)."""
        return np.floor((np.asarray(t) - self.first_north_s) / self.sector_s).astype(np.int64)

    def crossing_time(self, azimuth_deg: float, scan: int) -> float:
        """When the beam points at a fixed azimuth during a scan."""
        return (scan + float(self._phase(np.asarray(azimuth_deg))) % 1.0) * self.period

    def _phase(self, azimuth: FloatArray) -> FloatArray:
        """Turns of the beam from its start to ``azimuth`` (not wrapped: continuous)."""
        return np.asarray(self.direction * (azimuth - self.radar.initial_azimuth_deg) / 360.0)

    # --- detection geometry ---------------------------------------------------------------

    def _measure(
        self, aircraft: npt.NDArray[np.int64], t: FloatArray, horizon: bool = True
    ) -> dict[str, FloatArray]:
        """Geometry and state at ``t``; the radar horizon (costly: a geodesic per point)
        only with ``horizon``, else ``visible`` is all true."""
        state = self.truth.state_at(aircraft, t)
        h_ellipsoid = state.h_msl + geometry.geoid_undulation_m(state.lat, state.lon)
        x, y, z = geometry.geodetic_to_ecef(state.lat, state.lon, h_ellipsoid)
        rho, azimuth, elevation = geometry.measure(self.site, x, y, z)
        visible = (
            geometry.line_of_sight(self.site, x, y, z)
            if horizon
            else np.ones(np.shape(rho), dtype=np.bool_)
        )
        return {
            "rho": rho,
            "azimuth": azimuth,
            "elevation": elevation,
            "visible": visible,
            "h_msl": state.h_msl,
            "lat": state.lat,
            "lon": state.lon,
            "heading": state.heading_deg,
            "speed": state.ground_speed_mps,
            "roll": state.roll_deg,
            "turn_rate": state.turn_rate_deg_s,
            "vel_up": state.vel_up,
        }

    def detections(self) -> tuple[npt.NDArray[np.int64], FloatArray, dict[str, FloatArray]]:
        """(aircraft, detection time, measurements) of every beam crossing in coverage.

        The beam meets an aircraft whenever the continuous phase between them is a whole
        turn: t = P (m + phase(t)). The aircraft's azimuth is unwrapped along its whole
        flight, so each crossing is found exactly once even when the aircraft sits near the
        azimuth where scans start, or passes near the radar.
        """
        period = self.period
        mids = (np.arange(self.scans + 1) + 0.5) * period
        # Only aircraft alive in the run and near the coverage at some scan's middle.
        candidates = np.flatnonzero(self.truth.t0 <= self.duration)
        when = np.tile(mids, candidates.size)
        seen = self._measure(
            np.repeat(candidates, len(mids)), np.minimum(when, self.duration), horizon=False
        )
        rho_at_mid = np.nan_to_num(seen["rho"], nan=np.inf).reshape(-1, len(mids))
        near = rho_at_mid.min(axis=1, initial=np.inf) <= self.radar.max_range_nm * NM + (
            NEAR_COVERAGE_M
        )
        candidates = candidates[near]
        n = candidates.size
        azimuth = np.asarray(seen["azimuth"]).reshape(-1, len(mids))[near]
        # Unwrap through gaps (not alive): a lifetime is one stretch, so the gaps are at its
        # ends, filled with the nearest known azimuth (forward, then backward).
        known = np.isfinite(azimuth)
        columns = np.arange(len(mids))
        last_known = np.maximum.accumulate(np.where(known, columns, -1), axis=1)
        next_known = np.minimum.accumulate(np.where(known, columns, len(mids))[:, ::-1], axis=1)[
            :, ::-1
        ]
        nearest = np.where(last_known >= 0, last_known, np.minimum(next_known, len(mids) - 1))
        filled = np.take_along_axis(azimuth, nearest, axis=1)
        unwrapped = np.unwrap(filled, period=360.0, axis=1)
        phase_at_mid = self._phase(unwrapped)
        # Crossing numbers m with t = P (m + phase) inside the run, per aircraft.
        # (Rows never alive at a middle stay NaN and get no crossing: counts below.)
        highest = np.nan_to_num(phase_at_mid.max(axis=1, initial=0.0))
        lowest = np.nan_to_num(phase_at_mid.min(axis=1, initial=0.0))
        m_lo = np.floor(-highest - 1).astype(np.int64)
        m_hi = np.ceil(self.scans - lowest + 1).astype(np.int64)
        counts = np.where(np.isfinite(phase_at_mid).all(axis=1), m_hi - m_lo + 1, 0)
        ac = np.repeat(np.arange(n), counts)  # rows of ``candidates`` until the end
        m = (
            np.concatenate([np.arange(lo, lo + c) for lo, c in zip(m_lo, counts, strict=True)])
            if len(ac)
            else np.zeros(0, dtype=np.int64)
        )
        # Start from the phase at the nearest scan mid, then iterate on the true azimuth.
        guess = np.clip(m, 0, self.scans)
        phase = phase_at_mid[ac, guess]
        t = period * (m + phase)
        for _ in range(4):
            k = np.clip(np.round(t / period - 0.5).astype(np.int64), 0, self.scans)
            reference = unwrapped[ac, k]
            az = self._measure(candidates[ac], np.clip(t, 0.0, self.duration), horizon=False)[
                "azimuth"
            ]
            continuous = reference + (np.nan_to_num(az - reference) + 180.0) % 360.0 - 180.0
            t = period * (m + self._phase(continuous))
        inside = (t >= 0.0) & (t < self.duration)
        ac, t = candidates[ac[inside]], t[inside]
        alive = self.truth.alive(ac, t)
        ac, t = ac[alive], t[alive]
        measured = self._measure(ac, t)
        r = self.radar
        covered = (
            np.isfinite(measured["rho"])
            & (measured["rho"] >= r.min_range_nm * NM)
            & (measured["rho"] <= r.max_range_nm * NM)
            & (measured["elevation"] <= r.cone_of_silence_deg)
            & measured["visible"]
            & self._detectable(ac, measured["rho"])
        )
        scan = (t // period).astype(np.int64)
        for a, k in zip(ac[covered], scan[covered], strict=True):
            self.coverage[int(k)].append(int(a))
        detected = {key: v[covered] for key, v in measured.items()}
        # Mode C is pressure altitude: computed once for every detection, not per plot.
        atmosphere = self.scenario.atmosphere
        detected["fl"] = (
            geometry.pressure_altitude_ft(
                detected["h_msl"], atmosphere.qnh_hpa, atmosphere.temperature_offset_k
            )
            / 100.0
        )
        return ac[covered], t[covered], detected

    def _detectable(self, aircraft: npt.NDArray[np.int64], rho_m: FloatArray) -> npt.NDArray[Any]:
        """Whether the radar can see each aircraft at all: a transponder it interrogates, or
        a primary radar within its range. Coverage (and so the probability of update the
        evaluation measures) counts only these."""
        r = self.radar
        kinds = np.array([self.truth.identities[int(a)].transponder for a in aircraft])
        secondary = (r.ssr or r.mode_s) & (kinds != "none")
        primary = r.psr & (np.nan_to_num(rho_m, nan=np.inf) <= r.psr_max_range_nm * NM)
        return np.asarray(secondary | primary)

    # --- plots ----------------------------------------------------------------------------

    def plots(self) -> list[Plot]:
        aircraft, t, m = self.detections()
        rng, r = self.rng, self.radar
        kinds = [self.truth.identities[int(a)].transponder for a in aircraft]
        scan = np.minimum((t // self.period).astype(np.int64), self.scans - 1)
        u_ssr = rng.random(len(t))
        u_psr = rng.random(len(t))
        in_psr_range = m["rho"] <= r.psr_max_range_nm * NM
        out: list[Plot] = []
        for i, a in enumerate(aircraft):
            kind = kinds[i]
            if kind == "mode_s" and r.mode_s:
                ssr = u_ssr[i] < r.pd_mode_s
            elif kind in ("mode_s", "mode_ac") and (r.ssr or r.mode_s):
                ssr = u_ssr[i] < r.pd_ssr
            else:
                ssr = False
            psr = r.psr and bool(in_psr_range[i]) and u_psr[i] < r.pd_psr
            if not (ssr or psr):
                continue
            mode_s = ssr and kind == "mode_s" and r.mode_s
            typ = (5 if mode_s else 2) + (2 if mode_s and psr else 1 if psr else 0) if ssr else 1
            plot = self._plot(int(a), float(t[i]), int(scan[i]), m, i, typ, ssr, mode_s)
            out.append(plot)
            out.extend(self._pathologies(plot, int(a), ssr))
        if self.radar.field_monitor is not None:
            out.extend(self._fixed_plots(self.radar.field_monitor))
        for transponder in self.radar.fixed_transponders:
            out.extend(self._fixed_plots(transponder))
        for target in self.radar.test_targets:
            out.extend(self._test_target_plots(target))
        out.extend(self._clutter_plots())
        out.sort(key=lambda p: p.detection_time)
        return out

    def _errors(self, psr_only: bool) -> tuple[BiasSeries, float, float]:
        r = self.radar
        if psr_only:
            return (
                self.psr_bias,
                r.psr_sigma_range_m if r.psr_sigma_range_m is not None else r.sigma_range_m,
                r.psr_sigma_azimuth_deg
                if r.psr_sigma_azimuth_deg is not None
                else r.sigma_azimuth_deg,
            )
        return self.bias, r.sigma_range_m, r.sigma_azimuth_deg

    def _position_items(
        self, rho_m: float, azimuth_deg: float, t: float, scan: int, psr_only: bool
    ) -> tuple[dict[str, Any], bool]:
        """I010, I140, I040 (and RE beyond 256 NM) of a plot measured with errors."""
        bias, sigma_r, sigma_az = self._errors(psr_only)
        rho = (1.0 + bias.range_gain[scan]) * rho_m + bias.range_offset_m[scan]
        rho += self.rng.normal(0.0, sigma_r)
        theta = (azimuth_deg + bias.azimuth_deg[scan] + self.rng.normal(0.0, sigma_az)) % 360.0
        items: dict[str, Any] = {
            "010": {"SAC": self.radar.sac, "SIC": self.radar.sic},
            # One clock stamps every plot of the station, PSR or SSR.
            "140": self.time_of_day(t + self.bias.time_s[scan]),
        }
        return items, _set_polar(items, max(rho / NM, 0.0), theta)

    def time_of_day(self, t: float) -> float:
        return wrapped_time_of_day(self.start_tod + t)

    def _plot(
        self,
        a: int,
        t: float,
        scan: int,
        m: dict[str, FloatArray],
        i: int,
        typ: int,
        ssr: bool,
        mode_s: bool,
    ) -> Plot:
        identity = self.truth.identities[a]
        record, extended = self._position_items(
            float(m["rho"][i]), float(m["azimuth"][i]), t, scan, psr_only=not ssr
        )
        record["020"] = {"TYP": typ, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0}
        if extended:
            record["020"].update(TST=0, ERR=1)
        true_fl = float(m["fl"][i])
        if ssr:
            code = self.truth.mode3a_at(a, t)
            if code is not None:
                record["070"] = {"V": 0, "G": 0, "L": 0, "MODE3A": code}
            step = 0.25 if mode_s else 1.0  # Mode S reports 25 ft, Mode C 100 ft
            record["090"] = {"V": 0, "G": 0, "FL": _quantise(true_fl, step)}
        if mode_s:
            assert identity.address is not None
            record["220"] = identity.address
            if identity.callsign:
                record["240"] = identity.callsign.ljust(8)
            record["250"] = self._bds(scan, a, t, m, i, true_fl)
            record["230"] = {
                "COM": 1,
                "STAT": 0,
                "SI": 0,
                "MSSC": 1,
                "ARC": 1,
                "AIC": 1,
                "B1A": 1,
                "B1B": 5,
            }
        if self.rng.random() < self.radar.pathologies.missing_time:
            del record["140"]
        return Plot(
            t,
            int(self.sector_of(np.array([t]))[0]),
            record,
            {
                "kind": "aircraft",
                "aircraft": a,
                "true_range_m": float(m["rho"][i]),
                "true_azimuth_deg": float(m["azimuth"][i]),
                "true_fl": true_fl,
                "psr_only": not ssr,
            },
        )

    def _bds(
        self, scan: int, a: int, t: float, m: dict[str, FloatArray], i: int, fl: float
    ) -> list[dict[str, Any]]:
        """The Comm-B registers of one plot: one per plot in turn, as a radar's GICB
        extraction schedule, or BDS 4,0, 5,0 and 6,0 every scan (``ehs_registers``). With
        ``dap_max_age_s`` their contents are the aircraft's of a moment up to that long
        before the detection, as transponders refresh their registers."""
        age = self.radar.dap_max_age_s
        state = None
        if age > 0.0:
            state = self.truth.state_at(np.array([a]), np.array([t - self.rng.uniform(0, age)]))
            if not np.isfinite(state.roll_deg[0]):  # before the aircraft's first state
                state = None
        if state is not None:
            v = {
                "heading": float(state.heading_deg[0]),
                "speed": float(state.ground_speed_mps[0]),
                "roll": float(state.roll_deg[0]),
                "turn_rate": float(state.turn_rate_deg_s[0]),
                "vel_up": float(state.vel_up[0]),
                "h_msl": float(state.h_msl[0]),
            }
        else:
            v = {k: float(m[k][i]) for k in ("heading", "speed", "roll", "turn_rate", "vel_up")}
            v["h_msl"] = float(m["h_msl"][i])
        registers = (0, 1, 2) if self.radar.ehs_registers == "every_scan" else (scan % 3,)
        return [_register(r, v, fl, self.scenario.atmosphere.qnh_hpa) for r in registers]

    def _pathologies(self, plot: Plot, a: int, ssr: bool) -> list[Plot]:
        rng, p = self.rng, self.radar.pathologies
        extra: list[Plot] = []
        record = plot.record
        if ssr and "090" in record:
            if rng.random() < p.missing_mode_c:
                del record["090"]
            elif rng.random() < p.garbled_mode_c:
                # A garbled reply flips code bits: the level jumps by hundreds of feet.
                jump = float(rng.choice([-80.0, -40.0, -20.0, -10.0, 10.0, 20.0, 40.0, 80.0]))
                record["090"] = {"V": 1, "G": 1, "FL": record["090"]["FL"] + jump}
        if ssr and "070" in record:
            if rng.random() < p.missing_mode_3a:
                del record["070"]
            elif rng.random() < p.garbled_mode_3a:
                record["070"] = {
                    "V": 1,
                    "G": 1,
                    "L": 0,
                    "MODE3A": f"{int(rng.integers(0, 4096)):04o}",
                }
        # Beyond 256 NM the range is in the RE field, I040 holds its maximum.
        rho = record["RE"]["ERR"] if "RE" in record else record["040"]["RHO"]
        theta = record["040"]["THETA"]
        if ssr and rng.random() < p.reflection:
            reflector = float(rng.choice(self.reflector_azimuths))
            ghost = {k: v for k, v in record.items() if k not in ("040", "RE")}
            ghost["020"] = dict(record["020"])
            _set_polar(ghost, rho + float(rng.uniform(0.5, 3.0)), 2 * reflector - theta)
            extra.append(
                Plot(plot.detection_time, plot.sector, ghost, {**plot.origin, "kind": "reflection"})
            )
        if rng.random() < p.split:
            split: dict[str, Any] = {k: record[k] for k in ("010", "140") if k in record}
            split["020"] = {"TYP": 1, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0}
            offset = float(rng.choice([-1.0, 1.0]) * rng.uniform(0.4, 1.2))
            _set_polar(split, rho, theta + offset)
            extra.append(
                Plot(
                    plot.detection_time,
                    plot.sector,
                    split,
                    {**plot.origin, "kind": "split", "psr_only": True},
                )
            )
        return extra

    def _fixed_plots(self, monitor: FieldMonitor) -> list[Plot]:
        """A stationary transponder's plots: the field monitor (RAB = 1) or a fixed
        transponder, measured with the radar's errors like any SSR plot."""
        rab = monitor.rab if isinstance(monitor, FixedTransponder) else True
        n = geometry.geoid_undulation_m(monitor.lat, monitor.lon)
        x, y, z = geometry.geodetic_to_ecef(monitor.lat, monitor.lon, monitor.alt_m + n)
        rho, azimuth, _ = geometry.measure(self.site, x, y, z)
        rho_m, az = float(rho), float(azimuth)
        fl = (
            float(
                geometry.pressure_altitude_ft(
                    monitor.alt_m,
                    self.scenario.atmosphere.qnh_hpa,
                    self.scenario.atmosphere.temperature_offset_k,
                )
            )
            / 100.0
        )
        if isinstance(monitor, FixedTransponder) and monitor.reported_fl is not None:
            fl = monitor.reported_fl
        pd = self.radar.pd_mode_s if monitor.address else self.radar.pd_ssr
        out = []
        for scan in range(self.scans):
            t = self.crossing_time(az, scan)
            if t >= self.duration or self.rng.random() >= pd:
                continue
            record, _ = self._position_items(rho_m, az, t, scan, psr_only=False)
            record["020"] = {
                "TYP": 5 if monitor.address else 2,
                "SIM": 0,
                "RDP": 0,
                "SPI": 0,
                "RAB": int(rab),
            }
            record["070"] = {"V": 0, "G": 0, "L": 0, "MODE3A": monitor.mode3a}
            record["090"] = {"V": 0, "G": 0, "FL": _quantise(fl, 0.25)}
            if monitor.address:
                record["220"] = monitor.address
            out.append(
                Plot(
                    t,
                    int(self.sector_of(np.array([t]))[0]),
                    record,
                    {
                        "kind": "field_monitor",
                        "aircraft": None,
                        "true_range_m": rho_m,
                        "true_azimuth_deg": az,
                        "true_fl": fl,
                    },
                )
            )
        return out

    def _test_target_plots(self, target: TestTarget) -> list[Plot]:
        """A test target injected at the radar's processor: at its exact range and azimuth
        (no measurement error), each scan when the beam passes its azimuth."""
        out = []
        flag = {"TST": 1, "ERR": 0} if target.flag == "tst" else {}
        for scan in range(self.scans):
            t = self.crossing_time(target.azimuth_deg, scan)
            if t >= self.duration:
                continue
            record: dict[str, Any] = {
                "010": {"SAC": self.radar.sac, "SIC": self.radar.sic},
                "140": self.time_of_day(t + self.bias.time_s[scan]),
            }
            _set_polar(record, target.range_nm, target.azimuth_deg)
            record["020"] = {
                "TYP": 1 if target.mode3a is None else 2,
                "SIM": int(target.flag == "sim"),
                "RDP": 0,
                "SPI": 0,
                "RAB": 0,
                **flag,
            }
            if target.mode3a is not None:
                record["070"] = {"V": 0, "G": 0, "L": 0, "MODE3A": target.mode3a}
                if target.fl is not None:
                    record["090"] = {"V": 0, "G": 0, "FL": _quantise(target.fl, 1.0)}
            origin = {
                "kind": "field_monitor",
                "aircraft": None,
                "true_range_m": target.range_nm * NM,
                "true_azimuth_deg": target.azimuth_deg,
                "true_fl": target.fl,
                "psr_only": target.mode3a is None,
            }
            out.append(Plot(t, int(self.sector_of(np.array([t]))[0]), record, origin))
        return out

    def _clutter_plots(self) -> list[Plot]:
        clutter, r, rng = self.radar.clutter, self.radar, self.rng
        if not r.psr or (clutter.persistent_per_scan == 0 and clutter.random_per_scan == 0):
            return []
        max_range = min(r.psr_max_range_nm, r.max_range_nm) * NM
        min_range = r.min_range_nm * NM
        fixed_rho = rng.uniform(min_range, min(max_range, 30 * NM), clutter.persistent_per_scan)
        fixed_az = rng.uniform(0.0, 360.0, clutter.persistent_per_scan)
        out = []
        for scan in range(self.scans):
            count = int(rng.poisson(clutter.random_per_scan))
            rho = np.concatenate([fixed_rho, rng.uniform(min_range, max_range, count)])
            az = np.concatenate([fixed_az, rng.uniform(0.0, 360.0, count)])
            seen = np.concatenate([rng.random(len(fixed_rho)) < CLUTTER_PD, np.ones(count, bool)])
            for rho_m, azimuth in zip(rho[seen], az[seen], strict=True):
                t = self.crossing_time(float(azimuth), scan)
                if t >= self.duration:
                    continue
                record, _ = self._position_items(float(rho_m), float(azimuth), t, scan, True)
                record["020"] = {"TYP": 1, "SIM": 0, "RDP": 0, "SPI": 0, "RAB": 0}
                out.append(
                    Plot(
                        t,
                        int(self.sector_of(np.array([t]))[0]),
                        record,
                        {
                            "kind": "clutter",
                            "aircraft": None,
                            "true_range_m": float(rho_m),
                            "true_azimuth_deg": float(azimuth),
                            "true_fl": None,
                            "psr_only": True,
                        },
                    )
                )
        return out

    # --- datagrams ------------------------------------------------------------------------

    def emissions(self, plots: list[Plot]) -> list[Emission]:
        """CAT048 plots per sector and CAT034 service messages, as datagrams.

        A sector's plots leave when the beam leaves the sector, followed by the service
        message of the boundary just crossed: a north marker at north, else a sector
        crossing.
        """
        by_sector: dict[int, list[Plot]] = {}
        for plot in plots:
            by_sector.setdefault(plot.sector, []).append(plot)
        out: list[Emission] = []
        sector = int(self.sector_of(np.array(0.0)))
        while True:
            end = self.first_north_s + (sector + 1) * self.sector_s
            sent = end + PROCESSING_DELAY_S + float(self.rng.uniform(0.0, 0.02))
            if sent >= self.duration:
                return out
            out.extend(self._plot_datagrams(by_sector.get(sector, []), sent))
            out.append(Emission(sent + 0.001, self._service_message(sector + 1, end)))
            sector += 1

    def _plot_datagrams(self, plots: list[Plot], sent: float) -> list[Emission]:
        origins = [p.origin | {"detection_time": p.detection_time} for p in plots]
        if self.radar.asterix == "cat001":
            records = [encode_record(1, cat001_plot(p.record)) for p in plots]
            return pack_datagrams(1, list(zip(records, origins, strict=True)), sent)
        records = [encode_record(48, p.record) for p in plots]
        return pack_datagrams(48, list(zip(records, origins, strict=True)), sent)

    def _service_message(self, boundary: int, t: float) -> bytes:
        """The message of the beam crossing sector boundary ``boundary`` (0 = north) at t,
        stamped by the station's clock, like I140."""
        r = self.radar
        index = boundary % r.sectors
        record: dict[str, Any] = {
            "010": {"SAC": r.sac, "SIC": r.sic},
            "000": 1 if index == 0 else 2,
            "030": self.time_of_day(t + self.bias.time_s[self.scan_of(t)]),
        }
        if index == 0:
            record["041"] = _quantise(self.period, 1 / 128)
        else:
            record["020"] = wrapped_angle(self.direction * index * 360.0 / r.sectors, 360 / 256)
        # CAT002 names its items as CAT034 does (I000, I010, I020, I030, I041).
        return encode_block(2 if r.asterix == "cat001" else 34, [record])

    def scan_of(self, t: float) -> int:
        return min(max(int(t // self.period), 0), self.scans - 1)


def _set_polar(record: dict[str, Any], rho_nm: float, theta_deg: float) -> bool:
    """I040, and beyond 256 NM the RE field's range with I020 ERR set (REF 1.13); returns
    whether the range is extended."""
    record["040"] = {
        "RHO": min(_quantise(rho_nm, 1 / 256), 65535 / 256),
        "THETA": wrapped_angle(theta_deg, 360 / 65536),
    }
    record.pop("RE", None)
    extended = rho_nm >= 256.0
    if extended:
        record["RE"] = {"ERR": _quantise(rho_nm, 1 / 256)}
    if "020" in record:
        if extended:
            record["020"].update(TST=0, ERR=1)
        else:
            record["020"].pop("ERR", None)
    return extended


def pack_datagrams(
    cat: int, records: list[tuple[bytes, dict[str, Any]]], sent: float
) -> list[Emission]:
    """Encoded records as one data block per datagram, each under the UDP payload limit."""
    out: list[Emission] = []
    chunk: list[bytes] = []
    origins: list[dict[str, Any]] = []
    size = 3
    for encoded, origin in records:
        if chunk and size + len(encoded) > MAX_DATAGRAM:
            out.append(Emission(sent, _block(cat, chunk), origins))
            chunk, origins, size = [], [], 3
        chunk.append(encoded)
        origins.append(origin)
        size += len(encoded)
    if chunk:
        out.append(Emission(sent, _block(cat, chunk), origins))
    return out


def _block(cat: int, records: list[bytes]) -> bytes:
    body = b"".join(records)
    return bytes([cat]) + (len(body) + 3).to_bytes(2) + body


def _quantise(value: float, lsb: float) -> float:
    return round(value / lsb) * lsb


def wrapped_angle(angle_deg: float, lsb: float) -> float:
    """An angle on its LSB grid in [0, 360): 359.999 must not round up to 360."""
    return _quantise(angle_deg % 360.0, lsb) % 360.0


def wrapped_time_of_day(seconds: float) -> float:
    """Time of day on the 1/128 s grid, wrapping at midnight as I140 does."""
    return _quantise(seconds % 86400.0, 1 / 128) % 86400.0


def _isa_temperature_k(h_m: float) -> float:
    return 288.15 - 0.0065 * min(h_m, 11000.0)


def _register(register: int, v: dict[str, float], fl: float, qnh_hpa: float) -> dict[str, Any]:
    """One I048/250 repetition: BDS 4,0 (register 0), 5,0 (1) or 6,0 (2) of the aircraft
    state ``v`` (heading, speed, roll, turn_rate, vel_up, h_msl) at flight level ``fl``."""
    speed_kt = v["speed"] / KT
    heading = v["heading"]
    if register == 0:
        mb = encode_bds40(
            selected_altitude_mcp_ft=round(fl) * 100, baro_pressure_setting_mb=qnh_hpa
        )
    elif register == 1:
        mb = encode_bds50(
            roll_deg=v["roll"],
            track_angle_deg=heading,
            ground_speed_kt=min(speed_kt, 2046.0),
            track_angle_rate_deg_s=v["turn_rate"],
            true_airspeed_kt=min(speed_kt, 2046.0),
        )
    else:
        climb = v["vel_up"] / FT * 60.0
        mb = encode_bds60(
            magnetic_heading_deg=heading,
            indicated_airspeed_kt=min(_ias_kt(speed_kt, v["h_msl"]), 1023.0),
            mach=min(_mach(speed_kt, v["h_msl"]), 4.0),
            baro_vertical_rate_ft_min=climb,
            inertial_vertical_rate_ft_min=climb,
        )
    return {"MBDATA": f"{mb:014X}", "BDS1": 4 + register, "BDS2": 0}


def _mach(speed_kt: float, h_m: float) -> float:
    # No wind in the simulation: true airspeed is the ground speed.
    return speed_kt * KT / math.sqrt(1.4 * 287.053 * _isa_temperature_k(h_m))


def _ias_kt(speed_kt: float, h_m: float) -> float:
    # Equivalent airspeed from the density ratio; compressibility is below a few knots here.
    t = _isa_temperature_k(h_m)
    p_ratio = (
        (t / 288.15) ** 5.2559 if h_m <= 11000 else 0.22336 * math.exp(-(h_m - 11000.0) / 6341.6)
    )
    sigma = p_ratio * 288.15 / t
    return speed_kt * math.sqrt(sigma)
