"""Association over seeds: identity swaps per encounter type and associator, track breaks,
tracks per aircraft, RMS and false tracks on `encounters`; RMS on `three_sites`; CPU per
plot on `tma` (issue 13, figures in docs/association.md).

Each seed simulates `encounters` once (config/scenarios/encounters.toml, with the seed
given) and tracks it with every associator. An encounter's swaps are the identity changes
(``evaluation.metrics``: a change between two kept identity runs of one track) of the
confirmed local tracks of its aircraft, over the three radars, and of the system tracks;
the rate is per encounter and radar (local) or per encounter (system).

    python benchmarks/bench_association.py --seeds 20 [--first-seed 1] [--associators gnn jpda]
        [--tma tma.mcap] [--three-sites three_sites.mcap] [--json out.json]
    python benchmarks/bench_association.py --summarise a.json b.json   (seeds run apart;
        the associators of one seed may come from different files: joined by seed)

CPU per plot is the process time spent in ``LocalTracker.process`` (process time, not
wall time: the benchmark machine is shared) over the plots fed.
"""

from __future__ import annotations

import argparse
import itertools
import json
import statistics
import tempfile
import time
import tomllib
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.evaluation.command import Evaluation, evaluate
from tracker_service.evaluation.metrics import (
    PlotOrigins,
    Truth,
    associate_updates,
    identity_runs,
)
from tracker_service.evaluation.pipeline import EvaluationConfig
from tracker_service.evaluation.system_metrics import as_track_rows
from tracker_service.simulator.run import simulate
from tracker_service.simulator.scenario import load_scenario
from tracker_service.tracking import CONFIRMED, LocalTracker, TrackerConfig

ROOT = Path(__file__).resolve().parent.parent
ENCOUNTERS = ROOT / "config" / "scenarios" / "encounters.toml"
TRANSPONDERS = {"S": "mode_s", "C": "mode_ac", "P": "primary"}
ONE_KM = {"PAR10", "OPP", "PARAB", "ABR3", "CLIMB"}
"""The encounter types whose aircraft pass 1 km apart (the issue's 1 km target)."""


class TimedTracker(LocalTracker):
    """A LocalTracker that adds up the process time spent in ``process``."""

    def __init__(self, config: TrackerConfig) -> None:
        super().__init__(config)
        self.seconds, self.plots = 0.0, 0

    def process(self, plots: Any) -> npt.NDArray[Any]:
        started = time.process_time()
        out = super().process(plots)
        self.seconds += time.process_time() - started
        self.plots += len(plots)
        return out


FUSION: dict[str, float] = {}
"""``[fusion]`` settings of every run (``--fusion key=value``)."""


def timed_evaluation(path: Path, association: str) -> tuple[Evaluation, float]:
    """The evaluation of a recording with one associator, and its CPU per plot (s)."""
    trackers: list[TimedTracker] = []

    def make(source: str, config: TrackerConfig) -> LocalTracker:
        trackers.append(TimedTracker(config))
        return trackers[-1]

    config = EvaluationConfig.from_mapping(
        {"tracker": {"association": association}, "fusion": FUSION}
    )
    result = evaluate(path, config, make)
    plots = sum(t.plots for t in trackers)
    return result, sum(t.seconds for t in trackers) / max(plots, 1)


def encounter_of(callsigns: list[str]) -> list[tuple[str, str]]:
    """(encounter type, transponder) of each aircraft, from its callsign: type, the
    transponder letter, the aircraft letter."""
    return [(c[:-2], TRANSPONDERS[c[-2]]) for c in callsigns]


def swaps_by_encounter(
    updates: npt.NDArray[Any],
    origins: PlotOrigins,
    truth: Truth,
    groups: list[tuple[str, str]],
) -> tuple[dict[tuple[str, str], int], dict[tuple[str, str], list[int]]]:
    """Per (type, transponder): identity changes of the confirmed tracks, each counted
    for the aircraft the track held before the change; and per aircraft of the group
    the number of tracks that held it (kept identity runs of confirmed tracks)."""
    labels = associate_updates(updates, origins, truth, 1000.0)
    runs = identity_runs(updates, labels, 2)
    confirmed = set(updates["track_number"][updates["status"] == CONFIRMED].tolist())
    swaps: dict[tuple[str, str], int] = defaultdict(int)
    holders: dict[int, set[int]] = defaultdict(set)
    for number in confirmed:
        kept = [r for r in runs.get(number, []) if r.aircraft >= 0]
        for r in kept:
            holders[r.aircraft].add(number)
        for r0, r1 in itertools.pairwise(kept):
            if r0.aircraft != r1.aircraft:
                swaps[groups[r0.aircraft]] += 1
    tracks: dict[tuple[str, str], list[int]] = defaultdict(list)
    for aircraft, group in enumerate(groups):
        tracks[group].append(len(holders.get(aircraft, ())))
    return swaps, tracks


