"""Cost of the ASTERIX over UDP output's picture: extrapolation and CAT062 encoding.

    python benchmarks/bench_asterix_udp.py [--tracks 2000] [--repeats 5]

Builds ``--tracks`` system-track messages spread over 300 km around the system centre of
config/example.toml, then times, per picture: ``PeriodicPicture.at`` (every track
extrapolated to one time: arrays for the states and the conversion to lat/lon, one
message copy per track) and ``encode_system_tracks`` (CAT062 through the codec, blocks of
1,400 octets). Prints one JSON line: tracks, the median seconds of each and per track.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import numpy as np

from tracker_service.geodesy import SystemPlane
from tracker_service.outputs.cat062 import encode_system_tracks
from tracker_service.outputs.messages import SensorAges, SystemTrackMessage
from tracker_service.outputs.periodic import PeriodicPicture
from tracker_service.service.config import load_service_config

REPO = Path(__file__).resolve().parents[1]
T0 = 1_780_000_000.0


def messages(plane: SystemPlane, n: int, seed: int = 1) -> list[SystemTrackMessage]:
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(-300e3, 300e3, (2, n))
    lat, lon = plane.to_geodetic(x, y)
    out = []
    for k in range(n):
        speed, heading = rng.uniform(100, 250), rng.uniform(0, 2 * np.pi)
        p = np.diag([900.0, 900.0, 25.0, 25.0]).tolist()
        out.append(
            SystemTrackMessage.from_state(
                time=T0 - rng.uniform(0, 5),
                x_m=float(x[k]),
                y_m=float(y[k]),
                vx_mps=speed * np.sin(heading),
                vy_mps=speed * np.cos(heading),
                covariance=p,
                number=k,
                lat=float(lat[k]),
                lon=float(lon[k]),
                flight_level=float(rng.uniform(100, 400)),
                address=f"{k + 0x400000:06X}",
                mode3a=f"{k % 4096:04o}",
                sources=[],
                status="confirmed",
                ages=SensorAges(ssr=1.0, mode_s=1.0),
            )
        )
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--tracks", type=int, default=2000)
    parser.add_argument("--repeats", type=int, default=5)
    args = parser.parse_args()
    config = load_service_config(REPO / "config" / "example.toml")
    system = config.system
    plane = SystemPlane(system.centre_lat, system.centre_lon, system.projection)
    picture = PeriodicPicture(plane, 4.0)
    for message in messages(plane, args.tracks):
        picture.update(message)
    extrapolate, encode = [], []
    for _ in range(args.repeats):
        start = time.perf_counter()
        tracks = picture.at(T0 + 1.0)
        extrapolate.append(time.perf_counter() - start)
        start = time.perf_counter()
        data = encode_system_tracks(tracks, system)
        encode.append(time.perf_counter() - start)
    e, c = statistics.median(extrapolate), statistics.median(encode)
    print(
        json.dumps(
            {
                "tracks": args.tracks,
                "extrapolate_s": round(e, 4),
                "encode_s": round(c, 4),
                "per_track_us": round((e + c) / args.tracks * 1e6, 1),
                "octets": len(data),
            }
        )
    )


if __name__ == "__main__":
    main()
