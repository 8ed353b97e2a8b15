"""The ADS-B reference over arrays (``adsb.AdsbReference``: a ring of reports per address,
the references of a batch in array operations) against the loop per plot over a deque
per address it replaced (``PlainReference`` below, kept as it was): bit for bit, on
streams with repeated and late reports, times on the 1/128 s grid of ASTERIX (plots
equally near two reports), gaps, unknown addresses and forgotten tracks."""

from __future__ import annotations

from collections import deque

import numpy as np
import pytest

from tracker_service.adsb import (
    MANOEUVRE_M_S2,
    UNKNOWN_VELOCITY_SIGMA_M_S,
    AdsbReference,
    AdsbReferences,
    AdsbReports,
)
from tracker_service.geodesy import SystemPlane

PLANE = SystemPlane(48.0, 17.0)


class PlainReference:
    """``AdsbReference`` as it was: a deque per address, a loop per plot."""

    def __init__(self, max_gap_s: float = 1.5, keep: int = 4, max_age_s: float = 30.0) -> None:
        self.max_gap_s = max_gap_s
        self.max_age_s = max_age_s
        self.keep = keep
        self.tracks: dict[int, deque[tuple[float, float, float, float, float, float]]] = {}
        self.reports = 0
        self.rejected = 0

    def add(self, reports: AdsbReports) -> None:
        moving = reports.sigma_v < UNKNOWN_VELOCITY_SIGMA_M_S
        self.rejected += int(np.count_nonzero(~moving))
        for k in np.flatnonzero(moving).tolist():
            history = self.tracks.setdefault(int(reports.address[k]), deque(maxlen=self.keep))
            t = float(reports.time[k])
            if history and t <= history[-1][0]:
                continue
            history.append(
                (
                    t,
                    float(reports.x[k]),
                    float(reports.y[k]),
                    float(reports.vx[k]),
                    float(reports.vy[k]),
                    float(reports.sigma[k]),
                )
            )
        self.reports += int(np.count_nonzero(moving))

    def at(self, address: np.ndarray, time: np.ndarray) -> AdsbReferences:
        n = len(address)
        valid = np.zeros(n, dtype=bool)
        xy = np.zeros((n, 2))
        p = np.zeros((n, 2, 2))
        v = np.zeros((n, 2))
        rows: list[int] = []
        found: list[tuple[float, float, float, float, float]] = []
        for k, (a, t) in enumerate(zip(address.tolist(), time.tolist(), strict=True)):
            history = self.tracks.get(a)
            if not history:
                continue
            t0, x0, y0, vx, vy, sigma = min(history, key=lambda r: abs(r[0] - t))
            dt = t - t0
            if abs(dt) > self.max_gap_s:
                continue
            rows.append(k)
            variance = sigma**2 + (0.5 * MANOEUVRE_M_S2 * dt * dt) ** 2
            found.append((x0 + vx * dt, y0 + vy * dt, vx, vy, variance))
        if rows:
            values = np.array(found)
            valid[rows] = True
            xy[rows] = values[:, :2]
            v[rows] = values[:, 2:4]
            p[rows, 0, 0] = p[rows, 1, 1] = values[:, 4]
        return AdsbReferences(valid, xy, p, v)

    def forget(self, now: float) -> None:
        stale = [a for a, track in self.tracks.items() if now - track[-1][0] > self.max_age_s]
        for a in stale:
            del self.tracks[a]


def _reports(rng: np.random.Generator, now: float, addresses: int, n: int) -> AdsbReports:
    """A block of ``n`` reports around ``now``: times on the 1/128 s grid, a few late or
    repeated, some without a velocity."""
    time = now + np.round(rng.uniform(-0.6, 0.2, n) * 128.0) / 128.0
    return AdsbReports(
        address=rng.integers(0, addresses, n),
        time=time,
        x=rng.uniform(-3e5, 3e5, n),
        y=rng.uniform(-3e5, 3e5, n),
        vx=rng.normal(0.0, 150.0, n),
        vy=rng.normal(0.0, 150.0, n),
        sigma=rng.choice([1.2, 4.1, 12.3, 37.8], n),
        sigma_v=np.where(rng.random(n) < 0.1, UNKNOWN_VELOCITY_SIGMA_M_S, 0.4),
        flight_level=np.full(n, np.nan),
        mode3a=np.full(n, -1),
        record=np.arange(n),
    )


def _same(got: AdsbReferences, want: AdsbReferences) -> None:
    for name in ("valid", "xy", "P", "v"):
        assert getattr(got, name).tobytes() == getattr(want, name).tobytes(), name


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_references_are_the_plain_loop_bit_for_bit(seed: int) -> None:
    rng = np.random.default_rng(seed)
    reference, plain = AdsbReference(PLANE), PlainReference()
    checked = 0
    for step in range(300):
        now = 1000.0 + 0.5 * step
        block = _reports(rng, now, 150, int(rng.integers(0, 40)))
        reference.add(block)
        plain.add(block)
        # Plots of known and unknown addresses, at times between reports, equally near
        # two of them, and too far from any.
        n = int(rng.integers(0, 60))
        address = rng.integers(0, 200, n)
        time = now + np.round(rng.uniform(-2.5, 1.0, n) * 256.0) / 256.0
        _same(reference.at(address, time), plain.at(address, time))
        checked += int(plain.at(address, time).valid.sum())
        if step % 97 == 96:
            reference.forget(now - 1.0)
            plain.forget(now - 1.0)
    assert (reference.reports, reference.rejected) == (plain.reports, plain.rejected)
    assert checked > 1000


def test_a_reference_without_reports_has_none() -> None:
    empty = AdsbReference(PLANE).at(np.array([5, 6]), np.array([1.0, 2.0]))
    assert not empty.valid.any()
