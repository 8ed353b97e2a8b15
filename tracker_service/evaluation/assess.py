"""``tracker-service assess``: judge the tracker on a recording without truth.

On opportunity traffic a surveillance engineer has no truth, only what the aircraft say
of themselves and what physics allows. The recording goes through the processing chain
(``tracker_service.chain``) as the daemon runs it: its datagrams in reception order,
the redundant LAN's copies dropped (``service.replay.open_replay``). The measures, per
radar's local tracks and for the system tracks:

- tracks per identity: per Mode S address and per discrete Mode 3/A code (``NON_DISCRETE``
  codes are shared by many aircraft and are left out); a track counts for an identity
  once ``MIN_IDENTITY_UPDATES`` of its plots carry it;
- track breaks while plots continue: an identity's plots fall into stretches with no gap
  a confirmed track would not survive (``delete_misses + miss_tolerance`` scans); within
  one stretch, a track that starts after the previous one's last update is a break, one
  that starts while it still updates an overlap (a split track, or a duplicated address);
- kinematics of the published (confirmed or coasting) tracks: ground speed and
  acceleration (velocity difference over at least ``MIN_ACCELERATION_DT_S``) percentiles
  and maxima; position jumps, the distance between an update and its predecessor
  extrapolated along its velocity (what the velocity does not explain), and the share
  beyond 1 NM;
- consistency: each plot's innovation against the constant-velocity prediction of its
  track's previous update, normalised by S = F P F' + Q + R (NIS, 2 dof; Q of the local
  tracks mixes the IMM's CV and turn intensities by the previous model probabilities,
  that of the system tracks is the fuser's ``q``): its mean (2 if consistent) and the
  share beyond the 99 % gate (1 % if consistent);
- test and fixed targets: every plot use other than TRACKED (``chain.PlotUse``) counted
  by its name, the plots flagged I020 TST, SIM or RAB or coded 7777, and published tracks
  that took such plots or stay within ``STATIONARY_M`` of one place (a fixed
  transponder);
- time faults: each radar's plot times against their reception (median offset, plots
  more than a scan away from it, plots more than a scan older than the radar's latest);
- the radar's clock against the recording's: its service messages' time stamps (CAT034 or
  CAT002 I030, ``bias.reception``) against their reception, a straight line fitted by least
  squares and fitted again without the stamps more than ``CLOCK_OUTLIER_MADS`` median
  absolute deviations off it: the drift (s/h, positive for a radar clock that runs fast)
  with its standard error, and what the line does not explain (reception jitter and the
  stamps' 1/128 s resolution), the evidence ``[bias] clock_states = 2`` models;
- ADS-B (CAT021) as the reference where the recording has it: the distance of each
  published track update with a Mode S address from the ADS-B position of that address
  at the update's time (``tracker_service.adsb``).

Then the checks of issue 10 (``CHECKS``), each passed, failed or not applicable.

Sites: a configuration (``--config``, the service's TOML) gives them. Without one, the
recording's single radar is put at an assumed site (``ASSUMED_SITE``) and fused alone: a
single radar's tracks do not depend on where it is (the conversion to the plane is nearly
rigid near the site). Several radars without sites are tracked each at the assumed site,
and not fused: there are then no system tracks. A simulator recording carries its sites.

The JSON document (``--json``) is ``assess(run)``; its shape is in docs/real-data.md.
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import math
import sys
import time
from collections import defaultdict
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from asterix.containers import Datagram, read_file
from asterix.plots import extract_plots
from tracker_service.adsb import AdsbReference
from tracker_service.bias.reception import ReceptionEvidence
from tracker_service.chain import (
    CAT021,
    NM,
    RAW_PLOT_DTYPE,
    Chain,
    PlotUse,
    blocks_of,
    rejections,
    source_order,
)
from tracker_service.evaluation.real_data import DEFAULT_DAY_POSIX, north_marker_periods
from tracker_service.fusion import SYSTEM_UPDATE_DTYPE
from tracker_service.fusion.messages import COASTING, CONFIRMED, ENDED
from tracker_service.geodesy import RadarSite
from tracker_service.ingest import TimeSource
from tracker_service.radar_stage import RadarStage
from tracker_service.service.config import ConfigError, ServiceConfig, load_service_config
from tracker_service.service.config import parse_service_config as parse_config
from tracker_service.service.core import build_chain
from tracker_service.service.replay import open_replay, parse_date
from tracker_service.simulator.recording import is_mcap
from tracker_service.tracking import DELETED, LocalTracker, TrackerConfig
from tracker_service.tracking.plots import PlotArrays, as_plot_arrays
from tracker_service.validation import dataclass_kwargs

__all__ = [
    "ASSUMED_SITE",
    "CHECKS",
    "NON_DISCRETE",
    "PLOT_EXTRA_DTYPE",
    "SCHEMA",
    "AssessRun",
    "TrackSet",
    "add_arguments",
    "assess",
    "clock_measures",
    "format_summary",
    "identity_tracks",
    "is_discrete",
    "nis_samples",
    "published_kinematics",
    "run",
    "run_recording",
    "stretch_changes",
    "suspect_tracks",
    "track_instances",
]

SCHEMA = "tracker-service/assess/1"
ASSUMED_SITE = RadarSite(lat_deg=40.4, lon_deg=-3.7, alt_m=700.0)
"""Where a radar the configuration does not place is assumed to be (central Spain, where
the shared real recordings come from; any site serves a single radar's tracks)."""
ASSUMED_SIGMA_RANGE_M = 50.0
ASSUMED_SIGMA_AZIMUTH_DEG = 0.07
DEFAULT_PERIOD_S = 5.0
SERVICE_CATEGORIES = (34, 2)
"""Radar service messages: CAT034 (CAT048 radars), CAT002 (CAT001 radars)."""

NON_DISCRETE = frozenset({0o7500, 0o7600, 0o7700, 0o7777})
"""Mode 3/A codes that name no aircraft besides every code ending in 00 (2000, 7000,
1200, 1000, 0000 ...): the emergencies and the test transponders' 7777."""
TEST_CODE = 0o7777
MIN_IDENTITY_UPDATES = 2
GATE_99_2DOF = 9.21
"""The 99 % point of chi-square with 2 degrees of freedom."""
MIN_ACCELERATION_DT_S = 1.0
STATIONARY_M = 500.0
STATIONARY_SPAN_S = 120.0
STATIONARY_UPDATES = 10
ADSB_OTHER_AIRCRAFT_M = 5 * 1852.0
MAX_SPEED_KT = 650.0
MAX_JUMP_M = NM
CLOCK_MIN_MESSAGES = 10
CLOCK_MIN_SPAN_S = 300.0
"""Fewer service messages, or a shorter span, tell nothing of a drift."""
CLOCK_OUTLIER_MADS = 5.0
CLOCK_STAMP_RESOLUTION_S = 1.0 / 128.0
"""I030's LSB. A quiet line can be all in one or two steps of it (canalA's lags are 0,
7.8 or 15.6 ms): the deviation that sets the outlier bound is at least that of a uniform
error over one step (a quarter step), not zero."""
KT = NM / 3600.0
PUBLISHED = (CONFIRMED, COASTING)
REUSE_OFFSET = 1_000_000
PERCENTILES = (50, 95, 99)
CHECKS = (
    "one_system_track_per_address",
    "max_speed_650_kt",
    "max_jump_1_nm",
    "no_test_or_fixed_target_published",
)
"""The criteria of issue 10 on real recordings, in the order they are printed."""

TRACKED_PLOT_DTYPE = np.dtype(
    [
        ("plot_id", np.int64),
        ("time", np.float64),
        ("x", np.float64),
        ("y", np.float64),
        ("R", np.float64, (2, 2)),
    ]
)
"""A plot as the local tracker and the fuser took it (bias-corrected where estimated)."""
FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

PLOT_EXTRA_DTYPE = np.dtype(
    [("received", np.float64), ("tst", np.bool_), ("sim", np.bool_), ("radar", "U16")]
)
"""What assess keeps of each plot beside the chain's table: its datagram's reception
time, its I020 TST and SIM bits and its radar."""


@dataclass
class TrackSet:
    """A set of tracks: one radar's local tracks or the system tracks. ``rows``: every
    update (``track_update_dtype`` or ``SYSTEM_UPDATE_DTYPE``) in processing order;
    ``number``: the field that numbers the tracks, unique per track (a number used again
    after its track ended is offset, see ``track_instances``); ``q_of``: each row's
    white-acceleration intensity for the prediction that follows it (m^2/s^3);
    ``deletion_gap_s``: the longest plot gap a confirmed track survives."""

    name: str
    rows: npt.NDArray[Any]
    number: str
    q_of: FloatArray
    deletion_gap_s: float
    plot_sources: tuple[str, ...]
    """The radars whose plots these tracks take."""


@dataclass
class AssessRun:
    """A recording run through the chain: every plot (``RAW_PLOT_DTYPE``) with its extras,
    the track sets, and the ADS-B errors gathered as the run went."""

    recording: str
    kind: str
    assumed_sites: bool
    configured: dict[str, bool]
    periods: dict[str, float]
    plots: npt.NDArray[Any]
    extra: npt.NDArray[Any]
    tracked: npt.NDArray[Any]
    """Every plot the trackers took, as they took it (``TRACKED_PLOT_DTYPE``)."""
    local: dict[str, TrackSet]
    system: TrackSet | None
    adsb_reports: int
    adsb_errors: dict[str, list[tuple[float, int, float]]]
    """Per track set name: (time, address, error m) of each published update with an ADS-B
    reference."""
    clock_evidence: dict[str, FloatArray]
    """Per radar: its service messages' [radar time, reception] (``bias.reception``)."""
    seconds: float
    notes: list[str] = field(default_factory=list)


# --- running the recording ----------------------------------------------------------------


def _capture_radars(path: Path) -> tuple[list[str], dict[str, float], dict[int, int]]:
    """The SAC/SIC of every radar that sends plots in a capture, their north-marker
    periods, and the number of data blocks of each category."""
    datagrams = [d for d in read_file(path) if isinstance(d, Datagram)]
    sources: set[str] = set()
    categories: dict[int, int] = defaultdict(int)
    for datagram in datagrams:
        raw = extract_plots(datagram.payload).plots
        sources.update(f"{a}/{b}" for a, b in zip(raw["sac"], raw["sic"], strict=True))
        payload, pos = datagram.payload, 0
        while pos + 3 <= len(payload):  # data block headers: CAT, LEN
            categories[payload[pos]] += 1
            pos += max(3, int.from_bytes(payload[pos + 1 : pos + 3]))
    present = dict(sorted(categories.items()))
    periods = _north_marker_intervals(datagrams) | north_marker_periods(datagrams)
    return sorted(sources, key=source_order), periods, present


def _north_marker_intervals(datagrams: list[Datagram]) -> dict[str, float]:
    """Each radar's median interval between the receptions of its north markers (CAT034
    or CAT002 message type 1): its antenna period where the markers carry none (I041)."""
    times: dict[str, list[float]] = defaultdict(list)
    for datagram in datagrams:
        if datagram.time is None:
            continue
        for category in SERVICE_CATEGORIES:
            for block in blocks_of(datagram.payload, category):
                for event in decode_blocks(block):
                    if not isinstance(event, Block):
                        continue
                    for items in event.records:
                        source = items.get("010")
                        if items.get("000") == 1 and isinstance(source, dict):
                            times[f"{source['SAC']}/{source['SIC']}"].append(datagram.time)
    return {
        source: float(np.median(np.diff(t)))
        for source, t in times.items()
        if len(t) > 2 and float(np.median(np.diff(t))) > 0
    }


def _assumed_config(sources: list[str], periods: Mapping[str, float]) -> ServiceConfig:
    """The configuration assess assumes for a capture without one: every radar at
    ``ASSUMED_SITE``, the system's own SAC/SIC one not used by them."""
    keys = [tuple(int(p) for p in s.split("/")) for s in sources] or [(0, 1)]
    sac = keys[0][0]
    sic = next(n for n in range(100, 256) if (sac, n) not in keys)
    radars = [
        {
            "name": f"{sac_}/{sic_} (assumed site)",
            "sac": sac_,
            "sic": sic_,
            "lat": ASSUMED_SITE.lat_deg,
            "lon": ASSUMED_SITE.lon_deg,
            "alt_m": ASSUMED_SITE.alt_m,
            "antenna_period_s": periods.get(f"{sac_}/{sic_}", DEFAULT_PERIOD_S),
            "sigma_range_m": ASSUMED_SIGMA_RANGE_M,
            "sigma_azimuth_deg": ASSUMED_SIGMA_AZIMUTH_DEG,
        }
        for sac_, sic_ in keys
    ]
    system = {
        "centre_lat": ASSUMED_SITE.lat_deg,
        "centre_lon": ASSUMED_SITE.lon_deg,
        "sac": sac,
        "sic": sic,
    }
    return parse_config({"radars": radars, "system": system}, "the assumed configuration")


class _KeepingEvidence(ReceptionEvidence):
    """The radar stage's reception evidence, kept whole as the stage takes it batch by
    batch."""

    def __init__(self, max_offset_s: float, kept: dict[str, list[FloatArray]]) -> None:
        super().__init__(max_offset_s)
        self._kept = kept

    def take(self, source: str) -> FloatArray:
        evidence = super().take(source)
        self._kept[source].append(evidence)
        return evidence


class _KeepingTracker(LocalTracker):
    """A local tracker that keeps each plot as it tracked it: after the chain's bias
    correction, which the plot table does not carry."""

    def __init__(self, config: TrackerConfig, kept: list[npt.NDArray[Any]]) -> None:
        super().__init__(config)
        self._kept = kept

    def process(self, plots: PlotArrays | npt.NDArray[Any]) -> npt.NDArray[Any]:
        rows = as_plot_arrays(plots).rows
        kept = np.zeros(len(rows), TRACKED_PLOT_DTYPE)
        for name in TRACKED_PLOT_DTYPE.names or ():
            kept[name] = rows[name]
        self._kept.append(kept)
        return super().process(plots)


def _chain(config: ServiceConfig, fuse: bool, kept: list[npt.NDArray[Any]]) -> Chain:
    def make_tracker(_source: str, tracker_config: TrackerConfig) -> LocalTracker:
        return _KeepingTracker(tracker_config, kept)

    chain = build_chain(config, make_tracker)
    if fuse:
        return chain
    # Several radars at one assumed site must not be fused: each keeps its own tracks.
    infos = {k: replace(v, surveyed=False) for k, v in chain.infos.items()}
    tracker = dataclass_kwargs("tracker", config.tracker, TrackerConfig)
    return Chain(infos, chain.plane, tracker, make_tracker)


def run_recording(
    path: str | Path, config_path: str | Path | None = None, day_posix: float | None = None
) -> AssessRun:
    """Run a recording through the chain and keep what ``assess`` measures."""
    file = Path(path)
    started = time.perf_counter()
    config = load_service_config(config_path) if config_path is not None else None
    assumed = False
    fuse = True
    notes: list[str] = []
    periods: dict[str, float] = {}
    if config is None and not is_mcap(file) and not file.is_dir():
        sources, periods, categories = _capture_radars(file)
        config = _assumed_config(sources, periods)
        assumed = True
        fuse = len(sources) == 1
        if not sources:
            blocks = ", ".join(f"CAT{c:03d} x{n}" for c, n in categories.items())
            notes.append(f"no plot found; data blocks: {blocks or 'none'}")
        elif fuse:
            notes.append(f"no configuration: radar {sources[0]} at an assumed site, fused alone")
        else:
            notes.append(
                f"no configuration: {len(sources)} radars at an assumed site, not fused "
                "(no system tracks)"
            )
    replay = open_replay(file, config, DEFAULT_DAY_POSIX if day_posix is None else day_posix)
    kept: list[npt.NDArray[Any]] = []
    chain = _chain(replay.config, fuse, kept)
    stamps: dict[str, list[FloatArray]] = defaultdict(list)
    stage = chain.radar_stage
    if isinstance(stage, RadarStage):
        stage.reception = _KeepingEvidence(stage.reception.max_offset_s, stamps)
    adsb = AdsbReference(chain.plane)
    tables: list[npt.NDArray[Any]] = []
    extras: list[npt.NDArray[Any]] = []
    local: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    system: list[npt.NDArray[Any]] = []
    errors: dict[str, list[tuple[float, int, float]]] = defaultdict(list)
    for _name, datagram in replay.datagrams:
        received = float(datagram.time if datagram.time is not None else 0.0)
        for block in blocks_of(datagram.payload, CAT021):
            adsb.feed(block, received)
        outputs = chain.feed(datagram.payload, received)
        if not outputs:
            continue
        raw = extract_plots(datagram.payload).plots
        key = np.asarray(raw["sac"], np.int64) * 256 + np.asarray(raw["sic"], np.int64)
        for output in outputs:
            sac, sic = (int(p) for p in output.source.split("/"))
            mine = raw[key == sac * 256 + sic]
            extra = np.zeros(len(output.plots), PLOT_EXTRA_DTYPE)
            extra["received"] = received
            if len(mine) == len(extra):
                extra["tst"] = mine["tst"] == 1
                extra["sim"] = mine["sim"] == 1
            extra["radar"] = output.source
            tables.append(output.plots)
            extras.append(extra)
            local[output.source].append(output.local)
            if chain.radars[output.source].info.surveyed:
                _adsb_errors(adsb, output.local, errors[output.source])
            if len(output.system):
                system.append(output.system)
                _adsb_errors(adsb, output.system, errors["system"])

    plots = np.concatenate(tables) if tables else np.zeros(0, RAW_PLOT_DTYPE)
    extra_all = np.concatenate(extras) if extras else np.zeros(0, PLOT_EXTRA_DTYPE)
    tracked = np.concatenate(kept) if kept else np.zeros(0, TRACKED_PLOT_DTYPE)
    track_sets: dict[str, TrackSet] = {}
    for source in sorted(chain.radars, key=source_order):
        state = chain.radars[source]
        rows = np.concatenate(local[source])
        cfg = state.tracker_config
        track_sets[source] = TrackSet(
            source,
            track_instances(rows, "track_number", DELETED),
            "track_number",
            _imm_intensity(rows, cfg.q_cv, cfg.q_ct),
            (cfg.delete_misses + cfg.miss_tolerance) * cfg.scan_period_s,
            (source,),
        )
        periods[source] = cfg.scan_period_s
    system_set = None
    if chain.fuser is not None and any(s.index is not None for s in chain.radars.values()):
        rows = np.concatenate(system) if system else np.zeros(0, SYSTEM_UPDATE_DTYPE)
        fused = tuple(
            sorted((s for s, st in chain.radars.items() if st.index is not None), key=source_order)
        )
        system_set = TrackSet(
            "system",
            track_instances(rows, "system_number", ENDED),
            "system_number",
            np.full(len(rows), chain.fuser.config.q),
            max(track_sets[s].deletion_gap_s for s in fused),
            fused,
        )
    return AssessRun(
        recording=file.name,
        kind=replay.kind,
        assumed_sites=assumed,
        configured={s: state.info.surveyed for s, state in chain.radars.items()},
        periods=periods,
        plots=plots,
        extra=extra_all,
        tracked=tracked,
        local=track_sets,
        system=system_set,
        adsb_reports=adsb.reports,
        adsb_errors=dict(errors),
        clock_evidence={source: np.concatenate(parts) for source, parts in stamps.items()},
        seconds=time.perf_counter() - started,
        notes=notes,
    )


def track_instances(rows: npt.NDArray[Any], number: str, ended: int) -> npt.NDArray[Any]:
    """The rows with each track's number made unique per track: a number used again
    after its track ended (status ``ended``) becomes number + ``REUSE_OFFSET`` x reuse."""
    out = rows.copy()
    reuses: dict[int, int] = defaultdict(int)
    keys = out[number]
    for k, (value, status) in enumerate(
        zip(rows[number].tolist(), rows["status"].tolist(), strict=True)
    ):
        keys[k] = value + REUSE_OFFSET * reuses[value]
        if status == ended:
            reuses[value] += 1
    return out


def _imm_intensity(rows: npt.NDArray[Any], q_cv: float, q_ct: float) -> FloatArray:
    """Each local update's white-acceleration intensity: the IMM's CV and turn intensities
    mixed by the update's model probabilities (model 0 is CV)."""
    mu = rows["model_probabilities"]
    if mu.ndim != 2 or mu.shape[1] == 0:
        return np.full(len(rows), q_cv)
    return np.asarray(mu[:, 0] * q_cv + (1.0 - mu[:, 0]) * q_ct, dtype=np.float64)


def _adsb_errors(
    adsb: AdsbReference, rows: npt.NDArray[Any], out: list[tuple[float, int, float]]
) -> None:
    """The distance of each published update with an address from ADS-B at its time."""
    if adsb.reports == 0:
        return
    take = np.isin(rows["status"], PUBLISHED) & (rows["address"] >= 0)
    if not take.any():
        return
    chosen = rows[take]
    refs = adsb.at(chosen["address"], chosen["time"])
    for row, valid, xy in zip(chosen, refs.valid, refs.xy, strict=True):
        if valid:
            error = math.hypot(float(row["x"]) - xy[0], float(row["y"]) - xy[1])
            out.append((float(row["time"]), int(row["address"]), error))


# --- the measures ------------------------------------------------------------------------


def is_discrete(code: npt.NDArray[np.int64]) -> npt.NDArray[np.bool_]:
    """Mode 3/A codes (as integers of their octal digits' value) that name one aircraft."""
    code = np.asarray(code, dtype=np.int64)
    named: npt.NDArray[np.bool_] = (code >= 0) & (code % 0o100 != 0)
    return named & ~np.isin(code, list(NON_DISCRETE))


def _stats(values: Iterable[float] | FloatArray, digits: int = 1) -> dict[str, Any]:
    v = np.asarray(list(values) if not isinstance(values, np.ndarray) else values, float)
    v = v[np.isfinite(v)]
    out: dict[str, Any] = {"samples": int(v.size)}
    for p in PERCENTILES:
        out[f"p{p}"] = round(float(np.percentile(v, p)), digits) if v.size else None
    out["max"] = round(float(v.max()), digits) if v.size else None
    return out


def _ordered(rows: npt.NDArray[Any], number: str) -> tuple[npt.NDArray[Any], npt.NDArray[Any]]:
    """Rows sorted by track then time (stable), and whether each row follows a row of the
    same track."""
    order = np.lexsort((rows["time"], rows[number]))
    r = rows[order]
    follows = np.zeros(len(r), dtype=bool)
    follows[1:] = r[number][1:] == r[number][:-1]
    return order, follows


def _plot_index(plots: npt.NDArray[Any]) -> dict[int, int]:
    return {int(p): i for i, p in enumerate(plots["plot_id"].tolist())}


def published_kinematics(ts: TrackSet) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Of the published updates: ground speed (kt), the position jump of each update that
    follows one of its track (m), and the accelerations over at least
    ``MIN_ACCELERATION_DT_S`` (m/s^2)."""
    rows = ts.rows[np.isin(ts.rows["status"], PUBLISHED)]
    r = rows[np.lexsort((rows["time"], rows[ts.number]))]
    speed = np.hypot(r["vx"], r["vy"]) / KT
    same = r[ts.number][1:] == r[ts.number][:-1]
    prev, cur = r[:-1][same], r[1:][same]
    dt_ = cur["time"] - prev["time"]
    jump = np.hypot(
        cur["x"] - (prev["x"] + prev["vx"] * dt_), cur["y"] - (prev["y"] + prev["vy"] * dt_)
    )
    long_enough = dt_ >= MIN_ACCELERATION_DT_S
    accel = (
        np.hypot(cur["vx"] - prev["vx"], cur["vy"] - prev["vy"])[long_enough] / (dt_[long_enough])
    )
    return speed, jump, accel


def _kinematics(ts: TrackSet) -> dict[str, Any]:
    """Speeds, accelerations and position jumps of the published updates."""
    rows = ts.rows[np.isin(ts.rows["status"], PUBLISHED)]
    r = rows[np.lexsort((rows["time"], rows[ts.number]))]
    cur = r[1:][r[ts.number][1:] == r[ts.number][:-1]]
    speed, jump, accel = published_kinematics(ts)
    fastest = int(np.argmax(speed)) if speed.size else -1
    worst = int(np.argmax(jump)) if jump.size else -1
    return {
        "published_updates": len(rows),
        "speed_kt": _stats(speed)
        | ({"max_track": int(r[ts.number][fastest])} if fastest >= 0 else {}),
        "acceleration_m_s2": _stats(accel, 2),
        "jump_m": _stats(jump)
        | ({"max_track": int(cur[ts.number][worst])} if worst >= 0 else {})
        | {
            "over_1_nm": int(np.count_nonzero(jump > MAX_JUMP_M)),
            "share_over_1_nm": round(float(np.mean(jump > MAX_JUMP_M)), 5) if jump.size else None,
        },
    }


def nis_samples(ts: TrackSet, tracked: npt.NDArray[Any]) -> tuple[FloatArray, FloatArray]:
    """(time, NIS) of every plot that updated a track that had a previous update, against
    the plot as the tracker took it (``tracked``): see the module docstring."""
    index = _plot_index(tracked)
    order, follows = _ordered(ts.rows, ts.number)
    r = ts.rows[order]
    q = ts.q_of[order]
    take = np.flatnonzero(follows & (r["plot_id"] >= 0))
    if not take.size:
        return np.zeros(0), np.zeros(0)
    take = np.array([k for k in take if int(r["plot_id"][k]) in index], dtype=np.int64)
    if not take.size:
        return np.zeros(0), np.zeros(0)
    prev, cur = r[take - 1], r[take]
    qk = q[take - 1]
    plot = tracked[[index[int(p)] for p in cur["plot_id"]]]
    dt_ = plot["time"] - prev["time"]
    f = np.zeros((len(take), 4, 4))
    f[:, [0, 1, 2, 3], [0, 1, 2, 3]] = 1.0
    f[:, 0, 2] = f[:, 1, 3] = dt_
    p = prev["P"].reshape(-1, 4, 4)
    predicted = f @ p @ np.swapaxes(f, 1, 2)
    s = predicted[:, :2, :2] + plot["R"]
    # White acceleration q per axis: position variance q dt^3 / 3.
    s += np.eye(2) * (qk * np.abs(dt_) ** 3 / 3.0)[:, None, None]
    y = np.column_stack(
        [
            plot["x"] - (prev["x"] + prev["vx"] * dt_),
            plot["y"] - (prev["y"] + prev["vy"] * dt_),
        ]
    )
    nis = np.einsum("ka,kab,kb->k", y, np.linalg.inv(s), y)
    return np.asarray(plot["time"], float), nis


def _consistency(ts: TrackSet, tracked: npt.NDArray[Any]) -> dict[str, Any]:
    _, nis = nis_samples(ts, tracked)
    nis = nis[np.isfinite(nis)]
    return {
        "samples": int(nis.size),
        "mean": round(float(nis.mean()), 3) if nis.size else None,
        "share_over_99": round(float(np.mean(nis > GATE_99_2DOF)), 4) if nis.size else None,
        "gate_99": GATE_99_2DOF,
    }


def identity_tracks(
    ts: TrackSet,
    plots: npt.NDArray[Any],
    radar: npt.NDArray[np.str_],
    index: Mapping[int, int],
    field_name: str,
) -> dict[int, dict[str, Any]]:
    """Per identity (Mode S address or discrete Mode 3/A code): its plots' stretches and
    the published tracks that took at least ``MIN_IDENTITY_UPDATES`` of its plots, with
    the times of those updates."""
    own = np.isin(radar, ts.plot_sources) & (plots["use"] == PlotUse.TRACKED)
    values = plots[field_name]
    keep = own & (values >= 0)
    if field_name == "mode3a":
        keep &= is_discrete(values)
    out: dict[int, dict[str, Any]] = {}
    for identity in np.unique(values[keep]).tolist():
        times = np.sort(plots["time"][keep & (values == identity)])
        out[int(identity)] = {"stretches": _stretches(times, ts.deletion_gap_s), "tracks": {}}
    rows = ts.rows[np.isin(ts.rows["status"], PUBLISHED) & (ts.rows["plot_id"] >= 0)]
    seen: dict[tuple[int, int], list[float]] = defaultdict(list)
    # identity -> {"stretches": [(first, last)], "tracks": {number: sorted update times}}
    for number, plot_id, t in zip(
        rows[ts.number].tolist(), rows["plot_id"].tolist(), rows["time"].tolist(), strict=True
    ):
        k = index.get(int(plot_id))
        if k is None:
            continue
        identity = int(values[k])
        if identity in out:
            seen[(identity, int(number))].append(float(t))
    for (identity, number), taken in seen.items():
        if len(taken) >= MIN_IDENTITY_UPDATES:
            out[identity]["tracks"][number] = np.sort(np.asarray(taken))
    return out


def _stretches(times: FloatArray, gap: float) -> list[tuple[float, float]]:
    if times.size == 0:
        return []
    cut = np.flatnonzero(np.diff(times) > gap)
    starts = np.concatenate([[0], cut + 1])
    ends = np.concatenate([cut, [times.size - 1]])
    return [(float(times[a]), float(times[b])) for a, b in zip(starts, ends, strict=True)]


def stretch_changes(
    tracks: Mapping[int, FloatArray], first: float, last: float
) -> tuple[int, int, bool]:
    """Within one plot stretch of an identity: the breaks (a track that starts after the
    previous one's last update) and the overlaps (a track that starts while the previous
    one still updates: a split track or a duplicated identity); and whether any track
    held it."""
    spans = sorted(
        (float(t[inside].min()), float(t[inside].max()))
        for t in tracks.values()
        if (inside := (t >= first) & (t <= last)).any()
    )
    breaks = overlaps = 0
    end = -math.inf
    for start, stop in spans:
        if end > -math.inf:
            if start > end:
                breaks += 1
            else:
                overlaps += 1
        end = max(end, stop)
    return breaks, overlaps, bool(spans)


def _identity_measures(per_identity: Mapping[int, Mapping[str, Any]], label: str) -> dict[str, Any]:
    """Tracks per identity, and the breaks and overlaps while its plots continue."""
    counts = []
    breaks = overlaps = untracked = 0
    worst: list[dict[str, Any]] = []
    for identity, entry in per_identity.items():
        tracks = entry["tracks"]
        counts.append(len(tracks))
        own_breaks = own_overlaps = 0
        for first, last in entry["stretches"]:
            b, o, held = stretch_changes(tracks, first, last)
            own_breaks += b
            own_overlaps += o
            untracked += not held
        breaks += own_breaks
        overlaps += own_overlaps
        if own_breaks or own_overlaps or len(tracks) > len(entry["stretches"]):
            worst.append(
                {
                    label: _identity_text(identity, label),
                    "tracks": len(tracks),
                    "stretches": len(entry["stretches"]),
                    "breaks": own_breaks,
                    "overlaps": own_overlaps,
                }
            )
    worst.sort(key=lambda w: (-w["breaks"] - w["overlaps"], -w["tracks"]))
    return {
        "identities": len(counts),
        "tracked": int(sum(c > 0 for c in counts)),
        "tracks": int(sum(counts)),
        "tracks_per_identity": round(float(np.mean([c for c in counts if c])), 3)
        if any(counts)
        else None,
        "max_tracks": max(counts, default=0),
        "stretches": int(sum(len(e["stretches"]) for e in per_identity.values())),
        "untracked_stretches": untracked,
        "breaks": breaks,
        "overlaps": overlaps,
        "worst": worst[:10],
    }


def _identity_text(identity: int, label: str) -> str:
    return f"{identity:06X}" if label == "address" else f"{identity:04o}"


def suspect_tracks(
    ts: TrackSet, plots: npt.NDArray[Any], extra: npt.NDArray[Any], index: Mapping[int, int]
) -> list[dict[str, Any]]:
    """Published tracks that took a test or fixed target's plot, or stay in one place."""
    rows = ts.rows[np.isin(ts.rows["status"], PUBLISHED)]
    if not len(rows):
        return []
    rows = rows[np.argsort(rows[ts.number], kind="stable")]
    numbers, starts = np.unique(rows[ts.number], return_index=True)
    out: list[dict[str, Any]] = []
    for number, track in zip(numbers.tolist(), np.split(rows, starts[1:]), strict=True):
        ks = [index[int(p)] for p in track["plot_id"] if int(p) in index]
        reasons: set[str] = set()
        if ks:
            taken = plots[ks]
            flags = extra[ks]
            reasons.update(
                PlotUse(u).name.lower() for u in np.unique(taken["use"]) if u != PlotUse.TRACKED
            )
            if flags["tst"].any():
                reasons.add("tst")
            if flags["sim"].any():
                reasons.add("sim")
            if taken["rab"].any():
                reasons.add("rab")
            if (taken["mode3a"] == TEST_CODE).any():
                reasons.add("code_7777")
        span = float(track["time"].max() - track["time"].min())
        if len(track) >= STATIONARY_UPDATES and span >= STATIONARY_SPAN_S:
            cx, cy = np.median(track["x"]), np.median(track["y"])
            if float(np.max(np.hypot(track["x"] - cx, track["y"] - cy))) < STATIONARY_M:
                reasons.add("stationary")
        if reasons:
            address = track["address"][track["address"] >= 0]
            code = track["mode3a"][track["mode3a"] >= 0]
            out.append(
                {
                    "track": int(number),
                    "reasons": sorted(reasons),
                    "address": f"{int(address[-1]):06X}" if address.size else None,
                    "mode3a": f"{int(code[-1]):04o}" if code.size else None,
                    "updates": len(track),
                }
            )
    return out


def _adsb_measures(errors: list[tuple[float, int, float]]) -> dict[str, Any]:
    """Errors against ADS-B; beyond ``ADSB_OTHER_AIRCRAFT_M`` the ADS-B of that address is
    another aircraft (a duplicated address), counted apart."""
    all_errors = np.array([x[2] for x in errors], dtype=float)
    e = all_errors[all_errors <= ADSB_OTHER_AIRCRAFT_M]
    return {
        "updates": int(e.size),
        "addresses": len({x[1] for x in errors}),
        "other_aircraft": int(all_errors.size - e.size),
        "rms_m": round(float(np.sqrt(np.mean(e**2))), 1) if e.size else None,
        "error_m": _stats(e),
    }


def _track_measures(
    run: AssessRun, ts: TrackSet, plots: npt.NDArray[Any], index: Mapping[int, int]
) -> dict[str, Any]:
    statuses = ts.rows["status"]
    published = np.unique(ts.rows[ts.number][np.isin(statuses, PUBLISHED)])
    doc: dict[str, Any] = {
        "tracks": len(np.unique(ts.rows[ts.number])),
        "published_tracks": len(published),
        "updates": len(ts.rows),
        "per_address": _identity_measures(
            identity_tracks(ts, plots, run.extra["radar"], index, "address"), "address"
        ),
        "per_mode3a": _identity_measures(
            identity_tracks(ts, plots, run.extra["radar"], index, "mode3a"), "mode3a"
        ),
    }
    doc |= _kinematics(ts)
    doc["nis"] = _consistency(ts, run.tracked)
    doc["suspect_tracks"] = suspect_tracks(ts, plots, run.extra, index)
    errors = run.adsb_errors.get(ts.name)
    doc["adsb"] = _adsb_measures(errors) if errors else None
    return doc


def _time_faults(table: npt.NDArray[Any], extra: npt.NDArray[Any], period: float) -> dict[str, Any]:
    offset = table["time"] - extra["received"]
    median = float(np.median(offset)) if offset.size else math.nan
    latest = np.maximum.accumulate(table["time"]) if table.size else table["time"]
    sources, counts = np.unique(table["time_source"], return_counts=True)
    return {
        "median_offset_s": round(median, 3) if offset.size else None,
        "far_from_reception": int(np.count_nonzero(np.abs(offset - median) > period)),
        "older_than_latest": int(np.count_nonzero(table["time"] < latest - period)),
        "time_sources": {
            TimeSource(int(s)).name.lower(): int(n) for s, n in zip(sources, counts, strict=True)
        },
    }


def clock_measures(evidence: FloatArray) -> dict[str, Any] | None:
    """The radar clock against reception from its service messages' [radar time, reception]
    rows: the lag (reception - radar time: transmission delay minus clock offset) fitted
    as a straight line in reception time, then again without the outliers (a message held
    up on the way). None with fewer than ``CLOCK_MIN_MESSAGES`` or a shorter span than
    ``CLOCK_MIN_SPAN_S``."""
    if len(evidence) < CLOCK_MIN_MESSAGES:
        return None
    received = evidence[:, 1]
    span = float(received.max() - received.min())
    if span < CLOCK_MIN_SPAN_S:
        return None
    t = received - received.min()
    lag = received - evidence[:, 0]
    coef = _line_fit(t, lag)
    residual = lag - (coef[0] + coef[1] * t)
    mad = float(np.median(np.abs(residual - np.median(residual))))
    kept = np.abs(residual) <= CLOCK_OUTLIER_MADS * max(mad, CLOCK_STAMP_RESOLUTION_S / 4)
    coef = _line_fit(t[kept], lag[kept])
    residual = (lag - (coef[0] + coef[1] * t))[kept]
    dof = max(len(residual) - 2, 1)
    sigma = math.sqrt(float(residual @ residual) / dof)
    centred = t[kept] - t[kept].mean()
    slope_sigma = sigma / math.sqrt(float(centred @ centred))
    return {
        "messages": len(evidence),
        "span_s": round(span, 1),
        "lag_median_ms": round(float(np.median(lag)) * 1e3, 2),
        # The lag falls as a fast radar clock gains on reception.
        "drift_s_per_h": round(-float(coef[1]) * 3600.0, 5),
        "drift_sigma_s_per_h": round(slope_sigma * 3600.0, 5),
        "residual_sd_ms": round(sigma * 1e3, 2),
        "residual_max_ms": round(float(np.abs(residual).max()) * 1e3, 2),
        "outliers": int(np.count_nonzero(~kept)),
    }


def _line_fit(t: FloatArray, y: FloatArray) -> FloatArray:
    """Least-squares [a, b] of y = a + b t."""
    design = np.column_stack([np.ones(len(t)), t])
    return np.asarray(np.linalg.lstsq(design, y, rcond=None)[0], dtype=np.float64)


def _targets_seen(table: npt.NDArray[Any], extra: npt.NDArray[Any]) -> list[dict[str, Any]]:
    """Plots that are not traffic, or say they are not: grouped by what marks them
    (kept-out use, TST, SIM, RAB, code 7777) and their identity, with where they were."""
    groups: dict[tuple[str, int, int], list[int]] = defaultdict(list)
    marked_rows = (
        (table["use"] != PlotUse.TRACKED)
        | extra["tst"]
        | extra["sim"]
        | table["rab"]
        | (table["mode3a"] == TEST_CODE)
    )
    for k in np.flatnonzero(marked_rows).tolist():
        marks: list[str] = []
        if table["use"][k] != PlotUse.TRACKED:
            marks.append(PlotUse(int(table["use"][k])).name.lower())
        if extra["tst"][k]:
            marks.append("tst")
        if extra["sim"][k]:
            marks.append("sim")
        if table["rab"][k]:
            marks.append("rab")
        if table["mode3a"][k] == TEST_CODE:
            marks.append("code_7777")
        groups[("+".join(marks), int(table["address"][k]), int(table["mode3a"][k]))].append(k)
    out = []
    for (marked, address, code), ks in sorted(groups.items()):
        out.append(
            {
                "marks": marked,
                "address": f"{address:06X}" if address >= 0 else None,
                "mode3a": f"{code:04o}" if code >= 0 else None,
                "plots": len(ks),
                "range_nm": _finite_median(table["rho_m"][ks] / NM, 2),
                "azimuth_deg": _finite_median(table["theta_deg"][ks], 2),
            }
        )
    return out


def _finite_median(values: FloatArray, digits: int) -> float | None:
    """The median of the finite values; None where there is none (a CAT048 record of TYP 0,
    no detection, carries no position: JSON has no NaN)."""
    finite = values[np.isfinite(values)]
    return round(float(np.median(finite)), digits) if finite.size else None


def _radar_measures(run: AssessRun, source: str, index: Mapping[int, int]) -> dict[str, Any]:
    own = run.extra["radar"] == source
    table, extra = run.plots[own], run.extra[own]
    uses = {"tracked": int(np.count_nonzero(table["use"] == PlotUse.TRACKED))}
    uses |= rejections(table["use"])
    first = float(table["time"].min()) if len(table) else None
    span = float(table["time"].max()) - first if first is not None else 0.0
    return {
        "configured": run.configured.get(source, False),
        "period_s": round(run.periods[source], 3) if source in run.periods else None,
        "plots": len(table),
        "span_s": round(span, 1),
        "first_time": _iso(first),
        "plot_uses": uses,
        "flags": {
            "tst": int(np.count_nonzero(extra["tst"])),
            "sim": int(np.count_nonzero(extra["sim"])),
            "rab": int(np.count_nonzero(table["rab"])),
            "code_7777": int(np.count_nonzero(table["mode3a"] == TEST_CODE)),
        },
        "targets_seen": _targets_seen(table, extra),
        "time": _time_faults(table, extra, run.periods.get(source, DEFAULT_PERIOD_S)),
        "clock": clock_measures(run.clock_evidence[source])
        if source in run.clock_evidence
        else None,
        "local": _track_measures(run, run.local[source], run.plots, index),
    }


def _iso(t: float | None) -> str | None:
    if t is None:
        return None
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat(timespec="seconds")


def _check(name: str, passed: bool | None, detail: str) -> dict[str, Any]:
    return {"name": name, "passed": passed, "detail": detail}


def _checks(doc: Mapping[str, Any]) -> list[dict[str, Any]]:
    system = doc["system"]
    sets = {f"local {s}": r["local"] for s, r in doc["radars"].items()}
    if system is not None:
        sets["system"] = system
    out = []
    if system is None:
        out.append(_check(CHECKS[0], None, "no system tracks (radars not fused)"))
    elif system["per_address"]["tracked"] == 0:
        c = system["per_mode3a"]
        out.append(
            _check(
                CHECKS[0],
                None,
                "no Mode S address has a system track (per discrete Mode 3/A code: "
                f"{c['tracks']} tracks for {c['identities']} codes, {c['breaks']} breaks, "
                f"{c['overlaps']} overlaps)",
            )
        )
    else:
        a = system["per_address"]
        out.append(
            _check(
                CHECKS[0],
                a["breaks"] + a["overlaps"] == 0,
                f"{a['tracks']} system tracks for {a['identities']} addresses in "
                f"{a['stretches']} plot stretches: {a['breaks']} breaks, {a['overlaps']} "
                "overlaps",
            )
        )
    fast = {k: v["speed_kt"]["max"] for k, v in sets.items() if v["speed_kt"]["max"] is not None}
    jumps = {k: v["jump_m"] for k, v in sets.items() if v["jump_m"]["max"] is not None}
    if fast:
        top = max(fast, key=lambda k: fast[k])
        out.append(
            _check(
                CHECKS[1],
                fast[top] <= MAX_SPEED_KT,
                f"fastest published track {fast[top]:.0f} kt ({top}, track "
                f"{sets[top]['speed_kt'].get('max_track')}); limit {MAX_SPEED_KT:.0f} kt",
            )
        )
    else:
        out.append(_check(CHECKS[1], None, "no published track"))
    if jumps:
        top = max(jumps, key=lambda k: jumps[k]["max"])
        over = sum(j["over_1_nm"] for j in jumps.values())
        out.append(
            _check(
                CHECKS[2],
                over == 0,
                f"{over} jumps over 1 NM; largest {jumps[top]['max'] / NM:.2f} NM ({top}, "
                f"track {jumps[top].get('max_track')})",
            )
        )
    else:
        out.append(_check(CHECKS[2], None, "no track with two published updates"))
    suspects = [
        f"{k} track {t['track']} ({', '.join(t['reasons'])})"
        for k, v in sets.items()
        for t in v["suspect_tracks"]
    ]
    out.append(
        _check(
            CHECKS[3],
            not suspects if any(v["published_tracks"] for v in sets.values()) else None,
            "; ".join(suspects[:8]) + (f" and {len(suspects) - 8} more" * (len(suspects) > 8))
            if suspects
            else "no published track took a test or fixed target's plot or stood still",
        )
    )
    return out


def assess(run: AssessRun) -> dict[str, Any]:
    """The JSON document of a run (see docs/real-data.md for its shape)."""
    index = _plot_index(run.plots)
    radars = {
        source: _radar_measures(run, source, index)
        for source in sorted(run.local, key=source_order)
    }
    system = None
    if run.system is not None:
        system = _track_measures(run, run.system, run.plots, index)
        system["radars"] = list(run.system.plot_sources)
    doc: dict[str, Any] = {
        "schema": SCHEMA,
        "recording": run.recording,
        "kind": run.kind,
        "assumed_sites": run.assumed_sites,
        "notes": run.notes,
        "seconds": round(run.seconds, 2),
        "plots": len(run.plots),
        "adsb_reports": run.adsb_reports,
        "radars": radars,
        "system": system,
    }
    doc["checks"] = _checks(doc)
    verdicts = [c["passed"] for c in doc["checks"] if c["passed"] is not None]
    doc["passed"] = all(verdicts) if verdicts else None
    return doc


# --- output ------------------------------------------------------------------------------


def _v(value: Any, unit: str = "") -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.3g}{unit}" if abs(value) < 10 else f"{value:.0f}{unit}"
    return f"{value}{unit}"


