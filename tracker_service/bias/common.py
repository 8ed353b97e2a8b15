"""What the three split filters share: the interface, observability, gating and the update.

Every variant updates with Blom's form ``x += G S^-1 nu, P -= G S^-1 G^T`` where G is the
cross-covariance of the state with the residual and S the residual's covariance (the
INVERSE of S: DOMAIN.md section 6 corrects the note's typo). Components that are not
observable are "considered" (Schmidt): their uncertainty enters S but they are not updated,
so they keep their prior.
"""

from __future__ import annotations

import functools
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from tracker_service.bias.clock import ClockModel
from tracker_service.bias.config import N_BIAS, TIME, BiasConfig
from tracker_service.bias.observations import BiasObservations, ObservationKind
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray

FROM_OTHER_RADARS = "other_radars"
"""Traffic this radar shares with other radars whose bias is estimated (relative)."""
FROM_REFERENCE_RADAR = "reference_radar"
"""Traffic this radar shares with a reference radar (a radar whose bias is configured)."""
FROM_FIELD_MONITOR = "field_monitor"
"""A fixed transponder of this radar at a surveyed position (range and azimuth)."""
FROM_ADSB = "adsb"
"""ADS-B reports of aircraft this radar sees (position and, alone, time)."""
FROM_CONFIGURATION = "configuration"
"""The radar is a reference: its bias is given, not estimated."""

AIRCRAFT, FIELD_MONITOR, ADSB = (
    ObservationKind.AIRCRAFT.value,
    ObservationKind.FIELD_MONITOR.value,
    ObservationKind.ADSB.value,
)
"""``ObservationKind``'s values, for array comparisons."""

ObservedFrom = tuple[tuple[str, ...], ...]
"""One radar's, per component [range offset, gain, azimuth, time]: the sources that make it
observable (empty: not observable, the prior is kept)."""


@dataclass(frozen=True)
class BiasEstimates:
    """Per radar (L): bias s (L,4), covariance P (L,4,4), observations used and rejected,
    which components are estimated (L,4), which radars are references (L,), and what each
    component is observable from (``ObservedFrom``)."""

    s: FloatArray
    P: FloatArray
    n_used: IntArray
    n_rejected: IntArray
    estimated: BoolArray
    reference: BoolArray
    observed_from: tuple[ObservedFrom, ...]
    clock: FloatArray = field(default_factory=lambda: np.zeros((0, 0)))
    """Per radar the extra clock states (L, clock_states - 1): drift s/s, drift rate s/s^2."""
    clock_P: FloatArray = field(default_factory=lambda: np.zeros((0, 0, 0)))
    """Their covariance (L, clock_states - 1, clock_states - 1)."""

    def sigma(self) -> FloatArray:
        """1-sigma of each component (L,4)."""
        return np.sqrt(np.maximum(np.diagonal(self.P, axis1=1, axis2=2), 0.0))


class BiasEstimator(Protocol):
    def update(self, obs: BiasObservations) -> None: ...

    def estimates(self) -> BiasEstimates: ...

    def correction(self, radar: int) -> tuple[FloatArray, FloatArray]: ...

    def clock_correction(self, radar: int) -> tuple[FloatArray, FloatArray]: ...

    def update_reception(self, radar: int, evidence: FloatArray) -> None: ...


def split_update(
    x: FloatArray,
    P: FloatArray,
    G: FloatArray,
    S: FloatArray,
    nu: FloatArray,
    free: BoolArray,
    gate: float,
) -> bool:
    """One gated update in place; False (nothing changed) when the residual is an outlier.

    The gain K = G S^-1 is zeroed on the rows not free; the covariance update
    P - K G^T - G K^T + K S K^T is then exact for any such K (it reduces to P - G S^-1 G^T
    on the free block and leaves the considered block untouched).
    """
    s_inv = np.linalg.inv(S)
    if float(nu @ s_inv @ nu) > gate:
        return False
    K = G @ s_inv
    K[~free] = 0.0
    x += K @ nu
    KG = K @ G.T
    P += K @ S @ K.T - KG - KG.T
    P[:] = 0.5 * (P + P.T)
    return True


