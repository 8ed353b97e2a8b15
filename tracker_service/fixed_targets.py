"""Fixed transponders: stationary transponders a radar sees that are not aircraft.

Radar sites place transponders on masts (site monitors, "parrots") to check their SSR and
Mode S chain; many send code 7777 (ICAO reserves it for them) and RAB = 0, so nothing in
the plot says they are not aircraft. Tracked, they become stationary aircraft, and a
primary plot near one can be paired with it into a track at an absurd speed. This stage
keeps their plots out of traffic tracking, in two ways:

- by the configuration (``FixedTransponder``): a radar's transponders by Mode S address
  and/or Mode 3/A code, with their surveyed position when known. A plot of that identity
  within ``tolerance_m`` of the surveyed position (in slant range and across it, so that
  an aircraft wearing the same code elsewhere is not taken) is fixed; without a position,
  every plot of that identity is. A surveyed one is also a field monitor, whether or not
  it sets RAB: its plots are returned with the surveyed position in the plane, a bias
  reference, and the conversion uses the surveyed height instead of its Mode C (site
  monitors often send a test level such as FL719).
- detected (``FixedTargetConfig``): per identity (Mode S address, else a validated Mode
  3/A code that is neither shared by many aircraft nor an emergency code; primary plots
  have none and are never taken; a site-monitor code counts even garbled), a candidate
  gathers the plots that fall within a small area (``gate_sigmas`` plot sigmas, at
  least ``min_radius_m``) around its running mean.
  It is stationary when it has enough plots over a long enough time and its velocity,
  fitted by least squares over all of them, is below ``max_speed_kt`` even when
  ``speed_sigmas`` standard errors (from the plots' own covariances) are added. Codes
  reserved for site monitors (``site_monitor_codes``) need a few scans; any other
  identity needs minutes of standing still below walking speed, so that a hovering
  helicopter is not lost: the test runs on every plot, so a target that starts to move
  leaves the area (or fails the speed bound) and its plots are tracked again. Plots on
  a site-monitor code within ``halo_m`` of a stationary target of their identity are
  taken too: its reflections and split plots, which come and go too irregularly to
  stand still on their own. Candidates without a plot for ``stale_periods`` antenna
  periods are forgotten, stationary ones after ``fixed_memory_s``.

  A plot on a site-monitor code is kept out from its identity's first plot on: it is
  released to tracking only once its candidate is shown moving, so that a monitor's
  first scans start no track. Moving is shown either by the fit (enough plots, speed
  bound above ``site_monitor_max_speed_kt``) or, for a target too fast to stay in one
  area, by ``site_monitor_moving_steps`` successive plots each outside its identity's
  areas and reachable from a previous scan's candidate (at most
  ``site_monitor_reach_kt``, above the monitors' bound). The price: an aircraft that
  squawks 7777 loses its first few plots (two to four at 150 kt and more, a few more
  when slower) and is tracked from then on; one slower than the monitors' bound stays
  kept out.

Everything is per radar, on the radar's plot table (``chain.RAW_PLOT_DTYPE``), in arrays.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.geodesy import RadarSite, SystemPlane, geodetic_to_ecef
from tracker_service.small_arrays import is_one_of, median
from tracker_service.tracking.config import SHARED_MODE3A_CODES

__all__ = [
    "EMERGENCY_CODES",
    "Classification",
    "FixedTargetConfig",
    "FixedTargets",
    "FixedTransponder",
    "identity_keys",
]

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
BoolArray = npt.NDArray[np.bool_]

KT = 1852.0 / 3600.0
EMERGENCY_CODES = (0o7500, 0o7600, 0o7700)
_UNKEYED_CODES = np.array(SHARED_MODE3A_CODES + EMERGENCY_CODES, np.int64)
"""The codes no identity key is made of (shared or emergency)."""
"""Hijack, radio failure, emergency: never taken for a fixed transponder by detection."""
CODE_KEY = 1 << 24
"""Identity keys: a Mode S address as is, a Mode 3/A code offset past every address."""
NO_KEY = -1


@dataclass(frozen=True)
class FixedTransponder:
    """One configured fixed transponder of a radar: its identity (a 24-bit address, a
    12-bit code: at least one) and, when surveyed, its position (height above MSL)."""

    address: int | None = None
    mode3a: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None
    tolerance_m: float = 1000.0
    """How far from the surveyed position (slant range, and across at its range) a plot
    of that identity is still taken as this transponder: the radar's biases plus noise."""
    name: str = ""

    def __post_init__(self) -> None:
        if self.address is None and self.mode3a is None:
            raise ValueError("a fixed transponder needs an address or a Mode 3/A code")
        position = (self.lat_deg, self.lon_deg, self.alt_m)
        if any(v is None for v in position) and not all(v is None for v in position):
            raise ValueError("a fixed transponder's position needs lat, lon and alt_m together")

    @property
    def surveyed(self) -> bool:
        return self.lat_deg is not None


