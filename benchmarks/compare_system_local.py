"""System tracks against the radar's own local tracks on a real capture (no truth).

On the plots both used: the innovation (the plot against the track's previous update
extrapolated to it at constant velocity), the residual after the update (the plot against
the state the update produced) and the velocity difference between the system track and
the local track at the same plot. With one radar and no bias reference, the system track
should follow its local track (issue 10 finding 5).

    python benchmarks/compare_system_local.py \
        ../shared/data/asterix/reader_network/068test_bds30.gps
"""

from __future__ import annotations

import argparse
import json
import sys
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.bias import BiasConfig
from tracker_service.evaluation.real_data import (
    NOMINAL_SITE_068,
    prediction_residuals,
    track_capture,
)
from tracker_service.fusion import ENDED, FusionConfig

LIVES = 1 << 20
"""Room for the lives of one system number in a pseudo track number."""


def _as_updates(system: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """System rows in the local updates' field names that ``prediction_residuals`` reads;
    each life of a system number (a number is given again after its track ended) counts
    as a track of its own."""
    ended = system["status"] == ENDED
    lives = np.zeros(len(system), dtype=np.int64)
    for number in np.unique(system["system_number"]):
        rows_of = np.flatnonzero(system["system_number"] == number)
        lives[rows_of] = np.cumsum(ended[rows_of]) - ended[rows_of]
    life = lives[~ended]
    rows = system[~ended]
    out = np.zeros(
        len(rows),
        dtype=[(n, np.float64) for n in ("time", "x", "y", "vx", "vy")]
        + [("track_number", np.int64), ("plot_id", np.int64)],
    )
    for name in ("time", "x", "y", "vx", "vy", "plot_id"):
        out[name] = rows[name]
    out["track_number"] = rows["system_number"] * LIVES + life
    # A system row names its latest plot also when it only coasts: one row per plot.
    fresh = rows["fresh"] & (rows["plot_id"] >= 0)
    out["plot_id"][~fresh] = -1
    return out


def _measures(updates: npt.NDArray[Any], plots: npt.NDArray[Any], used: Any) -> dict[str, float]:
    ids, innovation, _ = prediction_residuals(updates, plots)
    keep = np.isin(ids, used)
    innovation_m = np.hypot(*innovation[keep].T)
    with_plot = updates[np.isin(updates["plot_id"], used)]
    at = np.searchsorted(plots["plot_id"], with_plot["plot_id"])
    residual_m = np.hypot(plots["x"][at] - with_plot["x"], plots["y"][at] - with_plot["y"])
    return {
        "innovation_median_m": float(np.median(innovation_m)),
        "innovation_rms_m": float(np.sqrt(np.mean(innovation_m**2))),
        "residual_median_m": float(np.median(residual_m)),
        "residual_rms_m": float(np.sqrt(np.mean(residual_m**2))),
    }


def compare(path: str) -> dict[str, Any]:
    runs = track_capture(path, NOMINAL_SITE_068, fusion=FusionConfig(), bias=BiasConfig())
    out: dict[str, Any] = {}
    for source, run in runs.items():
        assert run.system is not None
        system = _as_updates(run.system)
        plots = run.plots[np.argsort(run.plots["plot_id"])]
        used = np.intersect1d(system["plot_id"][system["plot_id"] >= 0], run.updates["plot_id"])
        if used.size == 0:
            continue
        local = run.updates[np.argsort(run.updates["plot_id"])]
        s = system[np.isin(system["plot_id"], used)]
        s = s[np.argsort(s["plot_id"])]
        matched = local[np.searchsorted(local["plot_id"], s["plot_id"])]
        dv = np.hypot(s["vx"] - matched["vx"], s["vy"] - matched["vy"])
        out[source] = {
            "plots_compared": int(used.size),
            "local": _measures(run.updates, plots, used),
            "system": _measures(system, plots, used),
            "velocity_difference_median_mps": float(np.median(dv)),
            "velocity_difference_p95_mps": float(np.percentile(dv, 95)),
        }
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("capture")
    args = parser.parse_args(argv)
    json.dump(compare(args.capture), sys.stdout, indent=2)
    print()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
