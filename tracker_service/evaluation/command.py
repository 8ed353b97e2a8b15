"""``tracker-service evaluate RECORDING [--json] [--report DIR] [--config FILE]``.

The CLI wiring lives in ``tracker_service/cli.py``: it calls ``add_arguments`` on the
subcommand's parser and ``run`` with the parsed arguments. ``main`` runs it standalone
(``python -m tracker_service.evaluation.command``).

``--json`` prints one object on stdout (logs go to stderr):
``{"plots": {"<SAC>/<SIC>": {"position_rms_m", ...}}, "local": {"<SAC>/<SIC>": {...}}}``
with the keys of issue 4 first, then extra ones (flight level error, initiation delay,
the 4-dof NEES, counts). A metric without data is ``null``.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import tomllib
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from tracker_service.evaluation.adsb_cover import adsb_cover_from_recording
from tracker_service.evaluation.manoeuvres import ManoeuvreMetrics, manoeuvre_metrics
from tracker_service.evaluation.metrics import (
    Coverage,
    LocalMetrics,
    PlotMetrics,
    PlotOrigins,
    Truth,
    coverage_from_recording,
    local_metrics,
    plot_metrics,
    truth_from_recording,
)
from tracker_service.evaluation.pipeline import EvaluationConfig, PipelineResult, run_pipeline
from tracker_service.evaluation.system_metrics import (
    SystemEvaluation,
    bias_metrics,
    clock_metrics,
    system_metrics,
    truth_biases,
)
from tracker_service.evaluation.vertical_metrics import vertical_metrics
from tracker_service.tracking import LocalTracker, TrackerConfig
from tracker_service.tracking.models import ModelSet

__all__ = ["Evaluation", "add_arguments", "evaluate", "main", "run"]

log = logging.getLogger("tracker_service.evaluation")


@dataclass
class Evaluation:
    pipeline: PipelineResult
    truth: Truth
    coverage: dict[str, Coverage]
    plots: dict[str, PlotMetrics]
    local: dict[str, LocalMetrics]
    system: SystemEvaluation | None
    bias: dict[str, dict[str, dict[str, float | None]]]
    vertical: dict[str, dict[str, float | int | None]] = field(default_factory=dict)
    """Per radar, ``vertical_metrics.vertical_metrics``."""
    manoeuvres: dict[str, ManoeuvreMetrics] = field(default_factory=dict)

    def as_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {
            "plots": {source: m.as_json() for source, m in self.plots.items()},
            "local": {source: m.as_json() for source, m in self.local.items()},
        }
        if self.system is not None:
            doc["system"] = self.system.system.as_json()
            doc["system_by_coverage"] = {
                "multi": self.system.multi.as_json(),
                "single": self.system.single.as_json(),
            }
            for key in ("adsb_only", "radar_and_adsb"):
                metrics = getattr(self.system, key)
                if metrics is not None:
                    doc["system_by_coverage"][key] = metrics.as_json()
            doc["fusion"] = {
                "rms_ratio_to_best_local": self.system.rms_ratio_to_best_local,
                "rms_ratio_to_best_local_own_updates": (
                    self.system.rms_ratio_to_best_local_own_updates
                ),
            }
        if self.bias:
            doc["bias"] = self.bias
        if self.vertical:
            doc["vertical"] = self.vertical
        if self.manoeuvres:
            doc["manoeuvres"] = {source: m.as_json() for source, m in self.manoeuvres.items()}
        return doc


def evaluate(
    path: str | Path,
    config: EvaluationConfig | None = None,
    make_tracker: Callable[[str, TrackerConfig], LocalTracker] | None = None,
) -> Evaluation:
    """Track a recording's radars and measure plots and local tracks against its truth.
    ``make_tracker``: as for ``run_pipeline`` (a benchmark times the trackers)."""
    config = config or EvaluationConfig()
    result = run_pipeline(path, config, make_tracker)
    truth = truth_from_recording(result.recording, result.plane)
    periods = {source: run.info.period_s for source, run in result.radars.items()}
    coverage = coverage_from_recording(result.recording, periods)
    plots: dict[str, PlotMetrics] = {}
    local: dict[str, LocalMetrics] = {}
    for source, radar in result.radars.items():
        site = radar.info.site
        sx, sy = result.plane.from_geodetic(site.lat_deg, site.lon_deg)
        plots[source] = plot_metrics(radar.plots, truth, (float(sx), float(sy)))
        end = float(radar.plots["time"].max()) if len(radar.plots) else None
        local[source] = local_metrics(
            radar.updates,
            PlotOrigins.from_plots(radar.plots),
            truth,
            coverage.get(source),
            gate_m=config.association_gate_m,
            min_identity_updates=config.min_identity_updates,
            end_time=end,
        )
    manoeuvres = {
        source: manoeuvre_metrics(
            radar.updates,
            PlotOrigins.from_plots(radar.plots),
            truth,
            local[source],
            ModelSet.from_config(radar.tracker_config).turn_rates_rad_s,
            radar.info.period_s,
            config.association_gate_m,
        )
        for source, radar in result.radars.items()
    }
    system = None
    if len(result.system):
        every_plot = np.concatenate([radar.plots for radar in result.radars.values()])
        system = system_metrics(
            result.system,
            PlotOrigins.from_plots(every_plot),
            truth,
            coverage,
            {
                source: (radar.updates, PlotOrigins.from_plots(radar.plots))
                for source, radar in result.radars.items()
            },
            gate_m=config.association_gate_m,
            min_identity_updates=config.min_identity_updates,
            end_time=float(every_plot["time"].max()),
            adsb=adsb_cover_from_recording(result.recording),
        )
    true_biases = truth_biases(result.recording)
    bias = bias_metrics(result.bias, true_biases)
    for source, entries in clock_metrics(result.clock, result.clock_history, true_biases).items():
        bias.setdefault(source, {}).update(entries)
    vertical = {
        source: vertical_metrics(
            radar.updates,
            PlotOrigins.from_plots(radar.plots),
            truth,
            gate_m=config.association_gate_m,
        )
        for source, radar in result.radars.items()
    }
    return Evaluation(result, truth, coverage, plots, local, system, bias, vertical, manoeuvres)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="an MCAP recording with truth (tracker-service simulate)")
    parser.add_argument(
        "--json", action="store_true", help="print one JSON object of metrics on stdout"
    )
    parser.add_argument(
        "--report", metavar="DIR", help="write a Markdown report with PNG figures into DIR"
    )
    parser.add_argument(
        "--config",
        metavar="FILE",
        help="TOML overrides: [evaluation] geoid_m, association_gate_m; [tracker] "
        'TrackerConfig fields; [radars."SAC/SIC"] site and sigma fields',
    )


def _clean(value: Any) -> Any:
    """JSON has no NaN or infinity: a metric that is not a number is null."""
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    return value


def _fmt(value: Any, digits: int = 1) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        return f"{value:.{digits}f}"
    return str(value)


def format_table(evaluation: Evaluation) -> str:
    """The metrics as text: one column per radar's local tracks, then, once system tracks
    exist, one per coverage class of the system tracks."""
    columns: dict[str, LocalMetrics] = dict(evaluation.local)
    plots = {s: _fmt(m.position_rms_m) for s, m in evaluation.plots.items()}
    if evaluation.system is not None:
        columns["system"] = evaluation.system.system
        columns["sys multi"] = evaluation.system.multi
        columns["sys single"] = evaluation.system.single
    text = _metrics_table(columns, plots)
    if evaluation.system is not None:
        ratio = _fmt(evaluation.system.rms_ratio_to_best_local, 3)
        text += f"\nsystem RMS / best local RMS (multi-radar coverage): {ratio}"
    for source, components in evaluation.bias.items():
        parts = [
            f"{name} {_fmt(v['estimate'], 5)} (truth {_fmt(v['truth'], 5)}, sigma "
            f"{_fmt(v['sigma'], 5)})"
            for name, v in components.items()
        ]
        text += f"\nbias {source}: " + "; ".join(parts)
    return text


def _metrics_table(columns: dict[str, LocalMetrics], plots: dict[str, str]) -> str:
    rows: list[tuple[str, Callable[[LocalMetrics], str]]] = [
        ("track RMS m", lambda m: _fmt(m.position_rms_m)),
        ("along RMS m", lambda m: _fmt(m.along_track_rms_m)),
        ("across RMS m", lambda m: _fmt(m.across_track_rms_m)),
        ("velocity RMS m/s", lambda m: _fmt(m.velocity_rms_mps, 2)),
        ("FL RMS ft", lambda m: _fmt(m.flight_level_rms_ft)),
        ("Pu", lambda m: _fmt(m.probability_of_update, 3)),
        (
            "Pu with initiation",
            lambda m: _fmt(m.probability_of_update_with_initiation, 3),
        ),
        ("tracks per aircraft", lambda m: _fmt(m.tracks_per_aircraft, 3)),
        ("identity changes", lambda m: _fmt(m.id_changes)),
        ("false tracks", lambda m: _fmt(m.false_tracks)),
        ("false track max scans", lambda m: _fmt(m.false_track_max_scans)),
        ("initiation delay s", lambda m: _fmt(m.initiation_delay_s)),
        ("NEES (dof 2)", lambda m: _fmt(m.nees_mean, 2)),
        ("NEES (dof 4)", lambda m: _fmt(m.nees_state_mean, 2)),
        ("confirmed tracks", lambda m: _fmt(m.confirmed_tracks)),
    ]
    width = max(len(name) for name, _ in rows)
    lines = [" " * width + "".join(f"{s:>12}" for s in columns)]
    lines.append(f"{'plot RMS m':<{width}}" + "".join(f"{plots.get(s, '-'):>12}" for s in columns))
    for name, get in rows:
        lines.append(f"{name:<{width}}" + "".join(f"{get(m):>12}" for m in columns.values()))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    prog = "tracker-service evaluate"
    try:
        config = EvaluationConfig()
        if args.config:
            with open(args.config, "rb") as stream:
                config = EvaluationConfig.from_mapping(tomllib.load(stream))
        evaluation = evaluate(args.recording, config)
    except (OSError, ValueError, TypeError, tomllib.TOMLDecodeError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    if args.json:
        json.dump(_clean(evaluation.as_json()), sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_table(evaluation))
    if args.report:
        from tracker_service.evaluation.report import write_report

        path = write_report(evaluation, Path(args.report))
        log.info("report written to %s", path)
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="tracker-service evaluate",
        description="Track a recording with truth and measure the tracks against it.",
    )
    add_arguments(parser)
    args = parser.parse_args(argv)
    if not logging.getLogger().handlers:
        logging.basicConfig(stream=sys.stderr, level=logging.INFO, format="%(message)s")
    return run(args)


if __name__ == "__main__":
    sys.exit(main())
