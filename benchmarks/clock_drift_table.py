"""The clock-drift figures of docs/fusion.md "Clock drift" from `evaluate --json` files.

Reads DIR/LABEL_SEED.json for every label and seed (the loop in docs/fusion.md makes
them) and prints per run and radar the drift estimate, its sigma, its error in sigmas and
in % of the truth, when it entered 10 % for good, and the time offset's error; then per
label and radar the spread over the seeds.

    .venv/bin/python benchmarks/clock_drift_table.py /tmp/clk --labels cs2a cs2 cs3 \\
        --seeds 1 2 3 4 5
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any


def rows(doc: dict[str, Any]) -> dict[str, dict[str, float | None]]:
    out = {}
    for source, bias in sorted(doc.get("bias", {}).items()):
        drift = bias.get("time_drift_s_per_h")
        offset = bias["time_s"]
        entry: dict[str, float | None] = {
            "offset_error_ms": 1e3 * (offset["estimate"] - offset["truth"]),
            "offset_sigma_ms": 1e3 * offset["sigma"],
        }
        if drift is not None:
            error = drift["estimate"] - drift["truth"]
            entry |= {
                "drift": drift["estimate"],
                "truth": drift["truth"],
                "sigma": drift["sigma"],
                "sigmas": error / drift["sigma"],
                "percent": 100.0 * abs(error) / abs(drift["truth"]),
                "converged_after_s": drift["converged_after_s"],
            }
        out[source] = entry
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", type=Path)
    parser.add_argument("--labels", nargs="+", required=True)
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    args = parser.parse_args()
    print("| seed | config | radar | drift s/h (truth) | sigma s/h | error/sigma | error % |")
    print("| converged after s | time offset error ms (sigma) |")
    spread: dict[tuple[str, str], list[dict[str, float | None]]] = {}
    for seed in args.seeds:
        for label in args.labels:
            path = args.directory / f"{label}_{seed}.json"
            if not path.exists() or path.stat().st_size == 0:
                continue
            for source, r in rows(json.loads(path.read_text())).items():
                spread.setdefault((label, source), []).append(r)
                if "drift" not in r:
                    print(
                        f"| {seed} | {label} | {source} | - | - | - | - | - | "
                        f"{r['offset_error_ms']:+.1f} ({r['offset_sigma_ms']:.1f}) |"
                    )
                    continue
                after = r["converged_after_s"]
                print(
                    f"| {seed} | {label} | {source} | {r['drift']:+.3f} ({r['truth']:+.1f}) | "
                    f"{r['sigma']:.3f} | {r['sigmas']:+.1f} | {r['percent']:.1f} | "
                    f"{'-' if after is None else f'{after:.0f}'} | "
                    f"{r['offset_error_ms']:+.1f} ({r['offset_sigma_ms']:.1f}) |"
                )
    print()
    for (label, source), runs in sorted(spread.items()):
        offsets = [abs(float(r["offset_error_ms"] or 0.0)) for r in runs]
        text = f"{label} {source}: n {len(runs)}, |time offset error| ms max {max(offsets):.1f}"
        if all("drift" in r for r in runs):
            percent = [float(r["percent"] or 0.0) for r in runs]
            sigmas = [abs(float(r["sigmas"] or 0.0)) for r in runs]
            sigma = [float(r["sigma"] or 0.0) for r in runs]
            after = [r["converged_after_s"] for r in runs]
            met = [a for a in after if a is not None]
            text += (
                f"; drift error % min {min(percent):.1f} max {max(percent):.1f}; "
                f"|error|/sigma max {max(sigmas):.1f}; sigma {min(sigma):.3f}-{max(sigma):.3f} "
                f"s/h; within 10 % for good in {len(met)}/{len(runs)}"
                + (f" after {min(met):.0f}-{max(met):.0f} s" if met else "")
            )
        print(text)


if __name__ == "__main__":
    main()
