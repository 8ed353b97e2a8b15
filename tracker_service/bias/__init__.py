"""Systematic-error (bias) estimation with Blom's split filters (DOMAIN.md section 6).

Per radar the bias s = [range offset m, range gain, azimuth offset rad, time offset s]
(measured minus true); the chain corrects a plot y to y - C s. ``make_bias_estimator``
picks the variant from ``BiasConfig.method``.
"""

from __future__ import annotations

from tracker_service.bias.common import (
    BiasEstimates,
    BiasEstimator,
    BiasFilterBase,
    ObservedFrom,
    OffEstimator,
)
from tracker_service.bias.config import COMPONENTS, N_BIAS, BiasConfig
from tracker_service.bias.coupled import CoupledBiasFilter, CoupledSizeError
from tracker_service.bias.macro import MacroBiasFilter
from tracker_service.bias.observations import (
    BiasObservations,
    ObservationKind,
    concatenate,
    fuse_references,
    make_observations,
)
from tracker_service.bias.separated import SeparatedBiasFilter

_METHODS: dict[str, type[BiasFilterBase]] = {
    "separated": SeparatedBiasFilter,
    "macro": MacroBiasFilter,
    "coupled": CoupledBiasFilter,
    "off": OffEstimator,
}


def make_bias_estimator(config: BiasConfig, n_radars: int) -> BiasEstimator:
    """The estimator ``config.method`` names, for radars 0 .. n_radars-1."""
    if n_radars < 1:
        raise ValueError(f"n_radars: {n_radars!r} must be >= 1")
    return _METHODS[config.method](config, n_radars)


__all__ = [
    "COMPONENTS",
    "N_BIAS",
    "BiasConfig",
    "BiasEstimates",
    "BiasEstimator",
    "BiasObservations",
    "CoupledBiasFilter",
    "CoupledSizeError",
    "MacroBiasFilter",
    "ObservationKind",
    "ObservedFrom",
    "SeparatedBiasFilter",
    "concatenate",
    "fuse_references",
    "make_bias_estimator",
    "make_observations",
]