def information_update(
    x: FloatArray, P: FloatArray, info: FloatArray, score: FloatArray, free: BoolArray
) -> None:
    """``split_update`` of a stacked batch whose noises are independent, in place.

    For y_i = C_i x + n_i (n_i ~ N_i) the stacked gain reduces by the push-through identity
    C^T (C P C^T + N)^-1 = (1 + I P)^-1 C^T N^-1, with I = sum C_i^T N_i^-1 C_i (info) and
    b = sum C_i^T N_i^-1 nu_i (score): K nu = A b and K G^T = A I P with A = P (1 + I P)^-1.
    O(n) in the batch instead of inverting a 2n x 2n S; the rows not free are considered
    as in ``split_update``.
    """
    eye, D, either, both = _free_terms(free.tobytes())
    A = np.linalg.solve((eye + info @ P).T, P).T
    M = A @ info @ P
    M = 0.5 * (M + M.T)
    x += D * (A @ score)
    P -= M * either - M * both


@functools.lru_cache(maxsize=64)
def _free_terms(free: bytes) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """``information_update``'s terms of a ``free`` mask (its bytes): the identity, D
    (1.0 where free), D_i + D_j and D_i D_j; the same few masks come every update."""
    D = np.frombuffer(free, dtype=np.bool_).astype(float)
    terms = (np.eye(len(D)), D, D[:, None] + D[None, :], D[:, None] * D[None, :])
    for term in terms:
        term.flags.writeable = False
    return terms


