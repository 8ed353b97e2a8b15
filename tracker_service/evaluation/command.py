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
from dataclasses import dataclass
from pathlib import Path
from typing import Any

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

__all__ = ["Evaluation", "add_arguments", "evaluate", "main", "run"]

log = logging.getLogger("tracker_service.evaluation")


@dataclass
class Evaluation:
    pipeline: PipelineResult
    truth: Truth
    coverage: dict[str, Coverage]
    plots: dict[str, PlotMetrics]
    local: dict[str, LocalMetrics]

    def as_json(self) -> dict[str, Any]:
        return {
            "plots": {source: m.as_json() for source, m in self.plots.items()},
            "local": {source: m.as_json() for source, m in self.local.items()},
        }


def evaluate(path: str | Path, config: EvaluationConfig | None = None) -> Evaluation:
    """Track a recording's radars and measure plots and local tracks against its truth."""
    config = config or EvaluationConfig()
    result = run_pipeline(path, config)
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
    return Evaluation(result, truth, coverage, plots, local)


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
    rows: list[tuple[str, Callable[[str], str]]] = [
        ("plot RMS m", lambda s: _fmt(evaluation.plots[s].position_rms_m)),
        ("track RMS m", lambda s: _fmt(evaluation.local[s].position_rms_m)),
        ("along RMS m", lambda s: _fmt(evaluation.local[s].along_track_rms_m)),
        ("across RMS m", lambda s: _fmt(evaluation.local[s].across_track_rms_m)),
        ("velocity RMS m/s", lambda s: _fmt(evaluation.local[s].velocity_rms_mps, 2)),
        ("FL RMS ft", lambda s: _fmt(evaluation.local[s].flight_level_rms_ft)),
        ("Pu", lambda s: _fmt(evaluation.local[s].probability_of_update, 3)),
        (
            "Pu with initiation",
            lambda s: _fmt(evaluation.local[s].probability_of_update_with_initiation, 3),
        ),
        ("tracks per aircraft", lambda s: _fmt(evaluation.local[s].tracks_per_aircraft, 3)),
        ("identity changes", lambda s: _fmt(evaluation.local[s].id_changes)),
        ("false tracks", lambda s: _fmt(evaluation.local[s].false_tracks)),
        ("false track max scans", lambda s: _fmt(evaluation.local[s].false_track_max_scans)),
        ("initiation delay s", lambda s: _fmt(evaluation.local[s].initiation_delay_s)),
        ("NEES (dof 2)", lambda s: _fmt(evaluation.local[s].nees_mean, 2)),
        ("NEES (dof 4)", lambda s: _fmt(evaluation.local[s].nees_state_mean, 2)),
        ("confirmed tracks", lambda s: _fmt(evaluation.local[s].confirmed_tracks)),
    ]
    sources = list(evaluation.local)
    width = max(len(name) for name, _ in rows)
    lines = [" " * width + "".join(f"{s:>12}" for s in sources)]
    for name, get in rows:
        lines.append(f"{name:<{width}}" + "".join(f"{get(s):>12}" for s in sources))
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
