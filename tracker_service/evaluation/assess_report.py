"""``assess --report DIR``: a Markdown report with PNG figures of a recording without truth.

matplotlib is optional (``pip install -e '.[report]'``), imported here only. For each
radar's local tracks and for the system tracks: the map of plots and published tracks;
the timeline of each identity (its plot stretches in grey, the tracks that held it in
colour: a break is a change of colour within one grey bar); and the distributions of
ground speed, position jump and NIS with the limits and the chi-square(2) law.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from tracker_service.evaluation.assess import (
    GATE_99_2DOF,
    MAX_JUMP_M,
    MAX_SPEED_KT,
    PUBLISHED,
    AssessRun,
    TrackSet,
    format_summary,
    identity_tracks,
    nis_samples,
    published_kinematics,
)
from tracker_service.evaluation.report import _pyplot, _safe

__all__ = ["write_report"]

KM = 1000.0
MAX_TIMELINE_IDENTITIES = 40


def _map(plt: Any, path: Path, run: AssessRun, ts: TrackSet, title: str) -> None:
    own = np.isin(run.extra["radar"], ts.plot_sources)
    plots = run.plots[own]
    fig, ax = plt.subplots(figsize=(8, 7))
    ax.scatter(plots["x"] / KM, plots["y"] / KM, s=2, c="0.7", label="plots", rasterized=True)
    rows = ts.rows[np.isin(ts.rows["status"], PUBLISHED)]
    for number in np.unique(rows[ts.number]):
        track = rows[rows[ts.number] == number]
        track = track[np.argsort(track["time"], kind="stable")]
        ax.plot(track["x"] / KM, track["y"] / KM, "-", lw=0.9)
    ax.set_xlabel("x km (plane of the tracks)")
    ax.set_ylabel("y km")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend(loc="best")
    ax.set_title(f"{title}: plots (grey) and published tracks")
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def _timeline(
    plt: Any,
    path: Path,
    run: AssessRun,
    ts: TrackSet,
    index: Mapping[int, int],
    title: str,
) -> bool:
    """Per identity, plot stretches and the tracks that held it; False when none."""
    label = "address"
    per = identity_tracks(ts, run.plots, run.extra["radar"], index, "address")
    if not per:
        label = "mode3a"
        per = identity_tracks(ts, run.plots, run.extra["radar"], index, "mode3a")
    if not per:
        return False
    t0 = float(run.plots["time"].min())
    chosen = sorted(per, key=lambda k: -sum(b - a for a, b in per[k]["stretches"]))
    chosen = chosen[:MAX_TIMELINE_IDENTITIES]
    fig, ax = plt.subplots(figsize=(11, 1.2 + 0.28 * len(chosen)))
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for k, identity in enumerate(chosen):
        for first, last in per[identity]["stretches"]:
            ax.plot([(first - t0) / 60, (last - t0) / 60], [k, k], color="0.8", lw=7)
        for number, times in per[identity]["tracks"].items():
            ax.plot(
                (times - t0) / 60,
                np.full(times.size, k),
                "|",
                ms=6,
                color=colours[number % len(colours)],
            )
            ax.annotate(str(number), ((times[0] - t0) / 60, k + 0.25), fontsize=6, color="0.2")
    ax.set_yticks(range(len(chosen)))
    text = [f"{i:06X}" if label == "address" else f"{i:04o}" for i in chosen]
    ax.set_yticklabels(text, fontsize=7)
    ax.set_ylim(-0.7, len(chosen) - 0.3)
    ax.invert_yaxis()
    ax.set_xlabel("minutes since the first plot")
    ax.set_title(
        f"{title}: plot stretches per {'Mode S address' if label == 'address' else 'code'} "
        "(grey), tracks that took them (colour, numbered)"
    )
    ax.grid(axis="x", alpha=0.3)
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)
    return True


def _distributions(
    plt: Any,
    path: Path,
    run: AssessRun,
    ts: TrackSet,
    index: Mapping[int, int],
    title: str,
) -> None:
    speed, jump, _ = published_kinematics(ts)
    _, nis = nis_samples(ts, run.tracked)
    fig, (ax_s, ax_j, ax_n) = plt.subplots(1, 3, figsize=(15, 4.2))
    if speed.size:
        ax_s.hist(speed, bins=50, color="C0")
    ax_s.axvline(MAX_SPEED_KT, color="C3", ls="--", label=f"{MAX_SPEED_KT:.0f} kt")
    ax_s.set_xlabel("ground speed of published updates (kt)")
    ax_s.set_ylabel("updates")
    ax_s.legend()
    if jump.size:
        x = np.sort(np.maximum(jump, 0.1))
        ax_j.plot(x, 1.0 - np.arange(x.size) / x.size, color="C0")
        ax_j.set_xscale("log")
        ax_j.set_yscale("log")
    ax_j.axvline(MAX_JUMP_M, color="C3", ls="--", label="1 NM")
    ax_j.set_xlabel("position jump: update - extrapolated previous (m)")
    ax_j.set_ylabel("share of updates beyond")
    ax_j.legend()
    if nis.size:
        top = max(20.0, float(np.percentile(nis, 99.5)))
        ax_n.hist(np.minimum(nis, top), bins=60, range=(0, top), density=True, color="C0")
        grid = np.linspace(0, top, 200)
        ax_n.plot(grid, 0.5 * np.exp(-grid / 2), color="k", label="chi-square, 2 dof")
        ax_n.set_yscale("log")
    ax_n.axvline(GATE_99_2DOF, color="C3", ls="--", label="99 % gate")
    ax_n.set_xlabel(f"NIS of each plot (mean {nis.mean():.2f})" if nis.size else "NIS")
    ax_n.set_ylabel("density")
    ax_n.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100, bbox_inches="tight")
    plt.close(fig)


def _figures(
    plt: Any,
    directory: Path,
    run: AssessRun,
    ts: TrackSet,
    index: Mapping[int, int],
    title: str,
) -> list[str]:
    name = _safe(ts.name)
    lines = [f"### {title}", ""]
    _map(plt, directory / f"map_{name}.png", run, ts, title)
    lines += [f"![map]({f'map_{name}.png'})", ""]
    if _timeline(plt, directory / f"timeline_{name}.png", run, ts, index, title):
        lines += [f"![timeline]({f'timeline_{name}.png'})", ""]
    _distributions(plt, directory / f"distributions_{name}.png", run, ts, index, title)
    lines += [f"![speed, jump, NIS]({f'distributions_{name}.png'})", ""]
    return lines


def _checks_table(doc: Mapping[str, Any]) -> list[str]:
    lines = ["| check | verdict | detail |", "|---|---|---|"]
    for check in doc["checks"]:
        verdict = {True: "pass", False: "**FAIL**", None: "n/a"}[check["passed"]]
        lines.append(f"| {check['name']} | {verdict} | {check['detail']} |")
    return lines


def write_report(run: AssessRun, doc: Mapping[str, Any], directory: Path) -> Path:
    """Write ``assess.md`` and its figures into ``directory``; return the Markdown's path."""
    plt = _pyplot()
    directory.mkdir(parents=True, exist_ok=True)
    index: dict[int, int] = {int(p): i for i, p in enumerate(run.plots["plot_id"].tolist())}
    lines = [
        f"# assess: {doc['recording']}",
        "",
        f"`tracker-service assess {doc['recording']}` ({doc['kind']}, {doc['plots']} plots).",
        "",
        *_checks_table(doc),
        "",
        "```",
        format_summary(doc),
        "```",
        "",
    ]
    sets: list[tuple[TrackSet, str]] = [
        (ts, f"local tracks of {source}") for source, ts in run.local.items() if len(ts.rows)
    ]
    if run.system is not None and len(run.system.rows):
        sets.append((run.system, "system tracks"))
    for ts, title in sets:
        lines += _figures(plt, directory, run, ts, index, title)
    path = directory / "assess.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path