@dataclass(frozen=True)
class FixedTargetConfig:
    """How stationary targets are detected (see the module docstring)."""

    detect: bool = True
    site_monitor_codes: tuple[str, ...] = ("7777",)
    """Mode 3/A codes (octal) reserved for site monitors: detected within a few scans."""
    site_monitor_min_plots: int = 3
    site_monitor_max_speed_kt: float = 60.0
    site_monitor_speed_sigmas: float = 1.0
    min_plots: int = 20
    """Any other identity: plots, time, speed bound and its margin in standard errors."""
    min_duration_s: float = 300.0
    max_speed_kt: float = 3.0
    speed_sigmas: float = 2.0
    gate_sigmas: float = 3.0
    min_radius_m: float = 150.0
    halo_m: float = 1852.0
    """Plots on a site-monitor code this close to a stationary target of their identity
    are its reflections and splits (canalA.gps: a 7777 ghost 1.5 km beside its monitor)."""
    stale_periods: float = 3.5
    fixed_memory_s: float = 120.0
    """A stationary target is remembered this long without a plot (missed scans)."""
    site_monitor_moving_steps: int = 2
    """Successive moves between scans that show a target on a site-monitor code moving
    (two: one ghost or noisy plot beside a monitor's first plots is not enough)."""
    site_monitor_reach_kt: float = 1000.0
    """The fastest move between scans taken as one target's (canalA.gps's two monitors,
    16.7 km apart, are not one target moving)."""

    def __post_init__(self) -> None:
        if not isinstance(self.detect, bool):
            raise ValueError(f"detect must be true or false, not {self.detect!r}")
        for f in dataclasses.fields(self)[2:]:
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"{f.name} must be a number, not {value!r}")
        if not isinstance(self.site_monitor_codes, tuple):
            raise ValueError("site_monitor_codes must be a list of codes, e.g. ['7777']")
        for code in self.site_monitor_codes:
            if len(code) != 4 or set(code) - set("01234567"):
                raise ValueError(f"site_monitor_codes: {code!r} is not a 4-digit octal code")
        if self.site_monitor_min_plots < 2 or self.min_plots < 2:
            raise ValueError("min_plots and site_monitor_min_plots must be at least 2")
        positive = (
            "site_monitor_max_speed_kt",
            "max_speed_kt",
            "gate_sigmas",
            "stale_periods",
            "site_monitor_moving_steps",
            "site_monitor_reach_kt",
        )
        for name in ("halo_m", "fixed_memory_s"):
            if getattr(self, name) < 0.0:
                raise ValueError(f"{name} must not be negative, not {getattr(self, name)}")
        for name in positive:
            if not getattr(self, name) > 0.0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)}")


@dataclass(frozen=True)
class Classification:
    """One table's verdict: which plots are fixed transponders, and for each the surveyed
    position in the plane (NaN where it is not known: detected, or configured without)."""

    fixed: BoolArray
    reference_xy: FloatArray


def identity_keys(address: IntArray, mode3a: IntArray, mode3a_valid: BoolArray) -> IntArray:
    """Each plot's identity for detection: its Mode S address, else its validated Mode 3/A
    code (offset by ``CODE_KEY``) unless that code is shared or an emergency; else
    ``NO_KEY`` (primary plots, garbled codes)."""
    code_ok = mode3a_valid & (mode3a >= 0) & ~is_one_of(mode3a, _UNKEYED_CODES)
    keys = np.where(code_ok, CODE_KEY + mode3a, NO_KEY)
    return np.where(address >= 0, address, keys).astype(np.int64)


def _largest_sigma(r: FloatArray) -> FloatArray:
    """The square root of the largest eigenvalue of each 2x2 covariance."""
    a, b, d = r[:, 0, 0], r[:, 0, 1], r[:, 1, 1]
    half = 0.5 * (a + d)
    return np.sqrt(half + np.sqrt(np.maximum(0.25 * (a - d) ** 2 + b * b, 0.0)))


