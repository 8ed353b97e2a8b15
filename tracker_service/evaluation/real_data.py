"""Run the local tracker on a real capture (no truth): pcap, GPS, final format, ...

``track_capture`` reads a capture with ``asterix.containers.read_file``, times the CAT048
plots with ``PlotClock`` (fed with every CAT034 record), converts them to the system
plane with ``convert_plots`` (heights from ``HeightModel``, as ``pipeline.run_pipeline``
does) and feeds each datagram to the ``LocalTracker`` of its SAC/SIC. Each radar's scan
period is the median CAT034 I041 of its north markers, when it sends any.

Captures without a site survey: a single radar's local tracks do not depend on where the
radar is (the conversion to the plane is nearly a rigid map near the site), so a nominal
site does for them; fusion and bias estimation need the real one.

GPS and final-format captures give reception times of day only: the date is unknown and
``day_posix`` (default 2000-01-01) stands in for it; times of day that go back by more
than half a day are taken as the next day.

``python -m tracker_service.evaluation.real_data CAPTURE --out FIGURE.png`` tracks a
capture with the nominal site and prints the per-address summary (``summarise``).
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import statistics
from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from asterix.codec import Block, decode_blocks
from asterix.containers import Datagram, read_file
from asterix.plots import extract_plots
from tracker_service.bias import BiasConfig
from tracker_service.chain import (
    NM,
    SERVICE_CATEGORIES,
    Chain,
    RadarInfo,
    blocks_of,
    source_order,
)
from tracker_service.fusion import FusionConfig
from tracker_service.geodesy import RadarSite, SystemPlane
from tracker_service.ingest import DAY_S
from tracker_service.tracking import CONFIRMED, TrackerConfig

__all__ = [
    "DEFAULT_DAY_POSIX",
    "NOMINAL_SITE_068",
    "AddressSummary",
    "CaptureRun",
    "TrackSummary",
    "address_stretches",
    "main",
    "north_marker_periods",
    "plot_figure",
    "prediction_residuals",
    "summarise",
    "track_capture",
]


DEFAULT_DAY_POSIX = 946_684_800.0
"""2000-01-01T00:00:00Z: stands in for the unknown date of GPS and final-format captures."""

NOMINAL_SITE_068 = RadarSite(lat_deg=40.4, lon_deg=-3.7, alt_m=700.0)
"""A nominal site for ``068test_bds30.gps`` (SAC 20/SIC 4, a Spanish radar whose site is not
published): central Spain. Only the local tracks of this one radar are meaningful."""


@dataclass
class CaptureRun:
    """One radar's run over a capture: track updates (``track_update_dtype``) and plots."""

    info: RadarInfo
    updates: npt.NDArray[Any]
    plots: npt.NDArray[Any]  # RAW_PLOT_DTYPE, in processing order
    tracker_config: TrackerConfig
    stats: dict[str, int]
    system: npt.NDArray[Any] | None = None
    """The system-track rows (``fusion.SYSTEM_UPDATE_DTYPE``) of this radar's batches, when
    ``track_capture`` was given a ``fusion`` configuration."""


def _source(sac: int, sic: int) -> str:
    return f"{sac}/{sic}"


def _reception_times(datagrams: Sequence[Datagram], day_posix: float) -> list[float]:
    """POSIX reception times: POSIX already (pcap) or times of day on the given day."""
    out: list[float] = []
    day = day_posix
    previous: float | None = None
    for index, datagram in enumerate(datagrams):
        t = datagram.time
        if t is None:
            raise ValueError(
                f"datagram {index} (offset {datagram.offset}) has no reception time: "
                "real-data tracking needs a timed capture (pcap, pcapng, GPS)"
            )
        if t > DAY_S:  # pcap/pcapng: already POSIX
            out.append(t)
            continue
        if previous is not None and t < previous - DAY_S / 2:
            day += DAY_S  # midnight
        previous = t
        out.append(day + t)
    return out


def north_marker_periods(datagrams: Sequence[Datagram]) -> dict[str, float]:
    """Median CAT034 I041 (antenna rotation period) of each radar's north markers."""
    periods: dict[str, list[float]] = defaultdict(list)
    for datagram in datagrams:
        for items in _cat034_records(datagram.payload):
            source, period = items.get("010"), items.get("041")
            if items.get("000") == 1 and isinstance(source, dict) and isinstance(period, float):
                periods[_source(source["SAC"], source["SIC"])].append(period)
    return {source: statistics.median(values) for source, values in periods.items() if values}