class BiasFilterBase(ABC):
    """State bookkeeping common to the variants: time, observability, references, counts."""

    times_from_traffic = True
    """Whether traffic shared with other radars updates the time offsets (once a clock is
    pinned): what ``observed_from`` reports."""
    reads_contributors = True
    """Whether ``_process`` reads the observations' contributors and their geometry (the
    macro filter's F_x and F_s): ``update`` leaves them out of its sorted copy if not."""

    def __init__(self, config: BiasConfig, n_radars: int) -> None:
        self.config = config
        self.n_radars = n_radars
        self.is_reference, self.reference_value = config.reference_bias(n_radars)
        self.n_used = np.zeros(n_radars, dtype=np.int64)
        self.n_rejected = np.zeros(n_radars, dtype=np.int64)
        self._traffic_seen = np.zeros(n_radars, dtype=bool)
        self._absolute_seen = np.zeros(n_radars, dtype=bool)
        self._monitor_seen = np.zeros(n_radars, dtype=bool)
        self._clock_seen = np.zeros(n_radars, dtype=bool)
        # The filters work on s / prior sigma: gain (1e-3) and azimuth (1e-3 rad) beside
        # positions (1e5 m) made the joint covariance so ill-conditioned (1e-9 beside 1e4)
        # that the coupled filter's covariance lost positive-definiteness after ~400 plots.
        self.scale = config.prior_sigma()
        self._walk_var = (config.walk_sigma() / self.scale) ** 2
        self.clock = ClockModel(config)
        self.n_state = N_BIAS + self.clock.n_extra
        """States per radar: the 4 biases, then the extra clock states (``bias.clock``)."""
        self.reception_used = np.zeros(n_radars, dtype=np.int64)
        self.reception_rejected = np.zeros(n_radars, dtype=np.int64)
        """CAT034 messages taken as clock observations, and those out of the gate."""

    def prior(self) -> tuple[FloatArray, FloatArray]:
        """Joint prior of all radars' scaled biases, then their extra clock states:
        (nL,) and (nL, nL), n = ``n_state``; references exact (their clocks too)."""
        extra = self.clock.n_extra * self.n_radars
        s = np.concatenate([(self.reference_value / self.scale).reshape(-1), np.zeros(extra)])
        var = np.ones(len(s))
        var[: N_BIAS * self.n_radars][np.repeat(self.is_reference, N_BIAS)] = 0.0
        var[N_BIAS * self.n_radars :][np.repeat(self.is_reference, self.clock.n_extra)] = 0.0
        return s, np.diag(var)

    def state_free(self, free: BoolArray | None = None) -> BoolArray:
        """``free`` per radar over its biases and extra clock states (L, n_state): the
        clock states are free with the time offset. ``free``: ``free()`` if known."""
        free = self.free() if free is None else free
        return np.concatenate([free, np.repeat(free[:, TIME:], self.clock.n_extra, axis=1)], 1)

    def state_walk_rate(self, free: BoolArray | None = None) -> FloatArray:
        """``walk_rate`` per radar over its biases and extra clock states (L, n_state).
        ``free``: ``free()`` if known (it costs a few dozen array operations)."""
        free = self.free() if free is None else free
        clock = np.where(free[:, TIME, None], self.clock.walk_var[None, :], 0.0)
        return np.concatenate([self.walk_rate(free), clock], axis=1)

    def joint_free(self) -> BoolArray:
        """``state_free`` in the layout of ``prior``."""
        return _joint_layout(self.state_free())

    def joint_walk_rate(self) -> FloatArray:
        """``state_walk_rate`` in the layout of ``prior``."""
        return _joint_layout(self.state_walk_rate())

    def predict_joint(self, x: FloatArray, P: FloatArray, dt: float, bias_start: int = 0) -> None:
        """The joint state of ``prior`` (placed from ``bias_start`` in x and P) over dt:
        the walks, then the clock transition of the radars whose time is estimated."""
        if dt == 0.0:
            return
        n = self.n_state * self.n_radars
        index = np.arange(bias_start, bias_start + n)
        P[index, index] += self.joint_walk_rate() * abs(dt)
        offset, extra = self.clock.indices(self.n_radars, bias_start)
        self.clock.predict(x, P, dt, offset, extra, self.free()[:, TIME])

    def free(self) -> BoolArray:
        """Which components (L,4) the data seen so far make observable.

        Range offset, gain and azimuth: a fixed reference (field monitor, ADS-B) seen by the
        radar, or traffic seen by it and by another radar (surveyed sites: rotations and
        stretches about different centres differ). Time: moving traffic and a clock
        reference (ADS-B or a reference radar) under "auto".
        """
        other_traffic = self._traffic_seen.sum() - self._traffic_seen.astype(np.int64) > 0
        seen = self._absolute_seen | (self._traffic_seen & other_traffic)
        mode = self.config.estimate_time
        clock = mode == "yes" or (
            mode == "auto" and bool(self._clock_seen.any() or self.is_reference.any())
        )
        free = np.repeat(seen[:, None], N_BIAS, axis=1)
        free[:, TIME] &= clock
        free[self.is_reference] = False
        return free

    def observed_from(self) -> tuple[ObservedFrom, ...]:
        """What makes each radar's free components observable (``free``): its field
        monitors and ADS-B (absolute), the traffic it shares with reference radars or with
        other radars; a reference radar's come from the configuration. A time offset is
        observable from ADS-B, and from traffic only where ``free`` says a clock is pinned
        (ADS-B elsewhere, a reference radar, or ``estimate_time = "yes"``)."""
        free = self.free()
        out: list[ObservedFrom] = []
        for radar in range(self.n_radars):
            if self.is_reference[radar]:
                out.append(((FROM_CONFIGURATION,),) * N_BIAS)
                continue
            others = self._traffic_seen.copy()
            others[radar] = False
            traffic: tuple[str, ...] = ()
            if self._traffic_seen[radar]:
                traffic = tuple(
                    name
                    for name, seen in (
                        (FROM_REFERENCE_RADAR, (others & self.is_reference).any()),
                        (FROM_OTHER_RADARS, (others & ~self.is_reference).any()),
                    )
                    if seen
                )
            absolute = tuple(
                name
                for name, seen in (
                    (FROM_FIELD_MONITOR, self._monitor_seen[radar]),
                    (FROM_ADSB, self._clock_seen[radar]),
                )
                if seen
            )
            sources: list[tuple[str, ...]] = [absolute + traffic] * N_BIAS
            clock = (FROM_ADSB,) if self._clock_seen[radar] else ()
            sources[TIME] = clock + (traffic if self.times_from_traffic else ())
            out.append(tuple(names if free[radar, k] else () for k, names in enumerate(sources)))
        return tuple(out)

    def update(self, obs: BiasObservations) -> None:
        if obs.n_radars != self.n_radars:
            raise ValueError(
                f"observations for {obs.n_radars} radars given to an estimator of {self.n_radars}"
            )
        if len(obs) == 0:
            return
        # Plain values: numpy compares with an IntEnum member through a slow path.
        traffic = obs.kind == AIRCRAFT
        self._traffic_seen[obs.radar[traffic]] = True
        self._absolute_seen[obs.radar[~traffic]] = True
        self._monitor_seen[obs.radar[obs.kind == FIELD_MONITOR]] = True
        self._clock_seen[obs.radar[obs.kind == ADSB]] = True
        order = np.argsort(obs.time, kind="stable")
        self._process(obs.subset(order, scale_c=self.scale, contributors=self.reads_contributors))

    def walk_rate(self, free: BoolArray | None = None) -> FloatArray:
        """Random-walk variance per second (L,4) on the free components (the rest keep the
        prior); ``free``: ``free()`` if known."""
        return np.where(self.free() if free is None else free, self._walk_var, 0.0)

    def count(self, radar: IntArray, accepted: BoolArray) -> None:
        # bincount rather than np.add.at, which costs tens of microseconds a call.
        self.n_used += np.bincount(radar[accepted], minlength=self.n_radars)
        self.n_rejected += np.bincount(radar[~accepted], minlength=self.n_radars)

    def estimates(self) -> BiasEstimates:
        s, P = self._unscaled()
        clock, clock_P = self._clock_unscaled()
        return BiasEstimates(
            clock=clock,
            clock_P=clock_P,
            s=s,
            P=P,
            n_used=self.n_used.copy(),
            n_rejected=self.n_rejected.copy(),
            estimated=self.free(),
            reference=self.is_reference.copy(),
            observed_from=self.observed_from(),
        )

    def correction(self, radar: int) -> tuple[FloatArray, FloatArray]:
        """The bias (4,) to take off radar's plots (y - C s) and its covariance (4,4)."""
        s, P = self.bias_state()
        # ``_unscaled``'s products, for this radar's rows only.
        return s[radar] * self.scale, P[radar] * self.scale[:, None] * self.scale[None, :]

    def clock_correction(self, radar: int) -> tuple[FloatArray, FloatArray]:
        """The radar's extra clock states (clock_states - 1,) [drift s/s, drift rate
        s/s^2] and their covariance."""
        clock, clock_P = self._clock_unscaled()
        return clock[radar], clock_P[radar]

    def update_reception(self, radar: int, evidence: FloatArray) -> None:
        """CAT034 time stamps of ``radar`` against their reception (``bias.reception``:
        rows [radar time s, reception s]) as clock observations (``BiasConfig.
        reception_clock``); only the separated filter takes them, the others ignore them."""
        return

    def _clock_unscaled(self) -> tuple[FloatArray, FloatArray]:
        # The published states: the reception delay (last, if any) is the receiver's.
        n = self.clock.n_clock
        c, P = self.clock_state()
        c, P = c[:, :n], P[:, :n, :n]
        scale = self.clock.scale[:n]
        return c * scale, P * scale[:, None] * scale[None, :]

    def _unscaled(self) -> tuple[FloatArray, FloatArray]:
        s, P = self.bias_state()
        return s * self.scale, P * self.scale[:, None] * self.scale[None, :]

    @abstractmethod
    def _process(self, obs: BiasObservations) -> None:
        """Update with a non-empty batch sorted by time."""

    @abstractmethod
    def bias_state(self) -> tuple[FloatArray, FloatArray]:
        """Per-radar scaled bias (L,4) and its covariance (L,4,4), views allowed."""

    @abstractmethod
    def clock_state(self) -> tuple[FloatArray, FloatArray]:
        """Per-radar scaled extra clock states (L,E) and their covariance (L,E,E)."""


