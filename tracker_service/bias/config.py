"""The bias estimator's knobs (DOMAIN.md section 6), validated once at construction.

Units follow the names; azimuths are given in degrees here for readability and converted
to radians (the estimators' unit) by ``prior_sigma`` and friends.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from tracker_service.tracking.plots import BoolArray, FloatArray

N_BIAS = 4
"""Components per radar: range offset (m), range gain (-), azimuth offset (rad), time (s)."""
TIME = 3
"""Index of the time offset in a radar's bias vector."""
COMPONENTS = ("range_offset_m", "range_gain", "azimuth_offset_rad", "time_offset_s")

METHODS = ("separated", "macro", "coupled", "off")
CLOCK_STATES = (1, 2, 3)
"""Time-error states per radar: 1 the offset alone (a random walk), 2 offset and drift,
3 offset, drift and drift rate (DOMAIN.md section 6, the UWB thesis's clock filter)."""
SECONDS_PER_HOUR = 3600.0
TIME_MODES = ("auto", "yes", "no")


def _si(range_m: float, gain: float, azimuth_deg: float, time_s: float) -> FloatArray:
    return np.array([range_m, gain, math.radians(azimuth_deg), time_s])


@dataclass(frozen=True)
class BiasConfig:
    """Every tunable of the bias estimators."""

    method: str = "separated"
    """"separated" (variant 3, scales), "macro" (variant 2), "coupled" (variant 1, the
    small-scenario reference) or "off" (no estimation: corrections are the reference values
    or zero)."""
    prior_sigma_range_m: float = 300.0
    prior_sigma_gain: float = 2e-3
    prior_sigma_azimuth_deg: float = 0.3
    prior_sigma_time_s: float = 0.3
    walk_sigma_range_m: float = 0.01
    """Random walk of the range offset, m per sqrt(s): 0.6 m in an hour. 0 is a constant bias;
    a little walk keeps the filter from freezing on biases that do drift."""
    walk_sigma_gain: float = 1e-7
    walk_sigma_azimuth_deg: float = 1e-5
    walk_sigma_time_s: float = 1e-4
    clock_states: int = 1
    """Time-error states per radar (``CLOCK_STATES``): 1 the offset as a random walk of
    ``walk_sigma_time_s``; 2 adds the drift (the offset grows by drift x dt); 3 adds the
    drift rate. Each state's process noise is its walk variance times the time step
    (Q = Q0 dt)."""
    prior_sigma_drift_s_per_h: float = 1.0
    """Prior sigma of a radar clock's drift: 1 s/h is 278 ppm, wide beside a free-running
    crystal's tens of ppm, so that the prior does not hold a bad clock back."""
    prior_sigma_drift_rate_s_per_h2: float = 0.1
    walk_sigma_drift_s_per_h: float = 1e-4
    """Random walk of the drift, s/h per sqrt(s): 6 ms/h in an hour."""
    walk_sigma_drift_rate_s_per_h2: float = 1e-4
    reception_clock: bool = True
    """With ``clock_states`` 2 or 3: each CAT034 message's time stamp (I030, the radar's
    clock at a sector boundary) against its reception time (the receiving host's clock,
    NTP/GNSS-disciplined) is a clock observation, reception - I030 = delay - offset, with
    the transmission delay an extra state per radar (``bias.clock``): it pins the drift to
    ms/h in minutes where ADS-B alone needs hours (docs/fusion.md "Clock drift")."""
    reception_jitter_s: float = 0.01
    """Sigma of the delay of a CAT034 message around its mean (the station's send timing
    and the network's queues)."""
    prior_sigma_reception_delay_s: float = 2.0
    """Prior sigma of that delay: wide, the data fix it."""
    walk_sigma_reception_delay_s: float = 1e-5
    """Random walk of the delay, s per sqrt(s): 0.6 ms in an hour."""
    estimate_time: str = "auto"
    """"auto": estimate the time offsets once an ADS-B observation has been seen or a reference
    radar pins the clock (the common offset of all radars is not observable from radars
    alone); "yes": always; "no": never (the prior is kept)."""
    reference_radars: Mapping[int, tuple[float, float, float, float]] = field(default_factory=dict)
    """Radars whose bias is known and not estimated: radar index -> (range offset m, gain,
    azimuth offset deg, time offset s); (0, 0, 0, 0) declares a radar as the reference."""
    outlier_gate: float = 13.82
    """Chi-square gate (2 dof) of each observation's residual: 13.82 is 99.9 %. Gross outliers
    (wrong association) are dropped and counted."""
    max_coupled_states: int = 600
    """The coupled filter refuses to grow its joint state (4 per aircraft + 4 per radar)
    beyond this: its cost is the square of it per plot."""
    coupled_accel_sigma: float = 0.5
    """Coupled filter: white acceleration of the aircraft's CV model, m/s^2 per axis."""
    coupled_velocity_sigma: float = 300.0
    """Coupled filter: sigma (m/s) of an aircraft's initial velocity around reference_v."""
    coupled_timeout_s: float = 60.0
    """Coupled filter: an aircraft silent this long leaves the joint state."""

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"method: {self.method!r} is not one of {', '.join(METHODS)}")
        if self.estimate_time not in TIME_MODES:
            raise ValueError(
                f"estimate_time: {self.estimate_time!r} is not one of {', '.join(TIME_MODES)}"
            )
        if self.clock_states not in CLOCK_STATES or isinstance(self.clock_states, bool):
            raise ValueError(
                f"clock_states: {self.clock_states!r} is not one of 1 (offset), 2 (offset, "
                "drift) or 3 (offset, drift, drift rate)"
            )
        positive = (
            "prior_sigma_drift_s_per_h",
            "prior_sigma_drift_rate_s_per_h2",
            "reception_jitter_s",
            "prior_sigma_reception_delay_s",
            "prior_sigma_range_m",
            "prior_sigma_gain",
            "prior_sigma_azimuth_deg",
            "prior_sigma_time_s",
            "outlier_gate",
            "coupled_velocity_sigma",
            "coupled_timeout_s",
        )
        non_negative = (
            "walk_sigma_drift_s_per_h",
            "walk_sigma_drift_rate_s_per_h2",
            "walk_sigma_reception_delay_s",
            "walk_sigma_range_m",
            "walk_sigma_gain",
            "walk_sigma_azimuth_deg",
            "walk_sigma_time_s",
            "coupled_accel_sigma",
        )
        for name in positive:
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name}: {value!r} must be a finite number > 0")
        for name in non_negative:
            value = getattr(self, name)
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: {value!r} must be a finite number >= 0")
        if not isinstance(self.reception_clock, bool):
            raise ValueError(f"reception_clock: {self.reception_clock!r} must be true or false")
        if self.max_coupled_states < 2 * N_BIAS:
            raise ValueError(f"max_coupled_states: {self.max_coupled_states!r} must be >= 8")
        for radar, values in self.reference_radars.items():
            if not (isinstance(radar, int) and radar >= 0):
                raise ValueError(f"reference_radars: key {radar!r} must be a radar index >= 0")
            if len(values) != N_BIAS or not all(math.isfinite(v) for v in values):
                raise ValueError(
                    f"reference_radars[{radar}]: {values!r} must be 4 finite numbers "
                    "(range offset m, gain, azimuth offset deg, time offset s)"
                )

    def prior_sigma(self) -> FloatArray:
        """Prior sigma of one radar's bias vector in SI units (4,)."""
        return _si(
            self.prior_sigma_range_m,
            self.prior_sigma_gain,
            self.prior_sigma_azimuth_deg,
            self.prior_sigma_time_s,
        )

    def walk_sigma(self) -> FloatArray:
        """Random-walk sigma per sqrt(s) of one radar's bias vector in SI units (4,)."""
        return _si(
            self.walk_sigma_range_m,
            self.walk_sigma_gain,
            self.walk_sigma_azimuth_deg,
            self.walk_sigma_time_s,
        )

    def clock_prior_sigma(self) -> FloatArray:
        """Prior sigma of the extra clock states (clock_states - 1,): drift in s/s, drift
        rate in s/s^2."""
        return np.array(
            [
                self.prior_sigma_drift_s_per_h / SECONDS_PER_HOUR,
                self.prior_sigma_drift_rate_s_per_h2 / SECONDS_PER_HOUR**2,
            ][: self.clock_states - 1]
        )

    def clock_walk_sigma(self) -> FloatArray:
        """Random-walk sigma per sqrt(s) of the extra clock states, SI (clock_states - 1,)."""
        return np.array(
            [
                self.walk_sigma_drift_s_per_h / SECONDS_PER_HOUR,
                self.walk_sigma_drift_rate_s_per_h2 / SECONDS_PER_HOUR**2,
            ][: self.clock_states - 1]
        )

    def reference_bias(self, n_radars: int) -> tuple[BoolArray, FloatArray]:
        """Which radars are references (L,), and their known biases in SI units (L, 4)."""
        is_reference = np.zeros(n_radars, dtype=bool)
        values = np.zeros((n_radars, N_BIAS))
        for radar, known in self.reference_radars.items():
            if radar >= n_radars:
                raise ValueError(
                    f"reference_radars: radar {radar} is outside the {n_radars} radars"
                )
            is_reference[radar] = True
            values[radar] = _si(*known)
        return is_reference, values