def _cat034_records(payload: bytes) -> list[dict[str, Any]]:
    records: list[dict[str, Any]] = []
    for category in SERVICE_CATEGORIES:  # CAT034, and CAT002 of CAT001 radars
        for block in blocks_of(payload, category):
            for event in decode_blocks(block):
                if isinstance(event, Block):
                    records.extend(event.records)
    return records


def track_capture(
    path: str | Path,
    site: RadarSite | dict[str, RadarSite],
    plane: SystemPlane | None = None,
    sigma_range_m: float = 50.0,
    sigma_azimuth_deg: float = 0.07,
    tracker_config: TrackerConfig | None = None,
    *,
    day_posix: float = DEFAULT_DAY_POSIX,
    fusion: FusionConfig | None = None,
    bias: BiasConfig | None = None,
) -> dict[str, CaptureRun]:
    """Track every radar of a capture; see the module docstring.

    ``site``: one site for every radar, or one per ``"SAC/SIC"`` (radars not listed are
    tracked at an assumed site, with a warning: see ``tracker_service.chain``). ``plane``:
    the system plane, centred on the (first) site by default. ``tracker_config``: the
    tracker's tunables; its ``scan_period_s`` is replaced by the radar's north-marker period
    when the capture has one. ``fusion`` and ``bias``: fuse the local tracks into system
    tracks (and estimate the biases), as the service does."""
    datagrams = [d for d in read_file(path) if isinstance(d, Datagram)]
    reception = _reception_times(datagrams, day_posix)
    periods = north_marker_periods(datagrams)
    if isinstance(site, RadarSite):
        sites = {source: site for source in _plot_sources(datagrams)}
        plane = plane or SystemPlane(site.lat_deg, site.lon_deg)
    else:
        sites = dict(site)
        first = next(iter(sites.values()))
        plane = plane or SystemPlane(first.lat_deg, first.lon_deg)
    base = tracker_config or TrackerConfig()
    infos = {
        source: RadarInfo(
            source=source,
            site=radar_site,
            period_s=periods.get(source, base.scan_period_s),
            sigma_range_m=sigma_range_m,
            sigma_azimuth_deg=sigma_azimuth_deg,
            psr_sigma_range_m=sigma_range_m,
            psr_sigma_azimuth_deg=sigma_azimuth_deg,
        )
        for source, radar_site in sites.items()
    }
    overrides = dataclasses.asdict(base)
    del overrides["scan_period_s"]  # each radar's own, from its north markers
    chain = Chain(infos, plane, overrides, fusion=fusion, bias=bias)
    updates: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    tables: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    system: dict[str, list[npt.NDArray[Any]]] = defaultdict(list)
    for datagram, received in zip(datagrams, reception, strict=True):
        for output in chain.feed(datagram.payload, received):
            updates[output.source].append(output.local)
            tables[output.source].append(output.plots)
            system[output.source].append(output.system)

    out: dict[str, CaptureRun] = {}
    for source in sorted(chain.radars, key=source_order):
        radar = chain.radars[source]
        out[source] = CaptureRun(
            radar.info,
            np.concatenate(updates[source]),
            np.concatenate(tables[source]),
            radar.tracker_config,
            dataclasses.asdict(radar.tracker.stats),
            np.concatenate(system[source]) if fusion is not None else None,
        )
    return out


def _plot_sources(datagrams: Sequence[Datagram]) -> list[str]:
    """Every SAC/SIC that sends plots."""
    sources: set[str] = set()
    for datagram in datagrams:
        raw = extract_plots(datagram.payload).plots
        sources.update(_source(int(a), int(b)) for a, b in zip(raw["sac"], raw["sic"], strict=True))
    return sorted(sources, key=source_order)


# --- what the run says ------------------------------------------------------------------


def address_stretches(
    times: npt.NDArray[np.float64], max_gap_s: float
) -> list[tuple[float, float]]:
    """(first, last) plot time of each run of plots with no gap longer than ``max_gap_s``."""
    t = np.sort(np.asarray(times, dtype=np.float64))
    if t.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(t) > max_gap_s)
    starts = np.concatenate([[0], breaks + 1])
    ends = np.concatenate([breaks, [t.size - 1]])
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends, strict=True)]