def encounter_seed(seed: int, associators: list[str], workdir: Path) -> dict[str, Any]:
    scenario = load_scenario(ENCOUNTERS)
    path = workdir / f"encounters_{seed}.mcap"
    simulate(scenario, path, seed=seed)
    callsigns = [a["callsign"] for a in tomllib.loads(ENCOUNTERS.read_text())["aircraft"]]
    groups = encounter_of(callsigns)
    out: dict[str, Any] = {}
    for name in associators:
        ev, cpu = timed_evaluation(path, name)
        local_swaps: dict[tuple[str, str], int] = defaultdict(int)
        local_tracks: dict[tuple[str, str], list[int]] = defaultdict(list)
        for source, run in ev.pipeline.radars.items():
            s, t = swaps_by_encounter(
                run.updates, PlotOrigins.from_plots(run.plots), ev.truth, groups
            )
            for g, v in s.items():
                local_swaps[g] += v
            for g, v in t.items():
                local_tracks[g] += v
            del source
        every_plot = np.concatenate([r.plots for r in ev.pipeline.radars.values()])
        system_swaps, system_tracks = swaps_by_encounter(
            as_track_rows(ev.pipeline.system), PlotOrigins.from_plots(every_plot), ev.truth, groups
        )
        out[name] = {
            "cpu_us_per_plot": cpu * 1e6,
            "local_swaps": {"/".join(g): v for g, v in local_swaps.items()},
            "local_tracks": {"/".join(g): v for g, v in local_tracks.items()},
            "system_swaps": {"/".join(g): v for g, v in system_swaps.items()},
            "system_tracks": {"/".join(g): v for g, v in system_tracks.items()},
            "local": {s: m.as_json() for s, m in ev.local.items()},
            "system": None if ev.system is None else ev.system.system.as_json(),
        }
    path.unlink()
    return out


def recording_figures(path: Path, associators: list[str]) -> dict[str, Any]:
    out = {}
    for name in associators:
        ev, cpu = timed_evaluation(path, name)
        out[name] = {
            "cpu_us_per_plot": cpu * 1e6,
            "local": {s: m.as_json() for s, m in ev.local.items()},
            "system": None if ev.system is None else ev.system.system.as_json(),
        }
    return out


def _spread(values: list[float]) -> str:
    if not values:
        return "-"
    if len(values) == 1:
        return f"{values[0]:.3f}"
    return f"{statistics.mean(values):.3f} (sd {statistics.stdev(values):.3f})"


def summarise(seeds: list[dict[str, Any]], associators: list[str]) -> str:
    """Markdown tables: swaps per encounter (local per radar, system), tracks per aircraft,
    then the run-wide metrics."""
    lines = []
    n = len(seeds)
    keys = sorted({g for s in seeds for a in associators for g in s[a]["local_tracks"]})
    head = " | ".join(f"{a} local | {a} system" for a in associators)
    lines.append(f"Identity swaps per encounter ({n} seeds; local: per encounter and radar)\n")
    lines.append(f"| encounter | {head} |")
    lines.append("|---" * (1 + 2 * len(associators)) + "|")
    for g in keys:
        cells = []
        for a in associators:
            local = sum(s[a]["local_swaps"].get(g, 0) for s in seeds) / (3 * n)
            system = sum(s[a]["system_swaps"].get(g, 0) for s in seeds) / n
            cells.append(f"{local:.3f} | {system:.3f}")
        lines.append(f"| {g} | {' | '.join(cells)} |")
    lines.append("")
    lines.append("By transponder: every encounter type, and the 1 km ones (PAR10, OPP, PARAB,")
    lines.append("ABR3, CLIMB)\n")
    lines.append(f"| transponder, types | {head} |")
    lines.append("|---" * (1 + 2 * len(associators)) + "|")
    for transponder in TRANSPONDERS.values():
        for label, types in (("all", None), ("1 km", ONE_KM)):
            chosen = [
                g
                for g in keys
                if g.endswith(transponder) and (types is None or g.split("/")[0] in types)
            ]
            cells = []
            for a in associators:
                local = sum(s[a]["local_swaps"].get(g, 0) for s in seeds for g in chosen)
                system = sum(s[a]["system_swaps"].get(g, 0) for s in seeds for g in chosen)
                count = len(chosen) * n
                cells.append(f"{local / (3 * count):.3f} | {system / count:.3f}")
            lines.append(f"| {transponder}, {label} | {' | '.join(cells)} |")
    lines.append("")
    lines.append(f"Tracks per aircraft ({n} seeds; local over the three radars)\n")
    head = " | ".join(f"{a} local | {a} system" for a in associators)
    lines.append(f"| encounter | {head} |")
    lines.append("|---" * (1 + 2 * len(associators)) + "|")
    for g in keys:
        cells = []
        for a in associators:
            local = [v for s in seeds for v in s[a]["local_tracks"].get(g, [])]
            system = [v for s in seeds for v in s[a]["system_tracks"].get(g, [])]
            cells.append(f"{np.mean(local):.3f} | {np.mean(system):.3f}")
        lines.append(f"| {g} | {' | '.join(cells)} |")
    lines.append("")
    lines.append("Run-wide, mean (sd) over seeds\n")
    lines.append("| metric | " + " | ".join(associators) + " |")
    lines.append("|---" * (1 + len(associators)) + "|")
    metrics = {
        "local position RMS m": lambda r: [m["position_rms_m"] for m in r["local"].values()],
        "local tracks per aircraft": lambda r: [
            m["tracks_per_aircraft"] for m in r["local"].values()
        ],
        "local identity changes": lambda r: [
            float(sum(m["id_changes"] for m in r["local"].values()))
        ],
        "local false tracks": lambda r: [
            float(sum(m["false_tracks"] for m in r["local"].values()))
        ],
        "system position RMS m": lambda r: [r["system"]["position_rms_m"]],
        "system tracks per aircraft": lambda r: [r["system"]["tracks_per_aircraft"]],
        "system identity changes": lambda r: [float(r["system"]["id_changes"])],
        "CPU us per plot": lambda r: [r["cpu_us_per_plot"]],
    }
    for label, get in metrics.items():
        cells = [
            _spread([v for s in seeds for v in get(s[a]) if v is not None]) for a in associators
        ]
        lines.append(f"| {label} | {' | '.join(cells)} |")
    return "\n".join(lines)


