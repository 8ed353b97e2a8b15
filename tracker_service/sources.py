"""Which plots the chain takes on, by their source (I048/010 SAC/SIC), with bounded memory.

Each radar the chain meets gets a tracker and a plane of its own. A configured radar is
expected; a source the configuration does not know is tracked too (a radar added to the
network before the configuration caught up), but only up to ``max_unknown`` of them:
a hostile or broken feed cycling through SAC/SICs (65,536 values at 1,000/s, seen) would
otherwise add a tracker per value, and a status line each, without end (113 MB to 1 GB).
Beyond the limit, plots of new unknown sources are dropped and counted. A plot without a
source (no I010: the radar cannot be known) is dropped and counted too.
"""

from __future__ import annotations

import logging
from collections.abc import Collection
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from tracker_service.ratelimit import RateLimitedLog

__all__ = ["DEFAULT_MAX_UNKNOWN", "SourceAdmission", "SourceCounts"]

log = logging.getLogger(__name__)

DEFAULT_MAX_UNKNOWN = 8
_KEYS = 256 * 256


@dataclass(frozen=True, slots=True)
class SourceCounts:
    """Cumulative counts since start (the core turns their growth into per-input counts)."""

    no_source: int = 0
    """Plots without I010 (SAC/SIC): dropped."""
    unknown_dropped: int = 0
    """Plots of unknown sources beyond the limit: dropped."""
    unknown_sources_dropped: int = 0
    """Distinct unknown SAC/SICs whose plots were dropped (exact: a 64 Kibit set)."""


class SourceAdmission:
    """``admit(plots)``: the rows of an ``asterix.plots`` table whose source the chain may
    track (configured, or among the first ``max_unknown`` unknown ones)."""

    def __init__(self, known: Collection[str], max_unknown: int = DEFAULT_MAX_UNKNOWN) -> None:
        if max_unknown < 0:
            raise ValueError(f"max_unknown must be 0 or more, not {max_unknown}")
        self.max_unknown = max_unknown
        self._admitted = np.zeros(_KEYS, dtype=np.bool_)
        for source in known:
            sac, sic = (int(part) for part in source.split("/"))
            self._admitted[sac * 256 + sic] = True
        self._refused = np.zeros(_KEYS, dtype=np.bool_)
        self._refused_count = 0
        """``_refused``'s True entries: ``counts`` is read twice per datagram, and a count
        over the 64 Kibit table cost more than the admission."""
        self.unknown: list[str] = []
        """The unknown sources admitted, in order of arrival (at most ``max_unknown``)."""
        self._no_source = 0
        self._unknown_dropped = 0
        self._warn = RateLimitedLog(log)

    @property
    def counts(self) -> SourceCounts:
        return SourceCounts(self._no_source, self._unknown_dropped, self._refused_count)

    def admit(self, plots: npt.NDArray[Any]) -> npt.NDArray[Any]:
        sac = np.asarray(plots["sac"], np.int64)
        sic = np.asarray(plots["sic"], np.int64)
        valid = (sac >= 0) & (sac < 256) & (sic >= 0) & (sic < 256)
        keys = np.where(valid, sac * 256 + sic, 0)
        admitted = valid & self._admitted[keys]
        if admitted.all():
            return plots
        missing = int(np.count_nonzero(~valid))
        if missing:
            self._no_source += missing
            self._warn.warning(
                "no_source", "%d plot(s) without a source (no I048/010 SAC/SIC) dropped", missing
            )
        for key in np.unique(keys[valid & ~admitted]).tolist():
            source = f"{key >> 8}/{key & 255}"
            if len(self.unknown) < self.max_unknown:
                self._admitted[key] = True
                self.unknown.append(source)
                admitted |= valid & (keys == key)
                continue
            rows = int(np.count_nonzero(valid & (keys == key)))
            self._unknown_dropped += rows
            self._refused_count += not self._refused[key]
            self._refused[key] = True
            self._warn.warning(
                "unknown_dropped",
                "plots of unknown source %s dropped: already %d unknown sources tracked "
                "([system] max_unknown_sources); configure the radar to track it",
                source,
                self.max_unknown,
            )
        return plots[admitted]