def prediction_residuals(
    updates: npt.NDArray[Any], plots: npt.NDArray[Any]
) -> tuple[npt.NDArray[np.int64], npt.NDArray[np.float64], npt.NDArray[np.float64]]:
    """Each plot against its track's prediction: (plot_id, residual x/y in m (N, 2), plot
    sigma per axis in m, sqrt(trace(R)/2)).

    The prediction is the constant-velocity extrapolation of the track's previous update
    to the plot's time (the IMM's own prediction mixes in the turn models: this one is a
    little worse at turn onsets). The first plot of each track has none and is left out."""
    ids: list[int] = []
    residuals: list[tuple[float, float]] = []
    sigmas: list[float] = []
    by_id = {int(p): i for i, p in enumerate(plots["plot_id"])}
    order = np.argsort(updates["time"], kind="stable")
    previous: dict[int, Any] = {}
    for row in updates[order]:
        number = int(row["track_number"])
        plot_id = int(row["plot_id"])
        before = previous.get(number)
        if plot_id >= 0:
            plot = plots[by_id[plot_id]]
            if before is not None:
                dt = float(plot["time"] - before["time"])
                px = float(before["x"] + before["vx"] * dt)
                py = float(before["y"] + before["vy"] * dt)
                ids.append(plot_id)
                residuals.append((float(plot["x"]) - px, float(plot["y"]) - py))
                sigmas.append(float(np.sqrt(np.trace(plot["R"]) / 2.0)))
            previous[number] = row
    return (
        np.asarray(ids, dtype=np.int64),
        np.asarray(residuals, dtype=np.float64).reshape(-1, 2),
        np.asarray(sigmas, dtype=np.float64),
    )


@dataclass
class TrackSummary:
    track_number: int
    first_s: float
    last_s: float
    plots: int
    residual_rms_m: float
    residual_rms_sigma: float
    """Residual RMS per axis over the plots' own sigma per axis."""

    @property
    def duration_s(self) -> float:
        return self.last_s - self.first_s


@dataclass
class AddressSummary:
    address: str
    plots: int
    largest_gap_s: float
    stretches: list[tuple[float, float]]
    """Runs of plots with no gap beyond the deletion threshold (POSIX s)."""
    tracks: list[TrackSummary]
    """Confirmed tracks that updated with a plot of this address."""


def _deletion_gap_s(config: TrackerConfig) -> float:
    """The longest plot gap a confirmed track survives: ``delete_misses`` misses are
    counted once ``delete_misses + miss_tolerance`` periods have passed."""
    return (config.delete_misses + config.miss_tolerance) * config.scan_period_s


def summarise(run: CaptureRun) -> tuple[dict[str, AddressSummary], list[int]]:
    """Per Mode S address: its plots, stretches and confirmed tracks; and the confirmed
    tracks that carry no plot with an address (possible false tracks)."""
    updates, plots = run.updates, run.plots
    confirmed_numbers = set(updates["track_number"][updates["status"] == CONFIRMED].tolist())
    address_of = dict(zip(plots["plot_id"].tolist(), plots["address"].tolist(), strict=True))
    ids, residuals, sigmas = prediction_residuals(updates, plots)
    residual_of = {int(i): (r, s) for i, r, s in zip(ids, residuals, sigmas, strict=True)}
    per_track: dict[int, list[Any]] = defaultdict(list)
    for row in updates[updates["plot_id"] >= 0]:
        per_track[int(row["track_number"])].append(row)
    addresses_of_track = {
        n: {address_of[int(r["plot_id"])] for r in rows} - {-1} for n, rows in per_track.items()
    }
    gap = _deletion_gap_s(run.tracker_config)
    out: dict[str, AddressSummary] = {}
    for address in sorted(set(plots["address"].tolist()) - {-1}):
        times = np.sort(plots["time"][plots["address"] == address])
        tracks: list[TrackSummary] = []
        for number in sorted(confirmed_numbers):
            if address not in addresses_of_track.get(number, set()):
                continue
            rows = per_track[number]
            res = [residual_of[int(r["plot_id"])] for r in rows if int(r["plot_id"]) in residual_of]
            r2 = np.array([float(np.sum(r**2)) / 2.0 for r, _ in res])
            n2 = np.array([float(np.sum(r**2)) / 2.0 / s**2 for r, s in res])
            tracks.append(
                TrackSummary(
                    track_number=number,
                    first_s=float(min(r["time"] for r in rows)),
                    last_s=float(max(r["time"] for r in rows)),
                    plots=len(rows),
                    residual_rms_m=float(np.sqrt(r2.mean())) if r2.size else float("nan"),
                    residual_rms_sigma=float(np.sqrt(n2.mean())) if n2.size else float("nan"),
                )
            )
        out[f"{address:06X}"] = AddressSummary(
            address=f"{address:06X}",
            plots=int(times.size),
            largest_gap_s=float(np.diff(times).max()) if times.size > 1 else 0.0,
            stretches=address_stretches(times, gap),
            tracks=tracks,
        )
    anonymous = sorted(n for n in confirmed_numbers if not addresses_of_track.get(n))
    return out, anonymous