def _joint_layout(per_radar: npt.NDArray[Any]) -> npt.NDArray[Any]:
    """(L, n_state) per-radar values as the joint state of ``prior`` lays them out: every
    radar's 4 biases, then every radar's extra clock states."""
    return np.concatenate([per_radar[:, :N_BIAS].reshape(-1), per_radar[:, N_BIAS:].reshape(-1)])


def joint_blocks(
    s: FloatArray, P: FloatArray, n_radars: int, size: int = N_BIAS, start: int = 0
) -> tuple[FloatArray, FloatArray]:
    """Per-radar (L,size) and (L,size,size) blocks of a joint vector whose radars' blocks
    of ``size`` start at ``start`` (the biases: 4 from 0; the extra clock states after
    them)."""
    idx = start + np.arange(n_radars * size).reshape(n_radars, size)
    return s[idx], P[idx[:, :, None], idx[:, None, :]]


def joint_clock_blocks(
    base: BiasFilterBase, s: FloatArray, P: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """The extra clock states' blocks of ``base``'s joint state (``prior``'s layout)."""
    return joint_blocks(s, P, base.n_radars, base.clock.n_extra, N_BIAS * base.n_radars)


class OffEstimator(BiasFilterBase):
    """method "off": no estimation; the corrections are the reference values (or zero)."""

    def __init__(self, config: BiasConfig, n_radars: int) -> None:
        super().__init__(config, n_radars)
        self._s, self._P = self.prior()

    def free(self) -> BoolArray:
        return np.zeros((self.n_radars, N_BIAS), dtype=bool)

    def _process(self, obs: BiasObservations) -> None:
        return

    def bias_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_blocks(self._s, self._P, self.n_radars)

    def clock_state(self) -> tuple[FloatArray, FloatArray]:
        return joint_clock_blocks(self, self._s, self._P)