def merged_seeds(paths: list[Path], associators: list[str]) -> list[dict[str, Any]]:
    """The seeds of several --json files, the associators of one seed run apart joined
    by its number; only the seeds every associator ran (so the comparison is paired)."""
    by_seed: dict[int, dict[str, Any]] = defaultdict(dict)
    for path in paths:
        for entry in json.loads(path.read_text())["seeds"]:
            by_seed[entry["seed"]].update(entry)
    kept = sorted(s for s, e in by_seed.items() if all(a in e for a in associators))
    print(f"seeds {kept}\n")
    return [by_seed[s] for s in kept]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--first-seed", type=int, default=1)
    parser.add_argument("--associators", nargs="+", default=["gnn", "jpda"])
    parser.add_argument("--tma", type=Path, help="a tma recording: CPU per plot, false tracks")
    parser.add_argument("--three-sites", type=Path, help="a three_sites recording: RMS")
    parser.add_argument("--json", type=Path, help="write every figure here")
    parser.add_argument(
        "--fusion", nargs="*", default=[], help="[fusion] settings, key=value (numbers)"
    )
    parser.add_argument(
        "--summarise",
        type=Path,
        nargs="+",
        help="only print the tables of these --json files' seeds together (runs in parallel)",
    )
    args = parser.parse_args()
    FUSION.update({k: float(v) for k, v in (kv.split("=") for kv in args.fusion)})
    if args.summarise:
        print(summarise(merged_seeds(args.summarise, args.associators), args.associators))
        return
    doc: dict[str, Any] = {"seeds": []}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in range(args.first_seed, args.first_seed + args.seeds):
            started = time.perf_counter()
            doc["seeds"].append({"seed": seed, **encounter_seed(seed, args.associators, Path(tmp))})
            print(f"seed {seed}: {time.perf_counter() - started:.0f} s", flush=True)
            if args.json:
                args.json.write_text(json.dumps(doc, indent=1))
    if doc["seeds"]:
        print(summarise(doc["seeds"], args.associators))
    for key, path in (("tma", args.tma), ("three_sites", args.three_sites)):
        if path is None:
            continue
        doc[key] = recording_figures(path, args.associators)
        print(f"\n{key}:")
        for a, r in doc[key].items():
            local = r["local"]
            rms = {s: round(m["position_rms_m"], 1) for s, m in local.items()}
            false = {
                s: (m["false_tracks"], round(m["false_track_max_scans"], 1))
                for s, m in local.items()
            }
            system = r["system"] or {}
            print(
                f"{a}: CPU {r['cpu_us_per_plot']:.1f} us/plot, local RMS {rms}, "
                f"false tracks (count, longest scans) {false}, "
                f"system RMS {system.get('position_rms_m')}"
            )
    if args.json:
        args.json.write_text(json.dumps(doc, indent=1))


if __name__ == "__main__":
    main()
