"""What the Foxglove map channels cost the log's output thread: per system-track update
(a ``foxglove.LocationFix``) and per picture (a ``foxglove.GeoJSON`` of every track), for
a picture of N live tracks with full trails.

    python benchmarks/bench_foxglove.py [--tracks 2000] [--repeats 5] [--json]

Prints the median microseconds per update, milliseconds (a quarter of the tracks moved
since the last) and kilobytes per picture, and the share of one core the scene takes at
one update per track per 4 s scan and one picture a second.
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import time

from tracker_service.outputs.foxglove_scene import MapRadar, MapScene
from tracker_service.outputs.messages import SystemTrackMessage, TrackSource
from tracker_service.outputs.updates import SystemBatch, SystemValues

T0 = 1_780_300_000.0
SCAN_S = 4.0
BATCH = 25


def message(number: int, t: float) -> SystemTrackMessage:
    angle = 2 * math.pi * number / 997
    return SystemTrackMessage.from_state(
        time=t,
        x_m=0.0,
        y_m=0.0,
        vx_mps=200.0 * math.sin(angle),
        vy_mps=200.0 * math.cos(angle),
        covariance=[[100.0, 1.0, 0, 0], [1.0, 80.0, 0, 0], [0, 0, 4, 0], [0, 0, 0, 4]],
        validate=False,
        number=number,
        lat=47.0 + 3.0 * (number % 100) / 100 + t * 1e-6,
        lon=15.0 + 7.0 * (number // 100) / 20,
        flight_level=100.0 + number % 300,
        callsign=f"TST{number:04d}",
        mode3a=f"{number % 4096:04o}",
        address=f"{number:06X}",
        sources=[TrackSource(radar="25/11", local_track=number, age_s=0.0)],
        status="confirmed",
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args()
    scene = MapScene([MapRadar("25/11", "Alpha", 48.2, 17.2, 250.0)])
    # Full trails: three minutes of scans, each in the service's batches (a radar
    # datagram's: about 25 system updates) as the mapper gives them (``SystemBatch``).
    scans = int(scene.trail_s / SCAN_S) + 1
    batches = [
        [
            SystemBatch.of_values(
                [
                    SystemValues.of_message(message(n, T0 + k * SCAN_S))
                    for n in range(first, min(first + BATCH, args.tracks))
                ]
            )
            for first in range(0, args.tracks, BATCH)
        ]
        for k in range(scans)
    ]
    update_us, picture_ms, picture_kb = [], [], []
    for _ in range(args.repeats):
        scene = MapScene([MapRadar("25/11", "Alpha", 48.2, 17.2, 250.0)])
        started = time.perf_counter()
        for scan in batches:
            for batch in scan:
                # One data time for all: after the first tick, fixes only.
                scene.updates(batch, T0 - 1.0)
        update_us.append((time.perf_counter() - started) / (scans * args.tracks) * 1e6)
        scene.picture_geojson()
        # In steady state a picture a second finds a quarter of the tracks moved (one
        # update per 4 s scan): their features are made again, the others' reused.
        for batch in batches[-1][: len(batches[-1]) // 4]:
            scene.updates(batch, T0 - 1.0)
        started = time.perf_counter()
        payload = scene.picture_geojson()
        picture_ms.append((time.perf_counter() - started) * 1e3)
        picture_kb.append(len(payload) / 1e3)
    result = {
        "tracks": args.tracks,
        "update_us": statistics.median(update_us),
        "picture_ms": statistics.median(picture_ms),
        "picture_kb": statistics.median(picture_kb),
    }
    result["core_share"] = (
        args.tracks / SCAN_S * result["update_us"] * 1e-6 + result["picture_ms"] * 1e-3
    )
    if args.json:
        print(json.dumps(result))
        return
    print(
        f"{args.tracks} tracks: {result['update_us']:.1f} us per update (LocationFix), "
        f"{result['picture_ms']:.1f} ms and {result['picture_kb']:.0f} kB per picture; "
        f"{100 * result['core_share']:.0f}% of a core at one update per track per "
        f"{SCAN_S:g} s and a picture a second"
    )


if __name__ == "__main__":
    main()
