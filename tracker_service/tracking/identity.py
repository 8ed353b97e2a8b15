"""Identity as a preference among kinematically possible pairs, written once for the local
tracker (track-plot), the initiator (plot-plot) and the fuser (local-system track)."""

from __future__ import annotations

from typing import Protocol

import numpy as np

from tracker_service.tracking.plots import BoolArray, FloatArray, IntArray, is_shared_code


class IdentityWeights(Protocol):
    """The three weights (``TrackerConfig`` and ``FusionConfig`` both carry them)."""

    @property
    def address_bonus(self) -> float: ...

    @property
    def address_mismatch_penalty(self) -> float: ...

    @property
    def mode3a_bonus(self) -> float: ...


def identity_cost(
    address_a: IntArray,
    address_b: IntArray,
    code_a: IntArray,
    code_b: IntArray,
    weights: IdentityWeights,
    code_usable: BoolArray | None = None,
) -> FloatArray:
    """Cost shift of each pair: two different Mode S addresses are two transponders
    (penalty), the same address the same one (bonus); the same Mode 3/A code is a bonus
    unless it is a shared code (7000, 2000, ...) or ``code_usable`` (the codes' validity,
    None: all usable) says otherwise. -1 is unknown. Applied to gated pairs only: identity
    never opens a gate."""
    both = (address_a >= 0) & (address_b >= 0)
    code_match = (code_a >= 0) & (code_a == code_b)
    if code_usable is not None:
        code_match &= code_usable
    if code_match.any():
        code_match &= ~is_shared_code(code_a)
    return np.asarray(
        weights.address_mismatch_penalty * (both & (address_a != address_b))
        - weights.address_bonus * (both & (address_a == address_b))
        - weights.mode3a_bonus * code_match,
        dtype=np.float64,
    )