def _set_lines(title: str, m: Mapping[str, Any]) -> list[str]:
    a, c = m["per_address"], m["per_mode3a"]
    s, j, n = m["speed_kt"], m["jump_m"], m["nis"]
    acc = m["acceleration_m_s2"]
    head = (
        f"  {title}: {m['published_tracks']} published tracks ({m['tracks']} started), "
        f"{m['published_updates']} published updates"
    )
    if not m["published_tracks"]:
        return [f"{head}; {a['identities']} addresses, {c['identities']} discrete codes"]
    lines = [
        head,
        f"    per Mode S address: {a['tracks']} tracks for {a['identities']} addresses "
        f"({_v(a['tracks_per_identity'])} per address, max {a['max_tracks']}), "
        f"{a['stretches']} plot stretches, {a['breaks']} breaks, {a['overlaps']} overlaps, "
        f"{a['untracked_stretches']} untracked",
        f"    per discrete Mode 3/A: {c['tracks']} tracks for {c['identities']} codes "
        f"({_v(c['tracks_per_identity'])} per code, max {c['max_tracks']}), "
        f"{c['breaks']} breaks, {c['overlaps']} overlaps",
        f"    speed kt: p50 {_v(s['p50'])} p95 {_v(s['p95'])} p99 {_v(s['p99'])} "
        f"max {_v(s['max'])}; acceleration m/s2: p50 {_v(acc['p50'])} p95 {_v(acc['p95'])} "
        f"p99 {_v(acc['p99'])} max {_v(acc['max'])}",
        f"    jump m: p50 {_v(j['p50'])} p95 {_v(j['p95'])} p99 {_v(j['p99'])} "
        f"max {_v(j['max'])}; over 1 NM: {j['over_1_nm']} ({_v(j['share_over_1_nm'])})",
        f"    NIS: mean {_v(n['mean'])} (2 if consistent) over {n['samples']} plots, "
        f"beyond the 99 % gate {_v(n['share_over_99'])} (0.01 if consistent)",
    ]
    for w in a["worst"][:5]:
        lines.append(
            f"    address {w['address']}: {w['tracks']} tracks, {w['stretches']} stretches, "
            f"{w['breaks']} breaks, {w['overlaps']} overlaps"
        )
    for t in m["suspect_tracks"][:5]:
        lines.append(
            f"    suspect track {t['track']} ({', '.join(t['reasons'])}): address "
            f"{t['address'] or '-'}, code {t['mode3a'] or '-'}, {t['updates']} updates"
        )
    if m["adsb"] is not None:
        e = m["adsb"]
        lines.append(
            f"    against ADS-B: {e['updates']} updates of {e['addresses']} addresses, RMS "
            f"{_v(e['rms_m'])} m, p50 {_v(e['error_m']['p50'])} m, p95 "
            f"{_v(e['error_m']['p95'])} m, max {_v(e['error_m']['max'])} m; "
            f"{e['other_aircraft']} beyond 5 NM (another aircraft with that address)"
        )
    return lines


