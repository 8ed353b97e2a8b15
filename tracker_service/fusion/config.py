"""The system-track fuser's knobs; units are SI (m, s) unless the name says otherwise."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

from tracker_service.tracking.config import TrackerConfig

Method = Literal["tracks", "plots"]
METHODS: tuple[Method, ...] = ("tracks", "plots")
AdsbMode = Literal["fuse", "reference", "off"]
ADSB_MODES: tuple[AdsbMode, ...] = ("fuse", "reference", "off")


@dataclass(frozen=True)
class FusionConfig:
    """Every tunable of ``SystemTracker``.

    ``method`` "tracks" (DOMAIN.md section 7, architecture B): the contributing local tracks
    are predicted to the output time and fused by maximum likelihood with an approximated
    cross-covariance. "plots" (architecture C): each system track is an IMM of its own,
    updated by every plot of its local tracks in arrival order; the local tracks then only
    serve association and initiation.
    """

    method: Method = "plots"
    """"plots" by default: on synthetic data (tests/test_fusion.py) it matched "tracks" on
    straight and turning flight (RMS 41.9 vs 42.0 m, position NEES 1.47 vs 1.21 for 2 dof)
    and beat it under random manoeuvres shared by the local tracks (RMS 52.8 vs 54.5 m,
    NEES 2.36 vs 2.74 with rho = 0.3, 3.59 with rho = 0): no cross-covariance to guess."""
    gate: float = 18.47
    """Chi-square gate on the 4-dof difference [x, y, vx, vy] of a local track and a system
    track at a common time (18.47: 99.9 %)."""
    address_bonus: float = 10.0
    """Cost taken off a gated pair whose Mode S addresses match."""
    address_mismatch_penalty: float = 30.0
    """Cost added to a gated pair whose Mode S addresses differ: two transponders."""
    mode3a_bonus: float = 4.0
    """Cost taken off a gated pair whose Mode 3/A codes match (never a shared code)."""
    correlation: float = 0.3
    """rho of the cross-covariance approximation P_ij = rho sqrt(P_i) sqrt(P_j) between the
    estimation errors of two local tracks of one aircraft (the shared process noise of
    their past). The process noise of the predictions to the output time is added exactly.
    0.3 brought the "tracks" NEES from 3.6 (rho = 0, over-confident) to 2.5-2.7 on aircraft
    wandering with the CV model's own noise; a larger rho costs RMS."""
    q: float = 1.0
    """White-acceleration intensity per axis (m^2/s^3) of the CV prediction of local and
    system tracks to a common time: covers the turns the local IMMs follow."""
    longest_period_s: float = 12.0
    """The longest antenna period among the radars."""
    max_silence_s: float | None = None
    """A system track none of whose local tracks had a plot for this long ends; None: 3 x
    ``longest_period_s``."""
    max_reference_age_s: float | None = None
    """A local track whose latest plot is older than this contributes neither to fusion nor
    to ``references``; None: 2 x ``longest_period_s``."""
    reassociate_after: int = 3
    """Consecutive gate failures after which a local track leaves its system track."""
    reassociate_kappa: float = 3.0
    """The consistency test of a local track in its system track: once the running mean
    of its 4-dof distance over ``reassociate_window`` updates exceeds kappa times the dof
    (the literature's trigger, kappa 2-5), it leaves the system track and is associated
    again. It catches a wrongly joined local track that stays inside the gate but
    consistently off (an aircraft 1 km abeam), which the gate's failures never do."""
    reassociate_window: int = 5
    """Updates of the consistency test's mean (the first ones a running mean, then an
    exponential one of this length); the test waits until it is full."""
    join_ambiguity_margin: float = 4.0
    """A free local track whose two likeliest system tracks in the gate differ in cost
    (d2 plus identity) by less than this, or which with another free local track of its
    radar is one of the two likeliest for one system track, waits up to ``found_delay``:
    it neither joins nor founds, while the biases are learnt and the geometry tells the
    two apart; after that GNN joins it as before. The first joins of a radar's tracks of
    two aircraft 0.5-1 km apart, made at one moment, went crosswise and stayed so for
    40-60 s until the exchange undid them (docs/association.md "Session 9"). 0: off (every
    first join at once, as before session 10)."""
    exchange_margin: float = 2.0
    """Two confirmed local tracks of one radar in two system tracks are exchanged between
    them once the running mean (over ``reassociate_window`` updates) of delta = d2(l, S) +
    d2(l', S') - d2(l, S') - d2(l', S) exceeds this: delta is twice the log-likelihood
    ratio, per update, of the crosswise assignment against the present one. The one-moment
    association can join a radar's two tracks of two close aircraft (parallel 500 m apart,
    a 15-degree crossing) crosswise, and each then holds the other's system track closed
    to it (``associate.open_systems``); 0 turns the test off."""
    orphan_coast_s: float | None = 0.0
    """An orphaned system track (its last local track ended: a single-coverage aircraft's
    track deleted on a detection gap) is published coasting for this long from then,
    instead of ending with its only source; a confirmed local track within its gate, with
    no Mode S address or Mode 3/A code telling them apart, takes it up again, number and
    identity kept. None: 5 x ``longest_period_s`` (the fuser knows no radar's own period);
    0, the default: orphans end at once. Opt-in for now: it makes three_sites' unseen
    seeds 1.000 system tracks per aircraft, but canalA's lone radar gets two position
    jumps over 1 NM where an orphan coasted up to 60 s is taken up, and orphans of
    aircraft turning as they leave cover drift kilometres (docs/fusion.md)."""
    found_delay_s: float | None = None
    """How long a confirmed local track whose address or Mode 3/A code a live system track
    carries waits to join it before founding its own; None: 2 x ``longest_period_s``."""
    merge_after: int = 3
    """Two system tracks fed by different radars that pass the gate together this many
    times in a row, with no identity telling them apart, are one aircraft: the younger
    merges into the older. Before the biases are known, the radars' local tracks of one
    aircraft can lie too far apart to associate, and each founds a system track."""
    number_reuse_delay_s: float = 300.0
    """A system track number is given again only this long after its track ended, unless
    no number past it is idle: then the one ended longest ago is taken rather than leave
    an aircraft without a system track (counted, and a status reason)."""
    max_backward_s: float = 5.0
    """"plots" method: a plot older than its system track by more than this is skipped."""
    max_sources: int = 8
    """Local tracks listed (and fused) per system track: the most recent ones."""
    adsb: AdsbMode = "reference"
    """What CAT021 reports are for: "fuse", a surveillance source of the fuser (system
    tracks of ADS-B-only aircraft, flagged when inconsistent with the radars) and the
    radars' absolute bias reference, no report both (fusion/adsb_source.py); "reference",
    the bias reference only; "off", unused. "reference" by default: what the service did
    before ADS-B was fused, so that configurations keep their results."""
    implementation: str = "compiled"
    """The plot filter's and the ML fusion's arithmetic: "compiled" (``fusion/kernels.py``,
    numba) or "numpy" (the reference: ``consider.py``, ``ml.py``); the same figures to
    1e-9 (tests/test_fusion_kernels.py)."""
    use_daps: bool = False
    """"plots" method: the plot filter takes each plot's Mode S BDS 5,0 velocity and turn
    rate as the local trackers do with ``[tracker] use_daps`` (``fusion.plot_daps``; the
    noise of ``plot_filter``'s ``dap_*`` fields, the tracker's defaults)."""
    plot_filter: TrackerConfig = field(
        default_factory=lambda: TrackerConfig(mean_sojourn_s=(150.0, 20.0, 20.0, 20.0, 20.0))
    )
    """"plots" method: the system tracks' IMM (only its model fields are used): the local
    trackers' models, with a CV model that holds longer (mean sojourn 150 s, not 60 s).
    Fed by several radars, a system track sees a turn onset within seconds and needs no
    eager switching; with 60 s its turn models' share spread its covariance and its
    straight flight. Measured (three_sites, seed 20261125; tests/test_fusion.py's
    aircraft wandering with white acceleration): multi-radar RMS 46.3, 43.8, 42.4 m and
    NEES 1.40, 1.44, 1.49 at 60, 150, 400 s; the wandering aircraft's NEES 2.41, 2.60,
    2.73 at 60, 100, 150 s (RMS 53.0, 52.1, 51.6 m), 2.95 at 300 s: beyond 150 s the
    system tracks grow over-confident under manoeuvres."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, not {self.method!r}")
        if self.adsb not in ADSB_MODES:
            raise ValueError(f"[fusion] adsb must be one of {ADSB_MODES}, not {self.adsb!r}")
        positive = ("gate", "q", "longest_period_s", "max_backward_s")
        for name in positive:
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, not {getattr(self, name)!r}")
        for name in ("max_silence_s", "max_reference_age_s", "found_delay_s"):
            value = getattr(self, name)
            if value is not None and not value > 0:
                raise ValueError(f"{name} must be positive or None, not {value!r}")
        if self.orphan_coast_s is not None and not self.orphan_coast_s >= 0:
            raise ValueError(f"orphan_coast_s must be >= 0 or None, not {self.orphan_coast_s!r}")
        for name in ("address_bonus", "address_mismatch_penalty", "mode3a_bonus"):
            if getattr(self, name) < 0:
                raise ValueError(f"{name} must be >= 0, not {getattr(self, name)!r}")
        if not 0.0 <= self.correlation < 1.0:
            raise ValueError(f"correlation must be in [0, 1), not {self.correlation!r}")
        if not isinstance(self.use_daps, bool):
            raise ValueError(f"[fusion] use_daps {self.use_daps!r}: use true or false")
        if self.implementation not in ("compiled", "numpy"):
            raise ValueError(f"implementation {self.implementation!r}: use 'compiled' or 'numpy'")
        if self.merge_after < 1:
            raise ValueError(f"merge_after must be >= 1, not {self.merge_after!r}")
        if self.reassociate_kappa <= 0 or self.reassociate_window < 1:
            raise ValueError(
                "reassociate_kappa must be > 0 (2-5) and reassociate_window >= 1, not "
                f"{self.reassociate_kappa!r}, {self.reassociate_window!r}"
            )
        if self.join_ambiguity_margin < 0:
            raise ValueError(
                f"join_ambiguity_margin must be >= 0 (0: off), not {self.join_ambiguity_margin!r}"
            )
        if self.exchange_margin < 0:
            raise ValueError(f"exchange_margin must be >= 0 (0: off), not {self.exchange_margin!r}")
        if self.reassociate_after < 1:
            raise ValueError(f"reassociate_after must be >= 1, not {self.reassociate_after!r}")
        if self.number_reuse_delay_s < 0:
            raise ValueError(
                f"number_reuse_delay_s must be >= 0, not {self.number_reuse_delay_s!r}"
            )
        if not 1 <= self.max_sources <= 8:
            raise ValueError(f"max_sources must be in 1..8, not {self.max_sources!r}")

    @property
    def silence_s(self) -> float:
        return 3.0 * self.longest_period_s if self.max_silence_s is None else self.max_silence_s

    @property
    def orphan_coast(self) -> float:
        if self.orphan_coast_s is None:
            return 5.0 * self.longest_period_s
        return self.orphan_coast_s

    @property
    def found_delay(self) -> float:
        return 2.0 * self.longest_period_s if self.found_delay_s is None else self.found_delay_s

    @property
    def reference_age_s(self) -> float:
        if self.max_reference_age_s is None:
            return 2.0 * self.longest_period_s
        return self.max_reference_age_s
