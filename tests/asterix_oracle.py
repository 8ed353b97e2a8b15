"""Comparison of our decoded items with the independent decoder's (libasterix) output."""

from __future__ import annotations

import math
from typing import Any


def _contains_in_order(needle: str, haystack: str) -> bool:
    it = iter(haystack)
    return all(c in it for c in needle)


def differences(oracle: Any, ours: Any, path: str = "") -> list[str]:
    """Every place where ours differs from the oracle, by the rules of SOURCES.md:
    floats within 1e-9, addresses and MB data given as hex by us and as integers by the
    oracle compared by value, oracle callsigns with dropped invalid characters matching any
    text of ours that holds them in order."""
    if isinstance(oracle, dict):
        if not isinstance(ours, dict):
            return [f"{path}: expected an object, got {ours!r}"]
        out = [f"{path}/{k}: missing" for k in oracle if k not in ours]
        out += [f"{path}/{k}: not in the oracle" for k in ours if k not in oracle]
        for key in oracle.keys() & ours.keys():
            out += differences(oracle[key], ours[key], f"{path}/{key}")
        return out
    if isinstance(oracle, list):
        if not isinstance(ours, list) or len(ours) != len(oracle):
            return [f"{path}: {oracle!r} != {ours!r}"]
        return [
            d
            for i, (o, m) in enumerate(zip(oracle, ours, strict=True))
            for d in differences(o, m, f"{path}[{i}]")
        ]
    if isinstance(oracle, float):
        ok = isinstance(ours, int | float) and math.isclose(
            oracle, ours, rel_tol=1e-9, abs_tol=1e-9
        )
        return [] if ok else [f"{path}: {oracle!r} != {ours!r}"]
    if isinstance(oracle, int) and isinstance(ours, str):
        try:
            return [] if int(ours, 16) == oracle else [f"{path}: {oracle:X} != {ours}"]
        except ValueError:
            return [f"{path}: {oracle!r} != {ours!r}"]
    if isinstance(oracle, str) and isinstance(ours, str) and oracle != ours:
        ok = len(oracle) < len(ours) and _contains_in_order(oracle, ours)
        return [] if ok else [f"{path}: {oracle!r} != {ours!r}"]
    if isinstance(ours, bool) or type(oracle) is not type(ours) or oracle != ours:
        return [f"{path}: {oracle!r} != {ours!r}"]
    return []
