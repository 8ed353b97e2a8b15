"""Bias estimation compared on one recording with systematic errors (issue 5's table).

Runs ``evaluate`` on the recording with: no bias estimation, each of Blom's three
variants (separated, macro, coupled) and the true biases given (the upper bound: method
"off" with every radar a reference at its ``/truth/biases`` values). For each: the
system-track position RMS (multi- and single-radar coverage), the fusion ratio, the
system tracks per aircraft, the NEES, each radar's bias errors and the CPU time per plot.

    tracker-service simulate config/scenarios/three_sites.toml -o three_sites.mcap
    python benchmarks/compare_bias.py three_sites.mcap > table.md
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from typing import Any

from tracker_service.bias import BiasConfig
from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.evaluation.system_metrics import truth_biases
from tracker_service.simulator.recording import read_recording


def _true_biases(path: str) -> BiasConfig:
    recording = read_recording(path)
    sources = sorted(recording.metadata["radars"], key=lambda s: tuple(map(int, s.split("/"))))
    truth = truth_biases(recording)
    references = {
        k: (
            truth[s]["range_offset_m"],
            truth[s]["range_gain"],
            truth[s]["azimuth_deg"],
            truth[s]["time_s"],
        )
        for k, s in enumerate(sources)
        if s in truth
    }
    return BiasConfig(method="off", reference_radars=references)


def _fmt(value: Any, digits: int) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value:.{digits}f}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording")
    parser.add_argument("--skip", nargs="*", default=[], help="variants to leave out")
    args = parser.parse_args()
    variants = {
        "no bias estimation": BiasConfig(method="off"),
        "separated (variant 3, default)": BiasConfig(method="separated"),
        "macro (variant 2)": BiasConfig(method="macro"),
        "coupled (variant 1)": BiasConfig(method="coupled"),
        "true biases given": _true_biases(args.recording),
    }
    print(
        "| bias estimation | system RMS multi m | system RMS single m | RMS / best local "
        "| system tracks per aircraft | NEES (dof 2) | radar | range offset error m "
        "| range gain error | azimuth error deg | time error ms | CPU us per plot |"
    )
    print("|" + " --- |" * 12)
    for name, bias in variants.items():
        if any(word in name for word in args.skip):
            continue
        start = time.process_time()
        evaluation = evaluate(args.recording, EvaluationConfig(bias=bias))
        cpu = time.process_time() - start
        doc = evaluation.as_json()
        plots = sum(len(run.plots) for run in evaluation.pipeline.radars.values())
        multi, single = doc["system_by_coverage"]["multi"], doc["system_by_coverage"]["single"]
        first = True
        for source, components in (doc.get("bias") or {"-": {}}).items():
            errors = {
                key: (v["estimate"] - v["truth"]) if v.get("truth") is not None else None
                for key, v in components.items()
            }
            head = (
                [
                    name,
                    _fmt(multi["position_rms_m"], 1),
                    _fmt(single["position_rms_m"], 1),
                    _fmt(doc["fusion"]["rms_ratio_to_best_local"], 3),
                    _fmt(doc["system"]["tracks_per_aircraft"], 3),
                    _fmt(doc["system"]["nees_mean"], 2),
                ]
                if first
                else [""] * 6
            )
            time_error = errors.get("time_s")
            row = [
                *head,
                source,
                _fmt(errors.get("range_offset_m"), 1),
                _fmt(errors.get("range_gain"), 6),
                _fmt(errors.get("azimuth_deg"), 4),
                _fmt(None if time_error is None else 1000 * time_error, 0),
                _fmt(1e6 * cpu / plots, 0) if first else "",
            ]
            print("| " + " | ".join(row) + " |")
            first = False
        sys.stdout.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