def plot_figure(run: CaptureRun, out: str | Path, title: str = "") -> Path:
    """The plots and the confirmed tracks in the system plane, and track speed over time."""
    # Imported by name, here only: matplotlib is optional (the ``report`` extra) and mypy
    # must pass where it is absent.
    try:
        matplotlib = importlib.import_module("matplotlib")
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ValueError("the figure needs matplotlib: pip install -e '.[report]'") from exc
    matplotlib.use("Agg")
    plt = importlib.import_module("matplotlib.pyplot")

    summary, _ = summarise(run)
    updates, plots = run.updates, run.plots
    t0 = float(plots["time"].min()) if len(plots) else 0.0
    fig, (ax_xy, ax_v) = plt.subplots(1, 2, figsize=(14, 6.5), width_ratios=(1.1, 1.0))
    ax_xy.scatter(
        plots["x"] / 1000, plots["y"] / 1000, s=2, c="0.6", label="plots", rasterized=True
    )
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    k = 0
    for address, entry in summary.items():
        for track in entry.tracks:
            rows = updates[updates["track_number"] == track.track_number]
            rows = rows[np.argsort(rows["time"], kind="stable")]
            colour = colours[k % len(colours)]
            k += 1
            label = (
                f"{address} track {track.track_number} ({track.duration_s / 60:.1f} min, "
                f"RMS {track.residual_rms_m:.0f} m)"
            )
            ax_xy.plot(rows["x"] / 1000, rows["y"] / 1000, lw=1.0, color=colour, label=label)
            speed_kt = np.hypot(rows["vx"], rows["vy"]) * 3600 / NM
            ax_v.plot((rows["time"] - t0) / 60, speed_kt, lw=1.0, color=colour, label=label)
    ax_xy.set_xlabel("x east (km; the radar, at a nominal site, is at 0, 0)")
    ax_xy.set_ylabel("y north (km)")
    ax_xy.set_aspect("equal", adjustable="datalim")
    ax_xy.legend(fontsize=7, loc="best")
    ax_xy.grid(alpha=0.3)
    ax_v.set_xlabel("minutes since the first plot")
    ax_v.set_ylabel("track ground speed (kt)")
    ax_v.grid(alpha=0.3)
    ax_v.legend(fontsize=7, loc="best")
    fig.suptitle(title or f"{run.info.source}: local tracks on real data")
    fig.tight_layout()
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _report(runs: dict[str, CaptureRun]) -> dict[str, Any]:
    doc: dict[str, Any] = {}
    for source, run in runs.items():
        summary, anonymous = summarise(run)
        doc[source] = {
            "scan_period_s": run.tracker_config.scan_period_s,
            "plots": len(run.plots),
            "stats": run.stats,
            "confirmed_tracks_without_address": anonymous,
            "addresses": {
                address: {
                    "plots": entry.plots,
                    "largest_gap_s": round(entry.largest_gap_s, 1),
                    "stretches": len(entry.stretches),
                    "tracks": [
                        {
                            "track_number": t.track_number,
                            "duration_min": round(t.duration_s / 60, 2),
                            "plots": t.plots,
                            "residual_rms_m": round(t.residual_rms_m, 1),
                            "residual_rms_sigma": round(t.residual_rms_sigma, 2),
                        }
                        for t in entry.tracks
                    ],
                }
                for address, entry in summary.items()
            },
        }
    return doc


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tracker_service.evaluation.real_data", description=__doc__
    )
    parser.add_argument("capture", type=Path)
    parser.add_argument("--out", type=Path, help="figure (PNG) of the first radar")
    parser.add_argument("--lat", type=float, default=NOMINAL_SITE_068.lat_deg)
    parser.add_argument("--lon", type=float, default=NOMINAL_SITE_068.lon_deg)
    parser.add_argument("--alt", type=float, default=NOMINAL_SITE_068.alt_m)
    parser.add_argument("--sigma-range", type=float, default=50.0, help="m")
    parser.add_argument("--sigma-azimuth", type=float, default=0.07, help="deg")
    args = parser.parse_args(argv)
    site = RadarSite(args.lat, args.lon, args.alt)
    runs = track_capture(args.capture, site, None, args.sigma_range, args.sigma_azimuth, None)
    print(json.dumps(_report(runs), indent=2))
    if args.out is not None and runs:
        source, run = next(iter(runs.items()))
        plot_figure(run, args.out, f"{args.capture.name} (SAC/SIC {source}): local tracks")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