class _Candidates:
    """Candidate stationary targets: an identity key and one row of ``values`` each (see
    ``FIELDS``); the sums are relative to the first plot (time t0, position x0, y0), so
    that they keep their precision over hours. One array, so that keeping, adding and
    accumulating are one numpy operation each whatever the number of fields."""

    FIELDS = ("n", "t0", "x0", "y0", "last", "st", "sx", "sy", "stt", "stx", "sty", "var", "moves")
    N, T0, X0, Y0, LAST, ST, SX, SY, STT, STX, STY, VAR, MOVES = range(len(FIELDS))
    """``moves``: successive moves between scans that led to this candidate (site-monitor
    codes), or ``site_monitor_moving_steps`` once its fit shows it moving."""
    SUMS = np.array([N, ST, SX, SY, STT, STX, STY, VAR])

    def __init__(self) -> None:
        self.key = np.zeros(0, np.int64)
        self.values = np.zeros((0, len(self.FIELDS)))
        self.fixed = np.zeros(0, np.bool_)
        """Each candidate's latest verdict: stationary."""

    def __len__(self) -> int:
        return len(self.key)

    @property
    def last(self) -> FloatArray:
        return self.values[:, self.LAST]

    @property
    def moves(self) -> FloatArray:
        return self.values[:, self.MOVES]

    def keep(self, rows: IntArray) -> None:
        self.key = self.key[rows]
        self.values = self.values[rows]
        self.fixed = self.fixed[rows]

    def add(self, key: IntArray, t: FloatArray, x: FloatArray, y: FloatArray) -> IntArray:
        """New candidates (no plot yet), one per plot given; returns their rows."""
        first = len(self.key)
        new = np.zeros((len(key), len(self.FIELDS)))
        new[:, self.T0] = new[:, self.LAST] = t
        new[:, self.X0], new[:, self.Y0] = x, y
        self.key = np.concatenate([self.key, key])
        self.values = np.concatenate([self.values, new])
        self.fixed = np.concatenate([self.fixed, np.zeros(len(key), np.bool_)])
        return np.arange(first, first + len(key), dtype=np.int64)

    def mean(self, rows: IntArray) -> tuple[FloatArray, FloatArray]:
        v = self.values[rows]
        n = np.maximum(v[..., self.N], 1.0)
        return v[..., self.X0] + v[..., self.SX] / n, v[..., self.Y0] + v[..., self.SY] / n

    def accumulate(
        self, rows: IntArray, t: FloatArray, x: FloatArray, y: FloatArray, var: FloatArray
    ) -> None:
        v = self.values[rows]
        dt, dx, dy = t - v[:, self.T0], x - v[:, self.X0], y - v[:, self.Y0]
        terms = np.empty((len(rows), len(self.SUMS)))  # the SUMS' columns, filled in place
        terms[:, 0] = 1.0
        terms[:, 1], terms[:, 2], terms[:, 3] = dt, dx, dy
        terms[:, 4], terms[:, 5], terms[:, 6] = dt * dt, dt * dx, dt * dy
        terms[:, 7] = var
        ordered = np.sort(rows)
        if not (ordered[1:] == ordered[:-1]).any():  # the rule: one plot per identity and area
            self.values[rows[:, None], self.SUMS] += terms
            self.values[rows, self.LAST] = np.maximum(v[:, self.LAST], t)
            return
        np.add.at(self.values, (rows[:, None], self.SUMS[None, :]), terms)
        np.maximum.at(self.values[:, self.LAST], rows, t)

    def plots(self, rows: IntArray) -> FloatArray:
        plots: FloatArray = self.values[rows, self.N]
        return plots

    def span(self, rows: IntArray) -> FloatArray:
        span: FloatArray = self.values[rows, self.LAST] - self.values[rows, self.T0]
        return span

    def speed_bound(self, rows: IntArray, sigmas: FloatArray) -> FloatArray:
        """Least-squares speed of each candidate plus ``sigmas`` standard errors (m/s);
        infinite while its plots span no time."""
        v = self.values[rows]
        n = v[:, self.N]
        st = v[:, self.ST]
        s_tt = v[:, self.STT] - st**2 / n
        with np.errstate(divide="ignore", invalid="ignore"):
            vx = (v[:, self.STX] - st * v[:, self.SX] / n) / s_tt
            vy = (v[:, self.STY] - st * v[:, self.SY] / n) / s_tt
            sigma_v = np.sqrt(v[:, self.VAR] / n / s_tt)
            bound = np.hypot(vx, vy) + sigmas * sigma_v
        return np.where(s_tt > 1e-6, bound, np.inf)


