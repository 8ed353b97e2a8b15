"""The local tracker's knobs, with defaults for en-route radars (4-12 s antenna periods)."""

from __future__ import annotations

from dataclasses import dataclass

KNOT_M_S = 1852.0 / 3600.0

SHARED_MODE3A_CODES = (0o7000, 0o2000, 0o1200)
"""Conspicuity and VFR codes worn by many aircraft at once: a match proves nothing."""

ASSOCIATION_METHODS = ("gnn", "jpda", "mht")
"""The associators of ``tracking.association``, by the name ``association`` takes."""


@dataclass(frozen=True)
class TrackerConfig:
    """Every tunable of ``LocalTracker``; units are SI (m, s) unless the name says otherwise.

    The IMM holds one constant-velocity model and one fixed-rate coordinated-turn model per
    entry of ``turn_rates_deg_s`` (positive: counter-clockwise, a left turn). 3 deg/s is the
    standard-rate turn of ATC; turns of other rates are followed by mixing the models.
    """

    scan_period_s: float = 5.0
    """Antenna period: the clock of misses (update it from CAT034 I041 when known)."""
    q_cv: float = 0.02
    """CV white-acceleration intensity per axis, m^2/s^3 (small: straight flight). Since
    ``address_gate`` keeps Mode S tracks through turn onsets, a quieter CV model costs
    no track breaks: 0.1 -> 0.02 took the track/plot RMS ratio of three_sites from
    0.615 to 0.596 on the 10 s radar."""
    q_ct: float = 0.5
    """Intensity of the turn models, m^2/s^3: covers roll-in, roll-out and rate mismatch."""
    turn_rates_deg_s: tuple[float, ...] = (1.5, -1.5, 3.0, -3.0)
    """Half and full standard rate: with 3 deg/s alone, the 1-2 deg/s turns of en-route
    traffic sat between the models and lost plots at onsets (three_sites: 1.03-1.11 tracks
    per aircraft with two turn models, 1.02-1.05 with four; about 6 % more time per plot)."""
    initial_model_probabilities: tuple[float, ...] = (0.8, 0.05, 0.05, 0.05, 0.05)
    mean_sojourn_s: tuple[float, ...] = (60.0, 20.0, 20.0, 20.0, 20.0)
    """Mean time spent in each model before switching; gives the IMM's Markov matrix for
    any time step, since the radars' steps are irregular. Measured on three_sites: with a
    300 s CV sojourn the IMM was slow to take up turn onsets, lost the next plot and
    restarted the track (1.7-1.9 tracks per aircraft); 60 s brings that to 1.0-1.1 at a
    cost of about 0.04 in the track/plot RMS ratio."""
    gate: float = 13.82
    """Chi-square gate of the normalised innovation squared, 2 dof (13.82: 99.9 %). The
    99 % gate (9.21) dropped one plot in a hundred of a well-tracked target, and each drop
    at a turn onset could end the track."""
    address_gate: float = 23.03
    """The chi-square gate (99.999 %) of a pair whose Mode S addresses match: still a
    kinematic test, but a wider one, since two replies with one address in one place
    are nearly always one aircraft; it keeps the track through a turn onset that
    the 99.9 % gate loses (one track in twenty broke there on ``three_sites``), while
    clutter and reflections without the address meet the normal gate."""
    address_bonus: float = 10.0
    """Cost taken off a gated pair whose Mode S addresses match."""
    address_mismatch_penalty: float = 10.0
    """Cost added to a gated pair whose Mode S addresses differ: two transponders."""
    mode3a_bonus: float = 4.0
    """Cost taken off a gated pair whose validated Mode 3/A codes match (not a shared code)."""
    confirm_m: int = 3
    confirm_n: int = 4
    echo_level_tolerance_fl: float = 3.0
    """A tentative track with the address of a live confirmed track is held back as an
    echo (reflection, split) unless its Mode 3/A differs or its flight level is further
    than this from the confirmed one's: then it is a second aircraft with the same
    address and is confirmed like any other."""
    delete_misses: int = 3
    """Consecutive missed scans after which a confirmed track is deleted."""
    tentative_delete_misses: int = 2
    miss_tolerance: float = 0.25
    """A scan counts as missed once (1 + this) periods have passed without a plot: the
    target's sector may come a little late since the target moves in azimuth."""
    min_confirm_speed_psr_only_m_s: float = 50.0 * KNOT_M_S
    """A track that never had a secondary reply (no address, no Mode 3/A) is confirmed only
    above this speed: persistent clutter (buildings, wind farms) wanders at a few m/s."""
    min_speed_m_s: float = 20.0 * KNOT_M_S
    max_speed_m_s: float = 700.0 * KNOT_M_S
    init_min_dt_periods: float = 0.5
    """Two-point initiation pairs plots of different scans: not a split of the same scan."""
    init_max_dt_periods: float = 1.6
    init_velocity_variance_scale: float = 4.0
    """Scale on the two-point velocity covariance: the difference of two plots is the worst
    known part of a new track, and a 3-sigma velocity error there would lose the next plot
    and restart the track two scans later; a wider early gate costs less."""
    max_backward_s: float = 2.0
    """A plot older than its track's state by more than this is dropped and counted."""
    max_clock_jump_periods: float = 2.0
    """A batch whose times lie more than this many antenna periods ahead of or behind
    the tracker's clock is held back, not taken as the present (``tracking.clock``): a
    2.25-period jump would already delete every tentative track."""
    clock_resync_batches: int = 3
    """Batches in a row that jump the same way, over at least one antenna period of their
    own time, after which the tracker re-synchronises to them (a radar restarted with
    another clock, or back after an outage); the held plots are lost (counted)."""
    max_position_variance_m2: float = 4.0e6
    """A coasting track whose position variance (trace) exceeds this is deleted."""
    vertical_q: tuple[float, float, float] = (1e-5, 1e-4, 0.01)
    """The vertical IMM's noise intensities (``tracking.vertical``): level (random walk of
    the level, FL^2/s), steady climb or descent and vertical manoeuvre (on the climb
    rate, FL^2/s^3: over a 10 s scan 60 and 600 ft/min of rate change)."""
    vertical_sojourn_s: tuple[float, float, float] = (120.0, 60.0, 10.0)
    """Mean time in each vertical model: levels and steady climbs last minutes, onsets and
    level-offs seconds."""
    vertical_initial_probabilities: tuple[float, float, float] = (0.6, 0.2, 0.2)
    level_rate_variance: float = 1e-6
    """(FL/s)^2 of the level model's zero rate (6 ft/min)."""
    baro_rate_sigma_fpm: float = 150.0
    """Sigma of BDS 6,0's barometric vertical rate (32 ft/min steps, the static port's lag
    and noise)."""
    inertial_rate_sigma_fpm: float = 80.0
    """Sigma of BDS 6,0's inertial (baro-inertial) vertical rate."""
    initial_climb_variance: float = 1.0
    """(FL/s)^2: 1 FL/s is 6,000 ft/min, more than any airliner climbs."""
    fl_step_mode_s: float = 0.25
    """Flight-level quantisation of Mode S plots (25 ft); the variance is step^2/12."""
    fl_step_mode_c: float = 1.0
    """Flight-level quantisation of Mode C (Gillham, 100 ft)."""
    fl_gate: float = 16.0
    """1-dof gate on flight-level innovations: garbled Mode C is ignored, then the filter
    restarts after ``fl_max_rejects`` rejections in a row (a real level change)."""
    fl_max_rejects: int = 2
    association: str = "gnn"
    """How gated plots go to tracks (``tracking.association``): "gnn", global nearest
    neighbour, one plot per track, the right choice where aircraft are well apart;
    "jpda", joint probabilistic association without coalescence, for closely spaced
    targets without distinct identities; "mht", track-oriented multiple hypotheses on
    the ambiguous clusters and GNN elsewhere (docs/association.md)."""
    detection_probability: float = 0.9
    """Pd of the JPDA likelihood: the prior that a track's own plot is in this batch."""
    clutter_density_per_km2: float = 0.01
    """Density of plots that are nobody's (clutter, new targets) in the JPDA likelihood:
    a plot at the edge of a 100 m gate is as likely a track's as clutter's at about
    0.01 per km^2, so a lone good pair keeps nearly all its weight."""
    initiation_max_weight: float = 0.2
    """With weighted association (JPDA), a plot that some track takes with at least this
    weight is that track's (in its mixture) and starts no track: the third aircraft of
    three abreast 1 km apart, whose plots a neighbour's mixture takes with a few per
    cent, still does."""
    jpda_max_events: int = 5000
    """A cluster is enumerated exactly when the product of its tracks' options (gated
    plots + the miss) is at most this; beyond, ``jpda_k_best`` events are ranked."""
    jpda_k_best: int = 64
    """The most likely joint events (Murty's ranking) kept for a large cluster."""
    use_daps: bool = False
    """Mode S DAPs (BDS 5,0) in the horizontal filter: the velocity as a measurement and
    the turn rate as evidence for the turn models (``tracking.daps``), and the BDS 6,0
    vertical rates and BDS 4,0 selected altitude in the vertical one (with the fuser's
    ``[fusion] use_daps``, its plot filter too). Off by default: on three_sites (seeds
    1-5 and the scenario's) they cut the local RMS by a quarter to a third and the
    multi-radar system RMS by a quarter, but on the scenario seed one local track is still
    lost at a sharp turn (1.022 system tracks per aircraft against the 1.02 target) and
    single coverage stays 4 m worse than 25/11's average local track; docs/tracking.md
    "Mode S DAPs", docs/fusion.md "Mode S DAPs in the plot filter"."""
    dap_speed_sigma_m_s: float = 1.0
    """Along-track sigma of the BDS 5,0 velocity: 2 kt steps, the avionics' error and
    speed changes over the register's age."""
    dap_track_sigma_deg: float = 0.5
    """Sigma of the true track angle (0.18 deg steps, heading/drift sources)."""
    dap_latency_s: float = 1.3
    """Oldest age of a register at its extraction (Doc 9871: BDS 5,0 refreshed every
    1.3 s at most); in a turn it lags by the turn over its age."""
    dap_turn_rate_sigma_deg_s: float = 0.5
    """Sigma of the turn rate from the track angle rate or the roll angle."""
    dap_velocity_gate: float = 13.82
    """Chi-square (2 dof, 99.9 %) of the DAP velocity against its track: beyond, unused."""
    mht_n_scan: int = 3
    """MHT's N-scan pruning: a choice older than N - 1/2 antenna periods is fixed to the
    best hypothesis's (N >= 2: each choice is deferred by at least one scan)."""
    mht_max_hypotheses: int = 12
    """Global hypotheses kept per MHT cluster (and Murty's k per parent)."""
    mht_ambiguity_llr: float = 6.9
    """A cluster of free tracks is branched when its second best assignment is within
    this log-likelihood ratio of the best (6.9: 1 in 1,000)."""
    mht_prune_llr: float = 6.9
    """Hypotheses further than this below the best are dropped. As the ambiguity test's:
    a cluster whose alternatives are all that far behind has nothing left to defer and
    dissolves (with 9.2, a track's "missed its plot, the plot was clutter" stayed within
    reach after every scan, and no cluster ever ended)."""
    mht_max_cluster_tracks: int = 6
    """A component of more tracks is left to GNN: the cost of branching stays bounded."""
    birth_relative_speed_sigma_m_s: float = 40.0
    """With MHT, a plot left over in the gate of a confirmed or coasting track starts a
    track at once, with that neighbour's velocity (``initiate.neighbour_state``); this is
    the sigma (per axis) of the new aircraft's velocity relative to it. A two-point start
    there paired left-over plots of the two aircraft of a close pair."""
    clutter_map: bool = True
    """Learn a clutter map (``tracking.clutter``) from the plots of no confirmed track:
    tracks seeded in its dense cells need ``clutter_extra_hits`` more hits to be
    confirmed, and JPDA weighs each pair against its cell's density."""
    clutter_origin_m: tuple[float, float] = (0.0, 0.0)
    """The radar's site in the system plane: the centre of the map's cells (the radar
    stage sets it from the radar's configured site)."""
    clutter_range_cell_m: float = 1852.0
    clutter_azimuth_cell_deg: float = 1.0
    """1 NM by 1 degree: about the extent of one persistent clutter source, and a cell
    an aircraft crosses in a few scans, so that it adds little to any one cell."""
    clutter_max_range_m: float = 600_000.0
    clutter_time_constant_s: float = 300.0
    """Memory of the map: long against a scan, so that a persistent source counts as
    such after a minute, short against the hours over which clutter changes (weather,
    anaprop)."""
    clutter_dense_per_scan: float = 0.2
    """A cell holding more plots of no confirmed track per scan than this is dense: a
    persistent source (seen in most scans) is well above it; random clutter and aircraft
    crossing the cell, far below."""
    clutter_extra_hits: int = 3
    """Extra hits (in a window as much longer) a track seeded in a dense cell needs to be
    confirmed: 3 of 4 becomes 6 of 7."""
    implementation: str = "compiled"
    """The code of the filters (the IMM, the vertical filter): "compiled"
    (``tracking.kernels``, numba) or "numpy" (the plain reference: ``tracking.imm`` and
    array operations); the same filters to rounding (tests hold them to 1e-9)."""

    def __post_init__(self) -> None:
        n_models = 1 + len(self.turn_rates_deg_s)
        for name in ("initial_model_probabilities", "mean_sojourn_s"):
            if len(getattr(self, name)) != n_models:
                raise ValueError(f"{name} needs {n_models} entries (CV + each turn rate)")
        if not 0 < self.confirm_m <= self.confirm_n <= 32:
            raise ValueError("need 0 < confirm_m <= confirm_n <= 32")
        if self.scan_period_s <= 0 or self.gate <= 0 or self.address_gate <= 0:
            raise ValueError("scan_period_s, gate and address_gate must be positive")
        if self.association not in ASSOCIATION_METHODS:
            raise ValueError(
                f"association: {self.association!r} is not one of {list(ASSOCIATION_METHODS)}"
            )
        if not 0.0 < self.detection_probability < 1.0 or self.clutter_density_per_km2 <= 0:
            raise ValueError("need 0 < detection_probability < 1 and clutter_density_per_km2 > 0")
        if self.jpda_max_events < 1 or self.jpda_k_best < 1:
            raise ValueError("jpda_max_events and jpda_k_best must be >= 1")
        if self.mht_n_scan < 2 or self.mht_max_hypotheses < 2 or self.mht_max_cluster_tracks < 1:
            raise ValueError(
                "need mht_n_scan >= 2, mht_max_hypotheses >= 2, mht_max_cluster_tracks >= 1"
            )
        if not 0 < self.mht_ambiguity_llr <= self.mht_prune_llr:
            raise ValueError("need 0 < mht_ambiguity_llr <= mht_prune_llr")
        if not self.birth_relative_speed_sigma_m_s > 0:
            raise ValueError("birth_relative_speed_sigma_m_s must be positive")
        if not self.max_clock_jump_periods > 0 or self.clock_resync_batches < 1:
            raise ValueError("max_clock_jump_periods and clock_resync_batches must be positive")
        for name in ("vertical_q", "vertical_sojourn_s", "vertical_initial_probabilities"):
            if len(getattr(self, name)) != 3:
                raise ValueError(f"{name} needs 3 entries (level, steady, manoeuvre)")
        if min(self.vertical_sojourn_s) <= 0 or min(self.vertical_q) < 0:
            raise ValueError("vertical_sojourn_s must be positive and vertical_q >= 0")
        if not isinstance(self.use_daps, bool):
            raise ValueError(f"use_daps {self.use_daps!r}: use true or false")
        for name in ("dap_speed_sigma_m_s", "dap_track_sigma_deg", "dap_turn_rate_sigma_deg_s"):
            if not getattr(self, name) > 0:
                raise ValueError(f"{name} must be positive, got {getattr(self, name)!r}")
        if not 0 <= self.clutter_extra_hits <= 32 - self.confirm_n:
            raise ValueError(f"clutter_extra_hits must be in [0, {32 - self.confirm_n}]")
        if (
            min(
                self.clutter_range_cell_m,
                self.clutter_azimuth_cell_deg,
                self.clutter_max_range_m,
                self.clutter_time_constant_s,
            )
            <= 0
        ):
            raise ValueError("the clutter map's cells, range and time constant must be positive")
        if self.implementation not in ("compiled", "numpy"):
            raise ValueError(f"implementation {self.implementation!r}: use 'compiled' or 'numpy'")

    @property
    def n_models(self) -> int:
        return 1 + len(self.turn_rates_deg_s)
