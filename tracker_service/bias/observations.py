"""What the bias estimators consume: plots in the system plane beside their references.

A plot y (plane metres) of radar l relates linearly to the true position p:
``y = p + C s_l + w``, w ~ N(0, R), with C (2x4) = [u_r, rho u_r, u_theta, -v] and
s_l = [range offset m, range gain, azimuth offset rad, time offset s] (measured minus true).
The chain builds C (geodesy gives u_r, u_theta, rho; the fuser gives v).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.bias.config import N_BIAS
from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray


class ObservationKind(IntEnum):
    AIRCRAFT = 0
    """Traffic: the reference is other radars' fused tracks (or the system prediction)."""
    FIELD_MONITOR = 1
    """A fixed transponder at a surveyed position: reference_P ~ 0 and v = 0."""
    ADSB = 2
    """A plot paired with the aircraft's ADS-B report interpolated to the plot's time."""


@dataclass(frozen=True)
class BiasObservations:
    """A batch of N observations as numpy columns (L radars); see ``make_observations``.

    reference_xy/P: the position at this time predicted by something this plot has not
    updated (other radars' bias-corrected tracks, a surveyed position, ADS-B); its
    covariance should hold the other radars' bias uncertainty too (``fuse_references``).
    prediction_xy/P: the system track's prediction from all radars (the macro filter's
    residual); contributors (N, L) the radars feeding that system track, with their latest
    R and C for this aircraft.
    """

    radar: IntArray
    time: FloatArray
    y: FloatArray
    R: FloatArray
    C: FloatArray
    kind: npt.NDArray[np.int8]
    group: IntArray
    reference_xy: FloatArray
    reference_P: FloatArray
    reference_v: FloatArray
    prediction_xy: FloatArray
    prediction_P: FloatArray
    contributors: BoolArray
    contributor_R: FloatArray
    contributor_C: FloatArray

    def __post_init__(self) -> None:
        n = self.radar.shape[0]
        n_radars = self.contributors.shape[1] if self.contributors.ndim == 2 else -1
        shapes = _shapes(n, n_radars)
        # All at once (a batch is built several times): then the first one off, named.
        if tuple(getattr(self, name).shape for name, _ in _TRAILING_SHAPES) != shapes:
            for (name, _), expected in zip(_TRAILING_SHAPES, shapes, strict=True):
                actual = getattr(self, name).shape
                if actual != expected:
                    raise ValueError(
                        f"BiasObservations.{name}: shape {actual}, expected {expected}"
                    )
        if n and (self.radar.min() < 0 or self.radar.max() >= n_radars):
            raise ValueError(f"BiasObservations.radar: indices must lie in [0, {n_radars})")

    def __len__(self) -> int:
        return int(self.radar.shape[0])

    @property
    def n_radars(self) -> int:
        return int(self.contributors.shape[1])

    def subset(
        self,
        index: IntArray | BoolArray,
        scale_c: FloatArray | None = None,
        *,
        contributors: bool = True,
    ) -> BiasObservations:
        """The rows selected by a mask or an index array, in that order (a mask that
        keeps every row: these observations, not a copy); ``scale_c``: their C and
        contributor_C multiplied by it (the filters' scaled biases, ``BiasFilterBase``).
        ``contributors`` False: without the contributors and their geometry (none, as
        ``make_observations`` leaves them, as read-only zero views), for a filter that
        does not read them (a batch's contributor_C alone is 64 numbers per row and
        radar: most of what a copy costs)."""
        if scale_c is None and contributors and index.dtype == np.bool_ and index.all():
            return self
        names = self.__dataclass_fields__ if contributors else _ROW_FIELDS
        fields = {name: getattr(self, name)[index] for name in names}
        if scale_c is not None:
            fields["C"] = fields["C"] * scale_c
        if not contributors:
            n = len(fields["radar"])
            for name in _CONTRIBUTOR_FIELDS:
                fields[name] = _zeros(name, (n, *getattr(self, name).shape[1:]))
        elif scale_c is not None:
            fields["contributor_C"] = fields["contributor_C"] * scale_c
        # Rows of these (checked) observations: the shapes and radars hold; no second check.
        rows = object.__new__(BiasObservations)
        rows.__dict__.update(fields)
        return rows


_TRAILING_SHAPES: tuple[tuple[str, tuple[int | None, ...]], ...] = (
    ("radar", ()),
    ("time", ()),
    ("y", (2,)),
    ("R", (2, 2)),
    ("C", (2, N_BIAS)),
    ("kind", ()),
    ("group", ()),
    ("reference_xy", (2,)),
    ("reference_P", (2, 2)),
    ("reference_v", (2,)),
    ("prediction_xy", (2,)),
    ("prediction_P", (2, 2)),
    ("contributors", (None,)),
    ("contributor_R", (None, 2, 2)),
    ("contributor_C", (None, 2, N_BIAS)),
)
"""Each field's shape after its leading N (None: the number of radars)."""


_CONTRIBUTOR_FIELDS = ("contributors", "contributor_R", "contributor_C")
_ROW_FIELDS = tuple(name for name, _ in _TRAILING_SHAPES if name not in _CONTRIBUTOR_FIELDS)


