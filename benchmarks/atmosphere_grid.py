"""Bias honesty and vertical tracking over a grid of atmospheres (issue 14).

For each QNH x ISA deviation x seed: the scenario (default config/scenarios/atmosphere.toml)
flown in that atmosphere (``simulate``), then ``evaluate`` with the atmosphere the
recording gives (what an operator configures) and, with ``--assume isa``, with the
standard atmosphere (what the tracker did before issue 14). Prints one line per run:
each radar's range-offset error (m, and in its reported sigmas), the worst range-gain
error in sigmas, the system RMS, and the worst radar's steady climb-rate error and mean
level-off delay; ``--json FILE`` writes every run's figures.

    .venv/bin/python benchmarks/atmosphere_grid.py --qnh 990 1035 --isa -15 15 --seeds 1
    .venv/bin/python benchmarks/atmosphere_grid.py --qnh 1004 --isa -7 --seeds 1 2 3 4 5 \\
        --assume recording isa
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path
from typing import Any

from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.geodesy import Atmosphere
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[1]


def run_one(
    scenario_path: Path,
    qnh: float,
    isa: float,
    seed: int,
    assume: str,
    out: Path,
    duration: float | None,
) -> dict[str, Any]:
    scenario = load_scenario(scenario_path)
    scenario = scenario.model_copy(
        update={"atmosphere": scenario.atmosphere.model_copy(
            update={"qnh_hpa": qnh, "temperature_offset_k": isa}
        )}
    )  # fmt: skip
    recording = out / f"{scenario.name}_q{qnh:g}_t{isa:+g}_s{seed}.mcap"
    if not recording.exists():
        simulate(scenario, recording, seed=seed, duration_s=duration)
    config = EvaluationConfig(atmosphere=Atmosphere() if assume == "isa" else None)
    started = time.process_time()
    doc = evaluate(recording, config).as_json()
    cpu = time.process_time() - started
    ranges = {}
    worst_gain = 0.0
    for source, bias in doc.get("bias", {}).items():
        offset, gain = bias["range_offset_m"], bias["range_gain"]
        error = offset["estimate"] - offset["truth"]
        ranges[source] = (error, error / offset["sigma"])
        worst_gain = max(worst_gain, abs(gain["estimate"] - gain["truth"]) / gain["sigma"])
    vertical = doc.get("vertical", {})
    steady = [
        v["climb_rate_rms_fpm_steady"] for v in vertical.values() if v["climb_rate_rms_fpm_steady"]
    ]
    p95 = [
        v["climb_rate_p95_fpm_steady"] for v in vertical.values() if v["climb_rate_p95_fpm_steady"]
    ]
    delay = [v["level_off_delay_mean_s"] for v in vertical.values() if v["level_off_delay_mean_s"]]
    return {
        "qnh_hpa": qnh,
        "isa_deviation_k": isa,
        "seed": seed,
        "assume": assume,
        "range_offset_error": ranges,
        "worst_gain_sigmas": worst_gain,
        "system_rms_m": doc.get("system", {}).get("position_rms_m"),
        "climb_rate_rms_fpm_steady_worst": max(steady, default=None),
        "climb_rate_p95_fpm_steady_worst": max(p95, default=None),
        "level_off_delay_mean_s_worst": max(delay, default=None),
        "vertical": vertical,
        "evaluate_cpu_s": cpu,
    }


def line(r: dict[str, Any]) -> str:
    ranges = " ".join(
        f"{s}:{e:+6.1f}m/{z:+4.1f}s" for s, (e, z) in sorted(r["range_offset_error"].items())
    )
    worst_m = max(abs(e) for e, _ in r["range_offset_error"].values())
    worst_z = max(abs(z) for _, z in r["range_offset_error"].values())

    def fmt(value: float | None, digits: int = 0) -> str:
        return "-" if value is None else f"{value:.{digits}f}"

    return (
        f"QNH {r['qnh_hpa']:7.2f} ISA{r['isa_deviation_k']:+5.1f} seed {r['seed']} "
        f"{r['assume']:9s} | {ranges} | worst {worst_m:5.1f} m {worst_z:4.1f} s, gain "
        f"{r['worst_gain_sigmas']:4.1f} s | sys {fmt(r['system_rms_m'], 1)} m | climb rms/p95 "
        f"{fmt(r['climb_rate_rms_fpm_steady_worst'])}/{fmt(r['climb_rate_p95_fpm_steady_worst'])}"
        f" fpm, level-off {fmt(r['level_off_delay_mean_s_worst'], 1)} s"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenario", type=Path, default=REPO / "config/scenarios/atmosphere.toml")
    parser.add_argument("--qnh", type=float, nargs="+", default=[1004.0])
    parser.add_argument("--isa", type=float, nargs="+", default=[-7.0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1])
    parser.add_argument("--assume", nargs="+", choices=["recording", "isa"], default=["recording"])
    parser.add_argument("--duration", type=float, default=None)
    parser.add_argument("--out", type=Path, default=Path("/tmp/atmosphere_grid"))
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    results = []
    for qnh in args.qnh:
        for isa in args.isa:
            for seed in args.seeds:
                for assume in args.assume:
                    r = run_one(args.scenario, qnh, isa, seed, assume, args.out, args.duration)
                    results.append(r)
                    print(line(r), flush=True)
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