def format_summary(doc: Mapping[str, Any]) -> str:
    """The document as text for a person: per radar, then the system, then the checks."""
    lines = [
        f"{doc['recording']} ({doc['kind']}): {doc['plots']} plots, "
        f"{doc['adsb_reports']} ADS-B reports, run in {doc['seconds']:.1f} s",
    ]
    lines += [f"  note: {note}" for note in doc["notes"]]
    for source, r in doc["radars"].items():
        t = r["time"]
        uses = ", ".join(f"{k} {v}" for k, v in r["plot_uses"].items())
        flags = ", ".join(f"{k} {v}" for k, v in r["flags"].items())
        lines += [
            f"radar {source}{'' if r['configured'] else ' (site assumed)'}: {r['plots']} plots "
            f"over {r['span_s'] / 60:.1f} min from {r['first_time']}, period "
            f"{_v(r['period_s'], ' s')}",
            f"  plot uses: {uses}; flags: {flags}",
            f"  time: plot time - reception median {_v(t['median_offset_s'], ' s')}, "
            f"{t['far_from_reception']} plots more than a scan from it, "
            f"{t['older_than_latest']} more than a scan older than the latest",
        ]
        if (c := r["clock"]) is not None:
            lines.append(
                f"  clock: drift {c['drift_s_per_h'] * 1e3:+.1f} ms/h "
                f"(sigma {c['drift_sigma_s_per_h'] * 1e3:.1f}) from {c['messages']} service "
                f"messages over {c['span_s'] / 60:.0f} min; lag median {_v(c['lag_median_ms'])} "
                f"ms, residual sd {_v(c['residual_sd_ms'])} ms, max "
                f"{_v(c['residual_max_ms'])} ms, {c['outliers']} outliers"
            )
        for target in r["targets_seen"][:8]:
            where = (
                f"at {target['range_nm']} NM, {target['azimuth_deg']} deg"
                if target["range_nm"] is not None
                else "without a position"
            )
            lines.append(
                f"  seen {target['marks']}: address {target['address'] or '-'}, code "
                f"{target['mode3a'] or '-'}, {target['plots']} plots {where}"
            )
        lines += _set_lines("local tracks", r["local"])
    if doc["system"] is not None:
        lines.append(f"system ({', '.join(doc['system']['radars'])}):")
        lines += _set_lines("system tracks", doc["system"])
    lines.append("checks:")
    for check in doc["checks"]:
        verdict = {True: "PASS", False: "FAIL", None: "n/a "}[check["passed"]]
        lines.append(f"  {verdict} {check['name']}: {check['detail']}")
    return "\n".join(lines)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "recording",
        help="a capture (pcap, pcapng, GPS, final format, raw, hex), a simulator MCAP "
        "recording or a service log",
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="the service configuration (TOML) that places the radars; without it a "
        "single radar is assumed at a nominal site and fused alone",
    )
    parser.add_argument(
        "--date",
        type=parse_date,
        metavar="YYYY-MM-DD",
        help="the day of a capture that holds times of day (default 2000-01-01)",
    )
    parser.add_argument("--json", action="store_true", help="print the JSON document on stdout")
    parser.add_argument(
        "--report", metavar="DIR", help="write a Markdown report with PNG figures into DIR"
    )


def run(args: argparse.Namespace) -> int:
    """The command: 0 when every applicable check passes, 1 when one fails, 2 on bad input."""
    try:
        result = run_recording(args.recording, args.config, args.date)
    except (ConfigError, ValueError, OSError) as exc:
        print(f"tracker-service assess: {exc}", file=sys.stderr)
        return 2
    doc = assess(result)
    if args.json:
        print(json.dumps(doc, indent=2))
    else:
        print(format_summary(doc))
    if args.report:
        from tracker_service.evaluation.assess_report import write_report

        path = write_report(result, doc, Path(args.report))
        print(f"report: {path}", file=sys.stderr)
    return 1 if doc["passed"] is False else 0
