"""The resident memory of a process of the service, for its status.

An operator sizing a host, or watching a service that runs for months, wants the memory
each process holds now (RSS), not its peak (``getrusage``'s ``ru_maxrss``): read from
``/proc/<pid>/statm`` (Linux); None where the platform does not tell.
"""

from __future__ import annotations

import os

__all__ = ["resident_mb"]

_PAGE_BYTES = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def resident_mb(pid: int | None = None) -> float | None:
    """RSS of process ``pid`` (this one by default), MB (2^20 bytes); None when unknown
    (no /proc, the process gone)."""
    path = f"/proc/{'self' if pid is None else pid}/statm"
    try:
        with open(path, encoding="ascii") as statm:
            pages = int(statm.read().split()[1])
    except (OSError, ValueError, IndexError):
        return None
    return round(pages * _PAGE_BYTES / 2**20, 1)
