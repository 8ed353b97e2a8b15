"""Trace one encounter of `encounters`, update by update: which aircraft each local and
system track's rows carry, and which local tracks fed each system row (issue 13's swaps,
docs/association.md "Session 9").

    python benchmarks/trace_encounter.py --seed 10 --group ABR3P [X15P ...]
        [--association mht] [--fusion join_ambiguity_margin=4] [--cache DIR]

A group is an encounter type and its transponder letter (ABR3P: three abreast, primary
only). Per radar, each local track that held one of the group's aircraft, as one
character per row: the aircraft's letter (A, B, C) of the row's plot, ``-`` a row
without a plot, ``?`` another aircraft, ``.`` no aircraft. Per system track, one line per
row with a plot: time, the radar whose batch made it, the aircraft, the feeding local
tracks (radar:number, most recent first). The evaluation is kept in ``--cache``
(pickle) so that several groups of one seed cost one run.
"""

from __future__ import annotations

import argparse
import pickle
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.command import evaluate
from tracker_service.evaluation.metrics import PlotOrigins, Truth, associate_updates
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.evaluation.system_metrics import as_track_rows
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario

ROOT = Path(__file__).resolve().parent.parent
ENCOUNTERS = ROOT / "config" / "scenarios" / "encounters.toml"

Run = tuple[
    dict[str, tuple[npt.NDArray[Any], npt.NDArray[Any]]], npt.NDArray[Any], list[str], Truth
]


def run(seed: int, association: str, fusion: dict[str, float], cache: Path) -> Run:
    """Per radar (updates, plots), the system rows, the radars in fusion order, truth."""
    settings = "".join(f"_{k}={v:g}" for k, v in sorted(fusion.items()))
    kept = cache / f"trace_{seed}_{association}{settings}.pkl"
    if kept.exists():
        result: Run = pickle.loads(kept.read_bytes())
        return result
    recording = cache / f"encounters_{seed}.mcap"
    if not recording.exists():
        simulate(load_scenario(ENCOUNTERS), recording, seed=seed)
    config = EvaluationConfig.from_mapping(
        {"tracker": {"association": association}, "fusion": fusion}
    )
    ev = evaluate(recording, config)
    radars = {s: (r.updates, r.plots) for s, r in ev.pipeline.radars.items()}
    result = (radars, ev.pipeline.system, ev.pipeline.sources, ev.truth)
    kept.write_bytes(pickle.dumps(result))
    return result


def letter(label: int, letters: dict[int, str]) -> str:
    return letters.get(label, "?" if label >= 0 else ".")


def trace(result: Run, group: str, callsigns: list[str]) -> list[str]:
    radars, system, sources, truth = result
    aircraft = [i for i, c in enumerate(callsigns) if c[:-1] == group]
    letters = {a: callsigns[a][-1] for a in aircraft}
    lines = [f"=== {group}: {[callsigns[a] for a in aircraft]}"]
    for source, (updates, plots) in radars.items():
        labels = associate_updates(updates, PlotOrigins.from_plots(plots), truth, 1000.0)
        lines.append(f"--- radar {source}")
        for number in np.unique(updates["track_number"][np.isin(labels, aircraft)]).tolist():
            rows = np.flatnonzero(updates["track_number"] == number)
            text = "".join(
                letter(int(labels[r]), letters) if updates["plot_id"][r] >= 0 else "-"
                for r in rows.tolist()
            )
            start = float(updates["time"][rows[0]])
            lines.append(f"  local {number} from {start:.0f}: {text}")
    plots = np.concatenate([p for _, p in radars.values()])
    rows_view = as_track_rows(system)
    labels = associate_updates(rows_view, PlotOrigins.from_plots(plots), truth, 1000.0)
    lines.append("--- system")
    for number in np.unique(rows_view["track_number"][np.isin(labels, aircraft)]).tolist():
        lines.append(f"  system {number}:")
        for r in np.flatnonzero(rows_view["track_number"] == number).tolist():
            if rows_view["plot_id"][r] < 0:
                continue
            feeders = ",".join(
                f"{sources[int(system['local_radars'][r][k])]}:{int(system['local_numbers'][r][k])}"
                for k in range(int(system["n_sources"][r]))
            )
            made_by = sources[int(system["radar"][r])]
            held = letter(int(labels[r]), letters)
            lines.append(f"    {system['time'][r]:.0f} {made_by} {held} [{feeders}]")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seed", type=int, required=True)
    parser.add_argument("--group", nargs="+", required=True, help="type + transponder: ABR3P")
    parser.add_argument("--association", default="mht")
    parser.add_argument("--fusion", nargs="*", default=[], help="[fusion] settings, key=value")
    parser.add_argument("--cache", type=Path, default=Path("/tmp"))
    args = parser.parse_args()
    fusion = {k: float(v) for k, v in (kv.split("=") for kv in args.fusion)}
    callsigns = [a["callsign"] for a in tomllib.loads(ENCOUNTERS.read_text())["aircraft"]]
    result = run(args.seed, args.association, fusion, args.cache)
    for group in args.group:
        print("\n".join(trace(result, group, callsigns)))


if __name__ == "__main__":
    main()