class FixedTargets:
    """One radar's fixed-transponder stage: ``classify`` each plot table (see the module
    docstring); ``surveyed_heights`` first, so that the conversion to the plane uses a
    surveyed transponder's height rather than the Mode C it sends."""

    def __init__(
        self,
        site: RadarSite,
        plane: SystemPlane,
        period_s: float,
        transponders: Sequence[FixedTransponder] = (),
        config: FixedTargetConfig | None = None,
        compiled: bool = True,
    ) -> None:
        self.config = config or FixedTargetConfig()
        self.compiled = compiled
        """Detection by ``fixed_target_kernels`` (the same verdicts), not numpy."""
        cfg = self.config
        self._settings = (
            float(period_s),
            float(cfg.fixed_memory_s),
            float(cfg.stale_periods * period_s),
            float(cfg.halo_m**2),
            float(cfg.min_radius_m),
            float(cfg.gate_sigmas),
            float(cfg.site_monitor_max_speed_kt * KT),
            float(cfg.site_monitor_reach_kt * KT),
            float(cfg.site_monitor_moving_steps),
            float(cfg.site_monitor_min_plots),
            float(cfg.min_plots),
            float(cfg.min_duration_s),
            float(cfg.site_monitor_max_speed_kt * KT),
            float(cfg.max_speed_kt * KT),
            float(cfg.site_monitor_speed_sigmas),
            float(cfg.speed_sigmas),
        )
        """``fixed_target_kernels.SETTINGS``, in its order."""
        self.period_s = period_s
        self.transponders = tuple(transponders)
        t = self.transponders
        self._address = np.array([-1 if e.address is None else e.address for e in t], np.int64)
        self._code = np.array([-1 if e.mode3a is None else e.mode3a for e in t], np.int64)
        self._surveyed = np.array([e.surveyed for e in t], np.bool_)
        self._tolerance = np.array([e.tolerance_m for e in t], np.float64)
        self._alt = np.array([np.nan if e.alt_m is None else e.alt_m for e in t])
        # Where the radar should see each surveyed one (slant range, reported azimuth)
        # and where it lies in the plane.
        self._rho = np.full(len(t), np.nan)
        self._theta = np.full(len(t), np.nan)
        self._xy = np.full((len(t), 2), np.nan)
        for k, e in enumerate(t):
            if e.lat_deg is None or e.lon_deg is None or e.alt_m is None:
                continue
            point = np.array(
                [float(v) for v in geodetic_to_ecef(e.lat_deg, e.lon_deg, e.alt_m + site.geoid_m)]
            )
            east, north, _ = site.enu_rotation @ (point - site.ecef_m)
            self._rho[k] = float(np.linalg.norm(point - site.ecef_m))
            azimuth = math.degrees(math.atan2(east, north)) - site.north_offset_deg
            self._theta[k] = azimuth % 360.0
            self._xy[k] = plane.from_geodetic(e.lat_deg, e.lon_deg, e.alt_m)
        self._monitor_codes = np.array(
            [int(code, 8) for code in self.config.site_monitor_codes], np.int64
        )
        self._candidates = _Candidates()

    def _configured(
        self,
        address: IntArray,
        mode3a: IntArray,
        mode3a_valid: BoolArray,
        rho_m: FloatArray,
        theta_deg: FloatArray,
    ) -> IntArray:
        """The configured transponder each plot is (its index), or -1."""
        which = np.full(len(address), -1, np.int64)
        if not self.transponders or not len(address):
            return which
        same = (address[:, None] >= 0) & (address[:, None] == self._address[None, :])
        same |= mode3a_valid[:, None] & (self._code[None, :] >= 0) & (mode3a[:, None] == self._code)
        across = np.radians((theta_deg[:, None] - self._theta[None, :] + 180.0) % 360.0 - 180.0)
        near = (np.abs(rho_m[:, None] - self._rho) <= self._tolerance) & (
            np.abs(across) * self._rho <= self._tolerance
        )
        match = same & (near | ~self._surveyed[None, :])
        rows = np.flatnonzero(match.any(axis=1))
        which[rows] = np.argmax(match[rows], axis=1)
        return which

    def surveyed_heights(self, raw: npt.NDArray[Any]) -> FloatArray | None:
        """Per plot of an ``asterix.plots`` batch, the surveyed height (m above MSL) of the
        configured transponder it is, NaN for the others; None when no plot is one."""
        if not self._surveyed.any() or not len(raw):
            return None
        which = self._configured(
            np.asarray(raw["address"], np.int64),
            np.asarray(raw["mode3a"], np.int64),
            _mode3a_valid(raw),
            np.asarray(raw["rho"], np.float64) * 1852.0,
            np.asarray(raw["theta"], np.float64),
        )
        if not (which >= 0).any():
            return None
        return np.where(which >= 0, self._alt[np.maximum(which, 0)], np.nan)

    def classify(
        self, table: npt.NDArray[Any], candidates: BoolArray, mode3a_valid: BoolArray
    ) -> Classification:
        """The fixed transponders among ``table``'s plots whose ``candidates`` is set (the
        plots still meant for tracking); ``mode3a_valid``: each plot's code is usable.
        The surveyed position is given for these and for field-monitor plots (RAB = 1)
        of a configured transponder."""
        n = len(table)
        fixed = np.zeros(n, np.bool_)
        reference = np.full((n, 2), np.nan)
        address = np.asarray(table["address"], np.int64)
        mode3a = np.asarray(table["mode3a"], np.int64)
        which = self._configured(address, mode3a, mode3a_valid, table["rho_m"], table["theta_deg"])
        configured = candidates & (which >= 0)
        fixed |= configured
        surveyed = (candidates | table["rab"]) & (which >= 0)
        reference[surveyed] = self._xy[which[surveyed]]
        if self.config.detect and self.compiled:
            fixed |= self._classify_compiled(
                table, candidates & ~configured, address, mode3a, mode3a_valid
            )
        elif self.config.detect:
            # A site monitor's code counts even garbled or not validated: replies that
            # overlap its own are often flagged so (canalA.gps: 89 of one monitor's 716).
            monitor = (mode3a >= 0) & is_one_of(mode3a, self._monitor_codes)
            keys = identity_keys(address, mode3a, mode3a_valid | monitor)
            rows = np.flatnonzero(candidates & ~configured & (keys != NO_KEY))
            if rows.size:
                fixed[rows] = self._detect(table[rows], keys[rows], monitor[rows])
        return Classification(fixed, reference)

    def _classify_compiled(
        self,
        table: npt.NDArray[Any],
        eligible: BoolArray,
        address: IntArray,
        mode3a: IntArray,
        mode3a_valid: BoolArray,
    ) -> BoolArray:
        """The identities and ``_detect`` of the ``eligible`` plots in one compiled pass
        (``fixed_target_kernels.classify``): which are fixed."""
        from tracker_service.fixed_target_kernels import classify

        c = self._candidates
        taken, c.key, c.values, c.fixed = classify(
            table["time"], table["x"], table["y"], table["R"], address, mode3a,
            np.asarray(mode3a_valid, np.bool_), eligible, self._monitor_codes, _UNKEYED_CODES,
            c.key, c.values, c.fixed, self._settings,
        )  # fmt: skip
        return taken

    def _detect(self, plots: npt.NDArray[Any], keys: IntArray, monitor: BoolArray) -> BoolArray:
        """Each plot joins the nearest candidate of its identity whose area it falls in,
        or starts one; returns whether each plot's candidate is stationary (by the site
        monitors' rule where ``monitor``: the plot wears a site-monitor code)."""
        cfg, c = self.config, self._candidates
        t = np.asarray(plots["time"], np.float64)
        x = np.asarray(plots["x"], np.float64)
        y = np.asarray(plots["y"], np.float64)
        sigma = _largest_sigma(np.asarray(plots["R"], np.float64))
        # Forget candidates that have gone quiet; keep the others sorted by identity, so
        # that each plot looks at its identity's few candidates only.
        now = median(t)  # one plot's wrong time does not age every candidate
        if len(c):
            memory = np.where(c.fixed, cfg.fixed_memory_s, cfg.stale_periods * self.period_s)
            live = np.flatnonzero(c.last >= now - memory)
            c.keep(live[np.argsort(c.key[live], kind="stable")])
        rows = np.full(len(keys), -1, np.int64)
        halo = np.zeros(len(keys), np.bool_)
        moves = np.zeros(len(keys))
        first = np.searchsorted(c.key, keys, "left")
        width = np.searchsorted(c.key, keys, "right") - first
        if width.any():
            slots = first[:, None] + np.arange(int(width.max()))
            mine = slots < (first + width)[:, None]
            slots = np.where(mine, slots, 0)
            mx, my = c.mean(slots)
            d2 = (x[:, None] - mx) ** 2 + (y[:, None] - my) ** 2
            near = (mine & c.fixed[slots] & (d2 <= cfg.halo_m**2)).any(axis=1)
            halo = near & monitor
            radius = np.maximum(cfg.min_radius_m, cfg.gate_sigmas * sigma)
            in_area = np.where(mine & (d2 <= radius[:, None] ** 2), d2, np.inf)
            nearest = np.argmin(in_area, axis=1)
            plot = np.arange(len(keys))
            inside = np.isfinite(in_area[plot, nearest])
            rows[inside] = slots[plot, nearest][inside]
            moves = self._moves(mine & ~c.fixed[slots], slots, t, d2) * (monitor & ~inside)
        new = rows < 0
        if new.any():
            rows[new] = c.add(keys[new], t[new], x[new], y[new])
            c.moves[rows[new]] = moves[new]
        c.accumulate(rows, t, x, y, sigma**2)
        # A target shown moving on a site-monitor code is no monitor, even when a few of
        # its plots happen to fit standing still.
        mover = monitor & (c.moves[rows] >= cfg.site_monitor_moving_steps)
        stationary = self._stationary(rows, monitor) & ~mover
        c.fixed[rows] = stationary
        # The fit shows a site-monitor code moving when even its speed less its margin
        # exceeds the monitors' bound (a monitor's first noisy plots do not).
        fitted = monitor & ~stationary & (c.plots(rows) >= cfg.site_monitor_min_plots)
        fitted &= c.span(rows) >= 0.5 * self.period_s
        lower = c.speed_bound(rows, np.full(len(rows), -cfg.site_monitor_speed_sigmas))
        fitted &= lower > cfg.site_monitor_max_speed_kt * KT
        c.moves[rows[fitted]] = cfg.site_monitor_moving_steps
        undecided = monitor & (c.moves[rows] < cfg.site_monitor_moving_steps)
        return stationary | halo | undecided

    def _moves(
        self, open_: BoolArray, slots: IntArray, t: FloatArray, d2: FloatArray
    ) -> FloatArray:
        """Per plot, one more than the most moves of a candidate of its identity it moved
        from (``open_``: not stationary; ``d2``: squared distance to its mean): seen a
        previous scan, at a speed between the site monitors' bound and the reach; 0 when
        none."""
        cfg, c = self.config, self._candidates
        dt = t[:, None] - c.last[slots]
        slowest = (cfg.site_monitor_max_speed_kt * KT * dt) ** 2
        fastest = (cfg.site_monitor_reach_kt * KT * dt) ** 2
        moved = open_ & (dt >= 0.5 * self.period_s) & (d2 > slowest) & (d2 <= fastest)
        steps: FloatArray = np.where(moved, c.moves[slots] + 1.0, 0.0).max(axis=1)
        return steps

    def _stationary(self, rows: IntArray, monitor: BoolArray) -> BoolArray:
        cfg, c = self.config, self._candidates
        min_plots = np.where(monitor, cfg.site_monitor_min_plots, cfg.min_plots)
        min_duration = np.where(monitor, 0.0, cfg.min_duration_s)
        max_speed = np.where(monitor, cfg.site_monitor_max_speed_kt, cfg.max_speed_kt) * KT
        sigmas = np.where(monitor, cfg.site_monitor_speed_sigmas, cfg.speed_sigmas)
        enough = (c.plots(rows) >= min_plots) & (c.span(rows) >= min_duration)
        return enough & (c.speed_bound(rows, sigmas) <= max_speed)


def _mode3a_valid(raw: npt.NDArray[Any]) -> BoolArray:
    """A code that was validated and not garbled (``asterix.plots`` columns)."""
    mode3a = np.asarray(raw["mode3a"], np.int64)
    valid: BoolArray = (mode3a >= 0) & (raw["mode3a_invalid"] != 1) & (raw["mode3a_garbled"] != 1)
    return valid
