"""``evaluate --report DIR``: a Markdown report with PNG figures.

matplotlib is an optional dependency (``pip install -e '.[report]'``): it is imported
here only, so that ``evaluate`` without ``--report`` runs without it. Figures per radar:
tracks over truth (map), position error over time per track, plot and track error
against range, NEES over time.
"""

from __future__ import annotations

import importlib
import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

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


def write_report(evaluation: Evaluation, directory: Path) -> Path:
    """Write ``report.md`` and its figures into ``directory``; returns the report's path."""
    plt = _pyplot()
    directory.mkdir(parents=True, exist_ok=True)
    truth = evaluation.truth
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
        metrics = evaluation.local[source]
        errors = metrics.errors
        name = _safe(source)
        site = radar.info.site
        sx, sy = (float(v) for v in plane.from_geodetic(site.lat_deg, site.lon_deg))
        lines += [f"## Radar {source}", ""]

        # Map: truth in grey, confirmed tracks in colour.
        fig, ax = plt.subplots(figsize=(8, 7))
        for a in range(truth.n_aircraft):
            ax.plot(truth.x[:, a] / KM, truth.y[:, a] / KM, color="0.75", lw=3, zorder=1)
        u = radar.updates
        confirmed = u[u["status"] == 1]
        for number in np.unique(confirmed["track_number"]):
            rows = confirmed[confirmed["track_number"] == number]
            ax.plot(rows["x"] / KM, rows["y"] / KM, ".-", ms=2, lw=0.8, zorder=2)
        ax.plot(sx / KM, sy / KM, "k^", ms=9, label=f"radar {source}")
        ax.set_xlabel("x km (system plane)")
        ax.set_ylabel("y km")
        ax.set_aspect("equal")
        ax.legend(loc="best")
        ax.set_title(f"{source}: confirmed local tracks (colour) over truth (grey)")
        fig.savefig(directory / f"map_{name}.png", dpi=110, bbox_inches="tight")
        plt.close(fig)
        lines += [f"![tracks over truth](map_{name}.png)", ""]

        if errors is not None and errors.time.size:
            t0 = float(errors.time.min())
            fig, ax = plt.subplots(figsize=(9, 4))
            for number in np.unique(errors.track):
                sel = errors.track == number
                ax.plot(errors.time[sel] - t0, np.hypot(errors.dx[sel], errors.dy[sel]), lw=0.7)
            ax.set_xlabel("time s")
            ax.set_ylabel("horizontal position error m")
            ax.set_title(f"{source}: error over time, one line per track")
            fig.savefig(directory / f"error_time_{name}.png", dpi=110, bbox_inches="tight")
            plt.close(fig)

            fig, ax = plt.subplots(figsize=(9, 4))
            plots = evaluation.plots[source]
            if plots.ranges_m is not None and plots.errors_m is not None:
                ax.scatter(plots.ranges_m / KM, plots.errors_m, s=3, c="0.6", label="plots")
            track_range = np.hypot(errors.x - sx, errors.y - sy)
            ax.scatter(track_range / KM, np.hypot(errors.dx, errors.dy), s=3, label="tracks")
            ax.set_xlabel("ground range from the radar km")
            ax.set_ylabel("horizontal position error m")
            ax.legend(loc="upper left")
            ax.set_title(f"{source}: error against range")
            fig.savefig(directory / f"error_range_{name}.png", dpi=110, bbox_inches="tight")
            plt.close(fig)

            fig, ax = plt.subplots(figsize=(9, 4))
            period = radar.info.period_s
            bins = np.floor((errors.time - t0) / period).astype(np.int64)
            ok = np.isfinite(errors.nees2)
            sums = np.bincount(bins[ok], weights=errors.nees2[ok])
            counts = np.bincount(bins[ok])
            used = counts > 0
            centres = (np.flatnonzero(used) + 0.5) * period
            ax.plot(centres, sums[used] / counts[used], ".-", label="mean NEES per scan (dof 2)")
            ax.axhline(2.0, color="k", lw=0.8, label="dof")
            ax.set_xlabel("time s")
            ax.set_ylabel("NEES")
            ax.legend(loc="upper right")
            ax.set_title(f"{source}: NEES of the position over time")
            fig.savefig(directory / f"nees_{name}.png", dpi=110, bbox_inches="tight")
            plt.close(fig)
            lines += [
                f"![error over time](error_time_{name}.png)",
                "",
                f"![error against range](error_range_{name}.png)",
                "",
                f"![NEES over time](nees_{name}.png)",
                "",
            ]
    path = directory / "report.md"
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path
