"""QNH and ISA deviation fitted to a recording's CAT021 reports (geodesy/atmosphere_fit.py),
against the atmosphere its scenario flew in.

Every report with I140 (GNSS height above the ellipsoid) and I145 (pressure altitude);
the geoid taken as one value for the region (``--geoid-m``, e.g. the sites' mean
``geoid_m``: the tracker has no geoid model), so its variation across the region (35-46 m
over clock_drift.toml's area) is an error of the fit's. ``--minutes`` fits the first
minutes only.

    .venv/bin/python benchmarks/atmosphere_fit.py /tmp/clk/cd_1.mcap --geoid-m 41 --minutes 1 5 10
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from asterix.codec import Block, decode_blocks
from tracker_service.geodesy.atmosphere_fit import fit_atmosphere
from tracker_service.simulator.recording import read_recording

FT = 0.3048


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("recording", type=Path)
    parser.add_argument("--geoid-m", type=float, required=True)
    parser.add_argument("--minutes", type=float, nargs="+", default=[10.0])
    parser.add_argument("--sigma-m", type=float, default=15.0)
    args = parser.parse_args()
    recording = read_recording(args.recording)
    truth = recording.metadata["scenario"].get("atmosphere", {})
    times, pressure, height = [], [], []
    for datagram in recording.datagrams():
        for event in decode_blocks(datagram.payload):
            if not isinstance(event, Block) or event.cat != 21:
                continue
            for items in event.records:
                if "140" in items and "145" in items:
                    times.append(datagram.time)
                    pressure.append(float(items["145"]) * 100.0)
                    height.append(float(items["140"]) * FT - args.geoid_m)
    t = np.array(times) - min(times)
    print(f"truth: {truth}")
    for minutes in args.minutes:
        use = t <= 60.0 * minutes
        fit = fit_atmosphere(np.array(pressure)[use], np.array(height)[use], args.sigma_m)
        sq, st = fit.sigma
        print(
            f"{minutes:g} min: QNH {fit.atmosphere.qnh_hpa:.2f} +/- {sq:.2f} hPa, ISA "
            f"{fit.atmosphere.isa_deviation_k:+.2f} +/- {st:.2f} K; {fit.used} reports used, "
            f"{fit.rejected} rejected, residual RMS {fit.residual_rms_m:.1f} m"
        )


if __name__ == "__main__":
    main()