@functools.lru_cache(maxsize=256)
def _zeros(name: str, shape: tuple[int, ...]) -> npt.NDArray[Any]:
    """``subset(..., contributors=False)``'s contributor field ``name`` of ``shape``: no
    contributors, read-only and shared (the batches' sizes repeat)."""
    zeros = np.zeros(shape, dtype=bool if name == "contributors" else np.float64)
    zeros.flags.writeable = False
    return zeros


@functools.lru_cache(maxsize=64)
def _shapes(n: int, n_radars: int) -> tuple[tuple[int, ...], ...]:
    """Each field's whole shape for N observations of ``n_radars`` radars (a batch's
    observations are built several times: once per size)."""
    return tuple(
        (n, *(n_radars if size is None else size for size in trailing))
        for _, trailing in _TRAILING_SHAPES
    )


def make_observations(
    n_radars: int,
    radar: npt.ArrayLike,
    time: npt.ArrayLike,
    y: npt.ArrayLike,
    R: npt.ArrayLike,
    C: npt.ArrayLike,
    reference_xy: npt.ArrayLike,
    reference_P: npt.ArrayLike,
    *,
    kind: npt.ArrayLike | int = ObservationKind.AIRCRAFT,
    group: npt.ArrayLike | int = -1,
    reference_v: npt.ArrayLike | None = None,
    prediction_xy: npt.ArrayLike | None = None,
    prediction_P: npt.ArrayLike | None = None,
    contributors: npt.ArrayLike | None = None,
    contributor_R: npt.ArrayLike | None = None,
    contributor_C: npt.ArrayLike | None = None,
) -> BiasObservations:
    """A batch with defaults for the optional columns.

    Defaults: reference_v zero, the prediction equal to the reference, no contributors
    (the macro filter then has no H term). Scalars kind and group apply to every row.
    """
    radar_a = np.asarray(radar, dtype=np.int64).reshape(-1)
    n = radar_a.shape[0]
    ref_xy = np.asarray(reference_xy, dtype=np.float64)
    ref_p = np.asarray(reference_P, dtype=np.float64)
    return BiasObservations(
        radar=radar_a,
        time=np.asarray(time, dtype=np.float64).reshape(-1),
        y=np.asarray(y, dtype=np.float64),
        R=np.asarray(R, dtype=np.float64),
        C=np.asarray(C, dtype=np.float64),
        # A plain int: numpy converts an IntEnum member through a slow path.
        kind=np.full(n, int(kind) if isinstance(kind, int) else kind, dtype=np.int8),
        group=np.full(n, group, dtype=np.int64),
        reference_xy=ref_xy,
        reference_P=ref_p,
        reference_v=_or_zeros(reference_v, (n, 2)),
        prediction_xy=ref_xy if prediction_xy is None else np.asarray(prediction_xy, float),
        prediction_P=ref_p if prediction_P is None else np.asarray(prediction_P, float),
        contributors=np.zeros((n, n_radars), dtype=bool)
        if contributors is None
        else np.asarray(contributors, dtype=bool),
        contributor_R=_or_zeros(contributor_R, (n, n_radars, 2, 2)),
        contributor_C=_or_zeros(contributor_C, (n, n_radars, 2, N_BIAS)),
    )


def _or_zeros(value: npt.ArrayLike | None, shape: tuple[int, ...]) -> FloatArray:
    return np.zeros(shape) if value is None else np.asarray(value, dtype=np.float64)


def concatenate(batches: list[BiasObservations]) -> BiasObservations:
    """One batch of several (same number of radars)."""
    names = BiasObservations.__dataclass_fields__
    return BiasObservations(
        **{name: np.concatenate([getattr(b, name) for b in batches]) for name in names}
    )


def fuse_references(
    y: FloatArray,
    R: FloatArray,
    C: FloatArray,
    s: FloatArray,
    P_s: FloatArray,
    mask: BoolArray,
) -> tuple[FloatArray, FloatArray]:
    """Information-weighted fusion of K bias-corrected positions per row, as references.

    y (N,K,2), R (N,K,2,2), C (N,K,2,4), s (N,K,4) and P_s (N,K,4,4) the current bias
    estimates of each source, mask (N,K) which sources exist. Each source is corrected to
    y - C s, with covariance R + C P_s C^T: leaving out the bias uncertainty would make
    the reference look better than it is and the estimates overconfident. Rows without any
    source get a NaN position and an infinite-looking covariance; drop them.
    """
    corrected = y - np.einsum("nkij,nkj->nki", C, s)
    cov = R + np.einsum("nkij,nkjl,nkml->nkim", C, P_s, C)
    info = masked_information(cov, mask)
    total = info.sum(axis=1)
    has_source = mask.any(axis=1)
    total[~has_source] = np.eye(2) * 1e-12
    fused_p = np.linalg.inv(total)
    weighted = np.einsum("nkij,nkj->ni", info, corrected)
    fused_xy = np.einsum("nij,nj->ni", fused_p, weighted)
    fused_xy[~has_source] = np.nan
    return fused_xy, fused_p


def masked_information(cov: FloatArray, mask: BoolArray) -> FloatArray:
    """Inverses of the 2x2 covariances (..., 2, 2) where mask, zero elsewhere (absent
    sources carry no information, and their zero covariances must not be inverted)."""
    where = mask[..., None, None]
    eye = np.broadcast_to(np.eye(2), cov.shape)
    return np.where(where, np.linalg.inv(np.where(where, cov, eye)), 0.0)
