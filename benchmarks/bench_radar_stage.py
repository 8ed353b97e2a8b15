"""CPU time per plot of the radar side alone (``RadarStage.feed``: decode, plot clock and
conversion, local tracking; and the stage message of each datagram with plots, as a radar
process publishes it), as ``bench_stages.py`` times those stages inside the whole
service, without the central stage and the outputs around them (issue 12).

The recording's datagrams (after the replay's duplicate filter) are read into memory, then
fed to a radar stage built as the service builds it (``build_radar_stage``). Each stage's
entry point is wrapped by ``bench_stages.instrumented`` (thread CPU time, nested stages
exclusive); "radar stage" is the CPU time of the whole feed loop, glue included. A first,
untimed run over ``--warmup-seconds`` loads (or compiles) the tracker's numba kernels.
"encoding" is ``stage_messages.encode_message`` of each datagram's result, outside the
radar stage's figure; "digest" the sha256 of every message (its bytes, in order): two
trees that agree publish the same radar batches. ``bench_radar_role.py`` measures the
radar process live (its UDP readers and Zenoh puts too).

    tracker-service simulate config/scenarios/scale.toml -o scale60.mcap --duration 60
    python benchmarks/bench_radar_stage.py scale60.mcap [--seconds 20] [--repeats 3]
        [--json] [--profile FILE]

To compare two trees, run each tree's copy of the code with this script
(``PYTHONPATH=COPY python benchmarks/bench_radar_stage.py ...``), alternated.
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import json
import statistics
import sys
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from bench_stages import StageClock, instrumented, slice_of  # noqa: E402

from tracker_service.service.core import build_radar_stage  # noqa: E402
from tracker_service.stage_messages import DatagramResult, encode_message  # noqa: E402

RADAR_STAGES = ("decode", "clock + conversion", "local tracking")


def run_once(
    replay: Any, datagrams: list[Any], profiler: cProfile.Profile | None = None
) -> tuple[dict[str, float], int, float, str]:
    """One pass of a fresh radar stage over the datagrams: exclusive CPU seconds of the
    three stages, of the rest of the feed ("glue") and of the messages' encoding, plots,
    the feed loop's CPU seconds, and the messages' digest."""
    stage = build_radar_stage(replay.config)
    clock = StageClock()
    digest = hashlib.sha256()
    encoding = 0.0
    with instrumented(clock):
        if profiler is not None:
            profiler.enable()
        started = time.process_time()
        for order, (_name, datagram) in enumerate(datagrams):
            batches = stage.feed(datagram.payload, datagram.time, order)
            if batches:
                encoded = time.process_time()
                result = DatagramResult(
                    order,
                    datagram.time,
                    batches,
                    stage.stats.decode_errors,
                    stage.admission.counts,
                )
                digest.update(encode_message(result))
                encoding += time.process_time() - encoded
        cpu = time.process_time() - started - encoding
        if profiler is not None:
            profiler.disable()
    seconds = {name: clock.seconds[name] for name in RADAR_STAGES}
    seconds["glue"] = cpu - sum(seconds.values())
    seconds["encoding"] = encoding
    return seconds, stage.stats.plots, cpu, digest.hexdigest()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", help="a simulated recording (e.g. of scale)")
    parser.add_argument("--seconds", type=float, default=20.0, help="slice of the recording")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument(
        "--warmup-seconds", type=float, default=5.0, help="slice of the untimed first run"
    )
    parser.add_argument("--json", action="store_true", help="the figures as JSON on stdout")
    parser.add_argument(
        "--profile", metavar="FILE", help="cProfile the timed runs into FILE (pstats)"
    )
    args = parser.parse_args()
    replay, datagrams = slice_of(args.recording, args.seconds)
    warmup_end = datagrams[0][1].time + args.warmup_seconds
    run_once(replay, [d for d in datagrams if d[1].time <= warmup_end])
    profiler = cProfile.Profile(time.thread_time) if args.profile else None
    runs = [run_once(replay, datagrams, profiler) for _ in range(args.repeats)]
    if profiler is not None:
        profiler.dump_stats(args.profile)
    plots = runs[0][1]
    names = [*RADAR_STAGES, "glue", "encoding"]
    digests = {r[3] for r in runs}
    median = {n: statistics.median(r[0][n] for r in runs) for n in names}
    cpu = statistics.median(r[2] for r in runs)
    three = statistics.median(sum(r[0][n] for n in RADAR_STAGES) for r in runs)
    if args.json:
        report = {
            "recording": args.recording,
            "seconds": args.seconds,
            "repeats": args.repeats,
            "plots": plots,
            "cpu_s": cpu,
            "stage_us_per_plot": {n: median[n] / plots * 1e6 for n in names},
            "three_stages_us_per_plot": three / plots * 1e6,
            "radar_stage_us_per_plot": cpu / plots * 1e6,
            "digest": sorted(digests),
        }
        json.dump(report, sys.stdout, indent=1)
        print()
        return
    print(f"{Path(args.recording).name}: first {args.seconds:g} s, {plots:,} plots,")
    print(f"median of {args.repeats} run(s)")
    print(f"{'stage':<20} {'CPU s':>8} {'us/plot':>9}")
    for n in names:
        print(f"{n:<20} {median[n]:>8.3f} {median[n] / plots * 1e6:>9.1f}")
    print(f"{'three stages':<20} {three:>8.3f} {three / plots * 1e6:>9.1f}")
    print(f"{'radar stage':<20} {cpu:>8.3f} {cpu / plots * 1e6:>9.1f}")
    print(f"plots per CPU-second (radar stage): {plots / cpu:,.0f}")
    print(f"messages' digest: {', '.join(sorted(digests))}")


if __name__ == "__main__":
    main()
