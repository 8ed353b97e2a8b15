"""``evaluate --report DIR``: a Markdown report with PNG figures.

matplotlib is an optional dependency (``pip install -e '.[report]'``): it is imported
here only, so that ``evaluate`` without ``--report`` runs without it. Figures per radar
and for the system tracks: tracks over truth (map), position error over time per track,
plot and track error against range (radars), NEES over time; and the bias estimates
converging.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tracker_service.evaluation.metrics import LocalMetrics, PlotMetrics
from tracker_service.evaluation.system_metrics import BIAS_COMPONENTS, truth_biases

if TYPE_CHECKING:
    from tracker_service.evaluation.command import Evaluation

__all__ = ["write_report"]

KM = 1000.0


def _pyplot() -> Any:
    # Imported by name: matplotlib is optional, and mypy must pass where it is absent.
    try:
        matplotlib = importlib.import_module("matplotlib")
    except ImportError as exc:  # pragma: no cover - depends on the installation
        raise ValueError("--report needs matplotlib: pip install -e '.[report]'") from exc
    # No display: render to files only, whatever the environment says.
    matplotlib.use("Agg")
    return importlib.import_module("matplotlib.pyplot")


def _safe(source: str) -> str:
    return source.replace("/", "_")


def _track_figures(
    plt: Any,
    directory: Path,
    evaluation: Evaluation,
    name: str,
    title: str,
    rows: Any,
    metrics: LocalMetrics,
    period: float,
    site_xy: tuple[float, float] | None,
    plots: PlotMetrics | None,
) -> list[str]:
    """Map over truth, error over time, error against range, NEES over time of one set
    of tracks (a radar's local tracks or the system tracks); the Markdown lines."""
    truth = evaluation.truth
    fig, ax = plt.subplots(figsize=(8, 7))
    for a in range(truth.n_aircraft):
        ax.plot(truth.x[:, a] / KM, truth.y[:, a] / KM, color="0.75", lw=3, zorder=1)
    confirmed = rows[rows["status"] == 1]
    for number in np.unique(confirmed["track_number"]):
        track = confirmed[confirmed["track_number"] == number]
        ax.plot(track["x"] / KM, track["y"] / KM, ".-", ms=2, lw=0.8, zorder=2)
    if site_xy is not None:
        ax.plot(site_xy[0] / KM, site_xy[1] / KM, "k^", ms=9, label="radar")
        ax.legend(loc="best")
    ax.set_xlabel("x km (system plane)")
    ax.set_ylabel("y km")
    ax.set_aspect("equal")
    ax.set_title(f"{title} (colour) over truth (grey)")
    fig.savefig(directory / f"map_{name}.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    lines = [f"![tracks over truth](map_{name}.png)", ""]
    errors = metrics.errors
    if errors is None or not errors.time.size:
        return lines

    t0 = float(errors.time.min())
    fig, ax = plt.subplots(figsize=(9, 4))
    for number in np.unique(errors.track):
        sel = errors.track == number
        ax.plot(errors.time[sel] - t0, np.hypot(errors.dx[sel], errors.dy[sel]), lw=0.7)
    ax.set_xlabel("time s")
    ax.set_ylabel("horizontal position error m")
    ax.set_title(f"{title}: error over time, one line per track")
    fig.savefig(directory / f"error_time_{name}.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    lines += [f"![error over time](error_time_{name}.png)", ""]

    if site_xy is not None:
        fig, ax = plt.subplots(figsize=(9, 4))
        if plots is not None and plots.ranges_m is not None and plots.errors_m is not None:
            ax.scatter(plots.ranges_m / KM, plots.errors_m, s=3, c="0.6", label="plots")
        track_range = np.hypot(errors.x - site_xy[0], errors.y - site_xy[1])
        ax.scatter(track_range / KM, np.hypot(errors.dx, errors.dy), s=3, label="tracks")
        ax.set_xlabel("ground range from the radar km")
        ax.set_ylabel("horizontal position error m")
        ax.legend(loc="upper left")
        ax.set_title(f"{title}: error against range")
        fig.savefig(directory / f"error_range_{name}.png", dpi=110, bbox_inches="tight")
        plt.close(fig)
        lines += [f"![error against range](error_range_{name}.png)", ""]

    fig, ax = plt.subplots(figsize=(9, 4))
    bins = np.floor((errors.time - t0) / period).astype(np.int64)
    ok = np.isfinite(errors.nees2)
    sums = np.bincount(bins[ok], weights=errors.nees2[ok])
    counts = np.bincount(bins[ok])
    used = counts > 0
    centres = (np.flatnonzero(used) + 0.5) * period
    ax.plot(centres, sums[used] / counts[used], ".-", label="mean NEES per period (dof 2)")
    ax.axhline(2.0, color="k", lw=0.8, label="dof")
    ax.set_xlabel("time s")
    ax.set_ylabel("NEES")
    ax.legend(loc="upper right")
    ax.set_title(f"{title}: NEES of the position over time")
    fig.savefig(directory / f"nees_{name}.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    lines += [f"![NEES over time](nees_{name}.png)", ""]
    return lines


def _bias_figure(plt: Any, directory: Path, evaluation: Evaluation) -> str:
    """Each radar's estimate minus the truth of each component over time, with its 1-sigma
    band: the estimates converging."""
    history = evaluation.pipeline.bias_history
    truth = truth_biases(evaluation.pipeline.recording)
    t0 = min(t for t, *_ in history)
    scale = np.array([1.0, 1e6, 1.0, 1000.0])
    units = ("range offset m", "range gain ppm", "azimuth deg", "time ms")
    fig, axes = plt.subplots(4, 1, figsize=(9, 11), sharex=True)
    # The prior's first minute would flatten the rest: each axis spans what comes after.
    settled = np.zeros(4)
    for source in sorted({s for _, s, *_ in history}):
        entries = [(t, b, p) for t, s, b, p in history if s == source]
        times = np.array([t for t, _, _ in entries]) - t0
        values = np.array([b for _, b, _ in entries]) * np.array([1, 1, np.degrees(1.0), 1])
        sigmas = np.sqrt(np.array([np.diag(p) for _, _, p in entries])) * np.array(
            [1, 1, np.degrees(1.0), 1]
        )
        true = np.array([truth.get(source, {}).get(name, np.nan) for name in BIAS_COMPONENTS])
        for k, ax in enumerate(axes):
            error = (values[:, k] - true[k]) * scale[k]
            (line,) = ax.plot(times, error, lw=1, label=source)
            band = sigmas[:, k] * scale[k]
            ax.fill_between(times, error - band, error + band, color=line.get_color(), alpha=0.15)
            late = times >= 0.1 * times.max()
            if late.any():
                reach = np.nanmax(np.abs(error[late]) + band[late])
                settled[k] = max(settled[k], float(reach))
    for ax, unit, reach in zip(axes, units, settled, strict=True):
        if reach > 0:
            ax.set_ylim(-2.0 * reach, 2.0 * reach)
        ax.axhline(0.0, color="k", lw=0.6)
        ax.set_ylabel(f"error, {unit}")
    axes[0].legend(loc="upper right")
    axes[0].set_title("bias estimate minus truth, with the reported 1-sigma band")
    axes[-1].set_xlabel("time s")
    fig.savefig(directory / "bias_convergence.png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    return "![bias estimates converging](bias_convergence.png)"


def write_report(evaluation: Evaluation, directory: Path) -> Path:
    """Write ``report.md`` and its figures into ``directory``; returns the report's path."""
    plt = _pyplot()
    directory.mkdir(parents=True, exist_ok=True)
    plane = evaluation.pipeline.plane
    lines = [
        "# Evaluation report",
        "",
        f"Recording: `{evaluation.pipeline.recording.path}`",
        "",
        "Metrics (see `tracker_service/evaluation/metrics.py` for the definitions):",
        "",
        "```json",
        json.dumps(evaluation.as_json(), indent=2, allow_nan=True),
        "```",
        "",
    ]
    for source, radar in evaluation.pipeline.radars.items():
        site = radar.info.site
        sx, sy = (float(v) for v in plane.from_geodetic(site.lat_deg, site.lon_deg))
        lines += [f"## Radar {source}", ""]
        lines += _track_figures(
            plt,
            directory,
            evaluation,
            _safe(source),
            f"{source}: confirmed local tracks",
            radar.updates,
            evaluation.local[source],
            radar.info.period_s,
            (sx, sy),
            evaluation.plots[source],
        )
    if evaluation.system is not None:
        lines += ["## System tracks", ""]
        period = max(radar.info.period_s for radar in evaluation.pipeline.radars.values())
        lines += _track_figures(
            plt,
            directory,
            evaluation,
            "system",
            "system tracks",
            evaluation.system.rows,
            evaluation.system.system,
            period,
            None,
            None,
        )
    if evaluation.pipeline.bias_history:
        lines += ["## Bias estimates", "", _bias_figure(plt, directory, evaluation), ""]
    path = directory / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
