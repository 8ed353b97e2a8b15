"""The log's format and level, for every command and the processes they start.

``tracker-service --log-level LEVEL`` sets the level of the command's process and, through
the environment, of the processes it starts (the daemon's output process is spawned, so
it inherits nothing else); without it, the daemon logs at INFO.
"""

from __future__ import annotations

import logging
import os

__all__ = ["LOG_FORMAT", "LOG_LEVELS", "LOG_LEVEL_VARIABLE", "configure"]

LOG_FORMAT = "%(asctime)s %(levelname)s %(processName)s %(message)s"
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR")
LOG_LEVEL_VARIABLE = "TRACKER_SERVICE_LOG_LEVEL"


def configure(level: str | None = None, default: str = "INFO") -> None:
    """The root logger at ``level``, else the inherited one, else ``default``; the first
    call of a process decides (later ones change nothing, as ``logging.basicConfig``)."""
    if level is not None:
        os.environ[LOG_LEVEL_VARIABLE] = level
    logging.basicConfig(level=os.environ.get(LOG_LEVEL_VARIABLE, default), format=LOG_FORMAT)
